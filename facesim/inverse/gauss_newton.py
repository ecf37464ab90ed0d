"""One frame of the inverse problem: controls whose equilibrium reproduces the markers
(Sifakis, Neverov, Fedkiw 2005 sections 5-7; PHYSICS.md section 4).

Objective over the control vector ``c`` (activations, jaw parameters, optional head increment,
see :class:`~facesim.inverse.jacobian.ControlSpace`)::

    F(c) = D(c) + mu B(c)
    D(c) = 1/2 sum_r w_r |P_r(x(c)) - T_r|^2          marker distance (mm^2), missing markers dropped
    B(c) = sum_i out(a_i, [0, 1])^2 + jaw penalty(q)   bound violations (activations, jaw model)

Each Gauss-Newton step linearises the markers with the implicit Jacobian ``P(c + dc) ~ P + J dc``
and minimises the linear model plus the penalty in control space. The penalty weight follows
the paper's progressive schedule inside that small problem: it starts at ``start_ratio`` times
the weight at which a unit bound violation costs as much as the marker noise, and grows by
``growth`` (5%) per nested step -- each nested step a Newton solve of the piecewise-quadratic
model warm-started from the last -- until it reaches ``final_ratio`` (1e6) times the data term.
The step is then searched along by golden section on the true objective, each trial point an
equilibrium warm-started from the interpolation of the bracketing equilibria.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.inverse.jacobian import ControlSpace, EquilibriumJacobian, equilibrium_jacobian

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class FitOptions:
    """max_steps : Gauss-Newton steps per frame; tolerance : stop when a step improves the objective
    by less than this fraction; step_tolerance : or when the largest control change is below this;
    noise : marker noise level (mm) the penalty schedule starts from; start_ratio, growth,
    final_ratio : the penalty schedule (see the module doc); golden_tolerance : bracket width, as a
    fraction of the step, where the golden-section search stops; max_step : the search interval is
    [0, max_step] of the Gauss-Newton step; damping : Levenberg-Marquardt regularisation of the
    linear model relative to its mean diagonal; linear_solver : for the Jacobian (None: automatic)."""

    max_steps: int = 5
    tolerance: float = 1e-3
    step_tolerance: float = 1e-3
    noise: float = 0.5
    start_ratio: float = 0.1
    growth: float = 1.05
    final_ratio: float = 1e6
    golden_tolerance: float = 0.1
    max_step: float = 2.0   # Gauss-Newton steps undershoot on stiffening muscles: search up to twice the step
    damping: float = 1e-6
    linear_solver: str | None = None

    def __post_init__(self):
        if not (self.growth > 1.0 and self.final_ratio > 0 and self.start_ratio > 0 and self.noise > 0):
            raise FacesimError("FitOptions: growth must be > 1 and start_ratio, final_ratio, noise > 0")
        if self.max_steps < 1 or not (0 < self.golden_tolerance < 1) or self.max_step <= 0:
            raise FacesimError("FitOptions: max_steps >= 1, 0 < golden_tolerance < 1, max_step > 0")


@dataclass
class FitReport:
    """What one frame's fit did."""

    gn_steps: int = 0
    equilibria: int = 0
    newton_iterations: int = 0
    linear_solves: int = 0
    marker_rms: float = float("nan")
    worst_violation: float = 0.0
    penalty_weight: float = 0.0
    schedule_steps: int = 0
    objective: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    converged: bool = False
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return {k: (list(map(float, v)) if isinstance(v, list) else v) for k, v in self.__dict__.items()}


@dataclass
class Fit:
    controls: Controls
    x: np.ndarray
    markers: np.ndarray
    report: FitReport
    jacobian: EquilibriumJacobian | None = None


class _Bounds:
    """The penalty B(c) and its derivatives: activations outside [0, 1], the jaw model's penalty."""

    def __init__(self, space: ControlSpace, jaw_model):
        self.space = space
        self.jaw_model = jaw_model if space.n_jaw else None

    def value_grad_hess(self, c):
        sa, sj, _ = self.space.slices()
        n = len(c)
        g, H = np.zeros(n), np.zeros((n, n))
        a = c[sa]
        ex = np.minimum(a, 0.0) + np.maximum(a - 1.0, 0.0)
        v = float(ex @ ex)
        g[sa] = 2 * ex
        H[sa, sa] = np.diag(2.0 * (ex != 0))
        if self.jaw_model is not None and hasattr(self.jaw_model, "penalty"):
            pv, pg, ph = self.jaw_model.penalty(c[sj])
            v += float(pv)
            g[sj] += pg
            H[sj, sj] += ph
        return v, g, H

    def violation(self, c) -> float:
        """Largest distance of a control outside its bounds (activations; jaw model bounds)."""
        sa, sj, _ = self.space.slices()
        a = c[sa]
        worst = float(np.max(np.maximum(-a, a - 1.0), initial=0.0))
        if self.jaw_model is not None and hasattr(self.jaw_model, "bounds"):
            lo, hi = np.asarray(self.jaw_model.bounds, dtype=np.float64).T
            q = c[sj]
            worst = max(worst, float(np.max(np.maximum(lo - q, q - hi), initial=0.0)))
        return max(worst, 0.0)


def schedule_penalty(r, J, c, bounds: _Bounds, options: FitOptions, w=None):
    """Minimise the linear model ``1/2 |r + J dc|_W^2 + mu B(c + dc)`` over ``dc`` with the
    progressive penalty schedule. Returns ``(dc, mu, nested steps)``.

    ``r (m,)`` current residual P - T (mm), ``J (m, nc)``. The start weight is the penalty at which
    a violation of one unit costs ``start_ratio`` times the noise energy ``noise^2`` (below the
    noise level), the final weight ``final_ratio`` times the data term at the model minimum."""
    w = np.ones(len(r)) if w is None else w
    JW = J * w[:, None]
    A = J.T @ JW
    A += options.damping * max(float(np.mean(np.diag(A))), 1e-12) * np.eye(len(c))
    b = JW.T @ r
    mu = options.start_ratio * options.noise ** 2
    dc = np.zeros(len(c))
    nested = 0
    while True:
        for _ in range(50):   # Newton on the piecewise-quadratic model (exact once the active set settles)
            v, g, H = bounds.value_grad_hess(c + dc)
            grad = A @ dc + b + mu * g
            step = np.linalg.solve(A + mu * H, -grad)
            dc = dc + step
            if np.abs(step).max() <= 1e-12 * (1.0 + np.abs(dc).max()):
                break
        nested += 1
        model = r + J @ dc
        data = 0.5 * float(model @ (w * model))
        if mu >= options.final_ratio * max(data, 1e-12):
            return dc, mu, nested
        mu *= options.growth


def _residual(model, x, targets, keep) -> np.ndarray:
    return (model.marker_positions(x)[keep] - targets[keep]).ravel()


def fit_frame(sim, targets, controls: Controls, x0=None, space: ControlSpace | None = None,
              options: FitOptions | None = None, weights=None, extra_terms=()) -> Fit:
    """Fit one frame: the controls (in ``space``, default all activations and the jaw model's
    parameters) whose equilibrium puts the model's markers on ``targets (r, 3)`` mm (NaN rows
    are missing markers), starting from ``controls`` and its equilibrium ``x0`` (solved if None).

    ``weights (r,)``: per-marker weights (default 1). Returns a :class:`Fit` with the final
    controls, positions, marker positions and the report; the Jacobian at the result is kept
    for the next frame."""
    t0 = time.perf_counter()
    options = options or FitOptions()
    model = sim.model
    targets = np.asarray(targets, dtype=np.float64)
    if targets.shape != (model.n_markers, 3):
        raise FacesimError(f"targets: expected ({model.n_markers}, 3) marker positions, got {targets.shape}")
    keep = np.isfinite(targets).all(axis=1)
    if keep.sum() < 3:
        raise FacesimError(f"targets: only {int(keep.sum())} markers present; need at least 3")
    w = np.ones(model.n_markers) if weights is None else np.asarray(weights, dtype=np.float64)
    w3 = np.repeat(w[keep], 3)
    space = space or ControlSpace.of(sim, jaw=bool(getattr(sim.jaw_model, "n_params", 0)))
    bounds = _Bounds(space, sim.jaw_model)
    rep = FitReport()
    rows = (3 * np.flatnonzero(keep)[:, None] + np.arange(3)).ravel()

    def solve(ctrl, warm):
        eq = sim.equilibrium(ctrl, x0=warm, extra_terms=extra_terms)
        rep.equilibria += 1
        rep.newton_iterations += eq.iterations
        rep.linear_solves += len(eq.report.linear_iterations)
        if not eq.converged:
            return None
        return eq.x

    def objective(c, x, mu):
        r = _residual(model, x, targets, keep)
        return 0.5 * float(r @ (w3 * r)) + mu * bounds.value_grad_hess(c)[0]

    x = solve(controls, x0) if x0 is None or not np.isfinite(x0).all() else np.asarray(x0, dtype=np.float64)
    if x is None:
        raise FacesimError("fit_frame: the starting controls have no converged equilibrium")
    c = space.vector(controls)
    base = controls
    mu = 0.0
    F = objective(c, x, mu)
    rep.objective.append(F)
    J = None
    for _ in range(options.max_steps):
        J = equilibrium_jacobian(sim, space.apply(base, c), x, space, extra_terms=extra_terms,
                                 linear_solver=options.linear_solver)
        rep.linear_solves += len(J.linear_iterations)
        r = _residual(model, x, targets, keep)
        dc, mu, nested = schedule_penalty(r, J.dP[rows], c, bounds, options, w3)
        rep.schedule_steps += nested
        F = objective(c, x, mu)   # the objective at the schedule's weight
        # golden-section search of F(c + alpha dc) on [0, max_step], equilibria warm-started from
        # the interpolation of the bracketing ones
        cache = {0.0: (F, x)}

        def at(alpha):
            if alpha in cache:
                return cache[alpha][0]
            done = sorted(cache)
            lo = max((s for s in done if s < alpha), default=0.0)
            hi = min((s for s in done if s > alpha), default=None)
            if hi is None:
                warm = J.predict(alpha * dc)
            else:
                t = (alpha - lo) / (hi - lo)
                warm = (1 - t) * cache[lo][1] + t * cache[hi][1]
            xa = solve(space.apply(base, c + alpha * dc), warm)
            cache[alpha] = (math.inf, None) if xa is None else (objective(c + alpha * dc, xa, mu), xa)
            return cache[alpha][0]

        a_, b_ = 0.0, options.max_step
        at(b_)
        x1, x2 = b_ - GOLDEN * (b_ - a_), a_ + GOLDEN * (b_ - a_)
        f1, f2 = at(x1), at(x2)
        while (b_ - a_) > options.golden_tolerance * options.max_step:
            if f1 <= f2:
                b_, x2, f2 = x2, x1, f1
                x1 = b_ - GOLDEN * (b_ - a_)
                f1 = at(x1)
            else:
                a_, x1, f1 = x1, x2, f2
                x2 = a_ + GOLDEN * (b_ - a_)
                f2 = at(x2)
        alpha = min(cache, key=lambda s: cache[s][0])
        F_new, x_new = cache[alpha]
        rep.gn_steps += 1
        rep.step_lengths.append(alpha)
        if alpha == 0.0 or x_new is None:
            break
        improvement = (F - F_new) / max(F, 1e-300)
        c, x, F = c + alpha * dc, x_new, F_new
        rep.objective.append(F)
        if improvement < options.tolerance or np.abs(alpha * dc).max() < options.step_tolerance:
            break
    rep.converged = True
    final = space.apply(base, c)
    P = model.marker_positions(x)
    rk = (P[keep] - targets[keep])
    rep.marker_rms = float(np.sqrt(np.mean(np.sum(rk ** 2, axis=1))))
    rep.worst_violation = bounds.violation(c)
    rep.penalty_weight = mu
    rep.seconds = time.perf_counter() - t0
    return Fit(final, x, P, rep, J)


__all__ = ["FitOptions", "FitReport", "Fit", "fit_frame", "schedule_penalty"]
