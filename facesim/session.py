"""Frame-by-frame scripting of a face: :class:`Simulation`.

A simulation keeps one :class:`~facesim.fem.equilibrium.FaceSimulator` (mesh precomputation,
linear-solver hierarchy, the jaw model and the contact set-up) and the last converged state, so a
script can drive the face one frame at a time::

    from facesim import Simulation, load_model
    from facesim.contact import Sphere

    model = load_model("meshes/face_coarse.npz")
    sim = Simulation(model, jaw_model="sliding-condyle", teeth_contact=True, lip_contact=True,
                     colliders=[KinematicPath.from_centres(Sphere((0, 0, 0), 12), [0, 10], centres)])
    for k in range(20):
        f = sim.step({"zygomaticus_major": k / 19}, jaw=sim.jaw_model.natural_parameters(0.02 * k))
        print(k, f.converged, f.iterations, f.penetration)

Each step is a quasistatic equilibrium warm-started from the last converged frame (a frame that
did not converge is returned flagged and never becomes a warm start). Contact is the simulator's
(:class:`~facesim.fem.equilibrium.EquilibriumOptions`): ``colliders`` (world, scripted or
bone-carried, see :mod:`facesim.contact.scene`) push the skin surface nodes out (area-weighted
penalty); ``teeth_contact`` keeps the lips out of the teeth; ``lip_contact`` keeps the upper and
lower lips out of each other. The same set-up serves ``facesim simulate`` and the inverse solver.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from facesim.constants import CONTACT_STIFFNESS
from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions, SolveReport
from facesim.model import FaceModel


def activation_vector(model: FaceModel, values) -> np.ndarray:
    """``(n_muscles,)`` activations from an array, or a dict ``{name: value}`` where a name is a
    muscle of the model (``zygomaticus_major_L``) or a base name for both sides
    (``zygomaticus_major``); unnamed muscles are 0. Values in [0, 1]."""
    names = model.muscles.names
    if values is None:
        return np.zeros(len(names))
    if isinstance(values, dict):
        a = np.zeros(len(names))
        for key, v in values.items():
            hits = [i for i, n in enumerate(names) if n == key or n.rsplit("_", 1)[0] == key]
            if not hits:
                import difflib

                close = difflib.get_close_matches(key, names, n=3, cutoff=0.5)
                raise FacesimError(f"activations: unknown muscle {key!r}" +
                                   (f"; closest: {', '.join(close)}" if close else ""))
            a[hits] = float(v)
    else:
        a = np.asarray(values, dtype=np.float64).ravel()
        if a.shape != (len(names),):
            raise FacesimError(f"activations: expected {len(names)} values, got {a.shape[0]}")
    if not np.isfinite(a).all() or a.min() < 0.0 or a.max() > 1.0:
        raise FacesimError("activations: expected finite values in [0, 1]")
    return a


@dataclass
class Frame:
    """One solved frame: positions ``x (n, 3)`` mm, the ``controls``, the posed external
    ``colliders``, the solver ``report``; ``measures``: deepest penetrations, mm
    (``penetration_mm`` skin in an external collider, ``lip_penetration_mm``,
    ``teeth_penetration_mm``, see :meth:`FaceSimulator.contact_measures`); ``inverted`` tets
    (det F <= 0) and the smallest det F ``min_J``; ``error`` why a solve failed ("" otherwise)."""

    index: float
    x: np.ndarray
    controls: Controls
    converged: bool
    report: SolveReport | None
    colliders: list = field(default_factory=list)
    measures: dict = field(default_factory=dict)
    inverted: int = 0
    min_J: float = 1.0
    error: str = ""
    _model: FaceModel | None = field(default=None, repr=False)

    @property
    def penetration(self) -> float:
        """Deepest skin node inside any external collider, mm (0 without colliders)."""
        return float(self.measures.get("penetration_mm", 0.0))

    @property
    def iterations(self) -> int:
        return 0 if self.report is None else self.report.iterations

    @property
    def seconds(self) -> float:
        return 0.0 if self.report is None else float(self.report.seconds.get("total", 0.0))

    @property
    def markers(self) -> np.ndarray:
        """``(r, 3)`` marker positions, mm."""
        return self._model.marker_positions(self.x)


class Simulation:
    """A face driven frame by frame (see the module doc).

    Parameters
    ----------
    model : FaceModel.
    jaw_model : a :class:`~facesim.kinematics.jaw_models.JawModel` or its name (``"rigid"``,
        ``"sliding-condyle"``, ``"posselt"``, ``"posselt:RIG.npz"``, ...).
    colliders : external colliders: :class:`~facesim.contact.Collider`, bare shapes, a
        :class:`~facesim.contact.KinematicPath` or :class:`~facesim.contact.scene.SceneCollider`.
    teeth_contact, lip_contact : keep the lips out of the teeth / out of each other.
    contact_stiffness : penalty stiffness, N/mm^3 (contact pressure per mm of penetration).
    newton : :class:`NewtonOptions`; gain : per-muscle exaggeration of the active force.
    options : an :class:`EquilibriumOptions` instead of the contact and Newton arguments.
    """

    def __init__(self, model: FaceModel, jaw_model="rigid", colliders=(), teeth_contact: bool = False,
                 lip_contact: bool = False, contact_stiffness: float = CONTACT_STIFFNESS,
                 newton: NewtonOptions | None = None, gain=None, options: EquilibriumOptions | None = None):
        self.model = model
        if options is None:
            options = EquilibriumOptions(newton=newton or NewtonOptions(), teeth_contact=bool(teeth_contact),
                                         lip_contact=bool(lip_contact), colliders=tuple(colliders),
                                         contact_stiffness=float(contact_stiffness))
        self.simulator = FaceSimulator(model, options, jaw_model=jaw_model, gain=gain)
        self.jaw_model = self.simulator.jaw_model
        self.frames_done = 0
        self.last: Frame | None = None   # the last converged frame (the next warm start)

    @property
    def options(self) -> EquilibriumOptions:
        return self.simulator.options

    @property
    def colliders(self) -> tuple:
        return self.simulator.options.colliders

    def reset(self) -> None:
        """Forget the warm start: the next step starts from the rest shape."""
        self.last = None
        self.frames_done = 0

    def controls(self, a=None, jaw=None, head=None) -> Controls:
        return Controls(activation_vector(self.model, a), jaw=jaw, head=head)

    def posed_colliders(self, frame: float, controls: Controls) -> list:
        """The external colliders posed at ``frame`` with the bones of ``controls``."""
        return self.simulator.posed_colliders(controls, frame)

    def step(self, a=None, jaw=None, head=None, frame: float | None = None, x0=None) -> Frame:
        """Solve one frame: activations ``a`` (array or ``{muscle: value}``), jaw controls of the jaw
        model, optional head transform, ``frame`` number for scripted colliders (default: the count
        of steps so far) and an optional warm start ``x0 (n, 3)`` (default: the last converged frame).

        A numerical failure (:class:`~facesim.errors.SolverError`) makes a non-converged frame; a
        user mistake (:class:`~facesim.errors.FacesimError`) is raised."""
        controls = a if isinstance(a, Controls) else self.controls(a, jaw, head)
        k = float(self.frames_done if frame is None else frame)
        sim = self.simulator
        warm = x0 if x0 is not None else (None if self.last is None else self.last.x)
        t0 = time.perf_counter()
        try:
            eq = sim.equilibrium(controls, x0=warm, frame=k)
            x, report, converged = eq.x, eq.report, eq.converged
            error = "" if np.isfinite(x).all() else "non-finite positions"
        except SolverError as exc:   # a numerical failure of this frame (e.g. the linear solver)
            x = sim.attached_positions(controls, warm)
            report, converged, error = None, False, " ".join(str(exc).split())
        if report is not None:
            report.seconds.setdefault("total", time.perf_counter() - t0)
        inverted, min_J = sim.element_quality(x)
        out = Frame(k, x, controls, converged, report, sim.posed_colliders(controls, k),
                    sim.contact_measures(x, controls, k), inverted, min_J, error, self.model)
        self.frames_done += 1
        if converged:
            self.last = out
        return out


__all__ = ["Simulation", "Frame", "activation_vector"]
