"""Results that replay (issue 15, part 3): what ``solve-mocap`` writes as controls is within the
model's bounds exactly (clipped on output, reported), ``simulate --controls-from OUT`` reproduces the
solved frames, and ``solve-mocap --write-meshes`` writes per frame what ``simulate`` writes, from the
solve's own equilibria, consistently across an interrupted and resumed run.

On the synthetic box model (lip and teeth contact on, as solve-mocap defaults), direct solvers on
one thread, a capture whose orbicularis stays at rest and whose jaw never slides: activations and
jaw parameters on their lower bounds, which the penalty schedule overshoots slightly.
"""

import csv
import dataclasses
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.conftest import one_numba_thread

from facesim.cli import main
from facesim.model import Tissue

N_FRAMES = 6


one_thread = pytest.fixture(scope="module", autouse=True)(one_numba_thread)


@pytest.fixture(scope="module")
def capture(box_model, tmp_path_factory):
    """The model file and a TRC of a performance made by forward simulation (0.02 mm noise)."""
    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.fem.newton import NewtonOptions
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.mocap.io import write_trc

    folder = tmp_path_factory.mktemp("replay_inputs")
    box_model.save(folder / "model.npz")
    t = np.linspace(0.0, 1.0, N_FRAMES)
    A = np.stack([0.5 * np.sin(np.pi * t) ** 2, np.zeros_like(t)], axis=1)   # orbicularis at rest
    jaw = np.stack([0.06 * t, np.zeros_like(t), np.zeros_like(t)], axis=1)     # no slide
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8)),
                        jaw_model=SlidingCondyleJaw(box_model.jaw))
    P = np.array([box_model.marker_positions(sim.equilibrium(Controls(a, jaw=q)).x) for a, q in zip(A, jaw)])
    P += np.random.default_rng(3).normal(scale=0.02, size=P.shape)
    write_trc(folder / "capture.trc", np.arange(N_FRAMES), box_model.markers.names, P, fps=30.0)
    return folder


def solve(capture, out, *extra) -> int:
    return main(["solve-mocap", "--model", str(capture / "model.npz"), "--markers", str(capture / "capture.trc"),
                 "-o", str(out), "--head", "none", "--noise", "0.05", "--solver", "direct", "--write-meshes", "-q",
                 *extra])


@pytest.fixture(scope="module")
def solved(capture, tmp_path_factory):
    """The solve-mocap --write-meshes folder of the capture (do not modify; copy)."""
    out = tmp_path_factory.mktemp("replay_solve")
    assert solve(capture, out) == 0
    return out


def rows(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


# ------------------------------------------------------------------ 1. within the bounds exactly
def test_written_controls_are_within_the_bounds_exactly_and_the_clips_are_reported(solved, box_model):
    from facesim.controls_io import read_activations_csv, read_jaw_csv
    from facesim.kinematics.condyle import SlidingCondyleJaw

    A, Q = rows(solved / "activations.csv")[:, 1:], rows(solved / "jaw.csv")[:, 1:]
    lo, hi = SlidingCondyleJaw(box_model.jaw).bounds.T
    assert A.min() >= 0.0 and A.max() <= 1.0 and (Q >= lo).all() and (Q <= hi).all()
    clipped = json.loads((solved / "report.json").read_text())["clipped"]
    # the case the test is for: the solver's state left some bound behind, and the output clipped it
    assert clipped["activations"]["values"] + clipped["jaw"]["values"] > 0, clipped
    for part in ("activations", "jaw"):
        assert 0.0 <= clipped[part]["largest"] < 1e-2 and clipped[part]["frames"] <= N_FRAMES
    assert sum(v[0] + v[2] for v in clipped["per_frame"].values()) == \
        clipped["activations"]["values"] + clipped["jaw"]["values"]
    # clipped values sit on their bound; frames.csv keeps the solver's violation
    assert (A == 0.0).sum() >= clipped["activations"]["values"]
    with open(solved / "frames.csv") as f:
        violation = np.array([float(r["worst_violation"]) for r in csv.DictReader(f)])
    assert len(violation) == N_FRAMES and np.isfinite(violation).all()
    # simulate's readers accept the files as they are
    read_activations_csv(solved / "activations.csv", box_model.muscles.names)
    read_jaw_csv(solved / "jaw.csv", box_model, "sliding-condyle")


def test_a_value_on_a_bound_that_6_digits_cannot_hold_is_written_in_full():
    from facesim.inverse.tracking import _control_lines

    jaw_model = SimpleNamespace(bounds=np.array([[0.0, 0.6234567891], [-1.0, 2.0]]))
    a_line, jaw_line = _control_lines(7, np.array([0.0, 1.0, 0.25]), np.array([0.6234567891, 1.5]), jaw_model)
    assert a_line == "7,0,1,0.25\n"
    q = [float(v) for v in jaw_line.strip().split(",")[1:]]
    assert q == [0.6234567891, 1.5]   # rounding to 0.623457 would step over the bound


# ------------------------------------------------------------------ 2. simulate --controls-from
def test_simulate_controls_from_reproduces_the_solved_markers(solved, capture, tmp_path):
    from facesim.mocap.io import read_markers_csv

    out = tmp_path / "replay"
    assert main(["simulate", "--model", str(capture / "model.npz"), "--controls-from", str(solved), "-o", str(out),
                 "--solver", "direct", "-q"]) == 0
    replay, at_solve = read_markers_csv(out / "markers.csv"), read_markers_csv(solved / "markers.csv")
    assert list(replay.frames) == list(range(N_FRAMES)) and replay.names == at_solve.names
    error = np.linalg.norm(replay.P - at_solve.P, axis=2)
    print(f"replay: largest marker difference {error.max():.3g} mm")
    assert np.isfinite(error).all() and error.max() < 0.01, error.max()   # mm
    report = json.loads((out / "report.json").read_text())
    assert report["options"]["jaw_model"] == "sliding-condyle" and report["converged"] == N_FRAMES
    assert report["options"]["lip_contact"] and report["options"]["teeth_contact"]   # the solve's set-up
    # the solved markers themselves: the capture minus the residuals... within the residuals
    residuals = rows(solved / "residuals.csv")[:, 2:]
    assert np.nanmax(residuals) < 0.5


def test_controls_from_with_another_model_is_refused_in_one_line(solved, capture, box_model, tmp_path, capsys):
    other = dataclasses.replace(box_model, tissues=(Tissue("fat", 2e-3, 0.0, 0.1), Tissue("muscle", 2e-3, 0.0, 0.2)))
    other.save(tmp_path / "other.npz")
    assert main(["simulate", "--model", str(tmp_path / "other.npz"), "--controls-from", str(solved),
                 "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "another model" in err and "tissues" in err, err
    assert str(tmp_path / "other.npz") in err and err.count("fingerprint") == 2
    assert not (tmp_path / "out").exists()
    for extra in (["--activations", str(solved / "activations.csv")], ["--jaw-model", "rigid"]):
        assert main(["simulate", "--model", str(capture / "model.npz"), "--controls-from", str(solved),
                     "-o", str(tmp_path / "out"), *extra]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "--controls-from: excludes" in err, err
    assert main(["simulate", "--model", str(capture / "model.npz"), "-o", str(tmp_path / "out")]) == 2
    assert "--controls-from" in capsys.readouterr().err


# ------------------------------------------------------------------ 3. --write-meshes
def test_write_meshes_writes_a_skin_and_a_state_per_frame(solved, box_model):
    A, Q = rows(solved / "activations.csv"), rows(solved / "jaw.csv")
    assert sorted(p.name for p in (solved / "skin").iterdir()) == [f"frame_{k:05d}.ply" for k in range(N_FRAMES)]
    assert sorted(p.name for p in (solved / "state").iterdir()) == [f"frame_{k:05d}.npz" for k in range(N_FRAMES)]
    for k in range(N_FRAMES):
        with np.load(solved / "state" / f"frame_{k:05d}.npz") as z:
            assert set(z.files) >= {"x", "a", "jaw", "converged", "error", "frame"}
            assert z["x"].shape == box_model.X.shape and bool(z["converged"]) and int(z["frame"]) == k
            np.testing.assert_allclose(z["a"], A[k, 1:], atol=1e-6)   # the written (clipped) controls
            np.testing.assert_allclose(z["jaw"], Q[k, 1:], atol=1e-6)
    assert (solved / "markers.trc").is_file()


def test_a_resumed_write_meshes_run_keeps_its_frames_consistent(solved, capture, tmp_path, monkeypatch):
    """Interrupted after frame 3's meshes but before its log lines, then resumed: the same logs,
    states and markers as the uninterrupted run."""
    import facesim.inverse.tracking as tracking

    out = tmp_path / "resumed"
    save_warm = tracking._save_warm

    def stop_at_frame_3(path, k, start):
        if k == 3:
            raise KeyboardInterrupt
        save_warm(path, k, start)

    monkeypatch.setattr(tracking, "_save_warm", stop_at_frame_3)
    assert solve(capture, out) == 130
    assert (out / "state" / "frame_00003.npz").is_file() and len(rows(out / "activations.csv")) == 3
    monkeypatch.setattr(tracking, "_save_warm", save_warm)
    assert solve(capture, out, "--resume") == 0
    for name in ("activations.csv", "jaw.csv", "residuals.csv", "markers.csv"):
        assert (out / name).read_text() == (solved / name).read_text(), name
    for k in range(N_FRAMES):
        with np.load(out / "state" / f"frame_{k:05d}.npz") as got, \
                np.load(solved / "state" / f"frame_{k:05d}.npz") as want:
            np.testing.assert_allclose(got["x"], want["x"], rtol=0, atol=1e-9)
            assert np.array_equal(got["a"], want["a"]) and np.array_equal(got["jaw"], want["jaw"])
    assert sorted(p.name for p in (out / "skin").iterdir()) == [f"frame_{k:05d}.ply" for k in range(N_FRAMES)]
    # a skin lost since is drawn again from its state on resume
    (out / "skin" / "frame_00001.ply").unlink()
    shutil.copy(out / "report.json", tmp_path / "report.json")
    assert solve(capture, out, "--resume") == 0
    assert (out / "skin" / "frame_00001.ply").is_file()
