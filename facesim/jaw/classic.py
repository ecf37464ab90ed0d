"""Traditional jaw rigs: rotations about a pivot, then a translation (Zoss et al. 2018 eq. 1).

In the jaw frame (:mod:`facesim.jaw.frame`: x left, y up, z forward) a rig with pivot ``o`` maps
a mandible point x to ``R (x − o) + o + t`` with ``R = R_y(yaw) R_x(pitch) R_z(roll)``; the
variants keep some of the six parameters (``DOF``)::

    1dof  pitch                          (opening hinge)
    3dof  pitch, yaw, tz                 (the usual animation rig: two rotations + forward slide)
    5dof  pitch, yaw, tx, ty, tz         (all translations, no roll)
    6dof  pitch, yaw, roll, tx, ty, tz   (any rigid pose)

Angles in rad, translations in mm. Fitting (Zoss eqs. 6-8): for a fixed pivot, each captured
pose gets the parameters minimising the weighted mean squared distance of the mandible points
(eq. 6, solved for all frames at once by a batched Levenberg-Marquardt); the pivot itself
minimises the sum of those optimal costs plus a soft-L1 penalty on its offset from a prior pivot
(eqs. 7-8), by ``scipy.optimize.least_squares`` on the variable-projection residual (the
per-frame parameters are eliminated; Golub & Pereyra 1973, Kaufman's Jacobian). With all three
translations (5dof, 6dof) the pivot is redundant and stays at the prior.

The point cost is exact and cheap: for D = T_rig − T_data (3x4) and the weighted second-moment
matrix S = Σ w_j x̃_j x̃_jᵀ / Σ w_j = L Lᵀ of the homogeneous points x̃, Σ w_j |D x̃_j|² / Σ w_j =
|D L|²_F, twelve residuals per frame whatever the number of points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw._lm import levenberg_marquardt
from facesim.jaw.frame import JawFrame
from facesim.jaw.points import second_moment_factor
from facesim.jaw.rigfile import load_rig, save_rig

PARAMETERS = ("pitch", "yaw", "roll", "tx", "ty", "tz")
DOF = {
    "1dof": ("pitch",),
    "3dof": ("pitch", "yaw", "tz"),
    "5dof": ("pitch", "yaw", "tx", "ty", "tz"),
    "6dof": ("pitch", "yaw", "roll", "tx", "ty", "tz"),
}
_AXIS = {"pitch": 0, "yaw": 1, "roll": 2}


def _elementary(angle, axis: int):
    """Rotations ``(N, 3, 3)`` by ``angle (N,)`` rad about coordinate ``axis``."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.zeros(angle.shape + (3, 3))
    R[..., axis, axis] = 1.0
    R[..., i, i], R[..., j, j], R[..., i, j], R[..., j, i] = c, c, -s, s
    return R


_K = se3.hat(np.eye(3))          # generators: d/dθ R_a(θ) = R_a(θ) K_a


def _rotations(angles):
    """R = R_y(yaw) R_x(pitch) R_z(roll) ``(N, 3, 3)`` and its three partials ``(3, N, 3, 3)``
    for ``angles (N, 3)`` = (pitch, yaw, roll) rad."""
    Rx, Ry, Rz = (_elementary(angles[:, k], k) for k in range(3))
    RyRx = Ry @ Rx
    R = RyRx @ Rz
    return R, np.stack([RyRx @ _K[0] @ Rz, Ry @ _K[1] @ Rx @ Rz, R @ _K[2]])


@dataclass(frozen=True)
class ClassicRig:
    """A traditional rig of Zoss eq. 1.

    dof : one of ``DOF`` ("1dof", "3dof", "5dof", "6dof").
    frame : JawFrame, the axes of the rotations and translations.
    origin : (3,) mm, the pivot in the jaw frame.
    bounds : (k, 2) [lower, upper] per parameter (rad, mm), default unbounded; ``fit_classic``
        sets the range of the fitted training parameters (the controls' range as a jaw model).

    ``q (..., k)`` are the ``names`` parameters (rad, mm); ``transform(q)`` gives poses
    ``(..., 4, 4)`` in the skull frame (mandible relative to skull, mm).
    """

    dof: str
    frame: JawFrame
    origin: np.ndarray
    bounds: np.ndarray | None = None

    def __post_init__(self):
        if self.dof not in DOF:
            raise FacesimError(f"classic rig: unknown dof {self.dof!r} (expected one of {', '.join(DOF)})")
        se3.check_rigid(se3.from_rt(self.frame.axes, self.frame.origin),
                        "classic rig: jaw frame (fields 'frame_origin', 'frame_axes')")
        origin = np.array(self.origin, dtype=np.float64)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise FacesimError("classic rig: expected a finite pivot origin (3,) mm")
        origin.setflags(write=False)
        object.__setattr__(self, "origin", origin)
        k = len(DOF[self.dof])
        bounds = np.tile([-np.inf, np.inf], (k, 1)) if self.bounds is None else np.array(self.bounds, dtype=np.float64)
        if bounds.shape != (k, 2) or np.isnan(bounds).any() or (bounds[:, 0] > bounds[:, 1]).any():
            raise FacesimError(f"classic rig: expected bounds ({k}, 2) with lower <= upper")
        bounds.setflags(write=False)
        object.__setattr__(self, "bounds", bounds)

    @property
    def names(self) -> tuple[str, ...]:
        return DOF[self.dof]

    @property
    def n_params(self) -> int:
        return len(self.names)

    def _full(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.shape[-1:] != (self.n_params,) or not np.isfinite(q).all():
            raise FacesimError(f"{self.dof} rig: expected (..., {self.n_params}) finite parameters "
                               f"{self.names}, got shape {q.shape}")
        full = np.zeros(q.shape[:-1] + (6,))
        full[..., [PARAMETERS.index(n) for n in self.names]] = q
        return full

    def _local(self, full: np.ndarray, origin=None):
        """Local poses (N, 4, 4) and their partials (6, N, 4, 4) w.r.t. all six parameters."""
        o = self.origin if origin is None else origin
        R, dR = _rotations(full[:, :3])
        T = se3.from_rt(R, full[:, 3:] + o - R @ o)
        dT = np.zeros((6,) + T.shape)
        dT[:3, :, :3, :3] = dR
        dT[:3, :, :3, 3] = -dR @ o
        for j in range(3):
            dT[3 + j, :, j, 3] = 1.0
        return T, dT

    def transform(self, q) -> np.ndarray:
        """Poses ``(..., 4, 4)`` (skull frame, mm) of the parameters ``q (..., k)``."""
        full = self._full(q)
        T, _ = self._local(full.reshape(-1, 6))
        return self.frame.pose_to_world(T).reshape(full.shape[:-1] + (4, 4))

    def fit_parameters(self, poses, points, weights=None, q0=None) -> np.ndarray:
        """Per-frame parameters ``(N, k)`` of the rig poses closest to ``poses (N, 4, 4)`` (skull
        frame) in the weighted mean squared distance of ``points (P, 3)`` mm (skull frame, the
        mandible at rest) with ``weights (P,)`` (Zoss eq. 6)."""
        poses = se3.check_poses(poses)
        L = second_moment_factor(self.frame.to_local(points), weights)
        return _fit_frames(self, self.frame.pose_to_local(poses), L, self.origin, q0)[0]

    def reproduce(self, poses, points, weights=None) -> np.ndarray:
        """The rig's best approximation ``(N, 4, 4)`` of ``poses (N, 4, 4)`` (``fit_parameters``)."""
        return self.transform(self.fit_parameters(poses, points, weights))

    def save(self, path):
        """Write the rig to a versioned ``.npz`` (see :mod:`facesim.jaw.rigfile`)."""
        return save_rig(path, "classic", {"origin": self.origin, "bounds": self.bounds,
                                          "frame_origin": self.frame.origin, "frame_axes": self.frame.axes},
                        {"dof": self.dof})

    @staticmethod
    def load(path) -> ClassicRig:
        """Read a rig written by :meth:`save` (one-line errors naming the file and field)."""
        arrays, meta = load_rig(path, "classic", ("origin", "bounds", "frame_origin", "frame_axes"), ("dof",))
        try:
            return ClassicRig(meta["dof"], JawFrame(arrays["frame_origin"], arrays["frame_axes"]), arrays["origin"],
                              arrays["bounds"])
        except FacesimError as exc:
            raise ModelFileError(path, str(exc)) from None
        except (TypeError, ValueError) as exc:      # strings where numbers belong
            raise ModelFileError(path, f"unreadable classic rig data ({type(exc).__name__}: {exc})") from None


def _initial(rig: ClassicRig, local: np.ndarray, origin) -> np.ndarray:
    """Parameters read off the local poses: Y-X-Z Euler angles and t = t_data − o + R o."""
    yaw, pitch, roll = Rotation.from_matrix(local[:, :3, :3]).as_euler("YXZ").T
    full = np.stack([pitch, yaw, roll], axis=1)
    R, _ = _rotations(full)
    full = np.concatenate([full, local[:, :3, 3] - origin + R @ origin], axis=1)
    return full[:, [PARAMETERS.index(n) for n in rig.names]]


def _residuals(rig, q, local, L, origin):
    """Residuals (N, 12), Jacobian w.r.t. q (N, 12, k), and the local rig poses (N, 4, 4)."""
    T, dT = rig._local(rig._full(q), origin)
    r = ((T - local)[:, :3] @ L).reshape(len(q), 12)
    cols = [PARAMETERS.index(n) for n in rig.names]
    J = (dT[cols][:, :, :3] @ L).reshape(len(cols), len(q), 12).transpose(1, 2, 0)
    return r, J, T


def _fit_frames(rig: ClassicRig, local, L, origin, q0=None, iterations: int = 60):
    """Batched Levenberg-Marquardt of eq. 6 for every frame: (q (N, k), r (N, 12), J (N, 12, k), T).
    Frames whose step has fallen below 1e-10 (rad or mm), or whose cost no longer falls above
    round-off, drop out of the iteration."""
    q = _initial(rig, local, origin) if q0 is None else q0
    # the initial guesses are close: start near Gauss-Newton
    return levenberg_marquardt(lambda q, rows: _residuals(rig, q, local[rows], L, origin), q, iterations,
                               mu=1e-6, floor=1e-9, accept_ties=True, stall=1e-13)


@dataclass(frozen=True)
class ClassicFit:
    """Result of :func:`fit_classic`: the ``rig``, the per-frame parameters ``q (N, k)`` and the
    final ``cost`` (mean weighted squared point distance, mm², without the regulariser)."""

    rig: ClassicRig
    q: np.ndarray
    cost: float


def pivot_estimate(local_poses) -> np.ndarray:
    """``(3,)`` mm, the point closest (least squares, weighted by rotation angle²) to the screw
    axes of ``local_poses (N, 4, 4)``, with a small pull toward the frame's midsagittal plane for the
    direction along which the axes are parallel: a data-driven prior for the pivot."""
    xi = se3.log(local_poses)
    w, v = xi[:, :3], xi[:, 3:]
    angle2 = np.einsum("ij,ij->i", w, w)
    keep = angle2 > 1e-8
    if not keep.any():
        return np.zeros(3)
    w, v, angle2 = w[keep], v[keep], angle2[keep]
    a = np.cross(w, v) / angle2[:, None]                         # a point of each screw axis
    n = w / np.sqrt(angle2)[:, None]
    P = np.eye(3) - n[:, :, None] * n[:, None, :]
    A = np.einsum("n,nij->ij", angle2, P)
    b = np.einsum("n,nij,nj->i", angle2, P, a)
    ridge = 1e-6 * np.trace(A)
    return np.linalg.solve(A + ridge * np.eye(3), b)


def fit_classic(poses, dof: str, frame: JawFrame, points, weights=None, origin0=None,
                regularization: float = 0.01, scale: float = 10.0, optimise_origin: bool = True) -> ClassicFit:
    """Fit the ``dof`` rig to ``poses (N, 4, 4)`` (skull frame, mm) with its pivot optimised.

    points : (P, 3) mm, the mandible at rest (skull frame); weights : (P,) >= 0 (default uniform).
    origin0 : (3,) mm prior pivot in the jaw frame (default ``pivot_estimate`` of the poses).
    regularization, scale : the soft-L1 penalty ``regularization · scale² · rho(|o − o0|² / scale²)``
        (mm², rho(z) = 2 (sqrt(1 + z) − 1)) added to the mean squared point distance (Zoss eq. 8).
    """
    poses = se3.check_poses(poses)
    if dof not in DOF:
        raise FacesimError(f"classic rig: unknown dof {dof!r} (expected one of {', '.join(DOF)})")
    if not regularization >= 0 or not scale > 0:
        raise FacesimError("classic rig: expected regularization >= 0 and scale > 0 mm")
    local = frame.pose_to_local(poses)
    L = second_moment_factor(frame.to_local(points), weights)
    o0 = pivot_estimate(local) if origin0 is None else np.asarray(origin0, dtype=np.float64)
    rig = ClassicRig(dof, frame, o0)
    n = len(poses)
    redundant = {"tx", "ty", "tz"} <= set(DOF[dof])
    state = {"q": None, "o": None}

    def inner(o):
        # the Jacobian is asked for at the point just evaluated: solve once per pivot
        if state["o"] is None or not np.array_equal(state["o"], o):
            state["fit"] = _fit_frames(rig, local, L, o, state["q"])
            state["q"], state["o"] = state["fit"][0], np.array(o)
        return state["fit"]

    def residual(o):
        r = inner(o)[1]
        z = np.sum((o - o0) ** 2) / scale**2
        reg = np.sqrt(regularization) * (o - o0) * np.sqrt(2 * (np.sqrt(1 + z) - 1) / z if z > 1e-12 else 1.0)
        return np.concatenate([r.ravel() / np.sqrt(n), reg])

    def jacobian(o):
        _, _, J, T = inner(o)
        # ∂r/∂o through t = o + t' − R o, projected off the span of ∂r/∂q (variable projection)
        R = T[:, :3, :3]
        dT = np.zeros((3, n, 3, 4))
        dT[..., 3] = np.eye(3)[:, None, :] - np.moveaxis(R, 2, 0)
        Jo = (dT @ L).reshape(3, n, 12).transpose(1, 2, 0)
        H = np.einsum("nij,nil->njl", J, J) + 1e-12 * np.eye(rig.n_params)
        Jo = Jo - J @ np.linalg.solve(H, np.einsum("nij,nil->njl", J, Jo))
        z = np.sum((o - o0) ** 2) / scale**2
        # derivative of the regulariser residual e = sqrt(lam) g(z) (o − o0), g = sqrt(rho(z)/z)
        if z > 1e-12:
            rho = 2 * (np.sqrt(1 + z) - 1)
            g = np.sqrt(rho / z)
            dg_dz = 0.5 / g * ((1 / np.sqrt(1 + z)) * z - rho) / z**2
        else:
            g, dg_dz = 1.0, -0.125
        dz = 2 * (o - o0) / scale**2
        Jreg = np.sqrt(regularization) * (g * np.eye(3) + np.outer(o - o0, dg_dz * dz))
        return np.concatenate([Jo.reshape(-1, 3) / np.sqrt(n), Jreg])

    if optimise_origin and not redundant:
        sol = least_squares(residual, o0, jac=jacobian, method="trf", x_scale=scale, xtol=1e-7, ftol=1e-9)
        origin = sol.x
    else:
        origin = o0
    q, r, _, _ = _fit_frames(ClassicRig(dof, frame, origin), local, L, origin, state["q"])
    rig = ClassicRig(dof, frame, origin, np.stack([q.min(axis=0), q.max(axis=0)], axis=1))
    return ClassicFit(rig=rig, q=q, cost=float(np.einsum("ij,ij->", r, r) / n))


__all__ = ["DOF", "PARAMETERS", "ClassicFit", "ClassicRig", "fit_classic", "pivot_estimate"]
