"""The jaw coordinate frame (Zoss et al. 2018 section 3.1).

Jaw rigs are set up in a frame attached to the skull whose origin is the reference point (the
lower incisal point) in the closed rest pose, with axes x toward the subject's left (the opening
axis: a positive rotation about x drops the chin), y up and z forward (toward the nose), so
x × y = z. In that frame the reference point's coordinates read directly as lateral, vertical
and antero-posterior motion, and the traditional rigs rotate about these axes.

``from_geometry`` builds it from the TMJ geometry (x along the intercondylar axis);
``from_poses`` from captured motion alone (x along the dominant rotation axis of the poses),
with a hint of the skull's up direction in both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim import se3
from facesim.errors import FacesimError


def _unit(a, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    n = np.linalg.norm(a)
    if a.shape != (3,) or not np.isfinite(n) or n < 1e-12:
        raise FacesimError(f"{what}: expected a non-zero 3-vector")
    return a / n


@dataclass(frozen=True)
class JawFrame:
    """Rigid jaw frame in the skull frame.

    origin : (3,) mm, the reference point at rest (skull frame).
    axes : (3, 3) rows x (left), y (up), z (forward): orthonormal, right-handed.
    """

    origin: np.ndarray
    axes: np.ndarray

    def __post_init__(self):
        origin = np.array(self.origin, dtype=np.float64)
        axes = np.array(self.axes, dtype=np.float64)
        if origin.shape != (3,) or axes.shape != (3, 3) or not np.isfinite(axes).all():
            raise FacesimError("jaw frame: expected origin (3,) and axes (3, 3)")
        if np.abs(axes @ axes.T - np.eye(3)).max() > 1e-9 or np.linalg.det(axes) < 0:
            raise FacesimError("jaw frame: expected orthonormal right-handed axes (rows x, y, z)")
        origin.setflags(write=False)
        axes.setflags(write=False)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "axes", axes)

    @classmethod
    def from_axes(cls, origin, lateral, up=(0.0, 1.0, 0.0)) -> JawFrame:
        """Frame at ``origin (3,)`` mm with x along ``lateral (3,)`` and y along the part of
        ``up (3,)`` orthogonal to it."""
        x = _unit(lateral, "jaw frame lateral axis")
        y = _unit(up, "jaw frame up direction")
        y = y - (y @ x) * x
        if np.linalg.norm(y) < 1e-6:
            raise FacesimError("jaw frame: the up direction is parallel to the lateral axis")
        y /= np.linalg.norm(y)
        return cls(np.asarray(origin, dtype=np.float64), np.stack([x, y, np.cross(x, y)]))

    @classmethod
    def from_geometry(cls, geometry, up=(0.0, 1.0, 0.0)) -> JawFrame:
        """Frame of a :class:`facesim.model.JawGeometry`: origin at its incisor, x along the
        intercondylar axis (right -> left condyle), y up."""
        return cls.from_axes(geometry.incisor, geometry.condyle_left - geometry.condyle_right, up)

    @classmethod
    def from_poses(cls, poses, reference_point, up=(0.0, 1.0, 0.0)) -> JawFrame:
        """Frame from captured poses ``(N, 4, 4)`` (mandible relative to skull, mm, rest = identity):
        x is the principal direction of the poses' rotation vectors (the opening axis), signed so
        that the pose moving ``reference_point (3,)`` mm furthest is a positive rotation."""
        poses = np.asarray(poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) < 2:
            raise FacesimError(f"poses: expected (N, 4, 4) with N >= 2, got {poses.shape}")
        omega = se3.so3_log(poses[:, :3, :3])
        if np.linalg.norm(omega, axis=1).max() < 1e-6:
            raise FacesimError("poses: no rotation in the data, the opening axis is undefined")
        x = np.linalg.svd(omega, full_matrices=False)[2][0]
        moved = np.linalg.norm(se3.transform_points(poses, reference_point)[:, 0] - reference_point, axis=1)
        if omega[np.argmax(moved)] @ x < 0:
            x = -x
        return cls.from_axes(reference_point, x, up)

    # --- conversions ----------------------------------------------------------------------------

    @property
    def matrix(self) -> np.ndarray:
        """4x4 map from skull coordinates to jaw-frame coordinates (mm)."""
        F = np.eye(4)
        F[:3, :3] = self.axes
        F[:3, 3] = -self.axes @ self.origin
        return F

    def to_local(self, points) -> np.ndarray:
        """Jaw-frame coordinates ``(..., 3)`` mm of skull-frame points ``(..., 3)`` mm."""
        return (np.asarray(points, dtype=np.float64) - self.origin) @ self.axes.T

    def to_world(self, points) -> np.ndarray:
        """Skull-frame coordinates ``(..., 3)`` mm of jaw-frame points ``(..., 3)`` mm."""
        return np.asarray(points, dtype=np.float64) @ self.axes + self.origin

    def pose_to_local(self, T) -> np.ndarray:
        """Poses ``(..., 4, 4)`` of the skull frame expressed in the jaw frame: F T F⁻¹."""
        return self.matrix @ np.asarray(T, dtype=np.float64) @ se3.inverse(self.matrix)

    def pose_to_world(self, T) -> np.ndarray:
        """Inverse of ``pose_to_local``: F⁻¹ T F."""
        return se3.inverse(self.matrix) @ np.asarray(T, dtype=np.float64) @ self.matrix


__all__ = ["JawFrame"]
