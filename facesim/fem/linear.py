"""Linear solvers for the Newton systems: AMG-preconditioned CG (default) or a direct solve.

AMG: pyamg smoothed aggregation on the 3x3-block matrix with the six rigid-body modes as
near-null space (without them CG needs ~10x more iterations, docs/physics.md section 5). The
hierarchy is kept and reused while CG converges in few iterations; it is rebuilt before the
next solve once CG needs more than ``rebuild_factor`` times the iterations per digit of residual
reduction it needed right after a rebuild (at once if CG fails).
Direct: SuperLU (scipy) on CSC, refactorised every call; fine to ~100K dofs and for many
right-hand sides. The matrices are symmetric, so SuperLU runs in its symmetric mode (minimum
degree on A^T + A, diagonal pivots preferred): half the fill of the default column ordering
and a 2-4x faster factorisation of the face's tangent (issue 5, benchmarks/bench_jacobian.py).
Pardiso: the same, by MKL PARDISO (``pypardiso``, the optional extra ``facesim[pardiso]``) on
the upper triangle, by Cholesky where the matrix is positive definite and as a symmetric
indefinite matrix (LDL^T) where it is not: supernodal, METIS-ordered and threaded,
~8x faster to factorise than SuperLU on the medium face's tangent and the direct solver that
still fits the paper-resolution face (benchmarks/RESULTS.md).

BLAS threads: every solve runs with the BLAS limited to one thread (:func:`single_blas_thread`).
OpenBLAS threads level-1 operations above 10,000 entries; CG does two dot products per
iteration, and on two cores already busy with numba kernels (or other processes) each one then
cost ~1-5 ms instead of ~7 us: on the coarse face that was a quarter of an inverse frame.
"""

from __future__ import annotations

import contextlib
import os
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from facesim.errors import FacesimError, SolverError

SOLVERS = ("amg", "direct", "pardiso")

_BLAS = None


def single_blas_thread():
    """Context manager limiting the BLAS library to one thread (no-op without ``threadpoolctl``).

    Sparse solves do their heavy work in single-threaded C (SuperLU, pyamg smoothers, sparse
    mat-vecs); the BLAS calls between them are short vector operations whose threading only
    adds synchronisation, which is ruinous when the cores are busy."""
    global _BLAS
    if _BLAS is None:
        try:
            from threadpoolctl import ThreadpoolController

            _BLAS = ThreadpoolController()
        except ImportError:   # optional: only speed depends on it
            _BLAS = False
    return _BLAS.limit(limits=1, user_api="blas") if _BLAS else contextlib.nullcontext()


@dataclass
class LinearStats:
    setups: int = 0
    solves: int = 0
    iterations: list = field(default_factory=list)
    setup_seconds: float = 0.0
    solve_seconds: float = 0.0


def counted_cg(A, b, rtol: float, maxiter: int, M) -> tuple[np.ndarray, int, int]:
    """CG on ``A x = b`` preconditioned by ``M`` to relative residual ``rtol``, BLAS on one thread;
    returns ``(x, info, iterations)`` (``info`` as scipy's: 0 converged)."""
    it = [0]

    def count(_):
        it[0] += 1

    with single_blas_thread():
        x, info = spla.cg(A, b, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=count)
    return x, info, it[0]


class AMGSolver:
    """CG preconditioned by a reusable pyamg smoothed-aggregation hierarchy."""

    def __init__(self, maxiter: int = 500, rebuild_factor: float = 2.0, smooth: str = "energy",
                 direct_below: int = 3000, stats: LinearStats | None = None):
        self.direct_below = int(direct_below)   # tiny systems: a sparse LU beats any hierarchy
        self.maxiter = int(maxiter)
        self.rebuild_factor = float(rebuild_factor)
        self.smooth = smooth
        self.ml = None
        self.base_iterations = None
        self.stale = False
        self.stats = stats if stats is not None else LinearStats()
        self._direct = DirectSolver(self.stats)

    def setup(self, A: sp.bsr_matrix, B: np.ndarray) -> None:
        import pyamg

        t = time.perf_counter()
        # coarse level by sparse LU: pyamg's default dense pinv is slow when BLAS threads compete
        self.ml = pyamg.smoothed_aggregation_solver(A, B=B, smooth=self.smooth, max_coarse=300,
                                                    coarse_solver="splu")
        self.base_iterations = None
        self.stale = False
        self.stats.setups += 1
        self.stats.setup_seconds += time.perf_counter() - t

    def _cg(self, A, b, rtol):
        return counted_cg(A, b, rtol, self.maxiter, self.ml.aspreconditioner(cycle="V"))

    def solve(self, A, b: np.ndarray, B: np.ndarray, rtol: float = 1e-8) -> np.ndarray:
        """Solve ``A x = b`` to relative residual ``rtol``; reuse or rebuild the hierarchy."""
        if A.shape[0] < self.direct_below:
            return self._direct.solve(A, b)
        if self.ml is None or self.ml.levels[0].A.shape != A.shape or self.stale:
            self.setup(A, B)
        # otherwise the hierarchy of an earlier matrix preconditions this one: still SPD, and
        # close enough while the iteration count stays low
        t = time.perf_counter()
        x, info, it = self._cg(A, b, rtol)
        if info != 0 and self.base_iterations is not None:   # too stale to converge: rebuild now
            self.setup(A, B)
            x, info, it = self._cg(A, b, rtol)
        # slow but converged: rebuild before the next solve rather than solving this one twice.
        # Cost is compared per digit of residual reduction (Newton tightens rtol as it converges).
        per_digit = it / max(1.0, -np.log10(max(rtol, 1e-16)))
        self.stale = self.base_iterations is not None and per_digit > self.rebuild_factor * max(self.base_iterations, 2.0)
        if self.base_iterations is None:
            self.base_iterations = per_digit
        self.stats.solves += 1
        self.stats.iterations.append(it)
        self.stats.solve_seconds += time.perf_counter() - t
        if info != 0:
            raise SolverError(f"linear solve: CG did not reach rtol {rtol:g} in {self.maxiter} iterations")
        return x

    def solve_many(self, A, b: np.ndarray, B: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
        """Solve ``A X = b`` for the columns of ``b (N, k)`` against one fresh hierarchy of ``A``."""
        if A.shape[0] < self.direct_below:
            return self._direct.solve_many(A, b)
        self.setup(A, B)
        return np.column_stack([self.solve(A, b[:, j], B, rtol) for j in range(b.shape[1])]) if b.shape[1] else \
            np.zeros_like(b)


def factorize(A) -> spla.SuperLU:
    """Sparse LU of the symmetric matrix ``A`` (any scipy format): symmetric mode, minimum degree
    ordering of A^T + A, a diagonal pivot kept while it is at least 0.1 of its column's largest
    entry (always, for the positive definite tangents of the face: no pivoting cost, and still
    stable for an indefinite tangent). ``.solve(b)`` takes ``(N,)`` or ``(N, k)``."""
    with single_blas_thread():
        try:
            return spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1,
                             options={"SymmetricMode": True})
        except RuntimeError as exc:   # "Factor is exactly singular"
            raise SolverError(f"linear solve: LU factorisation failed ({exc})") from None


_MKL = None
NO_PARDISO = "linear solver 'pardiso' needs the pypardiso package: pip install 'facesim[pardiso]'"


def _mkl_threads(n: int):
    """Context manager: MKL (PARDISO's library) limited to ``n`` threads; the controller is made
    once, after pypardiso has loaded MKL, so it sees it."""
    global _MKL
    if _MKL is None:
        try:
            _import_pypardiso()
            from threadpoolctl import ThreadpoolController

            _MKL = ThreadpoolController().select(internal_api="mkl")
        except ImportError:
            _MKL = False
    return _MKL.limit(limits=n) if _MKL else contextlib.nullcontext()


def _compute_threads() -> int:
    """Threads the process may use for one heavy kernel: numba's setting (one per dask worker)."""
    import numba

    return int(numba.get_num_threads())


#: factor entries from which PARDISO's triangular solves run on :func:`_compute_threads` threads:
#: the medium face's factor (14.6M) solves 1.5x faster on two, the coarse face's (2.2M) no faster,
#: and there the idle MKL threads' spinning only competes with numba's (benchmarks/RESULTS.md, session 31)
THREADED_SOLVE_ABOVE = 5_000_000


def _solve_threads(factor_nonzeros: int) -> int:
    """MKL threads for PARDISO's triangular solves with a factor of ``factor_nonzeros`` entries:
    ``FACESIM_SOLVE_THREADS`` if set (1 is the single-threaded solve of before), else
    :func:`_compute_threads` from ``THREADED_SOLVE_ABOVE`` entries and 1 below.
    Two threads: the paper-size face's tracked frames 20.5 against 27.2 s, its cold frame 82
    against 108 s, the coarse demo clip unchanged (benchmarks/RESULTS.md, session 31)."""
    value = os.environ.get("FACESIM_SOLVE_THREADS", "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise FacesimError(f"FACESIM_SOLVE_THREADS={value!r}: expected a whole number of threads") from None
    if factor_nonzeros < THREADED_SOLVE_ABOVE:
        return 1
    return _compute_threads()


def _import_pypardiso():
    """``import pypardiso`` (ImportError when absent), told first where pip's mkl put ``mkl_rt``
    (this environment's ``lib``, or ``Library/bin`` on Windows) when ``PYPARDISO_MKL_RT`` does not
    say: importing it makes a solver, which otherwise searches the whole ``sys.prefix`` tree for
    the library (1-2 s at every start)."""
    import sys

    if "pypardiso" not in sys.modules and "PYPARDISO_MKL_RT" not in os.environ:
        import ctypes
        import glob

        found = [path for pattern in ("lib/libmkl_rt.so*", "lib/libmkl_rt*.dylib", "Library/bin/mkl_rt*.dll")
                 for path in sorted(glob.glob(os.path.join(sys.prefix, pattern)), reverse=True)]
        for path in found:
            try:
                ctypes.CDLL(path)
            except OSError:
                continue
            os.environ["PYPARDISO_MKL_RT"] = path
            break
    import pypardiso

    return pypardiso


def pardiso_available() -> bool:
    """Whether the optional MKL PARDISO backend (``pip install 'facesim[pardiso]'``) is installed."""
    try:
        _import_pypardiso()
    except ImportError:
        return False
    return True


_PARDISO = None   # MKL's pardiso and pardisoinit, typed; loaded once


def _mkl_pardiso():
    """MKL's ``pardiso`` and ``pardisoinit`` from the ``mkl_rt`` library pypardiso finds (the
    ``facesim[pardiso]`` extra). facesim calls them itself: pypardiso passes double precision only,
    and the single-precision factors below halve the cost of a triangular solve. The library's path
    is kept in ``PYPARDISO_MKL_RT`` (this process and its children), which pypardiso reads first:
    without it every lookup searches the whole ``sys.prefix`` tree again (0.45 s each)."""
    global _PARDISO
    if _PARDISO is None:
        import ctypes

        try:
            pypardiso = _import_pypardiso()
        except ImportError:
            raise FacesimError(NO_PARDISO) from None
        lib = pypardiso.PyPardisoSolver(mtype=-2).libmkl
        ptr, i32 = ctypes.c_void_p, ctypes.POINTER(ctypes.c_int32)
        fn = lib.pardiso
        fn.restype = None
        fn.argtypes = [ptr, i32, i32, i32, i32, i32, ptr, ptr, ptr, ptr, i32, ptr, i32, ptr, ptr, i32]
        init = lib.pardisoinit
        init.restype = None
        init.argtypes = [ptr, i32, ptr]
        _PARDISO = (fn, init, getattr(lib, "_name", None))
    if _PARDISO[2] and "PYPARDISO_MKL_RT" not in os.environ:
        os.environ["PYPARDISO_MKL_RT"] = str(_PARDISO[2])
    return _PARDISO[:2]


REFINE_RTOL = 1e-10   # relative residual a PARDISO solve refines to (the face: one step from ~1e-6)
REFINE_STEPS = 6
SKETCH_ABOVE = 1e-8   # PardisoFactor.solve: tolerances above this check a many-column solve by a sketch first
#: columns from which PARDISO solves a block of right-hand sides in one call; fewer are solved one
#: by one: its block path cost 2-3 columns' time per column below ~8 (the coarse face's tangent:
#: 1 column 2.0 ms, 3 in one call 9.2 ms, 35 in one call 47 ms; its scalar Laplacian: 1 column
#: 0.6 ms, 3 in one call 4.5 ms; benchmarks/RESULTS.md, session 33)
BLOCK_SOLVE_FROM = 8


def _pardiso_error(error: int, spd: bool = False) -> str:
    """PARDISO's error code in words, e.g. ``error -4: zero pivot``."""
    what = {-4: "zero pivot: not positive definite" if spd else "zero pivot",
            -2: "not enough memory", -1: "inconsistent input"}.get(error, "")
    return f"error {error}{': ' + what if what else ''}"


class _PardisoHandle:
    """One PARDISO instance (its ``pt``): ``factorize`` runs the ordering, the symbolic and the
    numerical factorisation (phase 12) of one matrix of ``mtype``; ``call`` any later phase.
    Freed (phase -1) when collected. (Sharing one analysis among several factors of the same
    pattern, PARDISO's ``maxfct``, was tried: after a failed Cholesky in one of its slots MKL
    crashed in the next factorisation, so each factor has its own.)"""

    def __init__(self, indptr, indices, mtype: int, single: bool):
        import ctypes

        self._pardiso, init = _mkl_pardiso()
        self.n = len(indptr) - 1
        self.indptr, self.indices = indptr, indices
        self.mtype = int(mtype)
        self.dtype = np.float32 if single else np.float64
        self.pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        init(self.pt.ctypes.data, ctypes.byref(ctypes.c_int32(self.mtype)), self.iparm.ctypes.data)
        self.iparm[0] = 1     # the settings below, not all defaults
        self.iparm[7] = 0     # no iterative refinement inside (done by PardisoFactor, in double, when wanted)
        self.iparm[17] = -1   # report the factor's nonzeros
        self.iparm[27] = 1 if single else 0
        self.iparm[34] = 1    # zero-based indices
        self.perm = np.zeros(self.n, dtype=np.int32)
        self._live = False

    def factorize(self, data) -> int:
        """Phase 12 of ``data`` (the upper triangle's values); PARDISO's error code (0: done)."""
        self._live = True   # from here on phase -1 frees what the phases allocated
        with _mkl_threads(_compute_threads()):   # the factorisation is worth its threads (1.75x on 2 cores)
            return self.call(12, data, np.zeros((self.n, 1), dtype=self.dtype), check=False)[1]

    def call(self, phase: int, data, b, check: bool = True):
        """PARDISO's ``phase``; returns ``(x, error)`` (raises on an error when ``check``)."""
        import ctypes

        x = np.zeros_like(b)
        error = ctypes.c_int32(0)
        one = ctypes.c_int32(1)
        self._pardiso(self.pt.ctypes.data, ctypes.byref(one), ctypes.byref(one), ctypes.byref(ctypes.c_int32(self.mtype)),
                      ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(self.n)),
                      data.ctypes.data, self.indptr.ctypes.data, self.indices.ctypes.data,
                      self.perm.ctypes.data, ctypes.byref(ctypes.c_int32(1 if b.ndim == 1 else b.shape[1])),
                      self.iparm.ctypes.data, ctypes.byref(ctypes.c_int32(0)), b.ctypes.data, x.ctypes.data,
                      ctypes.byref(error))
        if check and error.value != 0:
            raise SolverError(f"linear solve: PARDISO failed in phase {phase} ({_pardiso_error(error.value)})")
        return x, error.value

    def __del__(self):
        if getattr(self, "_live", False):
            try:
                self.call(-1, np.zeros(1, dtype=self.dtype), np.zeros(1, dtype=self.dtype), check=False)
            except Exception:   # interpreter shutdown: nothing left to free
                pass


def _upper_with_diagonal(A) -> sp.csr_matrix:
    """The upper triangle of ``A`` as sorted CSR without duplicates, every diagonal entry stored:
    PARDISO wants the zeros too (a missing one crashes its analysis; COO to CSR keeps explicit zeros)."""
    U = sp.triu(A, format="csr")
    U.sum_duplicates()
    U.sort_indices()
    n = int(A.shape[0])
    if not (np.diff(U.indptr) > 0).all() or not (U.indices[U.indptr[:-1]] == np.arange(n)).all():
        U = U.tocoo()
        U = sp.csr_matrix((np.r_[U.data, np.zeros(n)], (np.r_[U.row, np.arange(n)], np.r_[U.col, np.arange(n)])),
                          shape=A.shape)
        U.sum_duplicates()
        U.sort_indices()
    return U


class PardisoFactor:
    """MKL PARDISO factorisation of the symmetric matrix ``A``, in single precision by default:
    Cholesky (PARDISO's ``mtype`` 2) first -- the projected Newton tangents and the true tangent
    at a stable equilibrium are positive definite -- and, where a pivot is not positive (an
    indefinite true tangent), the symmetric indefinite LDL^T with Bunch-Kaufman pivots (``mtype``
    -2); ``cholesky`` says which. On the paper-size face's tangent Cholesky factorises in 12.0 s
    against 12.3 s and solves in 0.15 s against 0.18 s (benchmarks/RESULTS.md, session 23); a failed
    attempt costs up to one more factorisation.

    ``solve(b)`` (``(N,)`` or ``(N, k)``, like SuperLU's) is accurate to double precision: a
    single-precision solve, then iterative refinement against ``A`` in double to a relative
    residual of ``REFINE_RTOL`` (the face's tangents: ~1e-6 after the first solve, ~1e-11 after one
    refinement step; an ill-conditioned indefinite matrix takes more).
    ``precondition(b)`` is the single-precision solve alone, for a preconditioner or a chord
    iteration, where the outer iteration checks the residual in double anyway. On the coarse
    face's tangent (14,766 unknowns): factorisation 58 ms against 79 ms in double, a solve
    1.4 ms against 2.3 ms, half the factor's memory (benchmarks/RESULTS.md, session 22).
    ``single=False``: a double-precision factor, whose ``solve`` is exact to round-off without
    refinement (MKL's two refinement steps are skipped when no pivot was perturbed: they only
    tripled a solve's cost). ``spd=False`` skips the Cholesky attempt (a matrix known to be
    indefinite), ``spd=True`` raises :class:`SolverError` rather than fall back. The factor lives
    in PARDISO's memory until this object is collected."""

    def __init__(self, A, single: bool = True, spd: bool | None = None):
        # the matrix as given (no copy of a float64 sparse matrix: the paper-size tangent's CSR is
        # 0.36 GB) for the refinement's residual, until release_matrix
        A = A if sp.issparse(A) and A.dtype == np.float64 else sp.csr_matrix(A, dtype=np.float64)
        self.full = A
        U = _upper_with_diagonal(A)
        n = int(A.shape[0])
        self.shape = A.shape
        self.n = n
        self.single = bool(single)
        self.dtype = np.float32 if self.single else np.float64
        self.data = U.data.astype(self.dtype)
        indptr, indices = U.indptr.astype(np.int32), U.indices.astype(np.int32)
        del U   # not kept through the factorisation (its float64 copy: 0.27 GB at paper size)
        for mtype in ((2, -2) if spd is None else (2,) if spd else (-2,)):
            handle = _PardisoHandle(indptr, indices, mtype, self.single)
            error = handle.factorize(self.data)
            if error != -4:
                break
            del handle   # a pivot not positive: not positive definite, the indefinite factorisation next
        if error == 0 and self.single and handle.iparm[13] > 0:
            # perturbed pivots (a nearly singular indefinite matrix): refinement from a single factor
            # may then diverge (a zero-diagonal saddle matrix: 68x the right-hand side), the double
            # factor solves it to round-off -- so the double factor
            self.single, self.dtype = False, np.float64
            self.data = _upper_with_diagonal(self.full).data
            handle = _PardisoHandle(indptr, indices, mtype, False)
            error = handle.factorize(self.data)
        if error != 0:
            raise SolverError(f"linear solve: PARDISO factorisation failed ({_pardiso_error(error, spd=bool(spd))})")
        self._handle = handle
        self.cholesky = mtype == 2
        self.perturbed = int(handle.iparm[13])
        self._nonzeros = int(handle.iparm[17])

    @property
    def factor_nonzeros(self) -> int:
        return self._nonzeros

    def precondition(self, b) -> np.ndarray:
        """``A^-1 b`` to the factor's precision (single: relative residual ~1e-6)."""
        b = np.asarray(b, dtype=np.float64)
        rhs = np.asfortranarray(b, dtype=self.dtype) if b.ndim == 2 else np.ascontiguousarray(b, dtype=self.dtype)
        # the triangular solves of a large factor on numba's threads too: on two cores 1.5x faster
        # from the medium face's factor up (paper size 0.17-0.20 s against 0.29-0.32 s)
        with _mkl_threads(_solve_threads(self._nonzeros)):
            if rhs.ndim == 2 and 1 < rhs.shape[1] < BLOCK_SOLVE_FROM:
                x = np.column_stack([self._handle.call(33, self.data, rhs[:, j])[0] for j in range(rhs.shape[1])])
            else:
                x = self._handle.call(33, self.data, rhs)[0]
        return np.ascontiguousarray(x, dtype=np.float64)

    def release_matrix(self) -> None:
        """Drop the reference to ``A`` kept for :meth:`solve`'s refinement, where only
        :meth:`precondition` will be used (a factor kept for chord iterations or as a
        preconditioner); :meth:`solve` then raises."""
        self.full = None

    def solve(self, b, rtol: float = REFINE_RTOL) -> np.ndarray:
        """``A^-1 b`` to double precision: refined until the relative residual is ``rtol`` (default
        ``REFINE_RTOL``; or stops halving) after a single-precision solve or a perturbed pivot.

        With several columns and ``rtol`` above ``SKETCH_ABOVE`` the single-precision solve is first
        checked on one random combination of its columns, each scaled to unit right-hand side (one
        matrix-vector product: the estimate's square is the columns' mean squared relative residual),
        and kept when that is within ``rtol / sqrt(k)`` -- so no column's, in expectation, exceeds
        ``rtol``. The paper-size tangent's 35 Jacobian columns: 2.0 s against 8.1 s refined
        (benchmarks/RESULTS.md, session 25)."""
        b = np.asarray(b, dtype=np.float64)
        x = self.precondition(b)
        if not (self.single or self.perturbed):   # a perturbed pivot: the double factor is not exact either
            return x
        if self.full is None:
            raise SolverError("linear solve: this PARDISO factor's matrix was released (release_matrix): "
                              "it only preconditions")
        size = np.maximum(np.linalg.norm(b, axis=0), 1e-300)
        if b.ndim == 2 and b.shape[1] > 1 and rtol > SKETCH_ABOVE:
            w = np.random.default_rng(0).standard_normal(b.shape[1]) / size
            bw = b @ w
            estimate = float(np.linalg.norm(bw - self.full @ (x @ w))) / max(float(np.linalg.norm(bw)), 1e-300)
            if estimate <= rtol / np.sqrt(b.shape[1]):
                return x
        last = np.inf
        for _ in range(REFINE_STEPS):
            r = b - self.full @ x
            worst = float((np.linalg.norm(r, axis=0) / size).max())
            if worst <= rtol or worst >= 0.5 * last:   # there, or no longer converging
                break
            x += self.precondition(r)
            last = worst
        return x

class DirectSolver:
    """Sparse LU (SuperLU) of every matrix it is given, or with ``backend="pardiso"`` an MKL PARDISO
    factorisation; ``stats`` may be shared with another solver. The last factorisation stays in
    ``lu`` (a caller may solve more right-hand sides with it)."""

    def __init__(self, stats: LinearStats | None = None, backend: str = "superlu"):
        self.stats = stats if stats is not None else LinearStats()
        self.lu = None
        self.backend = backend

    def factorize(self, A):
        t = time.perf_counter()
        self.lu = PardisoFactor(A) if self.backend == "pardiso" else factorize(A)
        self.stats.setups += 1
        self.stats.setup_seconds += time.perf_counter() - t
        return self.lu

    def solve(self, A, b: np.ndarray, B=None, rtol: float = 0.0) -> np.ndarray:
        """``A^-1 b`` by a new factorisation of ``A``: exact (SuperLU), or for PARDISO to the relative
        residual ``rtol`` where that is above its refinement's ``REFINE_RTOL`` (0: that)."""
        lu = self.factorize(A)
        t = time.perf_counter()
        with single_blas_thread():
            x = lu.solve(b, rtol=max(rtol, REFINE_RTOL)) if isinstance(lu, PardisoFactor) else lu.solve(b)
        self.stats.solves += 1
        self.stats.iterations.append(1)
        self.stats.solve_seconds += time.perf_counter() - t
        return x

    def solve_many(self, A, b: np.ndarray, B=None, rtol: float = 0.0) -> np.ndarray:
        """Solve ``A X = b`` for all columns of ``b (N, k)`` with one factorisation."""
        return self.solve(A, np.asarray(b, dtype=np.float64), B, rtol)


def preconditioner(factor):
    """The cheapest application of ``factor``'s inverse: a :class:`PardisoFactor`'s solve at its
    own precision, else ``factor.solve`` (SuperLU's, exact)."""
    return getattr(factor, "precondition", factor.solve)


#: unknowns above which FactorPCG, too far from the factor it was given, solves by AMG-CG rather
#: than make a second factorisation (memory: two factors of the paper-size face's tangent and a
#: factorisation's workspace set its peak, benchmarks/RESULTS.md session 24)
FACTOR_PCG_AMG_ABOVE = 200_000


class FactorPCG:
    """CG preconditioned by the factorisation of a nearby matrix, refactorised where it stops being near.

    Made for the Newton solves that follow a failed chord solve (:func:`~facesim.inverse.jacobian.near_equilibrium`):
    the tangent factorised for the frame's Jacobian (``factor``, anything with ``.solve(b)``) first
    preconditions CG; when CG needs more than ``maxiter`` iterations the matrix of that Newton step
    is factorised (PARDISO when installed, else SuperLU), solved directly, and its factor
    preconditions the steps after it. A Newton step then costs an assembly and a few triangular
    solves, or one factorisation -- not an AMG set-up and tens of V-cycles (benchmarks/RESULTS.md,
    session 22). The factor it makes is its own: ``factor`` is never changed. Above ``amg_above``
    unknowns (default :data:`FACTOR_PCG_AMG_ABOVE`) a step too far from the given factor is solved
    by AMG-CG instead, and so are all later steps: a second factor beside the caller's set the
    paper-size face's peak memory -- unless the factor came from ``owner`` (an object whose
    ``tangent`` attribute holds it, e.g. an :class:`~facesim.inverse.jacobian.EquilibriumJacobian`)
    and dropping it there frees it: then that step is factorised after all (one factor at a time)
    and the new factor becomes ``owner.tangent`` (its ``tangent_at``, if any, set to None: it was
    made inside this solve), a nearer tangent for the owner's later chord solves. The paper-size
    face's cold frame: its first trial's Newton as fast as by AMG-CG, the peak 0.8 GB lower, and
    the next trial 3.8 s against 11.9 s on the nearer factor (benchmarks/RESULTS.md, session 25)."""

    def __init__(self, factor=None, maxiter: int = 25, backend: str | None = None,
                 amg_above: int | None = None, owner=None):
        self.owner = owner
        self.factor = owner.tangent if owner is not None and factor is None else factor
        self.maxiter = int(maxiter)
        self.backend = backend or ("pardiso" if pardiso_available() else "superlu")
        self.stats = LinearStats()
        self.amg_above = FACTOR_PCG_AMG_ABOVE if amg_above is None else int(amg_above)
        self.amg = None

    def _release_owner(self) -> bool:
        """Drop the given factor here and at ``owner``; True if that freed it (no one else holds
        it), else both references are restored."""
        if self.owner is None or getattr(self.owner, "tangent", None) is not self.factor:
            return False
        try:
            ref = weakref.ref(self.factor)
        except TypeError:   # a factor that takes no weak reference: its holders are unknown
            return False
        self.factor = None
        self.owner.tangent = None
        if ref() is None:
            if getattr(self.owner, "tangent_at", None) is not None:
                self.owner.tangent_at = None
            return True
        self.factor = self.owner.tangent = ref()
        return False

    def solve(self, A, b: np.ndarray, B=None, rtol: float = 1e-8) -> np.ndarray:
        if self.amg is not None:   # the given factor was too far once: so it stays (the Newton moves on)
            return self.amg.solve(A, b, B, rtol)
        t = time.perf_counter()
        x, info, its = None, 1, 0
        if self.factor is not None:
            M = spla.LinearOperator(A.shape, matvec=preconditioner(self.factor), dtype=np.float64)
            x, info, its = counted_cg(A, b, rtol, self.maxiter, M)
            del M   # it holds the factor (its bound solve): not past here, where the factor may be freed
        if info != 0 or not np.isfinite(x).all():   # no factor, or too far from it
            self.stats.solve_seconds += time.perf_counter() - t
            adopt = False
            if self.factor is not None and A.shape[0] > self.amg_above:
                adopt = self._release_owner()
                if not adopt:
                    # too far from the given factor on a large system: AMG-CG, not a second factor
                    # beside the caller's (the paper-size face: 1.6 GB more at the cold frame's peak)
                    self.amg = AMGSolver(stats=self.stats)
                    return self.amg.solve(A, b, B, rtol)
            # else a factor of A
            # a factor made here before is dropped first: two of them beside the caller's would
            # be 3 at once (the paper-size face: 1.9 GB each, the cold frame's peak 7.0 GB)
            self.factor = None
            self.factor = DirectSolver(self.stats, self.backend).factorize(A)   # counted as a set-up
            t = time.perf_counter()
            with single_blas_thread():
                x = self.factor.solve(b)
            if hasattr(self.factor, "release_matrix"):   # from here on it only preconditions
                self.factor.release_matrix()
            if adopt:
                self.owner.tangent = self.factor
            its += 1
        self.stats.solves += 1
        self.stats.iterations.append(its)
        self.stats.solve_seconds += time.perf_counter() - t
        return x


def make_linear_solver(kind: str):
    if kind == "amg":
        return AMGSolver()
    if kind == "direct":
        return DirectSolver()
    if kind == "pardiso":
        if not pardiso_available():
            raise FacesimError(NO_PARDISO)
        return DirectSolver(backend="pardiso")
    raise FacesimError(f"linear_solver: expected one of {SOLVERS}, got {kind!r}")
