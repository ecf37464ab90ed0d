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
model warm-started from the last -- until it reaches ``final_ratio`` (1e6) times the data term
(while the active bounds stay the same, several 5% steps at a time: :func:`schedule_penalty`).
The step is then searched along by golden section on the true objective, each trial point an
equilibrium warm-started from the interpolation of the bracketing equilibria.

Speed (issue 5; the paper's figures: tracking frames usually take one Gauss-Newton step, the
line search ~10 % of the time):

* **Full step first.** The step ``dc`` is tried at length 1 (an equilibrium warm-started from the
  Jacobian's first-order prediction, or from the last equilibrium with the bones moved where that
  is nearer or the Jacobian is a nearby tangent's) and kept when the objective drops by at least
  ``accept_ratio`` of what the linear model predicted -- lengthened by one more trial where the
  markers moved less than predicted (stiffening tissue). When it fails, one backtracking trial at
  the minimum of the parabola through ``F(0)``, ``F'(0)``, ``F(1)``, and if that fails too the
  golden-section search on ``[0, 1]`` (``line_search="golden"`` always searches ``[0, max_step]``,
  as the paper does).
* **Jacobian reuse.** After every step the Jacobian is moved to the new equilibrium by a secant
  (Broyden) update, exact along the step, and serves the next step and the next frame
  (``fit_frame(..., jacobian=previous_fit.jacobian)``). It is evaluated anew when the secant
  mismatch of the last step ``|dP - J dc| / |J dc|`` exceeds ``jacobian_drift`` (the Jacobian
  changed along the step by about twice that), when it carries more than ``jacobian_max_age``
  updates, or when a step taken with an updated Jacobian fails the ratio test (the step is then
  redone with the exact one). After a drifted step the updated Jacobian first applies the
  stopping rule below: the exact one is evaluated only when another step is worth taking, else
  the updated one is handed to the next frame (whose first step is guarded by the ratio test).
* **Stopping without another step.** Before each step the linear model predicts its decrease;
  when that is below ``tolerance`` times the objective (or times the noise energy
  ``1/2 sum w noise^2``, when the fit is already at the noise level), or below
  ``1/2 (resolution noise)^2`` -- the step would move the controls by less than ``resolution``
  standard deviations of their estimate under the marker noise -- or the step is below
  ``step_tolerance``, the frame has converged: a tracked frame costs one step and one equilibrium.
* **Chord equilibria.** Trial equilibria first try chord iterations against the factorised tangent
  the direct Jacobian kept (:func:`~facesim.inverse.jacobian.near_equilibrium`: one gradient and
  a triangular solve per iteration, no assembly), falling back to Newton whose steps are solved by
  CG preconditioned with the same factor, refactorised where it no longer helps
  (:class:`~facesim.fem.linear.FactorPCG`; not the simulator's AMG: 14 % off the demo clip).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from facesim.budget import TIME_LIMIT, check_seconds, expired, time_budget
from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.fem.linear import FactorPCG, single_blas_thread
from facesim.inverse.head_frame import HeadFrame
from facesim.inverse.jacobian import ControlSpace, EquilibriumJacobian, equilibrium_jacobian, near_equilibrium

GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
#: why a fit stopped (``FitReport.stop_reason``): only ``"converged"`` is a converged frame
STOP_REASONS = ("converged", "step_limit", "line_search_failed", "equilibrium_failed", TIME_LIMIT)
ARMIJO = 1e-4              # sufficient decrease of a backtracking step, times its first-order decrease
EXTRAPOLATE_ABOVE = 1.03   # a kept full step is extended when the markers' response says it should be longer
EXTEND_TRIALS = 2          # by at most this many more equilibria


@dataclass(frozen=True)
class FitOptions:
    """max_steps : Gauss-Newton steps per frame; tolerance : stop when a step improves the objective
    by less than this fraction; step_tolerance : or when the largest control change is below this;
    noise : marker noise level (mm) the penalty schedule starts from; start_ratio, growth,
    final_ratio : the penalty schedule (see the module doc); golden_tolerance : bracket width, as a
    fraction of the step, where the golden-section search stops; max_step : the search interval is
    [0, max_step] of the Gauss-Newton step; damping : Levenberg-Marquardt regularisation of the
    linear model relative to its mean diagonal; linear_solver : for the Jacobian (None: automatic).
    line_search : ``"ratio"`` (keep the full step when it achieves ``accept_ratio`` of the predicted
    decrease, else golden section) or ``"golden"`` (always golden section); jacobian_max_age : secant
    updates a Jacobian may carry before it is evaluated anew (0: a new Jacobian at every step, as
    the paper); jacobian_drift : secant mismatch of a step above which the next step evaluates the
    Jacobian anew; chord : solve trial equilibria by chord iterations on the Jacobian's factorised
    tangent first; resolution : also stop when the next step would move the controls by less than
    this many standard deviations of their estimate under marker noise ``noise``; jacobian_rtol : CG
    tolerance of each Jacobian column when it is solved iteratively (above ``DIRECT_BELOW`` unknowns;
    a Gauss-Newton step needs a few digits, and the secant updates are approximate anyway);
    max_seconds : wall-clock budget of the fit (s; None: none but the caller's, see
    :mod:`facesim.budget`), after which it stops with ``stop_reason`` ``"time_limit"`` at its last
    accepted step. See the module doc."""

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
    line_search: str = "ratio"
    accept_ratio: float = 0.1
    jacobian_max_age: int = 8
    jacobian_drift: float = 0.1
    chord: bool = True
    resolution: float = 2.0
    jacobian_rtol: float = 1e-6   # CG tolerance per Jacobian column (AMG path; direct: DIRECT_COLUMN_RTOL)
    max_seconds: float | None = None

    def __post_init__(self):
        if not (self.growth > 1.0 and self.final_ratio > 0 and self.start_ratio > 0 and self.noise > 0):
            raise FacesimError("FitOptions: growth must be > 1 and start_ratio, final_ratio, noise > 0")
        if self.max_steps < 1 or not (0 < self.golden_tolerance < 1) or self.max_step <= 0:
            raise FacesimError("FitOptions: max_steps >= 1, 0 < golden_tolerance < 1, max_step > 0")
        if self.line_search not in ("ratio", "golden"):
            raise FacesimError(f"line_search: expected 'ratio' or 'golden', got {self.line_search!r}")
        if not (0 < self.accept_ratio < 1 and self.jacobian_max_age >= 0 and self.jacobian_drift > 0
                and self.resolution >= 0 and 0 < self.jacobian_rtol < 1):
            raise FacesimError("FitOptions: 0 < accept_ratio < 1, jacobian_max_age >= 0, jacobian_drift > 0, "
                               "resolution >= 0, 0 < jacobian_rtol < 1")
        check_seconds(self.max_seconds, "FitOptions.max_seconds")


@dataclass
class FitReport:
    """What one frame's fit did. ``newton_iterations`` and ``linear_solves`` include the chord
    iterations (``chord_iterations``); ``jacobians``: exact evaluations, ``secant_updates``: Broyden
    updates; ``full_steps``: steps kept at length 1 without a search. ``timing`` (s): ``equilibria``
    (the start and each step's first trial), ``jacobian`` (evaluations and updates), ``algebra``
    (penalty schedule, objective), ``line_search`` (golden-section trials beyond the first)."""

    gn_steps: int = 0
    equilibria: int = 0
    newton_iterations: int = 0
    linear_solves: int = 0
    chord_iterations: int = 0
    jacobians: int = 0
    secant_updates: int = 0
    full_steps: int = 0
    marker_rms: float = float("nan")
    worst_violation: float = 0.0
    penalty_weight: float = 0.0
    schedule_steps: int = 0
    objective: list = field(default_factory=list)
    step_lengths: list = field(default_factory=list)
    ratios: list = field(default_factory=list)   # per step: achieved / predicted decrease of the full step
    screened: list = field(default_factory=list)  # markers the first linear step flagged and dropped (``screen``)
    stop_reason: str = ""   # one of STOP_REASONS
    error: str = ""         # the numerical failure behind "equilibrium_failed"
    seconds: float = 0.0
    timing: dict = field(default_factory=lambda: dict.fromkeys(("equilibria", "jacobian", "algebra", "line_search"),
                                                               0.0))

    @property
    def converged(self) -> bool:
        """Whether the fit met its stopping rule (``stop_reason == "converged"``)."""
        return self.stop_reason == "converged"

    def to_dict(self) -> dict:
        out = {k: (list(map(float, v)) if isinstance(v, list) else dict(v) if isinstance(v, dict) else v)
               for k, v in self.__dict__.items()}
        return {**out, "converged": self.converged}


@dataclass
class Fit:
    """``jacobian``: at the result (exact or secant-updated; pass it to the next frame's
    :func:`fit_frame`), None when the last step asked for a new evaluation. ``equilibrium``: ``x``
    is the equilibrium of ``controls``; False when the fit found none to start from
    (``"equilibrium_failed"``, or ``"time_limit"`` before the first equilibrium), then ``x`` is the
    start's attached positions and no warm start for another frame."""

    controls: Controls
    x: np.ndarray
    markers: np.ndarray
    report: FitReport
    jacobian: EquilibriumJacobian | None = None
    equilibrium: bool = True
    head_frame: np.ndarray | None = None   # with a solved head frame: its 4x4 affine (model head frame -> world)


class _Bounds:
    """The penalty B(c) and its derivatives: activations outside [0, 1], the jaw model's penalty
    and, with a solved head frame (``head``, a :class:`~facesim.inverse.head_frame.HeadFrame`
    whose 12 coefficients follow the control space's unknowns), its rigidity penalty."""

    def __init__(self, space: ControlSpace, jaw_model, head=None):
        self.space = space
        self.jaw_model = jaw_model if space.n_jaw else None
        self.head = head
        self._slices = space.slices()
        self._diag = np.arange(len(space.muscles))   # activations come first

    def value_grad_hess(self, c):
        sa, sj, _ = self._slices
        n = len(c)
        g, H = np.zeros(n), np.zeros((n, n))   # called a few hundred times per schedule: kept lean
        a = c[sa]
        ex = np.minimum(a, 0.0) + np.maximum(a - 1.0, 0.0)
        v = float(ex @ ex)
        g[sa] = 2 * ex
        H[self._diag, self._diag] = 2.0 * (ex != 0)
        if self.jaw_model is not None:
            pv, pg, ph = self.jaw_model.penalty(c[sj])
            v += float(pv)
            g[sj] += pg
            H[sj, sj] += ph
        if self.head is not None:
            sf = slice(self.space.size, n)
            pv, pg, ph = self.head.penalty(c[sf])
            v += float(pv)
            g[sf] += pg
            H[sf, sf] += ph
        return v, g, H

    def box(self):
        """``(lower, upper, weight)`` over the unknowns when every bound is a box on one of them
        (activations in [0, 1] with weight 1; a jaw model whose ``penalty_box`` gives its ranges),
        else None (a solved head frame's rigidity, a jaw model's curved or coupled ranges)."""
        if self.head is not None:
            return None
        m = len(self.space.muscles)
        lower, upper, weight = np.zeros(self.space.size), np.ones(self.space.size), np.ones(self.space.size)
        if self.jaw_model is not None:
            jaw = getattr(self.jaw_model, "penalty_box", lambda: None)()
            if jaw is None:
                return None
            sj = self._slices[1]
            lower[sj], upper[sj], weight[sj] = (np.broadcast_to(np.asarray(v, dtype=np.float64), (sj.stop - m,))
                                                for v in jaw)
        return lower, upper, weight

    def violation(self, c) -> float:
        """Largest distance of a control outside its bounds (activations; jaw model bounds)."""
        sa, sj, _ = self.space.slices()
        a = c[sa]
        worst = float(np.max(np.maximum(-a, a - 1.0), initial=0.0))
        if self.jaw_model is not None:
            lo, hi = np.asarray(self.jaw_model.bounds, dtype=np.float64).T
            q = c[sj]
            worst = max(worst, float(np.max(np.maximum(lo - q, q - hi), initial=0.0)))
        return max(worst, 0.0)


def schedule_penalty(r, J, c, bounds: _Bounds, options: FitOptions, w=None, compiled: bool = True):
    """Minimise the linear model ``1/2 |r + J dc|_W^2 + mu B(c + dc)`` over ``dc`` with the
    progressive penalty schedule. Returns ``(dc, mu, nested steps)``.

    ``r (m,)`` current residual P - T (mm), ``J (m, nc)``. The start weight is the penalty at which
    a violation of one unit costs ``start_ratio`` times the noise energy ``noise^2`` (below the
    noise level), the final weight ``final_ratio`` times the data term at the model minimum.
    Where every bound is a box on one unknown (:meth:`_Bounds.box`) the same schedule runs
    compiled (:func:`facesim._kernels.schedule.box_schedule`), unless ``compiled=False``."""
    w = np.ones(len(r)) if w is None else w
    JW = J * w[:, None]
    A = J.T @ JW
    A += options.damping * max(float(np.mean(np.diag(A))), 1e-12) * np.eye(len(c))
    b = JW.T @ r
    mu = options.start_ratio * options.noise ** 2
    box = bounds.box() if compiled else None
    if box is not None:
        from facesim._kernels.schedule import box_schedule

        f64 = lambda v: np.ascontiguousarray(v, dtype=np.float64)   # noqa: E731
        dc, mu, nested = box_schedule(f64(A), f64(b), f64(r), f64(J), f64(w), f64(c), *map(f64, box), float(mu),
                                      float(options.growth), float(options.final_ratio))
        return dc, float(mu), int(nested)
    dc = np.zeros(len(c))
    nested = 0
    streak = 0            # nested steps in a row that stayed on one piece of the penalty
    piece = None
    v, g, H = bounds.value_grad_hess(c)
    while True:
        grad = A @ dc + b + mu * g
        for inner in range(50):   # Newton on the piecewise-quadratic model (exact once the active set settles)
            step = np.linalg.solve(A + mu * H, -grad)
            dc = dc + step
            v, g, H = bounds.value_grad_hess(c + dc)
            # the model's gradient at the new point: zero (to round-off) when the step stayed on
            # one quadratic piece of the penalty, so the next Newton step would be nil
            Adc = A @ dc
            grad = Adc + b + mu * g   # also the next iteration's gradient (same weight)
            if np.abs(grad).max() <= 1e-12 * max(np.abs(b).max(), np.abs(Adc).max(), 1e-300) or \
                    np.abs(step).max() <= 1e-12 * (1.0 + np.abs(dc).max()):
                break
        model = r + J @ dc
        data = 0.5 * float(model @ (w * model))
        target = options.final_ratio * max(data, 1e-12)
        if v == 0.0 and not g.any():
            # no bound is active at the minimum of the data term: it minimises the model for every
            # larger weight as well, so the rest of the schedule leaves dc unchanged; count its steps
            nested += 1
            while mu < target:
                mu *= options.growth
                nested += 1
        if mu >= target:
            return dc, mu, nested + (0 if v == 0.0 and not g.any() else 1)
        # Where a nested step's single Newton step stayed on the piece of the last one (the same
        # active bounds), the model's minimiser moves smoothly with mu: the schedule then takes
        # its 5 % steps two, four, eight ... at a time (counted as such). The path changes, not
        # where it ends: the minimiser of the piecewise-quadratic model at the final weight, which
        # the last nested step's Newton iterations reach from any start.
        active = np.flatnonzero(np.diag(H) != 0.0).tobytes()
        streak = streak + 1 if inner == 0 and active == piece else 0
        piece = active
        k = 2 ** min(streak, 6)
        jump = options.growth ** k
        if mu * jump >= target and k > 1:   # land on the target, not far beyond it
            k = max(1, math.ceil(math.log(target / mu) / math.log(options.growth)))
            jump = options.growth ** k
        nested += k
        mu *= jump


def _reusable(J: EquilibriumJacobian | None, space: ControlSpace, c, x) -> bool:
    """Whether ``J`` was taken (or secant-updated) at exactly this control vector and equilibrium."""
    if J is None or J.space != space or J.x.shape != x.shape:
        return False
    return bool(np.abs(space.vector(J.controls) - c).max(initial=0.0) <= 1e-12 and np.abs(J.x - x).max() <= 1e-9)


def fit_frame(sim, targets, controls: Controls, x0=None, space: ControlSpace | None = None,
              options: FitOptions | None = None, weights=None, extra_terms=(),
              jacobian: EquilibriumJacobian | None = None, screen=None, frame: float = 0.0,
              head_frame=None, jaw_prior=None, finish_start: bool = False) -> Fit:
    """Fit one frame: the controls (in ``space``, default all activations and the jaw model's
    parameters) whose equilibrium puts the model's markers on ``targets (r, 3)`` mm (NaN rows
    are missing markers), starting from ``controls`` and its equilibrium ``x0`` (solved if None).

    ``weights (r,)``: per-marker weights (default 1). ``jacobian``: the previous frame's
    ``Fit.jacobian``; used when it was taken at ``controls`` and ``x0`` (else evaluated here). Its
    factorised ``tangent`` may be replaced by a nearer one (its ``tangent_at`` then None) where a
    large face's trial equilibrium refactorises (:class:`~facesim.fem.linear.FactorPCG`'s ``owner``).
    ``screen``: outlier screening before any equilibrium, ``screen(P (r, 3)) -> marker indices``
    called once with the markers the first step's linear model predicts; the markers it names are
    dropped from the frame and listed in ``report.screened`` (a tracked frame's prediction is
    close to its fit, so an outlier costs no second fit).
    ``frame``: the frame number scripted colliders of the simulator's contact set-up are posed at.
    Every equilibrium and Jacobian of the fit includes the simulator's contact terms
    (:meth:`~facesim.fem.equilibrium.FaceSimulator.contact_terms`) and ``extra_terms``.
    ``head_frame``: a 4x4 affine transform (the model's head frame -> the targets' frame) to start
    from: the skull's frame is then solved with the other controls, 12 affine coefficients under
    the rigidity penalty (:mod:`facesim.inverse.head_frame`); the targets are in the capture's
    frame, the equilibrium in the head frame, and ``Fit.head_frame`` / ``Fit.markers`` are the
    solved frame and the markers it puts in the capture's frame.
    ``jaw_prior``: a :class:`~facesim.inverse.jaw_prior.PriorRows`, predicted mandible points the
    jaw parameters are drawn to (residual rows of the objective beside the markers'; needs jaw
    parameters in ``space``; :mod:`facesim.inverse.jaw_prior`).
    ``finish_start``: ``x0`` is an equilibrium solved to a looser tolerance than the simulator's
    (a coarse start's refinement, :data:`facesim.inverse.coarse.START_RTOL`): a fit that keeps no
    step then solves it to the full tolerance before returning it (chord iterations on the
    Jacobian's factor), so the fit's ``x`` is a converged equilibrium (``report.error`` says so
    where that solve fails).

    Returns a :class:`Fit` with the final controls, positions, marker positions, the report (with
    ``stop_reason``, one of :data:`STOP_REASONS`: ``"converged"`` by the stopping rule,
    ``"step_limit"`` after ``max_steps`` steps, ``"line_search_failed"`` when no step length
    lowered the objective, ``"equilibrium_failed"`` when the starting controls had no equilibrium
    -- then the fit is returned at its start with ``x`` the last iterate) and the Jacobian at the
    result for the next frame."""
    options = options or FitOptions()
    with single_blas_thread(), time_budget(options.max_seconds):   # vector-sized BLAS work: threads contend
        return _fit_frame(sim, targets, controls, x0, space, options, weights, extra_terms,
                          jacobian, screen, frame, head_frame, jaw_prior, finish_start)


class _OutOfTime(Exception):
    """The fit's wall-clock budget ran out (raised between equilibria, caught by the fit)."""


def _fit_frame(sim, targets, controls, x0, space, options, weights, extra_terms, jacobian, screen, frame,
               head_frame, jaw_prior=None, finish_start=False) -> Fit:
    t0 = time.perf_counter()
    model = sim.model
    targets = np.asarray(targets, dtype=np.float64)
    if targets.shape != (model.n_markers, 3):
        raise FacesimError(f"targets: expected ({model.n_markers}, 3) marker positions, got {targets.shape}")
    keep = np.isfinite(targets).all(axis=1)
    if keep.sum() < 3:
        raise FacesimError(f"targets: only {int(keep.sum())} markers present; need at least 3")
    w = np.ones(model.n_markers) if weights is None else np.asarray(weights, dtype=np.float64)
    space = space or ControlSpace.of(sim)
    nc = space.size
    head = None if head_frame is None else HeadFrame.of(model)
    bounds = _Bounds(space, sim.jaw_model, head)
    if jaw_prior is not None and not space.n_jaw:
        raise FacesimError("jaw prior: the control space solves no jaw parameters (a jaw model with parameters, "
                           "e.g. sliding-condyle, and jaw=True)")
    sj = space.slices()[1]
    rep = FitReport()
    clock = rep.timing

    def kept(keep):
        """Per-coordinate weights and rows of the markers ``keep`` selects, and the data term of a
        fit at the noise level."""
        w3 = np.repeat(w[keep], 3)
        rows = (3 * np.flatnonzero(keep)[:, None] + np.arange(3)).ravel()
        return w3, rows, 0.5 * options.noise ** 2 * float(w3.sum())

    w3, rows, noise_energy = kept(keep)
    # A step dc moves the estimate by |J dc|_W / noise = sqrt(2 predicted) / noise standard deviations
    # of its marker-noise covariance noise^2 (J^T W J)^-1. Stopping short of a step of k of them
    # leaves an error of at most k on top of the noise's, which is sqrt(n) of them over n controls
    # (~6 for 35): the expected error grows by sqrt(1 + k^2 / n), 6 % for k = 2 and n = 35, while
    # the step saved is a whole equilibrium and often a Jacobian. Measured on the demo clip
    # (benchmarks/RESULTS.md): the recovery is the same for k = 1, 1.5 and 2 (session 11; marker RMS,
    # activation and jaw errors), and k = 2 takes 100 steps on it against 114 at 1.5, 10 % of its
    # time (session 33; the medium face's benchmark: the same errors, half the Jacobians).
    resolution = 0.5 * (options.resolution * options.noise) ** 2

    def solve(ctrl, warm, source, previous=None):
        """Equilibrium of ``ctrl`` from ``warm`` (or from ``previous`` with the bones moved, when that
        is nearer): chord iterations on the factorised tangent of ``source`` (a Jacobian, or None)
        first, else Newton. Raises :class:`_OutOfTime` when the fit's budget has run out (before,
        or during the solve). The tangent is read from ``source`` here, not held: a Newton solve
        that refactorises may free it and hand ``source`` its own (FactorPCG's ``owner``)."""
        if expired():
            raise _OutOfTime
        chord = source is not None and source.tangent is not None and options.chord
        if chord:
            xc, its, solves, ok = near_equilibrium(sim, ctrl, warm, source.tangent, extra_terms, frame=frame,
                                                   previous=previous)
            rep.newton_iterations += its
            rep.chord_iterations += its
            rep.linear_solves += solves
            if ok:
                rep.equilibria += 1
                return xc
            warm = xc
        try:
            # after the chord solve: Newton whose steps are preconditioned by the same factor, then
            # by a factorisation of their own where it is no longer near (FactorPCG)
            linear = FactorPCG(owner=source) if chord else None
            eq = sim.equilibrium(ctrl, x0=warm, extra_terms=extra_terms, frame=frame, linear=linear)
        except SolverError as exc:   # a failed trial: the line search treats it as an infinite objective
            rep.equilibria += 1
            rep.error = " ".join(str(exc).split())
            return None
        rep.equilibria += 1
        rep.newton_iterations += eq.iterations
        rep.linear_solves += len(eq.report.linear_iterations)
        if eq.report.stop_reason == TIME_LIMIT:
            raise _OutOfTime
        return eq.x if eq.converged else None

    def motion(x, start):
        """Marker motion ``(k,)`` of the kept coordinates from the marker positions ``start`` (head frame)."""
        return (model.marker_positions(x) - start).ravel()[rows]

    def in_targets(Ph, c):
        """Head-frame marker positions ``Ph (r, 3)`` in the targets' frame: moved by the head frame
        when it is solved."""
        return Ph if head is None else head.apply(Ph, c[nc:])

    def markers(x, c):
        """Marker positions ``(r, 3)`` of the equilibrium ``x`` in the targets' frame."""
        return in_targets(model.marker_positions(x), c)

    def marker_jacobian(J, x, c):
        """``(3r, len(c))`` derivative of :func:`markers` from the equilibrium's ``J``."""
        return J.dP if head is None else head.jacobian(model.marker_positions(x), c[nc:], J.dP)

    def ctrl(c) -> Controls:
        return space.apply(base, c[:nc])

    def prior(c) -> float:
        if jaw_prior is None:
            return 0.0
        rp = jaw_prior.residual(sim.jaw_model, c[sj])
        return 0.5 * jaw_prior.weight * float(rp @ rp)

    def objective(c, x, mu):
        r = (markers(x, c)[keep] - targets[keep]).ravel()
        return 0.5 * float(r @ (w3 * r)) + prior(c) + mu * bounds.value_grad_hess(c)[0]

    def exact_jacobian(c, x):
        if expired():
            raise _OutOfTime
        t = time.perf_counter()
        J = equilibrium_jacobian(sim, ctrl(c), x, space, extra_terms=extra_terms,
                                 linear_solver=options.linear_solver, rtol=options.jacobian_rtol, frame=frame)
        rep.jacobians += 1
        rep.linear_solves += len(J.linear_iterations)
        clock["jacobian"] += time.perf_counter() - t
        return J

    def linear_step(J, c, x):
        """The schedule's step, its weight and the decrease the linear model predicts for it."""
        t = time.perf_counter()
        r = (markers(x, c)[keep] - targets[keep]).ravel()
        Jr = marker_jacobian(J, x, c)[rows]
        wr = w3
        if jaw_prior is not None:   # the predicted bone points: rows of their own beside the markers'
            Jp = np.zeros((3 * len(jaw_prior.rest), len(c)))
            Jp[:, sj] = jaw_prior.jacobian(sim.jaw_model, c[sj])
            r, Jr = np.r_[r, jaw_prior.residual(sim.jaw_model, c[sj])], np.vstack([Jr, Jp])
            wr = np.r_[w3, np.full(len(Jp), jaw_prior.weight)]
        dc, mu, nested = schedule_penalty(r, Jr, c, bounds, options, wr)
        rep.schedule_steps += nested
        F = objective(c, x, mu)
        m = r + Jr @ dc
        predicted = F - (0.5 * float(m @ (wr * m)) + mu * bounds.value_grad_hess(c + dc)[0])
        slope = float((Jr.T @ (wr * r) + mu * bounds.value_grad_hess(c)[1]) @ dc)   # d/dalpha F(c + alpha dc), 0
        clock["algebra"] += time.perf_counter() - t
        return dc, mu, F, predicted, slope

    t = time.perf_counter()
    out_of_time = False
    try:
        x = solve(controls, x0, None) if x0 is None or not np.isfinite(x0).all() else np.asarray(x0, np.float64)
    except _OutOfTime:
        x, out_of_time = None, True
    clock["equilibria"] += time.perf_counter() - t
    if x is None:   # no equilibrium to start from: the frame failed, reported as such
        rep.stop_reason = TIME_LIMIT if out_of_time else "equilibrium_failed"
        rep.error = rep.error or ("the time budget ran out before the starting equilibrium was found" if out_of_time
                                  else "the starting controls have no converged equilibrium")
        x = sim.attached_positions(controls, x0 if x0 is not None and np.isfinite(x0).all() else None)
        f0 = np.zeros(0) if head is None else head.coefficients(head_frame)
        P = markers(x, np.r_[np.zeros(nc), f0])
        rep.marker_rms = float(np.sqrt(np.mean(np.sum((P[keep] - targets[keep]) ** 2, axis=1))))
        rep.seconds = time.perf_counter() - t0
        return Fit(controls, x, P, rep, None, equilibrium=False,
                   head_frame=None if head is None else np.asarray(head_frame, dtype=np.float64))
    x_start = x if finish_start else None
    c = space.vector(controls)
    J = jacobian if _reusable(jacobian, space, c, x) else None
    if head is not None:   # the frame's coefficients follow the control space's unknowns
        c = np.r_[c, head.coefficients(head_frame)]
    base = controls
    mu = 0.0
    F = objective(c, x, mu)
    rep.objective.append(F)
    Ph = model.marker_positions(x)     # in the head frame (the equilibrium's Jacobian's)
    P = in_targets(Ph, c)              # in the targets' frame

    def small(dc, F, predicted) -> bool:
        """The stopping rule: the next step would change the objective (or the controls) too little."""
        return predicted <= max(options.tolerance * max(F, noise_energy), resolution) or \
            np.abs(dc).max() < options.step_tolerance

    stop = ""
    drifted = False   # the last step's secant mismatch exceeded jacobian_drift: evaluate J before the next
    try:
        while rep.gn_steps < options.max_steps:
            if drifted and J.age <= options.jacobian_max_age:
                # the secant-updated Jacobian (exact along the last step) first decides whether
                # there is a step worth taking: a drifted last step is often the frame's last, and
                # an evaluation only to stop cost the paper-size face 18-20 s a tracked frame
                dc, mu, F, predicted, slope = linear_step(J, c, x)
                if small(dc, F, predicted):
                    stop = "converged"
                    break
            if J is None or drifted or J.age > options.jacobian_max_age:
                J = None   # its factor freed before the new one is made (unless the caller holds it)
                J, drifted = exact_jacobian(c, x), False
            dc, mu, F, predicted, slope = linear_step(J, c, x)
            if screen is not None:
                dropped = [j for j in screen(P + (marker_jacobian(J, x, c) @ dc).reshape(-1, 3)) if keep[j]]
                screen = None
                if dropped and keep.sum() - len(dropped) >= 3:
                    rep.screened = sorted(dropped)
                    keep = keep.copy()
                    keep[dropped] = False
                    w3, rows, noise_energy = kept(keep)
                    rep.objective[0] = objective(c, x, 0.0)
                    dc, mu, F, predicted, slope = linear_step(J, c, x)
            if small(dc, F, predicted):
                stop = "converged"
                break
            # the full step first, its equilibrium warm-started from the first-order prediction (or
            # from x with the bones moved, when that is nearer) -- with a nearby Jacobian from x with
            # the bones moved alone: its columns, solved with another state's factor, are off by 9 %
            # in the median (the paper-size face after its coarse-to-fine cold frame): its
            # prediction started no trial better there, and it costs a start and a gradient
            # (0.3-0.5 s a tracked frame; benchmarks/RESULTS.md, session 35)
            t = time.perf_counter()
            x1 = solve(ctrl(c + dc), x, J) if J.nearby else solve(ctrl(c + dc), J.predict(dc[:nc]), J, x)
            F1 = math.inf if x1 is None else objective(c + dc, x1, mu)
            clock["equilibria"] += time.perf_counter() - t
            rep.ratios.append((F - F1) / predicted)
            if options.line_search == "ratio" and F - F1 >= options.accept_ratio * predicted:
                rep.full_steps += 1
                t = time.perf_counter()
                alpha, F_new, x_new = 1.0, F1, x1
                if not J.nearby:   # a Jacobian solved with a nearby tangent mispredicts the motion by itself
                    alpha, F_new, x_new = _extend(solve, objective, ctrl, c, dc, x, x1, F1, mu, options,
                                                  (J.dP @ dc[:nc])[rows], functools.partial(motion, start=Ph),
                                                  w3, J, resolution)
                clock["line_search"] += time.perf_counter() - t
            elif J.age > 0:   # the model of an updated Jacobian failed: evaluate it here and step again
                J = None
                continue
            else:
                t = time.perf_counter()
                cache = {0.0: (F, x), 1.0: (F1, x1)}
                alpha, F_new, x_new = None, math.inf, None
                if options.line_search == "ratio" and x1 is not None and F1 - F - slope > 0 and slope < 0:
                    # the full step failed: one backtracking trial at the minimum of the parabola through
                    # F(0), F'(0) and F(1), kept on sufficient (Armijo) decrease
                    short = min(max(-slope / (2.0 * (F1 - F - slope)), 0.1), 0.9)
                    xs = solve(ctrl(c + short * dc), J.predict(short * dc[:nc]), J)
                    Fs = math.inf if xs is None else objective(c + short * dc, xs, mu)
                    cache[short] = (Fs, xs)
                    if Fs <= F + ARMIJO * short * slope:
                        alpha, F_new, x_new = short, Fs, xs
                if alpha is None:   # golden section: over [0, 1] after a failed full step, else [0, max_step]
                    hi = 1.0 if options.line_search == "ratio" else options.max_step
                    alpha, F_new, x_new = _golden_section(solve, objective, ctrl, c, dc, J, nc, mu, options, cache,
                                                          hi)
                clock["line_search"] += time.perf_counter() - t
            rep.gn_steps += 1
            rep.step_lengths.append(alpha)
            if alpha == 0.0 or x_new is None:
                stop = "line_search_failed"   # no step length lowered the objective
                break
            t = time.perf_counter()
            step = alpha * dc
            Ph_new = model.marker_positions(x_new)
            moved = (Ph_new - Ph).ravel()   # the equilibrium's response, in the head frame
            linear = J.dP @ step[:nc]
            mismatch = float(np.linalg.norm(moved - linear)) / max(float(np.linalg.norm(linear)), 1e-300)
            J = J.secant_update(step[:nc], x_new, moved, ctrl(c + step))
            rep.secant_updates += 1
            clock["jacobian"] += time.perf_counter() - t
            improvement = (F - F_new) / max(F, 1e-300)
            c, x, F, Ph = c + step, x_new, F_new, Ph_new
            P = in_targets(Ph, c)
            rep.objective.append(F)
            if improvement < options.tolerance or np.abs(step).max() < options.step_tolerance:
                stop = "converged"
                break
            # the next step evaluates J anew; the next frame starts from the secant-updated one (its
            # first step is redone with an exact J if the ratio test fails: the paper-size face's
            # first tracked frame saves one evaluation, 18 s, benchmarks/RESULTS.md session 24)
            drifted = mismatch > options.jacobian_drift
    except _OutOfTime:   # the budget ran out: the fit stays at its last accepted step
        stop = TIME_LIMIT
    if not stop:   # out of steps: converged if the (secant-updated) Jacobian predicts no worthwhile step
        stop = "step_limit"
        if J is not None and not drifted and J.age <= options.jacobian_max_age:
            dc, _, F_next, predicted, _ = linear_step(J, c, x)
            if small(dc, F_next, predicted):
                stop = "converged"
    if x is x_start and stop != TIME_LIMIT:
        # no step kept: the start, solved to a looser tolerance, is finished here
        t = time.perf_counter()
        try:
            done = solve(ctrl(c), x, J)
        except _OutOfTime:
            done, stop = None, TIME_LIMIT
        clock["equilibria"] += time.perf_counter() - t
        if done is not None:
            x = done
            Ph = model.marker_positions(x)
            P = in_targets(Ph, c)
            if J is not None:
                J = dataclasses.replace(J, x=x)   # first-order accurate anyway (a nearby tangent's)
        elif stop != TIME_LIMIT:
            rep.error = rep.error or "the start's equilibrium, solved to a looser tolerance, could not be finished"
    rep.stop_reason = stop
    final = ctrl(c)
    rk = (P[keep] - targets[keep])
    rep.marker_rms = float(np.sqrt(np.mean(np.sum(rk ** 2, axis=1))))
    rep.worst_violation = bounds.violation(c)
    rep.penalty_weight = mu
    rep.seconds = time.perf_counter() - t0
    return Fit(final, x, P, rep, J, head_frame=None if head is None else head.matrix(c[nc:]))


def _extend(solve, objective, ctrl, c, dc, x, x1, F1, mu, options, linear, moved, w, J, resolution=0.0):
    """Lengthen a kept full step where Gauss-Newton undershoots (muscles stiffen as they shorten,
    flesh against bone): the markers moved only a fraction ``phi(alpha)`` of the predicted motion
    ``linear = J dc`` (kept rows) along it. The step minimises ``|r + phi J dc|`` at ``phi = 1``, so
    ``phi(alpha) = 1`` is solved by secant steps (at most ``EXTEND_TRIALS`` more equilibria, each
    warm-started by extrapolating the last two), kept while the objective falls -- and while the
    decrease left to gain, ``1/2 (1 - phi)^2 |J dc|_W^2`` by the linear model (whose minimum is at
    ``phi = 1``), is above ``resolution``, the stopping rule's: on the demo clip 38 of 40 extension
    trials gained nothing, their markers within the noise of the prediction (benchmarks/RESULTS.md,
    session 33). ``moved(x) (k,)``: marker motion from the start; ``ctrl(c)``: the controls of the
    unknowns ``c``. Returns ``(alpha, F, x)``."""
    norm = max(float(linear @ (w * linear)), 1e-300)
    path = [(0.0, 0.0, x), (1.0, float(linear @ (w * moved(x1))) / norm, x1)]
    best = (1.0, F1, x1)
    for _ in range(EXTEND_TRIALS):
        (a0, p0, xa0), (a1, p1, xa1) = path[-2], path[-1]
        if p1 >= 1.0 / EXTRAPOLATE_ABOVE or p1 <= p0 or 0.5 * norm * (1.0 - p1) ** 2 <= resolution:
            break
        a2 = min(a1 + (1.0 - p1) * (a1 - a0) / (p1 - p0), options.max_step)
        if a2 <= a1 * EXTRAPOLATE_ABOVE:
            break
        x2 = solve(ctrl(c + a2 * dc), xa1 + (a2 - a1) / (a1 - a0) * (xa1 - xa0), J)
        F2 = math.inf if x2 is None else objective(c + a2 * dc, x2, mu)
        if F2 >= best[1]:
            break
        best = (a2, F2, x2)
        path.append((a2, float(linear @ (w * moved(x2))) / norm, x2))
    return best


def _golden_section(solve, objective, ctrl, c, dc, J, nc, mu, options, cache, hi):
    """Golden-section search of ``F(c + alpha dc)`` on ``[0, hi]`` down to a bracket of
    ``golden_tolerance * hi``; ``cache`` maps the step lengths already solved to ``(F, x)``. Each
    trial equilibrium is warm-started from the interpolation of the bracketing ones (the
    first-order prediction of ``J`` for the first ``nc`` unknowns beyond the last).
    Returns ``(alpha, F, x)`` of the best point."""

    def at(alpha):
        if alpha in cache:
            return cache[alpha][0]
        done = [s for s in sorted(cache) if cache[s][1] is not None]   # failed trials bracket nothing
        lo = max((s for s in done if s < alpha), default=0.0)
        hi = min((s for s in done if s > alpha), default=None)
        if hi is None:
            warm = J.predict(alpha * dc[:nc])
        else:
            t = (alpha - lo) / (hi - lo)
            warm = (1 - t) * cache[lo][1] + t * cache[hi][1]
        xa = solve(ctrl(c + alpha * dc), warm, J)
        cache[alpha] = (math.inf, None) if xa is None else (objective(c + alpha * dc, xa, mu), xa)
        return cache[alpha][0]

    a_, b_ = 0.0, hi
    at(b_)
    x1, x2 = b_ - GOLDEN * (b_ - a_), a_ + GOLDEN * (b_ - a_)
    f1, f2 = at(x1), at(x2)
    while (b_ - a_) > options.golden_tolerance * hi:
        if f1 <= f2:
            b_, x2, f2 = x2, x1, f1
            x1 = b_ - GOLDEN * (b_ - a_)
            f1 = at(x1)
        else:
            a_, x1, f1 = x1, x2, f2
            x2 = a_ + GOLDEN * (b_ - a_)
            f2 = at(x2)
    alpha = min(cache, key=lambda s: cache[s][0])
    return alpha, cache[alpha][0], cache[alpha][1]


__all__ = ["STOP_REASONS", "FitOptions", "FitReport", "Fit", "fit_frame", "schedule_penalty"]
