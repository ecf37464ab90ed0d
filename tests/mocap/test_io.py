"""Marker CSV and TRC files: exact round trips, missing markers, the TRC layout, one-line errors."""

import numpy as np
import pytest

from facesim.errors import FacesimError
from facesim.mocap.io import read_markers_csv, read_trc, write_markers_csv, write_trc

NAMES = ("mouth_L", "mouth_R", "chin", "head_L")


@pytest.fixture
def trajectories():
    """Frames 3, 4, 7, 8 (not contiguous), 4 markers at face-sized coordinates (mm), two gaps."""
    rng = np.random.default_rng(7)
    frames = np.array([3, 4, 7, 8])
    P = rng.uniform(-120.0, 120.0, size=(4, len(NAMES), 3))
    P[1, 2] = np.nan      # chin missing in frame 4
    P[3, :, :] = np.nan   # every marker missing in frame 8
    P[3, 0] = [1e-7, -0.0, 123.4567891]
    return frames, P


def assert_same(P, Q, atol=1e-6):
    assert P.shape == Q.shape
    np.testing.assert_array_equal(np.isnan(P), np.isnan(Q))
    assert np.nanmax(np.abs(P - Q)) <= atol


def test_csv_round_trip(tmp_path, trajectories):
    frames, P = trajectories
    path = write_markers_csv(tmp_path / "m.csv", frames, NAMES, P)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("frame,mouth_L_x,mouth_L_y,mouth_L_z,mouth_R_x,") and lines[0].endswith(",head_L_z")
    assert len(lines) == 1 + len(frames) and "NaN" in lines[2]
    data = read_markers_csv(path)
    assert data.names == NAMES and data.rate is None
    np.testing.assert_array_equal(data.frames, frames)
    assert_same(data.P, P)
    assert np.nanmax(np.abs(data.P - P)) > 0   # written with 6 decimals, so not bit-exact: the test can fail


def test_trc_round_trip_and_layout(tmp_path, trajectories):
    frames, P = trajectories
    path = write_trc(tmp_path / "m.trc", frames, NAMES, P, fps=60.0)
    lines = path.read_text().split("\n")
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\tm.trc"
    keys = lines[1].split("\t")
    assert keys == ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                    "OrigDataStartFrame", "OrigNumFrames"]
    meta = dict(zip(keys, lines[2].split("\t")))
    assert meta == {"DataRate": "60", "CameraRate": "60", "NumFrames": "4", "NumMarkers": "4", "Units": "mm",
                    "OrigDataRate": "60", "OrigDataStartFrame": "4", "OrigNumFrames": "4"}
    assert [s for s in lines[3].split("\t") if s] == ["Frame#", "Time", *NAMES]
    assert lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"] and lines[4].split("\t")[-1] == "Z4"
    assert lines[5] == ""
    rows = [line.split("\t") for line in lines[6:] if line]
    assert len(rows) == 4 and all(len(r) == 2 + 3 * len(NAMES) for r in rows)   # gaps are empty fields
    assert [r[0] for r in rows] == ["4", "5", "8", "9"]                            # TRC counts from 1
    assert float(rows[2][1]) == pytest.approx(7 / 60.0, abs=1e-6)
    assert rows[1][8:11] == ["", "", ""]
    data = read_trc(path)
    assert data.names == NAMES and data.rate == 60.0
    np.testing.assert_array_equal(data.frames, frames)
    assert_same(data.P, P)


@pytest.mark.parametrize("units, scale", [("m", 1e-3), ("cm", 0.1)])
def test_trc_in_other_units_reads_back_in_mm(tmp_path, trajectories, units, scale):
    frames, P = trajectories
    path = write_trc(tmp_path / "m.trc", frames, NAMES, P, fps=100.0, units=units)
    first = path.read_text().splitlines()[6].split("\t")
    assert float(first[2]) == pytest.approx(P[0, 0, 0] * scale, abs=1e-6 * scale)   # 1e-6 mm
    assert_same(read_trc(path).P, P)


def test_csv_with_empty_fields_reads_as_missing(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("frame,a_x,a_y,a_z\n0,1,2,3\n1,,,\n")
    data = read_markers_csv(path)
    assert data.names == ("a",)
    np.testing.assert_array_equal(data.P[0, 0], [1, 2, 3])
    assert np.isnan(data.P[1]).all()


@pytest.mark.parametrize("text, words", [
    ("frame,a_x,a_y\n0,1,2\n", ["three columns"]),
    ("frame,a_x,a_y,b_z\n0,1,2,3\n", ["a_x,a_y,b_z"]),
    ("frame,a_x,a_y,a_z\n0,1,two,3\n", ["line 2", "'a_y'", "'two'"]),
    ("frame,a_x,a_y,a_z\n0,1,2,3\n0,1,2,3\n", ["line 3", "increasing"]),
    ("a_x,a_y,a_z\n1,2,3\n", ["'frame'"]),
    ("", ["empty"]),
])
def test_bad_marker_csv_is_one_line_error(tmp_path, text, words):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(FacesimError) as err:
        read_markers_csv(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    for w in words:
        assert w in message


def test_bad_trc_is_one_line_error(tmp_path, trajectories):
    frames, P = trajectories
    path = write_trc(tmp_path / "m.trc", frames, NAMES, P, fps=30.0)
    lines = path.read_text().splitlines()
    lines[7] = lines[7].replace(lines[7].split("\t")[3], "x", 1)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FacesimError, match=r"line 8, column 'Y1': expected a number, got 'x'"):
        read_trc(path)
    (tmp_path / "not.trc").write_text("hello\n")
    with pytest.raises(FacesimError, match="not a TRC file"):
        read_trc(tmp_path / "not.trc")
    with pytest.raises(FacesimError, match="no such TRC file"):
        read_trc(tmp_path / "missing.trc")


def test_writers_validate(tmp_path):
    P = np.zeros((2, 1, 3))
    with pytest.raises(FacesimError, match="cannot be written"):
        write_markers_csv(tmp_path / "a.csv", [0, 1], ["a,b"], P)
    with pytest.raises(FacesimError, match=r"shape \(frames, 2, 3\)"):
        write_trc(tmp_path / "a.trc", [0, 1], ["a", "b"], P, fps=30)
    with pytest.raises(FacesimError, match="frame rate"):
        write_trc(tmp_path / "a.trc", [0, 1], ["a"], P, fps=0)
    assert not list(tmp_path.iterdir())


def test_c3d_round_trip_with_gaps_units_and_first_frame(tmp_path):
    from facesim.mocap.io import read_c3d, read_markers, write_c3d

    rng = np.random.default_rng(4)
    P = rng.normal(scale=50.0, size=(5, 3, 3))
    P[2, 1] = np.nan
    path = write_c3d(tmp_path / "m.c3d", np.arange(10, 15), ["chin", "nose", "lip"], P, fps=120.0, units="m")
    d = read_c3d(path)
    assert d.names == ("chin", "nose", "lip") and list(d.frames) == list(range(10, 15)) and d.rate == 120.0
    np.testing.assert_allclose(d.P, P, atol=1e-4)      # written in metres (float32 in the file), read as mm
    assert np.isnan(d.P[2, 1]).all() and np.isfinite(d.P[2, 0]).all()
    # an explicit unit overrides the file's
    np.testing.assert_allclose(read_markers(path, units="mm").P, P / 1000.0, atol=1e-6)
    with pytest.raises(FacesimError, match="not a readable C3D"):
        (tmp_path / "bad.c3d").write_bytes(b"\x00" * 10)
        read_c3d(tmp_path / "bad.c3d")


def test_read_markers_dispatches_and_detects_metres_in_csv(tmp_path):
    from facesim.mocap.io import read_markers, write_markers_csv

    P = np.array([[[0.01, 0.02, 0.10], [0.05, -0.03, 0.09]]])   # a face in metres
    write_markers_csv(tmp_path / "m.csv", [0], ["a", "b"], P)
    np.testing.assert_allclose(read_markers(tmp_path / "m.csv").P, P * 1000.0)
    np.testing.assert_allclose(read_markers(tmp_path / "m.csv", units="mm").P, P)
    with pytest.raises(FacesimError, match="unknown marker file type '.txt'"):
        read_markers(tmp_path / "m.txt")
