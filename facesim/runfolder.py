"""The output folder of a long run (``facesim simulate``, ``facesim solve-mocap``): one run at a
time, never two runs mixed.

:class:`RunFolder` claims a folder for one run and checks what it already holds:

* **one writer**: an exclusive ``flock`` on ``OUT/.lock`` (holding the pid and host of the run)
  is taken before anything is written; a second run into the folder stops with a one-line
  :class:`FacesimError` naming the pid. The kernel drops the lock when its process ends, however
  it ends (SIGKILL included), so a stale ``.lock`` file never blocks a resume.
* **no silent replacement**: a folder holding a run needs ``resume`` (continue it) or
  ``overwrite`` (remove it first); they exclude each other.
* **resume only the same run**: ``OUT/run.json`` records the command and the fingerprints of its
  inputs when the run starts (the whole model, the capture or the controls, the frames, the jaw
  model, every option that changes results); a resume with other inputs is refused, naming what
  differs (``model (tissues)``, ``options (fit.noise)``).

:func:`fingerprint` hashes any value made of arrays, dataclasses, containers, scalars and plain
objects (their public attributes): the content, not the identity. :func:`finish` runs the
writes that end a run (the summary, the TRC) without masking the error that stopped it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import socket
from collections.abc import Mapping
from pathlib import Path
from typing import Callable

import numpy as np

import facesim
from facesim._files import atomic_write
from facesim.errors import FacesimError

RUN_RECORD = "run.json"
LOCK = ".lock"
#: option fields left out of the inputs record: wall-clock budgets (a resume may give a frame more
#: time; only frames that ran out of it depend on the budget, and they are flagged)
UNRECORDED = ("max_seconds",)


# ------------------------------------------------------------------ fingerprints
def fingerprint(value) -> str:
    """16 hex digits of SHA-256 over the content of ``value``: arrays (dtype, shape, bytes),
    dataclasses (type and fields), mappings, sequences, scalars, paths, functions (qualified name)
    and other objects (type and public attributes; underscored ones are caches or derived)."""
    h = hashlib.sha256()
    _feed(h, value, set())
    return h.hexdigest()[:16]


def _feed(h, v, active: set) -> None:
    if isinstance(v, np.generic):
        v = v.item()
    if v is None or isinstance(v, (bool, int, float, complex, str, bytes)):
        h.update(f"{type(v).__name__}:{v!r};".encode())
        return
    if isinstance(v, Path):
        h.update(f"path:{v};".encode())
        return
    if isinstance(v, np.ndarray) and v.dtype != object:
        a = np.ascontiguousarray(v)
        h.update(f"array:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
        return
    if id(v) in active:   # a cycle: the object is already being hashed
        h.update(b"cycle;")
        return
    active.add(id(v))
    try:
        if isinstance(v, np.ndarray):
            h.update(f"objects:{v.shape};".encode())
            for item in v.ravel():
                _feed(h, item, active)
        elif dataclasses.is_dataclass(v) and not isinstance(v, type):
            h.update(f"{type(v).__qualname__}(".encode())
            for f in dataclasses.fields(v):
                h.update(f"{f.name}=".encode())
                _feed(h, getattr(v, f.name), active)
            h.update(b")")
        elif isinstance(v, Mapping):
            h.update(b"{")
            for key in sorted(v, key=repr):
                _feed(h, key, active)
                _feed(h, v[key], active)
            h.update(b"}")
        elif isinstance(v, (list, tuple)):
            h.update(f"[{len(v)}:".encode())
            for item in v:
                _feed(h, item, active)
            h.update(b"]")
        elif isinstance(v, (set, frozenset)):
            _feed(h, sorted(v, key=repr), active)
        elif callable(v) and hasattr(v, "__qualname__"):
            h.update(f"callable:{getattr(v, '__module__', '')}.{v.__qualname__};".encode())
        elif hasattr(v, "__dict__"):
            h.update(f"{type(v).__qualname__}<".encode())
            _feed(h, {k: a for k, a in vars(v).items() if not k.startswith("_")}, active)
            h.update(b">")
        else:
            h.update(f"{type(v).__qualname__}:{v!r};".encode())
    finally:
        active.discard(id(v))


def describe(value, skip: tuple[str, ...] = UNRECORDED):
    """A JSON value standing for ``value`` in a run record: dataclasses as objects of their fields
    (leaving out the field names in ``skip``), scalars and strings as they are, lists of them as
    lists, anything else as its :func:`fingerprint` -- so a difference can be named by field."""
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: describe(getattr(value, f.name), skip) for f in dataclasses.fields(value) if f.name not in skip}
    if isinstance(value, (list, tuple)) and all(v is None or isinstance(v, (bool, int, float, str)) for v in value):
        return list(value)
    if isinstance(value, (list, tuple)):
        return [describe(v, skip) for v in value]
    return fingerprint(value)


def parts(value) -> dict:
    """``{field: fingerprint}`` of a dataclass (e.g. a :class:`~facesim.model.FaceModel`): the
    record of a model, so that a resume with another model can say which part differs."""
    return {f.name: fingerprint(getattr(value, f.name)) for f in dataclasses.fields(value)}


def differences(old, new, prefix: str = "") -> list[str]:
    """Dotted names of the entries of two JSON values that differ (an entry missing on one side
    differs)."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in list(old) + [k for k in new if k not in old]:
            name = f"{prefix}.{key}" if prefix else str(key)
            if key not in old or key not in new:
                out.append(name)
            else:
                out += differences(old[key], new[key], name)
        return out
    return [] if json.dumps(old, sort_keys=True) == json.dumps(new, sort_keys=True) else [prefix or "value"]


# ------------------------------------------------------------------ the folder
class RunFolder:
    """The output folder ``root`` of one ``command`` run (see the module doc). Construct it first
    (checks ``resume`` and ``overwrite``), then ``with folder:`` holds the lock for the whole run;
    inside, :attr:`previous` is the record of the run the folder holds (or None) and
    :meth:`start` refuses, clears or continues it and writes the new record.

    ``holds_a_run()``: whether the folder holds results of a run (its logs); ``clear()``: remove
    them (and nothing else)."""

    def __init__(self, root, command: str, resume: bool = False, overwrite: bool = False):
        self.root = Path(root)
        self.command = command
        self.resume, self.overwrite = bool(resume), bool(overwrite)
        if self.resume and self.overwrite:
            raise FacesimError(f"{command}: resume and overwrite exclude each other")
        if self.root.exists() and not self.root.is_dir():
            raise FacesimError(f"{self.root}: expected an output folder, found a file")
        self._fd = None

    @property
    def record_path(self) -> Path:
        return self.root / RUN_RECORD

    # -------------------------------------------------------------- the lock
    def __enter__(self) -> RunFolder:
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FacesimError(f"{self.root}: cannot create the output folder ({exc.strerror or exc})") from None
        self._fd = _lock(self.root / LOCK)
        return self

    def __exit__(self, *exc) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.unlink(self.root / LOCK)   # while still holding it: see _lock
            except OSError:
                pass
            os.close(fd)

    # -------------------------------------------------------------- the run record
    @property
    def previous(self) -> dict | None:
        """The record (``run.json``) of the run in the folder, None if there is none or it is
        unreadable."""
        try:
            record = json.loads(self.record_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return record if isinstance(record, dict) else None

    def start(self, inputs: dict, holds_a_run: Callable[[], bool], clear: Callable[[], None],
              info: dict | None = None) -> None:
        """Begin the run: refuse a folder holding a run unless resuming it (with the same
        ``inputs``: a JSON object of fingerprints and described options) or overwriting it (then
        ``clear()``), and write the new record. Call with the lock held."""
        if self._fd is None:
            raise RuntimeError("RunFolder.start: enter the folder (with folder:) first")
        inputs = json.loads(json.dumps(inputs))   # as it reads back from the file
        held = holds_a_run()
        if held and not (self.resume or self.overwrite):
            raise FacesimError(f"{self.root}: holds the results of an earlier run; use --resume to continue it, "
                               "--overwrite to replace it, or another folder")
        if held and self.resume:
            self._check(self.previous, inputs)
        if self.overwrite or not held:
            if held:
                clear()
            self.record_path.unlink(missing_ok=True)
        record = {"command": self.command, "facesim_version": facesim.__version__, "inputs": inputs,
                  "info": info or {}}
        atomic_write(self.record_path, lambda tmp: tmp.write_text(json.dumps(record, indent=2) + "\n"))

    def _check(self, old: dict | None, inputs: dict) -> None:
        if old is None:
            raise FacesimError(f"{self.root}: --resume: the run in this folder has no readable {RUN_RECORD} (made by an "
                               "older facesim?), so its inputs cannot be checked; use --overwrite to replace it")
        if old.get("command") != self.command:
            raise FacesimError(f"{self.root}: --resume: the folder holds a {old.get('command')} run, not a "
                               f"{self.command} run; use another folder or --overwrite")
        changed = differences(old.get("inputs", {}), inputs)
        if changed:
            groups: dict[str, list[str]] = {}
            for name in changed:
                top, _, rest = name.partition(".")
                groups.setdefault(top, [])
                if rest:
                    groups[top].append(rest)
            what = ", ".join(f"{top} ({', '.join(sub)})" if sub else top for top, sub in groups.items())
            raise FacesimError(f"{self.root}: --resume: the run in this folder was made with other inputs: {what} "
                               f"differ; resume with the inputs it was made with, or use --overwrite")


def _lock(path: Path) -> int | None:
    """An open descriptor of ``path`` holding an exclusive ``flock`` (None where ``fcntl`` does not
    exist), with this process's pid and host written in it. Another holder: FacesimError."""
    try:
        import fcntl
    except ImportError:   # not POSIX: runs are not locked
        return None
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise FacesimError(f"{path}: cannot create the lock file ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder(fd)
            os.close(fd)
            raise FacesimError(f"{path.parent}: another facesim run ({holder}) is writing into this folder") from None
        # the holder before us unlinks the file while holding its lock: if we locked that
        # unlinked file, the path now names another (or none), so start over with it
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except OSError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
    return fd


def _holder(fd: int) -> str:
    try:
        pid, _, host = os.pread(fd, 256, 0).decode(errors="replace").strip().partition(" ")
    except OSError:
        pid, host = "", ""
    if not pid:
        return "pid unknown"
    return f"pid {pid}" if host in ("", socket.gethostname()) else f"pid {pid} on {host}"


def finish(steps, failed: bool) -> None:
    """Run every callable of ``steps`` (the writes that end a run). When the run ``failed`` (an
    exception is on its way out), their errors are dropped: the first error is the one to
    report, not a consequence of it (a full disk also fails the summary). Otherwise the first of
    their errors is raised, after all steps ran."""
    first = None
    for step in steps:
        try:
            step()
        except (OSError, FacesimError) as exc:
            first = first or exc
    if first is not None and not failed:
        if isinstance(first, OSError):
            where = f"{first.filename}: " if first.filename else ""
            raise FacesimError(f"{where}cannot write ({first.strerror or first})") from None
        raise first


__all__ = ["LOCK", "RUN_RECORD", "RunFolder", "describe", "differences", "fingerprint", "finish", "parts"]
