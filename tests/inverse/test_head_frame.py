"""The head frame solved with the other controls (``--head solve``): the frame's algebra against
central differences, recovery of a known head pose with known controls, tracking, resume, CLI."""

import numpy as np
import pytest

from facesim.controls import Controls, rotation_about
from facesim.controls_io import read_head_poses
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse.gauss_newton import FitOptions, fit_frame
from facesim.inverse.head_frame import HeadFrame
from facesim.inverse.tracking import TrackOptions, track
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import MarkerSet
from tests.conftest import interrupt_frame_solves, one_numba_thread

DIRECT = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from one_numba_thread()   # resumed runs compare bit for bit


def _pose(rotvec, centre, shift):
    T = rotation_about(rotvec, centre)
    T[:3, 3] += shift
    return T


@pytest.fixture(scope="module")
def spread(box_model):
    """The box with 40 skin markers over all its sides (2 of them head markers on the back), and
    4 frames of known controls seen through a known head motion."""
    rng = np.random.default_rng(3)
    skin_c = box_model.X[box_model.skin].mean(axis=1)
    back = np.flatnonzero(skin_c[:, 2] < skin_c[:, 2].min() + 0.1)
    others = np.setdiff1d(np.arange(len(box_model.skin)), back)
    tri = np.r_[rng.choice(back, 2, replace=False), rng.choice(others, 38, replace=False)]
    head = np.zeros(40, bool)
    head[:2] = True
    markers = MarkerSet(names=[f"m{j:02d}" for j in range(40)], triangle=tri, bary=rng.dirichlet(np.ones(3), 40),
                        offset=np.zeros(40), head=head)
    model = box_model.with_(markers=markers)
    sim = FaceSimulator(model, DIRECT, jaw_model=SlidingCondyleJaw(model.jaw))
    truth = [Controls([0.15 * k, 0.1 * k], jaw=[0.02 * k, 0.3 * k, 0.3 * k]) for k in range(4)]
    c = model.marker_positions().mean(axis=0)
    poses = [_pose([0.02 * k, -0.03 * k, 0.01 * k], c, [1.0 * k, -0.5 * k, 0.8 * k]) for k in range(4)]
    face = np.array([model.marker_positions(sim.equilibrium(t).x) for t in truth])
    P = np.einsum("fij,frj->fri", np.array(poses)[:, :3, :3], face) + np.array(poses)[:, None, :3, 3]
    return sim, truth, poses, P


def test_frame_algebra_matches_central_differences(box_model):
    rng = np.random.default_rng(0)
    hf = HeadFrame.of(box_model)
    T = _pose([0.1, -0.2, 0.05], [1.0, 2.0, 3.0], [4.0, -1.0, 2.0])
    T[:3, :3] += 0.01 * rng.normal(size=(3, 3))            # a little strain
    f = hf.coefficients(T)
    np.testing.assert_allclose(hf.matrix(f), T, atol=1e-12)
    P = rng.normal(size=(7, 3)) * 20.0
    np.testing.assert_allclose(hf.apply(P, f), P @ T[:3, :3].T + T[:3, 3], atol=1e-10)
    dP = rng.normal(size=(21, 2))                           # two other controls' head-frame derivatives
    J = hf.jacobian(P, f, dP)
    M = T[:3, :3]
    np.testing.assert_allclose(J[:, :2], np.einsum("ij,rjc->ric", M, dP.reshape(7, 3, 2)).reshape(21, 2),
                               atol=1e-12)
    h = 1e-6
    for k in range(12):
        e = np.zeros(12)
        e[k] = h
        col = (hf.apply(P, f + e) - hf.apply(P, f - e)).ravel() / (2 * h)
        np.testing.assert_allclose(J[:, 2 + k], col, atol=1e-6)
    v, g, H = hf.penalty(f, project=False)
    for k in range(12):
        e = np.zeros(12)
        e[k] = h
        vp, gp, _ = hf.penalty(f + e, project=False)
        vm, gm, _ = hf.penalty(f - e, project=False)
        assert g[k] == pytest.approx((vp - vm) / (2 * h), rel=1e-5, abs=1e-6)
        np.testing.assert_allclose(H[:, k], (gp - gm) / (2 * h), rtol=1e-5, atol=1e-5)
    assert v > 0 and hf.weight == pytest.approx(0.25 * hf.radius ** 2)
    # a rigid frame is its own rigid part, with zero strain; a stretched one reports its stretch
    R = _pose([0.1, -0.2, 0.05], hf.centre + 3.0, [4.0, -1.0, 2.0])
    Rr, strain = hf.rigid(hf.coefficients(R))
    np.testing.assert_allclose(Rr, R, atol=1e-12)
    assert strain < 1e-12 and hf.penalty(hf.coefficients(R))[0] < 1e-20
    S = R.copy()
    S[:3, :3] = R[:3, :3] @ np.diag([1.002, 1.0, 1.0])
    Sr, strain = hf.rigid(hf.coefficients(S))
    assert strain == pytest.approx(0.002, rel=1e-6)
    np.testing.assert_allclose(Sr[:3, :3], R[:3, :3], atol=1e-12)
    np.testing.assert_allclose(hf.apply(hf.centre[None], hf.coefficients(Sr)),
                               hf.apply(hf.centre[None], hf.coefficients(S)), atol=1e-12)   # the centre stays


def test_fit_recovers_controls_and_head_pose(spread):
    sim, truth, poses, P = spread
    k = 3
    fit = fit_frame(sim, P[k], Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]), options=FitOptions(noise=0.01, max_steps=12),
                    head_frame=np.eye(4))
    assert fit.report.converged and fit.report.marker_rms < 5e-3   # the noise level 0.01 mm stops it
    np.testing.assert_allclose(fit.controls.a, truth[k].a, atol=2e-3)
    assert abs(fit.controls.jaw[0] - truth[k].jaw[0]) < 2e-3
    hf = HeadFrame.of(sim.model)
    R, strain = hf.rigid(hf.coefficients(fit.head_frame))
    assert strain < 1e-4                                    # the rigidity penalty's work
    rest = sim.model.marker_positions()
    err = rest @ (R - poses[k])[:3, :3].T + (R - poses[k])[:3, 3]
    assert np.abs(err).max() < 0.01                         # mm over the markers
    # the markers a fit reports are in the targets' frame
    assert np.sqrt(np.mean(np.sum((fit.markers - P[k]) ** 2, axis=1))) == pytest.approx(fit.report.marker_rms)


def test_track_solves_the_head_and_writes_its_poses(spread, tmp_path):
    sim, truth, poses, P = spread
    P = P.copy()
    P[2, :2] = np.nan                                       # no head marker at all in one frame
    options = TrackOptions(fit=FitOptions(noise=0.01, max_steps=12), head="solve", outlier_floor=1.0)
    s = track(sim, np.arange(4), P, tmp_path, options=options, progress=False)
    assert s["status"] == "complete" and s["converged"] == 4
    A = np.loadtxt(tmp_path / "activations.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(A[:, 1:], [c.a for c in truth], atol=0.01)
    found = read_head_poses(tmp_path)
    assert sorted(found) == [0, 1, 2, 3]
    rest = sim.model.marker_positions()
    for k, T in found.items():
        d = rest @ (T - poses[k])[:3, :3].T + (T - poses[k])[:3, 3]
        assert np.abs(d).max() < 0.02, k
    strain = np.loadtxt(tmp_path / "head.csv", delimiter=",", skiprows=1)[:, -1]
    assert strain.max() < 1e-4
    R = np.genfromtxt(tmp_path / "residuals.csv", delimiter=",", names=True)
    assert R["rms"].max() < 0.01                            # in the capture's frame


def test_head_solve_resumes_to_the_uninterrupted_result(spread, tmp_path, monkeypatch):
    sim, truth, poses, P = spread
    options = TrackOptions(fit=FitOptions(noise=0.01, max_steps=6), head="solve")
    whole = tmp_path / "whole"
    track(sim, np.arange(4), P, whole, options=options, progress=False)
    cut = tmp_path / "cut"
    interrupt_frame_solves(monkeypatch, at=3)
    with pytest.raises(KeyboardInterrupt):
        track(sim, np.arange(4), P, cut, options=options, progress=False)
    monkeypatch.undo()
    with pytest.raises(Exception, match="other inputs: options"):   # another head mode is another run
        track(sim, np.arange(4), P, cut, options=TrackOptions(fit=options.fit, head="procrustes"), resume=True,
              progress=False)
    s = track(sim, np.arange(4), P, cut, options=options, resume=True, progress=False)
    assert s["reused_frames"] == 2 and s["warm_starts_restored"] == 1
    for name in ("head", "activations", "jaw"):
        assert (cut / f"{name}.csv").read_text() == (whole / f"{name}.csv").read_text(), name


def test_solve_mocap_cli_head_solve(spread, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    sim, truth, poses, P = spread
    path = sim.model.save(tmp_path / "spread.npz")
    trc = write_trc(tmp_path / "cap.trc", np.arange(4), list(sim.model.markers.names), P, 30.0)
    out = tmp_path / "out"
    code = main(["solve-mocap", "--model", str(path), "--markers", str(trc), "-o", str(out), "--head", "solve",
                 "--noise", "0.05", "--max-steps", "12", "--jaw-model", "sliding-condyle", "--quiet",
                 "--head-smoothing", "5"])
    err = capsys.readouterr().err
    assert code == 0 and "--head-smoothing" in err and "ignored" in err   # no smoothing of a solved head
    assert sorted(read_head_poses(out)) == [0, 1, 2, 3]
