"""Implicit Jacobians of the quasistatic equilibrium (Sifakis, Neverov, Fedkiw 2005 eqs. 5-6).

At an equilibrium ``x(c)`` the free-node gradient of the total energy vanishes,
``g_U(x_U, c) = 0``, for every control vector ``c`` (activations, jaw parameters). Differentiating,

    K dx_U/dc = - dg_U/dc,        K = d2E/dx_U2  (the true tangent, not PSD-projected)

with ``dg_U/da_i = -G_i(x)`` (the muscle's active force column: the force is affine in the
activation, eq. 5) and ``dg_U/dq_k`` the force on the free nodes from moving only the bones (and
the colliders they carry) along the jaw parameter ``q_k`` (eq. 6, ``-K_UC dX_C/dq_k``). That bone
column is the directional derivative of the gradient at fixed free positions, taken by a central
difference (exact to O(h^2) ~ 1e-10 relative: the force is smooth in the bone pose), so the same
code covers flesh, muscles and contact terms whose colliders ride on the bones.

All columns are solved against one factorisation (direct) or one AMG hierarchy (CG per column).
Attached nodes move with their bone analytically; the head (optional) moves everything rigidly
(no solve: the energy is invariant under a rigid motion of the whole face). Markers are
``P = sum b_k x_k + offset * n(x)``; :func:`marker_jacobian` is their exact derivative.

Reuse between solves (the inverse solver's speed, issue 5): a direct Jacobian keeps the
factorised tangent, and :func:`near_equilibrium` solves the equilibrium of nearby controls by
chord iterations against it (one gradient and one pair of triangular solves per iteration, no
assembly); :meth:`EquilibriumJacobian.secant_update` moves a Jacobian to a new equilibrium with a
rank-one (Broyden) correction that makes it exact along the step just taken.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.linear import (DirectSolver, counted_cg, make_linear_solver, pardiso_available, preconditioner,
                                single_blas_thread)
from facesim.fem.newton import Problem
from facesim.model import FaceModel

DIRECT_BELOW = 150_000   # unknowns: SuperLU's fill stays within a few GB below this on face meshes
#: relative residual of the columns a single-precision PARDISO factor's solve is kept at (no
#: refinement; the face's tangents: ~1e-5 at most), estimated per solve (PardisoFactor.solve). A
#: Gauss-Newton step needs far less (its linear model is off by ~0.1 where jacobian_drift says so)
DIRECT_COLUMN_RTOL = 1e-4
HEAD_NAMES = ("head_rx", "head_ry", "head_rz", "head_tx", "head_ty", "head_tz")


def _cross_matrices(v: np.ndarray) -> np.ndarray:
    """``(k, 3, 3)`` matrices [v]x with [v]x w = v x w."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


def marker_jacobian(model: FaceModel, x=None) -> sp.csr_matrix:
    """``(3r, 3n)`` derivative of :meth:`FaceModel.marker_positions` with respect to the node positions.

    ``P = sum_k b_k x_k + o n/|n|`` with ``n = (x1 - x0) x (x2 - x0)``:
    ``dP/dx_k = b_k I + o (I - n^ n^T)/|n| dn/dx_k``, ``dn/dx1 = -[e2]x``, ``dn/dx2 = [e1]x``,
    ``dn/dx0 = -(dn/dx1 + dn/dx2)``."""
    x = model.X if x is None else np.asarray(x, dtype=np.float64)
    mk = model.markers
    tri = model.skin[mk.triangle]                 # (r, 3) node ids
    p = x[tri]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    n = np.cross(e1, e2)
    length = np.linalg.norm(n, axis=1)
    nh = n / length[:, None]
    proj = (np.eye(3)[None] - nh[:, :, None] * nh[:, None, :]) / length[:, None, None]   # (r, 3, 3)
    d1, d2 = -_cross_matrices(e2), _cross_matrices(e1)
    dn = np.stack([-(d1 + d2), d1, d2], axis=1)   # (r, 3 nodes, 3, 3)
    blocks = mk.bary[:, :, None, None] * np.eye(3) + mk.offset[:, None, None, None] * np.einsum("rab,rkbc->rkac",
                                                                                                   proj, dn)
    r = len(tri)
    rows = (3 * np.arange(r))[:, None, None, None] + np.arange(3)[None, None, :, None]   # (r, 1, 3, 1)
    cols = (3 * tri)[:, :, None, None] + np.arange(3)[None, None, None, :]               # (r, 3, 1, 3)
    rows, cols = np.broadcast_arrays(rows, cols)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * r, 3 * model.n_nodes))


@dataclass(frozen=True)
class ControlSpace:
    """Which controls are unknowns, in order: activations of ``muscles`` (indices; default all),
    the jaw model's parameters (``jaw=True``, needs ``jaw_model.n_params``), and 6 head parameters
    (``head=True``: rotation vector rad about ``head_centre`` and translation mm, applied on the left
    of the current head pose)."""

    n_muscles: int
    muscles: tuple = None
    n_jaw: int = 0
    head: bool = False
    head_centre: tuple = (0.0, 0.0, 0.0)
    jaw_rest: tuple = None    # the jaw controls standing for ``controls.jaw = None`` (default zeros)

    def __post_init__(self):
        m = tuple(range(self.n_muscles)) if self.muscles is None else tuple(int(i) for i in self.muscles)
        if any(i < 0 or i >= self.n_muscles for i in m) or len(set(m)) != len(m):
            raise FacesimError(f"control space: muscle indices must be distinct and in [0, {self.n_muscles})")
        object.__setattr__(self, "muscles", m)

    @staticmethod
    def of(sim, jaw: bool | None = None, head: bool = False, muscles=None) -> "ControlSpace":
        """The control space of the simulator ``sim``: its muscles (or ``muscles``), the jaw model's
        parameters (``jaw``: default whenever the jaw model has any; the rigid jaw has none) and
        optionally the head."""
        n_params = sim.jaw_model.n_params
        if jaw is None:
            jaw = n_params > 0
        if jaw and n_params == 0:
            raise FacesimError(f"control space: the {sim.jaw_model.name} jaw model has no parameters to solve for "
                               "(use the sliding-condyle jaw or a fitted rig)")
        n_jaw = n_params if jaw else 0
        centre = tuple(sim.model.X[sim.model.cranium_nodes].mean(axis=0)) if len(sim.model.cranium_nodes) else \
            (0.0, 0.0, 0.0)
        rest = tuple(float(v) for v in sim.jaw_model.rest) if n_jaw else None
        return ControlSpace(sim.model.n_muscles, muscles, n_jaw, head, centre, rest)

    @property
    def size(self) -> int:
        return len(self.muscles) + self.n_jaw + (6 if self.head else 0)

    def names(self, model: FaceModel, jaw_model=None) -> list[str]:
        """Names of the unknowns: muscles, the jaw model's ``param_names`` (``jaw_<k>`` without a jaw
        model), head parameters."""
        out = [model.muscles.names[i] for i in self.muscles]
        out += list(jaw_model.param_names) if jaw_model is not None else [f"jaw_{k}" for k in range(self.n_jaw)]
        return out + (list(HEAD_NAMES) if self.head else [])

    def slices(self) -> tuple[slice, slice, slice]:
        m, j = len(self.muscles), self.n_jaw
        return slice(0, m), slice(m, m + j), slice(m + j, self.size)

    def vector(self, controls: Controls) -> np.ndarray:
        """The unknowns of ``controls`` (head parameters are increments: 0)."""
        rest = np.zeros(self.n_jaw) if self.jaw_rest is None else np.array(self.jaw_rest)
        jaw = rest if controls.jaw is None else np.asarray(controls.jaw, dtype=np.float64).ravel()
        if self.n_jaw and jaw.shape != (self.n_jaw,):
            raise FacesimError(f"controls.jaw: expected {self.n_jaw} jaw parameters, got shape {jaw.shape}")
        return np.r_[controls.a[list(self.muscles)], jaw[:self.n_jaw], np.zeros(6 if self.head else 0)]

    def apply(self, controls: Controls, c) -> Controls:
        """``controls`` with the unknowns set from ``c (size,)`` (the head increment composed on the left)."""
        c = np.asarray(c, dtype=np.float64)
        if c.shape != (self.size,):
            raise FacesimError(f"control vector: expected {self.size} values, got shape {c.shape}")
        sa, sj, sh = self.slices()
        a = np.array(controls.a)
        a[list(self.muscles)] = c[sa]
        jaw = c[sj].copy() if self.n_jaw else controls.jaw
        head = controls.head
        if self.head:
            head = head_increment(c[sh], self.head_centre) @ (np.eye(4) if head is None else head)
        return Controls(a, jaw, head)


def head_increment(h, centre) -> np.ndarray:
    """4x4: rotation by the vector ``h[:3]`` (rad) about ``centre`` then translation ``h[3:]`` (mm)."""
    from facesim.controls import rotation_about

    T = rotation_about(np.asarray(h[:3], dtype=np.float64), centre)
    T[:3, 3] += np.asarray(h[3:6], dtype=np.float64)
    return T


@dataclass
class EquilibriumJacobian:
    """Derivatives at one equilibrium: ``dx (3n, nc)`` of all node positions and ``dP (3r, nc)`` of
    the markers with respect to the control vector of ``space`` (columns in ``space`` order).
    ``tangent``: the factorised tangent of the last exact evaluation, assembled at ``tangent_at``
    ``= (controls, x, frame)`` (kept through secant updates, so the factorisation can be rebuilt
    where it was taken, e.g. when a run resumes)."""

    space: ControlSpace
    controls: Controls
    x: np.ndarray
    dx: np.ndarray
    dP: np.ndarray
    seconds: dict = field(default_factory=dict)
    linear_iterations: list = field(default_factory=list)
    tangent: object = None   # factorised tangent of the last exact evaluation (direct solver), else None
    age: int = 0             # secant updates since the last exact evaluation (0: exact)
    tangent_at: tuple | None = None   # (controls, x, frame) the tangent was assembled at (None: no tangent)
    nearby: bool = False     # the columns were solved with a nearby tangent's factor (``tangent=``), not this one's

    def __getstate__(self):
        # a factorisation does not pickle (SuperLU): a Jacobian sent to another process (a dask
        # worker) travels without it, and its next equilibria use Newton
        return {**self.__dict__, "tangent": None}

    def predict(self, dc) -> np.ndarray:
        """First-order positions ``(n, 3)`` for the control change ``dc (nc,)``: a warm start."""
        return self.x + (self.dx @ np.asarray(dc, dtype=np.float64)).reshape(-1, 3)

    def secant_update(self, dc, x, dP_actual, controls: Controls) -> EquilibriumJacobian:
        """The Jacobian moved to the equilibrium ``x (n, 3)`` of ``controls``, reached by the control
        step ``dc (nc,)`` along which the markers moved by ``dP_actual (3r,)``: Broyden's rank-one
        update ``D + (d_actual - D dc) dc^T / |dc|^2`` of ``dx`` and ``dP``, exact along ``dc`` and
        unchanged across it. ``age`` counts the updates since the last exact evaluation."""
        dc = np.asarray(dc, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        ss = float(dc @ dc)
        if ss == 0.0:
            return replace(self, x=x, controls=controls)
        v = dc / ss
        dx = self.dx + np.outer((x - self.x).ravel() - self.dx @ dc, v)
        dP = self.dP + np.outer(np.asarray(dP_actual, dtype=np.float64) - self.dP @ dc, v)
        return replace(self, controls=controls, x=x, dx=dx, dP=dP, seconds={}, linear_iterations=[],
                       age=self.age + 1)


def _bone_step(space: ControlSpace, k: int) -> float:
    return 1e-5   # rad or mm: node motion ~1e-3 mm, far above round-off, O(h^2) error negligible


def _jaw_side_terms(sim) -> tuple:
    """The simulator's terms with the flesh restricted to the tets that touch a jaw node: moving
    the jaw changes only their forces, so the bone columns' central differences need no more
    (the flesh gradient is most of a Jacobian's right-hand-side cost otherwise)."""
    e = sim.elastic
    flesh = e.restricted(e.touching(sim.model.jaw_nodes))
    return tuple(flesh if t is e else t for t in sim.terms)


def default_jacobian_solver(n_dofs: int) -> str:
    """The Jacobian's linear solver when none is named: MKL PARDISO when installed (one
    factorisation for all columns at every size, ~8x faster than SuperLU to factorise), else
    SuperLU below ``DIRECT_BELOW`` unknowns and AMG-preconditioned CG per column above."""
    if pardiso_available():
        return "pardiso"
    return "direct" if n_dofs < DIRECT_BELOW else "amg"


def _jacobian_solver(sim, linear_solver: str | None):
    """The linear solver of a Jacobian's columns (``linear_solver``, else :func:`default_jacobian_solver`)."""
    return make_linear_solver(linear_solver or default_jacobian_solver(sim.system.n_dofs))


def _tangent(sim, controls: Controls, x, frame: float, extra_terms):
    """The true tangent at ``x (n, 3)`` of the energy an equilibrium of ``controls`` is solved with:
    the simulator's terms, its contact terms posed at ``frame``, ``extra_terms``."""
    return Problem(sim.terms + sim.solve_terms(controls, frame, extra_terms), sim.system, x,
                   controls.a).hessian(x, project=False)


def _preconditions_only(factor) -> None:
    """Drop the matrix a PARDISO factor keeps for its refined solves: the factor of a Jacobian's
    tangent only preconditions (chord iterations, CG) from here on."""
    if hasattr(factor, "release_matrix"):
        factor.release_matrix()


def factorised_tangent(sim, controls: Controls, x, frame: float = 0.0, extra_terms=(),
                       linear_solver: str | None = None):
    """The factorised tangent at ``x (n, 3)`` for ``controls`` as :func:`equilibrium_jacobian`
    factorises it there (the same energy -- the simulator's terms, its contact terms posed at
    ``frame``, ``extra_terms`` -- the same true tangent and linear solver: the same factors),
    without the Jacobian's columns; like the Jacobian's, it only preconditions (a PARDISO factor
    keeps no matrix). None for a solver that keeps no factorisation (AMG)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    solver = _jacobian_solver(sim, linear_solver)
    if not hasattr(solver, "factorize"):
        return None
    with single_blas_thread():
        factor = solver.factorize(_tangent(sim, controls, x, frame, extra_terms))
    _preconditions_only(factor)
    return factor


def equilibrium_jacobian(sim, controls: Controls, x, space: ControlSpace | None = None, extra_terms=(),
                         linear_solver: str | None = None, rtol: float = 1e-10,
                         frame: float = 0.0, tangent=None, tangent_at: tuple | None = None) -> EquilibriumJacobian:
    """Implicit Jacobian of the equilibrium ``x (n, 3)`` of ``sim`` (a
    :class:`~facesim.fem.equilibrium.FaceSimulator`) at ``controls``.

    The energy differentiated is the one the equilibrium was solved with: flesh, muscles, the
    simulator's contact terms posed for the controls at ``frame`` (re-posed with the bones for the
    jaw columns: teeth and bone-carried colliders move with them) and ``extra_terms``. Contact
    terms enter the tangent ``K`` with their stiffness like any other term. ``linear_solver``:
    ``"direct"`` (SuperLU), ``"pardiso"`` or ``"amg"`` (default: :func:`default_jacobian_solver` --
    one factorisation serves all columns and beats ~20 CG iterations per column where it fits).
    ``rtol``: CG tolerance per column.

    ``tangent``: a factorised tangent assembled near ``x`` (at ``tangent_at = (controls, x,
    frame)``), e.g. the one a trial equilibrium was solved with: the columns are then solved with
    it (one solve, no assembly or factorisation) instead of with the tangent at ``x``, so they
    are first-order accurate in the distance between the two; the Jacobian carries ``age`` 1,
    like a secant-updated one (:func:`~facesim.inverse.gauss_newton.fit_frame` evaluates an exact
    one where its model fails)."""
    with single_blas_thread():   # BLAS work here is vector-sized: threads only add contention
        return _equilibrium_jacobian(sim, controls, x, space, extra_terms, linear_solver, rtol, frame, tangent,
                                     tangent_at)


def _equilibrium_jacobian(sim, controls, x, space, extra_terms, linear_solver, rtol, frame, given=None,
                          given_at=None):
    t0 = time.perf_counter()
    model = sim.model
    space = space or ControlSpace.of(sim)
    x = np.ascontiguousarray(x, dtype=np.float64)
    if x.shape != model.X.shape:
        raise FacesimError(f"x: expected positions of shape {model.X.shape}, got {x.shape}")

    def extras(c: Controls):
        return sim.solve_terms(c, frame, extra_terms)

    system = sim.system
    K = _tangent(sim, controls, x, frame, extra_terms) if given is None else None
    t_assembly = time.perf_counter() - t0

    sa, sj, sh = space.slices()
    nc = space.size
    rhs = np.zeros((system.n_dofs, nc))   # -dg_U/dc
    if len(space.muscles):
        G = sp.csr_matrix(sim.force_columns(x))                   # (3n, M) active force per unit activation
        rows = (3 * system.active[:, None] + np.arange(3)).ravel()
        rhs[:, sa] = G[rows][:, list(space.muscles)].toarray()
        rhs[~system.free_dof, sa] = 0.0
    dx = np.zeros((3 * model.n_nodes, nc))
    if space.n_jaw:
        q = np.asarray(controls.jaw, dtype=np.float64).ravel()
        Hc = np.eye(4) if controls.head is None else controls.head
        dT = sim.jaw_model.jacobian(q)                            # (4, 4, n_jaw)
        Xj = model.X[model.jaw_nodes]
        bone_terms = _jaw_side_terms(sim)
        for k in range(space.n_jaw):
            h = _bone_step(space, k)
            g = []
            for sgn in (1.0, -1.0):
                qk = q.copy()
                qk[k] += sgn * h
                ck = Controls(controls.a, qk, controls.head)
                xk = sim.attached_positions(ck, x)
                g.append(Problem(bone_terms + extras(ck), system, xk, controls.a).energy_and_gradient(xk)[1])
            rhs[:, sj.start + k] = -(g[0] - g[1]) / (2.0 * h)
            dTk = Hc @ dT[:, :, k]
            dx.reshape(-1, 3, nc)[model.jaw_nodes, :, sj.start + k] = Xj @ dTk[:3, :3].T + dTk[:3, 3]
    t1 = time.perf_counter()
    solver = _jacobian_solver(sim, linear_solver)
    n_before = len(solver.stats.iterations)
    cols = slice(0, sj.stop)
    if sj.stop:
        if given is not None:
            du = preconditioner(given)(rhs[:, cols])
            solver.stats.iterations.append(1)
        else:
            du = solver.solve_many(K, rhs[:, cols], system.rigid_modes(x),
                                   rtol=DIRECT_COLUMN_RTOL if isinstance(solver, DirectSolver) else rtol)
        du[~system.free_dof] = 0.0
        rows = (3 * system.active[:, None] + np.arange(3)).ravel()
        dx[rows, cols] += du
    if space.head:
        c = np.asarray(space.head_centre, dtype=np.float64)
        d = x - c
        view = dx.reshape(-1, 3, nc)
        for j in range(3):
            e = np.zeros(3)
            e[j] = 1.0
            view[:, :, sh.start + j] = np.cross(e, d)
            view[:, j, sh.start + 3 + j] = 1.0
    dP = marker_jacobian(model, x) @ dx
    t2 = time.perf_counter()
    tangent = getattr(solver, "lu", None) if given is None else given
    _preconditions_only(tangent)
    at = given_at if given is not None else None if tangent is None else (controls, x, frame)
    return EquilibriumJacobian(space, controls, x, dx, dP,
                               seconds={"assembly": t_assembly, "rhs": t1 - t0 - t_assembly, "solve": t2 - t1,
                                        "total": t2 - t0},
                               linear_iterations=list(solver.stats.iterations[n_before:]),
                               tangent=tangent, tangent_at=at, age=0 if given is None else 1,
                               nearby=given is not None)


# CG tolerance of the Newton steps after the chord iterations: a forcing term (Eisenstat & Walker
# 1996, their choice 2), ``CHORD_NEWTON_GAMMA (|g_k| / |g_k-1|)^2`` after a Newton step, at most
# CHORD_NEWTON_RTOL (and that on a first Newton step), and no tighter than CHORD_LAST_SHARE of
# what is left to the tolerance. History: 0.1 tol / |g| (up to 1e-6 on a first step whose
# nonlinearity then cut the residual only 30-fold), then a fixed 1e-2 (session 22: 31 % fewer
# triangular solves on the demo clip). The nonlinear part of a step's error sets its rate (the
# paper-size face's tracked frames: 0.2-0.3 on the first Newton step), so the first steps' CG is
# solved only to what the step can use: the paper-size face's tracked frames 23-32 CG iterations
# against 32-47, one Newton step fewer in two of three (benchmarks/RESULTS.md, session 34).
CHORD_NEWTON_RTOL = 1e-1
CHORD_NEWTON_GAMMA = 0.9
#: the share of the distance to the tolerance (``tol / |g|``) a Newton step's CG of
#: :func:`near_equilibrium` is solved to, at the least: the step's nonlinear error adds the rest
CHORD_LAST_SHARE = 0.5
#: step lengths a Newton step of :func:`near_equilibrium` that did not shrink the residual enough is
#: cut back to (each one gradient), before the solve is given up to a Newton solve with line search
NEWTON_BACKTRACK = (0.5, 0.25, 0.125)
CHORD_LOOKAHEAD = 3   # chord iterations worth one Newton step (assembly + a few preconditioned CG iterations)
#: CG iterations a Newton step of :func:`near_equilibrium` may take on the factor of a nearby tangent
#: before the solve is given up (as FactorPCG's ``maxiter``): was 50, and the paper-size face's cold
#: first trial spent 25 s on one CG that failed at 50 (benchmarks/RESULTS.md, session 25)
CHORD_NEWTON_MAXITER = 25


def near_equilibrium(sim, controls: Controls, x0, tangent, extra_terms=(), max_iterations: int = 8,
                     contraction: float = 0.5, chord_rate: float = 0.5, frame: float = 0.0, previous=None):
    """Equilibrium of ``controls`` from ``x0 (n, 3)`` (e.g. :meth:`EquilibriumJacobian.predict`)
    with the factorised tangent ``tangent`` of a nearby equilibrium (``EquilibriumJacobian.tangent``)
    in place of an AMG hierarchy or a fresh factorisation.

    Chord iterations ``u <- u - K0^-1 g(u)`` (a gradient and two triangular solves each, no
    assembly) while they shrink the residual by ``chord_rate`` or better and ``CHORD_LOOKAHEAD``
    more at that rate would converge; then Newton steps with the true tangent at ``u``, solved by
    CG preconditioned with ``K0`` (a few iterations: the two tangents are close) to a forcing term
    (:data:`CHORD_NEWTON_RTOL`, :data:`CHORD_NEWTON_GAMMA`, :data:`CHORD_LAST_SHARE`). A last step
    that at the previous step's rate lands within ``CHORD_LAST_SHARE`` of the tolerance reuses
    that step's tangent (a modified Newton step: no assembly).

    Converged when ``|g|`` meets the simulator's Newton tolerance (``rtol`` times the reference
    force of :meth:`FaceSimulator.force_scale` at this start, plus ``atol``), as
    :meth:`FaceSimulator.equilibrium` requires. A chord iteration that does not shrink the residual
    is undone and the solve goes on with Newton steps from the best iterate (once: on the demo clip
    this keeps 7 of the 12 trial equilibria of 24 frames that used to fall back to a Newton solve
    from scratch). Gives up (``converged=False``) when a Newton step does not shrink the residual
    by ``contraction``, a chord iteration fails a second time, or CG fails -- the tangent here is then too
    far from ``K0`` -- or after ``max_iterations``. Returns ``(x (n, 3), iterations, linear solves,
    converged)``; ``x`` is the iterate of least residual, a warm start for Newton if not converged.

    The start is ``x0`` with the bones placed exactly and their difference from ``x0``'s carried
    into the flesh (:meth:`FaceSimulator.predict`, as :meth:`FaceSimulator.equilibrium` starts),
    not snapped onto the bone nodes alone (the paper-size face's third tracked frame: residual
    0.209 against 0.287). ``previous`` (``(n, 3)``, the equilibrium the step starts from): its flesh
    with the bones moved to ``controls`` is the start instead when its residual is lower. A
    first-order prediction can be far off (the paper-size face's first tracked frame, on a fresh
    Jacobian: residual 294 against 1.29 from the moved bones, benchmarks/RESULTS.md, session 23);
    one more gradient and a harmonic solve check it. An ``x0`` that, bones placed, has a tet
    crushed below :data:`~facesim.fem.equilibrium.PREDICT_MIN_J` is then dropped for that start
    rather than refined (the same face's first tracked frame: 3.5 s of as-rigid-as-possible steps
    for a residual of 90 against 1.27, session 35)."""
    import scipy.sparse.linalg as spla

    extras = sim.solve_terms(controls, frame, extra_terms)   # the same energy as FaceSimulator.equilibrium
    system = sim.system
    solves = 0
    with single_blas_thread():
        # with another start to compare, a crushed x0 is dropped rather than refined (FaceSimulator.predict)
        start = sim.predict(controls, x0, repair=previous is None)
        prob = g0 = None
        if start is not None:
            prob = Problem(sim.terms + extras, system, start, controls.a)
            g0 = prob.energy_and_gradient(prob.x_fixed)[1]
        if previous is not None:
            moved = Problem(sim.terms + extras, system, sim.predict(controls, previous), controls.a)
            g_moved = moved.energy_and_gradient(moved.x_fixed)[1]
            if g0 is None or np.linalg.norm(g_moved) < np.linalg.norm(g0):
                prob, g0 = moved, g_moved
        newton = sim.options.newton
        tol = newton.rtol * sim.force_scale(controls, extras, prob.x_fixed) + newton.atol
        u = prob.x_fixed[system.active].ravel().copy()
        x = best = prob.x_fixed
        previous, chord = np.inf, True
        inverse = preconditioner(tangent)   # single precision will do: g is checked in double
        M = spla.LinearOperator((system.n_dofs, system.n_dofs), matvec=inverse, dtype=np.float64)
        best_u = u.copy()
        retried = False
        du = None
        newton_before = False   # the step to this iterate was a Newton step (its rate predicts the next one's)
        A = None   # the last Newton step's tangent (set whenever newton_before is)
        for it in range(max_iterations + 1):
            g = g0 if it == 0 else prob.energy_and_gradient(x)[1]
            res = float(np.linalg.norm(g))
            if res <= tol:
                return x, it, solves, True
            rate = res / previous
            if chord and not retried and it > 0 and it < max_iterations and rate > 1.0:
                # the chord step overshot (the tangent changed: contact came on, say): back to the
                # best iterate and on with Newton steps there, CG preconditioned by K0, rather than
                # giving the whole solve up to a Newton solve from scratch
                retried, chord = True, False
                x, u, res = best, best_u.copy(), previous
                g = prob.energy_and_gradient(x)[1]
            elif not chord and it < max_iterations and not rate <= contraction:
                # a Newton step that overshot (contact coming on, a soft direction of a wide step):
                # shorter steps along it, each one more gradient, before giving the solve up
                for alpha in NEWTON_BACKTRACK:
                    u = best_u + alpha * du
                    x = prob.positions(u)
                    g = prob.energy_and_gradient(x)[1]
                    res = float(np.linalg.norm(g))
                    if res <= (1.0 - alpha * (1.0 - contraction)) * previous:
                        break
                else:
                    return best, it, solves, False
                if res <= tol:
                    return x, it, solves, True
                best, best_u, previous = x, u.copy(), res
            elif it == max_iterations or not np.isfinite(res) or rate > (1.0 if chord else contraction):
                return best, it, solves, False
            else:
                best, best_u, previous = x, u.copy(), res
                # stay with chord iterations while a few more of them at this rate would converge
                chord = chord and rate <= chord_rate and res * rate ** CHORD_LOOKAHEAD <= tol
            if chord:
                du = inverse(-g)
                solves += 1
            else:
                # the forcing term: the last Newton step's rate predicts this one's (superlinear)
                eta = CHORD_NEWTON_RTOL if not newton_before else min(CHORD_NEWTON_RTOL, CHORD_NEWTON_GAMMA * rate ** 2)
                # the last step's tangent once a step at its rate would land within the tolerance: a
                # modified Newton step contracts by about the last step's rate (the tangent moved by
                # O(|du|) since), so it converges too, without an assembly -- the demo clip's last
                # steps from ~1e-5 to ~1e-6 N (benchmarks/RESULTS.md, session 34)
                if not (newton_before and rate * res <= CHORD_LAST_SHARE * tol):   # (a Newton step before: A is set)
                    A = prob.hessian(x, project=False)
                du, info, its = counted_cg(A, -g, max(eta, CHORD_LAST_SHARE * tol / res), CHORD_NEWTON_MAXITER, M)
                solves += its
                if info != 0:
                    return best, it, solves, False
            newton_before = not chord
            du[~system.free_dof] = 0.0
            u += du
            x = prob.positions(u)
    return best, max_iterations, solves, False   # not reached: the loop returns


__all__ = ["ControlSpace", "EquilibriumJacobian", "equilibrium_jacobian", "factorised_tangent", "marker_jacobian",
           "head_increment", "near_equilibrium"]
