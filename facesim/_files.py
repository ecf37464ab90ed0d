"""File helpers at the bottom of the import graph: checked output names, atomic writes, the
shipped ``meshes/`` folder, and the versioned ``.npz`` + JSON format of models and jaw rigs."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from facesim.errors import FacesimError, ModelFileError


def require_suffix(path, suffixes: tuple[str, ...], what: str) -> Path:
    """``Path(path)`` if its suffix is one of ``suffixes`` (case-insensitive), else a one-line
    :class:`FacesimError` naming the file, what it should be and the accepted suffixes."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        got = f"{path.suffix!r}" if path.suffix else "no suffix"
        raise FacesimError(f"{path}: expected {what} ending in {' or '.join(suffixes)}, got {got}")
    return path


def atomic_write(path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    The temporary name keeps ``path``'s suffix (writers that choose the format by suffix still
    work), so a failed or interrupted write never leaves a truncated ``path`` behind. Errors
    of the file system become a one-line :class:`FacesimError` naming ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise FacesimError(f"{path}: cannot write ({exc.strerror or exc})") from None
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:   # cleaning up must not hide the error that made the mess
            pass
    return path


#: The ``meshes/`` folder of the repository holding the ``facesim`` package: the shipped models,
#: their jaw rigs and the demo capture.
MESHES = Path(__file__).resolve().parent.parent / "meshes"


def open_npz(path, what: str) -> np.lib.npyio.NpzFile:
    """``np.load`` of the ``.npz`` at ``path`` (no pickles), or a one-line :class:`ModelFileError`
    saying the file is missing or unreadable and that ``what`` (e.g. "a facesim model .npz") was
    expected."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(path, f"no such file (expected {what})")
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 (a damaged zip raises BadZipFile, NotImplementedError, zlib.error ...)
        raise ModelFileError(path, f"not a readable .npz file ({type(exc).__name__})") from None
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ModelFileError(path, f"not an .npz archive (a single .npy array?): expected {what}")
    return data


@dataclass(frozen=True)
class NpzFormat:
    """A versioned file format: one compressed ``.npz`` of arrays plus ``meta``, a JSON string
    whose ``format`` is ``tag`` and whose ``version`` is ``version``; and the words of its errors.

    what : what a file of the format is, for "no such file (expected ...)" ("a facesim model .npz").
    name : what a file without ``meta`` is not ("a facesim model file").
    label : the format in version and missing-field errors ("model format": "unknown model
        format version 2", "field 'X' missing (model format version 1)").
    """

    tag: str
    version: int
    what: str
    name: str
    label: str


def write_npz(path, fmt: NpzFormat, arrays: dict, meta: dict) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-serialisable, with ``format`` and ``version`` of ``fmt``
    put first) as one compressed ``.npz`` at ``path`` (written whatever its suffix), atomically."""
    payload = {k: np.asarray(v) for k, v in arrays.items()}
    payload["meta"] = np.array(json.dumps({"format": fmt.tag, "version": fmt.version, **meta}))

    def write(tmp: Path):
        with open(tmp, "wb") as f:          # a file object: numpy adds no ".npz" to the name
            np.savez_compressed(f, **payload)

    return atomic_write(path, write)


class NpzArchive:
    """A versioned archive opened by :func:`read_npz`: ``meta`` (dict) and the fields, each read
    with a one-line :class:`ModelFileError` naming the file and the field."""

    def __init__(self, path: Path, data: np.lib.npyio.NpzFile, meta: dict, fmt: NpzFormat):
        self.path, self.data, self.meta, self.fmt = path, data, meta, fmt

    @property
    def files(self) -> list[str]:
        return self.data.files

    def array(self, key: str) -> np.ndarray:
        """The array field ``key`` (missing or corrupt: ModelFileError)."""
        if key not in self.data.files:
            raise ModelFileError(self.path, f"field {key!r} missing ({self.fmt.label} version {self.fmt.version})")
        try:
            return self.data[key]
        except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, ValueError ...)
            raise ModelFileError(self.path, f"field {key!r} unreadable ({type(exc).__name__})") from None

    def field(self, key: str):
        """The ``meta`` entry ``key`` (missing: ModelFileError)."""
        if key not in self.meta:
            raise ModelFileError(self.path, f"field 'meta.{key}' missing ({self.fmt.label} version {self.fmt.version})")
        return self.meta[key]


@contextmanager
def read_npz(path, fmt: NpzFormat, check: Callable[[Path, dict], object] | None = None) -> Iterator[NpzArchive]:
    """Open a file of ``fmt`` written by :func:`write_npz`: the :class:`NpzArchive` while the
    ``with`` block runs. Checks, each a one-line :class:`ModelFileError` naming the file: it exists
    and is an ``.npz``, ``meta`` is a JSON object, its ``format`` is ``fmt.tag``, then
    ``check(path, meta)`` (optional, e.g. a rig's kind), then its ``version``."""
    path = Path(path)
    with open_npz(path, fmt.what) as data:
        if "meta" not in data.files:
            raise ModelFileError(path, f"field 'meta' missing: not {fmt.name}")
        try:
            raw = data["meta"]
        except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, NotImplementedError ...)
            raise ModelFileError(path, f"field 'meta' unreadable ({type(exc).__name__})") from None
        try:
            meta = json.loads(str(raw))
        except (json.JSONDecodeError, ValueError):
            raise ModelFileError(path, "field 'meta': expected a JSON string") from None
        if not isinstance(meta, dict):
            raise ModelFileError(path, "field 'meta': expected a JSON object")
        if meta.get("format") != fmt.tag:
            raise ModelFileError(path, f"field 'meta.format': expected {fmt.tag!r}, got {meta.get('format')!r}")
        if check is not None:
            check(path, meta)
        if meta.get("version") != fmt.version:
            raise ModelFileError(path, f"field 'meta.version': unknown {fmt.label} version {meta.get('version')!r} "
                                       f"(this facesim reads version {fmt.version})")
        yield NpzArchive(path, data, meta, fmt)
