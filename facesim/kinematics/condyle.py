"""Sliding-condyle jaw (Sifakis, Neverov, Fedkiw 2005 section 8; docs/physics.md section 3).

The mandible is an affine frame ``q = (M row-major (9,), t (3,))`` relative to the cranium
(``facesim.kinematics.frames``). With the rest TMJ geometry in the cranium frame -- u (unit,
right -> left condyle), v (unit, along the sliding tracks, back -> front, inclined downward),
w = v x u (unit normal of the track plane; up and slightly forward on the shipped model),
m (rest condyle midpoint), l (intercondylar distance), d (track length), s = sin(max opening) --
a valid pose satisfies the six constraints, all linear in q::

    psi1 = wᵀ M u                      = 0        rotated condyle axis stays in the track plane
    psi2 = wᵀ (M m + t − m)            = 0        midpoint stays on the track plane
    psi3 = uᵀ (M m + t − m)            = 0        midpoint equidistant from the two tracks
    psi4 = vᵀ [M(m − (l/2)u) + t − m]  in [0, d]  right condyle slide along its track, mm
    psi5 = vᵀ [M(m + (l/2)u) + t − m]  in [0, d]  left condyle slide along its track, mm
    psi6 = wᵀ M v                      in [−s, 0] opening: −sin(opening angle)

Sign conventions (checked against the shipped model in tests/kinematics/test_condyle.py, and
in agreement with docs/physics.md): a positive rotation about u drops the chin (opens the mouth) and
gives psi6 = −sin(angle) < 0, because R_u(θ) v = cos θ v + sin θ (u × v) = cos θ v − sin θ w;
a slide forward along +v makes psi4, psi5 positive.

The intuitive parameters ``p = (opening rad, right slide mm, left slide mm)`` map to an exactly
valid pose (``transform``): open by θ about the axis through the condyles, yaw by
γ = asin((s_R − s_L)/l) about w through the midpoint, then move the midpoint by (s_R + s_L)/2
along v::

    M = R_w(γ) R_u(θ),   t = m + ½(s_R + s_L) v − M m

so psi1 = psi2 = psi3 = 0, psi4 = s_R, psi5 = s_L and psi6 = −sin θ exactly. (With γ ≠ 0 each
condyle leaves its track sideways by (l/2)(1 − cos γ), second order in the slide difference: the
model only keeps the midpoint equidistant from the tracks, as in Sifakis 2005.)
"""

from __future__ import annotations

import numpy as np

from facesim.energy import ParameterTerm
from facesim.errors import FacesimError
from facesim.kinematics.frames import N_FRAME, matrix_to_frame, rigidity_penalty
from facesim.model import JawGeometry
from facesim.se3 import rigid_fit


def _skew(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _rotation(axis, angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` rad about the unit ``axis (3,)`` (Rodrigues)."""
    K = _skew(axis)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _range_penalty(values, lower, upper, weights, J):
    """Σ_i weights_i * (distance of values_i outside [lower_i, upper_i])², piecewise quadratic and
    zero inside, for ``values = J x + const``: returns (value, gradient (n,), Hessian (n, n)) with
    respect to x. ``J (k, n)``; the Hessian is 2 Jᵀ diag(weights * outside) J, PSD."""
    outside = (values > upper) | (values < lower)
    if not outside.any():   # inside the box (most calls of a penalty schedule): all zero
        n = J.shape[1]
        return 0.0, np.zeros(n), np.zeros((n, n))
    excess = np.maximum(values - upper, 0.0) + np.minimum(values - lower, 0.0)
    value = float(np.sum(weights * excess**2))
    grad = 2.0 * J.T @ (weights * excess)
    hess = 2.0 * (J.T * (weights * outside)) @ J
    return value, grad, hess


class SlidingCondyleJaw:
    """The Sifakis 2005 sliding-condyle jaw as a jaw model.

    Parameters
    ----------
    geometry : JawGeometry, the model's TMJ geometry (``model.jaw``); u must be orthogonal to v.
    penalty_weight : float, weight of the range penalty on the parameters (``penalty``);
        per rad² for the opening and per mm² for the slides.
    points : (k, 3) mm, optional jaw points whose distance ``project`` minimises (default: the two
        condyles and the incisor, which fix a rigid pose).

    Jaw-model interface (:class:`~facesim.kinematics.jaw_models.JawModel`): ``q = p = (opening rad,
    right slide mm, left slide mm)`` (``param_names``); ``transform(q) -> 4x4``, ``jacobian(q) -> (4, 4,
    3)``, ``penalty(q) -> (value, (3,), (3, 3))``, ``bounds (3, 2)``, ``rest``, ``parameters(T)``. Frame level (12 affine coefficients):
    ``psi``, ``psi_jacobian``, ``phi_kin``; conversions ``parameters`` and ``project``.
    """

    name = "sliding-condyle"
    n_params = 3
    param_names = ("opening", "right_slide", "left_slide")   # the order of q, and of jaw CSV columns

    def __init__(self, geometry: JawGeometry, penalty_weight: float = 1.0, points=None):
        if not isinstance(geometry, JawGeometry):
            raise FacesimError(f"SlidingCondyleJaw: expected a JawGeometry, got {type(geometry).__name__}")
        self.geometry = geometry
        self.u, self.v, self.w = geometry.u, geometry.v, geometry.w
        if abs(self.u @ self.v) > 1e-6:
            raise FacesimError(f"jaw.track_direction: expected orthogonal to the intercondylar axis "
                               f"(|u.v| = {abs(self.u @ self.v):.2e})")
        self.m = geometry.midpoint
        self.l = geometry.intercondylar_distance
        self.d = geometry.track_length
        self.s = float(np.sin(geometry.max_opening))
        self.penalty_weight = float(penalty_weight)
        if points is None:
            points = np.stack([geometry.condyle_right, geometry.condyle_left, geometry.incisor])
        self.points = np.array(points, dtype=np.float64).reshape(-1, 3)
        self.points.setflags(write=False)
        self.rest = np.zeros(3)   # closed, condyles at the back of their tracks: the identity
        self.rest.setflags(write=False)

        # psi = A q + b, A (6, 12): the constraints are linear in the frame coefficients
        u, v, w, m, l = self.u, self.v, self.w, self.m, self.l
        right, left = m - 0.5 * l * u, m + 0.5 * l * u
        zero = np.zeros(3)
        rows = [(w, u, zero), (w, m, w), (u, m, u), (v, right, v), (v, left, v), (w, v, zero)]
        self._A = np.array([np.concatenate([np.outer(a, x).ravel(), c]) for a, x, c in rows])
        self._b = np.array([0.0, -w @ m, -u @ m, -v @ m, -v @ m, 0.0])
        self._A.setflags(write=False)
        self.psi_lower = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -self.s])
        self.psi_upper = np.array([0.0, 0.0, 0.0, self.d, self.d, 0.0])

    # --- frame level: constraints and the kinematic penalty -------------------------------------

    def psi(self, q) -> np.ndarray:
        """``(6,)`` constraints psi1..psi6 of the jaw frame ``q (12,)`` (psi2..psi5 in mm)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (N_FRAME,):
            raise FacesimError(f"jaw frame: expected 12 affine coefficients, got shape {q.shape}")
        return self._A @ q + self._b

    def psi_jacobian(self, q=None) -> np.ndarray:
        """``(6, 12)`` derivative of ``psi`` with respect to ``q`` (constant: psi is linear in q)."""
        return self._A.copy()

    def phi_kin(self, q, weights=None, project: bool = False):
        """Kinematic penalty of the jaw frame ``q (12,)``: (value, gradient (12,), Hessian (12, 12)).

        phi_kin = w_0 ||MᵀM − I||²_F + Σ_{i=1..3} w_i psi_i² + Σ_{i=4..6} w_i dist(psi_i, range)²,
        ranges [0, d], [0, d], [−s, 0]. ``weights`` : scalar or (7,) (rigidity, psi1..psi6), default
        1; psi2..psi5 are in mm, so their terms are mm² times the weight. ``project=True`` PSD-projects
        the rigidity Hessian, the only indefinite part, so the sum is PSD.
        """
        weights = np.broadcast_to(np.asarray(1.0 if weights is None else weights, dtype=np.float64), (7,))
        value, grad, hess = rigidity_penalty(q, project=project)
        v2, g2, h2 = _range_penalty(self.psi(q), self.psi_lower, self.psi_upper, weights[1:], self._A)
        return weights[0] * value + v2, weights[0] * grad + g2, weights[0] * hess + h2

    # --- intuitive parameters p = (opening, right slide, left slide) ----------------------------

    def _p(self, p) -> np.ndarray:
        p = np.zeros(3) if p is None else np.asarray(p, dtype=np.float64).ravel()
        if p.shape != (3,) or not np.isfinite(p).all():
            raise FacesimError("controls.jaw: expected 3 finite sliding-condyle parameters "
                               "(opening rad, right slide mm, left slide mm)")
        if abs(p[1] - p[2]) >= self.l:
            raise FacesimError(f"controls.jaw: slide difference {abs(p[1] - p[2]):g} mm must be below the "
                               f"intercondylar distance {self.l:g} mm")
        return p

    def _pose(self, p):
        theta, sr, sl = p
        gamma = np.arcsin((sr - sl) / self.l)
        Rw, Ru = _rotation(self.w, gamma), _rotation(self.u, theta)
        return gamma, Rw, Ru, Rw @ Ru

    def transform(self, q=None) -> np.ndarray:
        """4x4 mandible transform relative to the cranium (mm) for ``q = p (3,)`` =
        (opening rad, right slide mm, left slide mm); ``None`` is the rest pose (identity)."""
        p = self._p(q)
        _, _, _, M = self._pose(p)
        T = np.eye(4)
        T[:3, :3] = M
        T[:3, 3] = self.m + 0.5 * (p[1] + p[2]) * self.v - M @ self.m
        return T

    def jacobian(self, q=None) -> np.ndarray:
        """``(4, 4, 3)`` derivative of ``transform(q)`` with respect to ``q = p`` (analytic);
        the last row is zero. Units: per rad for the opening, per mm for the slides."""
        p = self._p(q)
        gamma, Rw, Ru, M = self._pose(p)
        dM_theta = Rw @ _skew(self.u) @ Ru
        dM_gamma = _skew(self.w) @ M
        dgamma = 1.0 / (self.l * np.cos(gamma))            # d gamma / d s_R = − d gamma / d s_L
        dT = np.zeros((4, 4, 3))
        for k, (dM, dtrans) in enumerate([(dM_theta, 0.0),
                                          (dgamma * dM_gamma, 0.5),
                                          (-dgamma * dM_gamma, 0.5)]):
            dT[:3, :3, k] = dM
            dT[:3, 3, k] = dtrans * self.v - dM @ self.m
        return dT

    def frame(self, q=None) -> np.ndarray:
        """``(12,)`` affine coefficients of ``transform(q)``."""
        return matrix_to_frame(self.transform(q))

    def frame_jacobian(self, q=None) -> np.ndarray:
        """``(12, 3)`` derivative of ``frame(q)`` with respect to ``q = p``."""
        dT = self.jacobian(q)
        return np.concatenate([dT[:3, :3].reshape(9, 3), dT[:3, 3]])

    def parameters(self, T) -> np.ndarray:
        """Parameters ``p (3,)`` of a valid pose ``T`` (4x4): the exact inverse of ``transform``.

        opening = atan2(−wᵀMv, |(uᵀMv, vᵀMv)|) (= asin(−psi6) for a valid pose), slides = psi4, psi5.
        For an invalid T this is only a rough guess; use ``project`` for the nearest valid pose.
        """
        T = np.asarray(T, dtype=np.float64)
        if T.shape not in ((4, 4), (3, 4)):
            raise FacesimError(f"jaw pose: expected a 4x4 transform, got shape {T.shape}")
        Mv = T[:3, :3] @ self.v
        theta = np.arctan2(-(self.w @ Mv), np.hypot(self.u @ Mv, self.v @ Mv))
        psi = self.psi(matrix_to_frame(T))
        return np.array([theta, psi[3], psi[4]])

    def project(self, T) -> np.ndarray:
        """Nearest valid pose (4x4) to the affine ``T`` (4x4, any M): the ``transform(p)`` with p in
        ``bounds`` that minimises Σ_k ||T(P_k) − transform(p)(P_k)||² over the jaw points P
        (``points``, mm). Rigid, satisfies psi1..psi3 = 0 and the ranges, and is idempotent."""
        from scipy.optimize import least_squares


        T = np.asarray(T, dtype=np.float64)
        if T.shape not in ((4, 4), (3, 4)) or not np.isfinite(T).all():
            raise FacesimError(f"jaw pose: expected a finite 4x4 affine transform, got shape {T.shape}")
        P = self.points
        target = P @ T[:3, :3].T + T[:3, 3]
        lower, upper = self.bounds.T

        def residual(p):
            Tp = self.transform(p)
            return (P @ Tp[:3, :3].T + Tp[:3, 3] - target).ravel()

        def jac(p):
            dT = self.jacobian(p)
            return (np.einsum("kj,ijc->kic", P, dT[:3, :3]) + dT[:3, 3][None]).reshape(-1, 3)

        p0 = np.clip(self.parameters(rigid_fit(P, target)), lower, upper)
        scale = max(1.0, float(np.abs(target).max()))
        if np.abs(residual(p0)).max() <= 1e-12 * scale:    # already valid: keep it (idempotence)
            return self.transform(p0)
        fit = least_squares(residual, p0, jac=jac, bounds=(lower, upper), method="trf",
                            xtol=1e-14, ftol=1e-14, gtol=1e-14)
        return self.transform(fit.x)

    def natural_parameters(self, opening: float, hinge_drop: float = 18.0) -> np.ndarray:
        """Parameters ``p (3,)`` of a symmetric opening by ``opening`` rad along the natural path:
        pure rotation until the lower incisor has dropped by about ``hinge_drop`` mm (docs/physics.md:
        pure-hinge opening ~17-20 mm), then both condyles translate, linearly in the angle, to the
        end of their tracks at the maximum opening."""
        theta_max = self.geometry.max_opening
        if not (np.isfinite(opening) and 0.0 <= opening <= theta_max + 1e-12):
            raise FacesimError(f"opening: expected an angle in [0, {theta_max:.3g}] rad, got {opening}")
        reach = np.linalg.norm(self.geometry.incisor - self.m)
        hinge = min(hinge_drop / reach, 0.9 * theta_max)
        slide = self.d * float(np.clip((opening - hinge) / (theta_max - hinge), 0.0, 1.0))
        return np.array([float(opening), slide, slide])

    # --- jaw-model interface --------------------------------------------------------------------

    @property
    def bounds(self) -> np.ndarray:
        """``(3, 2)`` [lower, upper] per parameter: opening [0, max_opening] rad, slides [0, d] mm."""
        return np.array([[0.0, self.geometry.max_opening], [0.0, self.d], [0.0, self.d]])

    def penalty_box(self):
        """``(lower, upper, weight)``: :meth:`penalty` is the box penalty of these ranges."""
        lower, upper = self.bounds.T
        return lower, upper, np.full(3, self.penalty_weight)

    def penalty(self, q=None):
        """Range penalty on ``q = p (3,)``: ``penalty_weight`` * squared distance outside ``bounds``
        (rad² + mm²); returns (value, gradient (3,), Hessian (3, 3)), zero inside the box."""
        lower, upper, weight = self.penalty_box()
        return _range_penalty(self._p(q), lower, upper, weight, np.eye(3))


class KinematicTerm(ParameterTerm):
    """Energy term ``phi_kin`` of a :class:`SlidingCondyleJaw` on the jaw frame ``x = q (12,)``
    (a :class:`~facesim.energy.ParameterTerm`; ``a`` ignored), for solvers that move the 12 affine
    coefficients; ``weights`` as in ``phi_kin``. The Hessian is PSD-projected by default."""

    def __init__(self, jaw: SlidingCondyleJaw, weights=None):
        self.jaw = jaw
        self.weights = None if weights is None else np.array(weights, dtype=np.float64)

    def evaluate(self, q, project: bool = True):
        return self.jaw.phi_kin(q, self.weights, project=project)


__all__ = ["KinematicTerm", "SlidingCondyleJaw"]
