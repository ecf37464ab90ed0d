"""Fitted jaw rigs on disk: one versioned ``.npz`` per rig.

The archive holds the rig's arrays plus ``meta``, a JSON string with ``format`` (``RIG_FORMAT``),
``kind`` (``"posselt"``, ``"classic"``, ...), ``version`` and the rig's scalar settings. Reading
checks each of them and names the file and the field in a one-line error.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.errors import ModelFileError

RIG_FORMAT = "facesim-jaw-rig"
RIG_VERSION = 1


def save_rig(path, kind: str, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-serialisable) as a ``kind`` rig to ``path`` (.npz), atomically."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_name(path.name + ".npz")
    head = {"format": RIG_FORMAT, "kind": kind, "version": RIG_VERSION, **meta}
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    payload["meta"] = np.array(json.dumps(head))
    return atomic_write(path, lambda tmp: np.savez_compressed(tmp, **payload))


def open_npz(path, what: str) -> np.lib.npyio.NpzFile:
    """``np.load`` of the ``.npz`` at ``path`` (no pickles), or a one-line
    :class:`~facesim.errors.ModelFileError` saying the file is missing or unreadable and that
    ``what`` (e.g. "a posselt jaw rig .npz") was expected."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(path, f"no such file (expected {what})")
    try:
        data = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise ModelFileError(path, f"not a readable .npz file ({type(exc).__name__})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ModelFileError(path, f"not an .npz archive: expected {what}")
    return data


def load_rig(path, kind: str, array_keys, meta_keys) -> tuple[dict[str, np.ndarray], dict]:
    """Read a ``kind`` rig written by :func:`save_rig`: (arrays, meta). Raises
    :class:`~facesim.errors.ModelFileError` naming the file and field when anything is off."""
    path = Path(path)
    with open_npz(path, f"a {kind} jaw rig .npz") as data:
        if "meta" not in data.files:
            raise ModelFileError(path, "field 'meta' missing: not a facesim jaw rig")
        try:
            meta = json.loads(str(data["meta"]))
        except (json.JSONDecodeError, ValueError):
            raise ModelFileError(path, "field 'meta': expected a JSON string") from None
        if not isinstance(meta, dict) or meta.get("format") != RIG_FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise ModelFileError(path, f"field 'meta.format': expected {RIG_FORMAT!r}, got {got!r}")
        if meta.get("kind") != kind:
            raise ModelFileError(path, f"field 'meta.kind': expected a {kind!r} rig, got {meta.get('kind')!r}")
        if meta.get("version") != RIG_VERSION:
            raise ModelFileError(path, f"field 'meta.version': unknown jaw rig version {meta.get('version')!r} "
                                       f"(this facesim reads version {RIG_VERSION})")
        for key in meta_keys:
            if key not in meta:
                raise ModelFileError(path, f"field 'meta.{key}' missing ({kind} rig version {RIG_VERSION})")
        arrays = {}
        for key in array_keys:
            if key not in data.files:
                raise ModelFileError(path, f"field {key!r} missing ({kind} rig version {RIG_VERSION})")
            try:
                arrays[key] = data[key]
            except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, ValueError ...)
                raise ModelFileError(path, f"field {key!r} unreadable ({type(exc).__name__})") from None
    return arrays, meta


def rig_kind(path) -> str:
    """The ``kind`` of the rig stored in ``path`` (for loaders that dispatch on it)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
        return str(meta["kind"])
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError):
        raise ModelFileError(path, "not a facesim jaw rig (no readable 'meta.kind')") from None


__all__ = ["RIG_FORMAT", "RIG_VERSION", "load_rig", "open_npz", "rig_kind", "save_rig"]
