"""Sliding-condyle jaw (Sifakis 2005 section 8, docs/physics.md section 3) on the shipped model's TMJ."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from facesim.kinematics.jaw_models import RigidJaw
from facesim.errors import FacesimError
from facesim.kinematics.condyle import KinematicTerm, SlidingCondyleJaw
from facesim.kinematics.frames import matrix_to_frame
from tests.kinematics.test_frames import central_gradient, central_jacobian




@pytest.fixture(scope="module")
def jaw(model):
    return SlidingCondyleJaw(model.jaw)


def apply(T, X):
    return np.asarray(X) @ T[:3, :3].T + T[:3, 3]


def random_valid_p(jaw, rng):
    lower, upper = jaw.bounds.T
    return lower + (upper - lower) * rng.uniform(size=3)


# --- sign conventions against the model's frame (w = v x u) -----------------------------------

def test_frame_of_the_shipped_model(jaw):
    assert np.allclose([jaw.u @ jaw.v, jaw.u @ jaw.w, jaw.v @ jaw.w], 0)
    assert jaw.v[1] < 0 and jaw.v[2] > 0          # track: forward and inclined downward
    assert jaw.w[1] > 0                           # track-plane normal points up
    assert jaw.u[0] > 0                           # right -> left is +x


def test_opening_makes_psi6_negative_and_sliding_makes_psi45_positive(model, jaw):
    # independent of this module: RigidJaw's hinge rotation, chin down
    T = RigidJaw.from_rotation(model, opening=0.3)
    assert apply(T, model.jaw.incisor)[1] < model.jaw.incisor[1] - 10
    psi = jaw.psi(matrix_to_frame(T))
    assert psi[5] == pytest.approx(-np.sin(0.3))
    assert np.allclose(psi[:5], 0, atol=1e-12)
    # a pure slide forward along the track
    T = np.eye(4)
    T[:3, 3] = 5.0 * model.jaw.track_direction
    psi = jaw.psi(matrix_to_frame(T))
    assert psi[3] == pytest.approx(5.0) and psi[4] == pytest.approx(5.0)
    assert np.allclose(psi[[0, 1, 2, 5]], 0, atol=1e-12)


# --- derivatives -------------------------------------------------------------------------------

def perturbed_frames(jaw, rng):
    """A nearly valid frame (some range terms inactive) and a far random affine one (all active)."""
    near = jaw.frame(random_valid_p(jaw, rng)) + 1e-3 * rng.normal(size=12)
    far = np.concatenate([(np.eye(3) + 0.3 * rng.normal(size=(3, 3))).ravel(), 20 * rng.normal(size=3)])
    return [near, far]


def test_psi_jacobian_matches_central_differences(jaw):
    rng = np.random.default_rng(0)
    for q in perturbed_frames(jaw, rng):
        J = jaw.psi_jacobian(q)
        J_fd = central_jacobian(jaw.psi, q)
        assert J.shape == (6, 12) and np.linalg.norm(J) > 0
        assert np.linalg.norm(J - J_fd) < 1e-6 * np.linalg.norm(J)
        assert np.abs(J).sum(axis=1).min() > 0      # every constraint depends on q


@pytest.mark.parametrize("seed", [1, 2])
def test_phi_kin_derivatives_match_central_differences(jaw, seed):
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.5, 2.0, size=7)
    for q in perturbed_frames(jaw, rng):
        value, grad, hess = jaw.phi_kin(q, weights)
        assert value > 0 and np.linalg.norm(grad) > 0 and np.linalg.norm(hess) > 0
        g_fd = central_gradient(lambda y: jaw.phi_kin(y, weights)[0], q)
        H_fd = central_jacobian(lambda y: jaw.phi_kin(y, weights)[1], q)
        assert np.linalg.norm(grad - g_fd) < 1e-6 * np.linalg.norm(grad)
        assert np.linalg.norm(hess - H_fd) < 1e-6 * np.linalg.norm(hess)


def test_phi_kin_range_terms_are_zero_inside_and_quadratic_outside(jaw):
    rng = np.random.default_rng(3)
    q = jaw.frame(random_valid_p(jaw, rng))
    value, grad, _ = jaw.phi_kin(q)
    assert value < 1e-20 and np.abs(grad).max() < 1e-9
    # slide both condyles 2 mm past the track end: psi4 = psi5 = d + 2, excess 2 mm each
    q = jaw.frame([0.2, jaw.d + 2.0, jaw.d + 2.0])
    w = np.array([0, 0, 0, 0, 1.0, 1.0, 0])
    assert jaw.phi_kin(q, w)[0] == pytest.approx(8.0)


def test_phi_kin_projected_hessian_is_psd(jaw):
    rng = np.random.default_rng(4)
    q = jaw.frame(random_valid_p(jaw, rng))
    q[:9] *= 0.6                                  # compressed: the rigidity Hessian is indefinite
    _, _, exact = jaw.phi_kin(q)
    _, _, projected = jaw.phi_kin(q, project=True)
    assert np.linalg.eigvalsh(exact).min() < -1e-3
    lam = np.linalg.eigvalsh(projected)
    assert lam.max() > 0 and lam.min() > -1e-10 * lam.max()
    term = KinematicTerm(jaw, weights=np.full(7, 2.0))
    assert term.energy(q) == pytest.approx(2.0 * jaw.phi_kin(q)[0])
    assert np.allclose(term.hessian(q), 2.0 * projected)


def test_transform_jacobian_matches_central_differences(jaw):
    rng = np.random.default_rng(5)
    for _ in range(3):
        p = random_valid_p(jaw, rng)
        p[2] = rng.uniform(0, jaw.d)             # unequal slides: the yaw enters
        dT = jaw.jacobian(p)
        dT_fd = central_jacobian(jaw.transform, p, h=1e-6)
        assert dT.shape == (4, 4, 3)
        for k in range(3):
            assert np.linalg.norm(dT[..., k]) > 0
            assert np.linalg.norm(dT[..., k] - dT_fd[..., k]) < 1e-6 * np.linalg.norm(dT[..., k])
        assert np.allclose(jaw.frame_jacobian(p), central_jacobian(jaw.frame, p, h=1e-6), atol=1e-7)


def test_parameter_penalty(jaw):
    rng = np.random.default_rng(6)
    value, grad, hess = jaw.penalty(random_valid_p(jaw, rng))
    assert value == 0 and not grad.any() and not hess.any()
    p = np.array([-0.1, jaw.d + 3.0, 5.0])
    value, grad, hess = jaw.penalty(p)
    assert value == pytest.approx(0.01 + 9.0)
    assert np.linalg.norm(grad) > 0
    assert np.allclose(grad, central_gradient(lambda y: jaw.penalty(y)[0], p), rtol=1e-6)
    assert np.allclose(hess, np.diag([2.0, 2.0, 0.0]))
    assert np.allclose(jaw.bounds, [[0, jaw.geometry.max_opening], [0, jaw.d], [0, jaw.d]])


# --- conversions -------------------------------------------------------------------------------

def test_rest_pose_is_identity(jaw):
    assert np.allclose(jaw.transform([0, 0, 0]), np.eye(4), atol=1e-15)
    assert np.allclose(jaw.transform(None), np.eye(4), atol=1e-15)
    assert jaw.n_params == 3 and jaw.name == "sliding-condyle"


def test_transform_is_valid_and_inverted_by_parameters(jaw):
    rng = np.random.default_rng(7)
    for _ in range(20):
        p = random_valid_p(jaw, rng)
        T = jaw.transform(p)
        M = T[:3, :3]
        assert np.allclose(M.T @ M, np.eye(3), atol=1e-12) and np.linalg.det(M) == pytest.approx(1.0)
        psi = jaw.psi(matrix_to_frame(T))
        assert np.abs(psi[:3]).max() < 1e-9
        assert psi[3] == pytest.approx(p[1], abs=1e-9)        # right slide
        assert psi[4] == pytest.approx(p[2], abs=1e-9)        # left slide
        assert psi[5] == pytest.approx(-np.sin(p[0]), abs=1e-12)
        assert np.allclose(jaw.parameters(T), p, atol=1e-9)
    # the left condyle sliding further forward turns the chin toward the right (-x)
    T = jaw.transform([0.2, 0.0, 10.0])
    assert apply(T, jaw.geometry.incisor)[0] < -1.0


def test_half_open_jaw_slides_the_condyles_along_the_track(model, jaw):
    geo = model.jaw
    T = jaw.transform([0.5, 12.0, 12.0])
    drop = geo.incisor[1] - apply(T, geo.incisor)[1]
    assert 35.0 <= drop <= 55.0                                # docs/physics.md: 46-51 mm at ~0.6 rad
    hinge_drop = geo.incisor[1] - apply(jaw.transform([0.5, 0.0, 0.0]), geo.incisor)[1]
    assert drop > hinge_drop + 5.0                             # translation adds to the hinge opening
    # the condyles translate 12 mm along the track, forward and down, not a pure rotation
    for c in (geo.condyle_right, geo.condyle_left):
        assert np.allclose(apply(T, c), c + 12.0 * geo.track_direction, atol=1e-9)
    psi = jaw.psi(matrix_to_frame(T))
    assert np.all(psi[3:] >= jaw.psi_lower[3:]) and np.all(psi[3:] <= jaw.psi_upper[3:])


def test_maximum_opening_matches_the_physics_reference(model, jaw):
    geo = model.jaw
    T = jaw.transform([geo.max_opening, geo.track_length, geo.track_length])
    drop = geo.incisor[1] - apply(T, geo.incisor)[1]
    assert 46.0 <= drop <= 51.0                                # max incisal opening, docs/physics.md section 3


def test_project_restores_a_perturbed_pose(jaw):
    rng = np.random.default_rng(8)
    p = np.array([0.3, 9.0, 5.0])
    T = jaw.transform(p)
    A = T.copy()
    A[:3, :3] += 0.01 * rng.normal(size=(3, 3))
    A[:3, 3] += 0.3 * rng.normal(size=3)
    assert np.abs(jaw.psi(matrix_to_frame(A))[:3]).max() > 0.05   # the perturbation is not valid
    P = jaw.project(A)
    assert np.abs(jaw.psi(matrix_to_frame(P))[:3]).max() < 1e-9
    assert np.allclose(P[:3, :3].T @ P[:3, :3], np.eye(3), atol=1e-12)
    q = jaw.parameters(P)
    assert abs(q[0] - p[0]) < 0.03 and np.abs(q[1:] - p[1:]).max() < 2.0
    assert np.allclose(jaw.project(P), P, atol=1e-12)          # idempotent
    assert np.allclose(jaw.project(T), T, atol=1e-12)          # valid poses are fixed


def test_project_arbitrary_affine_pair_is_valid_rigid_and_idempotent(jaw):
    rng = np.random.default_rng(9)
    for _ in range(3):
        A = np.eye(4)
        A[:3, :3] += 0.5 * rng.normal(size=(3, 3))
        A[:3, 3] = 15.0 * rng.normal(size=3)
        P = jaw.project(A)
        M = P[:3, :3]
        assert np.allclose(M.T @ M, np.eye(3), atol=1e-12) and np.linalg.det(M) > 0
        psi = jaw.psi(matrix_to_frame(P))
        assert np.abs(psi[:3]).max() < 1e-9
        assert np.all(psi[3:] >= jaw.psi_lower[3:] - 1e-9) and np.all(psi[3:] <= jaw.psi_upper[3:] + 1e-9)
        assert np.allclose(jaw.project(P), P, atol=1e-12)


def test_bad_input(model, jaw):
    with pytest.raises(FacesimError):
        jaw.transform([0.1, 2.0])
    with pytest.raises(FacesimError):
        jaw.psi(np.zeros(9))
    skewed = replace(model.jaw, track_direction=np.array([0.6, -0.48, 0.64]))
    with pytest.raises(FacesimError):
        SlidingCondyleJaw(skewed)
