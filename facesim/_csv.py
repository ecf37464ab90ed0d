"""Reading small CSV tables with one-line errors (activations, jaw poses, marker trajectories).

Every error names the file, the line (the header is line 1) and the column, so the CLI can
print it as is. Blank lines are skipped; a UTF-8 byte-order mark is accepted.

Numbers are read strictly (:data:`NUMBER`): the decimal notation CSV writers produce, so that
a value cut short by a truncated file (``12.``, ``1.5e``, ``-``) is an error rather than a
different number; Python-only spellings (``1_000``, ``infinity``) are refused too, and so are
non-finite values (``inf``, ``1e400``). A value cut short that still parses (``12.3`` cut to
``12``) cannot be told from a complete one; the last row of a file that does not end with a
newline says so when its fields are too few.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim.errors import FacesimError

#: A number as CSV writers write it: optional sign, digits with an optional fraction (or a
#: leading-dot fraction), optional exponent. ASCII digits only.
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]+)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: The largest frame number: 2**53 - 1, kept exact wherever frame numbers pass through float64
#: (the frame logs, ``Time = frame / rate``).
MAX_FRAME = 2**53 - 1
_NON_FINITE = ("inf", "+inf", "-inf", "infinity", "+infinity", "-infinity")


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
    or unreadable file (a folder, binary, UTF-16 or other non-UTF-8 text), an empty file, a
    header without ``first`` or with duplicate or empty names, a file without data rows, and
    rows with the wrong number of fields.
    """
    path = Path(path)
    expected = f"; expected a header like '{example}'" if example else ""
    if not path.exists():
        raise FacesimError(f"{path}: no such {what}")
    if path.is_dir():
        raise FacesimError(f"{path}: expected a {what}, found a folder")
    text = read_text(path, f"a text CSV {what}", expected)
    try:
        records = [(k + 1, [f.strip() for f in fields]) for k, fields in enumerate(csv.reader(text.splitlines()))]
    except csv.Error as exc:   # a field over csv.field_size_limit(): not a table
        raise FacesimError(f"{path}: not a CSV table ({exc}){expected}") from None
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
                               f"got {len(fields)}{cut_short(text, line)}")
    return Table(path, tuple(header), tuple(tuple(f) for _, f in records[1:]), tuple(line for line, _ in records[1:]),
                 line0)


def read_text(path: Path, what: str, expected: str = "") -> str:
    """The text of ``path`` (UTF-8, optional byte-order mark); one-line errors for a file that is
    not UTF-8 text (binary, UTF-16: NUL bytes), is not a regular file (a folder, a named pipe or a
    device would block or never end) or cannot be read. ``what`` e.g. ``"a TRC file"``."""
    if not path.is_file():
        raise FacesimError(f"{path}: no such file" if not path.exists() else
                           f"{path}: not a regular file (a folder, pipe or device); expected {what}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FacesimError(f"{path}: not {what}: byte {exc.start} is not UTF-8 text{expected}") from None
    except OSError as exc:
        raise FacesimError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if "\0" in text:   # UTF-16 text or a binary file that happens to decode
        raise FacesimError(f"{path}: not {what}: it holds NUL bytes (a binary or UTF-16 file?){expected}")
    return text


def cut_short(text: str, line: int) -> str:
    """``"; the file ends in the middle of this line (cut short?)"`` if ``line`` (1-based) is the
    last line of ``text`` and the file does not end with a newline, else ``""``: for messages."""
    if text and not text.endswith(("\n", "\r")) and line == len(text.splitlines()):
        return "; the file ends in the middle of this line (cut short?)"
    return ""


def parse_number(text: str) -> float | None:
    """``text`` as a float if it is a number in :data:`NUMBER`'s form, else None (may be +-inf
    when it overflows float64, e.g. ``1e400``)."""
    return float(text) if NUMBER.fullmatch(text) else None


def number(table: Table, i: int, column: str, text: str, allow_missing: bool = False) -> float:
    """``text`` (row ``i``, ``column``) as a finite float; empty or ``nan`` gives NaN if ``allow_missing``."""
    if allow_missing and text.lower() in ("", "nan"):
        return math.nan
    value = parse_number(text)
    if value is None:
        if text.lower() in _NON_FINITE:
            raise FacesimError(f"{table.where(i, column)}: expected a finite number, got {text!r}")
        got = repr(text) if text else "an empty field"
        hint = " (a number cut short?)" if re.fullmatch(r"[+-]?[0-9]*\.?[0-9]*(?:[eE][+-]?)?", text) and text else ""
        raise FacesimError(f"{table.where(i, column)}: expected a number, got {got}{hint}")
    if not math.isfinite(value):
        raise FacesimError(f"{table.where(i, column)}: {text} overflows a float64; expected a finite number")
    return value


def numbers(table: Table, columns, allow_missing: bool = False) -> np.ndarray:
    """``(len(rows), len(columns))`` float64 values of the named columns (see :func:`number`)."""
    index = [table.header.index(c) for c in columns]
    out = np.empty((len(table.rows), len(index)))
    for i, row in enumerate(table.rows):
        for j, (c, k) in enumerate(zip(columns, index)):
            out[i, j] = number(table, i, c, row[k], allow_missing)
    return out


def frame_numbers(table: Table, column: str = "frame", start: int = 0, note: str = "") -> np.ndarray:
    """``(len(rows),)`` int64 frame numbers: integers from ``start`` to :data:`MAX_FRAME`,
    strictly increasing (``3.0`` and ``1e3`` are integers; ``3.5`` is not). ``note`` is added
    to the message for a number out of range (e.g. ``"; TRC numbers frames from 1"``)."""
    k = table.header.index(column)
    frames = np.empty(len(table.rows), dtype=np.int64)
    for i, row in enumerate(table.rows):
        text = row[k]
        value = parse_number(text)
        if value is not None and re.fullmatch(r"[+-]?[0-9]+", text):
            value = int(text) if len(text) < 30 else MAX_FRAME + 1   # exact; int() refuses > 4300 digits
        elif value is not None and math.isfinite(value) and value.is_integer():
            value = int(value)
        else:
            value = None
        if value is None or not start <= value <= MAX_FRAME:
            raise FacesimError(f"{table.where(i, column)}: expected a frame number (an integer from {start} to "
                               f"2**53-1), got {text!r}{note}")
        if i and value <= frames[i - 1]:
            what = "again" if value == frames[i - 1] else f"after frame {frames[i - 1]}"
            raise FacesimError(f"{table.where(i, column)}: frame {value} {what} (line {table.lines[i - 1]}); "
                               "expected increasing frame numbers, one row per frame")
        frames[i] = value
    return frames
