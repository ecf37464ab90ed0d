"""Fitted jaw rigs on disk: one versioned ``.npz`` per rig.

The archive holds the rig's arrays plus ``meta``, a JSON string with ``format`` (``RIG_FORMAT``),
``kind`` (``"posselt"``, ``"classic"``, ...), ``version`` and the rig's scalar settings. Reading
checks each of them and names the file and the field in a one-line error.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from facesim._files import NpzFormat, read_npz, write_npz
from facesim.errors import ModelFileError

RIG_FORMAT = "facesim-jaw-rig"
RIG_VERSION = 1
#: The largest magnitude of a rig's numbers (mm: 1 km; a head's are far below it).
MAX_VALUE = 1e6


def _format(kind: str) -> NpzFormat:
    return NpzFormat(RIG_FORMAT, RIG_VERSION, what=f"a {kind} jaw rig .npz", name="a facesim jaw rig",
                     label=f"{kind} rig")


def save_rig(path, kind: str, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-serialisable) as a ``kind`` rig to ``path`` (.npz), atomically."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        path = path.with_name(path.name + ".npz")
    return write_npz(path, _format(kind), arrays, {"kind": kind, **meta})


def load_rig(path, kind: str, array_keys, meta_keys) -> tuple[dict[str, np.ndarray], dict]:
    """Read a ``kind`` rig written by :func:`save_rig`: (arrays, meta). Raises
    :class:`~facesim.errors.ModelFileError` naming the file and field when anything is off."""

    def check_kind(path, meta):
        if meta.get("kind") != kind:
            raise ModelFileError(path, f"field 'meta.kind': expected a {kind!r} rig, got {meta.get('kind')!r}")

    with read_npz(path, _format(kind), check_kind) as archive:
        for key in meta_keys:
            archive.field(key)
        arrays = {key: archive.array(key) for key in array_keys}
    for key, a in arrays.items():   # a rig is numbers: refuse strings, booleans, complex ones before any cast
        if a.dtype.kind not in "fiu":
            raise ModelFileError(path, f"field {key!r}: expected real numbers, stored as dtype {a.dtype}")
        finite = np.abs(a[np.isfinite(a)]) if a.size else a
        if finite.size and finite.max() > MAX_VALUE:
            raise ModelFileError(path, f"field {key!r}: expected values within +-{MAX_VALUE:g} (mm or rad), got "
                                       f"{finite.max():g}")
    return arrays, archive.meta


def rig_kind(path) -> str:
    """The ``kind`` of the rig stored in ``path`` (for loaders that dispatch on it)."""
    path = Path(path)
    if not path.is_file():   # np.load of a named pipe blocks for ever
        raise ModelFileError(path, "no such file (expected a facesim jaw rig .npz)" if not path.exists() else
                             "not a regular file (expected a facesim jaw rig .npz)")
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
        return str(meta["kind"])
    except Exception:  # noqa: BLE001 (a damaged zip raises BadZipFile, NotImplementedError, zlib.error ...)
        raise ModelFileError(path, "not a facesim jaw rig (no readable 'meta.kind')") from None


__all__ = ["RIG_FORMAT", "RIG_VERSION", "load_rig", "rig_kind", "save_rig"]
