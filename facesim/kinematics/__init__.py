"""Bone kinematics: affine cranium/jaw frames with the rigidity penalty (``frames``) and the
Sifakis 2005 sliding-condyle jaw (``condyle``). See docs/physics.md section 3."""

from facesim.kinematics.condyle import KinematicTerm, SlidingCondyleJaw
from facesim.kinematics.frames import (
    RigidityTerm,
    attached_jacobian,
    attached_positions,
    frame_to_matrix,
    identity_frame,
    matrix_to_frame,
    psd_project,
    rigidity_penalty,
)

__all__ = [
    "KinematicTerm",
    "RigidityTerm",
    "SlidingCondyleJaw",
    "attached_jacobian",
    "attached_positions",
    "frame_to_matrix",
    "identity_frame",
    "matrix_to_frame",
    "psd_project",
    "rigidity_penalty",
]
