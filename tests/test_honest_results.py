"""Issue 13: one contact set-up in the inverse solver, honest stop reasons in every output, and
numerical failures (SolverError) kept apart from user mistakes (FacesimError)."""

import csv
import json

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse.gauss_newton import STOP_REASONS, FitOptions, fit_frame
from facesim.inverse.tracking import TrackOptions, track
from facesim.kinematics.jaw_models import JawModel, RigidJaw, make_jaw_model
from facesim.session import Simulation

DIRECT = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def remote(box_model):
    """A target far from rest (large activations and jaw opening) on the box face."""
    sim = FaceSimulator(box_model, DIRECT, jaw_model="sliding-condyle")
    truth = Controls([0.9, 0.7], jaw=[0.25, 3.0, 3.0])
    return sim, truth, box_model.marker_positions(sim.equilibrium(truth).x)


def test_every_jaw_model_implements_the_protocol(box_model):
    for name in ("rigid", "sliding-condyle"):
        jaw = make_jaw_model(box_model, name)
        assert isinstance(jaw, JawModel)
        assert len(jaw.param_names) == jaw.n_params and np.shape(jaw.bounds) == (jaw.n_params, 2)
        assert jaw.jacobian(None).shape == (4, 4, jaw.n_params)
        v, g, H = jaw.penalty(None)
        assert v == 0.0 and g.shape == (jaw.n_params,) and H.shape == (jaw.n_params,) * 2
        np.testing.assert_allclose(jaw.transform(None), np.eye(4), atol=1e-12)
    condyle = make_jaw_model(box_model, "sliding-condyle")
    assert condyle.param_names == ("opening", "right_slide", "left_slide")
    q = np.array([0.2, 2.0, 1.0])   # right and left slides differ: the order is visible
    np.testing.assert_allclose(condyle.parameters(condyle.transform(q)), q, atol=1e-9)
    assert RigidJaw().n_params == 0


def test_a_forced_failure_is_reported_not_converged(remote, box_model, tmp_path):
    sim, _, target = remote
    rest = Controls(np.zeros(2), jaw=np.zeros(3))
    fit = fit_frame(sim, target, rest, options=FitOptions(max_steps=1, noise=0.01))
    assert fit.report.stop_reason == "step_limit" and not fit.report.converged
    assert fit.report.to_dict()["converged"] is False
    ok = fit_frame(sim, target, rest, options=FitOptions(max_steps=8, noise=0.01))
    assert ok.report.stop_reason == "converged" and ok.report.converged
    assert set(STOP_REASONS) >= {fit.report.stop_reason, ok.report.stop_reason}

    s = track(sim, [0, 1], np.array([target, target]), tmp_path,
              options=TrackOptions(fit=FitOptions(max_steps=1, noise=0.01), head="none"), progress=False)
    assert 0 in s["unconverged_frames"] and s["stop_reasons"]["step_limit"] >= 1
    rows = _rows(tmp_path / "frames.csv")
    assert rows[0]["converged"] == "0" and rows[0]["stop_reason"] == "step_limit"
    assert [int(r["frame"]) for r in rows if r["converged"] == "0"] == s["unconverged_frames"]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["unconverged_frames"] == s["unconverged_frames"]
    assert report["unconverged_reasons"]["0"] == "step_limit"


def test_solve_mocap_warns_about_unconverged_frames(remote, box_model, box_model_path, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    _, _, target = remote
    write_trc(tmp_path / "m.trc", np.arange(2), list(box_model.markers.names), np.array([target, target]), fps=30.0)
    out = tmp_path / "out"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.01", "--solver", "direct", "--max-steps", "1", "-q"]) == 0
    captured = capsys.readouterr()
    assert "contact: lips on, teeth on" in captured.out   # the box has lip surfaces and lower teeth
    warning = [ln for ln in captured.err.splitlines() if "did not converge" in ln]
    assert len(warning) == 1 and "frame 0 (step_limit)" in warning[0], captured.err
    assert _rows(out / "frames.csv")[0]["stop_reason"] == "step_limit"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"),
                 "-o", str(tmp_path / "o2"), "--no-contact", "--head", "none", "--solver", "direct", "-q"]) == 0
    assert "contact: off (--no-contact)" in capsys.readouterr().out
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"),
                 "-o", str(tmp_path / "o3"), "--lip-contact", "--no-contact", "-q"]) == 2
    assert "--no-contact: excludes" in capsys.readouterr().err


def test_a_user_mistake_is_not_a_failed_frame(box_model):
    # teeth contact on a model without teeth: one-line FacesimError when the set-up is made, not a
    # silently failed frame in every step
    toothless = box_model.with_(colliders=())
    with pytest.raises(FacesimError, match="teeth contact: the model has no teeth"):
        Simulation(toothless, teeth_contact=True)
    lipless = box_model.with_(lip_upper=np.zeros((0, 3), np.int32), lip_lower=np.zeros((0, 3), np.int32))
    with pytest.raises(FacesimError, match="lip contact: the model has no upper and lower lip surfaces"):
        Simulation(lipless, lip_contact=True)
    assert not issubclass(SolverError, FacesimError) and not issubclass(FacesimError, SolverError)


def test_simulate_names_why_a_frame_stopped(box_model, tmp_path):
    from facesim.simulate import SimulateOptions, simulate

    options = SimulateOptions(newton=NewtonOptions(linear_solver="direct", max_iterations=1, settle_iterations=0))
    s = simulate(box_model, np.array([[0.9, 0.9]]), tmp_path, options=options, progress=False)
    row = _rows(tmp_path / "frames.csv")[0]
    assert row["converged"] == "0" and row["stop_reason"] in ("iteration_limit", "line_search_failed")
    assert s["unconverged_frames"] == [0] and s["unconverged_reasons"]["0"] == row["stop_reason"]


def test_a_solver_failure_is_a_flagged_frame_and_no_warm_start(box_model, monkeypatch):
    sim = Simulation(box_model, newton=NewtonOptions(linear_solver="direct"))
    good = sim.step({"lip_L": 0.2} if "lip_L" in box_model.muscles.names else np.full(2, 0.2))
    assert good.converged and sim.last is good

    def broken(*args, **kwargs):
        raise SolverError("linear solve: CG did not reach rtol 1e-06 in 400 iterations")

    monkeypatch.setattr(sim.simulator, "equilibrium", broken)
    bad = sim.step(np.full(2, 0.4))
    assert not bad.converged and "CG did not reach" in bad.error
    assert sim.last is good   # the failed frame is not the next warm start


def test_simulate_reports_inverted_tets_and_min_J(box_model, tmp_path):
    from facesim.simulate import simulate

    s = simulate(box_model, np.array([[0.0, 0.0], [0.5, 0.5]]), tmp_path, progress=False)
    rows = _rows(tmp_path / "frames.csv")
    assert [r["inverted_tets"] for r in rows] == ["0", "0"]
    assert [r["stop_reason"] for r in rows] == ["converged", "converged"] and s["stop_reasons"] == {"converged": 2}
    assert float(rows[0]["min_J"]) == pytest.approx(1.0, abs=1e-9)   # the rest shape
    assert 0.0 < float(rows[1]["min_J"]) < 1.0 and s["frames_with_inverted_tets"] == []
    # measured with the contact off: finite on the box (it has lips and teeth), NaN without the surfaces
    assert float(rows[1]["lip_penetration_mm"]) >= 0.0 and float(rows[1]["teeth_penetration_mm"]) >= 0.0
    lipless = box_model.with_(lip_upper=np.zeros((0, 3), np.int32), lip_lower=np.zeros((0, 3), np.int32))
    simulate(lipless, np.zeros((1, 2)), tmp_path / "lipless", progress=False)
    row = _rows(tmp_path / "lipless" / "frames.csv")[0]
    assert row["lip_penetration_mm"] == "nan" and row["teeth_penetration_mm"] == "nan"
