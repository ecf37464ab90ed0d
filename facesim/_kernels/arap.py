"""Kernels of the as-rigid-as-possible refinement of a starting guess (facesim.fem.equilibrium,
``FaceSimulator.predict``): per-node best rotations of the 1-ring edges (Sorkine & Alexa 2007,
"As-rigid-as-possible surface modeling", eqs. 5-9, on the tet mesh's edge graph) and the
right-hand side of the global step. Edges ``e (k, 2)`` int64, weights ``w (k,)``."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def edge_covariances(X, x, e, w, S):
    """``S (n, 3, 3)`` = sum over the edges (i, j) at node i of ``w (X_i - X_j)(x_i - x_j)^T``."""
    S[:] = 0.0
    for k in range(e.shape[0]):
        i, j = e[k, 0], e[k, 1]
        for a in range(3):
            d0 = w[k] * (X[i, a] - X[j, a])
            for b in range(3):
                c = d0 * (x[i, b] - x[j, b])
                S[i, a, b] += c
                S[j, a, b] += c


@njit(parallel=True, **JIT_FLAGS)
def best_rotations(S, R):
    """``R (n, 3, 3)``: the proper rotation maximising ``tr(R S)`` per node (``R = V U^T`` of
    ``S = U Σ V^T``, the last column of V negated when that reflects)."""
    for i in prange(S.shape[0]):
        U, s, Vt = np.linalg.svd(S[i])
        V = Vt.T.copy()
        r = V @ U.T
        if np.linalg.det(r) < 0:
            V[:, 2] = -V[:, 2]
            r = V @ U.T
        R[i] = r


@njit(**JIT_FLAGS)
def rotated_edges_rhs(X, R, e, w, b):
    """``b (n, 3)`` = sum over the edges (i, j) of ``± w (R_i + R_j)/2 (X_i - X_j)`` (the global
    step's right-hand side: + at i, - at j)."""
    b[:] = 0.0
    for k in range(e.shape[0]):
        i, j = e[k, 0], e[k, 1]
        for a in range(3):
            v = 0.0
            for c in range(3):
                v += 0.5 * (R[i, a, c] + R[j, a, c]) * (X[i, c] - X[j, c])
            b[i, a] += w[k] * v
            b[j, a] -= w[k] * v
