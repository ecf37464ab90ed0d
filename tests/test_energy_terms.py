"""Every energy term against central differences, through the one EnergyTerm protocol.

Adding a term is adding one line to ``CASES``: a factory returning the term at a random
deformed state where it is active (energy, gradient and Hessian asserted non-zero first).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pytest
import scipy.sparse as sp

from facesim.contact import ContactTerm, Plane, Sphere, SurfaceContactTerm
from facesim.energy import EnergyTerm, NodeTerm, ParameterTerm
from facesim.fem import DofSystem, ElasticTerm, MuscleTerm, RestShape, box_mesh
from facesim.fem.newton import Problem
from facesim.kinematics import KinematicTerm, RigidityTerm, SlidingCondyleJaw
from tests.conftest import boundary_triangles, make_box_model
from tests.fem.conftest import inverted_count, random_unit
from tests.fem.test_terms import _fd_gradient, _fd_hessian

RTOL = 1e-5   # relative error of the analytic derivatives against central differences


@dataclass
class Case:
    term: EnergyTerm
    x: np.ndarray            # (n, 3) mm for node terms, q (k,) for parameter terms
    a: np.ndarray | None = None
    tets: np.ndarray | None = None   # node terms: the mesh their add_hessian assembles on


def _block(cells=(2, 2, 2)):
    X, T = box_mesh((10.0, 8.0, 6.0), cells)
    return X, T, RestShape(X, T)


def _noisy(X, scale, seed):
    return X + scale * np.random.default_rng(seed).normal(size=X.shape)


def elastic(volumetric, noise, seed, min_inverted=0):
    X, T, rest = _block()
    rng = np.random.default_rng(seed)
    m = len(T)
    term = ElasticTerm(rest, 6e-3 * (1 + rng.random(m)), 2e-3 * (1 + rng.random(m)), 0.4 * (1 + rng.random(m)),
                       volumetric=volumetric)
    x = _noisy(X, noise, seed + 1)
    assert inverted_count(rest, x) >= min_inverted   # inverted tets: clamped singular values
    return Case(term, x, None, T)


def muscle(stretch, noise=0.05, seed=3):
    """Both muscles active, fibres near e_x, the block stretched along x by ``stretch``: the
    ascending (< 1) or descending (> 1) limb of the active force-length curve (1: random state
    with inverted tets)."""
    X, T, rest = _block()
    rng = np.random.default_rng(seed)
    k = 2 * len(T)
    tet, mus = np.tile(np.arange(len(T)), 2), np.repeat([0, 1], len(T))
    fibre = np.array([1.0, 0.0, 0.0]) + 0.1 * random_unit(rng, k)
    fibre /= np.linalg.norm(fibre, axis=1, keepdims=True)
    term = MuscleTerm(rest, tet, mus, rng.uniform(0.2, 1.0, k), fibre, np.array([0.1, 0.2]), gain=np.array([1.0, 1.5]))
    x = _noisy(X * [stretch, stretch**-0.5, stretch**-0.5], noise, seed + 1)
    F = np.einsum("mij,mjk->mik", np.stack([x[T[:, j]] - x[T[:, 0]] for j in (1, 2, 3)], -1), rest.Bm)
    lam = np.linalg.norm(np.einsum("mij,mj->mi", F[term.tet], term.fibre), axis=1)
    if stretch != 1:
        assert np.all(lam < 1) if stretch < 1 else np.all(lam > 1)
    else:
        assert inverted_count(rest, x) >= 2
    return Case(term, x, np.array([0.7, 0.4]), T)


def contact(colliders, margin=0.3, seed=5):
    X, T, _ = _block()
    w = np.random.default_rng(seed).uniform(0.5, 2.0, len(X))
    term = ContactTerm(np.arange(len(X)), colliders, stiffness=3.0, margin=margin, weights=w)
    x = _noisy(X, 0.3, seed + 1)
    assert (term.penetration(x) > 0).sum() >= 3   # nodes inside
    return Case(term, x, None, T)


def self_contact(seed=7):
    """Two 6 x 6 x 2 mm slabs 0.6 mm apart, the upper one shifted sideways (its nodes fall on the
    lower one's faces and beyond its rim) and pressed 0.4 mm into the lower one."""
    Xl, Tl = box_mesh((6.0, 6.0, 2.0), (3, 3, 1))
    Xu, Tu = box_mesh((6.0, 6.0, 2.0), (3, 3, 1), origin=(0.7, 0.45, 2.6))
    X, T = np.concatenate([Xl, Xu]), np.concatenate([Tl, Tu + len(Xl)])
    skin = boundary_triangles(T)
    z = X[skin][:, :, 2]
    term = SurfaceContactTerm(skin[np.all(z == 2.0, 1)], skin[np.all(np.isclose(z, 2.6), 1)], X)
    x = _noisy(X, 0.08, seed)
    x[len(Xl):, 2] -= 1.0
    assert term.min_distance(x) < -0.2
    return Case(term, x, None, T)


@cache
def _jaw() -> SlidingCondyleJaw:
    return SlidingCondyleJaw(make_box_model().jaw)


def kinematic(seed=11):
    jaw = _jaw()
    rng = np.random.default_rng(seed)
    q = jaw.frame([0.3, 2.0, 5.0]) + np.r_[0.03 * rng.normal(size=9), 0.5 * rng.normal(size=3)]
    return Case(KinematicTerm(jaw, weights=rng.uniform(0.5, 2.0, 7)), q)


def rigidity(seed=13):
    """A compressed, sheared frame: the exact Hessian is indefinite there."""
    q = np.r_[(0.6 * np.eye(3) + 0.2 * np.random.default_rng(seed).normal(size=(3, 3))).ravel(), [4.0, -2.0, 7.0]]
    return Case(RigidityTerm(2.5), q)


class JawPenalty(ParameterTerm):
    """A jaw model's range penalty ``penalty(q) -> (value, gradient, Hessian)`` as a term (its
    Hessian is PSD, piecewise constant)."""

    def __init__(self, jaw):
        self.jaw = jaw

    def evaluate(self, q, project=True):
        return self.jaw.penalty(q)


def jaw_penalty():
    jaw = _jaw()
    return Case(JawPenalty(jaw), np.array([-0.1, jaw.d + 1.5, -0.7]))


CASES = [
    pytest.param(lambda: elastic("log", 0.4, 1), id="elastic-log"),
    pytest.param(lambda: elastic("quadratic", 0.4, 1), id="elastic-quadratic"),
    pytest.param(lambda: elastic("log", 1.5, 2, min_inverted=2), id="elastic-log-inverted"),
    pytest.param(lambda: elastic("quadratic", 1.5, 2, min_inverted=2), id="elastic-quadratic-inverted"),
    pytest.param(lambda: muscle(0.8), id="muscle-ascending"),
    pytest.param(lambda: muscle(1.25), id="muscle-descending"),
    pytest.param(lambda: muscle(1.5), id="muscle-descending-tail"),
    pytest.param(lambda: muscle(1.0, noise=1.5), id="muscle-inverted"),
    pytest.param(lambda: contact([Sphere([10.0, 8.0, 6.0], 6.0)]), id="contact-sphere"),
    pytest.param(lambda: contact([Sphere([0.0, 0.0, 0.0], 5.0), Plane([0.0, 0.0, 5.0], [0.1, 0.2, 1.0])], 0.0),
                 id="contact-sphere-plane"),
    pytest.param(self_contact, id="self-contact"),
    pytest.param(kinematic, id="kinematic"),
    pytest.param(rigidity, id="rigidity"),
    pytest.param(jaw_penalty, id="jaw-penalty"),
]


def _dense(H) -> np.ndarray:
    return H.toarray() if sp.issparse(H) else np.asarray(H)


def _rel(A, B) -> float:
    return float(np.linalg.norm(A - B) / np.linalg.norm(B))


def _system_hessian(term: NodeTerm, x, a, tets, project):
    """The term assembled as Newton does, on a system with a fixed node and prescribed
    components: ``(matrix over the system's free dofs, the system's dof ids)``."""
    fixed = np.zeros((len(x), 3), bool)
    fixed[0] = True
    fixed[len(x) // 2, 1] = True
    fixed[-1, [0, 2]] = True
    system = DofSystem(tets, len(x), fixed, np.arange(len(tets)))
    data = system.new_data()
    term.add_hessian(x, a, system, data, project)
    A = system.matrix(data, diag=0.0).tocsr()
    S = term.sparse_hessian(x, a, system, project)
    if S is not None:
        assert S.shape == A.shape
        assert abs(S[~system.free_dof]).sum() == 0 and abs(S[:, ~system.free_dof]).sum() == 0
        A = A + S
    dof = (3 * system.active[:, None] + np.arange(3)).ravel()
    free = system.free_dof
    return A.toarray()[np.ix_(free, free)], dof[free]


@pytest.mark.parametrize("make", CASES)
def test_derivatives_against_central_differences(make):
    c = make()
    term, x, a = c.term, c.x, c.a
    assert isinstance(term, EnergyTerm)
    E, g = term.energy_and_gradient(x, a)
    H = _dense(term.hessian(x, a, project=False))
    # active: a trivial (zero) case cannot pass (a shortened active muscle has negative energy)
    assert abs(E) > 1e-6 and np.linalg.norm(g) > 1e-6 and np.linalg.norm(H) > 1e-6
    assert g.shape == x.shape and H.shape == (x.size, x.size)
    assert term.energy(x, a) == pytest.approx(E, rel=1e-13)
    np.testing.assert_allclose(term.gradient(x, a), g, rtol=1e-13, atol=0)

    assert _rel(g, _fd_gradient(term, x, a)) < RTOL
    assert _rel(H, _fd_hessian(term, x, a)) < RTOL
    np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())

    Hp = _dense(term.hessian(x, a, project=True))
    np.testing.assert_allclose(Hp, Hp.T, atol=1e-12 * np.abs(Hp).max())
    assert np.linalg.eigvalsh(Hp).min() >= -1e-10 * np.abs(Hp).max()

    dx = np.random.default_rng(0).normal(size=x.shape)
    assert term.max_step(x, dx) > 0
    if isinstance(term, NodeTerm):
        assert sp.issparse(term.hessian(x, a))
        for project, full in ((False, H), (True, Hp)):
            A, dof = _system_hessian(term, x, a, c.tets, project)
            np.testing.assert_allclose(A, full[np.ix_(dof, dof)], rtol=0, atol=1e-12 * np.abs(full).max())
    else:
        assert isinstance(term.hessian(x, a), np.ndarray)


def test_elastic_max_step_stops_where_the_first_tet_inverts():
    X, T, rest = _block()
    term = ElasticTerm(rest, 6e-3, 2e-3, 0.4)
    dx = np.zeros_like(X)
    dx[T[0, 0]] = 3.0 * (X[T[0, 1:]].mean(axis=0) - X[T[0, 0]])   # node 0 through its opposite face
    s = term.max_step(X, dx)
    assert 0.2 < s < 0.5
    assert inverted_count(rest, X + 0.999 * s * dx) == 0 and inverted_count(rest, X + 1.001 * s * dx) >= 1
    assert term.max_step(X, 1e-3 * dx) == 1.0
    # Newton's limit is the smallest over its terms (contact sets none)
    free = DofSystem(T, len(X), np.zeros((len(X), 3), bool), np.arange(len(T)))
    other = ContactTerm([0], [Sphere([0.0, 0.0, 0.0], 1.0)])
    prob = Problem([other, term], free, X)
    assert prob.max_step(X, dx[free.active].ravel()) == s
    assert Problem([other], free, X).max_step(X, dx[free.active].ravel()) == np.inf
