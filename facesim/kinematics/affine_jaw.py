"""The mandible as 12 affine coefficients with the kinematic penalties (Sifakis 2005 section 8).

Where :class:`~facesim.kinematics.condyle.SlidingCondyleJaw` solves for three natural parameters
that give an exactly valid pose, :class:`AffineCondyleJaw` solves for the jaw frame itself,
``q = (M row-major (9,), t (3,))`` (``facesim.kinematics.frames``), as the paper formulates it:
the mandible nodes are linear in ``q`` and the joint is enforced by penalties only -- the
constraints psi1..psi6 (condyles on their tracks and within their range, the opening within
its range) and the rigidity penalty ``||MᵀM − I||²_F``. The inverse solver adds the penalty to
the marker objective through its progressive penalty schedule
(:func:`facesim.inverse.gauss_newton.schedule_penalty`), so the pose is valid to the accuracy
the schedule's final weight buys, not exactly.

Penalty units. Each term is weighted so that it reads as a squared displacement of a bone point
in mm² (the marker objective's unit, and that of the sliding-condyle jaw's slide penalty):
psi2..psi5 are in mm already (weight 1); psi1, a tilt of the intercondylar axis out of the track
plane, moves each condyle by (l/2) psi1 (weight (l/2)²); psi6, minus the sine of the opening,
moves the incisor by r psi6 with r the incisor's distance from the condyle midpoint (weight r²);
a strain E of the frame (M = R (I + E)) gives ``||MᵀM − I||² ≈ 4 ||E||²`` and moves the incisor
by about ``||E|| r`` (weight r²/4). At the schedule's final weight mu = ``final_ratio`` (1e6)
times the data term, a violation costing the markers a gradient g (mm per mm) settles at about
g / (mu * 1 mm⁻²) mm: micrometres at the noise level of a capture.
"""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError
from facesim.kinematics.condyle import KinematicTerm, SlidingCondyleJaw
from facesim.kinematics.frames import N_FRAME, frame_to_matrix, identity_frame, matrix_to_frame
from facesim.model import JawGeometry

#: Half-width of the box on the entries of M (dimensionless); the penalties are the real limits.
M_BOX = 2.0


def default_weights(geometry: JawGeometry) -> np.ndarray:
    """``(7,)`` weights (rigidity, psi1..psi6) that make each penalty term a squared bone-point
    displacement in mm² (see the module doc): r²/4, (l/2)², 1, 1, 1, 1, r², with l the
    intercondylar distance and r the incisor's distance from the condyle midpoint (mm)."""
    r2 = float(np.sum((geometry.incisor - geometry.midpoint) ** 2))
    half_l2 = (0.5 * geometry.intercondylar_distance) ** 2
    return np.array([0.25 * r2, half_l2, 1.0, 1.0, 1.0, 1.0, r2])


class AffineCondyleJaw:
    """The jaw frame's 12 affine coefficients as the jaw controls, the sliding-condyle joint and
    rigidity as penalties (Sifakis 2005 section 8).

    Parameters
    ----------
    geometry : JawGeometry, the model's TMJ geometry (``model.jaw``).
    weights : (7,) or scalar, optional: weights of the rigidity penalty and of psi1..psi6 in
        :meth:`SlidingCondyleJaw.phi_kin` order; default :func:`default_weights` (penalty in mm²).

    Jaw-model interface (:class:`~facesim.kinematics.jaw_models.JawModel`): ``q (12,)`` = (M
    row-major, t mm) (``param_names`` m00..m22, tx, ty, tz); ``transform(q) -> 4x4`` the frame's
    matrix; ``jacobian(q) -> (4, 4, 12)`` constant; ``penalty(q) -> (value mm², (12,), (12, 12))``;
    ``bounds (12, 2)`` wide boxes; ``rest`` the identity frame; ``parameters(T)`` T's coefficients.
    """

    name = "affine-condyle"
    n_params = N_FRAME
    param_names = ("m00", "m01", "m02", "m10", "m11", "m12", "m20", "m21", "m22", "tx", "ty", "tz")

    def __init__(self, geometry: JawGeometry, weights=None):
        self.condyle = SlidingCondyleJaw(geometry)   # validates the geometry; psi1..psi6 and phi_kin
        self.geometry = geometry
        w = default_weights(geometry) if weights is None else weights
        self.weights = np.array(np.broadcast_to(np.asarray(w, dtype=np.float64), (7,)))
        if not (np.isfinite(self.weights).all() and (self.weights >= 0).all()):
            raise FacesimError(f"AffineCondyleJaw: expected finite weights >= 0, got {self.weights}")
        self.weights.setflags(write=False)
        self._term = KinematicTerm(self.condyle, self.weights)
        self.rest = identity_frame()
        self.rest.setflags(write=False)
        # t = m + slide v - M m for a valid pose: |t| <= d + |(I - M) m| <= d + 2 |m| for a rotation;
        # three track lengths and 20 mm more leave the box far outside anything the penalties allow
        half_t = 3.0 * geometry.track_length + 20.0 + 2.0 * float(np.linalg.norm(geometry.midpoint))
        self.bounds = np.array([[-M_BOX, M_BOX]] * 9 + [[-half_t, half_t]] * 3)
        self.bounds.setflags(write=False)
        dT = np.zeros((4, 4, N_FRAME))
        for i in range(3):
            for j in range(3):
                dT[i, j, 3 * i + j] = 1.0
            dT[i, 3, 9 + i] = 1.0
        self._dT = dT
        self._dT.setflags(write=False)

    def _q(self, q) -> np.ndarray:
        if q is None:
            return np.array(self.rest)
        q = np.asarray(q, dtype=np.float64).ravel()
        if q.shape != (N_FRAME,) or not np.isfinite(q).all():
            raise FacesimError(f"controls.jaw: expected 12 finite affine coefficients (m00..m22, tx, ty, tz mm), "
                               f"got shape {np.shape(q)}")
        return q

    def transform(self, q=None) -> np.ndarray:
        """4x4 mandible transform relative to the cranium (mm) of the frame ``q (12,)`` (None: rest,
        the identity). Not necessarily rigid: rigidity is a penalty."""
        return frame_to_matrix(self._q(q))

    def jacobian(self, q=None) -> np.ndarray:
        """``(4, 4, 12)`` derivative of :meth:`transform`: constant, 1 where the coefficient sits."""
        self._q(q)
        return self._dT.copy()

    def penalty(self, q=None, project: bool = True):
        """Kinematic penalty of the frame ``q (12,)``: ``weights``-weighted rigidity
        ``||MᵀM − I||²_F``, psi1² + psi2² + psi3² and squared distances of psi4..psi6 outside their
        ranges (:meth:`SlidingCondyleJaw.phi_kin`); mm² with the default weights. Returns
        ``(value, gradient (12,), Hessian (12, 12))``; the Hessian is PSD-projected unless
        ``project=False`` (the exact one)."""
        return self._term.evaluate(self._q(q), project=project)

    def psi(self, q=None) -> np.ndarray:
        """``(6,)`` constraints psi1..psi6 of the frame (psi2..psi5 mm), see :mod:`~facesim.kinematics.condyle`."""
        return self.condyle.psi(self._q(q))

    def parameters(self, T) -> np.ndarray:
        """``(12,)`` coefficients of the 4x4 (or 3x4) affine ``T``; the penalty is ~0 when ``T`` is a
        sliding-condyle pose within range."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape not in ((4, 4), (3, 4)) or not np.isfinite(T).all():
            raise FacesimError(f"jaw pose: expected a finite 4x4 affine transform, got shape {T.shape}")
        return matrix_to_frame(T)


__all__ = ["AffineCondyleJaw", "default_weights"]
