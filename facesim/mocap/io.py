"""Marker trajectory files: facesim's marker CSV and the TRC text format (OpenSim, Motion Analysis).

Positions are in mm in memory, ``P (F, N, 3) float64`` for F frames and N markers, NaN where a
marker is missing. Frame numbers are integers from 0 in facesim.

* CSV (DESIGN.md): header ``frame,<name>_x,<name>_y,<name>_z,...``, one row per frame, mm,
  ``NaN`` (or an empty field) for a missing marker.
* TRC: tab-separated, five header lines (``PathFileType``, the ``DataRate ... OrigNumFrames``
  keys and values, the marker names, ``X1 Y1 Z1 ...``), a blank line, then
  ``Frame#, Time, x, y, z, ...`` per frame with empty fields for missing markers. TRC numbers
  frames from 1: ``Frame# = frame + 1`` and ``Time = frame / rate`` (s).

Writers go through a temporary file renamed into place (never a truncated file); readers
raise one-line :class:`~facesim.errors.FacesimError` messages naming the file, line and column
(frame and marker for C3D). They refuse what would otherwise pass silently or crash later: no
frames or no markers, duplicate marker names, frame numbers that are not integers or do not
increase (TRC: from 1), non-finite coordinates (``inf``, ``1e400``), a marker with some but not
all of its three coordinates, rows or files cut short (a TRC with fewer rows than its
``NumFrames``, a C3D shorter than its header). A missing marker (NaN, or empty fields) is
accepted everywhere. The size of the capture is not checked by the readers: that is
:func:`check_capture_scale`, against the model's markers (a file in the wrong unit).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from facesim._csv import Table, cut_short, frame_numbers, numbers, parse_number, read_table, read_text
from facesim._files import atomic_write
from facesim.errors import FacesimError

#: Length units a TRC file may declare, in mm.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
#: Decimals written for positions in mm (1e-6 mm); a file in cm or m gets 1 or 3 more.
DECIMALS = 6
#: A capture's marker spread over the model's (or a face's) that :func:`check_capture_scale`
#: accepts: 1/3..3, the geometric middle between right and a factor 10 (mm read as cm).
SCALE_BAND = (1.0 / 3.0, 3.0)
#: The marker spread (RMS distance from the centroid, mm) of a typical face marker set, for a
#: capture checked without a model: face_coarse's 81 rest markers spread 62 mm.
TYPICAL_FACE_SPREAD_MM = 60.0
#: Positions further than this from the origin (mm; 1 km) are refused as absurd.
MAX_POSITION_MM = 1e6


@dataclass(frozen=True)
class MarkerData:
    """Marker trajectories read from a file.

    names : (N,) marker names; frames : (F,) int64 frame numbers; P : (F, N, 3) float64
    positions, mm, NaN = missing; rate : frames per second if the file says, else None;
    units : the unit the file's numbers were taken to be in (``"mm"``, ``"cm"``, ``"m"``: what
    the file declares, what was given, or mm for a CSV), already converted to mm in ``P``.
    """

    names: tuple[str, ...]
    frames: np.ndarray
    P: np.ndarray
    rate: float | None = None
    units: str | None = None

    def select(self, names) -> MarkerData:
        """The markers ``names`` (those the data has, in that order), e.g. the ones a model matches."""
        index = [self.names.index(n) for n in names if n in self.names]
        return replace(self, names=tuple(self.names[j] for j in index), P=self.P[:, index])


def _check(frames, names, P) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    names = tuple(str(n) for n in names)
    P = np.asarray(P, dtype=np.float64)
    frames = np.asarray(frames)
    if P.ndim != 3 or P.shape[1:] != (len(names), 3):
        raise FacesimError(f"markers: expected positions of shape (frames, {len(names)}, 3), got {P.shape}")
    if frames.shape != (len(P),) or (len(frames) and not np.all(frames == np.round(frames))):
        raise FacesimError(f"markers: expected {len(P)} integer frame numbers, got shape {frames.shape}")
    if len(set(names)) != len(names):
        raise FacesimError("markers: expected unique marker names")
    for n in names:
        if not n or n != n.strip() or any(c in n for c in ",\t\r\n\""):
            raise FacesimError(f"markers: name {n!r} cannot be written (empty, or with a comma, tab, quote "
                               "or surrounding space)")
    if np.isinf(P).any():
        raise FacesimError("markers: positions must be finite or NaN (missing)")
    return frames.astype(np.int64), names, P


def _fmt(v: float, missing: str, decimals: int = DECIMALS) -> str:
    return missing if math.isnan(v) else f"{v:.{decimals}f}"


# ------------------------------------------------------------------- CSV
def marker_csv_header(names) -> str:
    """Header line (with newline) of a marker CSV for ``names``."""
    for n in names:
        if _COORDINATE_END.search(n):
            raise FacesimError(f"markers: name {n!r} cannot be written to a marker CSV (it ends like a coordinate "
                               "column, _x, _y or _z)")
    return ",".join(["frame"] + [f"{n}_{c}" for n in names for c in "xyz"]) + "\n"


def _units(units: str) -> float:
    if units not in UNITS_MM:
        raise FacesimError(f"units: expected one of {', '.join(UNITS_MM)}, got {units!r}")
    return UNITS_MM[units]


def marker_csv_line(frame: int, p, units: str = "mm") -> str:
    """One marker CSV row (with newline): ``frame`` and ``p (N, 3)`` mm, written in ``units``
    (``"mm"``, ``"cm"`` or ``"m"``; 1e-6 mm resolution in each), NaN written as ``NaN``."""
    scale = _units(units)
    decimals = DECIMALS + round(math.log10(scale))
    values = np.asarray(p, dtype=np.float64).ravel() / scale
    return ",".join([str(int(frame))] + [_fmt(v, "NaN", decimals) for v in values]) + "\n"


def write_markers_csv(path, frames, names, P, units: str = "mm") -> Path:
    """Write marker trajectories ``P (F, N, 3)`` mm of ``frames (F,)`` to a CSV file, its numbers
    in ``units`` (default mm: a CSV says no unit, so a reader must be told another); return its path."""
    frames, names, P = _check(frames, names, P)
    text = marker_csv_header(names) + "".join(marker_csv_line(k, p, units) for k, p in zip(frames, P))
    return atomic_write(path, lambda tmp: tmp.write_text(text))


def read_markers_csv(path, units: str = "mm") -> MarkerData:
    """Read a marker CSV (``frame,<name>_x,<name>_y,<name>_z,...``, NaN or empty = missing), its
    numbers in ``units`` (default mm), into mm.

    Marker names must not themselves end in ``_x``, ``_y`` or ``_z`` (``lip_x_x`` is refused:
    most likely a mangled header). Frame numbers are integers >= 0, increasing.
    """
    scale = _units(units)
    example = "frame,chin_x,chin_y,chin_z,..."
    table = read_table(path, "marker file", example=example)
    names = _csv_marker_names(table)
    columns = table.header[1:]
    P = numbers(table, columns, allow_missing=True).reshape(len(table.rows), len(names), 3)
    _check_whole_markers(table, P, columns)
    return MarkerData(names, frame_numbers(table), P * scale if scale != 1.0 else P, units=units)


_COORDINATE_END = re.compile(r"_[xyz]$")
_TRIPLES = "three columns <name>_x,<name>_y,<name>_z per marker, in order"


def _csv_marker_names(table: Table) -> tuple[str, ...]:
    """The marker names of a marker CSV header, or a one-line error naming the first bad column."""
    columns = table.header[1:]
    at = f"{table.path}: line {table.header_line}"
    if not columns:
        raise FacesimError(f"{at}: no marker columns after 'frame'; expected {_TRIPLES}")
    names = []
    for j, c in enumerate(columns):
        axis = "xyz"[j % 3]
        if axis == "x":
            name = c[:-2] if c.endswith("_x") else ""
            trio = ",".join(columns[j:j + 3])
            if not name:
                raise FacesimError(f"{at}, column {c!r}: expected <name>_x to start a marker ({_TRIPLES}; got {trio})")
            if _COORDINATE_END.search(name):
                raise FacesimError(f"{at}, column {c!r}: marker name {name!r} ends like a coordinate; expected "
                                   f"{_TRIPLES}, with names not ending in _x, _y or _z")
            names.append(name)
        elif c != f"{names[-1]}_{axis}":
            raise FacesimError(f"{at}, column {c!r}: expected {names[-1] + '_' + axis!r} ({_TRIPLES}; got {trio})")
    if len(columns) % 3:
        axis = "xyz"[len(columns) % 3]
        raise FacesimError(f"{at}: expected {names[-1] + '_' + axis!r} after column {columns[-1]!r}, the last one "
                           f"({_TRIPLES}; got {trio})")
    _check_unique(names, at)
    return tuple(names)


def _check_unique(names, at: str) -> None:
    seen = {}
    for j, n in enumerate(names):
        if n in seen:
            raise FacesimError(f"{at}: marker {n!r} appears twice (markers {seen[n] + 1} and {j + 1}); expected "
                               "unique marker names")
        seen[n] = j


def _check_whole_markers(table: Table, P: np.ndarray, columns) -> None:
    """One-line error at the first marker with some but not all of its coordinates missing."""
    gap = np.isnan(P)
    partial = np.argwhere(gap.any(axis=2) & ~gap.all(axis=2))
    if len(partial):
        i, j = partial[0]
        k = int(np.flatnonzero(gap[i, j])[0])
        given = ",".join(columns[3 * j + a] for a in range(3) if not gap[i, j, a])
        raise FacesimError(f"{table.where(i, columns[3 * j + k])}: missing, but {given} of the same marker is given; "
                           "expected all three coordinates of a marker, or none (missing)")


# ------------------------------------------------------------------- TRC
def write_trc(path, frames, names, P, fps: float, units: str = "mm") -> Path:
    """Write marker trajectories ``P (F, N, 3)`` mm of ``frames (F,)`` as a TRC file; return its path.

    ``fps`` : frame rate (Hz), written as DataRate, CameraRate and OrigDataRate, and giving
    ``Time = frame / fps``. ``units`` : ``"mm"``, ``"cm"`` or ``"m"``, the file's unit
    (positions are converted from mm). Missing markers (NaN) are written as empty fields.
    """
    frames, names, P = _check(frames, names, P)
    path = Path(path)
    if not (math.isfinite(fps) and fps > 0):
        raise FacesimError(f"fps: expected a frame rate > 0, got {fps}")
    if units not in UNITS_MM:
        raise FacesimError(f"units: expected one of {', '.join(UNITS_MM)}, got {units!r}")
    Q = P / UNITS_MM[units]
    decimals = DECIMALS + round(math.log10(UNITS_MM[units]))
    start = int(frames[0]) + 1 if len(frames) else 1
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{fps:g}\t{fps:g}\t{len(frames)}\t{len(names)}\t{units}\t{fps:g}\t{start}\t{len(frames)}",
        "\t".join(["Frame#", "Time"] + [f"{n}\t\t" for n in names]).rstrip("\t"),
        "\t".join(["", ""] + [f"{c}{i + 1}" for i in range(len(names)) for c in "XYZ"]),
        "",
    ]
    for k, q in zip(frames, Q):
        values = [_fmt(v, "", decimals) for v in q.ravel()]
        lines.append("\t".join([str(int(k) + 1), f"{k / fps:.{DECIMALS}f}", *values]))
    text = "\n".join(lines) + "\n"
    return atomic_write(path, lambda tmp: tmp.write_text(text))


def read_trc(path) -> MarkerData:
    """Read a TRC file: names, frames (``Frame# - 1``), positions converted to mm, DataRate.

    A row may leave out the fields of whole markers at its end (missing); any other short row
    is an error, as is a file with fewer or more rows than its ``NumFrames`` or with data after
    a blank line.
    """
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such TRC file" if not path.exists() else f"{path}: expected a TRC file")
    text = read_text(path, "a TRC text file")
    raw = text.splitlines()
    if not raw or not raw[0].startswith("PathFileType"):
        raise FacesimError(f"{path}: line 1: not a TRC file (expected 'PathFileType' first)")
    if len(raw) < 5:
        raise FacesimError(f"{path}: expected 5 header lines, the file has {len(raw)} lines")
    keys = [k.strip() for k in raw[1].split("\t") if k.strip()]
    values = [v.strip() for v in raw[2].split("\t") if v.strip()]
    if len(keys) != len(values):
        raise FacesimError(f"{path}: line 3: expected {len(keys)} values for the keys of line 2, got {len(values)}")
    meta = dict(zip(keys, values))
    for key in ("DataRate", "NumMarkers", "Units"):
        if key not in meta:
            raise FacesimError(f"{path}: line 2: no {key!r} key in the header")
    units = meta["Units"].lower()
    if units not in UNITS_MM:
        raise FacesimError(f"{path}: line 3: Units {meta['Units']!r}, expected one of {', '.join(UNITS_MM)}")
    n_markers = _header_count(path, meta, "NumMarkers", 1)
    n_frames = _header_count(path, meta, "NumFrames", 0) if "NumFrames" in meta else None
    rate = parse_number(meta["DataRate"])
    if rate is None or not (math.isfinite(rate) and rate > 0):
        raise FacesimError(f"{path}: line 3: DataRate {meta['DataRate']!r}; expected a frame rate > 0 (Hz)")
    labels = [s.strip() for s in raw[3].split("\t") if s.strip()]
    if labels[:2] != ["Frame#", "Time"] or len(labels) != n_markers + 2:
        raise FacesimError(f"{path}: line 4: expected 'Frame#', 'Time' and {n_markers} marker names, got "
                           f"{len(labels)} labels")
    names = tuple(labels[2:])
    _check_unique(names, f"{path}: line 4")
    axes = [s.strip() for s in raw[4].split("\t") if s.strip()]
    if len(axes) != 3 * n_markers or any(not a.upper().startswith(c) for a, c in zip(axes, "XYZ" * n_markers)):
        raise FacesimError(f"{path}: line 5: expected the coordinate labels 'X1 Y1 Z1 ...' of {n_markers} markers, "
                           f"got {len(axes)} labels ({' '.join(axes[:3]) or 'an empty line'}...)")
    width = 2 + 3 * n_markers
    rows, lines, blank = [], [], None
    for i, line in enumerate(raw[5:], start=6):
        if not line.strip():
            if rows and blank is None:
                blank = i   # a blank line after the data ends it (as OpenSim reads TRC)
            continue
        if blank is not None:
            raise FacesimError(f"{path}: line {i}: data after the blank line {blank}; expected the rows of all "
                               "frames together, then the end of the file")
        fields = [f.strip() for f in line.split("\t")]
        while len(fields) > width and fields[-1] == "":
            fields.pop()   # trailing tabs
        if len(fields) < width:
            short = cut_short(text, i)
            if short or len(fields) < 2 or (len(fields) - 2) % 3:
                raise FacesimError(f"{path}: line {i}: expected {width} fields (Frame#, Time, X Y Z of {n_markers} "
                                   f"markers), got {len(fields)}{short}")
            fields += [""] * (width - len(fields))   # writers may drop the fields of missing markers at the end
        if len(fields) != width:
            raise FacesimError(f"{path}: line {i}: expected {width} fields (Frame#, Time, X Y Z of {n_markers} "
                               f"markers), got {len(fields)}")
        rows.append(fields)
        lines.append(i)
    if not rows:
        raise FacesimError(f"{path}: no data rows after the header")
    if n_frames is not None and n_frames != len(rows):
        why = " (cut short?)" if len(rows) < n_frames else ""
        raise FacesimError(f"{path}: line 3: NumFrames {n_frames}, but the file has {len(rows)} data rows{why}; "
                           "expected one row per frame")
    columns = ["Frame#", "Time"] + [f"{c}{j + 1}" for j in range(n_markers) for c in "XYZ"]
    table = Table(path, tuple(columns), tuple(map(tuple, rows)), tuple(lines))
    frames = frame_numbers(table, "Frame#", start=1, note="; TRC numbers frames from 1")
    numbers(table, ["Time"])
    P = numbers(table, columns[2:], allow_missing=True).reshape(len(rows), n_markers, 3)
    _check_whole_markers(table, P, columns[2:])
    return MarkerData(names, frames - 1, P * UNITS_MM[units], rate, units)


def _header_count(path: Path, meta: dict, key: str, least: int) -> int:
    """The integer ``meta[key]`` of a TRC header (line 3), at least ``least``."""
    text = meta[key]
    if not re.fullmatch(r"[0-9]{1,12}", text) or int(text) < least:
        raise FacesimError(f"{path}: line 3: {key} {text!r}; expected an integer >= {least}")
    return int(text)


# ------------------------------------------------------------------ C3D (through ezc3d)
def write_c3d(path, frames, names, P, fps: float, units: str = "mm") -> Path:
    """Write a C3D file (ezc3d): POINT labels ``names``, positions ``P (F, N, 3)`` mm written in
    ``units``, NaN = missing (residual -1), rate ``fps``, first frame ``frames[0]``."""
    import ezc3d

    frames, names, P = _check(frames, names, P)
    if units not in UNITS_MM:
        raise FacesimError(f"units: expected one of {', '.join(UNITS_MM)}, got {units!r}")
    if len(frames) and np.any(np.diff(frames) != 1):
        raise FacesimError("C3D: expected consecutive frame numbers")
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [float(fps)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    pts = np.ones((4, len(names), len(P)))
    pts[:3] = np.transpose(P, (2, 1, 0)) / UNITS_MM[units]
    c["data"]["points"] = pts
    if len(frames):
        c["header"]["points"]["first_frame"] = int(frames[0])
    return atomic_write(path, lambda tmp: c.write(str(tmp)))


def read_c3d(path) -> MarkerData:
    """Read the POINT data of a C3D file (ezc3d): labels, positions converted to mm from
    ``POINT:UNITS`` (mm when absent), frames from the header's first frame, ``POINT:RATE``.
    Points with a negative residual, all-zero or any NaN coordinates are missing (NaN).

    Errors: no frames or no points, labels that are empty, repeated or not one per point, an
    infinite coordinate of a point that is not missing, a rate that is not > 0, a file shorter
    than its header says (cut short: ezc3d itself reads what is there).
    """
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such C3D file" if not path.exists() else f"{path}: expected a C3D file")
    layout = _c3d_layout(path)   # ezc3d hangs or crashes on a file cut inside its sections
    if isinstance(layout, str):
        raise FacesimError(f"{path}: not a readable C3D file ({layout})")
    try:
        c = ezc3d.c3d(str(path), extract_forceplat_data=False)
    except Exception as exc:   # ezc3d raises plain RuntimeErrors for malformed files
        raise FacesimError(f"{path}: not a readable C3D file ({' '.join(str(exc).split())})") from None
    point = c["parameters"]["POINT"]
    pts = np.asarray(c["data"]["points"], dtype=np.float64)       # (4, N, F)
    labels = list(point["LABELS"]["value"]) if "LABELS" in point else []
    k = 2
    while f"LABELS{k}" in point:   # more than 255 points: LABELS2, LABELS3, ...
        labels += list(point[f"LABELS{k}"]["value"])
        k += 1
    names = tuple(str(n).strip() for n in labels)
    if pts.ndim != 3 or pts.shape[1] == 0:
        raise FacesimError(f"{path}: no POINT data (no markers)")
    if len(names) != pts.shape[1]:
        raise FacesimError(f"{path}: parameter POINT:LABELS has {len(names)} labels for {pts.shape[1]} points; "
                           "expected one label per point")
    if "" in names:
        raise FacesimError(f"{path}: parameter POINT:LABELS: point {names.index('') + 1} has an empty label; expected "
                           "a marker name for every point")
    _check_unique(names, f"{path}: parameter POINT:LABELS")
    if pts.shape[2] == 0:
        raise FacesimError(f"{path}: no frames (POINT data of {len(names)} markers, 0 frames)")
    short = _c3d_cut_short(layout, pts.shape[2])
    if short:
        raise FacesimError(f"{path}: {short} (cut short?)")
    units = str((point.get("UNITS", {}).get("value") or ["mm"])[0]).strip().lower() or "mm"
    if units not in UNITS_MM:
        raise FacesimError(f"{path}: parameter POINT:UNITS {units!r}, expected one of {', '.join(UNITS_MM)}")
    P = np.transpose(pts[:3], (2, 1, 0)) * UNITS_MM[units]
    missing = np.all(P == 0.0, axis=2) | np.isnan(P).any(axis=2)
    residuals = c["data"]["meta_points"]["residuals"] if "meta_points" in c["data"] else None
    if residuals is not None and np.size(residuals):
        missing |= np.transpose(np.asarray(residuals)[0]) < 0
    P[missing] = np.nan
    first = int(c["header"]["points"]["first_frame"])
    frames = first + np.arange(P.shape[0], dtype=np.int64)
    bad = np.argwhere(np.isinf(P).any(axis=2))
    if len(bad):
        f, j = bad[0]
        raise FacesimError(f"{path}: frame {frames[f]}, marker {names[j]!r}: coordinates "
                           f"{', '.join(f'{v:g}' for v in P[f, j] / UNITS_MM[units])}; expected finite coordinates "
                           "(or a negative residual for a missing marker)")
    value = np.ravel(point["RATE"]["value"]) if "RATE" in point else ()
    rate = float(value[0]) if np.size(value) else None
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise FacesimError(f"{path}: parameter POINT:RATE {rate:g}; expected a frame rate > 0 (Hz)")
    return MarkerData(names, frames, P, rate, units)


class _C3dLayout(NamedTuple):
    """The layout of a C3D file read from its 512-byte header and its parameter section's first
    bytes: the header, the processor type (1 Intel, 2 DEC: little-endian; 3 MIPS: big-endian), the
    file size in bytes and the first data block."""

    head: bytes
    processor: int
    size: int
    start: int

    @property
    def order(self) -> str:
        return ">" if self.processor == 3 else "<"


def _c3d_layout(path: Path) -> _C3dLayout | str:
    """The layout of the C3D file at ``path``, or what is wrong with it, before ezc3d reads it (ezc3d
    hangs or crashes the process on a file cut inside its parameter section): the 512-byte header
    with the key byte 0x50, the parameter section's first block (header byte 1) and its length in
    blocks (byte 3 of the section), and the first data block (header word 9) all within the file.
    C3D user guide, ch. 3."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(512)
            if len(head) < 512:
                return f"{size} bytes: shorter than the 512-byte C3D header"
            if head[1] != 0x50:
                return f"byte 2 is {head[1]:#04x}, not the C3D key 0x50"
            first_param = head[0]
            if first_param < 2 or (first_param - 1) * 512 + 4 > size:
                return f"the parameter section starts at block {first_param}, beyond the file's {size} bytes"
            f.seek((first_param - 1) * 512)
            section = f.read(4)
    except OSError as exc:
        return f"cannot read ({exc.strerror or exc})"
    blocks, processor = section[2], section[3] - 83
    if processor not in (1, 2, 3):
        return f"processor type {section[3]} in the parameter section, expected 84, 85 or 86"
    end = (first_param - 1 + blocks) * 512
    if blocks < 1 or end > size:
        return f"the parameter section of {blocks} blocks ends at byte {end}, beyond the file's {size} bytes (cut short?)"
    (start,) = struct.unpack((">" if processor == 3 else "<") + "H", head[16:18])
    if start < 1 or (start - 1) * 512 > size:
        return f"the data start at block {start}, beyond the file's {size} bytes (cut short?)"
    return _C3dLayout(head, processor, size, start)


def _c3d_cut_short(layout: _C3dLayout, n_frames: int) -> str | None:
    """What is missing if the C3D file of ``layout`` holds less than its header announces (ezc3d
    reads the frames that are there and says nothing), else None. Header words 2-5 hold the
    points, analog samples per frame, first and last frame; the scale's sign (negative: float
    data) says the bytes per value (C3D user guide, ch. 3)."""
    head = layout.head
    n_points, n_analog, first, last = struct.unpack(layout.order + "4H", head[2:10])
    sign_byte = {1: 15, 2: 13, 3: 12}[layout.processor]   # of the scale factor; DEC floats are word-swapped
    value_bytes = 4 if head[sign_byte] & 0x80 else 2
    announced = last - first + 1 if first >= 1 and first <= last < 65535 else None   # 65535: more frames than words
    if announced is not None and announced > n_frames:
        return f"the header announces {announced} frames, the file holds {n_frames}"
    need = (layout.start - 1) * 512 + n_frames * (4 * n_points + n_analog) * value_bytes
    if layout.size < need:
        return f"{layout.size} bytes, but {n_frames} frames of {n_points} points need {need}"
    return None


def read_markers(path, units: str | None = None) -> MarkerData:
    """Read a marker file by its extension: ``.c3d``, ``.trc`` or ``.csv``. ``units`` (``mm``,
    ``cm``, ``m``) overrides what the file says; CSV files carry no unit and are taken as mm
    unless the capture is implausibly small for a face in mm (bounding box < 1 unit, i.e. it is in
    metres), which is converted and reported through ``MarkerData`` as mm (``units="m"``).
    Whether the size then fits a face is :func:`check_capture_scale`'s job."""
    path = Path(path)
    suffix = path.suffix.lower()
    if units is not None and units not in UNITS_MM:
        raise FacesimError(f"units: expected one of {', '.join(UNITS_MM)}, got {units!r}")
    if suffix == ".c3d":
        data = read_c3d(path)
    elif suffix == ".trc":
        data = read_trc(path)
    elif suffix == ".csv":
        data = read_markers_csv(path)
    else:
        raise FacesimError(f"{path}: unknown marker file type {suffix!r}; expected .c3d, .trc or .csv")
    if units is not None:   # the reader scaled by the file's unit: undo it and apply the given one
        return replace(data, P=data.P * (UNITS_MM[units] / UNITS_MM[data.units or "mm"]), units=units)
    if suffix == ".csv" and np.isfinite(data.P).any():
        extent = np.nanmax(data.P, axis=(0, 1)) - np.nanmin(data.P, axis=(0, 1))
        if 0 < float(np.max(extent)) < 1.0:
            return replace(data, P=data.P * 1000.0, units="m")
    return data


# ------------------------------------------------------------------ the size of a capture
def marker_spread(P) -> tuple[float, int]:
    """How big a set of markers is: the RMS distance of a frame's finite markers from their centroid
    (mm), median over the frames with at least 3 finite markers; and how many frames those are.

    P : (F, N, 3) or (N, 3) float64, mm, NaN = missing. Returns ``(nan, 0)`` without such a frame,
    ``(inf, F)`` when the positions are too large to square. Robust to a few bad frames and to
    missing markers; independent of where the capture's origin is.
    """
    P = np.asarray(P, dtype=np.float64)
    P = P[None] if P.ndim == 2 else P
    ok = np.isfinite(P).all(axis=2)                        # (F, N)
    n = ok.sum(axis=1)
    use = n >= 3
    if not use.any():
        return math.nan, 0
    Q, ok, n = np.where(ok[..., None], P, 0.0)[use], ok[use], n[use]
    with np.errstate(over="ignore", invalid="ignore"):
        centre = Q.sum(axis=1) / n[:, None]
        d2 = (((Q - centre[:, None]) ** 2).sum(axis=2) * ok).sum(axis=1) / n
        spread = float(np.median(np.sqrt(d2)))
    return (spread if math.isfinite(spread) else math.inf), int(use.sum())


def check_capture_scale(data: MarkerData, model_spread_mm: float | None, path,
                        units_given: str | None = None) -> None:
    """Refuse a capture whose size does not fit the model's: most likely a file in another unit.

    data : the capture as read (mm); model_spread_mm : the model's :func:`marker_spread`, e.g.
    ``marker_spread(model.marker_positions())[0]``, or None to compare with a typical face
    (:data:`TYPICAL_FACE_SPREAD_MM`); path : the file, for messages; units_given : the unit the
    user gave (``--units``), if any. Passes when the capture's :func:`marker_spread` is within
    :data:`SCALE_BAND` of the model's and no position is further than :data:`MAX_POSITION_MM`
    from the origin. Otherwise a one-line :class:`FacesimError` suggests the unit among mm, cm
    and m that brings the spread closest to the model's (if that one fits), or says the markers
    do not fit the model's size in any unit; also for a capture without a frame of 3 finite markers.
    """
    given = model_spread_mm is not None and math.isfinite(model_spread_mm) and model_spread_mm > 0
    reference = float(model_spread_mm) if given else TYPICAL_FACE_SPREAD_MM   # a model of < 3 markers: a face's
    whose = "the model's" if given else "a typical face's"
    unit = units_given or data.units or "mm"
    spread, n = marker_spread(data.P)
    if n == 0:
        raise FacesimError(f"{path}: no frame has 3 markers with finite positions; expected at least one, to "
                           "measure the capture's size")
    lo, hi = SCALE_BAND
    ratio = spread / reference
    far = np.argwhere(np.nan_to_num(np.abs(data.P), nan=0.0).max(axis=2) > MAX_POSITION_MM)
    if lo <= ratio <= hi and not len(far):
        return
    read_as = f"read as {unit}" + (", --units" if units_given else "")
    if len(far):
        f, j = far[0]
        far_away = (f"frame {data.frames[f]}, marker {data.names[j]!r} has a coordinate of "
                    f"{np.nanmax(np.abs(data.P[f, j])):.3g} mm; expected positions within {MAX_POSITION_MM:.0e} mm "
                    "of the origin")
    if lo <= ratio <= hi:
        raise FacesimError(f"{path}: {far_away} ({read_as})")
    said = (f"{path}: markers spread {_mm(spread)} mm (RMS distance from their centroid, median over {n} frames, "
            f"{read_as}), {ratio:.3g}x {whose} {_mm(reference)} mm; expected 1/{1 / lo:.0f}..{hi:g}x")
    fits = {u: ratio * UNITS_MM[u] / UNITS_MM[unit] for u in UNITS_MM}
    best = min(fits, key=lambda u: abs(math.log(fits[u])) if 0 < fits[u] < math.inf else math.inf)
    if lo <= fits[best] <= hi:
        raise FacesimError(f"{said}: the file looks to be in {best}: try --units {best}")
    raise FacesimError(f"{said}: the markers do not match {whose} size in mm, cm or m"
                       + (f"; {far_away}" if len(far) else ""))


def _mm(v: float) -> str:
    """A length for messages: ``1,580``, ``6.29``, ``0.0629``, ``6.29e+31``."""
    return f"{v:,.0f}" if 100 <= v < 1e9 else f"{v:.3g}"


def frame_mask(spec, frames: np.ndarray, option: str = "--frames") -> np.ndarray:
    """Mask of ``frames`` within ``spec`` ``"FIRST:LAST"`` (inclusive; either end may be empty, a
    single number is that frame; empty ``spec``: all). ``option`` names the setting in errors."""
    frames = np.asarray(frames)
    if not spec:
        return np.ones(len(frames), dtype=bool)
    lo, sep, hi = str(spec).partition(":")
    try:
        first = int(lo) if lo.strip() else int(frames.min())
        last = int(hi) if hi.strip() else int(frames.max())
    except ValueError:
        raise FacesimError(f"{option}: expected FIRST:LAST frame numbers, e.g. 0:9, got {spec!r}") from None
    if not sep:
        last = first
    keep = (frames >= first) & (frames <= last)
    if not keep.any():
        raise FacesimError(f"{option} {spec}: no frames in that range (the capture has frames "
                           f"{int(frames.min())}..{int(frames.max())})")
    return keep
