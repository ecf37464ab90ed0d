"""Frame-by-frame scripting of a face: :class:`Simulation`.

A simulation keeps one :class:`~facesim.fem.equilibrium.FaceSimulator` (mesh precomputation,
linear-solver hierarchy), the jaw model, the contact set-up and the last converged state, so a
script can drive the face one frame at a time::

    from facesim import Simulation, load_model
    from facesim.contact import Sphere

    model = load_model("meshes/face_coarse.npz")
    sim = Simulation(model, jaw_model="sliding-condyle", teeth_contact=True, lip_contact=True,
                     colliders=[KinematicPath.from_centres(Sphere((0, 0, 0), 12), [0, 10], centres)])
    for k in range(20):
        f = sim.step({"zygomaticus_major": k / 19}, jaw=sim.jaw_model.natural_parameters(0.02 * k))
        print(k, f.converged, f.iterations, f.penetration)

Each step is a quasistatic equilibrium warm-started from the last converged frame. Contact:
``colliders`` (world, scripted or bone-carried, see :mod:`facesim.contact.scene`) push the skin
surface nodes out (area-weighted penalty); ``teeth_contact`` keeps the lips out of the teeth;
``lip_contact`` keeps the upper and lower lips out of each other.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from facesim.contact.penalty import DEFAULT_STIFFNESS, ContactTerm, node_areas
from facesim.contact.scene import as_scene_collider
from facesim.controls import Controls, RigidJaw
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions, SolveReport
from facesim.model import FaceModel

JAW_MODELS = ("rigid", "sliding-condyle", "posselt")


def make_jaw_model(model: FaceModel, spec="rigid", model_path=None):
    """A jaw model from a name (``"rigid"``: controls.jaw is a 4x4 transform; ``"sliding-condyle"``:
    (opening rad, right slide mm, left slide mm); ``"posselt"``: the model's own Posselt rig, fitted
    to motion generated for its TMJ -- ``<model>_posselt.npz`` next to ``model_path`` when given,
    else the shipped rig recording the same TMJ, see :func:`~facesim.kinematics.rig_jaw.model_rig_jaw`),
    a fitted rig ``"posselt:RIG.npz"`` / ``"nlpca:RIG.npz"`` (:class:`~facesim.kinematics.rig_jaw.RigJaw`:
    the rig's parameters) or an object with ``transform(q) -> 4x4``."""
    if not isinstance(spec, str):
        if not callable(getattr(spec, "transform", None)):
            raise FacesimError(f"jaw model: expected a name ({', '.join(JAW_MODELS)}) or an object with "
                               f"transform(q), got {type(spec).__name__}")
        return spec
    if spec == "rigid":
        return RigidJaw()
    if spec == "sliding-condyle":
        from facesim.kinematics.condyle import SlidingCondyleJaw

        return SlidingCondyleJaw(model.jaw)
    if spec == "posselt":
        from facesim.kinematics.rig_jaw import model_rig_jaw

        return model_rig_jaw(model, model_path)
    if ":" in spec:
        from facesim.kinematics.rig_jaw import rig_jaw_from_spec

        return rig_jaw_from_spec(model, spec)
    raise FacesimError(f"jaw model: expected one of {', '.join(JAW_MODELS)}, posselt:RIG.npz or nlpca:RIG.npz, "
                       f"got {spec!r}")


def jaw_rest(jaw_model):
    """The jaw controls of the rest pose (None for the rigid jaw: identity)."""
    n = getattr(jaw_model, "n_params", None)
    if n is None:
        return None
    rest = getattr(jaw_model, "rest", None)
    return np.zeros(n) if rest is None else np.array(rest, dtype=np.float64)


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
    ``colliders``, the solver ``report`` and ``penetration`` (deepest skin node inside any
    external collider, mm; 0 without colliders)."""

    index: float
    x: np.ndarray
    controls: Controls
    converged: bool
    report: SolveReport | None
    colliders: list = field(default_factory=list)
    penetration: float = 0.0
    error: str = ""
    _model: FaceModel | None = field(default=None, repr=False)

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
    jaw_model : ``"rigid"``, ``"sliding-condyle"`` or a jaw-model object (``transform(q)``).
    colliders : external colliders: :class:`~facesim.contact.Collider`, bare shapes, a
        :class:`~facesim.contact.KinematicPath` or :class:`~facesim.contact.scene.SceneCollider`.
    teeth_contact, lip_contact : keep the lips out of the teeth / out of each other.
    contact_stiffness : penalty stiffness, N/mm^3 (contact pressure per mm of penetration).
    newton : :class:`NewtonOptions`; gain : per-muscle exaggeration of the active force.
    """

    def __init__(self, model: FaceModel, jaw_model="rigid", colliders=(), teeth_contact: bool = False,
                 lip_contact: bool = False, contact_stiffness: float = DEFAULT_STIFFNESS,
                 newton: NewtonOptions | None = None, gain=None):
        self.model = model
        self.jaw_model = make_jaw_model(model, jaw_model)
        options = EquilibriumOptions(newton=newton or NewtonOptions(), teeth_contact=bool(teeth_contact),
                                     contact_stiffness=float(contact_stiffness))
        self.simulator = FaceSimulator(model, options, jaw_model=self.jaw_model, gain=gain)
        self.colliders = [as_scene_collider(c, i) for i, c in enumerate(colliders)]
        self.contact_stiffness = float(contact_stiffness)
        self._skin = None
        self._lips = None
        if lip_contact:
            from facesim.contact.self_contact import lip_contact_term

            self._lips = lip_contact_term(model, stiffness=contact_stiffness)
        self.frames_done = 0
        self.last: Frame | None = None   # the last converged frame (the next warm start)

    def reset(self) -> None:
        """Forget the warm start: the next step starts from the rest shape."""
        self.last = None
        self.frames_done = 0

    def controls(self, a=None, jaw=None, head=None) -> Controls:
        return Controls(activation_vector(self.model, a), jaw=jaw, head=head)

    def posed_colliders(self, frame: float, controls: Controls) -> list:
        """The external colliders posed at ``frame`` with the bones of ``controls``."""
        if not self.colliders:
            return []
        Hc, Hj = self.simulator.bone_transforms(controls)
        return [c.at(frame, Hc, Hj) for c in self.colliders]

    def _skin_term(self, colliders) -> ContactTerm | None:
        if not colliders:
            return None
        if self._skin is None:
            m = self.model
            nodes = np.unique(m.skin)
            self._skin = ContactTerm(nodes, [], stiffness=self.contact_stiffness,
                                     weights=node_areas(m.X, m.skin)[nodes])
        return self._skin.with_colliders(colliders)

    def terms(self, frame: float, controls: Controls) -> tuple[list, tuple]:
        """``(posed colliders, extra energy terms)`` of a frame."""
        colliders = self.posed_colliders(frame, controls)
        extra = tuple(t for t in (self._skin_term(colliders), self._lips) if t is not None)
        return colliders, extra

    def step(self, a=None, jaw=None, head=None, frame: float | None = None, x0=None) -> Frame:
        """Solve one frame: activations ``a`` (array or ``{muscle: value}``), jaw controls of the jaw
        model, optional head transform, ``frame`` number for scripted colliders (default: the count
        of steps so far) and an optional warm start ``x0 (n, 3)`` (default: the last converged frame)."""
        controls = a if isinstance(a, Controls) else self.controls(a, jaw, head)
        k = float(self.frames_done if frame is None else frame)
        colliders, extra = self.terms(k, controls)
        warm = x0 if x0 is not None else (None if self.last is None else self.last.x)
        t0 = time.perf_counter()
        try:
            eq = self.simulator.equilibrium(controls, x0=warm, extra_terms=extra)
            x, report, error = eq.x, eq.report, ""
            converged = eq.converged and bool(np.isfinite(x).all())
            if not np.isfinite(x).all():
                error = "non-finite positions"
        except FacesimError as exc:   # a numerical failure of this frame (e.g. the linear solver)
            x = self.simulator.attached_positions(controls, warm)
            report, converged, error = None, False, " ".join(str(exc).split())
        pen = 0.0
        if colliders and np.isfinite(x).all():
            pen = float(self._skin.with_colliders(colliders).penetration(x).max())
        out = Frame(k, x, controls, converged, report, colliders, pen, error, self.model)
        if report is not None:
            report.seconds.setdefault("total", time.perf_counter() - t0)
        self.frames_done += 1
        if converged:
            self.last = out
        return out


__all__ = ["Simulation", "Frame", "activation_vector", "make_jaw_model", "JAW_MODELS"]
