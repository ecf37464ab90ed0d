"""Coarse-to-fine cold frames: fit a frame that has no previous frame to start from on a coarser
model of the same face first, then carry the fit to the full model and finish it there.

A cold frame of a large face costs several factorisations of its tangent: a Jacobian for each
Gauss-Newton step from the neutral face and trial equilibria whose Newton solves start far from
the answer (the paper-size face: 179-215 s, benchmarks/RESULTS.md sessions 25-26). On a coarser
model of the same face the same fit costs a few seconds and lands close: :class:`CoarseStart` then

1. prolongs the coarse equilibrium to the fine nodes (barycentric interpolation of the coarse
   displacement in the coarse rest mesh; exact when the fine mesh refines the coarse one),
2. factorises the fine tangent there once and solves the fine equilibrium of the coarse controls
   by Newton with CG preconditioned by that factor (:class:`~facesim.fem.linear.FactorPCG`),
3. takes the fine Jacobian's columns with the same factor (first-order accurate: ``age`` 1, so the
   fit evaluates an exact one where its linear model fails; flagged ``nearby``, so its kept steps
   are not lengthened), and
4. hands controls, equilibrium and Jacobian to :func:`~facesim.inverse.gauss_newton.fit_frame` as a
   tracked frame's start: the fit then usually needs one step.

The paper-size face with the medium face as its coarse model: the cold frame 179 -> 68 s, the same
marker RMS, the tracked frames after it 14 s a frame (benchmarks/RESULTS.md session 26). Worth it
where a factorisation costs many seconds; on the medium face it gained or lost a third.

The coarse model must be of the same face: the same muscles (by name), the jaw joint within
``JAW_TOL_MM`` and its mesh covering the fine one's nodes. It is adapted to the fine model: the
fine markers are bound to its skin at their rest positions (so the two need not share a marker
layout: a capture's own layout bound to the fine model carries over), and it takes the fine
model's tissue table and muscle strengths (matched by name), the simulator's options, jaw model
and muscle gains.
"""

from __future__ import annotations

import dataclasses
import time
import weakref

import numpy as np

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.inverse.gauss_newton import Fit, FitOptions, FitReport, fit_frame
from facesim.inverse.jacobian import ControlSpace, equilibrium_jacobian, factorised_tangent
from facesim.model import FaceModel

#: fine nodes up to this far outside the coarse mesh take the values of its nearest tet's closest point
COARSE_SNAP_MM = 2.0
#: the fraction of the fine model's nodes that may lie farther than ``COARSE_SNAP_MM`` outside the
#: coarse mesh (they take their nearest coarse node's displacement) before the models are refused
COARSE_OUTSIDE_FRACTION = 0.01
#: the jaw joints (condyles, incisor) of the two models may differ by this much, mm
JAW_TOL_MM = 1.0
#: relative force residual the coarse model's equilibria and the refinement's fine equilibrium are
#: solved to (the simulator's Newton tolerance if that is looser): the fine fit's first step starts
#: there and its trial equilibrium is solved to the full tolerance; a fit that keeps no step is
#: finished to it (:meth:`CoarseStart.fit_frame`). The paper-size face: one Newton step of four
#: fewer in the refinement, 4-5 s, the same fit (benchmarks/RESULTS.md, session 32)
START_RTOL = 1e-4


def _at_start_rtol(newton):
    """The Newton options ``newton`` with their tolerance loosened to :data:`START_RTOL`."""
    return dataclasses.replace(newton, rtol=max(newton.rtol, START_RTOL))


def _joint_points(model: FaceModel) -> dict[str, np.ndarray]:
    j = model.jaw
    return {"condyle_right": np.asarray(j.condyle_right, float), "condyle_left": np.asarray(j.condyle_left, float),
            "incisor": np.asarray(j.incisor, float)}


class CoarseStart:
    """The coarse model ``coarse`` (a :class:`~facesim.model.FaceModel`) adapted to the simulator
    ``sim`` of the full model (see the module doc); ``name`` names it in errors (e.g. the file).
    Raises :class:`~facesim.errors.FacesimError` when the two are not models of the same face.

    ``sim``: the coarse :class:`~facesim.fem.equilibrium.FaceSimulator`; ``order[k]``: the coarse
    muscle of fine muscle ``k``."""

    def __init__(self, sim, coarse: FaceModel, name: str = "coarse model", of: str = "the model"):
        from facesim.fem.equilibrium import FaceSimulator
        from facesim.fem.meshes import TetLocator
        from facesim.mocap.layout import bind_layout

        fine = sim.model
        self.fine_sim = sim
        self.name = name
        self.nested: CoarseStart | None = None   # a coarser level still, where this level's fit starts
        if coarse.n_simulated >= fine.n_simulated:
            raise FacesimError(f"{name}: not coarser than {of} ({coarse.n_simulated:,} simulated tets against "
                               f"{fine.n_simulated:,}); name a coarser model of the same face (e.g. the one it was "
                               "refined from with 'model build --refine')")
        fnames, cnames = list(fine.muscles.names), list(coarse.muscles.names)
        missing = [n for n in fnames if n not in cnames]
        extra = [n for n in cnames if n not in fnames]
        if missing or extra:
            what = "; ".join(s for s in (f"missing {', '.join(missing[:5])}" if missing else "",
                                         f"not in the model: {', '.join(extra[:5])}" if extra else "") if s)
            raise FacesimError(f"{name}: its muscles are not the model's ({what}); a coarse start needs a model "
                               "of the same face")
        order = np.array([cnames.index(n) for n in fnames], dtype=np.int64)
        fp, cp = _joint_points(fine), _joint_points(coarse)
        for key in fp:
            d = float(np.linalg.norm(fp[key] - cp[key]))
            if not d <= JAW_TOL_MM:
                raise FacesimError(f"{name}: its jaw {key.replace('_', ' ')} is {d:.2f} mm from the model's "
                                   f"(at most {JAW_TOL_MM:g} mm): not a model of the same face")
        locator = TetLocator(coarse.X, coarse.tets, COARSE_SNAP_MM)
        tet, bary = locator.locate(fine.X)
        outside = np.flatnonzero(tet < 0)
        if len(outside) > COARSE_OUTSIDE_FRACTION * fine.n_nodes:
            raise FacesimError(f"{name}: {len(outside):,} of the model's {fine.n_nodes:,} nodes lie more than "
                               f"{COARSE_SNAP_MM:g} mm outside its mesh: not a model of the same face (or not in "
                               "the same units and frame)")
        if len(outside):   # a few beyond the snap: their nearest coarse node's displacement
            from scipy.spatial import cKDTree

            near = cKDTree(coarse.X).query(fine.X[outside])[1]
            tet[outside] = 0
            bary[outside] = 0.0
        self._tets = coarse.tets[np.maximum(tet, 0)]
        self._bary = bary
        self._outside, self._near = outside, (near if len(outside) else np.zeros(0, np.int64))
        tissues = {t.name: t for t in fine.tissues}
        absent = [t.name for t in coarse.tissues if t.name not in tissues]
        if absent:
            raise FacesimError(f"{name}: its tissues {', '.join(absent)} are not in the model's tissue table "
                               f"({', '.join(tissues)})")
        sigma = np.array(coarse.muscles.sigma_max, dtype=np.float64)
        sigma[order] = fine.muscles.sigma_max
        P = fine.marker_positions(fine.X)
        heads = [n for n, h in zip(fine.markers.names, fine.markers.head) if h]
        try:
            markers, _, rejected = bind_layout(coarse, fine.markers.names, P, head_names=heads)
        except FacesimError as exc:
            raise FacesimError(f"{name}: the model's markers cannot be placed on its skin ({exc})") from None
        if rejected:
            raise FacesimError(f"{name}: the model's markers cannot all be placed on its skin ("
                               + "; ".join(f"{k}: {v}" for k, v in list(rejected.items())[:3]) + ")")
        model = coarse.with_(markers=markers, tissues=tuple(tissues[t.name] for t in coarse.tissues),
                             muscles=dataclasses.replace(coarse.muscles, sigma_max=sigma))
        gain = np.ones(model.n_muscles)
        gain[order] = sim.muscle.gain
        # its equilibria to START_RTOL: its fit only seeds the full model's (the medium face's cold
        # fit 5.7-6.8 s against 7.6-8.3 s, the controls within 1.2e-4, benchmarks/RESULTS.md session 32)
        options = dataclasses.replace(sim.options, newton=_at_start_rtol(sim.options.newton))
        self.sim = FaceSimulator(model, options=options, jaw_model=sim.jaw_model, gain=gain)
        self.order = order

    @classmethod
    def chain(cls, sim, models, names=None) -> "CoarseStart":
        """Coarse starts through several coarser ``models`` of the same face (any order; named by
        ``names`` in errors): the finest of them starts ``sim``'s cold frames, the next finest
        starts its own, and so on (:attr:`nested`), each level adapted to the one above it. One
        model: as the constructor. Two models of the same size are refused (the coarser one must
        be coarser)."""
        models = list(models)
        names = list(names) if names is not None else [f"coarse model {k + 1}" for k in range(len(models))]
        if not models:
            raise FacesimError("coarse start: no coarse model given")
        order = sorted(range(len(models)), key=lambda k: -models[k].n_simulated)
        top = level = cls(sim, models[order[0]], names[order[0]])
        for k in order[1:]:
            level.nested = cls(level.sim, models[k], names[k], of=level.name)
            level = level.nested
        return top

    @property
    def levels(self) -> list["CoarseStart"]:
        """This start and its nested ones, finest first."""
        out, level = [], self
        while level is not None:
            out.append(level)
            level = level.nested
        return out

    def coarse_fit(self, targets, controls: Controls, space: ControlSpace, options: FitOptions, **kwargs) -> Fit:
        """The cold fit of ``targets`` on the coarse model, from the fine model's ``controls`` in the
        fine ``space`` (``kwargs``: ``fit_frame``'s ``weights``, ``frame``, ``head_frame``,
        ``jaw_prior``): itself coarse-to-fine where there is a :attr:`nested` level."""
        if self.nested is not None:
            return self.nested.fit_frame(targets, self.down(controls), self.space(space), options, **kwargs)
        return fit_frame(self.sim, targets, self.down(controls), None, self.space(space), options, **kwargs)

    # ------------------------------------------------------------------ transfers
    def down(self, controls: Controls) -> Controls:
        """The fine model's ``controls`` on the coarse model (its muscles ordered its own way)."""
        a = np.zeros(self.sim.model.n_muscles)
        a[self.order] = controls.a
        return Controls(a, controls.jaw, controls.head)

    def up(self, controls: Controls) -> Controls:
        """The coarse model's ``controls`` on the fine model."""
        return Controls(np.asarray(controls.a, dtype=np.float64)[self.order], controls.jaw, controls.head)

    def space(self, space: ControlSpace) -> ControlSpace:
        """The fine control ``space`` on the coarse model: the same unknowns in the same order."""
        return dataclasses.replace(space, n_muscles=self.sim.model.n_muscles,
                                   muscles=tuple(int(self.order[m]) for m in space.muscles))

    def prolong(self, x) -> np.ndarray:
        """Fine node positions ``(n, 3)`` from the coarse ones ``x``: the coarse displacement at each
        fine rest node (barycentric in the coarse rest mesh)."""
        coarse = self.sim.model
        u = np.asarray(x, dtype=np.float64) - coarse.X
        v = np.einsum("ij,ijk->ik", self._bary, u[self._tets])
        if len(self._outside):
            v[self._outside] = u[self._near]
        return self.fine_sim.model.X + v

    # ------------------------------------------------------------------ the fine start
    def refine(self, controls: Controls, x, space: ControlSpace, options: FitOptions | None = None, extra_terms=(),
               frame: float = 0.0) -> tuple[Controls, np.ndarray | None, object, FitReport]:
        """From the coarse fit's ``controls`` and equilibrium ``x``: the fine controls, the fine
        equilibrium (None when Newton fails from the prolonged start: the caller then solves its
        own) and its Jacobian in ``space`` (None without a factorising solver), with a
        :class:`FitReport` of the work (one equilibrium, one Jacobian, no steps)."""
        from types import SimpleNamespace

        from facesim.errors import SolverError
        from facesim.fem.linear import FactorPCG

        t0 = time.perf_counter()
        sim = self.fine_sim
        options = options or FitOptions()
        ctrl = self.up(controls)
        x0 = self.prolong(x)
        rep = FitReport(stop_reason="converged")
        # one factor, the owner's alone (FactorPCG may free it for a nearer one): the Newton's
        # preconditioner, then the Jacobian's
        t = time.perf_counter()
        xp = sim.predict(ctrl, x0)
        owner = SimpleNamespace(tangent=factorised_tangent(sim, ctrl, xp, frame, extra_terms, options.linear_solver),
                                tangent_at=(ctrl, xp, frame))
        rep.timing["jacobian"] += time.perf_counter() - t
        t = time.perf_counter()
        lin = FactorPCG(owner=owner) if owner.tangent is not None else None
        try:
            eq = sim.equilibrium(ctrl, x0=x0, extra_terms=extra_terms, frame=frame, linear=lin,
                                 newton_options=_at_start_rtol(sim.options.newton))
        except SolverError as exc:
            eq, rep.error = None, " ".join(str(exc).split())
        rep.timing["equilibria"] += time.perf_counter() - t
        rep.equilibria = 1
        if eq is None or not eq.converged:
            rep.stop_reason = "equilibrium_failed"
            rep.error = rep.error or "no converged equilibrium from the prolonged coarse fit"
            rep.seconds = time.perf_counter() - t0
            return ctrl, None, None, rep
        rep.newton_iterations = eq.iterations
        rep.linear_solves = len(eq.report.linear_iterations)
        J = None
        tangent, at = owner.tangent, owner.tangent_at
        if lin is not None and lin.factor is not None and lin.factor is not tangent:
            tangent = lin.factor   # the Newton's own, nearer factor (made below FactorPCG's amg_above)
        if tangent is not None and at is None:
            # made inside the Newton solve, at an iterate near its equilibrium: a resumed run
            # factorises again at the equilibrium (else it would go on without a factor at all)
            at = (ctrl, eq.x, frame)
        lin = owner.tangent = None
        if tangent is not None:
            # the columns with the Newton's factor, not a new one at the equilibrium: on the
            # paper-size face the fit then took one step (0.98 of its prediction) and stopped,
            # where an exact Jacobian's first step achieved 0.78 and the fit evaluated another:
            # 140 s against 74 s for the same marker RMS (benchmarks/RESULTS.md, session 26)
            t = time.perf_counter()
            J = equilibrium_jacobian(sim, ctrl, eq.x, space, extra_terms, options.linear_solver,
                                     options.jacobian_rtol, frame, tangent=tangent, tangent_at=at)
            rep.jacobians = 1
            rep.linear_solves += 1
            rep.timing["jacobian"] += time.perf_counter() - t
        rep.seconds = time.perf_counter() - t0
        return ctrl, eq.x, J, rep

    def start(self, cfit: Fit, controls: Controls, head_frame, space: ControlSpace, options: FitOptions,
              frame: float = 0.0) -> tuple[Controls, np.ndarray | None, object, np.ndarray | None, FitReport | None]:
        """The full model's start from the coarse fit ``cfit`` of a frame that was to start from
        ``controls`` and ``head_frame``: ``(controls, x, jacobian, head_frame, report)`` of
        :meth:`refine` where the coarse fit found an equilibrium within the time budget and the
        refinement converged; else the given ``controls`` and ``head_frame`` with ``x`` and
        ``jacobian`` None (the frame is fitted cold). ``report``: the refinement's, None where it
        was not tried."""
        from facesim.budget import expired

        if cfit.report.stop_reason == "equilibrium_failed" or not cfit.equilibrium or expired():
            return controls, None, None, head_frame, None
        ctrl, x, J, rep = self.refine(cfit.controls, cfit.x, space, options, frame=frame)
        if x is None:
            return controls, None, None, head_frame, rep
        return ctrl, x, J, (cfit.head_frame if cfit.head_frame is not None else head_frame), rep

    def fit_frame(self, targets, controls: Controls, space: ControlSpace | None = None,
                  options: FitOptions | None = None, weights=None, frame: float = 0.0, head_frame=None,
                  jaw_prior=None) -> Fit:
        """A cold frame coarse-to-fine: :func:`~facesim.inverse.gauss_newton.fit_frame` on the coarse
        model from ``controls`` (:meth:`coarse_fit`: itself coarse-to-fine with a nested level),
        :meth:`refine`, then ``fit_frame`` on the full model from there (the same arguments as
        ``fit_frame``'s, without ``x0``: the frame is cold). The result is
        the full model's fit; its report counts both levels' work (equilibria, Newton iterations,
        linear solves, Jacobians, seconds; ``gn_steps`` the full model's) and its ``timing["coarse"]``
        is the coarse fit's and the refinement's seconds. Where the coarse fit or the refinement
        fails, the frame is fitted cold on the full model from ``controls``."""
        from facesim.budget import time_budget

        options = options or FitOptions()
        space = space or ControlSpace.of(self.fine_sim)
        with time_budget(options.max_seconds):
            t0 = time.perf_counter()
            cfit = self.coarse_fit(targets, controls, space, options, weights=weights, frame=frame,
                                   head_frame=head_frame, jaw_prior=jaw_prior)
            start, x, J, head_frame, rep = self.start(cfit, controls, head_frame, space, options, frame)
            coarse_seconds = time.perf_counter() - t0
            fit = fit_frame(self.fine_sim, targets, start, x, space, options, weights=weights, jacobian=J,
                            frame=frame, head_frame=head_frame, jaw_prior=jaw_prior, finish_start=x is not None)
        merge(fit.report, [cfit.report] + ([rep] if rep is not None else []), coarse_seconds)
        return fit


def merge(report: FitReport, others, seconds: float) -> None:
    """Add the work of the reports ``others`` (a coarse fit's, a refinement's) to ``report`` and
    ``seconds`` to its time and its ``timing["coarse"]``."""
    for other in others:
        for key in ("equilibria", "newton_iterations", "linear_solves", "chord_iterations", "jacobians"):
            setattr(report, key, getattr(report, key) + getattr(other, key))
    report.seconds += seconds
    report.timing["coarse"] = report.timing.get("coarse", 0.0) + seconds


#: coarse starts made for a simulator, by the coarse model's path (tracking builds one per run)
_MADE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def coarse_paths(paths) -> tuple[str, ...]:
    """A coarse model path, or several, as a tuple of strings (None: none)."""
    if paths is None:
        return ()
    return (str(paths),) if isinstance(paths, (str, bytes)) or hasattr(paths, "__fspath__") else \
        tuple(str(p) for p in paths)


def coarse_start_for(sim, paths) -> CoarseStart:
    """The :class:`CoarseStart` of the coarse model file ``paths`` (one path, or several: a
    :meth:`CoarseStart.chain`) for ``sim``, made once per simulator."""
    from facesim.model import load_model

    made = _MADE.setdefault(sim, {})
    key = coarse_paths(paths)
    if key not in made:
        made[key] = CoarseStart.chain(sim, [load_model(p) for p in key], key)
    return made[key]


__all__ = ["CoarseStart", "coarse_paths", "coarse_start_for", "merge"]
