"""Equilibrium of the face: flesh and muscles under bone attachments (Dirichlet conditions),
with the one contact set-up every entry point shares.

``FaceSimulator(model, options, jaw_model)`` precomputes everything that depends only on the mesh
(rest shape, pattern, colouring, terms) and keeps the linear solver, so an AMG hierarchy carries
over from frame to frame. Its :class:`EquilibriumOptions` say which contact the face has: the lips
kept out of the teeth (``teeth_contact``), the upper and lower lips out of each other
(``lip_contact``), the skin out of external ``colliders`` (fixed, scripted in time or carried by
a bone), all with one penalty ``contact_stiffness``. ``facesim simulate``, the
:class:`~facesim.session.Simulation` scripting API, the inverse solver's ``fit_frame`` / ``track``
and ``facesim solve-mocap`` all solve through :meth:`FaceSimulator.equilibrium`, whose energy is
flesh + muscles + :meth:`FaceSimulator.contact_terms` posed for the controls and the frame number;
the implicit Jacobian differentiates the same sum. ``equilibrium(model, controls, x0)`` is the
one-shot convenience.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from facesim._arrays import unique_ints
from facesim.budget import TIME_LIMIT, time_budget
from facesim.constants import CONTACT_STIFFNESS
from facesim.contact.penalty import ContactTerm, node_areas
from facesim.contact.scene import as_scene_collider
from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.fem.linear import make_linear_solver
from facesim.fem.material import DEFAULT_CLAMP
from facesim.fem.newton import NewtonOptions, Problem, SolveReport, newton
from facesim.fem.system import DofSystem, RestShape
from facesim.fem.terms import ElasticTerm, MuscleTerm
from facesim.kinematics.jaw_models import JawModel, RigidJaw, make_jaw_model
from facesim.model import FaceModel
from facesim.se3 import interpolate_rigid, rigid_fit

#: a starting guess whose worst simulated tet keeps less than this fraction of its rest volume
#: (or is inverted) is refined by as-rigid-as-possible steps (:meth:`FaceSimulator.predict`)
PREDICT_MIN_J = 0.2
PREDICT_ARAP_ITERATIONS = 5
#: an equilibrium is first sought with the flesh clamped at this singular value (better conditioned
#: linear systems on the way); kept when no simulated tet ends below it -- it is then an equilibrium
#: of the flesh at the options' smaller clamp too, whose energy is the same there -- else solved
#: again from the start at the options' clamp (docs/physics.md)
PATH_CLAMP = 0.1


@dataclass(frozen=True)
class EquilibriumOptions:
    """newton : :class:`NewtonOptions`; volumetric : ``"log"`` or ``"quadratic"``; clamp : singular
    value clamp of the invertible flesh; substeps : when a solve fails, it is retried as a
    sequence of this many equilibria along the way from the start (bones interpolated on SE(3),
    activations linearly from the start's when starting from rest); 1 disables the retry.

    Contact (penalty energy terms, all with ``contact_stiffness`` N/mm^3: pressure per mm of
    penetration, area-weighted):

    teeth_contact : the lip surfaces (``model.lip_upper``, ``lip_lower``) are kept out of the teeth
        colliders, which move with their bones (where a node's rest clearance is negative -- the
        mesh envelope dipping into the teeth -- the penalty starts just below it, so the rest shape
        stays an equilibrium);
    lip_contact : the upper and lower lips are kept out of each other
        (:func:`~facesim.contact.self_contact.lip_contact_term`);
    colliders : external colliders the skin cannot enter: :class:`~facesim.contact.Collider`, bare
        shapes, :class:`~facesim.contact.KinematicPath` (posed at the frame number) or
        :class:`~facesim.contact.scene.SceneCollider` (optionally carried by a bone).
    """

    newton: NewtonOptions = NewtonOptions()
    volumetric: str = "log"
    clamp: float = DEFAULT_CLAMP
    substeps: int = 4    # on failure, retry moving bones and activations there in this many steps
    teeth_contact: bool = False
    lip_contact: bool = False
    colliders: tuple = ()
    contact_stiffness: float = CONTACT_STIFFNESS

    def __post_init__(self):
        k = self.contact_stiffness
        if not (isinstance(k, (int, float)) and np.isfinite(k) and k > 0):
            raise FacesimError(f"contact stiffness: expected a positive number (N/mm^3), got {k}")
        object.__setattr__(self, "colliders", tuple(as_scene_collider(c, i) for i, c in enumerate(self.colliders)))


def has_lips(model: FaceModel) -> bool:
    """Whether ``model`` has upper and lower lip surfaces (what lip contact needs)."""
    return bool(len(model.lip_upper) and len(model.lip_lower))


def has_teeth(model: FaceModel) -> bool:
    """Whether ``model`` has lip surfaces and teeth colliders (what teeth contact needs)."""
    return has_lips(model) and any("teeth" in s.name for s in model.colliders)


@dataclass
class Equilibrium:
    """Result of one equilibrium solve: positions ``x (n, 3)`` mm and what the solver did."""

    x: np.ndarray
    controls: Controls
    report: SolveReport

    @property
    def converged(self) -> bool:
        return self.report.converged

    @property
    def iterations(self) -> int:
        return self.report.iterations

    @property
    def residuals(self) -> list:
        return self.report.residuals


class FaceSimulator:
    """Quasistatic simulator of one :class:`FaceModel`.

    Parameters: ``model``; ``options`` (:class:`EquilibriumOptions`, with the contact set-up);
    ``jaw_model``: a :class:`~facesim.kinematics.jaw_models.JawModel` or its name (see
    :func:`~facesim.kinematics.jaw_models.make_jaw_model`; default the rigid jaw); ``gain (n_muscles,)`` per-muscle scale of the active
    force-length curve (exaggeration, Sifakis 2005 Fig. 8).
    """

    def __init__(self, model: FaceModel, options: EquilibriumOptions | None = None, jaw_model=None, gain=None):
        self.model = model
        self.options = options or EquilibriumOptions()
        self.jaw_model: JawModel = RigidJaw() if jaw_model is None else make_jaw_model(model, jaw_model)
        self.rest = RestShape(model.X, model.tets)
        self.elems = np.flatnonzero(model.simulated)
        n = model.n_nodes
        fixed = np.zeros((n, 3), bool)
        fixed[model.cranium_nodes] = True
        fixed[model.jaw_nodes] = True
        self.fixed = fixed
        self.system = DofSystem(self.rest.tets, n, fixed, self.elems)
        tis = model.tissues
        idx = model.tissue
        self.elastic = ElasticTerm(self.rest, np.array([t.c10 for t in tis])[idx], np.array([t.c01 for t in tis])[idx],
                                   np.array([t.kappa for t in tis])[idx], elems=self.elems,
                                   volumetric=self.options.volumetric, clamp=self.options.clamp)
        self._path_elastic = None
        self._cold = {}   # the flesh of the tets a cold start deforms, by clamp (force_scale)
        if self.options.clamp < PATH_CLAMP:
            self._path_elastic = self.elastic.with_clamp(PATH_CLAMP)
        self.elastic._chunked(self.system)   # the system's chunk order: the gradient's too (no second copy)
        mus = model.muscles
        self.muscle = MuscleTerm(self.rest, mus.tet, mus.muscle, mus.fraction, mus.fibre, mus.sigma_max, gain=gain,
                                 elems=self.elems)
        self.linear = make_linear_solver(self.options.newton.linear_solver)
        self._laplace = None
        self._edges = None
        self._teeth = None   # (lip nodes, teeth SDFs with their bones, weights, margin, rest overlap), built on first use
        self._lips = None    # the lip self-contact term, built on first use
        self._skin = None    # the skin-vs-external-colliders term (colliders posed per frame)
        if self.options.teeth_contact:
            self._teeth_setup()   # a model without teeth or lips is refused here, not in a frame
        if self.options.lip_contact:
            self.lip_term()

    def _harmonic(self):
        """Factorised graph Laplacian of the simulated mesh (edge weights 1/length), free x fixed split."""
        if self._laplace is None:
            import scipy.sparse as sp

            from facesim.fem.linear import PardisoFactor, factorize, pardiso_available

            T = self.rest.tets[self.elems]
            e = np.sort(T[:, [0, 1, 0, 2, 0, 3, 1, 2, 1, 3, 2, 3]].reshape(-1, 2), axis=1).astype(np.int64)
            key = unique_ints(e[:, 0] * np.int64(self.model.n_nodes) + e[:, 1])   # (np.unique(e, axis=0): 6.6 s)
            e = np.stack([key // self.model.n_nodes, key % self.model.n_nodes], axis=1)
            w = 1.0 / np.maximum(np.linalg.norm(self.model.X[e[:, 0]] - self.model.X[e[:, 1]], axis=1), 1e-9)
            n = self.model.n_nodes
            W = sp.coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
            L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
            free = np.flatnonzero(~self.fixed.all(axis=1))
            fixed = np.flatnonzero(self.fixed.all(axis=1))
            Lff = L[free][:, free].tocsc()
            Lff = Lff + sp.diags(np.where(np.asarray(Lff.diagonal()) == 0, 1.0, 0.0))   # isolated nodes
            # symmetric positive definite: PARDISO when installed, else SuperLU in symmetric mode
            # (scipy's default column ordering took 86 s on the paper-size face, this 1-2 s)
            # (a double factor: a 3-column solve without refinement, 2.0 ms against 5.0 ms refined
            # from a single one on the coarse face, every predicted start of a trial equilibrium)
            lu = PardisoFactor(Lff, single=False) if pardiso_available() else factorize(Lff)
            self._laplace = (free, fixed, lu, L[free][:, fixed].tocsr())
            self._edges = (np.ascontiguousarray(e, dtype=np.int64), w)
        return self._laplace

    def predict(self, controls: Controls, x=None, transforms=None, repair: bool = True) -> np.ndarray | None:
        """Starting guess: ``x`` (default: the rest shape moved with the skull) with the bones placed
        and their displacement carried into the free flesh by harmonic interpolation, so a large
        bone motion does not start Newton from crushed elements next to the bone. A guess whose worst
        simulated tet keeps less than :data:`PREDICT_MIN_J` of its volume is refined by
        as-rigid-as-possible steps; ``repair=False`` returns None for it instead (a caller with
        another start to fall back on: on the paper-size face those steps cost 3.5 s for a
        first-order prediction whose residual was still 70x the other start's)."""
        base = self.attached_positions(Controls(controls.a, None, controls.head), x) if x is None else \
            np.array(x, dtype=np.float64)
        target = self.attached_positions(controls, base, transforms)
        fixed = np.flatnonzero(self.fixed.all(axis=1))
        d = target[fixed] - base[fixed]
        if not np.any(d):   # no bone moved: nothing to carry (and no Laplacian to factorise)
            return target
        free, fixed, lu, Lfc = self._harmonic()
        out = target.copy()
        out[free] = base[free] + lu.solve(-(Lfc @ d))
        if self.element_quality(out)[1] < PREDICT_MIN_J:
            if not repair:
                return None
            out = self._as_rigid_as_possible(base, out, PREDICT_ARAP_ITERATIONS)
        return out

    def _as_rigid_as_possible(self, base, x, iterations: int) -> np.ndarray:
        """``x (n, 3)`` with its free nodes moved by ``iterations`` local-global steps of
        as-rigid-as-possible deformation (Sorkine & Alexa 2007) of ``base``'s edges onto ``x``'s
        (the mesh's edge graph, weights 1/rest length, the prefactorised Laplacian of
        :meth:`_harmonic`): harmonic interpolation of a large bone motion shears the flesh next to
        the bone, rotated edges follow it -- on the Badin face opened 0.3 rad from rest, 30
        inverted tets in the harmonic start, 17 after these steps, and Newton 62 -> 19 iterations
        with the 0.01 clamp (benchmarks/RESULTS.md, session 20)."""
        from facesim._kernels.arap import best_rotations, edge_covariances, rotated_edges_rhs

        free, fixed, lu, Lfc = self._harmonic()
        e, w = self._edges
        base = np.ascontiguousarray(base, dtype=np.float64)
        n = len(base)
        S, R, b = np.empty((n, 3, 3)), np.empty((n, 3, 3)), np.empty((n, 3))
        x = np.array(x, dtype=np.float64)
        for _ in range(iterations):
            edge_covariances(base, x, e, w, S)
            best_rotations(S, R)
            rotated_edges_rhs(base, R, e, w, b)
            x[free] = lu.solve(b[free] - Lfc @ x[fixed])
        return x

    @property
    def terms(self):
        return (self.elastic, self.muscle)

    # ------------------------------------------------------------------ contact
    def _teeth_setup(self):
        """Lip nodes, the teeth SDFs with their bones, area weights and the penalty's zero (mm)."""
        if self._teeth is None:
            from facesim.contact.sdf import MeshSDF

            m = self.model
            if not has_teeth(m):
                raise FacesimError("teeth contact: the model has no teeth colliders or no lip surfaces")
            tris = np.concatenate([m.lip_upper, m.lip_lower])
            nodes = np.unique(tris)
            teeth = [(MeshSDF.from_mesh(s.vertices, s.faces, spacing=1.0, name=s.name), s.bone)
                     for s in m.colliders if "teeth" in s.name]
            rest = np.min([sdf.distance(m.X[nodes]) for sdf, _ in teeth], axis=0)
            # per node: where the rest mesh's lip envelope already dips into the teeth, the penalty
            # starts 0.05 mm below that node's own rest clearance (the rest shape stays an
            # equilibrium); everywhere else at the teeth surface
            overlap = np.minimum(0.0, rest)   # per node, mm: <= 0, where the rest envelope is inside
            self._teeth = (nodes, teeth, node_areas(m.X, tris)[nodes], overlap - 0.05 * (rest < 0), overlap)
        return self._teeth

    def teeth_term(self, controls: Controls, force: bool = False, transforms=None):
        """The lips-against-teeth :class:`~facesim.contact.ContactTerm` posed for ``controls`` (None
        without teeth contact, unless ``force``: then also for measuring); ``transforms = (Hc, Hj)``
        overrides the controls' bones (the intermediate poses of a substep)."""
        if not (self.options.teeth_contact or force):
            return None
        nodes, teeth, weights, margin, _ = self._teeth_setup()
        Hc, Hj = transforms if transforms is not None else self.bone_transforms(controls)
        from facesim.contact.sdf import Collider

        colliders = [Collider(sdf, Hc if bone == "cranium" else Hj) for sdf, bone in teeth]
        return ContactTerm(nodes, colliders, stiffness=self.options.contact_stiffness, margin=margin,
                           weights=weights)

    def lip_term(self):
        """The upper-lip-against-lower-lip :class:`~facesim.contact.SurfaceContactTerm`."""
        if self._lips is None:
            if not has_lips(self.model):
                raise FacesimError("lip contact: the model has no upper and lower lip surfaces")
            from facesim.contact.self_contact import lip_contact_term

            self._lips = lip_contact_term(self.model, stiffness=self.options.contact_stiffness)
        return self._lips

    def posed_colliders(self, controls: Controls, frame: float = 0.0, transforms=None) -> list:
        """The external colliders posed at ``frame`` with the bones of ``controls`` (or ``transforms``)."""
        if not self.options.colliders:
            return []
        Hc, Hj = transforms if transforms is not None else self.bone_transforms(controls)
        return [c.at(frame, Hc, Hj) for c in self.options.colliders]

    def skin_term(self, colliders) -> ContactTerm | None:
        """The skin-against-``colliders`` term (None without colliders)."""
        if not colliders:
            return None
        if self._skin is None:
            m = self.model
            nodes = np.unique(m.skin)
            self._skin = ContactTerm(nodes, [], stiffness=self.options.contact_stiffness,
                                     weights=node_areas(m.X, m.skin)[nodes])
        return self._skin.with_colliders(colliders)

    def contact_terms(self, controls: Controls, frame: float = 0.0, transforms=None) -> tuple:
        """The contact energy terms of the set-up posed for ``controls`` at ``frame`` (teeth with
        their bones, lips, skin against the external colliders); ``transforms = (Hc, Hj)``
        overrides the controls' bones."""
        terms = [self.teeth_term(controls, transforms=transforms)]
        if self.options.lip_contact:
            terms.append(self.lip_term())
        terms.append(self.skin_term(self.posed_colliders(controls, frame, transforms)))
        return tuple(t for t in terms if t is not None)

    def contact_measures(self, x, controls: Controls, frame: float = 0.0) -> dict:
        """Deepest penetrations at ``x (n, 3)``, mm (0 when none; NaN where the model lacks the
        surfaces), whether or not the contact is on: ``penetration_mm`` (skin inside an external
        collider), ``lip_penetration_mm`` (a lip node behind the other lip; the mouth corners,
        where the lips meet, excluded), ``teeth_penetration_mm`` (a lip node inside the teeth,
        beyond where it already was at rest)."""
        out = {"penetration_mm": 0.0, "lip_penetration_mm": float("nan"), "teeth_penetration_mm": float("nan")}
        if not np.isfinite(x).all():
            return {k: float("nan") for k in out}
        skin = self.skin_term(self.posed_colliders(controls, frame))
        if skin is not None:
            out["penetration_mm"] = float(skin.penetration(x).max(initial=0.0))
        if has_lips(self.model):
            lips = self.lip_term()
            d = lips.signed_distances(x)[lips.weights > 0]
            out["lip_penetration_mm"] = float(max(0.0, -d.min(initial=np.inf)))
        if has_teeth(self.model):
            # depth beyond each lip node's own rest overlap: the rest mesh's lip envelope can dip
            # into the teeth surface by a fraction of a mm (the penalty's zero sits below it too)
            depth = self._teeth_setup()[4] - self.teeth_term(controls, force=True).signed_distances(x)
            out["teeth_penetration_mm"] = float(max(0.0, depth.max(initial=0.0)))
        return out

    def with_gain(self, gain) -> "FaceSimulator":
        """A simulator sharing this one's precomputation, with another exaggeration gain."""
        other = object.__new__(FaceSimulator)
        other.__dict__.update(self.__dict__)
        other.muscle = self.muscle.with_gain(gain)
        other.linear = make_linear_solver(self.options.newton.linear_solver)
        return other

    def _check(self, controls: Controls) -> Controls:
        if not isinstance(controls, Controls):
            controls = Controls(controls)
        if controls.a.shape != (self.model.n_muscles,):
            raise FacesimError(f"controls.a: expected {self.model.n_muscles} activations, got {controls.a.shape[0]}")
        return controls

    def bone_transforms(self, controls: Controls) -> tuple[np.ndarray, np.ndarray]:
        """World 4x4 transforms of the cranium and the mandible."""
        H = np.eye(4) if controls.head is None else controls.head
        return H, H @ self.jaw_model.transform(controls.jaw)

    def attached_positions(self, controls: Controls, x=None, transforms=None) -> np.ndarray:
        """``(n, 3)``: ``x`` (default: the rest shape moved with the skull) with cranium and jaw
        nodes placed by their bones (``transforms = (Hc, Hj)`` overrides the controls' bones)."""
        m = self.model
        Hc, Hj = transforms if transforms is not None else self.bone_transforms(controls)
        out = (m.X @ Hc[:3, :3].T + Hc[:3, 3]) if x is None else np.array(x, dtype=np.float64)
        out[m.cranium_nodes] = m.X[m.cranium_nodes] @ Hc[:3, :3].T + Hc[:3, 3]
        out[m.jaw_nodes] = m.X[m.jaw_nodes] @ Hj[:3, :3].T + Hj[:3, 3]
        return out

    def problem(self, controls: Controls, x=None, extra_terms=()) -> Problem:
        controls = self._check(controls)
        return Problem(self.terms + tuple(extra_terms), self.system, self.attached_positions(controls, x), controls.a)

    def _min_singular_value(self, x) -> float:
        """Smallest singular value of F over the simulated tets at ``x (n, 3)`` (negative if inverted)."""
        from facesim._kernels.elements import min_signed_singular_value

        return float(min_signed_singular_value(np.ascontiguousarray(x, dtype=np.float64), self.rest.tets,
                                               self.rest.Bm, self.elems))

    def _newton(self, prob: Problem, options: NewtonOptions, scale: float, clamp_scale=None, linear=None):
        """Newton on ``prob``, first at :data:`PATH_CLAMP` when the options' clamp is smaller
        (kept if no tet ends below it: the energies agree there), else again at the options' clamp
        from the same start (an imported face's wide opening: the first solve inverts tets)."""
        linear = linear or self.linear
        if self._path_elastic is None:
            return newton(prob, options, scale, linear)
        x, rep = newton(self._at_path_clamp(prob), options, scale, linear)
        if rep.converged and self._min_singular_value(x) >= PATH_CLAMP:
            return x, rep
        # the crushed tets that made the path invert also set this solve's force scale (the
        # tolerances all of benchmarks/RESULTS.md session 20 was measured with)
        x, rep2 = newton(prob, options, max(scale, clamp_scale()) if clamp_scale else scale, linear)
        rep2.iterations += rep.iterations
        rep2.residuals = list(rep.residuals) + list(rep2.residuals)
        rep2.linear_iterations = list(rep.linear_iterations) + list(rep2.linear_iterations)
        return x, rep2

    def force_scale(self, controls: Controls, extra_terms=(), start=None, path: bool = True) -> float:
        """The reference force "relative" refers to (N): the residual of the cold start (rest shape,
        bones placed), or of ``start (n, 3)`` (this solve's starting guess, bones placed) when that
        is larger. The cold start alone vanishes when it is the equilibrium -- the rest controls
        with no contact engaged, e.g. the jaw back at rest after an opening: the tolerance was then
        ``atol`` = 1e-10 N on forces of ~40 N out of balance at the warm start, which no solve
        reaches (frame 14 of examples/02_jaw_and_contact.py: relative residual 3e12 at 0.4 N)."""
        # measured with the flesh at PATH_CLAMP: a cold start crushes tets next to a bone that moved
        # far, and at the smaller clamp their forces (not the load) would set every tolerance
        # (path=False: at the options' clamp, the scale of the solve that follows a rejected path)
        at = self._at_path_clamp if path else (lambda p: p)
        controls = self._check(controls)
        cold = self.attached_positions(controls)
        Hc = self.bone_transforms(controls)[0]
        if np.abs(Hc[:3, :3].T @ Hc[:3, :3] - np.eye(3)).max() <= 1e-12:
            # the cold start moves only the jaw's tets: the rest of the flesh is the rest shape moved
            # rigidly, free of stress, so its gradient is left out (7-10 ms of the coarse face's
            # 24 ms force scale, a fixed cost of every trial equilibrium; benchmarks/RESULTS.md session 33)
            flesh = self._cold_flesh(path)
            terms = tuple(flesh if t is self.elastic else t for t in self.terms) + tuple(extra_terms)
            prob = Problem(terms, self.system, cold, controls.a)
        else:   # a head transform a little off rigid (controls accept |R^T R - I| <= 1e-4) strains every tet
            prob = at(Problem(self.terms + tuple(extra_terms), self.system, cold, controls.a))
        scale = float(np.linalg.norm(prob.energy_and_gradient(prob.x_fixed)[1]))
        if start is not None:
            prob = at(self.problem(controls, start, extra_terms))
            scale = max(scale, float(np.linalg.norm(prob.energy_and_gradient(prob.x_fixed)[1])))
        return scale

    def _cold_flesh(self, path: bool):
        """The flesh term restricted to the tets with a jaw node, at :data:`PATH_CLAMP` (``path``,
        where that is larger than the options' clamp) or the options' clamp: all the flesh that a
        cold start (:meth:`attached_positions` without ``x``) deforms."""
        key = bool(path and self._path_elastic is not None)
        if key not in self._cold:
            e = self._path_elastic if key else self.elastic
            self._cold[key] = e.restricted(e.touching(self.model.jaw_nodes))
        return self._cold[key]

    def _at_path_clamp(self, prob: Problem) -> Problem:
        """``prob`` with the flesh term at :data:`PATH_CLAMP` (itself when the clamp is not smaller)."""
        if self._path_elastic is None:
            return prob
        return Problem(tuple(self._path_elastic if t is self.elastic else t for t in prob.terms), prob.system,
                       prob.x_fixed, prob.a)

    def solve_terms(self, controls: Controls, frame: float = 0.0, extra_terms=(), transforms=None) -> tuple:
        """The energy terms besides flesh and muscles of a solve at ``controls`` and ``frame``: the
        set-up's contact terms posed there (with the bones of ``transforms`` when given), then
        ``extra_terms``."""
        return self.contact_terms(controls, frame, transforms) + tuple(extra_terms)

    def equilibrium(self, controls: Controls, x0=None, newton_options: NewtonOptions | None = None,
                    extra_terms=(), frame: float = 0.0, linear=None) -> Equilibrium:
        """Equilibrium positions for ``controls``, warm-started from ``x0 (n, 3)`` if given, with the
        set-up's contact posed at ``frame`` (scripted colliders) plus ``extra_terms``. ``linear``:
        the Newton steps' linear solver (default: the simulator's own, ``newton_options.linear_solver``),
        e.g. a :class:`~facesim.fem.linear.FactorPCG` on a nearby factorised tangent.

        A solve that does not converge is returned with ``converged`` False (not raised), also one
        out of time (``newton_options.max_seconds`` or the enclosing :func:`facesim.budget.time_budget`:
        ``stop_reason`` ``"time_limit"``); a linear solver failing inside it raises :class:`~facesim.errors.SolverError`."""
        controls = self._check(controls)
        t0 = time.perf_counter()
        if x0 is not None:
            x0 = np.asarray(x0, dtype=np.float64)
            if x0.shape != self.model.X.shape:
                raise FacesimError(f"x0: expected positions of shape {self.model.X.shape}, got {x0.shape}")
            if not np.isfinite(x0).all():
                raise SolverError("equilibrium: the warm start has non-finite positions")
        options = newton_options or self.options.newton
        user_terms = tuple(extra_terms)
        with time_budget(options.max_seconds):
            extra_terms = self.solve_terms(controls, frame, user_terms)
            start = self.predict(controls, x0)
            scale = self.force_scale(controls, extra_terms, start)
            prob = self.problem(controls, start, extra_terms)
            x, rep = self._newton(prob, options, scale,
                                  lambda: self.force_scale(controls, extra_terms, start, path=False), linear)
            if not rep.converged and self.options.substeps > 1 and rep.stop_reason != TIME_LIMIT:
                x, rep = self._substepped(controls, x0, options, scale, rep, user_terms, frame, linear)
        if not np.isfinite(x).all():
            rep.converged, rep.stop_reason = False, "non_finite"
        rep.seconds["total"] = time.perf_counter() - t0
        return Equilibrium(x=x, controls=controls, report=rep)

    def _substepped(self, controls, x0, options, scale, failed, extra_terms=(), frame: float = 0.0, linear=None):
        """Retry a failed solve as a path of equilibria from the start state to ``controls``; the
        bone-carried contact (teeth, colliders on a bone) is posed with each substep's bones."""
        m = self.model
        start = self.attached_positions(Controls(controls.a, None, controls.head)) if x0 is None else x0
        # the start's bone poses, fitted to its attached nodes (exact for rigid bones)
        H0 = (rigid_fit(m.X[m.cranium_nodes], start[m.cranium_nodes]), rigid_fit(m.X[m.jaw_nodes], start[m.jaw_nodes]))
        H1 = self.bone_transforms(controls)
        a0 = np.zeros_like(controls.a) if x0 is None else controls.a
        x = start
        iterations, residuals = failed.iterations, list(failed.residuals)
        k = self.options.substeps
        for i in range(1, k + 1):
            s = i / k
            Hs = tuple(interpolate_rigid(A, B, s, m.X[nodes].mean(axis=0) if len(nodes) else (0, 0, 0))
                       for A, B, nodes in zip(H0, H1, (m.cranium_nodes, m.jaw_nodes)))
            a = (1 - s) * a0 + s * controls.a
            terms = self.solve_terms(controls, frame, extra_terms, Hs)
            prob = Problem(self.terms + terms, self.system,
                           self.attached_positions(controls, self.predict(controls, x, Hs), Hs), a)
            x, rep = self._newton(prob, options, scale, linear=linear)
            iterations += rep.iterations
            residuals += rep.residuals
            if rep.stop_reason == TIME_LIMIT:
                break
        rep.iterations, rep.residuals = iterations, residuals
        rep.seconds["substeps"] = k
        return x, rep

    def element_quality(self, x) -> tuple[int, float]:
        """``(inverted, min_J)`` over the simulated tets at ``x (n, 3)``: how many have det F <= 0,
        and the smallest det F (volume ratio; NaN for non-finite positions)."""
        from facesim._kernels.elements import volume_ratio_range

        if not np.isfinite(x).all():
            return -1, float("nan")
        inverted, low = volume_ratio_range(np.ascontiguousarray(x, dtype=np.float64), self.rest.tets, self.rest.Bm,
                                           self.elems)
        return int(inverted), float(low)

    def internal_force(self, x, a) -> np.ndarray:
        """Total internal force ``-dE/dx (n, 3)`` (N) of flesh and muscles."""
        return -(self.elastic.gradient(x) + self.muscle.gradient(x, a))

    def force_columns(self, x):
        """``(3n, n_muscles)`` per-muscle active force columns at ``x`` (see :meth:`MuscleTerm.force_columns`)."""
        return self.muscle.force_columns(x)


def equilibrium(model: FaceModel, controls: Controls, x0=None, options: EquilibriumOptions | None = None,
                jaw_model=None, frame: float = 0.0) -> Equilibrium:
    """One-shot equilibrium (builds a :class:`FaceSimulator`; keep one for sequences)."""
    return FaceSimulator(model, options, jaw_model).equilibrium(controls, x0, frame=frame)


__all__ = ["EquilibriumOptions", "Equilibrium", "FaceSimulator", "equilibrium", "has_lips", "has_teeth"]
