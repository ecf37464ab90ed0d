"""Append-only CSV frame logs: the per-frame files of a long run, written so a crash never loses a frame.

A frame log is a CSV file with a header line and one line per finished frame, the frame number
first. :class:`FrameLog` writes it: the file is first rewritten atomically with the header and the
lines kept from an earlier run, then every :meth:`FrameLog.add` appends one complete line, synced
to disk, so the file on disk always ends with a whole frame (or a line cut by a crash, which the
reader drops; a line cut by a failed write is removed at once). :func:`read_lines` resumes: the complete, well-formed lines of an earlier
log by frame number. :func:`read_log` reads a finished log's numbers.

``facesim simulate`` writes ``frames.csv`` and ``markers.csv`` this way (:mod:`facesim.simulate`),
``facesim solve-mocap`` its four logs ``activations.csv``, ``jaw.csv``, ``residuals.csv`` and
``frames.csv`` (:mod:`facesim.inverse.tracking`).
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.errors import FacesimError


def csv_line(values) -> str:
    """One CSV line (with its newline) of ``values``, quoted where needed."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()


def read_lines(path, header: str, n_fields: int | None = None) -> dict[int, str]:
    """The complete, well-formed lines of the log at ``path`` by frame number (the first field).

    ``header`` : the header line the log must start with (with its newline); a missing or
    unreadable file, or one with another header, holds no lines. ``n_fields`` : the fields of a
    line (default: those of ``header``). Lines without a newline (cut by a crash), with another
    number of fields or without an integer frame number are left out; a frame written twice
    keeps its last line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return {}
    lines = text.splitlines(keepends=True)
    if not lines or lines[0] != header:
        return {}
    width = len(next(csv.reader([header]))) if n_fields is None else n_fields
    found = {}
    for line in lines[1:]:
        fields = next(csv.reader([line]), [])
        if not line.endswith("\n") or len(fields) != width:
            continue
        try:
            found[int(fields[0])] = line
        except ValueError:
            continue
    return found


class FrameLog:
    """An append-only log at ``path``: rewritten (atomically) as ``header`` and ``lines``, then kept
    open; each :meth:`add` writes one complete line and syncs it to disk. A context manager.

    Writes are unbuffered (``os.write`` on an ``O_APPEND`` descriptor): a failed write (a full disk,
    a file size limit) is cut back to the last complete line and raised as a one-line
    :class:`FacesimError` naming the file, and closing the log never writes (so it cannot fail
    again and hide the first error)."""

    def __init__(self, path, header: str, lines=()):
        self.path = Path(path)
        text = header + "".join(lines)
        atomic_write(self.path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
        try:
            self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)
        except OSError as exc:
            raise FacesimError(f"{self.path}: cannot open for appending ({exc.strerror or exc})") from None
        self.size = len(text.encode("utf-8"))

    def add(self, line: str) -> None:
        """Append ``line`` (one complete line, with its newline) and sync it to disk."""
        data = memoryview(line.encode("utf-8"))
        try:
            written = 0
            while written < len(data):   # a write may be short (a size limit reached midway)
                written += os.write(self.fd, data[written:])
            os.fsync(self.fd)
        except OSError as exc:
            try:   # no cut line left for a later append to run into
                os.ftruncate(self.fd, self.size)
            except OSError:
                pass   # a cut line has no newline: read_lines drops it
            raise FacesimError(f"{self.path}: cannot write ({exc.strerror or exc})") from None
        self.size += len(data)

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_log(path) -> tuple[list[str], np.ndarray]:
    """Header and rows ``(k, columns) float64`` of a finished numeric frame log (``frame`` first),
    e.g. the ``activations.csv`` a solve-mocap run wrote. One-line :class:`FacesimError` for a
    missing or empty file or a field that is not a number."""
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such file; expected the results of a solve-mocap run")
    with open(path, newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.reader(fh) if r]
    if not rows:
        raise FacesimError(f"{path}: empty file; expected a header line")
    try:
        data = np.array([[float(v) for v in r] for r in rows[1:]], dtype=np.float64)
    except ValueError:
        raise FacesimError(f"{path}: expected numbers after the header line") from None
    return rows[0], data.reshape(-1, len(rows[0]))


__all__ = ["FrameLog", "csv_line", "read_lines", "read_log"]
