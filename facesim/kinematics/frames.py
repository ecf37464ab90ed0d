"""Affine bone frames and the rigidity penalty (Sifakis 2005 section 8; docs/physics.md section 3).

A bone (cranium or jaw) is an affine frame ``x = M X + t`` stored as 12 coefficients
``q = (M row-major (9,), t (3,))``: ``q[3 i + j] = M[i, j]``, ``q[9 + i] = t[i]``. Node positions
attached to the bone are linear in ``q``, so a Gauss-Newton step in ``q`` moves them without the
distortion a linearised rotation would cause; rigidity is restored by the penalty
``||MᵀM − I||²_F`` instead. Sizes are tiny (12 coefficients), so everything here is plain numpy.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facesim._kernels.frames import rigidity_terms
from facesim.energy import ParameterTerm
from facesim.errors import FacesimError

N_FRAME = 12


def _frame(q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (N_FRAME,):
        raise FacesimError(f"frame: expected 12 affine coefficients (M row-major, t), got shape {q.shape}")
    return q


def identity_frame() -> np.ndarray:
    """``(12,)`` coefficients of the identity frame (M = I, t = 0)."""
    return matrix_to_frame(np.eye(4))


def frame_to_matrix(q) -> np.ndarray:
    """4x4 homogeneous matrix of the frame ``q (12,)`` (M dimensionless, t in mm)."""
    q = _frame(q)
    T = np.eye(4)
    T[:3, :3] = q[:9].reshape(3, 3)
    T[:3, 3] = q[9:]
    return T


def matrix_to_frame(T) -> np.ndarray:
    """``(12,)`` coefficients (M row-major, t mm) of a 4x4 (or 3x4) affine matrix ``T``."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape not in ((4, 4), (3, 4)):
        raise FacesimError(f"frame: expected a 4x4 or 3x4 affine matrix, got shape {T.shape}")
    return np.concatenate([T[:3, :3].ravel(), T[:3, 3]])


def attached_positions(X, q) -> np.ndarray:
    """Positions ``(k, 3)`` mm of points ``X (k, 3)`` mm attached to the frame ``q (12,)``: X Mᵀ + t."""
    q = _frame(q)
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    return X @ q[:9].reshape(3, 3).T + q[9:]


def attached_jacobian(X) -> sp.csr_matrix:
    """Constant Jacobian ``(3k, 12)`` of ``attached_positions(X, q).ravel()`` with respect to ``q``.

    Row ``3 a + i`` (point a, coordinate i) holds ``X[a]`` in columns ``3 i .. 3 i + 2`` (the M
    row i) and 1 in column ``9 + i`` (t_i); units mm per coefficient for M, 1 for t.
    """
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    k = len(X)
    rows = np.repeat(np.arange(3 * k), 4)
    i = np.tile(np.arange(3), k)                                    # coordinate of each row
    cols = np.stack([3 * i, 3 * i + 1, 3 * i + 2, 9 + i], axis=1).ravel()
    vals = np.concatenate([np.repeat(X, 3, axis=0), np.ones((3 * k, 1))], axis=1).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * k, N_FRAME))


def psd_project(H) -> np.ndarray:
    """Nearest positive semi-definite matrix to the symmetric ``H (k, k)``: eigenvalues clamped at 0."""
    H = np.asarray(H, dtype=np.float64)
    H = 0.5 * (H + H.T)
    lam, V = np.linalg.eigh(H)
    if lam[0] >= 0.0:
        return H
    return (V * np.maximum(lam, 0.0)) @ V.T


def rigidity_penalty(q, project: bool = False):
    """``||MᵀM − I||²_F`` of the frame ``q (12,)`` with its gradient ``(12,)`` and Hessian ``(12, 12)``.

    With C = MᵀM − I (symmetric): dE/dM = 4 M C and
    d²E/dM_ij dM_ab = 4 (δ_ia C_bj + M_ib M_aj + δ_jb (M Mᵀ)_ia); t does not enter. The Hessian is
    indefinite away from rotations, so ``project=True`` clamps its negative eigenvalues (a PSD
    matrix for Newton / Gauss-Newton); the default is the exact Hessian. Dimensionless.
    """
    q = _frame(q)
    grad = np.zeros(N_FRAME)
    H9 = np.empty((9, 9))
    value = float(rigidity_terms(np.ascontiguousarray(q[:9].reshape(3, 3)), bool(project), grad[:9], H9))
    hess = np.zeros((N_FRAME, N_FRAME))
    hess[:9, :9] = H9
    return value, grad, hess


class RigidityTerm(ParameterTerm):
    """Energy term ``weight * ||MᵀM − I||²_F`` on a frame ``x = q (12,)`` (a
    :class:`~facesim.energy.ParameterTerm`; ``a`` ignored); ``weight`` in the energy's units.

    ``hessian`` is PSD-projected by default (what the solver wants); pass ``project=False`` for
    the exact one.
    """

    def __init__(self, weight: float = 1.0):
        self.weight = float(weight)
        if not self.weight >= 0:
            raise FacesimError(f"RigidityTerm: expected weight >= 0, got {weight}")

    def evaluate(self, q, project: bool = True):
        value, grad, hess = rigidity_penalty(q, project=project)
        return self.weight * value, self.weight * grad, self.weight * hess


__all__ = [
    "N_FRAME",
    "RigidityTerm",
    "attached_jacobian",
    "attached_positions",
    "frame_to_matrix",
    "identity_frame",
    "matrix_to_frame",
    "psd_project",
    "rigidity_penalty",
]
