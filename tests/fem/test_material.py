"""Mooney-Rivlin in batches: closed forms, a plain-numpy oracle, derivatives, invariance."""

import numpy as np
import pytest

from facesim._kernels.svd3 import SVD_ROWS, svd3
from facesim.errors import FacesimError
from facesim.fem import MooneyRivlin


def numpy_mooney_rivlin(F, c10, c01, kappa, volumetric):
    """Oracle from the invariants (valid for det F > 0): psi and P (docs/physics.md section 1)."""
    C = np.einsum("kji,kjl->kil", F, F)
    I1 = np.trace(C, axis1=1, axis2=2)
    I2 = 0.5 * (I1 ** 2 - np.einsum("kij,kji->k", C, C))
    J = np.linalg.det(F)
    Finv_T = np.linalg.inv(F).transpose(0, 2, 1)
    if volumetric == "log":
        U, dU = 0.5 * kappa * np.log(J) ** 2, kappa * np.log(J) / J
    else:
        U, dU = 0.5 * kappa * (J - 1) ** 2, kappa * (J - 1)
    psi = c10 * (J ** (-2 / 3) * I1 - 3) + c01 * (J ** (-4 / 3) * I2 - 3) + U
    FC = np.einsum("kij,kjl->kil", F, C)
    P = (2 * c10 * J[:, None, None] ** (-2 / 3) * (F - I1[:, None, None] / 3 * Finv_T)
         + 2 * c01 * J[:, None, None] ** (-4 / 3) * (I1[:, None, None] * F - FC - 2 / 3 * I2[:, None, None] * Finv_T)
         + (dU * J)[:, None, None] * Finv_T)
    return psi, P


@pytest.fixture
def states():
    rng = np.random.default_rng(7)
    F = np.eye(3) + 0.35 * rng.normal(size=(300, 3, 3))
    return F


@pytest.mark.parametrize("volumetric", ["log", "quadratic"])
def test_kernel_matches_numpy_oracle(states, volumetric):
    mat = MooneyRivlin(0.06, 0.02, 3.0, volumetric)
    ok = np.linalg.svd(states, compute_uv=False).min(axis=1) > mat.clamp
    ok &= np.linalg.det(states) > 0
    assert ok.sum() > 100
    psi, P = numpy_mooney_rivlin(states[ok], mat.c10, mat.c01, mat.kappa, volumetric)
    np.testing.assert_allclose(mat.energy_density(states[ok]), psi, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(mat.first_piola(states[ok]), P, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("volumetric", ["log", "quadratic"])
def test_stress_and_tangent_against_central_differences_including_inverted(states, volumetric):
    mat = MooneyRivlin(6e-3, 2e-3, 0.4, volumetric)
    assert (np.linalg.det(states) < 0).sum() >= 5
    P = mat.first_piola(states)
    D = mat.tangent(states)
    assert np.linalg.norm(P) > 0 and np.linalg.norm(D) > 0
    h = 1e-6
    Pn = np.zeros_like(P)
    Dn = np.zeros_like(D)
    for r in range(9):
        E = np.zeros(9)
        E[r] = h
        E = E.reshape(3, 3)
        Pn[:, r // 3, r % 3] = (mat.energy_density(states + E) - mat.energy_density(states - E)) / (2 * h)
        Dn[:, :, r] = (mat.first_piola(states + E) - mat.first_piola(states - E)).reshape(-1, 9) / (2 * h)
    err_P = np.linalg.norm(P - Pn, axis=(1, 2)) / np.linalg.norm(P, axis=(1, 2))
    err_D = np.linalg.norm(D - Dn, axis=(1, 2)) / np.linalg.norm(D, axis=(1, 2))
    assert err_P.max() < 1e-5
    assert err_D.max() < 1e-5


def test_projected_tangent_is_psd_and_equal_where_already_psd(states):
    mat = MooneyRivlin(6e-3, 2e-3, 0.4)
    D = mat.tangent(states)
    Dp = mat.tangent(states, project=True)
    eig = np.linalg.eigvalsh(0.5 * (Dp + Dp.transpose(0, 2, 1)))
    assert eig.min() > -1e-12 * np.abs(eig).max()
    psd = np.linalg.eigvalsh(D).min(axis=1) >= 0
    assert psd.any() and (~psd).any()
    np.testing.assert_allclose(Dp[psd], D[psd], atol=1e-12)


def test_rest_state_is_stress_free_and_rotation_invariant(states):
    mat = MooneyRivlin(6e-3, 2e-3, 0.4)
    assert abs(mat.energy_density(np.eye(3))) < 1e-15
    np.testing.assert_allclose(mat.first_piola(np.eye(3)), 0, atol=1e-15)
    from scipy.spatial.transform import Rotation

    R = Rotation.random(len(states), random_state=3).as_matrix()
    np.testing.assert_allclose(mat.energy_density(R @ states), mat.energy_density(states), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(mat.first_piola(R @ states), R @ mat.first_piola(states), rtol=1e-8, atol=1e-13)
    # small-strain limit: shear modulus 2 (c10 + c01)
    g = 1e-6
    F = np.eye(3)
    F[0, 1] = g
    assert mat.first_piola(F)[0, 1] / g == pytest.approx(mat.shear_modulus, rel=1e-5)


def test_inverted_elements_push_back(states):
    mat = MooneyRivlin(6e-3, 2e-3, 0.4)
    F = np.diag([1.0, 1.0, -0.5])
    P = mat.first_piola(F)
    assert np.isfinite(mat.energy_density(F)) and mat.energy_density(F) > mat.energy_density(np.eye(3))
    assert P[2, 2] < 0   # energy decreases as F33 grows back toward positive


def test_signed_svd_matches_numpy(states):
    U, s, V = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    work = np.empty((SVD_ROWS, 3))
    for F in states[:100]:
        svd3(F, U, s, V, work)
        np.testing.assert_allclose(U @ np.diag(s) @ V.T, F, atol=1e-12)
        assert np.linalg.det(U) == pytest.approx(1.0) and np.linalg.det(V) == pytest.approx(1.0)
        np.testing.assert_allclose(np.abs(s), np.linalg.svd(F, compute_uv=False), rtol=1e-10, atol=1e-13)
        assert (s[2] < 0) == (np.linalg.det(F) < 0)


def test_bad_parameters_are_refused():
    with pytest.raises(FacesimError, match="volumetric"):
        MooneyRivlin(1, 1, 1, "cubic")
    with pytest.raises(FacesimError, match="c10"):
        MooneyRivlin(-1, 1, 1)
    with pytest.raises(FacesimError, match="shape"):
        MooneyRivlin(1, 1, 1).energy_density(np.eye(4))


@pytest.mark.parametrize("volumetric", ["log", "quadratic"])
def test_invariant_fast_path_equals_the_singular_value_form(states, volumetric):
    """The element kernels take stress and true Hessian from the invariants (no SVD) when no
    singular value can be clamped; there they must be the SVD form's, and the test that sends a
    tet to the SVD form must never let a clamped one through. The Hessian in the node positions of
    a tet with random shape gradients, against the SVD modes' dP/dF contracted with them."""
    from facesim._kernels.mooney import MODES_ROWS, NODE_HESSIAN_ROWS, mr_modes, mr_node_hessian, mr_stress

    mat = MooneyRivlin(6e-3, 2e-3, 0.4, volumetric)
    vol = 0 if volumetric == "log" else 1
    squashed = np.array([np.diag([1.0, 1.0, 0.12]), np.diag([1.3, 1.2, 0.105]), np.diag([1.0, 1.0, -0.5])])
    P, K, lam, Q = np.empty((3, 3)), np.empty((12, 12)), np.empty(9), np.empty((9, 3, 3))
    work, S, Pm = np.empty((MODES_ROWS, 3)), np.empty((NODE_HESSIAN_ROWS, 3)), np.empty((3, 3))
    rng = np.random.default_rng(7)
    fast = 0
    for F in np.concatenate([states, squashed]):
        b = rng.normal(size=(4, 3))
        b[0] = -b[1:].sum(axis=0)
        V0 = rng.uniform(0.5, 2.0)
        psi, ok = mr_stress(F, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, P, S)
        assert mr_node_hessian(F, b, V0, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, K, S) == ok
        s = np.linalg.svd(F, compute_uv=False)
        if not ok:
            continue
        fast += 1
        assert s.min() >= mat.clamp and np.linalg.det(F) > 0   # never a clamped tet
        psi_ref = mr_modes(F, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, Pm, lam, Q, work)
        D_ref = np.einsum("m,mij,mkl->ijkl", lam, Q, Q)     # dP_kl / dF_mn
        K_ref = V0 * np.einsum("klmn,al,cn->akcm", D_ref, b, b).reshape(12, 12)
        assert psi == pytest.approx(psi_ref, rel=1e-12, abs=1e-15)
        np.testing.assert_allclose(P, Pm, rtol=1e-10, atol=1e-13 * np.abs(Pm).max())
        np.testing.assert_allclose(K, K_ref, rtol=1e-9, atol=1e-11 * np.abs(K_ref).max())
        np.testing.assert_array_equal(K, K.T)
    assert 250 <= fast < len(states)   # most states take the fast path, the squashed ones do not


@pytest.mark.parametrize("volumetric", ["log", "quadratic"])
def test_projected_element_hessian_skips_the_svd_only_where_already_psd(states, volumetric):
    """The projected element Hessian takes the invariants' true Hessian where ``mr_psd`` finds dP/dF
    PSD from the principal stretches alone. ``mr_psd`` must agree with the SVD modes' eigenvalues
    (up to its margin), also at nearly equal stretches where its closed form is least accurate, and
    the element Hessian must equal the modes' clamped sum either way."""
    from scipy.spatial.transform import Rotation

    from facesim._kernels.elements import elastic_element_hessian, element_scratch
    from facesim._kernels.mooney import MODES_ROWS, PSD_MARGIN, PSD_ROWS, mr_modes, mr_psd

    mat = MooneyRivlin(6e-3, 2e-3, 0.4, volumetric)
    vol = 0 if volumetric == "log" else 1
    rng = np.random.default_rng(11)
    R = Rotation.random(120, random_state=5).as_matrix()
    Rv = Rotation.random(120, random_state=6).as_matrix()
    near = [np.diag([1.0, 1.0, 1.0]), np.diag([1.2, 1.2, 0.8]), np.diag([0.9, 0.9, 0.9]),
            np.diag([1.05, 1.05 + 1e-9, 0.93]), np.diag([0.8, 0.8 + 1e-7, 0.8 - 1e-7]), np.diag([1.3, 0.7, 0.7])]
    D = np.array([near[k % len(near)] for k in range(120)])
    F_all = np.concatenate([states, R @ D @ Rv.transpose(0, 2, 1), np.diag([1.0, 1.0, -0.5])[None]])
    X = np.array([[0.0, 0, 0], [1.0, 0.1, 0], [0.2, 1.1, 0.1], [0.1, 0.3, 0.9]])
    Dm = (X[1:] - X[0]).T
    Bm, V0 = np.linalg.inv(Dm), abs(np.linalg.det(Dm)) / 6
    tet = np.arange(4)
    b = np.vstack([-Bm.sum(axis=0), Bm])
    Pm, lam, Q, work = np.empty((3, 3)), np.empty(9), np.empty((9, 3, 3)), np.empty((MODES_ROWS, 3))
    T, S, K = np.empty((3, 3, 3)), np.empty((PSD_ROWS, 3)), np.empty((12, 12))
    scratch = element_scratch()
    tol = PSD_MARGIN * (mat.c10 + mat.c01)
    counts = {True: 0, False: 0}
    for F in F_all:
        psd = mr_psd(F, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, T, S)
        mr_modes(F, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, Pm, lam, Q, work)
        unclamped = np.linalg.det(F) > 0 and np.linalg.svd(F, compute_uv=False).min() >= mat.clamp
        if lam.min() < -2 * tol or lam.min() > -0.5 * tol:   # clear of the margin's band
            assert psd == (unclamped and lam.min() >= -tol), (F, lam)
        counts[psd] += 1
        elastic_element_hessian(X @ F.T, tet, Bm, V0, mat.c10, mat.c01, mat.kappa, vol, mat.clamp, True, K,
                                scratch)
        D_proj = np.einsum("m,mij,mkl->ijkl", np.maximum(lam, 0.0), Q, Q)
        K_ref = V0 * np.einsum("klmn,al,cn->akcm", D_proj, b, b).reshape(12, 12)
        scale = np.abs(K_ref).max()
        np.testing.assert_allclose(K, K_ref, rtol=1e-8, atol=1e-10 * scale + 20 * tol * V0 * (b ** 2).sum())
        np.testing.assert_array_equal(K, K.T)
    assert counts[True] >= 40 and counts[False] >= 60   # both paths taken


def test_min_signed_singular_value_matches_lapack(small_block):
    """The numba loop behind FaceSimulator's path-clamp check equals LAPACK's batched SVD (the
    smallest singular value, negative for an inverted tet), over a subset of tets and all of them."""
    from facesim._kernels.elements import min_signed_singular_value

    X, T, rest = small_block
    rng = np.random.default_rng(3)
    for scale, elems in ((0.05, np.arange(len(T))), (0.9, np.arange(0, len(T), 3))):
        x = X + scale * rng.normal(size=X.shape)
        D = np.stack([x[T[elems, k]] - x[T[elems, 0]] for k in (1, 2, 3)], axis=2)
        F = D @ rest.Bm[elems]
        expected = (np.linalg.svd(F, compute_uv=False)[:, -1] * np.sign(np.linalg.det(F))).min()
        got = min_signed_singular_value(x, rest.tets, rest.Bm, elems.astype(np.int64))
        assert got == pytest.approx(expected, rel=1e-10, abs=1e-12)
    assert (np.linalg.det(F) < 0).any() and got < 0   # the second state inverts tets: the sign is tested
    assert min_signed_singular_value(x, rest.tets, rest.Bm, np.zeros(0, np.int64)) == np.inf
