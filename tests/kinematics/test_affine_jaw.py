"""The affine-condyle jaw (Sifakis 2005 section 8: 12 frame coefficients, psi1..psi6 and rigidity
as penalties): the penalty's derivatives, zero on valid poses, the jaw-model interface, and a
Gauss-Newton fit that recovers a sliding-condyle pose from exact markers."""

from __future__ import annotations


import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import ControlSpace
from facesim.inverse.gauss_newton import FitOptions, fit_frame
from facesim.kinematics.affine_jaw import AffineCondyleJaw, default_weights
from facesim.kinematics.condyle import SlidingCondyleJaw, _rotation
from facesim.kinematics.frames import frame_to_matrix, psd_project
from facesim.kinematics.jaw_models import JAW_MODELS, JawModel, make_jaw_model
from tests.kinematics.test_frames import central_gradient, central_jacobian




@pytest.fixture(scope="module")
def jaw(model):
    return AffineCondyleJaw(model.jaw)


def valid_poses(model, rng, k=4):
    """``k`` sliding-condyle poses strictly inside the parameter bounds, as 4x4 transforms."""
    sc = SlidingCondyleJaw(model.jaw)
    lower, upper = sc.bounds.T
    return [sc.transform(lower + (upper - lower) * rng.uniform(0.05, 0.95, size=3)) for _ in range(k)]


def perturbed(jaw, T, rng, scale):
    return jaw.parameters(T) + scale * np.r_[rng.normal(size=9), 10.0 * rng.normal(size=3)]


def test_is_a_jaw_model_registered_by_name(model, jaw):
    assert isinstance(jaw, JawModel) and "affine-condyle" in JAW_MODELS
    made = make_jaw_model(model, "affine-condyle")
    assert isinstance(made, AffineCondyleJaw) and made.n_params == 12 == len(made.param_names)
    assert jaw.bounds.shape == (12, 2) and np.all(jaw.bounds[:, 0] < jaw.rest) and np.all(jaw.rest < jaw.bounds[:, 1])
    np.testing.assert_array_equal(jaw.transform(), np.eye(4))
    np.testing.assert_array_equal(jaw.transform(jaw.rest), np.eye(4))
    rng = np.random.default_rng(0)
    q = perturbed(jaw, np.eye(4), rng, 0.2)
    np.testing.assert_array_equal(jaw.transform(q), frame_to_matrix(q))
    np.testing.assert_array_equal(jaw.parameters(jaw.transform(q)), q)
    # the Jacobian is that of transform (linear in q): constant, and exact against differences
    dT = jaw.jacobian(q)
    np.testing.assert_allclose(dT, central_jacobian(jaw.transform, q), atol=1e-9)
    np.testing.assert_array_equal(dT, jaw.jacobian(None))
    with pytest.raises(FacesimError, match="12 finite affine coefficients"):
        jaw.transform(np.zeros(3))


def test_penalty_gradient_and_hessian_match_central_differences(model, jaw):
    rng = np.random.default_rng(1)
    for T in valid_poses(model, rng):
        for scale in (0.02, 0.2):   # near a valid pose (mostly psi1..psi3 and rigidity), and far off
            q = perturbed(jaw, T, rng, scale)
            value, grad, hess = jaw.penalty(q, project=False)
            assert value > 0 and np.linalg.norm(grad) > 1e-3 and np.linalg.norm(hess) > 1e-3
            g_fd = central_gradient(lambda p: jaw.penalty(p)[0], q, h=1e-6)
            np.testing.assert_allclose(grad, g_fd, rtol=1e-5, atol=1e-6 * np.abs(g_fd).max())
            H_fd = central_jacobian(lambda p: jaw.penalty(p)[1], q, h=1e-6)
            np.testing.assert_allclose(hess, H_fd, rtol=1e-5, atol=1e-6 * np.abs(H_fd).max())
            # the default Hessian is the PSD projection of the exact one (the rigidity part)
            _, g2, H2 = jaw.penalty(q)
            np.testing.assert_array_equal(g2, grad)
            assert np.linalg.eigvalsh(H2).min() > -1e-8 * np.abs(H2).max()
            np.testing.assert_allclose(H2, psd_project(H2), atol=1e-8 * np.abs(H2).max())


def test_penalty_is_zero_on_sliding_condyle_poses_and_positive_off_them(model, jaw):
    rng = np.random.default_rng(2)
    sc = SlidingCondyleJaw(model.jaw)
    for T in valid_poses(model, rng) + [np.eye(4), sc.transform([model.jaw.max_opening, sc.d, sc.d])]:
        value, grad, _ = jaw.penalty(jaw.parameters(T))
        assert value < 1e-20 and np.abs(grad).max() < 1e-9
    T = valid_poses(model, rng, 1)[0]
    q = jaw.parameters(T)
    u, v, w = sc.u, sc.v, sc.w
    off_track = q.copy()
    off_track[9:] += 0.1 * w                     # 0.1 mm off the track plane: psi2 = 0.1
    beyond = jaw.parameters(sc.transform([0.3, 0.0, 0.0]))
    beyond[9:] -= 0.5 * v                        # condyles 0.5 mm behind the back of their tracks
    stretched = q.copy()
    stretched[:9] = (np.diag([1.001, 1.0, 1.0]) @ T[:3, :3]).ravel()   # 0.1 % non-rigid
    sideways = jaw.parameters(sc.transform([0.2, 3.0, 3.0]))
    sideways[9:] += 0.2 * u                      # midpoint off-centre between the tracks: psi3
    weights = default_weights(model.jaw)
    assert jaw.penalty(off_track)[0] == pytest.approx(0.01, rel=1e-9)
    assert jaw.penalty(beyond)[0] == pytest.approx(2 * 0.25, rel=1e-9)
    assert jaw.penalty(sideways)[0] == pytest.approx(0.04, rel=1e-9)
    C = T[:3, :3].T @ np.diag([1.001, 1.0, 1.0]) ** 2 @ T[:3, :3] - np.eye(3)
    assert jaw.penalty(stretched)[0] >= weights[0] * np.sum(C**2) > 1e-4   # the psi terms add to it
    # beyond the maximum opening: psi6 below -s, weighted by the incisor reach squared (mm^2)
    wide = jaw.parameters(sc.transform([model.jaw.max_opening, sc.d, sc.d]))
    R = np.eye(4)
    R[:3, :3] = _rotation(sc.u, 0.05)            # opens 0.05 rad more about u
    R[:3, 3] = sc.m - R[:3, :3] @ sc.m
    over = jaw.parameters(frame_to_matrix(wide) @ R)
    psi = jaw.psi(over)
    assert psi[5] < -sc.s
    assert jaw.penalty(over)[0] == pytest.approx(weights[6] * (psi[5] + sc.s) ** 2
                                                  + (psi[3] - sc.d) ** 2 * (psi[3] > sc.d)
                                                  + (psi[4] - sc.d) ** 2 * (psi[4] > sc.d), rel=1e-6)


def test_default_weights_make_the_penalty_a_squared_displacement_in_mm(model, jaw):
    """Closing 1e-3 rad beyond the rest pose (psi6 > 0) moves the incisor by sqrt(penalty) mm; so
    does a tilt of the condyle axis out of the track plane move each condyle."""
    sc = SlidingCondyleJaw(model.jaw)
    for axis, point in ((sc.u, model.jaw.incisor), (sc.v, model.jaw.condyle_left)):
        R = np.eye(4)
        R[:3, :3] = _rotation(axis, -1e-3)
        R[:3, 3] = sc.m - R[:3, :3] @ sc.m
        moved = np.linalg.norm(R[:3, :3] @ point + R[:3, 3] - point)
        assert np.sqrt(jaw.penalty(jaw.parameters(R))[0]) == pytest.approx(moved, rel=1e-3)


# --- the inverse solver on the box model ------------------------------------------------------------
@pytest.fixture(scope="module")
def box_sims(box_model):
    options = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
    return (FaceSimulator(box_model, options, jaw_model=SlidingCondyleJaw(box_model.jaw)),
            FaceSimulator(box_model, options, jaw_model=AffineCondyleJaw(box_model.jaw)))


def test_control_space_has_twelve_jaw_columns(box_sims, box_model):
    _, sim = box_sims
    space = ControlSpace.of(sim)
    assert space.n_jaw == 12 and space.size == box_model.n_muscles + 12
    assert space.names(box_model, sim.jaw_model)[-12:] == list(AffineCondyleJaw.param_names)
    np.testing.assert_array_equal(space.vector(Controls([0.0, 0.0]))[-12:], sim.jaw_model.rest)


def test_fit_recovers_a_sliding_condyle_pose_and_activations(box_sims, box_model):
    sliding, affine = box_sims
    truth = Controls([0.6, 0.5], jaw=[0.15, 2.0, 1.5])
    T_true = sliding.jaw_model.transform(truth.jaw)
    targets = box_model.marker_positions(sliding.equilibrium(truth).x)
    start = Controls([0.0, 0.0], jaw=affine.jaw_model.rest)
    # 12 jaw unknowns and 6 markers: the penalties pin what the markers leave free; the exact
    # markers are fitted to a noise level of 1e-3 mm (the resolution stop of the fit)
    fit = fit_frame(affine, targets, start, options=FitOptions(noise=1e-3, max_steps=8))
    rep = fit.report
    T = affine.jaw_model.transform(fit.controls.jaw)
    R_err = T[:3, :3] @ T_true[:3, :3].T
    angle = np.arccos(np.clip(0.5 * (np.trace(R_err) - 1.0), -1.0, 1.0))
    incisor = box_model.jaw.incisor
    incisor_err = np.linalg.norm(T[:3, :3] @ incisor + T[:3, 3] - (T_true[:3, :3] @ incisor + T_true[:3, 3]))
    assert rep.stop_reason == "converged" and rep.marker_rms < 1e-3, rep
    assert angle < 1e-3 and incisor_err < 0.01, (angle, incisor_err)   # rad, mm
    np.testing.assert_allclose(fit.controls.a, truth.a, atol=2e-3)
    assert affine.jaw_model.penalty(fit.controls.jaw)[0] < 1e-5   # mm^2: within ~3e-3 mm of a valid pose
    assert all(np.diff(rep.objective) < 0)
