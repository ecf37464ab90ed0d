"""``facesim jaw markerless {dataset,train,retarget,predict,eval}`` round trip on the shipped
coarse face (issue 17): small datasets, one-line errors, predict from simulate's skin meshes."""

import json

import numpy as np
import pytest

from facesim._files import MESHES
from facesim.cli import main
from facesim.jaw.markerless_data import load_data

MODEL = MESHES / "face_coarse.npz"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from facesim.jaw.model_rig import model_motion
    from facesim.model import load_model

    tmp = tmp_path_factory.mktemp("markerless")
    run = lambda *a: main(["jaw", "markerless", *map(str, a)])  # noqa: E731
    # poses a few frames apart along a generated session (warm starts stay close: seconds, not
    # minutes, per dataset; random expressions, tested in tests/test_markerless_dataset.py, cost
    # several times more); the test frames in between the training ones
    poses = model_motion(load_model(MODEL).jaw, seed=2).poses
    np.savez(tmp / "P.npz", poses=poses[120:260:10])
    np.savez(tmp / "Q.npz", poses=poses[125:245:20])
    assert run("dataset", "--model", MODEL, "--poses", tmp / "P.npz", "--expressions", "none",
               "-o", tmp / "D.npz", "-q") == 0
    assert run("dataset", "--model", MODEL, "--poses", tmp / "Q.npz", "--expressions", "none",
               "-o", tmp / "T.npz", "-q") == 0
    assert run("train", "--data", tmp / "D.npz", "-o", tmp / "P.npz") == 0
    return tmp, run


def test_eval_json_and_table(files, capsys):
    tmp, run = files
    capsys.readouterr()
    assert run("eval", "--predictor", tmp / "P.npz", "--data", tmp / "T.npz", "--json") == 0
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == 6 and set(r) >= {"predictor", "baseline", "frames"}
    for k in ("predictor", "baseline"):
        s = r[k]
        assert 0 <= s["mean_mm"] <= s["p95_mm"] <= s["max_mm"] + 1e-12
    assert r["predictor"]["mean_mm"] < r["baseline"]["mean_mm"]      # 14 frames already beat Procrustes
    assert run("eval", "--predictor", tmp / "P.npz", "--data", tmp / "T.npz") == 0
    out = capsys.readouterr().out
    assert "predictor" in out and "baseline" in out and "mean mm" in out


def test_predict_writes_a_jaw_simulate_reads(files, capsys):
    """predict -> jaw.csv in the rigid form of simulate --jaw: replaying it places the jaw at the
    predicted poses, within the predictor's error of the dataset's true ones."""
    tmp, run = files
    assert run("predict", "--predictor", tmp / "P.npz", "--data", tmp / "T.npz", "--model", MODEL,
               "-o", tmp / "jaw.csv") == 0
    from facesim.controls_io import read_jaw_csv
    from facesim.model import load_model
    from facesim.se3 import vertex_errors

    model = load_model(MODEL)
    lines = (tmp / "jaw.csv").read_text().splitlines()
    assert lines[0] == "frame,rx,ry,rz,tx,ty,tz,ok" and len(lines) == 7
    (tmp / "jaw_rigid.csv").write_text("\n".join(",".join(l.split(",")[:7]) for l in lines) + "\n")
    _, T = read_jaw_csv(tmp / "jaw_rigid.csv", model, "rigid")
    with np.load(tmp / "jaw_poses.npz") as z:
        poses = z["poses"]
    assert np.abs(T - poses).max() < 1e-6                     # the CSV's rotation vectors are the poses
    d = load_data(tmp / "T.npz")
    err = vertex_errors(poses, d.poses, d.bone_rest)
    assert err.mean() < 2.0                                   # mm; eval's predictor figure


def test_predict_from_simulated_skin_meshes(files, tmp_path):
    """--skin DIR: the skin PLYs simulate writes (the model's topology) give the same prediction as
    the dataset's feature points of the same frames."""
    tmp, run = files
    d = load_data(tmp / "T.npz")
    jaw = tmp_path / "jaw.csv"
    from scipy.spatial.transform import Rotation

    from facesim.model import load_model

    model = load_model(MODEL)
    c = model.jaw.midpoint
    rows = ["frame,rx,ry,rz,tx,ty,tz"]
    for k, T in enumerate(d.poses[:3]):
        rv = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        tr = T[:3, 3] - c + T[:3, :3] @ c
        rows.append(",".join([str(k), *(f"{v:.12g}" for v in (*rv, *tr))]))
    jaw.write_text("\n".join(rows) + "\n")
    acts = tmp_path / "a.csv"
    acts.write_text("frame\n0\n1\n2\n")
    assert main(["simulate", "--model", str(MODEL), "--activations", str(acts), "--jaw", str(jaw),
                 "-o", str(tmp_path / "sim"), "-q"]) == 0
    assert run("predict", "--predictor", tmp / "P.npz", "--skin", tmp_path / "sim" / "skin", "--model", MODEL,
               "-o", tmp_path / "skin_jaw.csv") == 0
    assert run("predict", "--predictor", tmp / "P.npz", "--data", tmp / "T.npz", "-o", tmp_path / "data_jaw.csv") == 0
    with np.load(tmp_path / "skin_jaw_poses.npz") as a, np.load(tmp_path / "data_jaw_poses.npz") as b:
        assert np.abs(a["poses"] - b["poses"][:3]).max() < 0.05   # mm / rad: same skin, same jaw


def test_retarget_and_errors(files, capsys):
    tmp, run = files
    assert run("retarget", "--predictor", tmp / "P.npz", "--calibration", tmp / "T.npz", "--frames", "0,2,4",
               "-o", tmp / "P2.npz") == 0
    assert run("eval", "--predictor", tmp / "P2.npz", "--data", tmp / "T.npz", "--json") == 0
    capsys.readouterr()
    # a dataset where a predictor is expected, and a missing file: one line naming the file
    assert run("eval", "--predictor", tmp / "T.npz", "--data", tmp / "T.npz") == 2
    err = capsys.readouterr().err
    assert "T.npz" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert run("predict", "--predictor", tmp / "nope.npz", "--data", tmp / "T.npz", "-o", tmp / "j.csv") == 2
    err = capsys.readouterr().err
    assert "nope.npz" in err and "no such file" in err
    assert run("retarget", "--predictor", tmp / "P.npz", "--calibration", tmp / "T.npz", "--frames", "0,9",
               "-o", tmp / "P3.npz") == 2
    assert "--frames" in capsys.readouterr().err


def test_example_05_reports_on_the_datasets(files):
    """examples/05_markerless_jaw.py on the small datasets: the single-subject table (its split by
    time extrapolates on 14 frames: only its shape is checked here; the full report is in
    benchmarks/RESULTS.md) and the never-trained-on subject retargeted from 5 poses, whose
    held-out frame the predictor places better than the Procrustes baseline."""
    import importlib.util
    import shutil

    tmp, _ = files
    db = tmp / "db"
    db.mkdir(exist_ok=True)
    shutil.copy(tmp / "D.npz", db / "canonical.npz")
    shutil.copy(tmp / "T.npz", db / "heldout.npz")
    path = MESHES.parent / "examples" / "05_markerless_jaw.py"
    spec = importlib.util.spec_from_file_location("ex05", path)
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    r = ex.main(["--data", str(db), "--subjects", "canonical", "--out", str(tmp / "ex05"), "--train-fraction", "0.7"])
    assert r["single"]["frames"] == 4
    assert all(np.isfinite(r["single"][k]["mean_mm"]) for k in ("predictor", "baseline"))
    held = r["heldout"]["retargeted"]
    assert held["frames"] == 1 and held["predictor"]["mean_mm"] < held["baseline"]["mean_mm"]
    assert (tmp / "ex05" / "markerless_errors.png").is_file()


def test_shipped_predictor_is_the_default(files, capsys):
    """Without --predictor, eval uses meshes/markerless_jaw.npz (multi-subject, simulated
    subjects, the shipped faces' layout): on the shipped coarse face's frames it beats Procrustes."""
    tmp, run = files
    capsys.readouterr()
    assert run("eval", "--data", tmp / "T.npz", "--json") == 0
    r = json.loads(capsys.readouterr().out)
    assert r["predictor"]["mean_mm"] < r["baseline"]["mean_mm"] / 3


def test_marker_predictor_and_the_jaw_prior_in_solve_mocap(files, tmp_path, capsys):
    """train --features markers reads the model's markers the dataset recorded; solve-mocap
    --jaw-prior runs with it on a capture of the model's layout (the frames written, the prior in
    run.json), and refuses a skin-feature predictor in one line."""
    tmp, run = files
    d = load_data(tmp / "D.npz")
    assert d.markers is not None and d.markers.positions.shape == (d.n_frames, 81, 3)
    assert run("train", "--data", tmp / "D.npz", "--features", "markers", "-o", tmp_path / "PM.npz") == 0
    capsys.readouterr()
    assert run("eval", "--predictor", tmp_path / "PM.npz", "--data", tmp / "T.npz", "--json") == 0
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == 6 and r["predictor"]["mean_mm"] < 2.0
    out = tmp_path / "solve"
    capture = MESHES / "demo_clip.c3d"
    code = main(["solve-mocap", "--model", str(MODEL), "--markers", str(capture), "--frames", "0:1",
                 "--jaw-prior", str(tmp_path / "PM.npz"), "--jaw-prior-sigma", "0.5", "-o", str(out), "-q"])
    assert code == 0
    lines = (out / "jaw.csv").read_text().splitlines()
    assert lines[0].startswith("frame,opening") and len(lines) == 3
    record = json.loads((out / "run.json").read_text())
    assert "jaw_prior" in json.dumps(record)
    capsys.readouterr()
    code = main(["solve-mocap", "--model", str(MODEL), "--markers", str(capture), "--frames", "0:1",
                 "--jaw-prior", str(tmp / "P.npz"), "-o", str(tmp_path / "bad"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "reads skin features" in err[0] and "P.npz" in err[0]
