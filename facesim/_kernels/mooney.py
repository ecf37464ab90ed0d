"""Invertible Mooney-Rivlin flesh in principal stretches (docs/physics.md section 1).

    psi = c10 (I1_bar - 3) + c01 (I2_bar - 3) + psi_vol(J),
    psi_vol = (kappa/2) (ln J)^2  (``vol == 0``)  or  (kappa/2) (J - 1)^2  (``vol == 1``)

In the signed singular values s of F the isochoric invariants are sums of monomials,
I1_bar = sum_i s_i^(4/3) s_j^(-2/3) s_k^(-2/3) and I2_bar = sum_k s_i^(2/3) s_j^(2/3) s_k^(-4/3),
so derivatives of any order are closed forms. Inversion (Teran et al. 2005): singular values
below ``eps`` are clamped, and psi is continued below the clamp to first order,

    psi~(s) = psi(s^) + sum_{c clamped} psi_c(s^) (s_c - eps),   s^ = max(s, eps),

which is C1, keeps energy, force and tangent consistent (the line search sees the energy the
forces derive from), and pushes inverted elements back with a bounded force. Its exact Hessian
needs the third derivatives of psi at the clamp, which the monomial form gives for free.

The Hessian in F is assembled from its eigen-system in the SVD frame (Teran 2005; Smith et al.
2019): three modes from the 3x3 block d2psi/ds2 and, per pair (i, j), a symmetric and an
antisymmetric mode with eigenvalues (psi_i - psi_j)/(s_i - s_j) and (psi_i + psi_j)/(s_i + s_j).
Projection to PSD clamps those nine eigenvalues at zero.
"""

import math

import numpy as np
from numba import njit, prange

from facesim._kernels import JIT_FLAGS
from facesim._kernels.svd3 import SVD_ROWS, _sym_eig3, svd3

#: |s_i - s_j| (relative) below which the divided difference is replaced by its limit
_DIVIDED_TOL = 1e-7

# exponents of the six isochoric monomials: rows 0-2 belong to I1_bar, rows 3-5 to I2_bar
_P = np.array([[4.0, -2.0, -2.0], [-2.0, 4.0, -2.0], [-2.0, -2.0, 4.0],
               [-4.0, 2.0, 2.0], [2.0, -4.0, 2.0], [2.0, 2.0, -4.0]]) / 3.0


#: scratch rows ``(rows, 3)`` :func:`psi_derivatives`, :func:`psi_extended`, :func:`mr_modes` and
#: :func:`mr_node_hessian` need: 3x3 matrices and vectors are row slices of one array, never reshaped
#: views of a flat one (numba makes a reshape a call, ~20 ns: a tenth of a true element Hessian)
PSI_ROWS = 4
EXT_ROWS = 6 + PSI_ROWS
MODES_ROWS = 18 + SVD_ROWS + EXT_ROWS
NODE_HESSIAN_ROWS = 22


@njit(**JIT_FLAGS)
def psi_derivatives(s, c10, c01, kappa, vol, third, g, H, T, W):
    """psi at positive ``s`` (3,), with gradient ``g`` (3,) and Hessian ``H`` (3, 3) written in place;
    the third derivatives ``T`` (3, 3, 3) only if ``third``. ``W (>= PSI_ROWS, 3)`` scratch."""
    inv = W[0]
    cb = W[1]
    mono = W[2:4]   # row 0: the I1_bar monomials, row 1: the I2_bar ones
    psi = -3.0 * (c10 + c01)
    for i in range(3):
        g[i] = 0.0
        inv[i] = 1.0 / s[i]
        cb[i] = np.cbrt(s[i])   # s > 0 here; cbrt is cheaper than a power
        for j in range(3):
            H[i, j] = 0.0
            if third:
                for k in range(3):
                    T[i, j, k] = 0.0
    # s^(4/3) = s cb, s^(-2/3) = 1/cb^2, s^(2/3) = cb^2, s^(-4/3) = 1/(s cb)
    q = 1.0 / (cb[0] * cb[1] * cb[2]) ** 2      # J^(-2/3)
    for r in range(3):
        mono[0, r] = c10 * s[r] * s[r] * q                               # I1_bar terms
        mono[1, r] = c01 * q * q * (s[(r + 1) % 3] * s[(r + 2) % 3]) ** 2   # I2_bar terms
    for r in range(6):
        p = _P[r]
        m = mono[r // 3, r % 3]
        psi += m
        for i in range(3):
            g[i] += p[i] * m * inv[i]
            for j in range(3):
                pij = p[i] * (p[j] - (1.0 if i == j else 0.0))
                H[i, j] += pij * m * inv[i] * inv[j]
                if third:
                    for k in range(3):
                        e = p[k] - (1.0 if i == k else 0.0) - (1.0 if j == k else 0.0)
                        T[i, j, k] += pij * e * m * inv[i] * inv[j] * inv[k]
    if vol == 0:
        L = math.log(s[0] * s[1] * s[2])
        psi += 0.5 * kappa * L * L
        for i in range(3):
            g[i] += kappa * L * inv[i]
            for j in range(3):
                Lij = -inv[i] * inv[i] if i == j else 0.0
                H[i, j] += kappa * (inv[i] * inv[j] + L * Lij)
                if third:
                    for k in range(3):
                        Lik = -inv[i] * inv[i] if i == k else 0.0
                        Ljk = -inv[j] * inv[j] if j == k else 0.0
                        Lijk = 2.0 * inv[i] ** 3 if (i == j and j == k) else 0.0
                        T[i, j, k] += kappa * (Lik * inv[j] + inv[i] * Ljk + inv[k] * Lij + L * Lijk)
    else:
        J = s[0] * s[1] * s[2]
        psi += 0.5 * kappa * (J - 1.0) ** 2
        for i in range(3):
            Ji = J * inv[i]
            g[i] += kappa * (J - 1.0) * Ji
            for j in range(3):
                Jj = J * inv[j]
                Jij = 0.0 if i == j else J * inv[i] * inv[j]
                H[i, j] += kappa * (Ji * Jj + (J - 1.0) * Jij)
                if third:
                    for k in range(3):
                        Jk = J * inv[k]
                        Jik = 0.0 if i == k else J * inv[i] * inv[k]
                        Jjk = 0.0 if j == k else J * inv[j] * inv[k]
                        Jijk = J * inv[0] * inv[1] * inv[2] if (i != j and j != k and i != k) else 0.0
                        T[i, j, k] += kappa * (Jik * Jj + Ji * Jjk + Jk * Jij + (J - 1.0) * Jijk)
    return psi


@njit(**JIT_FLAGS)
def psi_extended(s, c10, c01, kappa, vol, eps, g, H, T0, W):
    """The clamped-and-continued energy psi~ at signed ``s`` (3,); gradient ``g`` and Hessian ``H``
    in the singular values written in place. ``T0 (3, 3, 3)`` and ``W (>= EXT_ROWS, 3)`` scratch."""
    sh = W[0]
    clamped = W[1]
    g0 = W[2]
    H0 = W[3:6]
    any_clamped = False
    for i in range(3):
        clamped[i] = 1.0 if s[i] < eps else 0.0
        sh[i] = eps if s[i] < eps else s[i]
        any_clamped = any_clamped or s[i] < eps
    psi = psi_derivatives(sh, c10, c01, kappa, vol, any_clamped, g0, H0, T0, W[6:])
    for i in range(3):
        g[i] = g0[i]
        for j in range(3):
            H[i, j] = H0[i, j]
    if not any_clamped:
        return psi
    for c in range(3):
        if clamped[c] == 0.0:
            continue
        d = s[c] - eps
        psi += g0[c] * d
        for i in range(3):
            if clamped[i] != 0.0:
                continue
            g[i] += H0[c, i] * d
            for j in range(3):
                if clamped[j] == 0.0:
                    H[i, j] += T0[c, i, j] * d
    for i in range(3):
        for j in range(3):
            if clamped[i] != 0.0 and clamped[j] != 0.0:
                H[i, j] = 0.0
    return psi


@njit(**JIT_FLAGS)
def _pair_eigenvalues(si, sj, gi, gj, Hii, Hij, Hjj):
    """Eigenvalues of the (i, j) off-diagonal block: symmetric mode, antisymmetric mode."""
    d = si - sj
    if abs(d) > _DIVIDED_TOL * max(1.0, abs(si) + abs(sj)):
        lam_sym = (gi - gj) / d
    else:
        lam_sym = 0.5 * (Hii + Hjj) - Hij
    t = si + sj
    if abs(t) > _DIVIDED_TOL * max(1.0, abs(si) + abs(sj)):
        lam_anti = (gi + gj) / t
    else:
        lam_anti = 0.5 * (Hii + Hjj) + Hij
    return lam_sym, lam_anti


@njit(**JIT_FLAGS)
def mr_modes(F, c10, c01, kappa, vol, eps, P, lam, Q, W, want_modes=True):
    """Energy density at ``F`` (3, 3); first Piola stress into ``P`` (3, 3); with ``want_modes`` the
    nine eigenvalues of dP/dF into ``lam`` (9,) and their unit eigenvectors (as 3x3 matrices) into
    ``Q`` (9, 3, 3), which is scratch until then. ``W (>= MODES_ROWS, 3)`` scratch."""
    U = W[0:3]
    V = W[3:6]
    s = W[6]
    g = W[7]
    H = W[8:11]
    A = W[11:14]
    E = W[14:17]
    w = W[17]
    svd3(F, U, s, V, W[18:18 + SVD_ROWS])
    psi = psi_extended(s, c10, c01, kappa, vol, eps, g, H, Q[0:3], W[18 + SVD_ROWS:])   # Q: filled below
    for k in range(3):
        for l in range(3):
            P[k, l] = U[k, 0] * g[0] * V[l, 0] + U[k, 1] * g[1] * V[l, 1] + U[k, 2] * g[2] * V[l, 2]
    if not want_modes:
        return psi
    # diagonal block
    for i in range(3):
        for j in range(3):
            A[i, j] = H[i, j]
    _sym_eig3(A, E, w)
    for e in range(3):
        lam[e] = w[e]
        for k in range(3):
            for l in range(3):
                Q[e, k, l] = U[k, 0] * E[0, e] * V[l, 0] + U[k, 1] * E[1, e] * V[l, 1] + U[k, 2] * E[2, e] * V[l, 2]
    r2 = 1.0 / math.sqrt(2.0)
    e = 3
    for i in range(3):
        for j in range(i + 1, 3):
            ls, la = _pair_eigenvalues(s[i], s[j], g[i], g[j], H[i, i], H[i, j], H[j, j])
            lam[e] = ls
            lam[e + 1] = la
            for k in range(3):
                for l in range(3):
                    a = U[k, i] * V[l, j]
                    b = U[k, j] * V[l, i]
                    Q[e, k, l] = r2 * (a + b)
                    Q[e + 1, k, l] = r2 * (a - b)
            e += 2
    return psi


@njit(**JIT_FLAGS)
def _unclamped_start(F, eps, cof):
    """``(J, I1, ok)`` of ``F``, with ``cof (3, 3)`` = cof F filled when ``ok``: no singular value
    of F can be below the clamp ``eps`` (``det F > 0`` and ``2 J / I1 >= eps``, see :func:`mr_stress`)."""
    c00 = F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]
    c01 = F[1, 2] * F[2, 0] - F[1, 0] * F[2, 2]
    c02 = F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]
    J = F[0, 0] * c00 + F[0, 1] * c01 + F[0, 2] * c02
    I1 = 0.0
    for k in range(3):
        for l in range(3):
            I1 += F[k, l] * F[k, l]
    if not (J > 0.0) or 2.0 * J < eps * I1:
        return J, I1, False
    cof[0, 0], cof[0, 1], cof[0, 2] = c00, c01, c02
    cof[1, 0] = F[0, 2] * F[2, 1] - F[0, 1] * F[2, 2]
    cof[1, 1] = F[0, 0] * F[2, 2] - F[0, 2] * F[2, 0]
    cof[1, 2] = F[0, 1] * F[2, 0] - F[0, 0] * F[2, 1]
    cof[2, 0] = F[0, 1] * F[1, 2] - F[0, 2] * F[1, 1]
    cof[2, 1] = F[0, 2] * F[1, 0] - F[0, 0] * F[1, 2]
    cof[2, 2] = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return J, I1, True


@njit(**JIT_FLAGS)
def mr_stress(F, c10, c01, kappa, vol, eps, P, S):
    """Energy density and first Piola stress ``P`` (3, 3) at ``F`` from the invariants, without
    an SVD (``S (>= 6, 3)`` scratch rows): ``(psi, True)``, or ``(0, False)`` (``P``
    untouched) when a singular value of F may be below the clamp ``eps`` and :func:`mr_modes`
    must decide.

    No clamp is active when ``det F > 0`` and the smallest eigenvalue of ``C = F^T F`` is at least
    ``eps^2``; since ``l2 l3 <= (tr C / 2)^2`` for the other two, ``l1 >= 4 det C / (tr C)^2``, so
    ``2 J / I1 >= eps`` suffices (all but badly squashed tets). Then, with ``cof F = J F^-T``,

        P = 2 c10 J^(-2/3) F + 2 c01 J^(-4/3) (I1 F - F C)
            + [-(2/3) c10 J^(-2/3) I1 - (4/3) c01 J^(-4/3) I2 + J U'(J)] cof F / J,

    the same energy as the singular-value form (docs/physics.md section 1), at a fraction of its cost."""
    C = S[0:3]
    cof = S[3:6]
    J, I1, ok = _unclamped_start(F, eps, cof)
    if not ok:
        return 0.0, False
    # C = F^T F, FC = F C, I2 = (I1^2 - tr C^2) / 2
    trC2 = 0.0
    for i in range(3):
        for j in range(3):
            C[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    for i in range(3):
        for j in range(3):
            trC2 += C[i, j] * C[j, i]
    I2 = 0.5 * (I1 * I1 - trC2)
    q = 1.0 / np.cbrt(J) ** 2   # J^(-2/3): cbrt is cheaper than a power
    q2 = q * q
    if vol == 0:
        L = math.log(J)
        U = 0.5 * kappa * L * L
        JdU = kappa * L
    else:
        U = 0.5 * kappa * (J - 1.0) ** 2
        JdU = kappa * (J - 1.0) * J
    psi = c10 * (q * I1 - 3.0) + c01 * (q2 * I2 - 3.0) + U
    a = 2.0 * c10 * q + 2.0 * c01 * q2 * I1
    b = -2.0 * c01 * q2
    s = (-(2.0 / 3.0) * c10 * q * I1 - (4.0 / 3.0) * c01 * q2 * I2 + JdU) / J
    for k in range(3):
        for l in range(3):
            FC = F[k, 0] * C[0, l] + F[k, 1] * C[1, l] + F[k, 2] * C[2, l]
            P[k, l] = a * F[k, l] + b * FC + s * cof[k, l]
    return psi, True


@njit(**JIT_FLAGS)
def _invariant_partials(J, I1, I2, c10, c01, kappa, vol):
    """psi's nonzero partial derivatives in the invariants ``(I1, I2, J)`` (J > 0):
    ``(psi_1, psi_2, psi_J, psi_1J, psi_2J, psi_JJ)`` (psi is linear in I1 and I2)."""
    q = 1.0 / np.cbrt(J) ** 2   # J^(-2/3): cbrt is cheaper than a power
    q2 = q * q
    iJ = 1.0 / J
    if vol == 0:
        L = math.log(J)
        dU = kappa * L * iJ
        ddU = kappa * (1.0 - L) * iJ * iJ
    else:
        dU = kappa * (J - 1.0)
        ddU = kappa
    p1 = c10 * q
    p2 = c01 * q2
    pJ = -(2.0 / 3.0) * p1 * I1 * iJ - (4.0 / 3.0) * p2 * I2 * iJ + dU
    p1J = -(2.0 / 3.0) * p1 * iJ
    p2J = -(4.0 / 3.0) * p2 * iJ
    pJJ = (10.0 / 9.0) * p1 * I1 * iJ * iJ + (28.0 / 9.0) * p2 * I2 * iJ * iJ + ddU
    return p1, p2, pJ, p1J, p2J, pJJ


@njit(**JIT_FLAGS)
def mr_node_hessian(F, b, V0, c10, c01, kappa, vol, eps, K, S):
    """The true (unprojected) 12x12 Hessian ``K`` of one linear tet in its node positions, from the
    invariants without an SVD, or False (``K`` untouched) when a clamp may be active (the test of
    :func:`mr_stress`). ``b (4, 3)`` shape-function gradients, ``V0`` rest volume; ``S (>= NODE_HESSIAN_ROWS, 3)``
    scratch (rows, not reshaped views of a flat array: numba makes a reshape a call, ~20 ns, the
    cost of a tenth of this kernel).

    With the invariants ``(I1, I2, J)`` and their gradients ``2F``, ``2(I1 F - F C)``, ``cof F``,
    ``dP/dF = sum_ij psi_ij G_i (x) G_j + sum_i psi_i d2I_i/dF2`` (``d2I1 = 2 Id``,
    ``d2I2[dF] = 2(2 (F:dF) F + I1 dF - dF C - F dF^T F - F F^T dF)``,
    ``d2J[dF]_kl = eps_kmp eps_lnq F_pq dF_mn``), contracted with the shape gradients block by block
    rather than formed: with ``f_a = F b_a``, ``y_a = cof(F) b_a``, ``beta = b_a . b_c`` and
    ``z_a = 2 psi_1J f_a + 2 psi_2J (I1 f_a - F F^T f_a)``,
    ``K_ac / V0 = (z_a + psi_JJ y_a) y_c^T + y_a z_c^T + 2 psi_1 beta I
    + 2 psi_2 (2 f_a f_c^T - f_c f_a^T + (beta I1 - f_a . f_c) I - beta F F^T) + psi_J [eps_kmp h_p]``,
    ``h = F (b_a x b_c)``. About half the flops of forming the 9x9 ``dP/dF`` and contracting it
    (benchmarks/RESULTS.md, session 29)."""
    C = S[0:3]     # F^T F
    B = S[3:6]     # F F^T
    cof = S[6:9]
    f = S[9:13]    # F b_a
    y = S[13:17]   # cof(F) b_a
    z = S[17:21]
    h = S[21]
    J, I1, ok = _unclamped_start(F, eps, cof)
    if not ok:
        return False
    for i in range(3):
        for j in range(3):
            C[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
            B[i, j] = F[i, 0] * F[j, 0] + F[i, 1] * F[j, 1] + F[i, 2] * F[j, 2]
    trC2 = 0.0
    for i in range(3):
        for j in range(3):
            trC2 += C[i, j] * C[j, i]
    I2 = 0.5 * (I1 * I1 - trC2)
    p1, p2, pJ, p1J, p2J, pJJ = _invariant_partials(J, I1, I2, c10, c01, kappa, vol)
    for a in range(4):
        for k in range(3):
            f[a, k] = F[k, 0] * b[a, 0] + F[k, 1] * b[a, 1] + F[k, 2] * b[a, 2]
            y[a, k] = cof[k, 0] * b[a, 0] + cof[k, 1] * b[a, 1] + cof[k, 2] * b[a, 2]
        for k in range(3):   # F C b_a = (F F^T) F b_a = B f_a
            fcb = B[k, 0] * f[a, 0] + B[k, 1] * f[a, 1] + B[k, 2] * f[a, 2]
            z[a, k] = 2.0 * p1J * f[a, k] + 2.0 * p2J * (I1 * f[a, k] - fcb)
    for a in range(4):
        for c in range(a, 4):
            beta = b[a, 0] * b[c, 0] + b[a, 1] * b[c, 1] + b[a, 2] * b[c, 2]
            ff = f[a, 0] * f[c, 0] + f[a, 1] * f[c, 1] + f[a, 2] * f[c, 2]
            diag = 2.0 * p1 * beta + 2.0 * p2 * (beta * I1 - ff)
            for k in range(3):
                ua = z[a, k] + pJJ * y[a, k]
                for m in range(k if c == a else 0, 3):   # a diagonal block: its upper triangle, mirrored below
                    v = ua * y[c, m] + y[a, k] * z[c, m]
                    v += 2.0 * p2 * (2.0 * f[a, k] * f[c, m] - f[c, k] * f[a, m] - beta * B[k, m])
                    K[3 * a + k, 3 * c + m] = V0 * v
                K[3 * a + k, 3 * c + k] += V0 * diag
            if c == a:   # b_a x b_a = 0: no J term
                for k in range(3):
                    for m in range(k):
                        K[3 * a + k, 3 * a + m] = K[3 * a + m, 3 * a + k]
                continue
            # + psi_J eps_kmp h_p, h = F (b_a x b_c)
            e0 = b[a, 1] * b[c, 2] - b[a, 2] * b[c, 1]
            e1 = b[a, 2] * b[c, 0] - b[a, 0] * b[c, 2]
            e2 = b[a, 0] * b[c, 1] - b[a, 1] * b[c, 0]
            for k in range(3):
                h[k] = pJ * (F[k, 0] * e0 + F[k, 1] * e1 + F[k, 2] * e2)
            K[3 * a + 0, 3 * c + 1] += V0 * h[2]
            K[3 * a + 1, 3 * c + 0] -= V0 * h[2]
            K[3 * a + 0, 3 * c + 2] -= V0 * h[1]
            K[3 * a + 2, 3 * c + 0] += V0 * h[1]
            K[3 * a + 1, 3 * c + 2] += V0 * h[0]
            K[3 * a + 2, 3 * c + 1] -= V0 * h[0]
            for k in range(3):
                for m in range(3):
                    K[3 * c + m, 3 * a + k] = K[3 * a + k, 3 * c + m]
    return True


#: a mode's eigenvalue counts as non-negative down to this fraction of the shear scale ``c10 + c01``
#: below zero (:func:`mr_psd`): the projected Hessian differs from the true one by at most that
PSD_MARGIN = 1e-8
#: scratch rows :func:`mr_psd` needs
PSD_ROWS = 9 + PSI_ROWS


@njit(**JIT_FLAGS)
def mr_psd(F, c10, c01, kappa, vol, eps, T, S):
    """Whether the true dP/dF at ``F`` is positive semi-definite (every one of its nine eigenvalues
    at least ``-PSD_MARGIN (c10 + c01)``) with no clamp active (the test of :func:`mr_stress`): then
    its projection is itself and :func:`mr_node_hessian` gives the projected element Hessian
    without an SVD. ``T (3, 3, 3)`` and ``S (>= PSD_ROWS, 3)`` scratch.

    The eigenvalues are those of :func:`mr_modes` from the principal stretches alone: the squared
    ones are the eigenvalues of ``C = F^T F`` in closed form (trigonometric), the smallest stretch is
    ``J / (s0 s1)``; then the 3x3 Hessian in the stretches (a Cholesky factorisation of it shifted
    by the margin) and the pairs' divided differences."""
    cof = S[0:3]
    C = S[0:3]   # cof F is not needed once J and I1 are known
    s = S[3]
    g = S[4]
    H = S[5:8]
    J, I1, ok = _unclamped_start(F, eps, cof)
    if not ok:
        return False
    for i in range(3):
        for j in range(i, 3):
            C[i, j] = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
    q = I1 / 3.0
    d0, d1, d2 = C[0, 0] - q, C[1, 1] - q, C[2, 2] - q
    off = C[0, 1] * C[0, 1] + C[0, 2] * C[0, 2] + C[1, 2] * C[1, 2]
    p = math.sqrt((d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * off) / 6.0)
    if p <= 1e-14 * q:   # C a multiple of the identity
        l0 = l1 = q
    else:
        det = (d0 * (d1 * d2 - C[1, 2] * C[1, 2]) - C[0, 1] * (C[0, 1] * d2 - C[1, 2] * C[0, 2])
               + C[0, 2] * (C[0, 1] * C[1, 2] - d1 * C[0, 2]))
        r = min(max(0.5 * det / (p * p * p), -1.0), 1.0)
        phi = math.acos(r) / 3.0
        l0 = q + 2.0 * p * math.cos(phi)
        l2 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
        l1 = 3.0 * q - l0 - l2
    s[0] = math.sqrt(l0)
    s[1] = math.sqrt(max(l1, 0.0))
    if s[1] <= 0.0:
        return False
    s[2] = J / (s[0] * s[1])
    psi_derivatives(s, c10, c01, kappa, vol, False, g, H, T, S[8:])
    tol = PSD_MARGIN * (c10 + c01)
    a = H[0, 0] + tol   # H + tol I positive definite: Cholesky's pivots
    if a <= 0.0:
        return False
    m11 = H[1, 1] + tol - H[0, 1] * H[0, 1] / a
    if m11 <= 0.0:
        return False
    m12 = H[1, 2] - H[0, 1] * H[0, 2] / a
    if H[2, 2] + tol - H[0, 2] * H[0, 2] / a - m12 * m12 / m11 <= 0.0:
        return False
    for i in range(3):
        for j in range(i + 1, 3):
            ls, la = _pair_eigenvalues(s[i], s[j], g[i], g[j], H[i, i], H[i, j], H[j, j])
            if ls < -tol or la < -tol:
                return False
    return True


@njit(parallel=True, **JIT_FLAGS)
def mr_density_batch(F, c10, c01, kappa, vol, eps, psi, P):
    """Energy density ``psi`` (k,) and first Piola stress ``P`` (k, 3, 3) for ``F`` (k, 3, 3);
    material parameters are (k,) arrays."""
    for e in prange(F.shape[0]):
        lam = np.empty(9)
        Q = np.empty((9, 3, 3))
        W = np.empty((MODES_ROWS, 3))
        psi[e] = mr_modes(F[e], c10[e], c01[e], kappa[e], vol, eps, P[e], lam, Q, W)


@njit(parallel=True, **JIT_FLAGS)
def mr_tangent_batch(F, c10, c01, kappa, vol, eps, project, D):
    """dP/dF as ``D`` (k, 9, 9) (row-major vec of P and F), optionally PSD-projected."""
    for e in prange(F.shape[0]):
        lam = np.empty(9)
        Q = np.empty((9, 3, 3))
        P = np.empty((3, 3))
        W = np.empty((MODES_ROWS, 3))
        mr_modes(F[e], c10[e], c01[e], kappa[e], vol, eps, P, lam, Q, W)
        for r in range(9):
            for c in range(9):
                D[e, r, c] = 0.0
        for m in range(9):
            lm = max(lam[m], 0.0) if project else lam[m]
            if lm == 0.0:
                continue
            for r in range(9):
                qr = Q[m, r // 3, r % 3] * lm
                for c in range(9):
                    D[e, r, c] += qr * Q[m, c // 3, c % 3]
