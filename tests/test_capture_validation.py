"""Bad captures and controls files never hang, crash or pass silently (issue 14).

Every bad file here is written independently of facesim's writers (raw text, or ezc3d directly)
and must give a one-line :class:`FacesimError` naming the file and what was wrong. The unit
check takes a real capture (meshes/demo_clip.c3d) and the coarse model's rest markers, writes the
capture in other units and expects the right ``--units`` suggestion (and the right unit to pass).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from facesim.controls_io import read_activations_csv, read_jaw_csv
from facesim.errors import FacesimError
from facesim.mocap.io import (MarkerData, check_capture_scale, marker_spread, read_c3d, read_markers,
                              read_markers_csv, read_trc, write_markers_csv)

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def fails(read, path, *words):
    """``read(path)`` raises a one-line FacesimError naming ``path`` and every one of ``words``."""
    with pytest.raises(FacesimError) as err:
        read(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message, message
    for w in words:
        assert w in message, message
    return message


def write_bytes(path, data: bytes):
    path.write_bytes(data)
    return path


# ------------------------------------------------------------------ marker CSV
GOOD_CSV = "frame,lip_x,lip_y,lip_z,nose_x,nose_y,nose_z\n0,1,2,3,4,5,6\n1,1.5,2.5,3.5,4,5,6\n"


@pytest.mark.parametrize("text, words", [
    ("frame,lip_x_x,lip_x_y,lip_x_z\n0,1,2,3\n", ["column 'lip_x_x'", "ends like a coordinate"]),
    ("frame,nose_tip_x_1,nose_tip_y_1,nose_tip_z_1\n0,1,2,3\n", ["column 'nose_tip_x_1'", "<name>_x"]),
    ("frame,nose_tip_x,nose_tip_y_1,nose_tip_z\n0,1,2,3\n", ["column 'nose_tip_y_1'", "expected 'nose_tip_y'"]),
    ("frame,lip_x,lip_z,lip_y\n0,1,2,3\n", ["column 'lip_z'", "expected 'lip_y'", "in order"]),
    ("frame,lip_x,lip_y,lip_z,lip_x,lip_y,lip_z\n0,1,2,3,1,2,3\n", ["duplicate column 'lip_x'"]),
    ("frame\n0\n1\n", ["no marker columns"]),
    ("frame,lip_x,lip_y,lip_z\n", ["no data rows"]),
    ("", ["empty marker file"]),
    ("\n\n  \n", ["empty marker file"]),
    ("frame,lip_x,lip_y,lip_z\n99999999999999999999999,1,2,3\n", ["line 2", "column 'frame'",
                                                                  "'99999999999999999999999'", "frame number"]),
    ("frame,lip_x,lip_y,lip_z\n" + "9" * 5000 + ",1,2,3\n", ["line 2", "column 'frame'", "frame number"]),
    ("frame,lip_x,lip_y,lip_z\n1e300,1,2,3\n", ["line 2", "column 'frame'", "'1e300'"]),
    ("frame,lip_x,lip_y,lip_z\n-1,1,2,3\n", ["line 2", "'-1'"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n2,1,2,3\n1,1,2,3\n", ["line 4", "frame 1 after frame 2",
                                                             "increasing frame numbers"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n0,1,2,3\n", ["line 3", "frame 0 again", "increasing frame numbers"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,inf,3\n", ["line 2", "column 'lip_y'", "finite", "'inf'"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,-Infinity\n", ["line 2", "column 'lip_z'", "finite"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,1e400\n", ["line 2", "column 'lip_z'", "1e400", "finite"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n1,1,2,12.", ["line 3", "column 'lip_z'", "'12.'", "cut short"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n1,1,2,2.5e", ["line 3", "'2.5e'", "cut short"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n1,1,2", ["line 3", "expected 4 fields", "got 3", "cut short"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n1,1,2\n", ["line 3", "expected 4 fields", "got 3"]),
    ("frame,lip_x,lip_y,lip_z\n0,1_000,2,3\n", ["line 2", "'1_000'"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,,3\n", ["line 2", "column 'lip_y'", "lip_x,lip_z", "all three coordinates"]),
    ("frame,lip_x,lip_y,lip_z\n0,NaN,2,3\n", ["column 'lip_x'", "lip_y,lip_z"]),
    ("frame,lip_x,lip_y,lip_z\n0,1,2,3\n1,1," + "2" * 200_000 + ",3\n", ["not a CSV table"]),
])
def test_bad_marker_csv(tmp_path, text, words):
    path = tmp_path / "cap.csv"
    path.write_text(text)
    fails(read_markers_csv, path, *words)
    fails(read_markers, path)   # the same through the dispatcher


def test_unreadable_marker_csv(tmp_path):
    good = GOOD_CSV.encode()
    fails(read_markers_csv, write_bytes(tmp_path / "u16.csv", GOOD_CSV.encode("utf-16")), "not UTF-8")
    fails(read_markers_csv, write_bytes(tmp_path / "u16le.csv", GOOD_CSV.encode("utf-16-le")), "NUL bytes")
    fails(read_markers_csv, write_bytes(tmp_path / "bin.csv", bytes(range(256)) * 4), "not a text CSV")
    fails(read_markers_csv, write_bytes(tmp_path / "nul.csv", good[:30] + b"\x00" + good[30:]), "NUL bytes")
    fails(read_markers_csv, write_bytes(tmp_path / "c3d.csv", (MESHES / "demo_clip.c3d").read_bytes()))
    (tmp_path / "folder.csv").mkdir()
    fails(read_markers_csv, tmp_path / "folder.csv", "found a folder")
    fails(read_markers_csv, tmp_path / "missing.csv", "no such marker file")


def test_missing_markers_and_a_byte_order_mark_are_accepted(tmp_path):
    """NaN (any case) or three empty fields: a missing marker; frame 3.0 is frame 3."""
    path = write_bytes(tmp_path / "cap.csv", "\ufeffframe,lip_x,lip_y,lip_z,nose_x,nose_y,nose_z\n"
                       "0,1,2,3,NaN,nan,NAN\n3.0,,,,4,5,6\r\n".encode())
    data = read_markers_csv(path)
    assert data.names == ("lip", "nose") and list(data.frames) == [0, 3] and data.units == "mm"
    np.testing.assert_array_equal(data.P[0, 0], [1, 2, 3])
    assert np.isnan(data.P[0, 1]).all() and np.isnan(data.P[1, 0]).all()
    np.testing.assert_array_equal(data.P[1, 1], [4, 5, 6])


def test_csv_writer_refuses_names_the_reader_would_refuse(tmp_path):
    with pytest.raises(FacesimError, match="'lip_x'.*ends like a coordinate"):
        write_markers_csv(tmp_path / "m.csv", [0], ["lip_x"], np.zeros((1, 1, 3)))
    assert not (tmp_path / "m.csv").exists()


# ------------------------------------------------------------------ TRC
def trc_text(names, rows, units="mm", num_frames=None, rate="100", end="\n") -> str:
    """A TRC file as text, built by hand: ``rows`` are lists of fields (Frame#, Time, x, y, z, ...)."""
    n = len(rows) if num_frames is None else num_frames
    lines = ["PathFileType\t4\t(X/Y/Z)\tcap.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{rate}\t{rate}\t{n}\t{len(names)}\t{units}\t{rate}\t1\t{n}",
             "Frame#\tTime\t" + "\t\t\t".join(names),
             "\t\t" + "\t".join(f"{c}{i + 1}" for i in range(len(names)) for c in "XYZ"),
             ""]
    lines += ["\t".join(str(f) for f in r) for r in rows]
    return "\n".join(lines) + end


def row(frame, *xyz):
    return [frame, f"{(frame - 1) / 100:.4f}", *xyz]


TRC_ROWS = [row(1, 1, 2, 3, 4, 5, 6), row(2, 1, 2, 3, 4, 5, 6), row(3, 1, 2, 3, 4, 5, 6)]


def test_hand_written_trc_reads(tmp_path):
    """The reference file for the cases below; trailing markers left out of a row are missing."""
    rows = [*TRC_ROWS[:2], row(3, 1, 2, 3)]
    path = tmp_path / "cap.trc"
    path.write_text(trc_text(["lip", "nose"], rows, units="cm"))
    data = read_trc(path)
    assert data.names == ("lip", "nose") and list(data.frames) == [0, 1, 2] and data.rate == 100.0
    assert data.units == "cm"
    np.testing.assert_array_equal(data.P[0], [[10, 20, 30], [40, 50, 60]])
    assert np.isnan(data.P[2, 1]).all()


@pytest.mark.parametrize("names, rows, options, words", [
    (["lip", "lip"], TRC_ROWS, {}, ["line 4", "marker 'lip' appears twice"]),
    (["lip", "nose"], [TRC_ROWS[1], TRC_ROWS[0], TRC_ROWS[2]], {}, ["line 8", "column 'Frame#'",
                                                                     "frame 1 after frame 2"]),
    (["lip", "nose"], [TRC_ROWS[0], TRC_ROWS[0], TRC_ROWS[2]], {}, ["line 8", "frame 1 again"]),
    (["lip", "nose"], [row(0, 1, 2, 3, 4, 5, 6), *TRC_ROWS[1:]], {}, ["line 7", "column 'Frame#'", "'0'",
                                                                       "TRC numbers frames from 1"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(99999999999999999999999, 1, 2, 3, 4, 5, 6)], {},
     ["line 9", "column 'Frame#'", "frame number"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(3, 1, 2, 3, 4, 5, "12.")], {"end": ""}, ["line 9", "column 'Z2'",
                                                                                   "'12.'", "cut short"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(3, 1, 2, 3, 4, 5)], {"end": ""}, ["line 9", "expected 8 fields",
                                                                            "got 7", "cut short"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(3, 1, 2, 3, 4)], {"end": ""}, ["line 9", "got 6", "cut short"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(3, 1, 2, 3, 4)], {}, ["line 9", "expected 8 fields", "got 6"]),
    (["lip", "nose"], [*TRC_ROWS[:2], row(3, 1, 2, 3)], {"end": ""}, ["line 9", "got 5", "cut short"]),
    (["lip", "nose"], TRC_ROWS[:2], {"num_frames": 3}, ["line 3", "NumFrames 3", "2 data rows", "cut short"]),
    (["lip", "nose"], [*TRC_ROWS[:2], [], TRC_ROWS[2]], {"num_frames": 3}, ["line 10", "after the blank line 9"]),
    (["lip", "nose"], [TRC_ROWS[0], row(2, 1, "inf", 3, 4, 5, 6)], {}, ["line 8", "column 'Y1'", "finite"]),
    (["lip", "nose"], [TRC_ROWS[0], row(2, 1, 2, 3, 4, 5, "-1e999")], {}, ["line 8", "column 'Z2'", "finite"]),
    (["lip", "nose"], [TRC_ROWS[0], row(2, 1, "", 3, 4, 5, 6)], {}, ["line 8", "column 'Y1'",
                                                                      "all three coordinates"]),
    (["lip", "nose"], [TRC_ROWS[0], [2, "soon", 1, 2, 3, 4, 5, 6]], {}, ["line 8", "column 'Time'", "'soon'"]),
    (["lip", "nose"], TRC_ROWS, {"rate": "0"}, ["line 3", "DataRate '0'", "> 0"]),
    (["lip", "nose"], TRC_ROWS, {"rate": "nan"}, ["line 3", "DataRate 'nan'"]),
    (["lip", "nose"], TRC_ROWS, {"units": "inches"}, ["line 3", "Units 'inches'"]),
    ([], [[1, 0.0], [2, 0.01]], {}, ["line 3", "NumMarkers '0'", ">= 1"]),
    (["lip", "nose"], [], {}, ["no data rows"]),
])
def test_bad_trc(tmp_path, names, rows, options, words):
    path = tmp_path / "cap.trc"
    path.write_text(trc_text(names, rows, **options))
    fails(read_trc, path, *words)
    fails(read_markers, path)


def test_unreadable_trc(tmp_path):
    text = trc_text(["lip", "nose"], TRC_ROWS)
    fails(read_trc, write_bytes(tmp_path / "u16.trc", text.encode("utf-16")), "not UTF-8")
    fails(read_trc, write_bytes(tmp_path / "u16le.trc", text.encode("utf-16-le")), "NUL bytes")
    fails(read_trc, write_bytes(tmp_path / "bin.trc", bytes(range(256)) * 4), "not a TRC")
    fails(read_trc, write_bytes(tmp_path / "empty.trc", b""), "not a TRC file")
    fails(read_trc, write_bytes(tmp_path / "head.trc", "\n".join(text.splitlines()[:3]).encode()), "5 header lines")
    fails(read_trc, write_bytes(tmp_path / "header_only.trc", "\n".join(text.splitlines()[:6]).encode()),
          "no data rows")
    (tmp_path / "folder.trc").mkdir()
    fails(read_trc, tmp_path / "folder.trc", "expected a TRC file")


# ------------------------------------------------------------------ C3D (ezc3d directly)
def c3d_file(path, labels, points, rate=100.0, units="mm") -> Path:
    """Write ``points (3, N, F)`` with ezc3d, as a C3D of any make would come."""
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c["parameters"]["POINT"]["UNITS"]["value"] = [units]
    pts = np.ones((4, *np.shape(points)[1:]))
    pts[:3] = points
    c["data"]["points"] = pts
    if pts.shape[2] == 0:
        del c["data"]["rotations"]   # ezc3d's writer divides by the number of frames otherwise
    c.write(str(path))
    return Path(path)


def some_points(n=3, frames=4, seed=0):
    return np.random.default_rng(seed).normal(scale=40.0, size=(3, n, frames))


def test_bad_c3d(tmp_path):
    good = c3d_file(tmp_path / "good.c3d", ["chin", "nose", "lip"], some_points())
    data = read_c3d(good)
    assert data.names == ("chin", "nose", "lip") and data.P.shape == (4, 3, 3) and data.units == "mm"

    fails(read_c3d, c3d_file(tmp_path / "zero.c3d", ["chin", "nose"], np.ones((3, 2, 0))), "no frames")
    fails(read_c3d, c3d_file(tmp_path / "none.c3d", [], np.ones((3, 0, 4))), "no POINT data")
    p = some_points()
    p[1, 2, 3] = np.inf
    fails(read_c3d, c3d_file(tmp_path / "inf.c3d", ["chin", "nose", "lip"], p), "frame 3", "marker 'lip'", "inf",
          "finite")
    fails(read_c3d, c3d_file(tmp_path / "dup.c3d", ["chin", "nose", "chin"], some_points()), "POINT:LABELS",
          "marker 'chin' appears twice")
    fails(read_c3d, c3d_file(tmp_path / "rate.c3d", ["chin", "nose", "lip"], some_points(), rate=-50.0),
          "POINT:RATE", "> 0")
    fails(read_c3d, c3d_file(tmp_path / "units.c3d", ["chin", "nose", "lip"], some_points(), units="in"),
          "POINT:UNITS 'in'")
    long = c3d_file(tmp_path / "long.c3d", ["chin", "nose", "lip"], some_points(frames=200))
    data = long.read_bytes()
    fails(read_c3d, write_bytes(tmp_path / "cut.c3d", data[:len(data) // 2]), "cut short")
    fails(read_c3d, write_bytes(tmp_path / "text.c3d", GOOD_CSV.encode() * 20), "not a readable C3D")
    fails(read_c3d, write_bytes(tmp_path / "empty.c3d", b""), "not a readable C3D")
    (tmp_path / "folder.c3d").mkdir()
    fails(read_c3d, tmp_path / "folder.c3d", "expected a C3D file")


def test_c3d_nan_and_negative_residual_are_missing(tmp_path):
    p = some_points()
    p[0, 1, 2] = np.nan   # one coordinate: the whole marker is missing
    data = read_c3d(c3d_file(tmp_path / "gap.c3d", ["chin", "nose", "lip"], p))
    assert np.isnan(data.P[2, 1]).all() and np.isfinite(np.delete(data.P.reshape(-1, 3), 7, axis=0)).all()


# ------------------------------------------------------------------ controls files
MUSCLES = ("zygomaticus_major_L", "orbicularis_oris")


@pytest.mark.parametrize("text, words", [
    ("frame,orbicularis_oris\n99999999999999999999999,0.5\n", ["line 2", "column 'frame'", "frame number"]),
    ("frame,orbicularis_oris\n0,0.5\n0,0.5\n", ["line 3", "frame 0 again"]),
    ("frame,orbicularis_oris\n0,0.5\n4,0.5\n2,0.5\n", ["line 4", "frame 2 after frame 4"]),
    ("frame,orbicularis_oris\n0,0.5\n1,0.", ["line 3", "'0.'", "cut short"]),
    ("frame,orbicularis_oris,zygomaticus_major_L\n0,0.5,0.1\n1,0.5", ["line 3", "expected 3 fields", "cut short"]),
    ("frame,orbicularis_oris\n0,inf\n", ["line 2", "column 'orbicularis_oris'", "finite"]),
    ("frame,orbicularis_oris\n0,nan\n", ["line 2", "'nan'"]),
    ("frame,orbicularis_oris,orbicularis_oris\n0,0.5,0.5\n", ["line 1", "duplicate column 'orbicularis_oris'"]),
    ("frame,orbicularis_oris\n", ["no data rows"]),
])
def test_bad_activations_csv(tmp_path, text, words):
    path = tmp_path / "act.csv"
    path.write_text(text)
    fails(lambda p: read_activations_csv(p, MUSCLES), path, *words)


def test_unreadable_activations_csv(tmp_path):
    text = "frame,orbicularis_oris\n0,0.5\n"
    read = lambda p: read_activations_csv(p, MUSCLES)   # noqa: E731
    fails(read, write_bytes(tmp_path / "u16.csv", text.encode("utf-16")), "not UTF-8")
    fails(read, write_bytes(tmp_path / "bin.csv", bytes(range(256))), "activations file")
    (tmp_path / "folder.csv").mkdir()
    fails(read, tmp_path / "folder.csv", "found a folder")
    frames, A = read_activations_csv(write_bytes(tmp_path / "rest.csv", b"frame\n0\n1\n"), MUSCLES)
    assert list(frames) == [0, 1] and not A.any()   # no muscle columns: every muscle at rest (documented)


@pytest.fixture(scope="module")
def face():
    from facesim.model import load_model

    return load_model(MESHES / "face_coarse.npz")


@pytest.mark.parametrize("text, words", [
    ("frame,opening\n18446744073709551616,0.1\n", ["line 2", "column 'frame'", "frame number"]),
    ("frame,opening\n0,0.1\n0,0.2\n", ["line 3", "frame 0 again"]),
    ("frame,opening\n3,0.1\n1,0.2\n", ["line 3", "frame 1 after frame 3"]),
    ("frame,opening\n0,0.1\n1,0.", ["line 3", "'0.'", "cut short"]),
    ("frame,rx,ry,rz,tx,ty,tz\n0,0,0,0,0,0,0\n1,0,0,0,0,0", ["line 3", "expected 7 fields", "cut short"]),
    ("frame,opening\n0,-inf\n", ["line 2", "column 'opening'", "finite"]),
    ("frame,rx,ry,rz,tx,ty,tz\n0,0,0,0,0,1e999,0\n", ["line 2", "column 'ty'", "finite"]),
    ("frame,opening,opening\n0,0.1,0.1\n", ["duplicate column 'opening'"]),
])
def test_bad_rigid_jaw_csv(tmp_path, face, text, words):
    path = tmp_path / "jaw.csv"
    path.write_text(text)
    fails(lambda p: read_jaw_csv(p, face), path, *words)


@pytest.mark.parametrize("text, words", [
    ("frame,opening,right_slide,left_slide\n0,0,0,0\n0,0,0,0\n", ["line 3", "frame 0 again"]),
    ("frame,opening,right_slide,left_slide\n0,0,0,nan\n", ["line 2", "column 'left_slide'", "'nan'"]),
    ("frame,opening,right_slide,left_slide\n0,0,0,0\n1,0,0", ["line 3", "cut short"]),
    ("frame,opening,right_slide,right_slide\n0,0,0,0\n", ["duplicate column 'right_slide'"]),
])
def test_bad_jaw_parameter_csv(tmp_path, face, text, words):
    path = tmp_path / "jaw.csv"
    path.write_text(text)
    fails(lambda p: read_jaw_csv(p, face, "sliding-condyle"), path, *words)


# ------------------------------------------------------------------ units: the size of the capture
@pytest.fixture(scope="module")
def capture():
    """The demo clip (mm) and the coarse model's marker spread (mm)."""
    from facesim.model import load_model

    data = read_markers(MESHES / "demo_clip.c3d")
    return data, marker_spread(load_model(MESHES / "face_coarse.npz").marker_positions())[0]


def csv_text(data: MarkerData, scale: float) -> str:
    header = ",".join(["frame"] + [f"{n}_{c}" for n in data.names for c in "xyz"])
    rows = [",".join([str(k)] + [("NaN" if np.isnan(v) else repr(float(v))) for v in p.ravel() * scale])
            for k, p in zip(data.frames, data.P)]
    return "\n".join([header, *rows]) + "\n"


def trc_of(data: MarkerData, scale: float, units: str) -> str:
    rows = [[k + 1, f"{k / 24:.5f}", *[("" if np.isnan(v) else repr(float(v))) for v in p.ravel() * scale]]
            for k, p in zip(data.frames, data.P)]
    return trc_text(data.names, rows, units=units, rate="24")


def scale_error(path, model_spread, units=None) -> str:
    data = read_markers(path, units=units)
    with pytest.raises(FacesimError) as err:
        check_capture_scale(data, model_spread, path, units_given=units)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    return message


def test_marker_spread_is_the_rms_distance_from_the_centroid():
    P = np.full((3, 4, 3), np.nan)
    P[0, :, :] = [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]]   # RMS distance 1
    P[1, :3] = 2 * P[0, :3] + 100.0                                # 3 markers, scaled and moved
    P[2, :2] = 5.0                                                  # 2 finite markers: not used
    spread, n = marker_spread(P)
    second = np.sqrt(np.mean(np.sum((P[1, :3] - P[1, :3].mean(0)) ** 2, axis=1)))
    assert n == 2 and second > 1.0
    assert spread == pytest.approx(np.median([1.0, second]))
    assert marker_spread(np.full((2, 5, 3), np.nan)) == (pytest.approx(np.nan, nan_ok=True), 0)


def test_the_demo_capture_fits_the_model(capture):
    data, model = capture
    assert 55.0 < model < 70.0 and 55.0 < marker_spread(data.P)[0] < 70.0
    check_capture_scale(data, model, "demo_clip.c3d")
    check_capture_scale(data, None, "demo_clip.c3d")   # without a model: a typical face


@pytest.mark.parametrize("fmt", ["csv", "trc"])
def test_a_capture_in_cm_read_as_mm_suggests_cm(tmp_path, capture, fmt):
    data, model = capture
    path = tmp_path / f"cap.{fmt}"
    path.write_text(csv_text(data, 0.1) if fmt == "csv" else trc_of(data, 0.1, units="mm"))
    message = scale_error(path, model)
    assert "0.101x the model's" in message and "72 frames" in message and "try --units cm" in message
    check_capture_scale(read_markers(path, units="cm"), model, path, units_given="cm")   # the right unit passes


def test_a_trc_in_metres_that_says_mm_suggests_m(tmp_path, capture):
    data, model = capture
    path = tmp_path / "cap.trc"
    path.write_text(trc_of(data, 1e-3, units="mm"))
    message = scale_error(path, model)
    assert "0.00101x the model's" in message and "try --units m" in message
    check_capture_scale(read_markers(path, units="m"), model, path, units_given="m")
    path.write_text(trc_of(data, 1e-3, units="m"))    # the same numbers, the right Units: passes as is
    check_capture_scale(read_markers(path), model, path)


def test_a_csv_in_metres_is_taken_as_metres_and_a_wrong_units_option_is_caught(tmp_path, capture):
    data, model = capture
    path = tmp_path / "cap.csv"
    path.write_text(csv_text(data, 1e-3))
    read = read_markers(path)
    assert read.units == "m"   # a face-sized CSV under 1 unit across is in metres (documented)
    np.testing.assert_allclose(read.P, data.P, rtol=1e-12, equal_nan=True)
    check_capture_scale(read, model, path)
    message = scale_error(path, model, units="cm")   # the user insists on cm: 1/10 of the face
    assert "read as cm, --units" in message and "try --units m" in message


def test_a_trc_in_mm_that_says_m_suggests_mm(tmp_path, capture):
    data, model = capture
    path = tmp_path / "cap.trc"
    path.write_text(trc_of(data, 1.0, units="m"))
    message = scale_error(path, model)
    assert "1e+03x the model's" in message and "read as m" in message and "try --units mm" in message
    check_capture_scale(read_markers(path, units="mm"), model, path, units_given="mm")


def test_captures_no_unit_can_fix(tmp_path, capture):
    data, model = capture
    path = tmp_path / "cap.csv"
    path.write_text(csv_text(data, 20.0))   # 20x: neither mm, cm nor m
    assert "do not match the model's size in mm, cm or m" in scale_error(path, model)
    path.write_text(csv_text(data, 1e30))
    message = scale_error(path, model)
    assert "do not match the model's size" in message and "expected positions within 1e+06 mm" in message
    far = data.P.copy()
    far[5, 7] += 5e6    # one marker 5 km away in one frame: the median spread is fine, the marker is not
    path.write_text(csv_text(MarkerData(data.names, data.frames, far), 1.0))
    message = scale_error(path, model)
    assert f"frame {data.frames[5]}, marker {data.names[7]!r}" in message and "within 1e+06 mm" in message
    nowhere = np.full_like(data.P, np.nan)
    nowhere[:, :2] = data.P[:, :2]   # two markers per frame: nothing to measure
    path.write_text(csv_text(MarkerData(data.names, data.frames, nowhere), 1.0))
    assert "no frame has 3 markers" in scale_error(path, model)


def test_select_keeps_the_named_markers(capture):
    data, _ = capture
    sub = data.select(["nose_tip", "not_a_marker", data.names[0]])
    assert sub.names == ("nose_tip", data.names[0]) and sub.P.shape == (len(data.frames), 2, 3)
    np.testing.assert_array_equal(sub.P[:, 1], data.P[:, 0])


# ------------------------------------------------------------------ files that would block or crash
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes are POSIX")
@pytest.mark.parametrize("reader", ["activations", "markers", "rig"])
def test_a_named_pipe_is_refused_not_read(reader, tmp_path):
    """Opening a named pipe nobody writes to blocks for ever: readers refuse anything but a regular file."""
    from facesim.controls_io import read_activations_csv
    from facesim.jaw.rigfile import rig_kind
    from facesim.mocap.io import read_markers

    pipe = tmp_path / {"activations": "a.csv", "markers": "m.trc", "rig": "r.npz"}[reader]
    os.mkfifo(pipe)
    read = {"activations": lambda p: read_activations_csv(p, ("m",)), "markers": read_markers, "rig": rig_kind}[reader]
    with pytest.raises(FacesimError, match="not a regular file|expected a TRC file"):
        read(pipe)


@pytest.mark.parametrize("cut", [100, 518, 739, 1030])
def test_a_c3d_cut_inside_its_header_or_parameters_is_refused_before_ezc3d(cut, tmp_path):
    """ezc3d hangs (739 bytes) or crashes the process (518) on a file cut inside its parameter
    section: the layout is checked first, and the error says the file is cut short."""
    import subprocess
    import sys

    from facesim._files import MESHES

    whole = (MESHES / "demo_clip.c3d").read_bytes()
    path = tmp_path / "cut.c3d"
    path.write_bytes(whole[:cut])
    code = ("import sys\nfrom facesim.errors import FacesimError\nfrom facesim.mocap.io import read_markers\n"
            f"try:\n    read_markers({str(path)!r})\nexcept FacesimError as e:\n    print(e)\n    sys.exit(2)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, (run.returncode, run.stderr[-300:])
    assert run.stdout.startswith(f"{path}: ") and len(run.stdout.splitlines()) == 1
