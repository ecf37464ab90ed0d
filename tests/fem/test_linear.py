"""Linear solvers: the symmetric-mode sparse LU and AMG-CG against dense solves."""

import numpy as np
import pytest
import scipy.sparse as sp

from facesim.errors import FacesimError
from facesim.fem.linear import AMGSolver, DirectSolver, factorize, make_linear_solver, single_blas_thread


def laplacian_3d(n):
    """(n^3, n^3) SPD 7-point Laplacian plus identity."""
    one = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    eye = sp.identity(n)
    return (sp.kron(sp.kron(one, eye), eye) + sp.kron(sp.kron(eye, one), eye) + sp.kron(sp.kron(eye, eye), one)
            + sp.identity(n ** 3)).tocsr()


def stiffer_along_x(n):
    """``laplacian_3d(n)`` with its coupling along x 1000 times stiffer (CSR): far from its factor."""
    one = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    return (laplacian_3d(n) + 999.0 * sp.kron(sp.kron(one, sp.identity(n)), sp.identity(n))).tocsr()


class _Factor:
    """A factor whose applications are counted (a Python object: it takes weak references)."""

    def __init__(self, factor):
        self.factor, self.calls = factor, 0

    def solve(self, b):
        self.calls += 1
        return self.factor.solve(b)


def test_factorize_solves_spd_and_symmetric_indefinite_systems():
    rng = np.random.default_rng(0)
    A = laplacian_3d(6)
    b = rng.normal(size=(A.shape[0], 3))
    X = factorize(A).solve(b)
    np.testing.assert_allclose(A @ X, b, atol=1e-10)
    # symmetric indefinite (a shifted Laplacian with negative eigenvalues): still solved, pivoting kept
    S = (A - 4.0 * sp.identity(A.shape[0])).tocsc()
    assert np.linalg.eigvalsh(S.toarray()).min() < 0
    x = factorize(S).solve(b[:, 0])
    np.testing.assert_allclose(S @ x, b[:, 0], atol=1e-9 * np.abs(b).max() * np.linalg.cond(S.toarray()))


def test_direct_solver_keeps_its_factorisation_and_counts():
    A = laplacian_3d(5)
    b = np.ones((A.shape[0], 4))
    solver = DirectSolver()
    X = solver.solve_many(A, b)
    np.testing.assert_allclose(solver.lu.solve(b[:, 1]), X[:, 1])
    assert solver.stats.setups == 1 and solver.stats.solves == 1


def test_amg_cg_matches_the_direct_solve():
    A = laplacian_3d(16)                       # above the direct threshold: a real hierarchy
    b = np.random.default_rng(1).normal(size=A.shape[0])
    B = np.ones((A.shape[0], 1))
    amg = AMGSolver()
    x = amg.solve(A, b, B, rtol=1e-10)
    np.testing.assert_allclose(x, factorize(A).solve(b), rtol=1e-7, atol=1e-9)
    assert amg.stats.setups == 1 and 0 < amg.stats.iterations[-1] < 60


def test_single_blas_thread_is_reentrant_and_solvers_are_named():
    with single_blas_thread(), single_blas_thread():
        assert float(np.ones(20_000) @ np.ones(20_000)) == 20_000.0
    with pytest.raises(FacesimError, match="linear_solver"):
        make_linear_solver("cholesky")


def test_pardiso_finds_mkl_once_per_process(monkeypatch):
    """pypardiso searches the whole sys.prefix tree for libmkl_rt in every solver it makes (0.45 s,
    paid by every Jacobian); the first factorisation keeps the library's path in PYPARDISO_MKL_RT,
    which later ones use, and the factors stay correct."""
    pytest.importorskip("pypardiso")
    import os

    import scipy.sparse as sp

    from facesim.fem.linear import PardisoFactor

    monkeypatch.delenv("PYPARDISO_MKL_RT", raising=False)
    A = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(50, 50)).tocsr()
    b = np.arange(50.0)
    PardisoFactor(A)
    assert "mkl_rt" in os.environ.get("PYPARDISO_MKL_RT", "")
    x = PardisoFactor(A).solve(b)
    np.testing.assert_allclose(A @ x, b, atol=1e-10)


@pytest.mark.parametrize("backend", ["superlu", "pardiso"])
def test_factor_pcg_uses_a_near_factor_and_refactorises_a_far_one(backend):
    from facesim.fem.linear import FactorPCG, factorize, pardiso_available

    if backend == "pardiso" and not pardiso_available():
        pytest.skip("pypardiso is not installed")
    rng = np.random.default_rng(3)
    A = laplacian_3d(8)
    b = rng.normal(size=A.shape[0])
    near = (A + 0.01 * sp.diags(rng.uniform(0, 1, A.shape[0]))).tocsr()   # a nearby matrix's factor
    solver = FactorPCG(factorize(near), maxiter=25, backend=backend)
    x = solver.solve(A, b, rtol=1e-10)
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)
    assert solver.stats.setups == 0 and 1 <= solver.stats.iterations[-1] <= 6   # CG, no factorisation
    # far from the factor (the coupling along x 1000 times stiffer): one factorisation of this
    # matrix, an exact solve, and that factor kept for the next solves
    far = stiffer_along_x(8)
    x = solver.solve(far, b, rtol=1e-10)
    np.testing.assert_allclose(far @ x, b, atol=1e-8 * np.abs(b).max())
    assert solver.stats.setups == 1 and solver.stats.iterations[-1] == 26   # 25 CG iterations, then direct
    x = solver.solve(far, 2 * b, rtol=1e-10)
    assert solver.stats.setups == 1 and solver.stats.iterations[-1] <= 2
    np.testing.assert_allclose(far @ x, 2 * b, atol=1e-8 * np.abs(b).max())
    # no factor to start with: the first solve factorises
    fresh = FactorPCG(backend=backend)
    np.testing.assert_allclose(A @ fresh.solve(A, b), b, atol=1e-9 * np.abs(b).max())
    assert fresh.stats.setups == 1


def test_factor_pcg_on_a_large_system_solves_a_far_one_by_amg_not_a_second_factor():
    """Above ``amg_above`` unknowns a system too far from the given factor is solved by AMG-CG to
    the tolerance asked, no factorisation of its own is made, and the next solves go to AMG-CG
    straight away (the given factor is not tried again)."""
    from facesim.fem.linear import FactorPCG

    A = laplacian_3d(16)   # 4,096 unknowns: above AMGSolver's direct_below
    b = np.random.default_rng(4).normal(size=A.shape[0])
    given = _Factor(factorize(A))   # its applications counted
    solver = FactorPCG(given, maxiter=25, backend="superlu", amg_above=1000)
    far = stiffer_along_x(16).tobsr(blocksize=(1, 1))
    x = solver.solve(far, b, np.ones((A.shape[0], 1)), rtol=1e-8)
    assert np.linalg.norm(far @ x - b) <= 1e-8 * np.linalg.norm(b)
    assert solver.factor is given and solver.amg is not None and solver.amg.stats is solver.stats
    assert solver.stats.iterations[-1] > 1                       # CG iterations, not a direct solve
    calls = given.calls
    assert calls >= 25                                           # PCG was tried first
    x = solver.solve(far, 2 * b, np.ones((A.shape[0], 1)), rtol=1e-8)
    assert np.linalg.norm(far @ x - 2 * b) <= 2e-8 * np.linalg.norm(b) and given.calls == calls
    below = FactorPCG(factorize(A), maxiter=25, backend="superlu", amg_above=10**6)
    below.solve(far.tocsr(), b, rtol=1e-8)
    assert below.amg is None and below.factor is not None and below.stats.setups == 1   # factorised


class _Owner:
    """What FactorPCG's ``owner`` is: something whose ``tangent`` holds the factor."""

    def __init__(self, tangent, tangent_at):
        self.tangent, self.tangent_at = tangent, tangent_at


def test_factor_pcg_frees_an_owned_far_factor_and_hands_its_own_back():
    """Above ``amg_above``: a far factor held only by its ``owner`` is freed and this step
    factorised after all (one factor at a time), the new factor becomes the owner's tangent (its
    ``tangent_at`` cleared); a factor someone else still holds stays, and the step goes to AMG-CG."""
    import weakref

    from facesim.fem.linear import FactorPCG

    A = laplacian_3d(16)
    b = np.random.default_rng(6).normal(size=A.shape[0])
    far = stiffer_along_x(16)
    B = np.ones((A.shape[0], 1))

    owner = _Owner(_Factor(factorize(A)), ("controls", "x", 0.0))
    given = weakref.ref(owner.tangent)
    solver = FactorPCG(owner=owner, maxiter=25, backend="superlu", amg_above=1000)
    x = solver.solve(far, b, B, rtol=1e-8)
    assert np.linalg.norm(far @ x - b) <= 1e-8 * np.linalg.norm(b)
    assert given() is None                                           # the far factor was freed
    assert solver.amg is None and solver.stats.setups == 1 and solver.stats.iterations[-1] == 26
    assert owner.tangent is solver.factor and owner.tangent_at is None
    x = solver.solve(far, 2 * b, B, rtol=1e-8)                       # its own factor: near
    assert solver.stats.setups == 1 and solver.stats.iterations[-1] <= 2
    assert np.linalg.norm(far @ x - 2 * b) <= 2e-8 * np.linalg.norm(b)

    held = _Factor(factorize(A))                                     # the caller keeps a reference
    owner = _Owner(held, ("controls", "x", 0.0))
    solver = FactorPCG(owner=owner, maxiter=25, backend="superlu", amg_above=1000)
    x = solver.solve(far, b, B, rtol=1e-8)
    assert np.linalg.norm(far @ x - b) <= 1e-8 * np.linalg.norm(b)
    assert solver.amg is not None and solver.stats.iterations[-1] > 1   # AMG-CG, not a direct solve
    assert owner.tangent is held and solver.factor is held and owner.tangent_at == ("controls", "x", 0.0)


def test_pardiso_many_columns_keep_the_single_solve_only_within_rtol():
    """``solve(B, rtol)`` with many columns: the single-precision solve is kept where one random
    combination of the columns says it is within ``rtol`` (no refinement), refined where one
    column is off (a solve perturbed by 1e-3 in that column alone)."""
    pytest.importorskip("pypardiso")
    from facesim.fem.linear import PardisoFactor

    rng = np.random.default_rng(7)
    A = (laplacian_3d(10) + sp.diags(rng.uniform(0, 5, 1000))).tocsr()
    B = rng.normal(size=(A.shape[0], 9)) * np.logspace(-3, 3, 9)    # columns of very different sizes
    f = PardisoFactor(A)

    def res(X):
        return np.linalg.norm(A @ X - B, axis=0) / np.linalg.norm(B, axis=0)

    X = f.solve(B, rtol=1e-4)
    np.testing.assert_array_equal(X, f.precondition(B))              # kept as solved: no refinement
    assert 1e-9 < res(X).max() < 1e-4
    assert res(f.solve(B)).max() < 1e-10                             # default: refined to REFINE_RTOL
    clean = f.precondition

    def off(b):
        x = clean(b)
        if x.ndim == 2:
            x[:, 4] *= 1 + 1e-3 * rng.normal(size=x.shape[0])
        return x

    f.precondition = off
    assert res(off(B))[4] > 1e-4
    assert res(f.solve(B, rtol=1e-4)).max() < 1e-4                   # caught and refined


def test_pardiso_single_precision_factor_refines_to_double():
    """The single-precision factor: ``precondition`` to ~1e-6, ``solve`` (one refinement step in
    double) to ~1e-10 and better, one and many right-hand sides; a double factor solves exactly."""
    pytest.importorskip("pypardiso")
    from facesim.fem.linear import PardisoFactor

    rng = np.random.default_rng(5)
    A = laplacian_3d(10)
    A = (A + sp.diags(rng.uniform(0, 5, A.shape[0]))).tocsr()
    b = rng.normal(size=A.shape[0])
    B = rng.normal(size=(A.shape[0], 7))
    f = PardisoFactor(A)

    def res(x, b):
        return np.linalg.norm(A @ x - b, axis=0).max() / np.linalg.norm(b, axis=0).min()

    assert f.single and f.factor_nonzeros > A.nnz // 2
    assert 1e-9 < res(f.precondition(b), b) < 1e-5          # single precision, no more
    assert res(f.solve(b), b) < 1e-10
    X = f.solve(B)
    assert X.shape == B.shape and X.flags.c_contiguous and res(X, B) < 1e-10
    np.testing.assert_allclose(X[:, 3], f.solve(B[:, 3]), rtol=1e-9, atol=1e-12)
    d = PardisoFactor(A, single=False)
    assert res(d.precondition(b), b) < 1e-13 and res(d.solve(B), B) < 1e-13
    # an indefinite matrix: still factorised (Bunch-Kaufman pivots), solved to double precision
    S = (A - 6.0 * sp.identity(A.shape[0])).tocsr()
    assert np.linalg.eigvalsh(S.toarray()).min() < 0
    x = PardisoFactor(S).solve(b)
    assert np.linalg.norm(S @ x - b) < 1e-9 * np.linalg.norm(b)


@pytest.mark.parametrize("k", [2, 3, 7, 8, 12])
def test_pardiso_few_columns_are_solved_one_by_one_as_in_a_block(k):
    """Below ``BLOCK_SOLVE_FROM`` columns PARDISO solves each column on its own (its block path
    was slower there); the result is the single-column solves', in either precision and order."""
    pytest.importorskip("pypardiso")
    from facesim.fem.linear import BLOCK_SOLVE_FROM, PardisoFactor

    rng = np.random.default_rng(k)
    A = laplacian_3d(8)
    B = rng.normal(size=(A.shape[0], k))
    for single in (True, False):
        f = PardisoFactor(A, single=single)
        X = f.precondition(B)
        assert X.shape == B.shape and X.flags.c_contiguous
        one = np.column_stack([f.precondition(B[:, j]) for j in range(k)])
        tol = 1e-6 if single else 1e-13
        np.testing.assert_allclose(X, one, rtol=tol, atol=tol * np.abs(one).max())
        assert np.linalg.norm(A @ X - B) < 10 * tol * np.linalg.norm(B)
        if k < BLOCK_SOLVE_FROM:   # the very same solves
            np.testing.assert_array_equal(X, one)
        X2 = f.precondition(np.asfortranarray(B))   # a column-major right-hand side too
        np.testing.assert_array_equal(X2, X)


def test_pardiso_solves_on_one_and_two_threads_agree(monkeypatch):
    """The triangular solves of a large factor run on numba's thread count, of a small one on one,
    unless ``FACESIM_SOLVE_THREADS`` says otherwise; one and two threads give the same single-precision solution (a threaded solve of a
    factor made on other threads can be wrong: MKL's two-level factorisation, not used here, gives
    residuals of order 1 then), a bad setting is a one-line error."""
    pytest.importorskip("pypardiso")
    import numba

    from facesim.fem.linear import PardisoFactor, _solve_threads

    rng = np.random.default_rng(9)
    A = (laplacian_3d(16) + sp.diags(rng.uniform(0, 5, 16 ** 3))).tocsr()
    B = rng.normal(size=(A.shape[0], 3))
    f = PardisoFactor(A)
    monkeypatch.delenv("FACESIM_SOLVE_THREADS", raising=False)
    assert _solve_threads(10 ** 8) == numba.get_num_threads()
    assert _solve_threads(f.factor_nonzeros) == 1   # a small factor: one thread
    out = {}
    for n in ("1", "2"):
        monkeypatch.setenv("FACESIM_SOLVE_THREADS", n)
        assert _solve_threads(f.factor_nonzeros) == _solve_threads(10 ** 8) == int(n)
        out[n] = (f.precondition(B[:, 0]), f.precondition(B))
        for x, b in ((out[n][0], B[:, 0]), (out[n][1], B)):
            assert np.linalg.norm(A @ x - b) < 1e-5 * np.linalg.norm(b)
    np.testing.assert_allclose(out["2"][0], out["1"][0], rtol=0, atol=1e-5 * np.abs(out["1"][0]).max())
    np.testing.assert_allclose(out["2"][1], out["1"][1], rtol=0, atol=1e-5 * np.abs(out["1"][1]).max())
    monkeypatch.setenv("FACESIM_SOLVE_THREADS", "two")
    with pytest.raises(FacesimError, match="FACESIM_SOLVE_THREADS='two': expected a whole number"):
        _solve_threads(f.factor_nonzeros)


def test_pardiso_factor_keeps_the_matrix_as_given_until_released():
    """A float64 sparse matrix is kept as given (no copy: the refinement's residual uses it, BSR
    too); after release_matrix the factor still preconditions (single precision, ~1e-6) and its
    double-precision solve refuses rather than return an unrefined answer."""
    pytest.importorskip("pypardiso")
    from facesim.errors import SolverError
    from facesim.fem.linear import PardisoFactor

    A = laplacian_3d(8).tobsr(blocksize=(2, 2))
    b = np.random.default_rng(3).normal(size=A.shape[0])
    f = PardisoFactor(A)
    assert f.full is A
    x = f.solve(b)
    assert np.linalg.norm(A @ x - b) < 1e-10 * np.linalg.norm(b)
    f.release_matrix()
    assert f.full is None
    assert np.linalg.norm(A @ f.precondition(b) - b) < 1e-5 * np.linalg.norm(b)
    with pytest.raises(SolverError, match="released"):
        f.solve(b)


def test_pardiso_tries_cholesky_and_falls_back_to_ldlt_on_an_indefinite_matrix():
    """Positive definite: a Cholesky factor; indefinite: Cholesky's zero pivot caught, the
    LDL^T factor solves it; ``spd=True`` says it is not positive definite; a matrix whose diagonal
    has structural zeros (PARDISO's analysis needs them stored) is factorised either way."""
    pytest.importorskip("pypardiso")
    from facesim.errors import SolverError
    from facesim.fem.linear import PardisoFactor

    A = laplacian_3d(10)   # diagonal 7, eigenvalues in (1, 13)
    b = np.random.default_rng(8).normal(size=A.shape[0])
    f = PardisoFactor(A)
    assert f.cholesky and np.linalg.norm(A @ f.solve(b) - b) < 1e-10 * np.linalg.norm(b)
    S = (A - 7.0 * sp.identity(A.shape[0])).tocsr()   # indefinite, its diagonal all zero
    S.eliminate_zeros()
    assert S.diagonal().max() == 0 and np.linalg.eigvalsh(S.toarray()).min() < -1
    g = PardisoFactor(S)
    assert not g.cholesky and np.linalg.norm(S @ g.solve(b) - b) < 1e-8 * np.linalg.norm(b)
    assert not PardisoFactor(A, spd=False).cholesky
    with pytest.raises(SolverError, match="not positive definite"):
        PardisoFactor(S, spd=True)
    np.testing.assert_allclose(f.solve(b), PardisoFactor(A, single=False).solve(b), rtol=1e-8, atol=1e-12)
