"""The jaw-model interface and the factory that makes a jaw model from its name.

A jaw model maps the jaw controls ``q`` to the mandible's 4x4 rigid transform relative to the
skull (mm). Every jaw model -- :class:`RigidJaw`, the sliding-condyle jaw
(:class:`~facesim.kinematics.condyle.SlidingCondyleJaw`, Sifakis 2005 section 8), its affine
formulation (:class:`~facesim.kinematics.affine_jaw.AffineCondyleJaw`: 12 frame coefficients and
penalties, as the paper solves it) and every fitted rig
(:class:`~facesim.kinematics.rig_jaw.RigJaw`: Posselt, NLPCA, 1/3/5/6-DOF) -- implements
:class:`JawModel`; the simulator, the inverse solver and the file readers use nothing else.

``n_params`` is the number of parameters the inverse solver can solve for. The rigid jaw has none:
its controls are the 4x4 transform itself (``rest`` the identity), fixed during a fit.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from facesim.controls import as_transform, rotation_about
from facesim.errors import FacesimError


@runtime_checkable
class JawModel(Protocol):
    """The jaw-model interface (docs/architecture.md).

    name : str; n_params : int, solvable parameters; param_names : tuple of n_params names, the
    column names of jaw CSV files in this order; rest : the controls of the rest pose ((n_params,),
    or the 4x4 identity for the rigid jaw); bounds : (n_params, 2) [lower, upper].
    """

    name: str
    n_params: int
    param_names: tuple
    rest: np.ndarray
    bounds: np.ndarray

    def transform(self, q=None) -> np.ndarray:
        """(4, 4) mandible transform relative to the skull (mm) of the controls ``q`` (None: rest)."""

    def jacobian(self, q=None) -> np.ndarray:
        """(4, 4, n_params) derivative of :meth:`transform` with respect to the parameters."""

    def penalty(self, q=None) -> tuple:
        """Range penalty: ``(value, gradient (n_params,), Hessian (n_params, n_params))``."""

    def parameters(self, T) -> np.ndarray:
        """The controls whose :meth:`transform` is (closest to) the pose ``T (4, 4)``."""


class RigidJaw:
    """The simplest jaw model: the controls are the mandible's 4x4 rigid transform relative to the
    skull (None: rest). It has no solvable parameters (``n_params = 0``): the inverse solver keeps
    the given pose."""

    name = "rigid"
    n_params = 0
    param_names = ()

    def __init__(self):
        self.rest = np.eye(4)
        self.rest.setflags(write=False)
        self.bounds = np.zeros((0, 2))
        self.bounds.setflags(write=False)

    def transform(self, q=None) -> np.ndarray:
        return np.eye(4) if q is None else as_transform(q, "controls.jaw")

    def jacobian(self, q=None) -> np.ndarray:
        return np.zeros((4, 4, 0))

    def penalty(self, q=None):
        return 0.0, np.zeros(0), np.zeros((0, 0))

    def parameters(self, T) -> np.ndarray:
        return np.array(as_transform(T, "jaw pose"))

    @staticmethod
    def from_rotation(model, opening: float = 0.0, rotvec=None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Jaw transform: rotation about the intercondylar axis (``opening`` rad, positive opens the
        mouth) or by a general ``rotvec`` about the condyle midpoint, then a translation (mm)."""
        geo = model.jaw
        if rotvec is None:
            rotvec = opening * geo.u   # u points right -> left; positive rotation about it drops the chin
        T = rotation_about(rotvec, geo.midpoint)
        T[:3, 3] += np.asarray(translation, dtype=np.float64)
        return T


#: jaw models by name; fitted rigs also as ``posselt:RIG.npz``, ``nlpca:RIG.npz``, ``classic:RIG.npz``
JAW_MODELS = ("rigid", "sliding-condyle", "affine-condyle", "posselt")
RIG_SPECS = ("posselt:RIG.npz", "nlpca:RIG.npz", "classic:RIG.npz")


def make_jaw_model(model, spec="rigid", model_path=None) -> JawModel:
    """A jaw model from a name: ``"rigid"`` (controls: a 4x4 transform), ``"sliding-condyle"``
    (opening rad, right slide mm, left slide mm), ``"affine-condyle"`` (the jaw frame's 12 affine
    coefficients with the sliding-condyle joint and rigidity as penalties,
    :class:`~facesim.kinematics.affine_jaw.AffineCondyleJaw`), ``"posselt"`` (the model's own Posselt rig,
    fitted to motion generated for its TMJ: ``<model>_posselt.npz`` next to ``model_path`` when
    given, else the shipped rig recording the same TMJ, see
    :func:`~facesim.kinematics.rig_jaw.model_rig_jaw`), a fitted rig ``"posselt:RIG.npz"``,
    ``"nlpca:RIG.npz"``, ``"classic:RIG.npz"``, or an object implementing :class:`JawModel`."""
    if not isinstance(spec, str):
        if not isinstance(spec, JawModel):
            raise FacesimError(f"jaw model: expected a name ({', '.join(JAW_MODELS)}) or an object implementing "
                               f"the JawModel interface (name, n_params, param_names, rest, bounds, transform(q), jacobian(q), "
                               f"penalty(q), parameters(T)), got {type(spec).__name__}")
        return spec
    if spec == "rigid":
        return RigidJaw()
    if spec == "sliding-condyle":
        from facesim.kinematics.condyle import SlidingCondyleJaw

        return SlidingCondyleJaw(model.jaw)
    if spec == "affine-condyle":
        from facesim.kinematics.affine_jaw import AffineCondyleJaw

        return AffineCondyleJaw(model.jaw)
    if spec == "posselt":
        from facesim.kinematics.rig_jaw import model_rig_jaw

        return model_rig_jaw(model, model_path)
    if ":" in spec:
        from facesim.kinematics.rig_jaw import rig_jaw_from_spec

        return rig_jaw_from_spec(model, spec)
    raise FacesimError(f"jaw model: expected one of {', '.join(JAW_MODELS + RIG_SPECS)}, got {spec!r}")


__all__ = ["JAW_MODELS", "JawModel", "RigidJaw", "make_jaw_model"]
