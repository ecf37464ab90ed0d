"""Data-driven jaw modelling, independent of the FEM (DESIGN.md ``jaw/``).

- ``se3`` -- log/exp maps of SE(3), pose errors, geodesic interpolation.
- ``frame`` -- the jaw coordinate frame (Zoss et al. 2018 section 3.1).
- ``motion`` -- synthetic TMJ motion: subjects and capture-like sessions.
- ``classic`` -- the traditional 1/3/5/6-DOF rigs with an optimised pivot (Zoss eqs. 1, 6-8).
- ``posselt`` -- the Posselt-envelope rig: shield, unit-cube sliders, RBF map (Zoss eqs. 3, 9, 15).
- ``evaluate`` -- mandible points, front-weighted errors, train/test comparison of rigs.
- ``rigfile`` -- fitted rigs on disk (versioned .npz).
"""

from facesim.jaw import se3
from facesim.jaw.classic import DOF, ClassicRig, fit_classic
from facesim.jaw.evaluate import (
    compare_rigs,
    front_weights,
    mandible_points,
    pose_errors,
)
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Session, Subject
from facesim.jaw.posselt import PosseltRig, Shield, fit_posselt
from facesim.jaw.rigfile import rig_kind


def load_rig(path):
    """A fitted rig (:class:`PosseltRig` or :class:`ClassicRig`) from its ``.npz``, by its kind."""
    kind = rig_kind(path)
    return {"posselt": PosseltRig.load, "classic": ClassicRig.load}.get(kind, PosseltRig.load)(path)


__all__ = [
    "DOF",
    "ClassicRig",
    "JawFrame",
    "JawMotion",
    "PosseltRig",
    "Session",
    "Shield",
    "Subject",
    "compare_rigs",
    "fit_classic",
    "fit_posselt",
    "front_weights",
    "load_rig",
    "mandible_points",
    "pose_errors",
    "se3",
]
