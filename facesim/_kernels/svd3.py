"""Rotation-variant SVD of a 3x3 matrix for invertible finite elements.

``F = U diag(s) V^T`` with ``U`` and ``V`` proper rotations (det +1), ``s[0] >= s[1] >= |s[2]|``
and ``s[2] < 0`` exactly when ``det F < 0`` (Irving, Teran, Fedkiw 2004). Computed as in
McAdams et al. 2011: Jacobi eigen-decomposition of ``F^T F`` gives ``V``; the columns of
``F V`` are orthogonalised (Gram-Schmidt, third column by cross product) to give ``U`` and the
signed singular values. No LAPACK call, no allocation: a few hundred flops per element.
"""

import math

from numba import njit

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def _sym_eig3(A, V, w):
    """Cyclic Jacobi on the symmetric 3x3 ``A`` (overwritten): eigenvectors in the columns of ``V``,
    eigenvalues in ``w``."""
    for i in range(3):
        for j in range(3):
            V[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(30):
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        scale = A[0, 0] * A[0, 0] + A[1, 1] * A[1, 1] + A[2, 2] * A[2, 2]
        if off <= 1e-32 * scale or off == 0.0:   # off-diagonal below 1e-16 of the diagonal
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = A[p, q]
            if apq == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * apq)
            t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp = A[k, p]
                akq = A[k, q]
                A[k, p] = c * akp - s * akq
                A[k, q] = s * akp + c * akq
            for k in range(3):
                apk = A[p, k]
                aqk = A[q, k]
                A[p, k] = c * apk - s * aqk
                A[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp = V[k, p]
                vkq = V[k, q]
                V[k, p] = c * vkp - s * vkq
                V[k, q] = s * vkp + c * vkq
    for i in range(3):
        w[i] = A[i, i]


@njit(**JIT_FLAGS)
def _any_orthogonal(a, out):
    """A unit vector orthogonal to the unit vector ``a``."""
    if abs(a[0]) < 0.6:
        bx, by, bz = 0.0, a[2], -a[1]
    else:
        bx, by, bz = -a[2], 0.0, a[0]
    n = math.sqrt(bx * bx + by * by + bz * bz)
    out[0] = bx / n
    out[1] = by / n
    out[2] = bz / n


#: scratch rows :func:`svd3` needs in ``W (rows, 3)``
SVD_ROWS = 9


@njit(**JIT_FLAGS)
def svd3(F, U, s, V, W):
    """Signed SVD of ``F`` (3, 3) into ``U`` (3, 3), ``s`` (3,), ``V`` (3, 3), all preallocated;
    ``W (>= SVD_ROWS, 3)`` scratch (no allocation in the element loops, no reshaped views)."""
    A = W[0:3]
    w = W[3]
    B = W[4:7]
    u1 = W[7]
    u2 = W[8]
    for i in range(3):
        for j in range(3):
            A[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    _sym_eig3(A, V, w)
    # sort eigenpairs descending
    for i in range(3):
        k = i
        for j in range(i + 1, 3):
            if w[j] > w[k]:
                k = j
        if k != i:
            w[i], w[k] = w[k], w[i]
            for r in range(3):
                V[r, i], V[r, k] = V[r, k], V[r, i]
    # V a proper rotation
    det = (V[0, 0] * (V[1, 1] * V[2, 2] - V[1, 2] * V[2, 1]) - V[0, 1] * (V[1, 0] * V[2, 2] - V[1, 2] * V[2, 0])
           + V[0, 2] * (V[1, 0] * V[2, 1] - V[1, 1] * V[2, 0]))
    if det < 0.0:
        for r in range(3):
            V[r, 2] = -V[r, 2]
    for i in range(3):
        for j in range(3):
            B[i, j] = F[i, 0] * V[0, j] + F[i, 1] * V[1, j] + F[i, 2] * V[2, j]
    n1 = math.sqrt(B[0, 0] ** 2 + B[1, 0] ** 2 + B[2, 0] ** 2)
    if n1 > 1e-300:
        for r in range(3):
            u1[r] = B[r, 0] / n1
    else:
        u1[0], u1[1], u1[2] = 1.0, 0.0, 0.0
    d = u1[0] * B[0, 1] + u1[1] * B[1, 1] + u1[2] * B[2, 1]
    for r in range(3):
        u2[r] = B[r, 1] - d * u1[r]
    n2 = math.sqrt(u2[0] ** 2 + u2[1] ** 2 + u2[2] ** 2)
    if n2 > 1e-12 * max(n1, 1e-300):
        for r in range(3):
            u2[r] /= n2
    else:
        _any_orthogonal(u1, u2)
    u3x = u1[1] * u2[2] - u1[2] * u2[1]
    u3y = u1[2] * u2[0] - u1[0] * u2[2]
    u3z = u1[0] * u2[1] - u1[1] * u2[0]
    for r in range(3):
        U[r, 0] = u1[r]
        U[r, 1] = u2[r]
    U[0, 2], U[1, 2], U[2, 2] = u3x, u3y, u3z
    s[0] = n1
    s[1] = u2[0] * B[0, 1] + u2[1] * B[1, 1] + u2[2] * B[2, 1]
    s[2] = u3x * B[0, 2] + u3y * B[1, 2] + u3z * B[2, 2]
