"""Newton's method on a sum of energy terms over a :class:`DofSystem`.

Each step solves ``H du = -g`` with the PSD-projected Hessian (so CG applies), limits the step
so no valid element reaches zero volume, and backtracks on the total energy (Armijo).
Convergence: ``|g| <= rtol * force_scale + atol`` on the free components, where
``force_scale`` is the caller's reference force (the equilibrium solver passes the residual of
the cold start, so "relative" means relative to what the load does to the rest shape).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from facesim.budget import TIME_LIMIT, check_seconds, expired
from facesim.errors import FacesimError, SolverError
from facesim.fem.linear import SOLVERS, make_linear_solver
from facesim.fem.system import DofSystem


@dataclass(frozen=True)
class NewtonOptions:
    """Options of the nonlinear solve (forces in N, lengths in mm).

    rtol : relative force residual to reach; atol : absolute floor (N).
    max_iterations : Newton steps before giving up (the result is flagged, not raised).
    settle_iterations : further steps allowed once, at ``max_iterations``, to a solve whose relative
        residual is already below :data:`SETTLE_BELOW` (the last approach: e.g. lips pressed
        together sliding into place across the facets of each other's meshes, where every facet
        crossing costs Newton a short step). Such a solve is converging, only slowly; giving up
        there threw its progress away for a restart (substeps) from the start state.
    linear_solver : ``"amg"`` (pyamg + CG, default) or ``"direct"`` (SuperLU).
    linear_rtol : CG tolerance cap; each step uses ``min(linear_rtol, rel residual)`` (inexact
        Newton with a forcing term that keeps quadratic convergence).
    project : ``"auto"`` (default): PSD-projected element Hessians while far from equilibrium
        (the true tangent is indefinite for compressed, inverted or over-stretched active tets),
        then the true tangent once the relative residual is below ``true_tangent_below`` (it is
        positive definite at a stable equilibrium and restores quadratic convergence; a
        non-descent direction, an indefinite matrix or a failed line search switches back to
        projection until the residual has dropped tenfold more, or for ``true_tangent_retry``
        steps). ``True`` always projects, ``False`` never does.
    true_tangent_retry : projected steps after a failed true-tangent step before the true tangent
        is tried again, even though the residual has not dropped tenfold (0: not before it has).
        Lips sliding into place across each other's facets stall for a hundred projected steps
        at a relative residual of ~1e-3 (alpha 1/128); retried after 5, the true tangent takes
        over from there (benchmarks/RESULTS.md, session 28).
    step_fraction : fraction of the largest inversion-free step tried first.
    min_limited_step : below this the limit is ignored and the full step is tried first.
    max_seconds : wall-clock budget of one equilibrium (s; None: none but the caller's, see
        :mod:`facesim.budget`); a solve out of time stops with ``stop_reason`` ``"time_limit"``.
    """

    rtol: float = 1e-6
    atol: float = 1e-10
    max_iterations: int = 60
    settle_iterations: int = 60
    linear_solver: str = "amg"
    linear_rtol: float = 1e-2
    project: object = "auto"
    true_tangent_below: float = 1e-2
    true_tangent_retry: int = 5
    step_fraction: float = 0.9
    min_limited_step: float = 0.05
    armijo: float = 1e-4
    max_backtracks: int = 30
    max_seconds: float | None = None

    def __post_init__(self):
        if self.linear_solver not in SOLVERS:
            raise FacesimError(f"linear_solver: expected one of {SOLVERS}, got {self.linear_solver!r}")
        if self.project not in ("auto", True, False):
            raise FacesimError(f"project: expected 'auto', True or False, got {self.project!r}")
        if not (self.rtol >= 0 and self.atol >= 0 and self.max_iterations >= 1 and self.settle_iterations >= 0
                and self.true_tangent_retry >= 0):
            raise FacesimError("NewtonOptions: rtol, atol must be >= 0, max_iterations >= 1, settle_iterations and "
                               "true_tangent_retry >= 0")
        check_seconds(self.max_seconds, "NewtonOptions.max_seconds")


@dataclass
class SolveReport:
    """What a nonlinear solve did: convergence, residual history (N), energies (mJ), timings (s)."""

    converged: bool
    iterations: int
    residuals: list = field(default_factory=list)
    energies: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    projected: list = field(default_factory=list)
    linear_iterations: list = field(default_factory=list)
    force_scale: float = 1.0
    stop_reason: str = ""   # "converged", "iteration_limit", "line_search_failed" or "time_limit"
    seconds: dict = field(default_factory=dict)

    @property
    def relative_residual(self) -> float:
        """Last residual over ``force_scale`` (0 for a problem with no load that is at rest)."""
        if not self.residuals:
            return float("nan")
        r = self.residuals[-1]
        return r / self.force_scale if self.force_scale > 0 else (0.0 if r == 0 else float("inf"))

    def to_dict(self) -> dict:
        return {"converged": self.converged, "iterations": self.iterations,
                "relative_residual": self.relative_residual, "residuals": list(map(float, self.residuals)),
                "energies": list(map(float, self.energies)), "step_lengths": list(map(float, self.step_lengths)),
                "projected": list(map(bool, self.projected)),
                "linear_iterations": list(map(int, self.linear_iterations)), "force_scale": self.force_scale,
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


class Problem:
    """Total energy of ``terms`` (:class:`~facesim.energy.NodeTerm` s) at activations ``a`` over
    ``system``, with prescribed positions taken from ``x_fixed (n, 3)`` (free components of
    ``x_fixed`` are the starting guess).

    The matrix is every term's ``add_hessian`` blocks plus its ``sparse_hessian`` (couplings
    outside the mesh pattern, e.g. self-contact); the step limit is the smallest ``max_step``."""

    def __init__(self, terms, system: DofSystem, x_fixed: np.ndarray, a=None):
        self.terms = list(terms)
        self.system = system
        self.x_fixed = np.ascontiguousarray(x_fixed, dtype=np.float64)
        self.a = a
        self.timing = {"assembly": 0.0, "gradient": 0.0}

    def positions(self, u: np.ndarray) -> np.ndarray:
        return self.system.scatter(self.x_fixed, u)

    def energy(self, x) -> float:
        return float(sum(t.energy(x, self.a) for t in self.terms))

    def energy_and_gradient(self, x) -> tuple[float, np.ndarray]:
        t0 = time.perf_counter()
        e, g = 0.0, np.zeros_like(x)
        for t in self.terms:
            et, gt = t.energy_and_gradient(x, self.a)
            e += et
            g += gt
        self.timing["gradient"] += time.perf_counter() - t0
        return e, self.system.gather(g)

    def hessian(self, x, project: bool = True):
        t0 = time.perf_counter()
        data = self.system.new_data()
        extra = []
        for t in self.terms:
            t.add_hessian(x, self.a, self.system, data, project)
            H = t.sparse_hessian(x, self.a, self.system, project)
            if H is not None and H.nnz:
                extra.append(H)
        d = np.diagonal(data, axis1=1, axis2=2)   # a view (fancy indexing copied: 80 ms at paper size)
        diag = float(np.abs(d).mean()) if d.size else 1.0
        A = self.system.matrix(data, diag=diag if diag > 0 else 1.0)
        if extra:
            A = (A.tocsr() + sum(extra)).tobsr(blocksize=(3, 3))
        self.timing["assembly"] += time.perf_counter() - t0
        return A

    def max_step(self, x, du: np.ndarray) -> float:
        """Largest fraction of the step ``du (3N,)`` every term allows (``inf``: no limit)."""
        dx = np.zeros_like(x)
        dx[self.system.active] = du.reshape(-1, 3)
        return float(min((t.max_step(x, dx) for t in self.terms), default=np.inf))


#: the share of the residual left to the tolerance a Newton step's linear solve needs to reach
#: (its forcing term's floor): the step's nonlinear error adds the rest
LAST_STEP_SHARE = 0.1

#: relative residual below which a solve at its iteration limit is settling, not failing, and gets
#: ``NewtonOptions.settle_iterations`` more (measured: benchmarks/RESULTS.md, session 28)
SETTLE_BELOW = 1e-2


def newton(problem: Problem, options: NewtonOptions, force_scale: float, linear=None) -> tuple[np.ndarray, SolveReport]:
    """Minimise the problem's energy from its starting guess; returns ``(x (n, 3), report)``.

    ``linear`` may be a solver from :func:`~facesim.fem.linear.make_linear_solver` to reuse
    (an AMG hierarchy carries over between solves of similar systems). Bounded by
    ``options.max_iterations`` and by the enclosing :func:`facesim.budget.time_budget`, checked
    before every iteration."""
    t_start = time.perf_counter()
    sysm = problem.system
    linear = linear or make_linear_solver(options.linear_solver)
    lin_t0 = linear.stats.setup_seconds + linear.stats.solve_seconds
    u = problem.x_fixed[sysm.active].ravel().copy()
    x = problem.positions(u)
    E, g = problem.energy_and_gradient(x)
    rep = SolveReport(converged=False, iterations=0, force_scale=float(force_scale))
    tol = options.rtol * force_scale + options.atol
    rep.residuals.append(float(np.linalg.norm(g)))
    rep.energies.append(E)
    B = None
    allow_true = options.project == "auto"
    # The true tangent is tried below true_tangent_below; after it fails, only once the residual
    # has dropped tenfold from there or true_tangent_retry steps later (the projected tangent
    # converges only linearly: at the widest jaw opening of examples/02 by 3% per step, 300 steps
    # from 1e-2 to 1e-6)
    failed = None   # (relative residual, iterations done) when the true tangent last failed
    allowed = options.max_iterations
    while rep.residuals[-1] > tol:
        if rep.iterations >= allowed:
            if (allowed > options.max_iterations or not options.settle_iterations
                    or rep.residuals[-1] > SETTLE_BELOW * force_scale):
                break
            allowed += options.settle_iterations   # settling: once
        if expired():   # the frame's wall-clock budget (facesim.budget): stop, flagged
            rep.stop_reason = TIME_LIMIT
            break
        rel = rep.residuals[-1] / max(force_scale, 1e-300)
        true = allow_true and rel < options.true_tangent_below and (
            failed is None or rel < 0.1 * failed[0]
            or 0 < options.true_tangent_retry <= rep.iterations - failed[1])
        project = options.project is True or (options.project == "auto" and not true)
        A = problem.hessian(x, project)
        if B is None:
            B = sysm.rigid_modes(x)
        n_before = len(linear.stats.iterations)
        try:
            # inexact Newton: the forcing term min(linear_rtol, rel) keeps quadratic convergence, but
            # no more accurate than a tenth of what is left to the tolerance (the last step's CG
            # otherwise solves to rel ~ 1e-5..1e-4 where 1e-2 reaches it)
            du = linear.solve(A, -g, B, rtol=min(options.linear_rtol,
                                                 max(rel, LAST_STEP_SHARE * tol / rep.residuals[-1], 1e-12)))
        except SolverError:   # CG on an indefinite true tangent
            if project or options.project is False:
                raise
            failed = (rel, rep.iterations)   # the true tangent is not SPD here: project for a while
            continue
        rep.linear_iterations.extend(linear.stats.iterations[n_before:])
        du[~sysm.free_dof] = 0.0
        slope = float(g @ du)
        if slope >= 0:
            if not project and options.project == "auto":
                failed = (rel, rep.iterations)
                continue
            du = -g   # cannot happen with an SPD matrix; steepest descent as a last resort
            slope = -float(g @ g)
        # Step limiting: start where no valid tet inverts. If that is a small fraction of the step
        # (one tet squeezed between two bones can veto any progress), start from the full step:
        # the invertible energy is defined beyond inversion and the line search keeps it decreasing.
        limit = problem.max_step(x, du)
        alpha = 1.0 if limit >= 1.0 else options.step_fraction * limit
        if alpha < options.min_limited_step:
            alpha = 1.0
        for _ in range(options.max_backtracks):
            x_new = problem.positions(u + alpha * du)
            E_new, g_new = problem.energy_and_gradient(x_new)
            if E_new <= E + options.armijo * alpha * slope or abs(E_new - E) <= 1e-14 * abs(E):
                break
            alpha *= 0.5
        else:
            if not project and options.project == "auto":
                failed = (rel, rep.iterations)
                continue
            rep.iterations += 1
            rep.stop_reason = "line_search_failed"
            break   # line search failed: energy cannot decrease along du any more
        u = u + alpha * du
        x, E, g = x_new, E_new, g_new
        rep.iterations += 1
        rep.step_lengths.append(alpha)
        rep.projected.append(project)
        rep.residuals.append(float(np.linalg.norm(g)))
        rep.energies.append(E)
    rep.converged = rep.residuals[-1] <= tol
    if rep.converged:
        rep.stop_reason = "converged"
    elif not rep.stop_reason:
        rep.stop_reason = "iteration_limit"
    rep.seconds = {"total": time.perf_counter() - t_start, "assembly": problem.timing["assembly"],
                   "gradient": problem.timing["gradient"],
                   "linear": linear.stats.setup_seconds + linear.stats.solve_seconds - lin_t0}
    return x, rep
