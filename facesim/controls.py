"""Controls of the face: muscle activations, jaw pose and head pose (docs/architecture.md).

``Controls(a, jaw, head)``: ``a (n_muscles,)`` activations in [0, 1]; ``jaw`` the jaw model's
parameters (for :class:`~facesim.kinematics.jaw_models.RigidJaw`, a 4x4 rigid transform of the mandible relative to the skull);
``head`` an optional 4x4 transform of the skull in the world (identity when None).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim.errors import FacesimError
from facesim.se3 import check_rigid


def as_transform(T, name: str) -> np.ndarray | None:
    """``T`` as a read-only 4x4 float64 rigid transform (None stays None); a one-line
    :class:`FacesimError` starting with ``name`` for anything else (a reflection, a scaling,
    non-finite entries: :func:`facesim.se3.check_rigid`)."""
    if T is None:
        return None
    T = np.array(T, dtype=np.float64) if np.asarray(T).dtype.kind in "biuf" else T
    if np.shape(T) != (4, 4):
        raise FacesimError(f"{name}: expected a 4x4 rigid transform, got shape {np.shape(T)}")
    T = np.array(check_rigid(T, name, tolerance=1e-4), dtype=np.float64)   # 1e-4: matrices written to ~6 digits
    T.setflags(write=False)
    return T


@dataclass(frozen=True)
class Controls:
    a: np.ndarray
    jaw: object = None
    head: np.ndarray | None = None

    def __post_init__(self):
        a = np.array(self.a, dtype=np.float64).ravel()
        if not np.isfinite(a).all():
            raise FacesimError("controls.a: activations must be finite")
        a.setflags(write=False)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "head", as_transform(self.head, "controls.head"))

    @staticmethod
    def rest(n_muscles: int) -> "Controls":
        return Controls(np.zeros(n_muscles))


def rotation_about(axis_angle, centre) -> np.ndarray:
    """4x4 rotation by the rotation vector ``axis_angle (3,)`` (rad) about the point ``centre (3,)`` (mm)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.asarray(axis_angle, dtype=np.float64)).as_matrix()
    c = np.asarray(centre, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = c - R @ c
    return T
