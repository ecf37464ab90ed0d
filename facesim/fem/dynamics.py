"""Implicit dynamics of the face: the quasistatic energy plus inertia and damping, integrated in
time with BDF2 (Sifakis et al. 2005 re-simulate extracted activations dynamically for ballistic
effects such as a head shake or softened nose cartilage, and find that with realistic tissue the
dynamic and quasistatic results are indistinguishable; ``benchmarks/bench_dynamics.py`` measures it).

**What is integrated.** ``M a = f(x, a) - C v`` with ``f = -dE/dx``, ``E`` the energy the
quasistatic solve minimises (:class:`~facesim.fem.equilibrium.FaceSimulator`: flesh, muscles and
its contact terms, the same bone attachments as moving Dirichlet conditions), ``M`` the mass
matrix and ``C = alpha M + beta K0`` Rayleigh damping.

**Integrator: BDF2, started (and restarted) by backward Euler.** With ``c = 2/3`` (BDF2) or
``c = 1`` (backward Euler), ``xbar = (4 x_n - x_{n-1})/3``, ``vbar = (4 v_n - v_{n-1})/3`` (BDF2)
or ``x_n``, ``v_n`` (BE), the step is ``x_{n+1} = xbar + c h v_{n+1}``,
``v_{n+1} = vbar + c h M^-1 (f(x_{n+1}) - C v_{n+1})``. Eliminating ``v_{n+1}`` turns it into the
minimisation of an incremental potential

    Phi(x) = E(x) + 1/(2 (c h)^2) |x - xhat|_M^2 + 1/(2 c h) |x - xbar|_C^2,   xhat = xbar + c h vbar

(its stationarity is exactly the BDF equations), solved by the quasistatic solver's own Newton
(:func:`~facesim.fem.newton.newton`), so contact, the inversion-safe line search, PSD projection
and the tolerances all carry over; then ``v_{n+1} = (x_{n+1} - xbar) / (c h)``. Why BDF2:

* *stable at any step*: BE and BDF2 are A- and L-stable, so the stiff mesh modes (hundreds of Hz
  to kHz for nearly incompressible tets) that no frame rate resolves are damped out instead of
  ringing; the trapezoidal rule / implicit Newmark (beta = 1/4) is A- but not L-stable (those
  modes ring forever) and its nonlinear form can gain energy.
* *second order, little numerical dissipation*: on an undamped oscillator, BDF2 loses 0.04 %,
  0.3 %, 6.7 % and 70 % of the energy per period at ``omega h`` = 0.05, 0.1, 0.3 and 1.3; BE
  loses 27 %, 46 %, 84 % and 99 % (BE makes every resolved mode look over-damped, so it is only
  the first step, where BDF2 has no history, and the step after a restart or a change of step).
* *never adds energy*: BDF2 is G-stable (Dahlquist 1978), so the numerical energy of a linear
  undamped system never grows; on the nonlinear box face (tests/fem/test_dynamics.py) the energy
  of a free oscillation of its lowest mode falls at every step, by 0.96 % per period at 50 steps
  per period, as the scalar oscillator predicts.

**Mass.** Lumped (row-sum) by default: each simulated tet gives ``rho V / 4`` to each of its
nodes (a scatter; ``mass="consistent"`` uses ``rho V / 20 (1 + delta_ab)``, same row sums).
Densities per tissue (t/mm^3): 1.06e-9 for flesh, lip and any tissue not listed (soft tissue,
1060 kg/m^3), 1.1e-9 for nose cartilage (:data:`DENSITY`); ``density`` overrides them.

**Damping defaults** (:data:`DAMPING` = ``(alpha, beta)`` = ``(0 1/s, 1e-3 s)``). ``beta K0`` (K0
the PSD-projected tangent of flesh and muscles at the start of the step, over every node of the
simulated tets, bones included, so the term is a PSD quadratic and a rigid motion of the whole
face is not damped) is a Kelvin-Voigt viscosity with retardation time ``beta``: loss tangent
``beta omega`` and damping ratio ``zeta = beta omega / 2`` per mode. 1 ms puts the loss tangent
at 0.13-0.63 between 21 and 100 Hz; MR elastography of soft tissues (brain, liver, muscle)
reports loss tangents of roughly 0.1-0.5 in that band (an order of magnitude, not a measurement
of the face). The coarse face's lowest modes (attached to the skull and jaw at rest, lumped mass,
1.72 kg of flesh) are at 21.0, 24.4, 28.0 and 31.0 Hz, so they get ``zeta`` = 0.066-0.097; modes
above 318 Hz (``omega > 2 / beta``) are over-damped. Where the projection clips element
eigenvalues (stressed, activated states) the damping sees the projected stiffness: a mode's ratio
is ``alpha / (2 omega) + beta omega_p^2 / (2 omega)``, ``omega_p^2`` its Rayleigh quotient of
``K0`` (``omega^2`` at rest; 2.1 ``omega^2`` for the activated box's lowest mode). ``alpha`` is 0:
mass-proportional damping brakes the absolute velocity, i.e. drags the face against the world
(air that is not there) in a head shake, and the face has no low modes that need it.

**Substeps.** A frame of duration ``frame_dt`` (``1 / fps``) is ``substeps`` steps of
``h = frame_dt / substeps``; the activations and jaw parameters are interpolated linearly across
them, the skull (and a rigid jaw) along the shortest rigid path (:func:`facesim.se3.interpolate_rigid`),
so the bones are moving Dirichlet conditions. Each step starts Newton from the predictor ``xhat``
with the bones placed (their mismatch carried into the flesh harmonically,
:meth:`~facesim.fem.equilibrium.FaceSimulator.predict`); the tolerance is the options' ``rtol``
relative to the frame's load (:meth:`~facesim.fem.equilibrium.FaceSimulator.force_scale`) or to
the step's own force imbalance at the predictor when that is larger.

Default 2 substeps: at 24-30 fps, h = 17-21 ms, one dynamic frame of the demo clip costs 1.3-2.1
quasistatic frames on the coarse face, up to 2.6 under a head shake (4 substeps: 2.1-4.0;
``benchmarks/bench_dynamics.py``). The drive is resolved (a 3 Hz motion has ``omega h`` = 0.3-0.4;
BDF2 takes ~12 % of its energy per period, about what ``beta`` takes), the face's own 21-31 Hz
ringing is not: it lies above the input's Nyquist frequency (12-15 Hz), and BDF2 at ``omega h`` > 1
damps it out. That suits frame-sampled controls: interpolated linearly, they change the bones' and
muscles' velocity at every frame boundary, a kick, and steps that resolve the ringing (16 substeps
and more) reproduce the ringing of those kicks, an artefact of the sampling, not of the motion.
Fast ballistic detail needs more steps: a 10 degree head shake (sin^3 at 3 Hz) moves the softened
(0.2 x) nose tip 1.4 mm away from the quasistatic path with 4 substeps, 0.45 mm with 2.

**Stiffness overrides.** ``soften`` scales a tissue's Mooney-Rivlin constants (``c10, c01,
kappa``, so its Poisson ratio stays) by a factor: ``"nose:0.2"`` is nose cartilage at 0.2 x its
stiffness. Short names: ``nose`` / ``cartilage`` -> ``nose_cartilage``, ``lips`` -> ``lip``; a
model's own tissue names and unique prefixes of them work too (:func:`tissue_name`).

Units: mm, N, s, MPa, tonnes (t = N s^2 / mm); energies mJ (N mm), velocities mm/s.
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from facesim.budget import time_budget
from facesim.controls import Controls
from facesim.energy import NodeTerm
from facesim.errors import FacesimError, SolverError
from facesim.fem.equilibrium import Equilibrium, EquilibriumOptions, FaceSimulator
from facesim.fem.newton import Problem, SolveReport, newton
from facesim.fem.system import DofSystem
from facesim.model import FaceModel
from facesim.se3 import interpolate_rigid

SOFT_TISSUE_DENSITY = 1.06e-9
"""Density of soft tissue, t/mm^3 (1060 kg/m^3): flesh, lip and any tissue :data:`DENSITY` lacks."""
DENSITY = {"flesh": SOFT_TISSUE_DENSITY, "lip": SOFT_TISSUE_DENSITY, "nose_cartilage": 1.1e-9}
"""Default density per tissue name, t/mm^3."""
DAMPING = (0.0, 1e-3)
"""Default Rayleigh damping ``(alpha 1/s, beta s)``: see the module doc."""
METHODS = ("bdf2", "euler")
MASSES = ("lumped", "consistent")
TANGENT_UPDATES = ("frame", "step")
TISSUE_ALIASES = {"nose": "nose_cartilage", "cartilage": "nose_cartilage", "lips": "lip"}
"""Short tissue names (accepted wherever the model has the tissue they stand for)."""


# ------------------------------------------------------------------ options and tissue specs
def tissue_name(model: FaceModel, name: str, what: str = "tissue") -> str:
    """The model's tissue that ``name`` stands for: the name itself, a short name
    (:data:`TISSUE_ALIASES`) or a unique prefix; a one-line :class:`FacesimError` naming ``what``
    and listing the model's tissues otherwise."""
    names = [t.name for t in model.tissues]
    key = str(name).strip()
    if key in names:
        return key
    if TISSUE_ALIASES.get(key) in names:
        return TISSUE_ALIASES[key]
    hits = [n for n in names if n.startswith(key)] if key else []
    if len(hits) == 1:
        return hits[0]
    short = [f"{a} = {t}" for a, t in TISSUE_ALIASES.items() if t in names]
    raise FacesimError(f"{what}: {'ambiguous' if hits else 'unknown'} tissue {key!r}; the model's tissues: "
                       f"{', '.join(names)}" + (f" (short: {', '.join(short)})" if short else ""))


def parse_tissue_values(specs, what: str = "tissue") -> tuple[tuple[str, float], ...]:
    """``TISSUE:VALUE`` specs (strings like ``"nose:0.2"``, ``(name, value)`` pairs or a mapping) as
    ``((name, value), ...)`` with finite values > 0, names as given (resolve them against a model
    with :func:`tissue_name`). One-line :class:`FacesimError` naming ``what`` on a malformed spec."""
    if specs is None:
        return ()
    items = specs.items() if isinstance(specs, dict) else ([specs] if isinstance(specs, str) else specs)
    out = []
    for item in items:
        if isinstance(item, str):
            name, sep, value = item.rpartition(":")
            if not sep or not name.strip():
                raise FacesimError(f"{what}: expected TISSUE:VALUE (e.g. nose:0.2), got {item!r}")
        else:
            try:
                name, value = item
            except (TypeError, ValueError):
                raise FacesimError(f"{what}: expected TISSUE:VALUE or (tissue, value), got {item!r}") from None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise FacesimError(f"{what}: expected a number after {str(name).strip()}:, got {value!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise FacesimError(f"{what}: expected a finite value > 0 for {str(name).strip()}, got {value!r}")
        out.append((str(name).strip(), v))
    return tuple(out)


def parse_damping(spec) -> tuple[float, float]:
    """``"ALPHA,BETA"`` (or a pair) as ``(alpha 1/s, beta s)``, both finite and >= 0."""
    parts = spec.split(",") if isinstance(spec, str) else list(spec)
    try:
        alpha, beta = (float(p) for p in parts)
    except (TypeError, ValueError):
        raise FacesimError(f"damping: expected ALPHA,BETA (mass-proportional 1/s, stiffness-proportional s; "
                           f"e.g. 0,1e-3), got {spec!r}") from None
    if not (math.isfinite(alpha) and math.isfinite(beta) and alpha >= 0 and beta >= 0):
        raise FacesimError(f"damping: expected finite ALPHA,BETA >= 0, got {spec!r}")
    return alpha, beta


@dataclass(frozen=True)
class DynamicsOptions:
    """How the face is integrated in time (see the module doc).

    method : ``"bdf2"`` (default; its first step and any restart are backward Euler) or ``"euler"``.
    substeps : time steps per frame (``h = frame_dt / substeps``).
    damping : ``(alpha 1/s, beta s)`` Rayleigh damping ``C = alpha M + beta K0``, or ``"ALPHA,BETA"``.
    density : per-tissue density overrides, t/mm^3 (``"lip:1.1e-9"``, pairs or a mapping).
    soften : per-tissue stiffness factors (``"nose:0.2"``: nose cartilage at 0.2 x its c10, c01, kappa).
    mass : ``"lumped"`` (row-sum, default) or ``"consistent"``.
    damping_tangent : where ``K0`` is assembled: ``"step"`` (default: at the start of every step) or
        ``"frame"`` (at the start of the frame's first step, kept for its other steps: one assembly
        per frame instead of one per step, ~0.17 s each on the coarse face; the tangent then lags by
        up to a frame, so the order in the step is kept only for the tangent's frame-wise path).
    """

    method: str = "bdf2"
    substeps: int = 2
    damping: tuple = DAMPING
    density: tuple = ()
    soften: tuple = ()
    mass: str = "lumped"
    damping_tangent: str = "step"

    def __post_init__(self):
        if self.method not in METHODS:
            raise FacesimError(f"integrator: expected one of {', '.join(METHODS)}, got {self.method!r}")
        if self.mass not in MASSES:
            raise FacesimError(f"mass: expected one of {', '.join(MASSES)}, got {self.mass!r}")
        if self.damping_tangent not in TANGENT_UPDATES:
            raise FacesimError(f"damping_tangent: expected one of {', '.join(TANGENT_UPDATES)}, got "
                               f"{self.damping_tangent!r}")
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, (int, np.integer)) or self.substeps < 1:
            raise FacesimError(f"substeps: expected an integer >= 1, got {self.substeps!r}")
        object.__setattr__(self, "substeps", int(self.substeps))
        object.__setattr__(self, "damping", parse_damping(self.damping))
        object.__setattr__(self, "density", parse_tissue_values(self.density, "density"))
        object.__setattr__(self, "soften", parse_tissue_values(self.soften, "soften"))

    @property
    def alpha(self) -> float:
        return self.damping[0]

    @property
    def beta(self) -> float:
        return self.damping[1]


def softened_model(model: FaceModel, soften) -> FaceModel:
    """``model`` with each tissue of ``soften`` (``TISSUE:FACTOR`` specs) scaled in stiffness: its
    ``c10, c01, kappa`` times the factor (the Poisson ratio stays). The same model without specs."""
    factors = {tissue_name(model, n, "soften"): f for n, f in parse_tissue_values(soften, "soften")}
    if not factors:
        return model
    tissues = tuple(type(t)(t.name, t.c10 * factors[t.name], t.c01 * factors[t.name], t.kappa * factors[t.name])
                    if t.name in factors else t for t in model.tissues)
    return model.with_tissues(tissues)


def tissue_densities(model: FaceModel, density=()) -> np.ndarray:
    """``(n_tissues,)`` density per tissue of ``model``, t/mm^3: :data:`DENSITY` (soft tissue for
    names it lacks) with the ``density`` overrides (``TISSUE:VALUE`` specs)."""
    rho = np.array([DENSITY.get(t.name, SOFT_TISSUE_DENSITY) for t in model.tissues])
    names = [t.name for t in model.tissues]
    for n, v in parse_tissue_values(density, "density"):
        rho[names.index(tissue_name(model, n, "density"))] = v
    return rho


def lumped_mass(tets, V0, rho, elems, n_nodes: int) -> np.ndarray:
    """``(n_nodes,)`` lumped (row-sum) mass, t: each tet of ``elems`` gives ``rho V0 / 4`` to each of
    its nodes. ``tets (m, 4)``, ``V0 (m,)`` mm^3, ``rho (m,)`` t/mm^3, ``elems (k,)`` tet ids."""
    T = np.asarray(tets)[elems]
    share = np.repeat(np.asarray(rho)[elems] * np.asarray(V0)[elems] / 4.0, 4)
    return np.bincount(T.ravel(), share, minlength=n_nodes)


def consistent_mass(tets, V0, rho, elems, n_nodes: int) -> sp.csr_matrix:
    """``(n_nodes, n_nodes)`` consistent mass of linear tets, t: ``rho V0 / 20 (1 + delta_ab)`` per
    node pair of a tet (its rows sum to :func:`lumped_mass`)."""
    T = np.asarray(tets)[elems]
    m = np.asarray(rho)[elems] * np.asarray(V0)[elems] / 20.0
    local = np.ones((4, 4)) + np.eye(4)
    rows = np.repeat(T, 4, axis=1).ravel()
    cols = np.tile(T, (1, 4)).ravel()
    vals = (m[:, None] * local.ravel()[None, :]).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(n_nodes, n_nodes))


# ------------------------------------------------------------------ the two extra energy terms
def _block_index(system: DofSystem, nodes_i, nodes_j) -> np.ndarray:
    """Block of ``system``'s BSR data coupling node ``nodes_i[k]`` with ``nodes_j[k]``; -1 where either
    node is not a system row or the pair is outside the pattern."""
    ri, rj = system.row_of[nodes_i], system.row_of[nodes_j]
    out = np.full(len(ri), -1, np.int64)
    if not len(system.indices):
        return out
    N = len(system.active)
    rows = np.repeat(np.arange(N, dtype=np.int64), np.diff(system.indptr))
    keys = rows * N + system.indices            # sorted: rows in order, columns sorted within a row
    want = ri * N + rj
    pos = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
    ok = (ri >= 0) & (rj >= 0) & (keys[pos] == want)
    out[ok] = pos[ok]
    return out


class _PerSystem:
    """One derived array per :class:`DofSystem` (the pattern never changes): the last one kept."""

    def __init__(self, build):
        self.build, self.ref, self.value = build, None, None

    def __call__(self, system):
        if self.ref is None or self.ref() is not system:
            self.value, self.ref = self.build(system), weakref.ref(system)
        return self.value


class MassTerm(NodeTerm):
    """``(w / 2) (x - centre)^T M (x - centre)`` over all node coordinates: the inertia term of an
    implicit step (``w = 1 / (c h)^2``, ``centre`` the predictor) or mass-proportional damping
    (``w = alpha / (c h)``, ``centre`` the BDF history point).

    ``mass``: ``(n,)`` lumped masses (t) or an ``(n, n)`` sparse consistent mass; ``weight`` 1/s^2
    (or 1/s); ``centre (n, 3)`` mm. Energy mJ, gradient N, Hessian ``w M (x) I3`` N/mm (exact, PSD).
    """

    def __init__(self, mass, weight: float, centre):
        self.mass = mass if sp.issparse(mass) else np.ascontiguousarray(mass, dtype=np.float64)
        self.weight = float(weight)
        self.centre = np.ascontiguousarray(centre, dtype=np.float64)
        n = self.mass.shape[0]
        if self.centre.shape != (n, 3):
            raise FacesimError(f"mass term: expected a centre of shape ({n}, 3), got {self.centre.shape}")
        self._blocks = _PerSystem(self._map)

    def _times_mass(self, d) -> np.ndarray:
        return self.mass @ d if sp.issparse(self.mass) else self.mass[:, None] * d

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        d = np.asarray(x, dtype=np.float64) - self.centre
        Md = self._times_mass(d)
        return 0.5 * self.weight * float(np.sum(d * Md)), self.weight * Md

    def _map(self, system):
        if sp.issparse(self.mass):
            M = self.mass.tocoo()
            return _block_index(system, M.row, M.col), M.data
        nodes = np.arange(len(self.mass))
        return _block_index(system, nodes, nodes), self.mass

    def add_hessian(self, x, a, system: DofSystem, data: np.ndarray, project: bool = True) -> None:
        blocks, m = self._blocks(system)
        ok = blocks >= 0
        if sp.issparse(self.mass):   # several node pairs may share a block: sum them first
            diagonal = np.bincount(blocks[ok], self.weight * m[ok], minlength=len(data))
            for k in range(3):
                data[:, k, k] += diagonal
        else:                        # one diagonal block per node
            for k in range(3):
                data[blocks[ok], k, k] += self.weight * m[ok]

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        M = self.mass if sp.issparse(self.mass) else sp.diags(self.mass)
        return sp.kron(self.weight * M, sp.identity(3), format="csr")


class TangentDampingTerm(NodeTerm):
    """``(w / 2) (x - centre)^T K0 (x - centre)``: stiffness-proportional damping of an implicit step
    (``w = beta / (c h)``), ``K0`` a frozen tangent over every node of the simulated tets, bones
    included (so a rigid motion of the whole face is not damped).

    ``full``: the :class:`DofSystem` of ``K0`` (no prescribed node); ``K0_data (full.n_blocks, 3, 3)``
    N/mm its BSR blocks; ``weight`` dimensionless (``beta / (c h)``); ``centre (n, 3)`` mm. Energy
    mJ, gradient N, Hessian ``w K0`` N/mm (PSD when K0 is).
    """

    def __init__(self, full: DofSystem, K0_data, weight: float, centre):
        self.full = full
        self.data = np.ascontiguousarray(K0_data, dtype=np.float64)
        self.K0 = sp.bsr_matrix((self.data, full.indices, full.indptr), shape=(full.n_dofs, full.n_dofs))
        self.weight = float(weight)
        self.centre = np.ascontiguousarray(centre, dtype=np.float64)
        self._blocks = _PerSystem(self._map)

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        act = self.full.active
        d = (np.asarray(x, dtype=np.float64)[act] - self.centre[act]).ravel()
        Kd = self.K0 @ d
        g = np.zeros((self.full.n_nodes, 3))
        g[act] = self.weight * Kd.reshape(-1, 3)
        return 0.5 * self.weight * float(d @ Kd), g

    def _map(self, system):
        full = self.full
        rows = np.repeat(np.arange(len(full.active), dtype=np.int64), np.diff(full.indptr))
        return _block_index(system, full.active[rows], full.active[full.indices])

    def add_hessian(self, x, a, system: DofSystem, data: np.ndarray, project: bool = True) -> None:
        blocks = self._blocks(system)
        ok = blocks >= 0
        data[blocks[ok]] += self.weight * self.data[ok]   # one full block per system block: no repeats

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        n = self.full.n_nodes
        dof = (3 * self.full.active[:, None] + np.arange(3)).ravel()
        K = self.K0.tocoo()
        return sp.csr_matrix((self.weight * K.data, (dof[K.row], dof[K.col])), shape=(3 * n, 3 * n))


# ------------------------------------------------------------------ state and reports
@dataclass(frozen=True)
class DynamicState:
    """Where the integration stands: positions ``x (n, 3)`` mm and velocities ``v (n, 3)`` mm/s now,
    ``x_prev``, ``v_prev`` one step earlier (BDF2's history), ``h_prev`` the step that led here (s;
    0 when there is no history: the next step is backward Euler), the ``controls`` and ``frame``
    (number, may be fractional) of ``x``. Arrays are read-only."""

    x: np.ndarray
    v: np.ndarray
    x_prev: np.ndarray
    v_prev: np.ndarray
    h_prev: float
    controls: Controls
    frame: float = 0.0

    def __post_init__(self):
        for name in ("x", "v", "x_prev", "v_prev"):
            a = np.array(getattr(self, name), dtype=np.float64)
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "h_prev", float(self.h_prev))
        object.__setattr__(self, "frame", float(self.frame))

    @staticmethod
    def at_rest(x, controls: Controls, frame: float = 0.0) -> "DynamicState":
        """The state resting at ``x`` (zero velocity, no history)."""
        z = np.zeros_like(np.asarray(x, dtype=np.float64))
        return DynamicState(x, z, x, z, 0.0, controls, frame)

    def arrays(self) -> dict:
        """The arrays a restart needs (``x, v, x_prev, v_prev, h_prev``), for a state file."""
        return {"x": self.x, "v": self.v, "x_prev": self.x_prev, "v_prev": self.v_prev, "h_prev": self.h_prev}

    @staticmethod
    def from_arrays(arrays, controls: Controls, frame: float) -> "DynamicState":
        """The state of :meth:`arrays` (a mapping, e.g. an open ``.npz``) at ``controls`` and ``frame``."""
        return DynamicState(arrays["x"], arrays["v"], arrays["x_prev"], arrays["v_prev"], float(arrays["h_prev"]),
                            controls, frame)


@dataclass
class DynamicReport:
    """One frame of integration: ``substeps`` time steps, ``iterations`` Newton iterations summed over
    them, ``converged`` (every step did), ``kinetic_energy`` at the frame's end (mJ), ``stop_reason``
    (``"converged"`` or the first failing step's), ``seconds``, and each step's :class:`SolveReport`."""

    substeps: int
    iterations: int
    converged: bool
    kinetic_energy: float
    stop_reason: str
    seconds: float
    steps: list = field(default_factory=list)
    methods: list = field(default_factory=list)

    def solve_report(self) -> SolveReport:
        """The frame as one :class:`SolveReport` (what ``frames.csv`` logs): iterations and linear
        iterations summed over the steps, the last step's residuals and force scale."""
        last = self.steps[-1]
        return SolveReport(converged=self.converged, iterations=self.iterations, residuals=list(last.residuals),
                           energies=list(last.energies), linear_iterations=[i for s in self.steps for i in
                                                                             s.linear_iterations],
                           force_scale=last.force_scale, stop_reason=self.stop_reason,
                           seconds={"total": self.seconds, "substeps": self.substeps})


class _KnownTangent(NodeTerm):
    """The flesh and muscle terms of one implicit step whose projected Hessian at the step's start
    ``x_at`` is already assembled -- the damping tangent ``K0``, over every node of the simulated
    tets. Newton's first Hessian is taken there: it reads ``K0``'s blocks on the system's pattern
    (``blocks``: the ``K0`` block of each system block) instead of assembling the same element
    Hessians a second time (a third of a two-iteration step's assembly). It is the projected
    tangent even where Newton would have tried the true one: the first iteration of a step from the
    predictor, the true tangent's advantage (quadratic convergence near the solution) comes later.
    Everything else is the terms' own."""

    def __init__(self, terms, x_at, K0_data, blocks):
        self.terms, self.x_at, self.K0_data, self.blocks = tuple(terms), x_at, K0_data, blocks
        self.reused = 0

    def energy_and_gradient(self, x, a=None):
        e, g = 0.0, np.zeros_like(x)
        for t in self.terms:
            et, gt = t.energy_and_gradient(x, a)
            e += et
            g += gt
        return e, g

    def hessian(self, x, a=None, project: bool = True):
        return sum(t.hessian(x, a, project) for t in self.terms)

    def add_hessian(self, x, a, system, data, project: bool = True) -> None:
        if x is self.x_at or (x.shape == self.x_at.shape and np.array_equal(x, self.x_at)):
            data += self.K0_data[self.blocks]
            self.reused += 1
            return
        for t in self.terms:
            t.add_hessian(x, a, system, data, project)

    def sparse_hessian(self, x, a, system, project: bool = True):
        parts = [H for t in self.terms if (H := t.sparse_hessian(x, a, system, project)) is not None]
        return sum(parts[1:], parts[0]) if parts else None

    def max_step(self, x, dx) -> float:
        return float(min((t.max_step(x, dx) for t in self.terms), default=math.inf))


# ------------------------------------------------------------------ the integrator
class DynamicSimulator:
    """Implicit dynamics of one :class:`FaceModel` (see the module doc).

    Parameters: ``model``; ``options`` (:class:`EquilibriumOptions`: Newton, contact; the same as a
    quasistatic run); ``jaw_model`` and ``gain`` as for :class:`FaceSimulator`; ``dynamics``
    (:class:`DynamicsOptions`). The stiffness overrides make a softened copy of the model
    (``self.model``; the quasistatic simulator of it is ``self.sim``).

    Scripting::

        dyn = DynamicSimulator(model, jaw_model="sliding-condyle", dynamics=DynamicsOptions(soften=["nose:0.2"]))
        dyn.start(Controls(a0, jaw=q0))              # quasistatic equilibrium, at rest
        for a, q, H in frames[1:]:
            report = dyn.step(Controls(a, jaw=q, head=H), 1 / 24)
            x = dyn.state.x

    :meth:`advance` is the same step as a function of an explicit :class:`DynamicState`.
    """

    def __init__(self, model: FaceModel, options: EquilibriumOptions | None = None, jaw_model=None, gain=None,
                 dynamics: DynamicsOptions | None = None):
        self.dynamics = dynamics or DynamicsOptions()
        self.base_model = model
        self.model = softened_model(model, self.dynamics.soften)
        self.sim = FaceSimulator(self.model, options, jaw_model=jaw_model, gain=gain)
        self.jaw_model = self.sim.jaw_model
        rest, elems = self.sim.rest, self.sim.elems
        self.rho = tissue_densities(model, self.dynamics.density)[model.tissue]   # (m,) t/mm^3 per tet
        n = model.n_nodes
        self.lumped = lumped_mass(rest.tets, rest.V0, self.rho, elems, n)
        self.mass = self.lumped if self.dynamics.mass == "lumped" else consistent_mass(rest.tets, rest.V0, self.rho,
                                                                                          elems, n)
        # every node of the simulated tets, bones included, for the damping tangent
        self.full = DofSystem(rest.tets, n, np.zeros((n, 3), bool), elems) if self.dynamics.beta > 0 else None
        self._known = None   # the K0 block of each block of the simulator's system (_KnownTangent)
        if self.full is not None:
            sysm = self.sim.system
            rows = np.repeat(np.arange(len(sysm.active)), np.diff(sysm.indptr))
            blocks = _block_index(self.full, sysm.active[rows], sysm.active[sysm.indices])
            if (blocks >= 0).all():   # always, for a system of the same tets (kept general: else assembled)
                self._known = blocks
        m = self.model
        self._centres = (m.X[m.cranium_nodes].mean(axis=0) if len(m.cranium_nodes) else np.zeros(3),
                         m.X[m.jaw_nodes].mean(axis=0) if len(m.jaw_nodes) else np.zeros(3))
        self.state: DynamicState | None = None

    # -------------------------------------------------------------- measures
    @property
    def total_mass(self) -> float:
        """Mass of the simulated tets, t."""
        return float(self.lumped.sum())

    def kinetic_energy(self, v) -> float:
        """``v^T M v / 2`` over all nodes, mJ (``v (n, 3)`` mm/s)."""
        v = np.asarray(v, dtype=np.float64)
        Mv = self.mass @ v if sp.issparse(self.mass) else self.mass[:, None] * v
        return 0.5 * float(np.sum(v * Mv))

    def potential_energy(self, x, controls: Controls, frame: float = 0.0) -> float:
        """The quasistatic energy (flesh, muscles, contact) at ``x (n, 3)``, mJ."""
        controls = self.sim._check(controls)
        terms = self.sim.terms + self.sim.solve_terms(controls, frame)
        return float(sum(t.energy(x, controls.a) for t in terms))

    # -------------------------------------------------------------- stepping
    def start(self, controls: Controls, x0=None, frame: float = 0.0) -> Equilibrium:
        """Start at rest at the quasistatic equilibrium of ``controls`` (warm start ``x0``); sets
        :attr:`state` and returns the equilibrium (flagged, not raised, when it did not converge)."""
        eq = self.sim.equilibrium(controls, x0=x0, frame=frame)
        self.state = DynamicState.at_rest(eq.x, eq.controls, frame)
        return eq

    def restart(self, controls: Controls, x0=None, frame: float = 0.0) -> tuple[DynamicState, SolveReport | None, str]:
        """The state at rest at the quasistatic equilibrium of ``controls`` (warm start ``x0`` when
        finite), as a value: ``(state, report, error)``. A linear solver failing inside (``report``
        None) or non-finite positions leave the state at the warm start with the bones placed, and
        ``error`` says why."""
        controls = self.sim._check(controls)
        warm = x0 if x0 is not None and np.isfinite(x0).all() else None
        try:
            eq = self.sim.equilibrium(controls, x0=warm, frame=frame)
        except SolverError as exc:
            report, error = None, " ".join(str(exc).split())
        else:
            if np.isfinite(eq.x).all():
                return DynamicState.at_rest(eq.x, controls, frame), eq.report, ""
            report, error = eq.report, "non-finite positions"
        return DynamicState.at_rest(self.sim.attached_positions(controls, warm), controls, frame), report, error

    def posed_colliders(self, frame: float, controls: Controls) -> list:
        """The external colliders posed at ``frame`` with the bones of ``controls`` (as
        :meth:`facesim.session.Simulation.posed_colliders`)."""
        return self.sim.posed_colliders(controls, frame)

    def step(self, controls: Controls, frame_dt: float, frame: float | None = None) -> DynamicReport:
        """Advance :attr:`state` by one frame of ``frame_dt`` s to ``controls`` (at frame number
        ``frame``, default the state's + 1); returns the frame's report."""
        if self.state is None:
            raise FacesimError("dynamics: call start(controls) before step()")
        self.state, report = self.advance(self.state, controls, frame_dt, frame)
        return report

    def interpolate(self, c0: Controls, c1: Controls, s: float) -> Controls:
        """Controls a fraction ``s`` in [0, 1] of the way from ``c0`` to ``c1``: activations and jaw
        parameters linearly, the skull (and a rigid jaw's 4x4 pose) along the shortest rigid path."""
        if s >= 1.0:
            return c1
        a = (1.0 - s) * c0.a + s * c1.a
        head = None
        if c0.head is not None or c1.head is not None:
            head = interpolate_rigid(np.eye(4) if c0.head is None else c0.head,
                                     np.eye(4) if c1.head is None else c1.head, s, self._centres[0])
        rest = self.jaw_model.rest
        q0 = rest if c0.jaw is None else np.asarray(c0.jaw, dtype=np.float64)
        q1 = rest if c1.jaw is None else np.asarray(c1.jaw, dtype=np.float64)
        if self.jaw_model.n_params:
            jaw = (1.0 - s) * q0 + s * q1
        else:   # the rigid jaw's controls are its pose relative to the skull
            jaw = interpolate_rigid(q0, q1, s, self._centres[1])
        return Controls(a, jaw=jaw, head=head)

    def advance(self, state: DynamicState, controls: Controls, frame_dt: float, frame: float | None = None,
                substeps: int | None = None) -> tuple[DynamicState, DynamicReport]:
        """One frame: ``substeps`` (default the options') implicit steps from ``state`` to ``controls``
        over ``frame_dt`` s (the controls interpolated across them, :meth:`interpolate`); returns the
        new state and the report. The frame is bounded by the Newton options' ``max_seconds`` (and an
        enclosing :func:`facesim.budget.time_budget`). A step that does not converge is flagged in
        the report and the integration goes on from it; :class:`SolverError` is raised when a step
        leaves non-finite positions or its linear solver fails."""
        frame_dt = float(frame_dt)
        if not (math.isfinite(frame_dt) and frame_dt > 0):
            raise FacesimError(f"frame_dt: expected a duration > 0 (s), got {frame_dt}")
        t0 = time.perf_counter()
        c1 = self.sim._check(controls)
        f0 = state.frame
        f1 = f0 + 1.0 if frame is None else float(frame)
        k = self.dynamics.substeps if substeps is None else int(substeps)
        if k < 1:
            raise FacesimError(f"substeps: expected an integer >= 1, got {substeps!r}")
        h = frame_dt / k
        c0 = state.controls
        steps, methods = [], []
        with time_budget(self.sim.options.newton.max_seconds):
            load = self.sim.force_scale(c1)   # the frame's load (N): what the tolerance is relative to
            K0 = None   # the damping tangent: per frame (at its first step's start) or per step
            for i in range(1, k + 1):
                s = i / k
                if self.dynamics.damping_tangent == "step":
                    K0 = None
                state, rep, method, K0 = self._substep(state, self.interpolate(c0, c1, s), h, f0 + s * (f1 - f0),
                                                       load, K0)
                steps.append(rep)
                methods.append(method)
        failed = next((r for r in steps if not r.converged), None)
        report = DynamicReport(substeps=k, iterations=int(sum(r.iterations for r in steps)), converged=failed is None,
                               kinetic_energy=self.kinetic_energy(state.v),
                               stop_reason="converged" if failed is None else failed.stop_reason,
                               seconds=time.perf_counter() - t0, steps=steps, methods=methods)
        return state, report

    def tangent(self, x, a) -> np.ndarray:
        """``(full.n_blocks, 3, 3)`` projected (PSD) tangent of flesh and muscles at ``x (n, 3)`` and
        activations ``a``, N/mm, over every node of the simulated tets (the damping's ``K0``)."""
        data = self.full.new_data()
        for term in self.sim.terms:
            term.add_hessian(x, a, self.full, data, True)
        return data

    def step_terms(self, state: DynamicState, controls: Controls, h: float, K0=None) -> tuple:
        """The implicit step of ``h`` s from ``state`` to ``controls``: ``(terms, start, xbar, c h,
        method, K0)``, the inertia and damping terms, Newton's start (the predictor ``xhat`` with the
        bones placed), ``v_{n+1} = (x_{n+1} - xbar) / (c h)`` and the damping tangent used. BDF2
        needs a history made with the same step; otherwise (the first step, a restart, another step
        size) backward Euler.

        The damping tangent ``K0`` (:meth:`tangent`) is the one given, else taken at the start: for
        BDF2 the predictor is within O(h^2) of ``x_{n+1}``, so the damping force keeps second order (at
        ``x_n`` it would be off by O(h) and the method first order, as measured on the box face)."""
        # the same step up to rounding (1/fps split differently over a skipped frame number)
        bdf2 = self.dynamics.method == "bdf2" and abs(state.h_prev - h) <= 1e-9 * h
        if bdf2:
            ch = 2.0 * h / 3.0
            # (4 x_n - x_{n-1}) / 3 as an increment: exactly x_n for a state at rest (no drift)
            xbar = state.x + (state.x - state.x_prev) / 3.0
            vbar = state.v + (state.v - state.v_prev) / 3.0
        else:
            ch, xbar, vbar = h, state.x, state.v
        xhat = xbar + ch * vbar
        start = self.sim.predict(controls, xhat)   # the bones placed, their mismatch carried into the flesh
        terms = [MassTerm(self.mass, 1.0 / ch ** 2, xhat)]
        alpha, beta = self.dynamics.damping
        if alpha > 0:
            terms.append(MassTerm(self.mass, alpha / ch, xbar))
        if beta > 0:
            K0 = self.tangent(start, controls.a) if K0 is None else K0
            terms.append(TangentDampingTerm(self.full, K0, beta / ch, xbar))
        return tuple(terms), start, xbar, ch, "bdf2" if bdf2 else "euler", K0

    def _substep(self, state: DynamicState, controls: Controls, h: float, frame: float, load: float, K0=None):
        """One implicit step of ``h`` s to ``controls`` at ``frame``: minimise the incremental potential
        from the predictor; returns ``(state, SolveReport, method, damping tangent)``."""
        sim = self.sim
        fresh = K0 is None
        terms, start, xbar, ch, method, K0 = self.step_terms(state, controls, h, K0)
        flesh = sim.terms
        if fresh and K0 is not None and self._known is not None:   # K0 taken at start: Newton's first Hessian
            flesh = (_KnownTangent(sim.terms, start, K0, self._known),)
        prob = Problem(flesh + sim.solve_terms(controls, frame) + terms, sim.system, start, controls.a)
        # relative to the frame's load, or to the step's own imbalance at the predictor when larger
        # (a head shake under rest controls has no load: the cold start is an equilibrium)
        scale = max(load, float(np.linalg.norm(prob.energy_and_gradient(prob.x_fixed)[1])))
        x, rep = newton(prob, sim.options.newton, scale, sim.linear)
        if not np.isfinite(x).all():
            raise SolverError(f"dynamics: non-finite positions after a {method} step of {h:.3g} s at frame {frame:g}")
        v = (x - xbar) / ch
        return DynamicState(x, v, state.x, state.v, h, controls, frame), rep, method, K0


__all__ = ["DAMPING", "DENSITY", "DynamicReport", "DynamicSimulator", "DynamicState", "DynamicsOptions", "MassTerm",
           "SOFT_TISSUE_DENSITY", "TISSUE_ALIASES", "TangentDampingTerm", "consistent_mass", "lumped_mass",
           "parse_damping", "parse_tissue_values", "softened_model", "tissue_densities", "tissue_name"]
