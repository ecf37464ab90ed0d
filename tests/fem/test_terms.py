"""Flesh and muscle terms: numpy oracles for the kernels, assembly, force columns (their derivatives
are checked with every other term's in tests/test_energy_terms.py)."""

import numpy as np
import pytest

from facesim._kernels.fibre import active_curve, passive_curve
from facesim.fem import DofSystem, ElasticTerm, MuscleTerm
from tests.fem.conftest import inverted_count, random_unit
from tests.fem.test_material import numpy_mooney_rivlin


def _terms(rest, volumetric="log", seed=1):
    rng = np.random.default_rng(seed)
    m = len(rest.tets)
    el = ElasticTerm(rest, 6e-3 * (1 + rng.random(m)), 2e-3 * (1 + rng.random(m)), 0.4 * (1 + rng.random(m)),
                     volumetric=volumetric)
    k = 60
    mu = MuscleTerm(rest, rng.integers(0, m, k), rng.integers(0, 3, k), rng.uniform(0.2, 1.0, k),
                    random_unit(rng, k), np.array([0.1, 0.2, 0.15]), gain=np.array([1.0, 1.5, 0.7]))
    return el, mu


def _deformed(X, rest, scale, seed):
    x = X + scale * np.random.default_rng(seed).normal(size=X.shape)
    return x, inverted_count(rest, x)


def _fd_gradient(term, x, a, h=1e-6):
    """Central differences of ``term.energy`` at ``x`` (any shape: node positions or parameters)."""
    g = np.zeros(x.size)
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.flat[i] += h
        xm.flat[i] -= h
        g[i] = (term.energy(xp, a) - term.energy(xm, a)) / (2 * h)
    return g.reshape(x.shape)


def _fd_hessian(term, x, a, h=1e-6):
    """``(x.size, x.size)`` central differences of ``term.gradient`` at ``x`` (column i: d/dx.flat[i])."""
    H = np.zeros((x.size, x.size))
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.flat[i] += h
        xm.flat[i] -= h
        H[:, i] = (term.gradient(xp, a) - term.gradient(xm, a)).ravel() / (2 * h)
    return H


def test_energy_and_forces_are_invariant_under_rigid_motion(small_block):
    from scipy.spatial.transform import Rotation

    X, T, rest = small_block
    el, mu = _terms(rest)
    a = np.array([0.5, 0.2, 0.9])
    x, _ = _deformed(X, rest, 0.4, 5)
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    y = x @ R.T + np.array([5.0, -3.0, 2.0])
    for term in (el, mu):
        assert term.energy(y, a) == pytest.approx(term.energy(x, a), rel=1e-11)
        np.testing.assert_allclose(term.gradient(y, a), term.gradient(x, a) @ R.T, atol=1e-10)
        g = term.gradient(x, a)
        assert np.abs(g.sum(axis=0)).max() < 1e-10 * np.abs(g).max() * len(x)   # no net force
        assert np.abs(np.cross(x, g).sum(axis=0)).max() < 1e-9 * np.abs(g).max() * len(x)   # no net torque


def test_element_kernels_match_numpy_oracle(small_block):
    X, T, rest = small_block
    el, mu = _terms(rest)
    x, n_inv = _deformed(X, rest, 0.3, 9)
    assert n_inv == 0
    Ds = np.stack([x[T[:, j]] - x[T[:, 0]] for j in (1, 2, 3)], axis=-1)
    F = Ds @ rest.Bm
    # flesh: element gradients V0 P b_a scattered with np.add.at
    psi = np.array([numpy_mooney_rivlin(F[e:e + 1], el.c10[e], el.c01[e], el.kappa[e], "log")[0][0]
                    for e in range(len(T))])
    P = np.concatenate([numpy_mooney_rivlin(F[e:e + 1], el.c10[e], el.c01[e], el.kappa[e], "log")[1]
                        for e in range(len(T))])
    b = np.concatenate([-rest.Bm.sum(axis=1, keepdims=True), rest.Bm], axis=1)   # (m, 4, 3)
    ge = rest.V0[:, None, None] * np.einsum("mkl,mal->mak", P, b)
    g = np.zeros_like(x)
    np.add.at(g, T, ge)
    assert el.energy(x) == pytest.approx((rest.V0 * psi).sum(), rel=1e-11)
    np.testing.assert_allclose(el.gradient(x), g, rtol=1e-9, atol=1e-12)
    # fibres: T = sigma rho [f_P + a g f_L], P_f = (T / lam) (F d) (x) d
    a = np.array([0.2, 0.7, 1.0])
    gm = np.zeros_like(x)
    energy = 0.0
    for j in range(len(mu.tet)):
        e, m, d = mu.tet[j], mu.muscle[j], mu.fibre[j]
        fd = F[e] @ d
        lam = np.linalg.norm(fd)
        fl, _, Fl = active_curve(lam - 1)
        fp, _, Fp = passive_curve(lam - 1)
        s = mu.sigma[m] * mu.fraction[j]
        energy += rest.V0[e] * s * (Fp + a[m] * mu.gain[m] * Fl)
        Pf = s * (fp + a[m] * mu.gain[m] * fl) / lam * np.outer(fd, d)
        np.add.at(gm, T[e], rest.V0[e] * b[e] @ Pf.T)
    assert mu.energy(x, a) == pytest.approx(energy, rel=1e-11)
    np.testing.assert_allclose(mu.gradient(x, a), gm, rtol=1e-9, atol=1e-13)


def test_assembly_equals_dense_sum_of_element_matrices(small_block):
    X, T, rest = small_block
    el, _ = _terms(rest)
    x, _ = _deformed(X, rest, 0.8, 4)
    Ke = el.element_hessians(x, project=True)
    dofs = (3 * T[:, :, None] + np.arange(3)).reshape(len(T), 12)
    K = np.zeros((x.size, x.size))
    for e in range(len(T)):
        K[np.ix_(dofs[e], dofs[e])] += Ke[e]
    np.testing.assert_allclose(el.hessian(x, project=True).toarray(), K, atol=1e-12 * np.abs(K).max())


def test_colouring_and_dirichlet_rows(small_block):
    X, T, rest = small_block
    fixed = np.zeros((len(X), 3), bool)
    fixed[X[:, 0] < 1e-9] = True          # clamped face: nodes leave the system
    fixed[X[:, 0] > 10 - 1e-9, 1] = True  # roller: one component prescribed
    sysm = DofSystem(T, len(X), fixed, np.arange(len(T)))
    assert len(sysm.active) == len(X) - (X[:, 0] < 1e-9).sum()
    for c in range(len(sysm.colour_ptr) - 1):
        chunks = [sysm.chunk_elems[sysm.chunk_ptr[k]:sysm.chunk_ptr[k + 1]]
                  for k in range(sysm.colour_ptr[c], sysm.colour_ptr[c + 1])]
        nodes = np.concatenate([np.unique(T[el]) for el in chunks])
        assert len(np.unique(nodes)) == len(nodes)   # no node shared by two chunks of a colour
    assert sorted(sysm.chunk_elems) == list(range(len(T)))
    assert sorted(sysm.active) == sorted(np.flatnonzero(X[:, 0] >= 1e-9))   # rows: a permutation of the nodes
    assert (sysm.row_of[sysm.active] == np.arange(len(sysm.active))).all()
    el, _ = _terms(rest)
    data = sysm.new_data()
    el.add_hessian(X + 0.1, None, sysm, data)
    A = sysm.matrix(data, diag=7.0).toarray()
    pres = ~sysm.free_dof
    assert pres.sum() == (X[:, 0] > 10 - 1e-9).sum()
    np.testing.assert_allclose(A[pres][:, pres], 7.0 * np.eye(pres.sum()))
    assert np.abs(A[pres][:, ~pres]).max() == 0 and np.abs(A[~pres][:, pres]).max() == 0


def test_force_columns_are_the_activation_derivative_of_the_force(small_block):
    X, T, rest = small_block
    _, mu = _terms(rest)
    x, _ = _deformed(X, rest, 0.5, 11)
    G = mu.force_columns(x).toarray()
    a = np.array([0.1, 0.4, 0.8])
    assert np.abs(G).max() > 1e-3
    for m in range(3):
        e = np.zeros(3)
        e[m] = 1.0
        df = -(mu.gradient(x, a + e) - mu.gradient(x, a)).ravel()   # force is affine in a
        np.testing.assert_allclose(G[:, m], df, atol=1e-12)


def test_gain_scales_only_the_active_curve(small_block):
    X, T, rest = small_block
    _, mu = _terms(rest)
    x, _ = _deformed(X, rest, 0.5, 12)
    a = np.array([1.0, 1.0, 1.0])
    passive = mu.gradient(x, np.zeros(3))
    active = mu.gradient(x, a) - passive
    doubled = mu.with_gain(2 * mu.gain)
    np.testing.assert_allclose(doubled.gradient(x, a) - passive, 2 * active, atol=1e-12)


def test_chunked_gradient_equals_per_tet_sum():
    """The flesh gradient added chunk by chunk in parallel (chunks of a colour share no node)
    equals the per-tet gradients of the numpy oracle summed one by one, on a mesh of 64 chunks and
    on a third of its tets; the chunks cover each tet once; the chunk arrays are not pickled."""
    import pickle

    from facesim.fem import RestShape, box_mesh
    from facesim.fem.system import element_chunks

    X, T = box_mesh((30.0, 24.0, 18.0), (10, 8, 6))
    rest = RestShape(X, T)
    rng = np.random.default_rng(2)
    x = X + 0.3 * rng.normal(size=X.shape)
    for elems in (np.arange(len(T)), np.sort(rng.choice(len(T), len(T) // 3, replace=False))):
        colour_ptr, chunk_ptr, order = element_chunks(rest.tets, elems, len(X))
        assert len(chunk_ptr) - 1 == min(64, len(elems) // 32) and sorted(order) == list(range(len(elems)))
        ordered = elems[order]
        for c in range(len(colour_ptr) - 1):
            nodes = np.concatenate([np.unique(T[ordered[chunk_ptr[k]:chunk_ptr[k + 1]]])
                                    for k in range(colour_ptr[c], colour_ptr[c + 1])])
            assert len(np.unique(nodes)) == len(nodes)
        el = ElasticTerm(rest, 9e-3, 2e-3, 0.4, elems=elems)
        F = np.stack([x[T[elems, j]] - x[T[elems, 0]] for j in (1, 2, 3)], axis=-1) @ rest.Bm[elems]
        assert np.linalg.svd(F, compute_uv=False).min() > el.clamp   # the oracle's (unclamped) range
        psi, P = numpy_mooney_rivlin(F, 9e-3, 2e-3, 0.4, "log")
        b = np.concatenate([-rest.Bm[elems].sum(axis=1, keepdims=True), rest.Bm[elems]], axis=1)   # (k, 4, 3)
        g_ref = np.zeros_like(x)
        np.add.at(g_ref, T[elems], rest.V0[elems, None, None] * np.einsum("mkl,mal->mak", P, b))
        e, g = el.energy_and_gradient(x)
        assert e == pytest.approx((rest.V0[elems] * psi).sum(), rel=1e-11)
        assert el.energy(x) == pytest.approx(e, rel=1e-12)
        np.testing.assert_allclose(g, g_ref, rtol=1e-9, atol=1e-12 * np.abs(g_ref).max())
        assert np.abs(g[np.setdiff1d(np.arange(len(X)), T[elems].ravel())]).max(initial=0) == 0
    copy = pickle.loads(pickle.dumps(el))
    assert el._copies.gradient is not None and copy._copies.gradient is None
    np.testing.assert_array_equal(copy.gradient(x), g)


def test_gradient_shares_the_systems_chunk_order(small_block):
    """A term that assembles into a system over its own tets takes that system's chunk order for its
    gradient (no copy of its own); a copy with another clamp shares the copies and keeps its clamp."""
    X, T, rest = small_block
    el, _ = _terms(rest)
    sysm = DofSystem(T, len(X), np.zeros((len(X), 3), bool), np.arange(len(T)))
    arrays = el._chunked(sysm)
    x, _ = _deformed(X, rest, 0.3, 11)
    g = el.gradient(x)
    assert el._copies.gradient[0] is arrays and el._copies.gradient[1] is sysm.colour_ptr
    other = el.with_clamp(0.3)
    assert other._copies is el._copies and other.clamp == 0.3 and el.clamp != 0.3
    squashed = X.copy()
    squashed[:, 2] *= 0.2   # singular values of 0.2 < 0.3: the clamp changes the energy
    assert other.energy(squashed) != pytest.approx(el.energy(squashed), rel=1e-6)
    np.testing.assert_allclose(other.gradient(x), g)   # no singular value near either clamp at x
