"""The starting guess of an equilibrium (``FaceSimulator.predict``): the as-rigid-as-possible
kernels against numpy oracles; the local-global steps reproduce a rigid motion exactly, which
harmonic interpolation does not; a jaw turned far in one step starts from a less crushed guess
than harmonic interpolation alone gives."""

from __future__ import annotations

import numpy as np
import pytest

import facesim.fem.equilibrium as equilibrium_module
from facesim._kernels.arap import best_rotations, edge_covariances, rotated_edges_rhs
from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.kinematics.jaw_models import RigidJaw
from facesim.se3 import exp as se3_exp


def _edges(tets):
    e = np.sort(tets[:, [0, 1, 0, 2, 0, 3, 1, 2, 1, 3, 2, 3]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0).astype(np.int64)


def test_kernels_match_numpy(box_model):
    rng = np.random.default_rng(3)
    X = box_model.X
    x = X + rng.normal(scale=2.0, size=X.shape)
    e = _edges(box_model.tets)
    w = rng.uniform(0.5, 2.0, len(e))
    n = len(X)
    S = np.empty((n, 3, 3))
    edge_covariances(X, x, e, w, S)
    C = w[:, None, None] * np.einsum("ka,kb->kab", X[e[:, 0]] - X[e[:, 1]], x[e[:, 0]] - x[e[:, 1]])
    S_ref = np.zeros((n, 3, 3))
    np.add.at(S_ref, e[:, 0], C)
    np.add.at(S_ref, e[:, 1], C)
    assert np.abs(S_ref).max() > 1.0
    np.testing.assert_allclose(S, S_ref, rtol=1e-12, atol=1e-9)
    R = np.empty((n, 3, 3))
    best_rotations(S, R)
    np.testing.assert_allclose(R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # each R maximises tr(R S) among rotations: no random rotation does better
    best = np.einsum("nij,nji->n", R, S)
    for k in range(20):
        Q = se3_exp(np.r_[rng.normal(size=3), 0, 0, 0])[:3, :3]
        assert (np.einsum("ij,nji->n", Q, S) <= best + 1e-9).all()
    b = np.empty((n, 3))
    rotated_edges_rhs(X, R, e, w, b)
    v = w[:, None] * np.einsum("kab,kb->ka", 0.5 * (R[e[:, 0]] + R[e[:, 1]]), X[e[:, 0]] - X[e[:, 1]])
    b_ref = np.zeros((n, 3))
    np.add.at(b_ref, e[:, 0], v)
    np.add.at(b_ref, e[:, 1], -v)
    np.testing.assert_allclose(b, b_ref, rtol=1e-12, atol=1e-9)


def _harmonic_only(monkeypatch):
    monkeypatch.setattr(equilibrium_module, "PREDICT_MIN_J", -np.inf)


def test_rigid_motion_is_the_fixed_point(box_model, monkeypatch):
    """Both bones moved by one rigid motion (35 deg): harmonic interpolation bends the free flesh,
    the local-global steps bring it back onto the rigid motion."""
    sim = FaceSimulator(box_model)
    H = se3_exp(np.r_[0.2, 0.5, -0.3, 4.0, -3.0, 2.0])
    _harmonic_only(monkeypatch)
    guess = sim.predict(Controls(np.zeros(box_model.n_muscles)), transforms=(H, H))
    rigid = box_model.X @ H[:3, :3].T + H[:3, 3]
    err0 = np.abs(guess - rigid).max()
    assert err0 > 1.0   # mm: harmonic interpolation is not rotation-aware
    errors = [np.abs(sim._as_rigid_as_possible(box_model.X, guess, k) - rigid).max() for k in (1, 5, 40)]
    assert errors[0] < err0 and errors[1] < errors[0] and errors[2] < 1e-3 * err0, (err0, errors)


def test_a_far_jaw_turn_starts_less_crushed(box_model, monkeypatch):
    sim = FaceSimulator(box_model)
    controls = Controls(np.zeros(box_model.n_muscles), RigidJaw.from_rotation(box_model, 0.9))
    V0 = box_model.tet_volumes()
    refined = sim.predict(controls)
    with monkeypatch.context() as m:
        m.setattr(equilibrium_module, "PREDICT_MIN_J", -np.inf)
        harmonic = sim.predict(controls)
    elems = box_model.simulated
    j_h = (box_model.tet_volumes(harmonic) / V0)[elems].min()
    j_r = (box_model.tet_volumes(refined) / V0)[elems].min()
    assert j_h < equilibrium_module.PREDICT_MIN_J, j_h     # the case triggers the refinement
    assert j_r > j_h + 0.05, (j_h, j_r)
    # bones where the controls put them
    np.testing.assert_array_equal(refined[box_model.jaw_nodes], harmonic[box_model.jaw_nodes])
    np.testing.assert_array_equal(refined[box_model.cranium_nodes], box_model.X[box_model.cranium_nodes])


def test_small_motions_keep_the_harmonic_guess(box_model, monkeypatch):
    sim = FaceSimulator(box_model)
    controls = Controls(np.zeros(box_model.n_muscles), RigidJaw.from_rotation(box_model, 0.02))
    guess = sim.predict(controls)
    _harmonic_only(monkeypatch)
    np.testing.assert_array_equal(guess, sim.predict(controls))


def test_element_quality_counts_inverted_tets_and_finds_the_least_volume_ratio(box_model):
    """The compiled volume ratios against numpy's signed volumes over the simulated tets, with
    tets inverted on purpose; non-finite positions are reported, not measured."""
    from facesim.model import signed_volumes

    sim = FaceSimulator(box_model, jaw_model=RigidJaw())
    rng = np.random.default_rng(8)
    x = box_model.X + rng.normal(scale=3.0, size=box_model.X.shape)
    T = box_model.tets[sim.elems]
    J = signed_volumes(x, T) / signed_volumes(box_model.X, T)
    assert (J <= 0).sum() >= 3   # the noise inverted some
    inverted, low = sim.element_quality(x)
    assert inverted == int((J <= 0).sum())
    assert low == pytest.approx(J.min(), rel=1e-12, abs=1e-12)
    assert sim.element_quality(box_model.X) == (0, pytest.approx(1.0, abs=1e-12))
    x[3] = np.nan
    inverted, low = sim.element_quality(x)
    assert inverted == -1 and np.isnan(low)


@pytest.mark.parametrize("head", ["none", "rotated", "sheared"])
def test_force_scale_of_the_cold_start_needs_only_the_jaw_s_tets(head):
    """``force_scale`` leaves out the flesh a cold start moves rigidly: it equals the full energy's
    residual at the cold start (rest shape, bones placed) at either clamp, with the head still,
    rotated, or with a head transform a little off rigid (then every tet is strained: the full sum)."""
    from pathlib import Path

    from facesim.controls import rotation_about
    from facesim.fem.newton import Problem
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.model import load_model

    model = load_model(Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz")
    sim = FaceSimulator(model, jaw_model=SlidingCondyleJaw(model.jaw))
    assert sim._path_elastic is not None   # both clamps are exercised
    rng = np.random.default_rng(2)
    H = None
    if head != "none":
        H = rotation_about(np.array([0.05, -0.1, 0.08]), np.array([0.0, 10.0, 0.0]))
        H[:3, 3] += [1.0, -2.0, 0.5]
        if head == "sheared":
            H[:3, :3] = H[:3, :3] @ np.diag([1.0 + 3e-5, 1.0, 1.0])   # within the rigidity check's 1e-4
    c = Controls(rng.uniform(0, 1, model.n_muscles), np.array([0.15, 1.0, 2.0]), H)
    for path in (True, False):
        at = sim._at_path_clamp if path else (lambda p: p)
        prob = at(Problem(sim.terms, sim.system, sim.attached_positions(c), c.a))
        full = float(np.linalg.norm(prob.energy_and_gradient(prob.x_fixed)[1]))
        assert full > 1.0
        assert sim.force_scale(c, path=path) == pytest.approx(full, rel=1e-12)
    jaw_tets = sim._cold_flesh(True).elems
    assert 0 < len(jaw_tets) < len(sim.elems) / 4   # a fraction of the flesh
