"""facesim simulate: input files and their one-line errors, the per-frame outputs, resume, flags.

Runs on the synthetic box model with the direct linear solver; one 3-frame run (rest, the
zygomaticus fully active, half active with the orbicularis and the jaw opened) is shared by
the tests that only read its outputs, and copied by those that change it.
"""

import json
import shutil
import sys

import meshio
import numpy as np
import pytest
from PIL import Image

from facesim.cli import main
from facesim.controls import rotation_about
from facesim.controls_io import read_activations_csv, read_jaw_csv
from facesim.kinematics.jaw_models import RigidJaw
from facesim.errors import FacesimError
from facesim.fem.newton import NewtonOptions
from facesim.mocap.io import read_markers_csv, read_trc
from facesim.simulate import SimulateOptions, simulate

ACTIVATIONS = "frame,zygomaticus_major_L,orbicularis_oris\n0,0,0\n1,1,0\n2,0.5,0.3\n"
JAW = "frame,opening\n0,0\n1,0\n2,0.05\n"
FRAME_LOG = ["frame", "converged", "stop_reason", "iterations", "relative_residual", "residual_N", "seconds", "linear_iterations",
             "penetration_mm", "lip_penetration_mm", "teeth_penetration_mm", "inverted_tets", "min_J", "error"]


def write(path, text):
    path.write_text(text)
    return str(path)


def simulate_cli(model_path, activations, out, *extra):
    return main(["simulate", "--model", str(model_path), "--activations", str(activations), "-o", str(out),
                 "--solver", "direct", "-q", *extra])


def frame_log(out):
    lines = (out / "frames.csv").read_text().splitlines()
    assert lines[0].split(",") == FRAME_LOG
    return [dict(zip(FRAME_LOG, line.split(","))) for line in lines[1:]]


@pytest.fixture(scope="module")
def run(box_model_path, tmp_path_factory):
    """The shared 3-frame run: its output folder (do not modify; copy it)."""
    folder = tmp_path_factory.mktemp("sim")
    a = write(folder / "a.csv", ACTIVATIONS)
    j = write(folder / "j.csv", JAW)
    assert simulate_cli(box_model_path, a, folder / "out", "--jaw", j) == 0
    return folder / "out"


def copy_run(run, tmp_path):
    return shutil.copytree(run, tmp_path / "out", copy_function=shutil.copy2)


# ------------------------------------------------------------------ input files
def test_activations_subset_in_any_order(tmp_path, box_model):
    path = write(tmp_path / "a.csv", "frame,orbicularis_oris\n0,0.25\n5,1\n")
    frames, A = read_activations_csv(path, box_model.muscles.names)
    np.testing.assert_array_equal(frames, [0, 5])
    np.testing.assert_array_equal(A, [[0.0, 0.25], [0.0, 1.0]])   # zygomaticus missing: 0


@pytest.mark.parametrize("text, words", [
    (None, ["no such activations file"]),
    ("", ["empty activations file", "frame,zygomaticus_major_L"]),
    ("zygomaticus_major_L\n0.5\n", ["no 'frame' column"]),
    ("frame,zygomaticus_L\n0,0.5\n", ["'zygomaticus_L'", "unknown muscle", "closest: zygomaticus_major_L"]),
    ("frame,orbicularis_oris,orbicularis_oris\n0,0,0\n", ["duplicate column 'orbicularis_oris'"]),
    ("frame,orbicularis_oris\n0,0.1\n1,abc\n", ["line 3", "column 'orbicularis_oris'", "expected a number",
                                               "'abc'"]),
    ("frame,orbicularis_oris\n0,0.1\n1,1.5\n", ["line 3", "column 'orbicularis_oris'", "1.5", "outside [0, 1]"]),
    ("frame,orbicularis_oris\n0,0.1\n1,-0.2\n", ["line 3", "-0.2", "outside [0, 1]"]),
    ("frame,orbicularis_oris\n0,0.1\n1,\n", ["line 3", "an empty field"]),
    ("frame,orbicularis_oris\n0,0.1\n1,0.2,0.3\n", ["line 3", "expected 2 fields"]),
    ("frame,orbicularis_oris\n1,0.1\n1,0.2\n", ["line 3", "increasing frame numbers"]),
    ("frame,orbicularis_oris\n0.5,0.1\n", ["line 2", "column 'frame'", "'0.5'"]),
    ("frame,orbicularis_oris\n", ["no data rows"]),
])
def test_bad_activations_exit_2_with_one_line(box_model_path, tmp_path, capsys, text, words):
    path = tmp_path / "act.csv"
    if text is not None:
        path.write_text(text)
    assert simulate_cli(box_model_path, path, tmp_path / "out") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("facesim: error: ") and "Traceback" not in err
    for w in [str(path), *words]:
        assert w in err, err
    assert not (tmp_path / "out").exists()   # nothing written for bad input


@pytest.mark.parametrize("text, words", [
    ("frame,opening\n0,0\n1,0\n", ["2 frames", "has 3"]),
    ("frame,opening\n0,0\n1,0\n3,0\n", ["data row 3 is frame 3", "frame 2"]),
    ("frame,rx,ry,rz,tx,ty\n0,0,0,0,0,0\n", ["frame,rx,ry,rz,tx,ty,tz"]),
    ("frame,yaw\n0,0\n", ["unknown column 'yaw'"]),
    ("frame,opening\n0,0\n1,wide\n2,0\n", ["line 3", "column 'opening'", "'wide'"]),
])
def test_bad_jaw_exit_2_with_one_line(box_model_path, tmp_path, capsys, text, words):
    a = write(tmp_path / "a.csv", ACTIVATIONS)
    j = write(tmp_path / "j.csv", text)
    assert simulate_cli(box_model_path, a, tmp_path / "out", "--jaw", j) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    for w in [j, *words]:
        assert w in err, err


def test_jaw_csv_forms(tmp_path, box_model):
    frames, T = read_jaw_csv(write(tmp_path / "o.csv", "frame,opening\n0,0\n1,0.2\n"), box_model)
    np.testing.assert_array_equal(frames, [0, 1])
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-15)
    np.testing.assert_allclose(T[1], RigidJaw.from_rotation(box_model, 0.2), atol=1e-15)
    assert T[1][1, 3] != 0   # a real rotation about an off-origin axis, not the identity

    r, t = np.array([0.1, -0.05, 0.02]), np.array([0.5, -1.0, 2.0])
    text = "frame,rx,ry,rz,tx,ty,tz\n4," + ",".join(map(str, [*r, *t])) + "\n"
    frames, T = read_jaw_csv(write(tmp_path / "f.csv", text), box_model)
    expected = rotation_about(r, box_model.jaw.midpoint)
    expected[:3, 3] += t
    np.testing.assert_array_equal(frames, [4])
    np.testing.assert_allclose(T[0], expected, atol=1e-12)
    m = box_model.jaw.midpoint   # the condyle midpoint only translates
    np.testing.assert_allclose(T[0][:3, :3] @ m + T[0][:3, 3], m + t, atol=1e-12)
    # the same opening in the full form: a rotation vector along the intercondylar axis
    text = "frame,ty,rx,ry,rz,tx,tz\n0,0," + ",".join(map(str, 0.2 * box_model.jaw.u)) + ",0,0\n"
    np.testing.assert_allclose(read_jaw_csv(write(tmp_path / "g.csv", text), box_model)[1][0],
                               RigidJaw.from_rotation(box_model, 0.2), atol=1e-12)


# ------------------------------------------------------------------ a run
def test_run_writes_every_output(run, box_model):
    n = box_model.n_nodes
    for k in range(3):
        skin = meshio.read(run / "skin" / f"frame_{k:05d}.ply")
        assert skin.cells_dict["triangle"].shape == box_model.skin.shape
        with np.load(run / "state" / f"frame_{k:05d}.npz") as z:
            assert z["x"].shape == (n, 3) and z["x"].dtype == np.float64 and bool(z["converged"])
            x = z["x"]
        used = np.unique(box_model.skin)   # the PLY holds the skin nodes in increasing node order
        np.testing.assert_allclose(skin.points, x[used], atol=1e-9)
    log = frame_log(run)
    assert [r["frame"] for r in log] == ["0", "1", "2"] and all(r["converged"] == "1" for r in log)
    assert log[0]["iterations"] == "0" and int(log[1]["iterations"]) > 0 and int(log[1]["linear_iterations"]) > 0
    assert float(log[1]["relative_residual"]) <= 1e-6
    csv = read_markers_csv(run / "markers.csv")
    assert csv.names == box_model.markers.names and csv.P.shape == (3, box_model.n_markers, 3)
    trc = read_trc(run / "markers.trc")
    assert trc.names == csv.names and trc.rate == 30.0
    np.testing.assert_array_equal(trc.frames, [0, 1, 2])
    np.testing.assert_allclose(trc.P, csv.P, atol=1e-6)
    from facesim.mocap.io import read_c3d

    c3d = read_c3d(run / "markers.c3d")   # the simulated markers for a mocap tool (float32 in the file)
    assert c3d.names == csv.names and c3d.rate == 30.0
    np.testing.assert_array_equal(c3d.frames, [0, 1, 2])
    np.testing.assert_allclose(c3d.P, csv.P, atol=1e-4)
    report = json.loads((run / "report.json").read_text())
    assert report["status"] == "complete" and report["frames"] == 3 and report["converged"] == 3
    assert report["unconverged_frames"] == [] and report["options"]["solver"] == "direct"
    assert report["model"].endswith("box.npz") and report["jaw"].endswith("j.csv")
    assert report["newton_iterations"] == sum(int(r["iterations"]) for r in log)


def test_markers_move_with_the_muscles_and_the_jaw(run, box_model):
    P = read_markers_csv(run / "markers.csv").P
    with np.load(run / "state" / "frame_00001.npz") as z:
        x1 = z["x"]
    np.testing.assert_allclose(P[1], box_model.marker_positions(x1), atol=1e-6)   # the CSV holds the state's markers
    rest = box_model.marker_positions()
    d = np.linalg.norm(P - rest, axis=2)   # (frames, markers) mm
    assert d[0].max() < 1e-6                 # frame 0: no activation, no jaw motion
    mouth_L = box_model.markers.names.index("mouth_L")
    assert d[1, mouth_L] > 1.0               # zygomaticus fully active: the mouth corner moves mm
    assert not np.allclose(P[2], P[1], atol=0.1)
    with np.load(run / "state" / "frame_00002.npz") as z:
        x2, T = z["x"], z["jaw"]
    np.testing.assert_allclose(T, RigidJaw.from_rotation(box_model, 0.05), atol=1e-15)
    jaw = box_model.jaw_nodes
    np.testing.assert_allclose(x2[jaw], box_model.X[jaw] @ T[:3, :3].T + T[:3, 3], atol=1e-9)
    assert np.abs(x2[jaw] - box_model.X[jaw]).max() > 0.5   # the jaw really moved


def test_resume_recomputes_only_the_missing_frame(run, box_model_path, tmp_path):
    out = copy_run(run, tmp_path)
    (out / "state" / "frame_00002.npz").unlink()
    (out / "skin" / "frame_00002.ply").unlink()
    log = (out / "frames.csv").read_text()
    (out / "frames.csv").write_text(log[:-12])   # the last row cut by a crash
    kept = [out / "skin" / "frame_00000.ply", out / "skin" / "frame_00001.ply", out / "state" / "frame_00000.npz",
            out / "state" / "frame_00001.npz"]
    stamps = {p: p.stat().st_mtime_ns for p in kept}
    a = write(tmp_path / "a.csv", ACTIVATIONS)
    j = write(tmp_path / "j.csv", JAW)
    assert simulate_cli(box_model_path, a, out, "--jaw", j, "--resume") == 0
    assert {p: p.stat().st_mtime_ns for p in kept} == stamps
    assert (out / "frames.csv").read_text().splitlines()[:3] == log.splitlines()[:3]
    assert len(frame_log(out)) == 3 and len(read_markers_csv(out / "markers.csv").frames) == 3
    with np.load(out / "state" / "frame_00002.npz") as z, np.load(run / "state" / "frame_00002.npz") as z0:
        np.testing.assert_allclose(z["x"], z0["x"], atol=1e-6)   # the same warm start: the same equilibrium
    report = json.loads((out / "report.json").read_text())
    assert report["reused_frames"] == 2 and report["resumed_at_frame"] == 2 and report["finished_frames"] == 3
    assert (out / "skin" / "frame_00002.ply").is_file() and read_trc(out / "markers.trc").P.shape[0] == 3


def test_interrupted_run_keeps_finished_frames(box_model, tmp_path, monkeypatch):
    from facesim.fem.equilibrium import FaceSimulator

    solve = FaceSimulator.equilibrium
    calls = []

    def interrupted_at_third_frame(self, controls, x0=None, **kwargs):
        calls.append(controls)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return solve(self, controls, x0, **kwargs)

    monkeypatch.setattr(FaceSimulator, "equilibrium", interrupted_at_third_frame)
    A = np.zeros((4, 2))   # at rest: no Newton step, the test is about the files
    out = tmp_path / "out"
    options = SimulateOptions(newton=NewtonOptions(linear_solver="direct"))
    with pytest.raises(KeyboardInterrupt):
        simulate(box_model, A, out, options=options, progress=False)
    assert len(frame_log(out)) == 2 and not (out / "state" / "frame_00002.npz").exists()
    assert json.loads((out / "report.json").read_text())["status"] == "interrupted"
    assert read_trc(out / "markers.trc").P.shape == (2, box_model.n_markers, 3)   # the TRC of what is done
    monkeypatch.setattr(FaceSimulator, "equilibrium", solve)
    summary = simulate(box_model, A, out, options=options, progress=False, resume=True)
    assert summary["status"] == "complete" and summary["reused_frames"] == 2 and len(frame_log(out)) == 4


def test_existing_run_needs_resume_or_overwrite(run, box_model_path, tmp_path, capsys):
    out = copy_run(run, tmp_path)
    a = write(tmp_path / "a.csv", "frame\n0\n")   # one frame at rest: no muscle columns at all
    assert simulate_cli(box_model_path, a, out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out) in err and "--resume" in err and "--overwrite" in err
    assert simulate_cli(box_model_path, a, out, "--overwrite") == 0
    assert sorted(p.name for p in (out / "state").iterdir()) == ["frame_00000.npz"]   # stale frames gone
    assert len(frame_log(out)) == 1 and json.loads((out / "report.json").read_text())["frames"] == 1


def test_render_and_video_from_a_finished_run(run, box_model_path, tmp_path, monkeypatch, capsys):
    """--resume on a complete run solves nothing; it draws the missing pictures and skins from the states."""
    out = copy_run(run, tmp_path)
    (out / "skin" / "frame_00001.ply").unlink()
    stamp = (out / "skin" / "frame_00000.ply").stat().st_mtime_ns
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)   # the GIF fallback, whatever is installed
    a = write(tmp_path / "a.csv", ACTIVATIONS)
    j = write(tmp_path / "j.csv", JAW)
    assert simulate_cli(box_model_path, a, out, "--jaw", j, "--resume", "--video", "--size", "96x80") == 0
    printed = capsys.readouterr().out
    assert "GIF" in printed and "video.gif" in printed
    pictures = [np.asarray(Image.open(out / "png" / f"frame_{k:05d}.png").convert("RGB")) for k in range(3)]
    assert all(p.shape == (80, 96, 3) and p.std() > 5 for p in pictures)
    assert np.abs(pictures[1].astype(int) - pictures[0]).max() > 0   # the face moved between frames
    gif = Image.open(out / "video.gif")
    assert gif.n_frames == 3 and gif.size == (96, 80)
    report = json.loads((out / "report.json").read_text())
    assert report["reused_frames"] == 3 and report["outputs"]["video"].endswith("video.gif")
    assert frame_log(out) == frame_log(run)
    assert (out / "skin" / "frame_00000.ply").stat().st_mtime_ns == stamp
    redrawn, original = (meshio.read(f / "skin" / "frame_00001.ply").points for f in (out, run))
    np.testing.assert_array_equal(redrawn, original)


def test_unconverged_frame_is_flagged_and_its_markers_missing(box_model, tmp_path):
    A = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    options = SimulateOptions(newton=NewtonOptions(linear_solver="direct", max_iterations=1, settle_iterations=0))
    summary = simulate(box_model, A, tmp_path / "out", options=options, progress=False)
    assert summary["unconverged_frames"] == [1] and summary["converged"] == 2
    log = frame_log(tmp_path / "out")
    assert [r["converged"] for r in log] == ["1", "0", "1"] and int(log[1]["iterations"]) >= 1   # + substep retries
    P = read_markers_csv(tmp_path / "out" / "markers.csv").P
    assert np.isnan(P[1]).all() and np.isfinite(P[[0, 2]]).all()
    with np.load(tmp_path / "out" / "state" / "frame_00001.npz") as z:
        assert not bool(z["converged"]) and np.isfinite(z["x"]).all()   # kept for inspection, flagged
    # frame 2 (rest) started from converged frame 0, not from the unconverged frame 1: nothing to do
    assert log[2]["iterations"] == "0"


def test_simulate_validates_arrays(box_model, tmp_path):
    with pytest.raises(FacesimError, match=r"shape \(frames, 2\)"):
        simulate(box_model, np.zeros((3, 5)), tmp_path / "o", progress=False)
    with pytest.raises(FacesimError, match=r"\[0, 1\]"):
        simulate(box_model, np.full((1, 2), 2.0), tmp_path / "o", progress=False)
    with pytest.raises(FacesimError, match="jaw"):
        simulate(box_model, np.zeros((2, 2)), tmp_path / "o", jaw=np.eye(4)[None], progress=False)
    assert not (tmp_path / "o").exists()


def test_help(capsys):
    assert main(["simulate", "--help"]) == 0
    out = capsys.readouterr().out
    for words in ("--activations", "--resume", "--render", "--video", "--fps", "mm", "rad", "frames.csv"):
        assert words in out


def test_sliding_condyle_jaw_csv(tmp_path):
    from pathlib import Path

    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.model import load_model
    from facesim.controls_io import read_jaw_csv

    model = load_model(Path(__file__).resolve().parents[1] / "meshes" / "face_coarse.npz")
    f = tmp_path / "j.csv"
    f.write_text("frame,opening,left_slide,right_slide\n0,0,0,0\n1,0.3,8,5\n")
    frames, p = read_jaw_csv(f, model, "sliding-condyle")
    assert list(frames) == [0, 1]
    # parameters in the jaw model's order (opening, right slide, left slide)
    np.testing.assert_allclose(p, [[0.0, 0.0, 0.0], [0.3, 5.0, 8.0]], atol=0)
    jaw = SlidingCondyleJaw(model.jaw)
    np.testing.assert_allclose(jaw.transform(p[0]), np.eye(4), atol=1e-12)
    f.write_text("frame,opening,left_slide,right_slide\n0,0.3,40,0\n")
    with pytest.raises(FacesimError, match=r"j.csv: data row 1, column 'left_slide': 40 outside"):
        read_jaw_csv(f, model, "sliding-condyle")
    f.write_text("frame,opening\n0,0.3\n")
    with pytest.raises(FacesimError, match="left_slide"):
        read_jaw_csv(f, model, "sliding-condyle")


def test_cli_sliding_condyle_jaw_and_a_scripted_collider(box_model_path, box_model, tmp_path):
    """--jaw-model sliding-condyle keeps the parameters as the frame's jaw controls; --collider puts a
    ball on a CSV path that the skin cannot enter; the rendered frames draw it."""
    a = write(tmp_path / "a.csv", "frame,zygomaticus_major_L\n0,0\n1,0\n2,0.5\n")
    j = write(tmp_path / "j.csv", "frame,opening,left_slide,right_slide\n0,0,0,0\n1,0.1,1,1\n2,0.2,2,3\n")
    front = box_model.X[:, 2].max()
    write(tmp_path / "ball.csv", f"frame,x,y,z\n0,0,15,{front + 20}\n2,0,15,{front + 5}\n")
    out = tmp_path / "out"
    assert simulate_cli(box_model_path, a, out, "--jaw", j, "--jaw-model", "sliding-condyle",
                        "--collider", "sphere:radius=8,path=ball.csv,name=ball", "--render", "--size", "96x96") == 0
    log = frame_log(out)
    assert [r["converged"] for r in log] == ["1", "1", "1"]
    pen = [float(r["penetration_mm"]) for r in log]
    assert pen[0] == 0.0 and pen[2] < 0.1
    with np.load(out / "state" / "frame_00002.npz") as z:
        np.testing.assert_array_equal(z["jaw"], [0.2, 3.0, 2.0])   # (opening, right, left)
        x = z["x"]
    # the ball's centre reached front + 5 with radius 8: the node under it was pushed onto its surface
    # (in and aside: frictionless contact on 10 mm elements)
    under = np.argmin(np.linalg.norm(box_model.X - [0.0, 15.0, front], axis=1))
    assert np.linalg.norm(x[under] - box_model.X[under]) > 2.0
    assert abs(np.linalg.norm(x[under] - [0.0, 15.0, front + 5.0]) - 8.0) < 0.1
    report = json.loads((out / "report.json").read_text())
    assert report["options"]["jaw_model"] == "sliding-condyle" and report["collider_specs"] == [
        "sphere:radius=8,path=ball.csv,name=ball"]
    assert Image.open(out / "png" / "frame_00002.png").size == (96, 96)


def test_cli_bad_collider_spec_exits_2(box_model_path, tmp_path, capsys):
    a = write(tmp_path / "a.csv", ACTIVATIONS)
    assert simulate_cli(box_model_path, a, tmp_path / "out", "--collider", "sphere:radius=8,path=missing.csv") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.csv" in err[0] and "no such file" in err[0]
