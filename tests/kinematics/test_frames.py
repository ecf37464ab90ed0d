"""Affine frames: attached positions, their Jacobian, and the rigidity penalty (docs/physics.md section 3)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesim.errors import FacesimError
from facesim.kinematics.frames import (
    RigidityTerm,
    attached_jacobian,
    attached_positions,
    frame_to_matrix,
    identity_frame,
    matrix_to_frame,
    psd_project,
    rigidity_penalty,
)


def central_gradient(f, q, h=1e-5):
    g = np.zeros_like(q)
    for i in range(len(q)):
        e = np.zeros_like(q)
        e[i] = h
        g[i] = (f(q + e) - f(q - e)) / (2 * h)
    return g


def central_jacobian(f, q, h=1e-5):
    """Columns d f / d q_i of a vector function ``f``."""
    cols = []
    for i in range(len(q)):
        e = np.zeros_like(q)
        e[i] = h
        cols.append((f(q + e) - f(q - e)) / (2 * h))
    return np.stack(cols, axis=-1)


def random_frame(rng, scale=0.3):
    M = np.eye(3) + scale * rng.normal(size=(3, 3))
    return np.concatenate([M.ravel(), 10.0 * rng.normal(size=3)])


def rigid_frame(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = 20.0 * rng.normal(size=3)
    return matrix_to_frame(T)


def test_frame_matrix_roundtrip_and_layout():
    q = np.arange(12.0)
    T = frame_to_matrix(q)
    assert np.array_equal(T[:3, :3], [[0, 1, 2], [3, 4, 5], [6, 7, 8]])   # M row-major
    assert np.array_equal(T[:3, 3], [9, 10, 11])
    assert np.array_equal(T[3], [0, 0, 0, 1])
    assert np.array_equal(matrix_to_frame(T), q)
    assert np.array_equal(frame_to_matrix(identity_frame()), np.eye(4))
    with pytest.raises(FacesimError):
        frame_to_matrix(np.zeros(11))


def test_attached_positions_are_linear_with_exact_jacobian():
    rng = np.random.default_rng(1)
    X = rng.normal(scale=50.0, size=(7, 3))
    q1, q2 = random_frame(rng), random_frame(rng)
    T = frame_to_matrix(q1)
    x = attached_positions(X, q1)
    assert x.shape == (7, 3)
    assert np.allclose(x, X @ T[:3, :3].T + T[:3, 3])
    a, b = 0.7, -1.9
    assert np.allclose(attached_positions(X, a * q1 + b * q2),
                       a * attached_positions(X, q1) + b * attached_positions(X, q2))
    J = attached_jacobian(X)
    assert J.shape == (21, 12) and J.nnz == 21 * 4
    assert np.allclose(J @ q1, x.ravel(), rtol=0, atol=1e-12)
    J_fd = central_jacobian(lambda q: attached_positions(X, q).ravel(), q1)
    assert np.linalg.norm(J_fd) > 0
    assert np.allclose(J.toarray(), J_fd, rtol=0, atol=1e-8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rigidity_derivatives_match_central_differences(seed):
    rng = np.random.default_rng(seed)
    q = random_frame(rng)
    value, grad, hess = rigidity_penalty(q)
    assert value > 0 and np.linalg.norm(grad) > 0 and np.linalg.norm(hess) > 0
    g_fd = central_gradient(lambda y: rigidity_penalty(y)[0], q)
    H_fd = central_jacobian(lambda y: rigidity_penalty(y)[1], q)
    assert np.linalg.norm(grad - g_fd) < 1e-6 * np.linalg.norm(grad)
    assert np.linalg.norm(hess - H_fd) < 1e-6 * np.linalg.norm(hess)
    assert np.allclose(hess, hess.T)
    assert not hess[9:].any() and not hess[:, 9:].any()       # translation-free


def test_rigidity_vanishes_at_any_rotation():
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rigid_frame(rng)
        value, grad, hess = rigidity_penalty(q)
        assert value < 1e-24
        assert np.abs(grad).max() < 1e-12
        assert np.linalg.eigvalsh(hess).min() > -1e-10          # a minimum: PSD without projection
    reflection = matrix_to_frame(np.diag([1.0, 1.0, -1.0, 1.0]))
    assert rigidity_penalty(reflection)[0] == 0.0             # orthogonal, det -1: also zero


def test_projected_hessian_is_psd():
    rng = np.random.default_rng(4)
    U, V = Rotation.random(2, random_state=rng).as_matrix()
    M = U @ np.diag([0.5, 1.2, 1.5]) @ V          # one axis compressed: C = MᵀM − I is indefinite
    q = np.concatenate([M.ravel(), rng.normal(size=3)])
    _, _, exact = rigidity_penalty(q)
    _, _, projected = rigidity_penalty(q, project=True)
    assert np.linalg.eigvalsh(exact).min() < -1e-3            # the case is indefinite to begin with
    lam = np.linalg.eigvalsh(projected)
    assert lam.min() > -1e-12 * lam.max()
    assert np.linalg.norm(projected) > 0
    # eigen-clamp keeps the positive part: projected − exact is PSD
    assert np.linalg.eigvalsh(projected - exact).min() > -1e-10 * lam.max()
    # a PSD matrix is left alone
    A = rng.normal(size=(5, 5))
    assert np.allclose(psd_project(A @ A.T), A @ A.T)


def test_rigidity_term_scales_with_weight():
    rng = np.random.default_rng(5)
    q = random_frame(rng)
    value, grad, hess = rigidity_penalty(q, project=True)
    term = RigidityTerm(2.5)
    assert term.energy(q) == pytest.approx(2.5 * value)
    assert np.allclose(term.gradient(q), 2.5 * grad)
    assert np.allclose(term.hessian(q), 2.5 * hess)
    assert np.allclose(term.hessian(q, project=False), 2.5 * rigidity_penalty(q)[2])
    with pytest.raises(FacesimError):
        RigidityTerm(-1.0)
