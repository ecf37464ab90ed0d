"""Reading small CSV tables with one-line errors (activations, jaw poses, marker trajectories).

Every error names the file, the line (the header is line 1) and the column, so the CLI can
print it as is. Blank lines are skipped; a UTF-8 byte-order mark is accepted.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim.errors import FacesimError


@dataclass(frozen=True)
class Table:
    """A CSV file split into its header and data rows (strings, whitespace stripped).

    path : the file; header : column names; rows : one tuple of fields per data row;
    lines : (len(rows),) the file line number of each row; header_line : that of the header.
    """

    path: Path
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    lines: tuple[int, ...]
    header_line: int = 1

    def where(self, i: int, column: str | None = None) -> str:
        """``"FILE: line L, column 'C'"`` of data row ``i`` (0-based), for messages."""
        at = f"{self.path}: line {self.lines[i]}"
        return f"{at}, column {column!r}" if column is not None else at


def read_table(path, what: str, first: str = "frame", example: str = "") -> Table:
    """Read ``path`` as a CSV table whose first column is ``first``.

    ``what`` names the kind of file in messages (e.g. ``"activations file"``), ``example`` is
    the expected header shown when it is missing. Raises :class:`FacesimError` for a missing
    or unreadable file, an empty file, a header without ``first`` or with duplicate or empty
    names, a file without data rows, and rows with the wrong number of fields.
    """
    path = Path(path)
    expected = f"; expected a header like '{example}'" if example else ""
    if not path.exists():
        raise FacesimError(f"{path}: no such {what}")
    if path.is_dir():
        raise FacesimError(f"{path}: expected a {what}, found a folder")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise FacesimError(f"{path}: not a text CSV file (not UTF-8){expected}") from None
    except OSError as exc:
        raise FacesimError(f"{path}: cannot read ({exc.strerror or exc})") from None
    records = [(k + 1, [f.strip() for f in fields]) for k, fields in enumerate(csv.reader(text.splitlines()))]
    records = [(line, fields) for line, fields in records if any(fields)]
    if not records:
        raise FacesimError(f"{path}: empty {what}{expected}")
    line0, header = records[0]
    if first not in header:
        raise FacesimError(f"{path}: line {line0}: no {first!r} column in the header{expected}")
    if header[0] != first:
        raise FacesimError(f"{path}: line {line0}: expected {first!r} as the first column, got {header[0]!r}")
    seen = set()
    for name in header:
        if not name:
            raise FacesimError(f"{path}: line {line0}: empty column name in the header")
        if name in seen:
            raise FacesimError(f"{path}: line {line0}: duplicate column {name!r}")
        seen.add(name)
    if len(records) == 1:
        raise FacesimError(f"{path}: no data rows after the header")
    for line, fields in records[1:]:
        if len(fields) != len(header):
            raise FacesimError(f"{path}: line {line}: expected {len(header)} fields like the header, "
                               f"got {len(fields)}")
    return Table(path, tuple(header), tuple(tuple(f) for _, f in records[1:]), tuple(line for line, _ in records[1:]),
                 line0)


def number(table: Table, i: int, column: str, text: str, allow_missing: bool = False) -> float:
    """``text`` (row ``i``, ``column``) as a finite float; empty or ``nan`` gives NaN if ``allow_missing``."""
    if allow_missing and text.lower() in ("", "nan"):
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        got = repr(text) if text else "an empty field"
        raise FacesimError(f"{table.where(i, column)}: expected a number, got {got}")
    return value


def numbers(table: Table, columns, allow_missing: bool = False) -> np.ndarray:
    """``(len(rows), len(columns))`` float64 values of the named columns (see :func:`number`)."""
    index = [table.header.index(c) for c in columns]
    out = np.empty((len(table.rows), len(index)))
    for i, row in enumerate(table.rows):
        for j, (c, k) in enumerate(zip(columns, index)):
            out[i, j] = number(table, i, c, row[k], allow_missing)
    return out


def frame_numbers(table: Table, column: str = "frame") -> np.ndarray:
    """``(len(rows),)`` int64 frame numbers: non-negative integers, strictly increasing."""
    k = table.header.index(column)
    frames = np.empty(len(table.rows), dtype=np.int64)
    for i, row in enumerate(table.rows):
        text = row[k]
        try:
            value = int(text)
        except ValueError:
            try:
                f = float(text)
                value = int(f) if f.is_integer() else None
            except ValueError:
                value = None
        if value is None or value < 0:
            raise FacesimError(f"{table.where(i, column)}: expected a frame number (integer >= 0), got {text!r}")
        if i and value <= frames[i - 1]:
            raise FacesimError(f"{table.where(i, column)}: frame {value} after frame {frames[i - 1]}; "
                               "expected increasing frame numbers, one row per frame")
        frames[i] = value
    return frames
