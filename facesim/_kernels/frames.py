"""Kernel of the affine frames' rigidity penalty ``||MᵀM − I||²_F`` (facesim.kinematics.frames).

The inverse solver's penalty schedule evaluates it hundreds of times per Gauss-Newton step (once
per nested Newton step, for the jaw frame and the head frame): in numpy its three einsums and an
eigendecomposition cost ~50 us a call, here ~2 us.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def rigidity_terms(M, project, grad, hess):
    """``||MᵀM − I||²_F`` of ``M (3, 3)``; writes dE/dM (row-major) into ``grad (9,)`` and the
    Hessian ``d²E/dM_ij dM_ab`` into ``hess (9, 9)`` (index ``3 i + j``), PSD-projected (negative
    eigenvalues clamped at 0) when ``project``. With C = MᵀM − I: dE/dM = 4 M C and
    d²E/dM_ij dM_ab = 4 (δ_ia C_bj + M_ib M_aj + δ_jb (M Mᵀ)_ia). Returns the value."""
    C = M.T @ M
    for k in range(3):
        C[k, k] -= 1.0
    MMt = M @ M.T
    G = 4.0 * (M @ C)
    value = 0.0
    for i in range(3):
        for j in range(3):
            value += C[i, j] * C[i, j]
            grad[3 * i + j] = G[i, j]
    for i in range(3):
        for j in range(3):
            for a in range(3):
                for b in range(3):
                    h = M[i, b] * M[a, j]
                    if i == a:
                        h += C[b, j]
                    if j == b:
                        h += MMt[i, a]
                    hess[3 * i + j, 3 * a + b] = 4.0 * h
    if project:
        for r in range(9):   # symmetric to round-off; symmetrise before the eigendecomposition
            for c in range(r + 1, 9):
                s = 0.5 * (hess[r, c] + hess[c, r])
                hess[r, c] = s
                hess[c, r] = s
        lam, V = np.linalg.eigh(hess)
        if lam[0] < 0.0:
            for k in range(9):
                if lam[k] < 0.0:
                    lam[k] = 0.0
            hess[:, :] = (V * lam) @ V.T
    return value
