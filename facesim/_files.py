"""Output-file helpers shared by the exporters, the renderer and the CLI."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from facesim.errors import FacesimError


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
        if tmp.exists():
            tmp.unlink()
    return path
