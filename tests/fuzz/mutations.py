"""Mutation operators: a valid input (file bytes, npz arrays, option value, collider spec) in, a
:class:`Mutant` out -- the new input, what was changed and whether the result may be accepted.

Verdicts: :data:`GARBAGE` (facesim must refuse it: exit 0 is a failure), :data:`EITHER` (a
different but possibly valid input: a one-line refusal or a success are both fine) and
:data:`VALID` (the documented readers accept it: a refusal is a failure too, e.g. a UTF-8
byte-order mark, a blank line, columns in another order, a missing marker as NaN).

Every operator is a function ``op(rng, base, spec) -> Mutant`` registered under its name in one
of the tables (:data:`CSV_OPS`, :data:`TRC_OPS`, :data:`C3D_OPS`, :data:`NPZ_OPS`, ...); the
name (and the variant it picked, after a colon) is what ``KNOWN_FAILURES`` refers to.
"""

from __future__ import annotations

import io
import json
import math
import re
from dataclasses import dataclass, field

import numpy as np

GARBAGE, EITHER, VALID = "garbage", "either", "valid"
#: the numbers the CSV readers accept (facesim._csv.NUMBER)
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]+)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


@dataclass(frozen=True)
class Mutant:
    """A mutated input. ``op``: operator[:variant]; ``what``: the change, for the failure message;
    ``verdict``: GARBAGE, EITHER or VALID; ``data``: the new file bytes (None: see ``special``);
    ``special``: ``"missing"``, ``"dir"``, ``"fifo"`` or ``"loop"`` (a symlink to itself) instead of
    a file; ``value``: the new argv word(s) for option and spec mutations."""

    op: str
    what: str
    verdict: str
    data: bytes | None = None
    special: str | None = None
    value: tuple = field(default_factory=tuple)


def _worst(*verdicts: str) -> str:
    return GARBAGE if GARBAGE in verdicts else EITHER if EITHER in verdicts else VALID


# ------------------------------------------------------------------ whole files (any kind)
def file_missing(rng, base, spec):
    return Mutant("file:missing", "no file at the path", GARBAGE, special="missing")


def file_dir(rng, base, spec):
    return Mutant("file:dir", "a folder at the path", GARBAGE, special="dir")


def file_fifo(rng, base, spec):
    return Mutant("file:fifo", "a named pipe (nobody writes to it) at the path", GARBAGE, special="fifo")


def file_loop(rng, base, spec):
    return Mutant("file:loop", "a symbolic link to itself at the path", GARBAGE, special="loop")


def file_empty(rng, base, spec):
    return Mutant("file:empty", "an empty file", GARBAGE, b"")


def file_text(rng, base, spec):
    return Mutant("file:text", "a line of prose", GARBAGE, b"this is not the file you are looking for\n")


def file_binary(rng, base, spec):
    return Mutant("file:binary", "4 KiB of random bytes", GARBAGE, bytes(rng.getrandbits(8) for _ in range(4096)))


def file_truncate(rng, base, spec):
    cut = rng.randrange(1, len(base))
    return Mutant("file:truncate", f"cut at byte {cut} of {len(base)}", GARBAGE, base[:cut])


def file_flip(rng, base, spec):
    data = bytearray(base)
    where = sorted(rng.sample(range(len(data)), min(3, len(data))))
    for i in where:
        data[i] ^= 1 << rng.randrange(8)
    return Mutant("file:flip", f"one bit flipped in bytes {where}", EITHER, bytes(data))


FILE_OPS = {f.__name__.replace("_", ":", 1): f for f in
            (file_missing, file_dir, file_fifo, file_loop, file_empty, file_text, file_binary, file_truncate, file_flip)}


# ------------------------------------------------------------------ CSV tables
@dataclass(frozen=True)
class CsvSpec:
    """What a CSV kind accepts. ``roles``: column -> role of its values: ``frame``, ``unit``
    (an activation in [0, 1]), ``value`` (a jaw parameter or rotation, rad or mm, plausibly
    checked), ``coord`` (a marker coordinate: one NaN alone is half a marker), ``far`` (a collider
    position: far away is harmless); ``optional``: columns that may be left out (muscles);
    ``same_frames``: the frames are compared with another file's (a jaw file beside activations);
    ``markers``: columns come as NAME_x, NAME_y, NAME_z."""

    roles: dict
    optional: frozenset = frozenset()
    same_frames: bool = False
    markers: bool = False


TOKENS = ("nan", "NaN", "", "NA", "inf", "-inf", "Infinity", "1e400", "1e30", "-1e30", "-0", "+0", "0.0", "1e-320",
          "abc", "0x1F", "1_000", "12.", "1.5e", "-", "\u0663", "\u22121", " 0.25 ", '"0.25"', "9" * 40, "1" * 5000,
          "2", "-0.5", "0.5")


def token_verdict(role: str, token: str) -> str:
    """May a field of ``role`` holding ``token`` be accepted?"""
    t = token.strip()
    if t.startswith('"') and t.endswith('"') and len(t) >= 2:
        t = t[1:-1].strip()   # the csv module unquotes
    if role == "frame":
        return EITHER if re.fullmatch(r"[+-]?[0-9]{1,15}(\.0)?", t) and not t.startswith("-") or t == "-0" else GARBAGE
    if not _NUMBER.fullmatch(t):
        return GARBAGE
    v = float(t)
    if not math.isfinite(v):
        return GARBAGE
    if abs(v) >= 1e6:
        return EITHER if role == "far" else GARBAGE
    if role == "unit":
        return VALID if 0.0 <= v <= 1.0 else GARBAGE
    return EITHER


class Csv:
    """A CSV file as lines and fields (the base is plain: no quotes, one header line)."""

    def __init__(self, base: bytes):
        self.lines = base.decode().splitlines()
        self.header = self.lines[0].split(",")
        self.rows = [line.split(",") for line in self.lines[1:]]

    @staticmethod
    def join(header, rows, end="\n") -> bytes:
        return (end.join([",".join(header)] + [",".join(r) for r in rows]) + end).encode()


def _role(spec: CsvSpec, column: str) -> str:
    return spec.roles.get(column, "value")


def _marker_of(column: str) -> str | None:
    m = re.fullmatch(r"(.+)_[xyz]", column)
    return m.group(1) if m else None


def csv_number(rng, base, spec):
    t = Csv(base)
    i, j = rng.randrange(len(t.rows)), rng.randrange(len(t.header))
    token = rng.choice(TOKENS)
    column, old = t.header[j], t.rows[i][j]
    t.rows[i][j] = token
    verdict = token_verdict(_role(spec, column), token)
    if token in (",", "") and _role(spec, column) == "coord":
        verdict = GARBAGE
    label = {"9" * 40: "huge-int", "1" * 5000: "5000-digits"}.get(token, token.strip() or "empty")
    return Mutant(f"csv:number:{label}", f"data row {i + 1}, column {column!r}: {old!r} -> {token[:12]!r}",
                  verdict, Csv.join(t.header, t.rows))


def csv_missing_marker(rng, base, spec):
    """A whole marker missing in one frame (NaN or empty fields): documented as accepted."""
    t = Csv(base)
    names = sorted({_marker_of(c) for c in t.header[1:]} - {None})
    if not spec.markers or not names:
        return csv_number(rng, base, spec)
    name, i, token = rng.choice(names), rng.randrange(len(t.rows)), rng.choice(("NaN", "", "nan"))
    for axis in "xyz":
        t.rows[i][t.header.index(f"{name}_{axis}")] = token
    return Mutant("csv:missing_marker", f"marker {name!r} in data row {i + 1}: {token!r} x3", VALID,
                  Csv.join(t.header, t.rows))


def csv_delete_line(rng, base, spec):
    t = Csv(base)
    k = rng.randrange(len(t.lines))
    lines = t.lines[:k] + t.lines[k + 1:]
    if k == 0:
        verdict = GARBAGE
    elif len(t.rows) == 1 or spec.same_frames:
        verdict = GARBAGE
    else:
        verdict = EITHER
    return Mutant("csv:delete_line:" + ("header" if k == 0 else "row"), f"line {k + 1} deleted", verdict,
                  ("\n".join(lines) + "\n").encode())


def csv_duplicate_line(rng, base, spec):
    t = Csv(base)
    k = rng.randrange(len(t.lines))
    lines = t.lines[:k + 1] + t.lines[k:]
    return Mutant("csv:duplicate_line:" + ("header" if k == 0 else "row"), f"line {k + 1} twice", GARBAGE,
                  ("\n".join(lines) + "\n").encode())


def csv_reverse_rows(rng, base, spec):
    t = Csv(base)
    return Mutant("csv:reverse_rows", "data rows in reverse order (frames decrease)",
                  GARBAGE if len(t.rows) > 1 else VALID, Csv.join(t.header, t.rows[::-1]))


def csv_frames(rng, base, spec):
    t = Csv(base)
    how = rng.choice(("zero", "minus1", "plus1000", "max", "float", "sci"))
    first = int(t.rows[0][0])
    for r in t.rows:
        f = int(r[0])
        r[0] = {"zero": "0", "minus1": str(f - first - 1), "plus1000": str(f + 1000), "max": str(2**53 + f),
                "float": f"{f}.5", "sci": f"{f}e0"}[how]
    verdict = {"zero": GARBAGE if len(t.rows) > 1 else EITHER, "minus1": GARBAGE, "max": GARBAGE, "float": GARBAGE,
               "plus1000": GARBAGE if spec.same_frames else EITHER, "sci": EITHER}[how]
    return Mutant(f"csv:frames:{how}", f"frame column rewritten ({how})", verdict, Csv.join(t.header, t.rows))


def csv_truncate(rng, base, spec):
    t = Csv(base)
    cut = rng.randrange(1, len(base))
    data = base[:cut]
    lines = [line for line in data.decode(errors="replace").splitlines() if line.strip()]
    verdict = EITHER
    if len(lines) < 2 or cut < len(t.lines[0]) + 1:
        verdict = GARBAGE
    else:
        last = lines[-1].split(",")
        if len(last) != len(t.header) or not last[-1] or not _NUMBER.fullmatch(last[-1]) and \
                token_verdict(_role(spec, t.header[-1]), last[-1]) == GARBAGE:
            verdict = GARBAGE
        elif spec.same_frames and len(lines) - 1 != len(t.rows):
            verdict = GARBAGE
    return Mutant("csv:truncate", f"cut at byte {cut} of {len(base)}", verdict, data)


def csv_rename_column(rng, base, spec):
    t = Csv(base)
    j = rng.randrange(len(t.header))
    old = t.header[j]
    how = rng.choice(("typo", "suffix", "upper", "empty", "duplicate", "space"))
    if how == "typo" and len(old) <= 2:
        how = "suffix"
    if how == "typo":
        k = rng.randrange(len(old) - 1)
        new = old[:k] + old[k + 1] + old[k] + old[k + 2:]
        how = "typo" if new != old else "suffix"
    if how != "typo":
        new = {"suffix": old + "_1", "upper": old.upper(), "empty": "", "space": old + " x",
               "duplicate": t.header[(j + 1) % len(t.header)]}.get(how, old + "_1")
    header = list(t.header)
    header[j] = new
    verdict = GARBAGE
    if how == "upper" and old != "frame":
        verdict = EITHER
    if spec.markers and how in ("suffix", "typo") and _marker_of(old):
        # renaming one coordinate of a marker leaves half a marker; renaming all three is a new marker
        name = _marker_of(old)
        if rng.random() < 0.5:
            header = list(t.header)
            for axis in "xyz":
                header[t.header.index(f"{name}_{axis}")] = f"{name}Z_{axis}"
            new, how, verdict = f"{name}Z_*", "marker", EITHER
    return Mutant(f"csv:rename_column:{how}", f"header column {j + 1} {old!r} -> {new!r}", verdict,
                  Csv.join(header, t.rows))


def csv_add_column(rng, base, spec):
    t = Csv(base)
    how = rng.choice(("unknown", "duplicate", "marker") if spec.markers else ("unknown", "duplicate"))
    if how == "marker":
        header = t.header + ["extra_x", "extra_y", "extra_z"]
        rows = [r + ["1.0", "2.0", "30.0"] for r in t.rows]
        return Mutant("csv:add_column:marker", "a marker 'extra' the model lacks", EITHER, Csv.join(header, rows))
    j = rng.randrange(1, len(t.header)) if len(t.header) > 1 else 0
    name = "extra" if how == "unknown" else t.header[j]
    header = t.header + [name]
    rows = [r + [r[j]] for r in t.rows]
    return Mutant(f"csv:add_column:{how}", f"column {name!r} appended", GARBAGE, Csv.join(header, rows))


def csv_drop_column(rng, base, spec):
    t = Csv(base)
    j = rng.randrange(len(t.header))
    column = t.header[j]
    drop = [j]
    verdict = VALID if column in spec.optional else GARBAGE
    if spec.markers and _marker_of(column) and rng.random() < 0.5:
        name = _marker_of(column)
        drop = [t.header.index(f"{name}_{a}") for a in "xyz"]
        column, verdict = f"{name}_*", EITHER
    header = [c for k, c in enumerate(t.header) if k not in drop]
    rows = [[v for k, v in enumerate(r) if k not in drop] for r in t.rows]
    return Mutant("csv:drop_column" + (":frame" if j == 0 else ""), f"column {column!r} removed", verdict,
                  Csv.join(header, rows))


def csv_swap_columns(rng, base, spec):
    """Two columns swapped in the header and the data alike (the file means the same)."""
    t = Csv(base)
    if len(t.header) < 3:
        return csv_reverse_rows(rng, base, spec)
    if spec.markers and rng.random() < 0.6:
        names = sorted({_marker_of(c) for c in t.header[1:]} - {None})
        a, b = rng.sample(names, 2)
        order = list(range(len(t.header)))
        for axis in "xyz":
            i, k = t.header.index(f"{a}_{axis}"), t.header.index(f"{b}_{axis}")
            order[i], order[k] = order[k], order[i]
        how, what, verdict = "marker", f"markers {a!r} and {b!r} swapped", VALID
    else:
        i, k = rng.sample(range(len(t.header)), 2)
        order = list(range(len(t.header)))
        order[i], order[k] = order[k], order[i]
        frame = 0 in (i, k)
        how = "frame" if frame else "column"
        what = f"columns {t.header[i]!r} and {t.header[k]!r} swapped"
        verdict = EITHER if frame or spec.markers else VALID
    return Mutant(f"csv:swap_columns:{how}", what, verdict,
                  Csv.join([t.header[k] for k in order], [[r[k] for k in order] for r in t.rows]))


def csv_row_fields(rng, base, spec):
    t = Csv(base)
    i = rng.randrange(len(t.rows))
    how = rng.choice(("extra", "short"))
    if how == "extra":
        t.rows[i] = t.rows[i] + ["0"]
    else:
        t.rows[i] = t.rows[i][:-1]
    return Mutant(f"csv:row_fields:{how}", f"data row {i + 1} with {len(t.rows[i])} fields for {len(t.header)}",
                  GARBAGE, Csv.join(t.header, t.rows))


def csv_text(rng, base, spec):
    """Whole-text variants: encodings, line ends, separators, blank and comment lines."""
    t = Csv(base)
    text = base.decode()
    how = rng.choice(("bom", "crlf", "cr", "blank_line", "trailing_blank", "utf16", "nul", "semicolon", "tab",
                      "comment", "header_only", "whitespace", "latin1", "junk_tail", "long_field", "quoted"))
    if how == "bom":
        return Mutant("csv:text:bom", "UTF-8 byte-order mark first", VALID, b"\xef\xbb\xbf" + base)
    if how == "crlf":
        return Mutant("csv:text:crlf", "CRLF line ends", EITHER, text.replace("\n", "\r\n").encode())
    if how == "cr":
        return Mutant("csv:text:cr", "CR line ends (old Mac)", EITHER, text.replace("\n", "\r").encode())
    if how == "blank_line":
        k = rng.randrange(1, len(t.lines) + 1)
        lines = t.lines[:k] + [""] + t.lines[k:]
        return Mutant("csv:text:blank_line", f"blank line before line {k + 1}", VALID, ("\n".join(lines) + "\n").encode())
    if how == "trailing_blank":
        return Mutant("csv:text:trailing_blank", "blank lines and spaces at the end", VALID, base + b"\n  \n\n")
    if how == "utf16":
        return Mutant("csv:text:utf16", "UTF-16 encoded", GARBAGE, text.encode("utf-16"))
    if how == "nul":
        k = rng.randrange(len(base))
        return Mutant("csv:text:nul", f"NUL byte at {k}", GARBAGE, base[:k] + b"\0" + base[k:])
    if how == "semicolon":
        return Mutant("csv:text:semicolon", "';' separators", GARBAGE, text.replace(",", ";").encode())
    if how == "tab":
        return Mutant("csv:text:tab", "tab separators", GARBAGE, text.replace(",", "\t").encode())
    if how == "comment":
        return Mutant("csv:text:comment", "a '# comment' line first", GARBAGE, b"# made by hand\n" + base)
    if how == "header_only":
        return Mutant("csv:text:header_only", "the header and no data rows", GARBAGE, (t.lines[0] + "\n").encode())
    if how == "whitespace":
        return Mutant("csv:text:whitespace", "only spaces and newlines", GARBAGE, b"   \n\n \t \n")
    if how == "latin1":
        header = list(t.header)
        header[-1] = header[-1] + "\u00e9"
        return Mutant("csv:text:latin1", "a Latin-1 byte in the header", GARBAGE,
                      Csv.join(header, t.rows).decode().encode("latin-1"))
    if how == "junk_tail":
        return Mutant("csv:text:junk_tail", "random binary bytes appended", GARBAGE, base + bytes(range(128, 256)))
    if how == "long_field":
        t.rows[0][-1] = "0." + "0" * 200_000 + "1"
        return Mutant("csv:text:long_field", "a 200,000-character number (0.000...1)", EITHER,
                      Csv.join(t.header, t.rows))
    quoted = [[f'"{v}"' for v in r] for r in t.rows]
    return Mutant("csv:text:quoted", "every data field in double quotes", EITHER, Csv.join(t.header, quoted))


CSV_OPS = {"csv:number": csv_number, "csv:missing_marker": csv_missing_marker, "csv:delete_line": csv_delete_line,
           "csv:duplicate_line": csv_duplicate_line, "csv:reverse_rows": csv_reverse_rows, "csv:frames": csv_frames,
           "csv:truncate": csv_truncate, "csv:rename_column": csv_rename_column, "csv:add_column": csv_add_column,
           "csv:drop_column": csv_drop_column, "csv:swap_columns": csv_swap_columns,
           "csv:row_fields": csv_row_fields, "csv:text": csv_text,
           **{k: FILE_OPS[k] for k in ("file:missing", "file:dir", "file:fifo", "file:empty", "file:binary")}}


# ------------------------------------------------------------------ TRC
class Trc:
    """A TRC file as its header lines (5), the blank line and the data rows (tab-separated)."""

    def __init__(self, base: bytes):
        lines = base.decode().splitlines()
        self.head = lines[:5]
        self.rows = [line.split("\t") for line in lines[6:] if line.strip()]
        self.keys = self.head[1].split("\t")
        self.values = self.head[2].split("\t")

    def meta(self, key, value=None):
        k = self.keys.index(key)
        if value is not None:
            self.values[k] = value
            self.head[2] = "\t".join(self.values)
        return self.values[k]

    def bytes(self, blank=True) -> bytes:
        return ("\n".join(self.head + ([""] if blank else []) + ["\t".join(r) for r in self.rows]) + "\n").encode()


def trc_number(rng, base, spec):
    t = Trc(base)
    i, j = rng.randrange(len(t.rows)), rng.randrange(len(t.rows[0]))
    token = rng.choice(TOKENS)
    old = t.rows[i][j]
    t.rows[i][j] = token
    role = "frame" if j == 0 else "time" if j == 1 else "coord"
    verdict = token_verdict("value" if role == "time" else role, token)
    if role == "frame" and token.strip() not in (old, f"+{old}", f"{old}.0"):
        verdict = GARBAGE   # Frame# from 1 and increasing
    label = {"9" * 40: "huge-int", "1" * 5000: "5000-digits"}.get(token, token.strip() or "empty")
    return Mutant(f"trc:number:{label}", f"data row {i + 1}, field {j + 1} ({role}): {old!r} -> {token[:12]!r}",
                  verdict, t.bytes())


def trc_missing_marker(rng, base, spec):
    t = Trc(base)
    n = (len(t.rows[0]) - 2) // 3
    i, m = rng.randrange(len(t.rows)), rng.randrange(n)
    token = rng.choice(("", "NaN"))
    t.rows[i][2 + 3 * m: 5 + 3 * m] = [token] * 3
    return Mutant("trc:missing_marker", f"marker {m + 1} in data row {i + 1}: {token!r} x3", VALID, t.bytes())


#: edits of the TRC header's values (line 3): name -> (key, new value or f(old value), verdict)
_TRC_META = {
    "units_cm": ("Units", "cm", GARBAGE), "units_m": ("Units", "m", GARBAGE), "units_upper": ("Units", "MM", EITHER),
    "units_bad": ("Units", "furlongs", GARBAGE), "units_empty": ("Units", "", GARBAGE),
    "numframes_more": ("NumFrames", lambda n: str(int(n) + 1), GARBAGE),
    "numframes_less": ("NumFrames", lambda n: str(int(n) - 1), GARBAGE), "numframes_abc": ("NumFrames", "abc", GARBAGE),
    "nummarkers_more": ("NumMarkers", lambda n: str(int(n) + 1), GARBAGE), "nummarkers_zero": ("NumMarkers", "0", GARBAGE),
    "rate_zero": ("DataRate", "0", GARBAGE), "rate_negative": ("DataRate", "-30", GARBAGE),
    "rate_nan": ("DataRate", "nan", GARBAGE), "rate_huge": ("DataRate", "1e30", EITHER),
    "rate_abc": ("DataRate", "abc", GARBAGE),
}


def trc_header(rng, base, spec):
    t = Trc(base)
    how = rng.choice(("units_cm", "units_m", "units_upper", "units_bad", "units_empty", "numframes_more",
                      "numframes_less", "numframes_abc", "nummarkers_more", "nummarkers_zero", "rate_zero",
                      "rate_negative", "rate_nan", "rate_huge", "rate_abc", "no_units_key", "dup_name",
                      "rename_marker", "empty_name", "drop_xyz_line", "no_blank_line", "no_pathfiletype"))
    verdict, what = GARBAGE, how
    if how in _TRC_META:
        key, value, verdict = _TRC_META[how]
        old = t.meta(key)
        value = value(old) if callable(value) else value
        t.meta(key, value)
        what = f"{key} {old!r} -> {value!r}"
    elif how == "no_units_key":
        k = t.keys.index("Units")
        t.head[1] = "\t".join(t.keys[:k] + t.keys[k + 1:])
        t.head[2] = "\t".join(t.values[:k] + t.values[k + 1:])
    elif how in ("dup_name", "rename_marker", "empty_name"):
        labels = t.head[3].split("\t")
        named = [k for k, s in enumerate(labels) if s.strip() and k >= 2]
        a = rng.choice(named)
        if how == "dup_name":
            b = rng.choice([k for k in named if k != a])
            labels[a] = labels[b]
            what = f"marker name {labels[b]!r} twice"
        elif how == "rename_marker":
            labels[a] = labels[a] + "Z"
            what, verdict = f"marker renamed {labels[a]!r} (unknown to the model)", EITHER
        else:
            labels[a] = ""
            what = "a marker name left empty"
        t.head[3] = "\t".join(labels)
    elif how == "drop_xyz_line":
        t.head = t.head[:4]
        return Mutant("trc:header:drop_xyz_line", "line 5 (X1 Y1 Z1 ...) removed", GARBAGE, t.bytes())
    elif how == "no_blank_line":
        return Mutant("trc:header:no_blank_line", "no blank line between header and data", EITHER, t.bytes(False))
    else:
        t.head[0] = t.head[0].replace("PathFileType", "PathFile")
    return Mutant(f"trc:header:{how}", what, verdict, t.bytes())


def trc_rows(rng, base, spec):
    t = Trc(base)
    how = rng.choice(("delete", "duplicate", "reverse", "from_zero", "blank_inside", "short_row", "long_row",
                      "time_zero"))
    verdict = GARBAGE
    if how == "delete":
        del t.rows[rng.randrange(len(t.rows))]
    elif how == "duplicate":
        k = rng.randrange(len(t.rows))
        t.rows.insert(k, list(t.rows[k]))
    elif how == "reverse":
        t.rows.reverse()
    elif how == "from_zero":
        for r in t.rows:
            r[0] = str(int(r[0]) - 1)
    elif how == "blank_inside":
        lines = t.bytes().decode().splitlines()
        lines.insert(7, "")
        return Mutant("trc:rows:blank_inside", "a blank line between the data rows", GARBAGE,
                      ("\n".join(lines) + "\n").encode())
    elif how == "short_row":
        k = rng.randrange(len(t.rows))
        t.rows[k] = t.rows[k][:-1]
    elif how == "long_row":
        k = rng.randrange(len(t.rows))
        t.rows[k] = t.rows[k] + ["1.0"]
    else:
        for r in t.rows:
            r[1] = "0"
        verdict = EITHER
    return Mutant(f"trc:rows:{how}", f"data rows: {how}", verdict, t.bytes())


def trc_truncate(rng, base, spec):
    cut = rng.randrange(1, len(base))
    data = base[:cut]
    lines = data.decode(errors="replace").splitlines()
    full = base.decode().splitlines()
    verdict = GARBAGE
    if len(lines) == len(full):
        last, whole = lines[-1].split("\t"), full[-1].split("\t")
        if len(last) == len(whole) and _NUMBER.fullmatch(last[-1]):
            verdict = EITHER   # a number cut short that still reads as one (12.34 -> 12.3)
    return Mutant("trc:truncate", f"cut at byte {cut} of {len(base)}", verdict, data)


def trc_text(rng, base, spec):
    how = rng.choice(("bom", "crlf", "utf16", "nul", "spaces"))
    text = base.decode()
    if how == "bom":
        return Mutant("trc:text:bom", "UTF-8 byte-order mark first", EITHER, b"\xef\xbb\xbf" + base)
    if how == "crlf":
        return Mutant("trc:text:crlf", "CRLF line ends", EITHER, text.replace("\n", "\r\n").encode())
    if how == "utf16":
        return Mutant("trc:text:utf16", "UTF-16 encoded", GARBAGE, text.encode("utf-16"))
    if how == "nul":
        k = rng.randrange(len(base))
        return Mutant("trc:text:nul", f"NUL byte at {k}", GARBAGE, base[:k] + b"\0" + base[k:])
    return Mutant("trc:text:spaces", "spaces instead of tabs", GARBAGE, text.replace("\t", " ").encode())


TRC_OPS = {"trc:number": trc_number, "trc:missing_marker": trc_missing_marker, "trc:header": trc_header,
           "trc:rows": trc_rows, "trc:truncate": trc_truncate, "trc:text": trc_text,
           **{k: FILE_OPS[k] for k in ("file:missing", "file:dir", "file:fifo", "file:empty", "file:binary")}}


# ------------------------------------------------------------------ C3D (spec: the capture)
@dataclass(frozen=True)
class Capture:
    """The data a C3D is written from: frames, names, P (F, N, 3) mm, rate."""

    frames: np.ndarray
    names: tuple
    P: np.ndarray
    rate: float = 30.0


def write_c3d_bytes(frames, names, P, rate=30.0, units="mm", first=None) -> bytes:
    """A C3D file (ezc3d) as bytes, without facesim's checks (duplicate labels and all)."""
    import os
    import tempfile

    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(rate)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    pts = np.ones((4, len(names), len(P)))
    pts[:3] = np.transpose(np.asarray(P, dtype=np.float64), (2, 1, 0))
    c["data"]["points"] = pts
    if len(P):
        c["header"]["points"]["first_frame"] = int(frames[0] if first is None else first)
    fd, tmp = tempfile.mkstemp(suffix=".c3d")
    os.close(fd)
    try:
        c.write(tmp)
        with open(tmp, "rb") as f:
            return f.read()
    finally:
        os.unlink(tmp)


def c3d_data(rng, base, spec: Capture):
    """A change of the capture, written anew (ezc3d)."""
    P, names = spec.P.copy(), list(spec.names)
    rate, units, first = spec.rate, "mm", None
    how = rng.choice(("marker_nan", "coord_nan", "inf", "huge", "dup_label", "empty_label", "unknown_label",
                      "all_unknown", "units_cm", "units_m", "units_bad", "units_upper", "rate_zero", "rate_negative",
                      "rate_nan", "first_frame_big", "zeros"))
    f, m = rng.randrange(len(P)), rng.randrange(len(names))
    verdict = GARBAGE
    if how == "marker_nan":
        P[f, m] = np.nan
        verdict = VALID
    elif how == "coord_nan":
        P[f, m, rng.randrange(3)] = np.nan
        verdict = EITHER
    elif how == "inf":
        P[f, m, rng.randrange(3)] = np.inf
    elif how == "huge":
        P[f, m, rng.randrange(3)] = 1e30
    elif how == "dup_label":
        names[m] = names[(m + 1) % len(names)]
    elif how == "empty_label":
        names[m] = ""
    elif how == "unknown_label":
        names[m] = names[m] + "Z"
        verdict = EITHER
    elif how == "all_unknown":
        names = [f"M{k}" for k in range(len(names))]
    elif how.startswith("units"):
        units = {"units_cm": "cm", "units_m": "m", "units_bad": "in", "units_upper": "MM"}[how]
        verdict = EITHER if how == "units_upper" else GARBAGE
    elif how == "rate_zero":
        # ezc3d will not write a rate of 0 (it aborts the process): patch the float32 30.0 of the
        # header and of POINT:RATE in a valid file
        data = write_c3d_bytes(spec.frames, names, P, 30.0)
        head = data[:1536].replace(np.float32(30.0).tobytes(), np.float32(0.0).tobytes())
        return Mutant("c3d:data:rate_zero", "POINT:RATE and the header rate 0", GARBAGE, head + data[1536:])
    elif how.startswith("rate"):
        rate = {"rate_negative": -30.0, "rate_nan": math.nan}[how]
    elif how == "first_frame_big":
        first, verdict = 60000, EITHER
    else:
        P[f] = 0.0   # all-zero coordinates: every marker missing in that frame
        verdict = EITHER
    return Mutant(f"c3d:data:{how}", f"{how} (frame {f}, marker {m})", verdict,
                  write_c3d_bytes(spec.frames, names, P, rate, units, first))


def c3d_bytes(rng, base, spec):
    import struct

    how = rng.choice(("header", "parameters", "data", "block"))
    data = bytearray(base)
    start = (struct.unpack("<H", base[16:18])[0] - 1) * 512     # the first byte of the point data
    lo, hi = {"header": (0, 512), "parameters": (512, start), "data": (start, len(data))}.get(how, (0, len(data)))
    hi = max(lo + 1, min(hi, len(data)))
    if how == "block":
        k = rng.randrange(0, len(data) - 64)
        value = rng.choice((0, 255))
        data[k:k + 64] = bytes([value]) * 64
        what = f"bytes {k}..{k + 63} set to {value}"
    else:
        where = sorted(rng.sample(range(lo, hi), min(4, hi - lo)))
        for i in where:
            data[i] = rng.randrange(256)
        what = f"random values at bytes {where} ({how})"
    return Mutant(f"c3d:bytes:{how}", what, EITHER, bytes(data))


def c3d_truncate(rng, base, spec):
    """Cut the file: garbage if the cut reaches into the parameters or the point data, else only
    the padding of the last 512-byte block goes (EITHER)."""
    import struct

    n_points, _, first, last = struct.unpack("<4H", base[2:10])
    (start,) = struct.unpack("<H", base[16:18])
    end = (start - 1) * 512 + (last - first + 1) * n_points * 16
    cut = rng.randrange(1, len(base))
    return Mutant("c3d:truncate", f"cut at byte {cut} of {len(base)} (data end at {end})",
                  GARBAGE if cut < end else EITHER, base[:cut])


C3D_OPS = {"c3d:data": c3d_data, "c3d:bytes": c3d_bytes, "c3d:truncate": c3d_truncate,
           **{k: FILE_OPS[k] for k in ("file:missing", "file:dir", "file:fifo", "file:empty", "file:text")}}


# ------------------------------------------------------------------ npz archives (model, poses, rig)
def load_arrays(base: bytes) -> dict:
    with np.load(io.BytesIO(base), allow_pickle=False) as d:
        return {k: d[k] for k in d.files}


def save_arrays(arrays: dict, compressed=True, pickle=False) -> bytes:
    buf = io.BytesIO()
    if pickle:
        np.savez(buf, **arrays)      # object arrays are pickled (np.load refuses them without allow_pickle)
    elif compressed:
        np.savez_compressed(buf, **arrays)
    else:
        np.savez(buf, **arrays)
    return buf.getvalue()


@dataclass(frozen=True)
class NpzSpec:
    """``optional``: fields a reader may do without (dropping them is EITHER); ``unread``: fields
    the command never reads (any change is EITHER); ``extremes``: the command reads a poses file's
    ``names`` and ``sliders`` (jaw retarget); ``unbounded``: fields where an infinite value is a
    documented "no limit" (EITHER)."""

    optional: frozenset = frozenset()
    unread: frozenset = frozenset()
    extremes: bool = False
    unbounded: frozenset = frozenset()   # fields where +-inf means "no limit" (a classic rig's bounds)


def _array_key(rng, arrays, kinds="fiub"):
    keys = [k for k, a in arrays.items() if k != "meta" and a.dtype.kind in kinds and a.size]
    return rng.choice(sorted(keys))


def npz_value(rng, base, spec: NpzSpec):
    """One element of a numeric field set to NaN, inf, a huge number or a negative one."""
    a = load_arrays(base)
    key = _array_key(rng, a, "f")
    value = rng.choice((math.nan, math.inf, -math.inf, 1e30, -1e30))
    arr = a[key].copy()
    idx = tuple(rng.randrange(s) for s in arr.shape) if arr.ndim else ()
    arr[idx] = value
    a[key] = arr
    limitless = key in spec.unbounded and math.isinf(value)
    return Mutant(f"npz:value:{value:g}", f"field {key!r}{list(idx)} = {value:g}",
                  EITHER if key in spec.unread or limitless else GARBAGE, save_arrays(a))


def npz_dtype(rng, base, spec):
    a = load_arrays(base)
    key = _array_key(rng, a)
    old = a[key]
    how = rng.choice(("str", "complex", "float", "int", "bool", "float32", "object"))
    verdict = GARBAGE
    pickle = False
    if how == "str":
        new = old.astype(str)
    elif how == "complex":
        new = old.astype(np.complex128)
    elif how == "float":
        new = old.astype(np.float64)
        verdict = VALID if old.dtype.kind == "f" else GARBAGE
    elif how == "int":
        new = old.astype(np.int64)
        verdict = GARBAGE if old.dtype.kind == "b" else EITHER   # integers are numbers (other values, maybe)
    elif how == "bool":
        new = old.astype(bool)
        verdict = VALID if old.dtype.kind == "b" else GARBAGE
    elif how == "float32":
        new = old.astype(np.float32)
        verdict = EITHER if old.dtype.kind == "f" else GARBAGE
    else:
        new = old.astype(object)
        pickle = True
    if key in spec.unread:
        verdict = EITHER
    a[key] = new
    return Mutant(f"npz:dtype:{how}", f"field {key!r} {old.dtype} -> {new.dtype}", verdict, save_arrays(a, pickle=pickle))


def npz_shape(rng, base, spec):
    a = load_arrays(base)
    key = _array_key(rng, a)
    old = a[key]
    how = rng.choice(("empty", "scalar", "flat", "extra_axis", "drop_row", "transpose"))
    if how == "empty":
        new = old[:0] if old.ndim else np.zeros(0, old.dtype)
    elif how == "scalar":
        new = np.asarray(old.ravel()[0])
    elif how == "flat":
        new = old.ravel()
    elif how == "extra_axis":
        new = old[None]
    elif how == "drop_row":
        new = old[:-1] if old.ndim and len(old) > 1 else old[:0]
    else:
        new = old.T if old.ndim >= 2 else old[:, None] if old.ndim == 1 else old[None]
    verdict = GARBAGE
    if new.shape == old.shape:
        # the transpose of a square matrix: a rotation stays one; anything else may change meaning
        verdict = VALID if how != "transpose" or np.array_equal(new, old) else EITHER
    elif how == "drop_row" and (key.endswith("_faces") or key == "skin"):
        verdict = EITHER   # a surface with one triangle fewer (open, but a surface)
    if key in spec.unread:
        verdict = EITHER
    a[key] = new
    return Mutant(f"npz:shape:{how}", f"field {key!r} shape {old.shape} -> {new.shape}", verdict, save_arrays(a))


def npz_drop(rng, base, spec: NpzSpec):
    a = load_arrays(base)
    key = rng.choice(sorted(a))
    del a[key]
    verdict = EITHER if key in spec.optional | spec.unread else GARBAGE
    return Mutant("npz:drop" + (":meta" if key == "meta" else ""), f"field {key!r} removed", verdict, save_arrays(a))


def npz_extra(rng, base, spec):
    a = load_arrays(base)
    a["zz_extra"] = np.arange(3.0)
    return Mutant("npz:extra", "an unknown field 'zz_extra' added", EITHER, save_arrays(a))


def npz_uncompressed(rng, base, spec):
    return Mutant("npz:uncompressed", "the same arrays, saved uncompressed (np.savez)", VALID,
                  save_arrays(load_arrays(base), compressed=False))


def npz_npy(rng, base, spec):
    buf = io.BytesIO()
    np.save(buf, np.zeros((3, 3)))
    return Mutant("npz:npy", "a .npy array saved under the .npz name", GARBAGE, buf.getvalue())


def _meta(a):
    return json.loads(str(a["meta"]))


def npz_meta(rng, base, spec):
    a = load_arrays(base)
    if "meta" not in a:
        return npz_drop(rng, base, spec)
    meta = _meta(a)
    how = rng.choice(("not_json", "list", "version", "version_str", "format", "drop_key", "extra_key", "value_nan",
                      "value_str", "value_null", "kind"))
    verdict, what = GARBAGE, how
    if how == "not_json":
        text = json.dumps(meta)[:-7]
    elif how == "list":
        text = json.dumps(list(meta))
    else:
        if how == "version":
            meta["version"] = 999
        elif how == "version_str":
            meta["version"] = str(meta.get("version"))
        elif how == "format":
            meta["format"] = "something-else"
        elif how == "kind" and "kind" in meta:
            meta["kind"] = {"posselt": "nlpca", "nlpca": "classic", "classic": "posselt"}.get(meta["kind"], "rig")
        elif how == "kind":
            meta["format"] = "facesim-jaw-rig"
        elif how == "extra_key":
            meta["zz_extra"] = [1, 2, 3]
            verdict = EITHER
        else:
            keys = [k for k in meta if k not in ("format", "version")]
            key = rng.choice(keys)
            if how == "drop_key":
                del meta[key]
            else:
                meta[key] = {"value_nan": float("nan"), "value_str": "abc", "value_null": None}[how]
                if key == "build":
                    verdict = EITHER   # free-form build notes
            what = f"{how} meta.{key}"
        text = json.dumps(meta)
    a["meta"] = np.array(text)
    return Mutant(f"npz:meta:{how}", what, verdict, save_arrays(a))


NPZ_OPS = {"npz:value": npz_value, "npz:dtype": npz_dtype, "npz:shape": npz_shape, "npz:drop": npz_drop,
           "npz:extra": npz_extra, "npz:uncompressed": npz_uncompressed, "npz:npy": npz_npy, "npz:meta": npz_meta,
           **{k: FILE_OPS[k] for k in ("file:missing", "file:dir", "file:fifo", "file:loop", "file:empty",
                                        "file:text", "file:truncate", "file:flip")}}


# ------------------------------------------------------------------ model files (semantic changes)
def model_content(rng, base, spec):
    """Content a well-formed archive can hold that no face model may: the content checks' cases."""
    a = load_arrays(base)
    meta = _meta(a)
    n_nodes, n_tets = len(a["X"]), len(a["tets"])
    how = rng.choice(("negative_material", "zero_kappa", "negative_sigma", "zero_fibre", "long_fibre",
                      "fraction_above_1", "fraction_negative", "tet_index_oob", "tet_index_negative", "inverted_tet",
                      "degenerate_tet", "no_simulated", "no_cranium", "no_jaw_nodes", "marker_triangle_oob",
                      "marker_bary_zero", "marker_bary_outside", "dup_marker_name", "dup_muscle_name",
                      "marker_names_short", "jaw_zero_direction", "max_opening_negative", "track_length_zero",
                      "collider_faces_oob", "skin_oob", "tissue_oob", "muscle_index_oob", "collapsed_nodes",
                      "condyles_same", "huge_model", "bone_bad"))
    verdict = GARBAGE
    what = how
    if how in ("negative_material", "zero_kappa"):
        t = rng.randrange(len(meta["tissues"]))
        meta["tissues"][t]["c10" if how == "negative_material" else "kappa"] = -1e-3 if how == "negative_material" else 0.0
    elif how == "negative_sigma":
        a["muscle_sigma_max"] = -a["muscle_sigma_max"]
    elif how in ("zero_fibre", "long_fibre"):
        f = a["muscle_entry_fibre"].copy()
        f[rng.randrange(len(f))] = 0.0 if how == "zero_fibre" else 3.0
        a["muscle_entry_fibre"] = f
    elif how.startswith("fraction"):
        f = a["muscle_entry_fraction"].copy()
        f[rng.randrange(len(f))] = 1.5 if how == "fraction_above_1" else -0.1
        a["muscle_entry_fraction"] = f
    elif how.startswith("tet_index"):
        t = a["tets"].copy()
        t[rng.randrange(n_tets), rng.randrange(4)] = n_nodes if how == "tet_index_oob" else -1
        a["tets"] = t
    elif how == "inverted_tet":
        t = a["tets"].copy()
        k = rng.randrange(n_tets)
        t[k, [1, 2]] = t[k, [2, 1]]
        a["tets"] = t
    elif how == "degenerate_tet":
        t = a["tets"].copy()
        k = rng.randrange(n_tets)
        t[k, 3] = t[k, 0]
        a["tets"] = t
    elif how == "no_simulated":
        a["simulated"] = np.zeros_like(a["simulated"])
    elif how == "no_cranium":
        a["cranium_nodes"] = a["cranium_nodes"][:0]
    elif how == "no_jaw_nodes":
        a["jaw_nodes"] = a["jaw_nodes"][:0]
    elif how == "marker_triangle_oob":
        m = a["marker_triangle"].copy()
        m[rng.randrange(len(m))] = len(a["skin"])
        a["marker_triangle"] = m
    elif how.startswith("marker_bary"):
        b = a["marker_bary"].copy()
        b[rng.randrange(len(b))] = [0.0, 0.0, 0.0] if how == "marker_bary_zero" else [3.0, -1.0, -1.0]
        a["marker_bary"] = b
    elif how == "dup_marker_name":
        meta["marker_names"][1] = meta["marker_names"][0]
    elif how == "dup_muscle_name":
        meta["muscle_names"][-1] = meta["muscle_names"][0]
    elif how == "marker_names_short":
        meta["marker_names"] = meta["marker_names"][:-1]
    elif how == "jaw_zero_direction":
        a["jaw_track_direction"] = np.zeros(3)
    elif how == "max_opening_negative":
        meta["jaw_max_opening"] = -0.5
    elif how == "track_length_zero":
        meta["jaw_track_length"] = 0.0
        verdict = EITHER   # a jaw without condylar translation is a hinge
    elif how == "collider_faces_oob":
        f = a["collider0_faces"].copy()
        f[0, 0] = len(a["collider0_vertices"]) + 5
        a["collider0_faces"] = f
    elif how == "skin_oob":
        s = a["skin"].copy()
        s[rng.randrange(len(s)), 0] = n_nodes + 1
        a["skin"] = s
    elif how == "tissue_oob":
        t = a["tissue"].copy()
        t[rng.randrange(len(t))] = len(meta["tissues"])
        a["tissue"] = t
    elif how == "muscle_index_oob":
        m = a["muscle_entry_muscle"].copy()
        m[rng.randrange(len(m))] = len(meta["muscle_names"])
        a["muscle_entry_muscle"] = m
    elif how == "collapsed_nodes":
        a["X"] = np.zeros_like(a["X"])
    elif how == "condyles_same":
        a["jaw_condyle_left"] = a["jaw_condyle_right"].copy()
    elif how == "huge_model":
        a["X"] = a["X"] * 1e12
        what = "every node coordinate x 1e12 (mm)"
    else:
        a["bone0_vertices"] = np.full_like(a["bone0_vertices"], np.nan)
    a["meta"] = np.array(json.dumps(meta))
    return Mutant(f"model:{how}", what, verdict, save_arrays(a))


MODEL_OPS = {**NPZ_OPS, "model:content": model_content}


# ------------------------------------------------------------------ poses files
def poses_content(rng, base, spec):
    a = load_arrays(base)
    P = a["poses"].copy()
    k = rng.randrange(len(P))
    how = rng.choice(("scale", "reflect", "shear", "bottom_row", "bottom_w", "translation_huge", "translation_far",
                      "tiny_noise", "rotation_noise", "shape_3x4", "shape_single", "no_poses", "identity_all",
                      "ref_nan", "ref_shape", "mandible_two", "mandible_nan", "weights_negative", "weights_zero",
                      "weights_length", "weights_alone", "segment_oob", "segment_float", "segment_reversed",
                      "segment_half", "names_length", "names_int", "names_unknown", "sliders_shape",
                      "sliders_nan", "sliders_range"))
    verdict = GARBAGE
    if how == "scale":
        P[k, :3, :3] *= 1.1
    elif how == "reflect":
        P[k, :3, 0] *= -1
    elif how == "shear":
        P[k, 0, 1] += 0.2
    elif how == "bottom_row":
        P[k, 3] = [0.0, 0.0, 1.0, 1.0]
    elif how == "bottom_w":
        P[k, 3, 3] = 2.0
    elif how == "translation_huge":
        P[k, :3, 3] = 1e30
    elif how == "translation_far":
        P[k, :3, 3] += 1000.0
        verdict = EITHER
    elif how == "tiny_noise":
        P[k, :3, :3] += 1e-12
        verdict = EITHER
    elif how == "rotation_noise":
        P[k, :3, :3] += 1e-3
    elif how == "shape_3x4":
        P = P[:, :3]
    elif how == "shape_single":
        P = P[k]
    elif how == "no_poses":
        P = P[:0]
    elif how == "identity_all":
        P = np.repeat(np.eye(4)[None], len(P), axis=0)
        verdict = EITHER
    a["poses"] = P
    if how == "ref_nan":
        a["reference_point"] = np.array([np.nan, 0.0, 0.0])
    elif how == "ref_shape":
        a["reference_point"] = np.zeros(2)
    elif how.startswith("mandible") or how.startswith("weights"):
        m = np.array([[0.0, -40.0, 80.0], [10.0, -40.0, 70.0], [-10.0, -40.0, 70.0], [0.0, -30.0, 60.0]])
        w = np.ones(len(m))
        if how == "mandible_two":
            m = m[:2]
        elif how == "mandible_nan":
            m[0, 0] = np.nan
        elif how == "weights_negative":
            w[0] = -1.0
        elif how == "weights_zero":
            w[:] = 0.0
        elif how == "weights_length":
            w = w[:-1]
        if how != "weights_alone":
            a["mandible"] = m
        if how.startswith("weights"):
            a["weights"] = w
    elif how.startswith("segment"):
        n = len(a["poses"]) if a["poses"].ndim == 3 else 1
        names = np.array(["rest", "open"])
        bounds = np.array([[0, 1], [1, n]])
        if how == "segment_oob":
            bounds[1, 1] = n + 5
        elif how == "segment_float":
            bounds = bounds.astype(float)
        elif how == "segment_reversed":
            bounds[1] = bounds[1, ::-1]
        a["segment_names"] = names
        if how != "segment_half":
            a["segment_bounds"] = bounds
        else:
            a.pop("segment_bounds", None)
    elif how.startswith("names"):
        n = len(a["poses"])
        names = np.array(["rest", "open", "protrusion", "left", "right", "rest", "open"][:n])
        if how == "names_length":
            names = names[:-1]
        elif how == "names_int":
            names = np.arange(n)
        else:
            names = names.copy()
            names[-1] = "sideways"
            verdict = GARBAGE if spec.extremes else EITHER   # only retarget uses the names
        a["names"] = names
    elif how.startswith("sliders"):
        n = len(a["poses"])
        s = np.full((n, 3), 0.5)
        if how == "sliders_shape":
            s = s[:, :2]
        elif how == "sliders_nan":
            s[0, 0] = np.nan
        else:
            s[0, 0] = 7.0
            verdict = GARBAGE if spec.extremes else EITHER   # only retarget uses the values
        a["sliders"] = s
    return Mutant(f"poses:{how}", f"{how} (pose {k})", verdict, save_arrays(a))


POSES_OPS = {**NPZ_OPS, "poses:content": poses_content}
POSES_OPS.pop("npz:meta")


# ------------------------------------------------------------------ rig files
def rig_content(rng, base, spec):
    a = load_arrays(base)
    how = rng.choice(("axes_scale", "axes_reflect", "axes_zero", "origin_far", "bounds_swapped", "curves_collapsed",
                      "coefficients_zero"))
    verdict = GARBAGE
    if how.startswith("axes"):
        ax = a["frame_axes"].copy()
        if how == "axes_scale":
            ax *= 1.5
        elif how == "axes_reflect":
            ax[0] *= -1
        else:
            ax[:] = 0.0
        a["frame_axes"] = ax
    elif how == "origin_far":
        a["frame_origin"] = a["frame_origin"] + 1e4
        verdict = EITHER
    elif how == "bounds_swapped" and "bounds" in a:
        a["bounds"] = a["bounds"][:, ::-1].copy()
    elif how == "curves_collapsed" and "curves" in a:
        a["curves"] = np.zeros_like(a["curves"])
    elif how == "coefficients_zero" and "coefficients" in a:
        a["coefficients"] = np.zeros_like(a["coefficients"])
        verdict = EITHER
    else:
        return npz_value(rng, base, spec)
    return Mutant(f"rig:{how}", how, verdict, save_arrays(a))


RIG_OPS = {**NPZ_OPS, "rig:content": rig_content}


__all__ = ["C3D_OPS", "CSV_OPS", "EITHER", "GARBAGE", "MODEL_OPS", "NPZ_OPS", "POSES_OPS", "RIG_OPS", "TRC_OPS",
           "VALID", "Capture", "CsvSpec", "Mutant", "NpzSpec", "token_verdict", "write_c3d_bytes"]
