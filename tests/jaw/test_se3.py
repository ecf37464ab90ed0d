"""SE(3) log/exp maps, errors and geodesic interpolation (facesim.se3)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesim import se3
from facesim.errors import FacesimError


def _twists(rng, n, angles):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return np.concatenate([np.asarray(angles)[:, None] * axis, rng.normal(scale=20.0, size=(n, 3))], axis=1)


@pytest.mark.parametrize("angles", [
    "random",
    [0.0, 1e-14, 1e-10, 1e-7, 1e-4, 0.0099999, 0.01, 0.0100001],               # near zero
    [np.pi - 1e-3, np.pi - 1e-6, np.pi - 1e-9, np.pi - 1e-12, np.pi],          # near a half turn
])
def test_exp_log_round_trip(angles):
    rng = np.random.default_rng(1)
    angles = rng.uniform(0.0, np.pi, 500) if angles == "random" else np.repeat(angles, 20)
    xi = _twists(rng, len(angles), angles)
    T = se3.exp(xi)
    # the rotation part agrees with an independent Rodrigues implementation
    assert np.abs(T[:, :3, :3] - Rotation.from_rotvec(xi[:, :3]).as_matrix()).max() < 1e-13
    assert se3.rigidity_error(T).max() < 1e-13
    back = se3.log(T)
    assert np.abs(se3.exp(back) - T).max() < 1e-12
    # log inverts exp below a half turn; at pi either axis sign is the same rotation
    below = angles < np.pi - 1e-7
    assert np.abs(back[below] - xi[below]).max() < 1e-9 * max(1.0, np.abs(xi).max())
    assert np.allclose(np.linalg.norm(back[:, :3], axis=1), angles, atol=1e-7)


def test_log_exp_from_poses():
    """Starting from poses (not twists): random rotations including 180-degree turns."""
    rng = np.random.default_rng(2)
    R = Rotation.random(200, random_state=3).as_matrix()
    R[:10] = Rotation.from_rotvec(np.pi * np.eye(3)[rng.integers(0, 3, 10)]).as_matrix()
    T = se3.from_rt(R, rng.normal(scale=30.0, size=(200, 3)))
    assert np.abs(se3.exp(se3.log(T)) - T).max() < 1e-12
    assert np.abs(se3.log(np.eye(4))).max() == 0.0


def test_single_and_batch_agree():
    rng = np.random.default_rng(4)
    xi = _twists(rng, 5, rng.uniform(0, 3, 5))
    assert se3.exp(xi[0]).shape == (4, 4)
    assert np.array_equal(se3.exp(xi)[3], se3.exp(xi[3]))
    assert np.allclose(se3.log(se3.exp(xi))[2], se3.log(se3.exp(xi[2])))
    assert np.allclose(se3.inverse(se3.exp(xi)) @ se3.exp(xi), np.eye(4), atol=1e-12)


def test_bad_shapes_are_refused():
    with pytest.raises(FacesimError, match="twist"):
        se3.exp(np.zeros(5))
    with pytest.raises(FacesimError, match="pose"):
        se3.log(np.eye(3))
    with pytest.raises(FacesimError, match="finite"):
        se3.exp(np.full(6, np.nan))


def test_interpolation_endpoints_and_constant_speed():
    rng = np.random.default_rng(5)
    A, B = se3.exp(_twists(rng, 2, [0.7, 2.9]))
    s = np.linspace(0.0, 1.0, 41)
    path = se3.interpolate(A, B, s)
    assert np.allclose(path[0], A, atol=1e-12) and np.allclose(path[-1], B, atol=1e-12)
    steps = np.linalg.norm(se3.log(se3.inverse(path[:-1]) @ path[1:]), axis=1)
    total = np.linalg.norm(se3.log(se3.inverse(A) @ B))
    assert steps.min() > 0
    assert np.allclose(steps, total / 40, rtol=1e-9)
    # a geodesic: the middle pose is the same halfway from either end
    mid = se3.interpolate(A, B, 0.5)
    assert np.allclose(se3.interpolate(B, A, 0.5), mid, atol=1e-10)
    assert se3.rigidity_error(path).max() < 1e-12


def test_vertex_errors_closed_forms():
    X = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 20.0, 0.0]])
    shift = np.eye(4)
    shift[:3, 3] = [3.0, 4.0, 0.0]                                       # every point moves 5 mm
    assert np.isclose(se3.vertex_errors(shift, np.eye(4), X), 5.0)
    turn = se3.exp(np.array([0.0, 0.0, np.pi / 2, 0, 0, 0]))            # quarter turn about z
    d = np.array([0.0, 10 * np.sqrt(2), 20 * np.sqrt(2)])
    w = np.array([1.0, 3.0, 0.0])
    assert np.isclose(se3.vertex_errors(turn, np.eye(4), X, w), (3 * d[1]) / 4)
    batch = se3.vertex_errors(np.stack([shift, turn]), np.eye(4), X)
    assert np.allclose(batch, [5.0, d.mean()])
    with pytest.raises(FacesimError, match="weights"):
        se3.vertex_errors(shift, np.eye(4), X, [1.0, -1.0, 0.0])
