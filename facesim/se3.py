"""Rigid motions: the log and exp maps of SE(3), rigid (Kabsch) and similarity (Umeyama) fits,
errors and interpolation. The bottom of the import graph (numpy, scipy and facesim.errors only):
the jaw rigs, the bone frames, the solver's bone predictor and the head stabilisation all use it.

A pose is a 4x4 homogeneous transform ``T = [[R, t], [0, 1]]`` (R a rotation, t in mm); a twist
is the 6-vector ``xi = (omega, v)``: ``omega`` (rad) the rotation vector, ``v`` (mm) the
translational part, with ``T = exp(xi)`` (Murray, Li & Sastry 1994, ch. 2; Yang et al. 2018 work
with jaw poses in this se(3) chart). The maps take one item or a batch: ``xi (6,)`` or
``(..., 6)``, ``T (4, 4)`` or ``(..., 4, 4)``.

Closed forms, with theta = |omega| and K = hat(omega)::

    R     = I + A K + B K²                      A = sin θ / θ, B = (1 − cos θ) / θ²
    t     = V v,   V = I + B K + C K²           C = (θ − sin θ) / θ³
    V⁻¹   = I − K / 2 + D K²                    D = (1 − (θ/2) cot(θ/2)) / θ²

A, B, C, D switch to their Taylor series below ``_SMALL`` rad, so both maps keep full precision
at and near the identity. The rotation log reads the angle with atan2 (accurate everywhere) and,
past 90 degrees, the axis from the symmetric part of R (R + Rᵀ)/2 − cos θ I = (1 − cos θ) n nᵀ,
so it stays exact up to and at a half turn, where the skew part vanishes.
"""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError

_SMALL = 1e-2      # rad: below this the coefficient series (to θ⁴) are exact to double precision


def _array(a, tail: tuple[int, ...], what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim < len(tail) or a.shape[a.ndim - len(tail):] != tail:
        raise FacesimError(f"{what}: expected shape {tail} or (n, {', '.join(map(str, tail))}), got {a.shape}")
    if not np.isfinite(a).all():
        raise FacesimError(f"{what}: expected finite values")
    return a


def hat(omega) -> np.ndarray:
    """Skew matrices ``(..., 3, 3)`` of ``omega (..., 3)``: ``hat(omega) @ x = omega × x``."""
    w = np.asarray(omega, dtype=np.float64)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return K


def vee(K) -> np.ndarray:
    """``(..., 3)`` axial vectors of the skew parts of ``K (..., 3, 3)`` (inverse of ``hat``)."""
    K = np.asarray(K, dtype=np.float64)
    return 0.5 * np.stack([K[..., 2, 1] - K[..., 1, 2], K[..., 0, 2] - K[..., 2, 0],
                           K[..., 1, 0] - K[..., 0, 1]], axis=-1)


def _coefficients(theta: np.ndarray):
    """A, B, C, D of the module docstring for angles ``theta (...)`` rad, series below _SMALL."""
    small = theta < _SMALL
    t = np.where(small, 1.0, theta)                  # placeholder keeps the closed forms finite
    t2 = theta * theta
    A = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    B = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / (t * t))
    C = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / t**3)
    half = 0.5 * t
    D = np.where(small, 1 / 12 + t2 / 720 + t2 * t2 / 30240, (1 - half * np.cos(half) / np.sin(half)) / (t * t))
    return A, B, C, D


def so3_exp(omega) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of rotation vectors ``omega (..., 3)`` rad (Rodrigues)."""
    w = _array(omega, (3,), "rotation vector")
    A, B, _, _ = _coefficients(np.linalg.norm(w, axis=-1))
    K = hat(w)
    return np.eye(3) + A[..., None, None] * K + B[..., None, None] * (K @ K)


def so3_log(R) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` rad, |omega| <= pi, of rotation matrices ``R (..., 3, 3)``.

    At exactly a half turn omega and −omega are the same rotation; either may be returned.
    """
    R = _array(R, (3, 3), "rotation matrix")
    s = vee(R)                                               # sin θ n
    sin = np.linalg.norm(s, axis=-1)
    cos = np.clip(0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0), -1.0, 1.0)
    theta = np.arctan2(sin, cos)
    t2 = theta * theta
    # regular branch: omega = θ / sin θ · s
    ratio = np.where(theta < _SMALL, 1 + t2 / 6 + 7 * t2 * t2 / 360, theta / np.where(sin > 0, sin, 1.0))
    omega = ratio[..., None] * s
    wide = cos < 0.0
    if np.any(wide):
        # axis from the symmetric part, (1 − cos θ) n nᵀ, then oriented along sin θ n
        Rw, cw, sw = R[wide], cos[wide], s[wide]
        Bm = 0.5 * (Rw + np.swapaxes(Rw, -1, -2)) - cw[:, None, None] * np.eye(3)
        k = np.argmax(np.diagonal(Bm, axis1=-2, axis2=-1), axis=-1)
        n = Bm[np.arange(len(k)), :, k]
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        n *= np.where(np.einsum("ij,ij->i", n, sw) < 0, -1.0, 1.0)[:, None]
        omega[wide] = theta[wide][:, None] * n
    return omega


def exp(xi) -> np.ndarray:
    """Poses ``(..., 4, 4)`` of twists ``xi (..., 6) = (omega rad, v mm)``."""
    xi = _array(xi, (6,), "twist")
    w, v = xi[..., :3], xi[..., 3:]
    A, B, C, _ = _coefficients(np.linalg.norm(w, axis=-1))
    K = hat(w)
    K2 = K @ K
    T = np.zeros(xi.shape[:-1] + (4, 4))
    T[..., :3, :3] = np.eye(3) + A[..., None, None] * K + B[..., None, None] * K2
    V = np.eye(3) + B[..., None, None] * K + C[..., None, None] * K2
    T[..., :3, 3] = np.einsum("...ij,...j->...i", V, v)
    T[..., 3, 3] = 1.0
    return T


def log(T) -> np.ndarray:
    """Twists ``(..., 6) = (omega rad, v mm)`` of poses ``T (..., 4, 4)``, |omega| <= pi."""
    T = _array(T, (4, 4), "pose")
    w = so3_log(T[..., :3, :3])
    _, _, _, D = _coefficients(np.linalg.norm(w, axis=-1))
    K = hat(w)
    Vinv = np.eye(3) - 0.5 * K + D[..., None, None] * (K @ K)
    return np.concatenate([w, np.einsum("...ij,...j->...i", Vinv, T[..., :3, 3])], axis=-1)


def inverse(T) -> np.ndarray:
    """Inverses ``(..., 4, 4)`` of rigid poses ``T (..., 4, 4)`` (uses Rᵀ: T must be rigid)."""
    T = _array(T, (4, 4), "pose")
    Ti = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    Ti[..., :3, :3] = Rt
    Ti[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    Ti[..., 3, 3] = 1.0
    return Ti


def from_rt(R, t) -> np.ndarray:
    """Poses ``(..., 4, 4)`` from rotations ``R (..., 3, 3)`` and translations ``t (..., 3)`` mm."""
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def transform_points(T, X) -> np.ndarray:
    """Points ``X (k, 3)`` mm moved by poses ``T (..., 4, 4)``: ``(..., k, 3)`` mm."""
    T = np.asarray(T, dtype=np.float64)
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    return np.swapaxes(T[..., :3, :3] @ X.T + T[..., :3, 3:], -1, -2)


def _departures(T: np.ndarray):
    """``(ortho, det R, row)`` per pose of ``T (..., 4, 4)``: max |RᵀR − I|, det R and
    max |last row − (0, 0, 0, 1)|."""
    R = T[..., :3, :3]
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-2, -1))
    row = np.abs(T[..., 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=-1)
    return ortho, np.linalg.det(R), row


def rigidity_error(T) -> np.ndarray:
    """``(...)`` departure of ``T (..., 4, 4)`` from a proper rigid motion:
    max(|RᵀR − I|, |det R − 1|, |last row − (0, 0, 0, 1)|), dimensionless."""
    ortho, det, row = _departures(_array(T, (4, 4), "pose"))
    return np.maximum(np.maximum(ortho, np.abs(det - 1.0)), row)


#: how far a pose read from a file or given to a rig may depart from a proper rigid motion
#: (max |RᵀR − I| and |last row − (0, 0, 0, 1)|); float32 storage rounds rotations to ~1e-7
RIGID_TOLERANCE = 1e-6


def check_rigid(T, what: str = "pose", tolerance: float = RIGID_TOLERANCE) -> np.ndarray:
    """``T (4, 4)`` or ``(..., 4, 4)`` as float64 when every pose is a proper rigid motion: finite,
    R orthonormal within ``tolerance`` with det R = +1 (a rotation, not a reflection) and last row
    0 0 0 1 within ``tolerance``. Otherwise a one-line :class:`FacesimError` starting with ``what``
    (e.g. "P.npz: field 'poses'") that names the first bad pose and what is wrong with it.

    The one check of every pose and rig reader (poses files, rig frames, the rigs' pose inputs)."""
    T = np.asarray(T)
    if T.dtype.kind not in "biuf":
        raise FacesimError(f"{what}: expected 4x4 rigid transforms (numbers), got dtype {T.dtype}")
    T = T.astype(np.float64)
    if T.ndim < 2 or T.shape[-2:] != (4, 4):
        raise FacesimError(f"{what}: expected 4x4 rigid transforms, shape (4, 4) or (N, 4, 4), got {T.shape}")
    flat = T.reshape(-1, 4, 4)

    def refuse(bad: np.ndarray, expected: str, got) -> None:
        if bad.any():
            i = int(np.argmax(bad))
            at = "" if T.ndim == 2 else f" in pose {i} ({int(bad.sum()):,} of {len(flat):,} poses)"
            raise FacesimError(f"{what}: expected {expected}, got {got(i)}{at}")

    refuse(~np.isfinite(flat).all(axis=(1, 2)), "finite rigid transforms", lambda i: "NaN or inf entries")
    ortho, det, row = _departures(flat)
    refuse(~(row <= tolerance), f"rigid transforms with last row 0 0 0 1 (within {tolerance:g})",
           lambda i: f"last row {' '.join(f'{v:g}' for v in flat[i, 3])}")
    refuse(~(ortho <= tolerance), f"rigid transforms with an orthonormal rotation (|R^T R - I| <= {tolerance:g})",
           lambda i: f"|R^T R - I| = {ortho[i]:.3g}")
    refuse(det < 0, "rigid transforms with a rotation (det R = +1)", lambda i: f"a reflection (det R = {det[i]:.3g})")
    return T


def check_poses(poses, what: str = "poses", minimum: int = 1) -> np.ndarray:
    """``poses (N, 4, 4)`` float64 with N >= ``minimum``, each passing :func:`check_rigid`; one-line
    :class:`FacesimError` starting with ``what`` otherwise."""
    P = np.asarray(poses)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or len(P) < minimum:
        raise FacesimError(f"{what}: expected (N, 4, 4) rigid transforms with N >= {minimum}, got shape {P.shape}")
    return check_rigid(P, what)


def vertex_errors(T_a, T_b, points, weights=None) -> np.ndarray:
    """Per-pose weighted mean distance ``(...)`` mm between the mandible points ``points (k, 3)``
    mm moved by ``T_a (..., 4, 4)`` and by ``T_b (..., 4, 4)`` (Zoss et al. 2018's error):
    Σ_j w_j |T_a x_j − T_b x_j| / Σ_j w_j, ``weights (k,)`` >= 0 (default uniform)."""
    T_a, T_b = _array(T_a, (4, 4), "pose"), _array(T_b, (4, 4), "pose")
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(X)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(X),) or not (w >= 0).all() or not w.sum() > 0:
        raise FacesimError(f"weights: expected {len(X)} non-negative values with a positive sum")
    D = T_a[..., :3, :] - T_b[..., :3, :]
    diff = D[..., :3] @ X.T + D[..., 3:]                       # (..., 3, k): matmul, not einsum (BLAS)
    d = np.sqrt(np.einsum("...ik,...ik->...k", diff, diff))
    return d @ (w / w.sum())


def fit_rotation(P, Q) -> np.ndarray:
    """Rotations ``(..., 3, 3)`` R minimising Σ_j |R (p_j − p̄) − (q_j − q̄)|² for the point sets
    ``P (..., k, 3)`` and ``Q (..., k, 3)`` mm (broadcast against each other, k >= 1): the Kabsch
    (1976) fit, det R = +1. From the SVD U S Vᵀ of H = Σ_j (p_j − p̄)(q_j − q̄)ᵀ, R = V D Uᵀ with
    D = diag(1, 1, sign det(V Uᵀ))."""
    P, Q = np.asarray(P, dtype=np.float64), np.asarray(Q, dtype=np.float64)
    A = P - P.mean(axis=-2, keepdims=True)
    B = Q - Q.mean(axis=-2, keepdims=True)
    U, _, Vt = np.linalg.svd(np.swapaxes(A, -1, -2) @ B)
    V, Ut = np.swapaxes(Vt, -1, -2), np.swapaxes(U, -1, -2)
    D = np.broadcast_to(np.eye(3), V.shape).copy()
    D[..., 2, 2] = np.where(np.linalg.det(V @ Ut) < 0, -1.0, 1.0)
    return V @ D @ Ut


def rigid_fit(P, Q) -> np.ndarray:
    """4x4 rigid transform(s) ``(..., 4, 4)`` taking points ``P (..., k, 3)`` closest to ``Q (..., k,
    3)`` mm in least squares (broadcast against each other: one rest set onto a batch of frames;
    :func:`fit_rotation`, then the centroids); the identity if k = 0."""
    P, Q = np.asarray(P, dtype=np.float64), np.asarray(Q, dtype=np.float64)
    if P.shape[-2] == 0:
        return np.broadcast_to(np.eye(4), np.broadcast_shapes(P.shape[:-2], Q.shape[:-2]) + (4, 4)).copy()
    R = fit_rotation(P, Q)
    return from_rt(R, Q.mean(axis=-2) - np.einsum("...ij,...j->...i", R, P.mean(axis=-2)))


def similarity(source, target):
    """Least-squares similarity (Umeyama 1991) taking ``source (n, 3)`` onto ``target (n, 3)`` mm:
    (scale c, rotation Q (3, 3), translation b (3,) mm) with target ≈ c Q source + b. Q is the
    :func:`fit_rotation` of the two; c = tr(Q H) / Σ |x − x̄|², which is Umeyama's tr(D S) / σ²."""
    X, Y = np.asarray(source, dtype=np.float64), np.asarray(target, dtype=np.float64)
    mx, my = X.mean(axis=0), Y.mean(axis=0)
    Xc, Yc = X - mx, Y - my
    Q = fit_rotation(X, Y)
    var = (Xc * Xc).sum()
    c = float(np.trace(Q @ (Xc.T @ Yc)) / var) if var > 0 else 1.0
    return c, Q, my - c * Q @ mx


def interpolate_rigid(A, B, s: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Rigid 4x4 a fraction ``s`` of the way from ``A (4, 4)`` to ``B (4, 4)``: the rotation along
    the shortest arc (slerp), the image of ``centre (3,)`` mm (choose a point of the moving body)
    along the straight line. Unlike :func:`interpolate` (a screw at constant twist speed), a point
    of the body does not swing around a far-away axis."""
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    c = np.asarray(centre, dtype=np.float64)
    r = so3_log(B[:3, :3] @ A[:3, :3].T)
    R = so3_exp(s * r) @ A[:3, :3]
    p = (1 - s) * (A[:3, :3] @ c + A[:3, 3]) + s * (B[:3, :3] @ c + B[:3, 3])
    return from_rt(R, p - R @ c)


def interpolate(A, B, s) -> np.ndarray:
    """Geodesic from pose ``A (4, 4)`` to ``B (4, 4)``: ``A exp(s log(A⁻¹ B))`` at ``s`` (scalar ->
    (4, 4); (k,) -> (k, 4, 4)). A screw motion at constant twist speed; s = 0 gives A, s = 1 B."""
    A, B = _array(A, (4, 4), "pose"), _array(B, (4, 4), "pose")
    if A.shape != (4, 4) or B.shape != (4, 4):
        raise FacesimError("interpolate: expected two single 4x4 poses")
    xi = log(inverse(A) @ B)
    s = np.asarray(s, dtype=np.float64)
    return A @ exp(s[..., None] * xi)


__all__ = [
    "RIGID_TOLERANCE",
    "check_poses",
    "check_rigid",
    "exp",
    "fit_rotation",
    "from_rt",
    "hat",
    "interpolate",
    "interpolate_rigid",
    "inverse",
    "log",
    "rigid_fit",
    "rigidity_error",
    "similarity",
    "so3_exp",
    "so3_log",
    "transform_points",
    "vee",
    "vertex_errors",
]
