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
raise one-line :class:`~facesim.errors.FacesimError` messages naming the file, line and column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._csv import Table, frame_numbers, number, numbers, read_table
from facesim._files import atomic_write
from facesim.errors import FacesimError

#: Length units a TRC file may declare, in mm.
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
#: Decimals written for positions in mm (1e-6 mm); a file in cm or m gets 1 or 3 more.
DECIMALS = 6


@dataclass(frozen=True)
class MarkerData:
    """Marker trajectories read from a file.

    names : (N,) marker names; frames : (F,) int64 frame numbers; P : (F, N, 3) float64
    positions, mm, NaN = missing; rate : frames per second if the file says, else None.
    """

    names: tuple[str, ...]
    frames: np.ndarray
    P: np.ndarray
    rate: float | None = None


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
    return ",".join(["frame"] + [f"{n}_{c}" for n in names for c in "xyz"]) + "\n"


def marker_csv_line(frame: int, p) -> str:
    """One marker CSV row (with newline): ``frame`` and ``p (N, 3)`` mm, NaN written as ``NaN``."""
    return ",".join([str(int(frame))] + [_fmt(v, "NaN") for v in np.asarray(p, dtype=np.float64).ravel()]) + "\n"


def write_markers_csv(path, frames, names, P) -> Path:
    """Write marker trajectories ``P (F, N, 3)`` mm of ``frames (F,)`` to a CSV file; return its path."""
    frames, names, P = _check(frames, names, P)
    text = marker_csv_header(names) + "".join(marker_csv_line(k, p) for k, p in zip(frames, P))
    return atomic_write(path, lambda tmp: tmp.write_text(text))


def read_markers_csv(path) -> MarkerData:
    """Read a marker CSV (``frame,<name>_x,<name>_y,<name>_z,...``, mm, NaN or empty = missing)."""
    example = "frame,chin_x,chin_y,chin_z,..."
    table = read_table(path, "marker file", example=example)
    columns = table.header[1:]
    at = f"{table.path}: line {table.header_line}"
    if len(columns) % 3:
        raise FacesimError(f"{at}: expected three columns <name>_x,<name>_y,<name>_z per marker, "
                           f"got {len(columns)} columns after 'frame'")
    names = []
    for j in range(0, len(columns), 3):
        trio = columns[j:j + 3]
        name = trio[0][:-2]
        if not name or [c[-2:] for c in trio] != ["_x", "_y", "_z"] or any(c[:-2] != name for c in trio):
            raise FacesimError(f"{at}: expected columns <name>_x,<name>_y,<name>_z, got "
                               f"{','.join(trio)}")
        names.append(name)
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise FacesimError(f"{at}: marker {dup!r} appears twice")
    P = numbers(table, columns, allow_missing=True).reshape(len(table.rows), len(names), 3)
    return MarkerData(tuple(names), frame_numbers(table), P)


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
    """Read a TRC file: names, frames (``Frame# - 1``), positions converted to mm, DataRate."""
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such TRC file" if not path.exists() else f"{path}: expected a TRC file")
    try:
        raw = path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError:
        raise FacesimError(f"{path}: not a TRC text file (not UTF-8)") from None
    if not raw or not raw[0].startswith("PathFileType"):
        raise FacesimError(f"{path}: line 1: not a TRC file (expected 'PathFileType' first)")
    if len(raw) < 5:
        raise FacesimError(f"{path}: expected 5 header lines, the file has {len(raw)} lines")
    keys = [k for k in raw[1].strip().split("\t") if k.strip()]
    values = [v.strip() for v in raw[2].strip().split("\t") if v.strip()]
    if len(keys) != len(values):
        raise FacesimError(f"{path}: line 3: expected {len(keys)} values for the keys of line 2, got {len(values)}")
    meta = dict(zip((k.strip() for k in keys), values))
    for key in ("DataRate", "NumMarkers", "Units"):
        if key not in meta:
            raise FacesimError(f"{path}: line 2: no {key!r} key in the header")
    units = meta["Units"].lower()
    if units not in UNITS_MM:
        raise FacesimError(f"{path}: line 3: Units {meta['Units']!r}, expected one of {', '.join(UNITS_MM)}")
    try:
        n_markers = int(meta["NumMarkers"])
        rate = float(meta["DataRate"])
    except ValueError:
        raise FacesimError(f"{path}: line 3: expected a number for NumMarkers and DataRate") from None
    labels = [s.strip() for s in raw[3].split("\t") if s.strip()]
    if labels[:2] != ["Frame#", "Time"] or len(labels) != n_markers + 2:
        raise FacesimError(f"{path}: line 4: expected 'Frame#', 'Time' and {n_markers} marker names, got "
                           f"{len(labels)} labels")
    names = tuple(labels[2:])
    width = 2 + 3 * n_markers
    rows, lines = [], []
    for i, line in enumerate(raw[5:], start=6):
        if not line.strip():
            if rows:
                break   # a blank line after the data ends it (as OpenSim reads TRC)
            continue
        fields = [f.strip() for f in line.rstrip("\r\n").split("\t")]
        while len(fields) > width and fields[-1] == "":
            fields.pop()   # trailing tabs
        fields += [""] * (width - len(fields))   # writers may drop trailing missing markers
        if len(fields) != width:
            raise FacesimError(f"{path}: line {i}: expected {width} fields, got {len(fields)}")
        rows.append(fields)
        lines.append(i)
    if not rows:
        raise FacesimError(f"{path}: no data rows after the header")
    columns = ["Frame#", "Time"] + [f"{c}{j + 1}" for j in range(n_markers) for c in "XYZ"]
    table = Table(path, tuple(columns), tuple(map(tuple, rows)), tuple(lines))
    frames = np.array([number(table, i, "Frame#", r[0]) for i, r in enumerate(table.rows)])
    if not np.all(frames == np.round(frames)):
        raise FacesimError(f"{path}: column 'Frame#': expected integer frame numbers")
    P = numbers(table, columns[2:], allow_missing=True).reshape(len(rows), n_markers, 3) * UNITS_MM[units]
    return MarkerData(names, frames.astype(np.int64) - 1, P, rate)


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
    Points with a negative residual or all-zero coordinates are missing (NaN)."""
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such C3D file" if not path.exists() else f"{path}: expected a C3D file")
    try:
        c = ezc3d.c3d(str(path), extract_forceplat_data=False)
    except Exception as exc:   # ezc3d raises plain RuntimeErrors for malformed files
        raise FacesimError(f"{path}: not a readable C3D file ({' '.join(str(exc).split())})") from None
    point = c["parameters"]["POINT"]
    names = tuple(str(n).strip() for n in point["LABELS"]["value"])
    units = str((point.get("UNITS", {}).get("value") or ["mm"])[0]).strip().lower() or "mm"
    if units not in UNITS_MM:
        raise FacesimError(f"{path}: parameter POINT:UNITS {units!r}, expected one of {', '.join(UNITS_MM)}")
    pts = np.asarray(c["data"]["points"], dtype=np.float64)       # (4, N, F)
    P = np.transpose(pts[:3], (2, 1, 0)) * UNITS_MM[units]
    missing = np.all(P == 0.0, axis=2)
    residuals = c["data"]["meta_points"]["residuals"] if "meta_points" in c["data"] else None
    if residuals is not None and np.size(residuals):
        missing |= np.transpose(np.asarray(residuals)[0]) < 0
    P[missing] = np.nan
    first = int(c["header"]["points"]["first_frame"])
    rate = float(np.ravel(point["RATE"]["value"])[0]) if np.size(point["RATE"]["value"]) else None
    return MarkerData(names, first + np.arange(P.shape[0], dtype=np.int64), P, rate)


def read_markers(path, units: str | None = None) -> MarkerData:
    """Read a marker file by its extension: ``.c3d``, ``.trc`` or ``.csv``. ``units`` (``mm``,
    ``cm``, ``m``) overrides what the file says; CSV files carry no unit and are taken as mm
    unless the capture is implausibly small for a face in mm (bounding box < 1 unit, i.e. it is in
    metres), which is converted and reported through ``MarkerData`` as mm."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".c3d":
        data = read_c3d(path)
    elif suffix == ".trc":
        data = read_trc(path)
    elif suffix == ".csv":
        data = read_markers_csv(path)
    else:
        raise FacesimError(f"{path}: unknown marker file type {suffix!r}; expected .c3d, .trc or .csv")
    if units is not None:
        if units not in UNITS_MM:
            raise FacesimError(f"units: expected one of {', '.join(UNITS_MM)}, got {units!r}")
        declared = 1.0 if suffix == ".csv" else None
        if declared is None:   # the reader already scaled by the declared unit: undo and apply the given one
            raw_units = _declared_units(path, suffix)
            scale = UNITS_MM[units] / UNITS_MM[raw_units]
        else:
            scale = UNITS_MM[units]
        return MarkerData(data.names, data.frames, data.P * scale, data.rate)
    if suffix == ".csv":
        extent = np.nanmax(data.P, axis=(0, 1)) - np.nanmin(data.P, axis=(0, 1)) if np.isfinite(data.P).any() else 0
        if np.all(np.isfinite(extent)) and 0 < float(np.max(extent)) < 1.0:
            return MarkerData(data.names, data.frames, data.P * 1000.0, data.rate)
    return data


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


def _declared_units(path: Path, suffix: str) -> str:
    if suffix == ".c3d":
        import ezc3d

        c = ezc3d.c3d(str(path), extract_forceplat_data=False)
        return str((c["parameters"]["POINT"].get("UNITS", {}).get("value") or ["mm"])[0]).strip().lower() or "mm"
    raw = path.read_text(encoding="utf-8-sig").splitlines()
    keys = [k.strip() for k in raw[1].strip().split("\t") if k.strip()]
    values = [v.strip() for v in raw[2].strip().split("\t") if v.strip()]
    return dict(zip(keys, values))["Units"].lower()
