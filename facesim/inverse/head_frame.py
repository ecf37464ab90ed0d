"""The cranium frame as 12 affine coefficients solved with the other controls (Sifakis 2005 section 8).

With ``solve-mocap --head solve`` the capture is not stabilised first: each frame's head pose is an
unknown of the fit, next to the activations and the jaw, as the paper solves for its kinematic
controls. The skull is an affine frame ``world = M (p - c) + c + t`` applied to the face as the
head-frame equilibrium puts it, stored as 12 coefficients ``f = (M row-major (9,), t (3,) mm)``
(:mod:`facesim.kinematics.frames`) about the centre ``c`` (the centroid of the model's rest
markers, so M and t are not coupled through a lever arm); the rigidity penalty
``||MᵀM − I||²_F`` (:func:`~facesim.kinematics.frames.rigidity_penalty`) enters the bounds term
of the progressive penalty schedule and makes the frame rigid to the accuracy its final weight
buys (micrometres of marker motion).

Why the frame moves the solved face rather than the skull's nodes: the flesh energy is invariant
under a rigid motion of the whole face, so a rigid head pose needs no equilibrium of its own (the
same reason :class:`~facesim.inverse.jacobian.ControlSpace`'s rigid head increments solve none);
applying the affine frame to the head-frame equilibrium is that, to first order in the frame's
strain, which the penalty drives to ~1e-5. A head-only step of the fit therefore costs no
equilibrium solve. The penalty is weighted ``r² / 4`` with ``r`` the RMS distance of the rest
markers from ``c``: a strain E (M = R (I + E)) costs ``||MᵀM − I||² ≈ 4 ||E||²`` and moves the
markers by about ``||E|| r``, so the penalty reads as a squared marker displacement in mm², the
unit of the marker term (as :func:`facesim.kinematics.affine_jaw.default_weights` does for the jaw).
"""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError
from facesim.kinematics.frames import N_FRAME, rigidity_penalty


class HeadFrame:
    """The skull's affine frame as unknowns of a fit: ``world = M (p - centre) + centre + t``.

    Parameters
    ----------
    centre : (3,) mm, the point the frame's linear part acts about (default the model's rest
        marker centroid, :meth:`of`).
    radius : RMS distance (mm) of the markers from ``centre``; the rigidity penalty's weight is
        ``radius² / 4`` (the module doc).
    """

    n = N_FRAME

    def __init__(self, centre, radius: float):
        self.centre = np.array(centre, dtype=np.float64).reshape(3)
        self.radius = float(radius)
        if not (np.isfinite(self.centre).all() and np.isfinite(self.radius) and self.radius > 0):
            raise FacesimError(f"head frame: expected a finite centre and a radius > 0 mm, got {self.centre}, {radius}")
        self.weight = 0.25 * self.radius ** 2

    @staticmethod
    def of(model) -> "HeadFrame":
        """The head frame of ``model``: about its rest markers' centroid."""
        P = model.marker_positions()
        c = P.mean(axis=0)
        return HeadFrame(c, float(np.sqrt(np.mean(np.sum((P - c) ** 2, axis=1)))))

    def coefficients(self, T) -> np.ndarray:
        """``(12,)`` coefficients of the 4x4 affine ``T`` (model head frame -> world)."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise FacesimError(f"head frame: expected a finite 4x4 affine transform, got shape {T.shape}")
        M = T[:3, :3]
        return np.r_[M.ravel(), T[:3, 3] + M @ self.centre - self.centre]

    def matrix(self, f) -> np.ndarray:
        """4x4 affine transform (model head frame -> world) of the coefficients ``f (12,)``."""
        f = np.asarray(f, dtype=np.float64)
        M = f[:9].reshape(3, 3)
        T = np.eye(4)
        T[:3, :3] = M
        T[:3, 3] = self.centre + f[9:] - M @ self.centre
        return T

    def apply(self, P, f) -> np.ndarray:
        """Points ``P (k, 3)`` mm of the head frame moved into the world by the frame ``f``."""
        f = np.asarray(f, dtype=np.float64)
        return (np.asarray(P, dtype=np.float64) - self.centre) @ f[:9].reshape(3, 3).T + self.centre + f[9:]

    def jacobian(self, P, f, dP) -> np.ndarray:
        """``(3k, nc + 12)`` derivative of :meth:`apply` (markers ``P (k, 3)`` of the head frame)
        with respect to the other controls -- whose head-frame derivative is ``dP (3k, nc)`` -- and
        then the frame's 12 coefficients."""
        P = np.asarray(P, dtype=np.float64)
        k, nc = len(P), dP.shape[1]
        M = np.asarray(f, dtype=np.float64)[:9].reshape(3, 3)
        out = np.zeros((k, 3, nc + N_FRAME))
        out[:, :, :nc] = np.einsum("ij,rjc->ric", M, dP.reshape(k, 3, nc))
        d = P - self.centre
        for i in range(3):
            out[:, i, nc + 3 * i:nc + 3 * i + 3] = d   # d world_i / d M_ij = d_j
            out[:, i, nc + 9 + i] = 1.0
        return out.reshape(3 * k, nc + N_FRAME)

    def rigid(self, f) -> tuple[np.ndarray, float]:
        """The rigid transform (4x4, model head frame -> world) nearest the frame ``f``: the rotation
        of M's polar decomposition about the centre, which it moves as ``f`` does; and the strain
        of M, the largest ``|s - 1|`` of its singular values s."""
        f = np.asarray(f, dtype=np.float64)
        U, s, Vt = np.linalg.svd(f[:9].reshape(3, 3))
        if np.linalg.det(U @ Vt) < 0:   # a reflection is no head pose: the nearest rotation instead
            U[:, -1] *= -1.0
        R = U @ Vt
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = self.centre + f[9:] - R @ self.centre
        return T, float(np.max(np.abs(s - 1.0)))

    def penalty(self, f, project: bool = True):
        """``weight ||MᵀM − I||²_F`` (mm²) of the frame ``f`` with its gradient ``(12,)`` and Hessian
        ``(12, 12)`` (PSD-projected unless ``project=False``)."""
        v, g, H = rigidity_penalty(np.asarray(f, dtype=np.float64), project=project)
        return self.weight * v, self.weight * g, self.weight * H


__all__ = ["HeadFrame"]
