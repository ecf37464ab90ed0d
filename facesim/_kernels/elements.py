"""Per-tet energy, gradient and Hessian loops of the flesh and muscle terms.

Linear tets: ``F = [x1-x0, x2-x0, x3-x0] Bm`` with ``Bm = Dm^-1`` precomputed, shape-function
gradients ``b[a] (3,)`` (``b0 = -(b1 + b2 + b3)``), rest volume ``V0``. Then
``dE/dx_a = V0 P b_a`` and, for a rank-one tangent mode ``q`` (3, 3) with eigenvalue ``lam``,
the element Hessian gains ``V0 lam (G^T q)(G^T q)^T`` with ``(G^T q)_(a,k) = (q b_a)_k``.

Flesh gradients and Hessians run over coloured chunks of tets (chunks of one colour share no
node): each colour is a parallel loop adding straight into the nodes, or into the BSR blocks
through the precomputed scatter map ``e2b`` (-1 where a block is not part of the system). The
fibre gradient is computed per entry in parallel and summed serially (a few flops per entry).
"""

import math

import numpy as np
from numba import njit, prange

from facesim._kernels import JIT_FLAGS
from facesim._kernels.fibre import fibre_stress
from facesim._kernels.svd3 import SVD_ROWS, svd3
from facesim._kernels.mooney import MODES_ROWS, NODE_HESSIAN_ROWS, PSD_ROWS, mr_modes, mr_node_hessian, mr_psd, mr_stress


@njit(**JIT_FLAGS)
def _chunks(n):
    """Number of chunks a parallel loop over ``n`` items is split into (scratch is allocated per chunk;
    a constant, so cached kernels do not depend on the thread count)."""
    return min(n, 64)


@njit(**JIT_FLAGS)
def deformation_gradient(x, tet, Bm, F):
    """F (3, 3) of one tet: ``x (n, 3)``, ``tet (4,)``, ``Bm (3, 3)``."""
    for k in range(3):
        d1 = x[tet[1], k] - x[tet[0], k]
        d2 = x[tet[2], k] - x[tet[0], k]
        d3 = x[tet[3], k] - x[tet[0], k]
        for l in range(3):
            F[k, l] = d1 * Bm[0, l] + d2 * Bm[1, l] + d3 * Bm[2, l]


@njit(**JIT_FLAGS)
def shape_gradients(Bm, b):
    """b (4, 3): gradients of the four linear shape functions."""
    for l in range(3):
        b[1, l] = Bm[0, l]
        b[2, l] = Bm[1, l]
        b[3, l] = Bm[2, l]
        b[0, l] = -(Bm[0, l] + Bm[1, l] + Bm[2, l])


@njit(parallel=True, **JIT_FLAGS)
def rest_shape(X, tets, Bm, V0):
    """Fill ``Bm (m, 3, 3)`` = Dm^-1 and signed rest volumes ``V0 (m,)``."""
    for e in prange(tets.shape[0]):
        D = np.empty((3, 3))
        t = tets[e]
        for k in range(3):
            for j in range(3):
                D[k, j] = X[t[j + 1], k] - X[t[0], k]
        det = (D[0, 0] * (D[1, 1] * D[2, 2] - D[1, 2] * D[2, 1]) - D[0, 1] * (D[1, 0] * D[2, 2] - D[1, 2] * D[2, 0])
               + D[0, 2] * (D[1, 0] * D[2, 1] - D[1, 1] * D[2, 0]))
        V0[e] = det / 6.0
        if det == 0.0:
            for k in range(3):
                for j in range(3):
                    Bm[e, k, j] = 0.0
            continue
        inv = 1.0 / det
        Bm[e, 0, 0] = (D[1, 1] * D[2, 2] - D[1, 2] * D[2, 1]) * inv
        Bm[e, 0, 1] = (D[0, 2] * D[2, 1] - D[0, 1] * D[2, 2]) * inv
        Bm[e, 0, 2] = (D[0, 1] * D[1, 2] - D[0, 2] * D[1, 1]) * inv
        Bm[e, 1, 0] = (D[1, 2] * D[2, 0] - D[1, 0] * D[2, 2]) * inv
        Bm[e, 1, 1] = (D[0, 0] * D[2, 2] - D[0, 2] * D[2, 0]) * inv
        Bm[e, 1, 2] = (D[0, 2] * D[1, 0] - D[0, 0] * D[1, 2]) * inv
        Bm[e, 2, 0] = (D[1, 0] * D[2, 1] - D[1, 1] * D[2, 0]) * inv
        Bm[e, 2, 1] = (D[0, 1] * D[2, 0] - D[0, 0] * D[2, 1]) * inv
        Bm[e, 2, 2] = (D[0, 0] * D[1, 1] - D[0, 1] * D[1, 0]) * inv


@njit(parallel=True, **JIT_FLAGS)
def min_signed_singular_value(x, tets, Bm, elems):
    """The smallest signed singular value of ``F`` over the tets ``elems`` at ``x (n, 3)`` (the
    signed SVD's: negative where a tet is inverted; inf for none). A numba loop: LAPACK's batched
    SVD took 2.9 s over the paper-size face's 824K tets (benchmarks/RESULTS.md, session 32)."""
    n = elems.shape[0]
    nc = _chunks(n)
    part = np.full(max(nc, 1), np.inf)
    for c in prange(nc):
        F = np.empty((3, 3))
        U = np.empty((3, 3))
        V = np.empty((3, 3))
        s = np.empty(3)
        W = np.empty((SVD_ROWS, 3))
        low = np.inf
        for i in range(c * n // nc, (c + 1) * n // nc):
            e = elems[i]
            deformation_gradient(x, tets[e], Bm[e], F)
            svd3(F, U, s, V, W)
            if s[2] < low:
                low = s[2]
        part[c] = low
    return part.min()


@njit(parallel=True, **JIT_FLAGS)
def volume_ratio_range(x, tets, Bm, elems):
    """``(inverted, min_J)`` over the tets ``elems`` at ``x (n, 3)``: how many have ``J = det F <= 0``
    and the smallest ``J`` (inf for none). A numba loop: numpy's signed volumes took 4.8 ms on the
    coarse face, a fixed cost of every predicted start of a trial equilibrium (benchmarks/RESULTS.md,
    session 33)."""
    n = elems.shape[0]
    nc = _chunks(n)
    low = np.full(max(nc, 1), np.inf)
    count = np.zeros(max(nc, 1), dtype=np.int64)
    for c in prange(nc):
        F = np.empty((3, 3))
        lo = np.inf
        k = 0
        for i in range(c * n // nc, (c + 1) * n // nc):
            e = elems[i]
            deformation_gradient(x, tets[e], Bm[e], F)
            J = (F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
                 + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]))
            if J <= 0.0:
                k += 1
            if J < lo:
                lo = J
        low[c] = lo
        count[c] = k
    return count.sum(), low.min()


# ---------------------------------------------------------------- Mooney-Rivlin flesh

@njit(**JIT_FLAGS)
def stress_scratch():
    """The scratch arrays ``(F, P, b, lam, Q, W)`` of :func:`tet_stress` (``b (4, 3)`` for the
    caller's shape gradients), made once per chunk of tets."""
    return (np.empty((3, 3)), np.empty((3, 3)), np.empty((4, 3)), np.empty(9), np.empty((9, 3, 3)),
            np.empty((MODES_ROWS, 3)))


@njit(inline="always", **JIT_FLAGS)
def tet_stress(x, tet, Bm, c10, c01, kappa, vol, eps, F, P, lam, Q, W):
    """Energy density of one tet at ``x``, its first Piola stress into ``P``: from the invariants
    where no singular value can be clamped, else from the SVD form (``F, lam, Q, W`` scratch).
    Inlined into the gradient loops: called, it made the paper-size gradient 25-30 % slower
    (benchmarks/RESULTS.md, session 32)."""
    deformation_gradient(x, tet, Bm, F)
    psi, fast = mr_stress(F, c10, c01, kappa, vol, eps, P, W)
    if not fast:   # a singular value may be clamped: the SVD form
        psi = mr_modes(F, c10, c01, kappa, vol, eps, P, lam, Q, W, False)
    return psi


@njit(parallel=True, **JIT_FLAGS)
def elastic_energy(x, tets, Bm, V0, c10, c01, kappa, vol, eps, elems):
    """The energy of the listed tets at ``x`` (their gradient: :func:`elastic_gradient`)."""
    n = elems.shape[0]
    nc = _chunks(n)
    part = np.zeros(max(nc, 1))
    for c in prange(nc):
        F, P, _, lam, Q, W = stress_scratch()
        acc = 0.0
        for i in range(c * n // nc, (c + 1) * n // nc):
            e = elems[i]
            acc += V0[e] * tet_stress(x, tets[e], Bm[e], c10[e], c01[e], kappa[e], vol, eps, F, P, lam, Q, W)
        part[c] = acc
    return part.sum()


@njit(parallel=True, **JIT_FLAGS)
def elastic_gradient(x, tets, Bm, V0, c10, c01, kappa, vol, eps, colour_ptr, chunk_ptr, g):
    """Add dE/dx of the tets into ``g (n, 3)`` and return their energy. The tets' arrays are in
    chunk order, the chunks grouped by colour as in :func:`elastic_assemble`: chunks of a colour
    share no node, so each adds straight into ``g`` in parallel (no per-tet gradients stored and
    summed afterwards on one thread)."""
    part = np.zeros(max(chunk_ptr.shape[0] - 1, 1))
    for col in range(colour_ptr.shape[0] - 1):
        first = colour_ptr[col]
        for c in prange(colour_ptr[col + 1] - first):
            F, P, b, lam, Q, W = stress_scratch()
            acc = 0.0
            for i in range(chunk_ptr[first + c], chunk_ptr[first + c + 1]):
                t = tets[i]
                psi = tet_stress(x, t, Bm[i], c10[i], c01[i], kappa[i], vol, eps, F, P, lam, Q, W)
                v = V0[i]
                acc += v * psi
                shape_gradients(Bm[i], b)
                for a in range(4):
                    for k in range(3):
                        g[t[a], k] += v * (P[k, 0] * b[a, 0] + P[k, 1] * b[a, 1] + P[k, 2] * b[a, 2])
            part[first + c] = acc
    return part.sum()


@njit(**JIT_FLAGS)
def scatter_gradient(tets, elems, ge, g):
    """Add per-element gradients ``ge (k, 4, 3)`` of tets ``elems`` into ``g (n, 3)``."""
    for i in range(elems.shape[0]):
        t = tets[elems[i]]
        for a in range(4):
            for k in range(3):
                g[t[a], k] += ge[i, a, k]


@njit(**JIT_FLAGS)
def _add_block(data, e2b_e, K):
    """Add the 12x12 element matrix ``K`` into the BSR ``data (nb, 3, 3)`` via ``e2b_e (4, 4)``."""
    for a in range(4):
        for c in range(4):
            blk = e2b_e[a, c]
            if blk < 0:
                continue
            for k in range(3):
                for m in range(3):
                    data[blk, k, m] += K[3 * a + k, 3 * c + m]


@njit(**JIT_FLAGS)
def element_scratch():
    """The scratch arrays :func:`elastic_element_hessian` works in, made once per chunk of tets
    (separate arrays and row slices: numba turns a reshaped view into a call, ~20 ns each, a
    tenth of a true element Hessian)."""
    return (np.empty((3, 3)), np.empty((3, 3)), np.empty((9, 3, 3)), np.empty((4, 3)), np.empty(12), np.empty(9),
            np.empty((max(NODE_HESSIAN_ROWS, MODES_ROWS, PSD_ROWS), 3)))


@njit(**JIT_FLAGS)
def elastic_element_hessian(x, tet, Bm, V0, c10, c01, kappa, vol, eps, project, K, scratch):
    """12x12 Hessian of one tet into ``K`` (overwritten); ``scratch`` from :func:`element_scratch`.
    The true Hessian of an unclamped tet comes from the invariants
    (:func:`~facesim._kernels.mooney.mr_node_hessian`), otherwise from the SVD modes; so does the
    projected one of a tet whose dP/dF is already PSD (:func:`~facesim._kernels.mooney.mr_psd`, from
    the principal stretches without an SVD: about half the tets of a face at equilibrium)."""
    F, P, Q, b, w, lam, W = scratch
    deformation_gradient(x, tet, Bm, F)
    shape_gradients(Bm, b)
    if (not project or mr_psd(F, c10, c01, kappa, vol, eps, Q, W)) and \
            mr_node_hessian(F, b, V0, c10, c01, kappa, vol, eps, K, W):
        return   # no clamp active (and, projected, already PSD): the true Hessian from the invariants, no SVD
    mr_modes(F, c10, c01, kappa, vol, eps, P, lam, Q, W)
    for r in range(12):
        for c in range(12):
            K[r, c] = 0.0
    for m in range(9):
        lm = max(lam[m], 0.0) if project else lam[m]
        if lm == 0.0:
            continue
        for a in range(4):
            for k in range(3):
                w[3 * a + k] = Q[m, k, 0] * b[a, 0] + Q[m, k, 1] * b[a, 1] + Q[m, k, 2] * b[a, 2]
        s = V0 * lm
        for r in range(12):
            wr = s * w[r]
            for c in range(r, 12):
                K[r, c] += wr * w[c]
    for r in range(12):
        for c in range(r):
            K[r, c] = K[c, r]


@njit(parallel=True, **JIT_FLAGS)
def elastic_assemble(x, tets, Bm, V0, c10, c01, kappa, vol, eps, project, colour_ptr, chunk_ptr, e2b, data):
    """Add the Hessians of tets into BSR ``data``. The tets' arrays (``tets, Bm, V0, c10, c01,
    kappa`` and the block map ``e2b``) are in chunk order: chunk ``k`` is items ``chunk_ptr[k]:
    chunk_ptr[k + 1]``, the chunks grouped by colour (chunks ``colour_ptr[c]:colour_ptr[c + 1]``);
    one parallel loop over the chunks of each colour (:class:`~facesim.fem.system.DofSystem`)."""
    for col in range(colour_ptr.shape[0] - 1):
        first = colour_ptr[col]
        for c in prange(colour_ptr[col + 1] - first):
            K = np.empty((12, 12))
            scratch = element_scratch()
            for i in range(chunk_ptr[first + c], chunk_ptr[first + c + 1]):
                elastic_element_hessian(x, tets[i], Bm[i], V0[i], c10[i], c01[i], kappa[i], vol, eps, project, K,
                                        scratch)
                _add_block(data, e2b[i], K)


@njit(parallel=True, **JIT_FLAGS)
def elastic_element_hessians(x, tets, Bm, V0, c10, c01, kappa, vol, eps, project, elems, Ke):
    """``Ke (k, 12, 12)``: element Hessians of the listed tets (for tests and small problems)."""
    for i in prange(elems.shape[0]):
        e = elems[i]
        elastic_element_hessian(x, tets[e], Bm[e], V0[e], c10[e], c01[e], kappa[e], vol, eps, project, Ke[i],
                                element_scratch())


# ---------------------------------------------------------------- muscle fibres

@njit(**JIT_FLAGS)
def _fibre_entry(x, tet, Bm, d, F, b, fd):
    """Fibre stretch of one entry; fills F, b and ``fd = F d``; returns lam and ``w_a = b_a . d``."""
    deformation_gradient(x, tet, Bm, F)
    shape_gradients(Bm, b)
    for k in range(3):
        fd[k] = F[k, 0] * d[0] + F[k, 1] * d[1] + F[k, 2] * d[2]
    return math.sqrt(fd[0] * fd[0] + fd[1] * fd[1] + fd[2] * fd[2])


@njit(**JIT_FLAGS)
def _entry_scales(j, ent_muscle, ent_fraction, sigma, gain, a, active_only):
    m = ent_muscle[j]
    base = sigma[m] * ent_fraction[j]
    if active_only:
        return 0.0, base * gain[m]
    return base, base * gain[m] * a[m]


@njit(parallel=True, **JIT_FLAGS)
def fibre_element_gradients(x, tets, Bm, V0, ent_tet, ent_muscle, ent_fraction, ent_fibre, sigma, gain, a,
                            active_only, ge):
    """Per-entry gradients ``ge (k, 4, 3)``; returns the fibre energy. With ``active_only`` the
    term is sigma rho g F_L (activation 1, no passive part): the force columns g_m."""
    total = 0.0
    for j in prange(ent_tet.shape[0]):
        e = ent_tet[j]
        F = np.empty((3, 3))
        b = np.empty((4, 3))
        fd = np.empty(3)
        lam = _fibre_entry(x, tets[e], Bm[e], ent_fibre[j], F, b, fd)
        sp, sa = _entry_scales(j, ent_muscle, ent_fraction, sigma, gain, a, active_only)
        psi, T, dT = fibre_stress(lam, sp, sa)
        total += V0[e] * psi
        c = V0[e] * T / lam if lam > 0.0 else 0.0
        d = ent_fibre[j]
        for q in range(4):
            wq = b[q, 0] * d[0] + b[q, 1] * d[1] + b[q, 2] * d[2]
            for k in range(3):
                ge[j, q, k] = c * fd[k] * wq
    return total


@njit(**JIT_FLAGS)
def fibre_element_hessian(x, tet, Bm, V0, d, sp, sa, project, K):
    """12x12 Hessian of one fibre entry into ``K`` (zeroed here): (w w^T) (x) M with
    M = (T/lam) I + (T' - T/lam) f f^T."""
    F = np.empty((3, 3))
    b = np.empty((4, 3))
    fd = np.empty(3)
    w = np.empty(4)
    lam = _fibre_entry(x, tet, Bm, d, F, b, fd)
    psi, T, dT = fibre_stress(lam, sp, sa)
    for r in range(12):
        for c in range(12):
            K[r, c] = 0.0
    if lam <= 0.0:
        return
    t_lam = T / lam
    if project:
        t_lam_p = max(t_lam, 0.0)
        dT_p = max(dT, 0.0)
    else:
        t_lam_p = t_lam
        dT_p = dT
    M = np.empty((3, 3))
    for k in range(3):
        for m in range(3):
            M[k, m] = (dT_p - t_lam_p) * fd[k] * fd[m] / (lam * lam)
        M[k, k] += t_lam_p
    for q in range(4):
        w[q] = b[q, 0] * d[0] + b[q, 1] * d[1] + b[q, 2] * d[2]
    for p in range(4):
        for q in range(4):
            s = V0 * w[p] * w[q]
            for k in range(3):
                for m in range(3):
                    K[3 * p + k, 3 * q + m] = s * M[k, m]


@njit(parallel=True, **JIT_FLAGS)
def fibre_assemble(x, tets, Bm, V0, ent_ptr, ent_fibre, ent_muscle, ent_fraction, sigma, gain, a, project,
                   colour_ptr, chunk_ptr, chunk_elems, e2b, data):
    """Add the fibre Hessians into BSR ``data``: entries grouped by tet (``ent_ptr``, CSR over tets),
    tets in the flesh's coloured chunks (:func:`elastic_assemble`; ``chunk_elems`` the tets and
    ``e2b`` their block maps, in chunk order)."""
    for col in range(colour_ptr.shape[0] - 1):
        first = colour_ptr[col]
        for c in prange(colour_ptr[col + 1] - first):
            K = np.empty((12, 12))
            Ksum = np.empty((12, 12))
            for i in range(chunk_ptr[first + c], chunk_ptr[first + c + 1]):
                e = chunk_elems[i]
                if ent_ptr[e] == ent_ptr[e + 1]:
                    continue
                for r in range(12):
                    for q in range(12):
                        Ksum[r, q] = 0.0
                for j in range(ent_ptr[e], ent_ptr[e + 1]):
                    sp, sa = _entry_scales(j, ent_muscle, ent_fraction, sigma, gain, a, False)
                    fibre_element_hessian(x, tets[e], Bm[e], V0[e], ent_fibre[j], sp, sa, project, K)
                    for r in range(12):
                        for q in range(12):
                            Ksum[r, q] += K[r, q]
                _add_block(data, e2b[i], Ksum)


# ---------------------------------------------------------------- step limiting

@njit(**JIT_FLAGS)
def _det3(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)


@njit(parallel=True, **JIT_FLAGS)
def max_inversion_free_step(x, dx, tets, elems, samples):
    """Largest ``alpha`` in (0, 1] such that no listed tet with positive volume at ``x`` reaches
    zero volume along ``x + alpha dx`` (first sign change of the cubic det(Ds + alpha dDs),
    found by sampling ``samples`` points and bisecting). Returns 1.0 when nothing inverts."""
    out = np.ones(elems.shape[0])
    for i in prange(elems.shape[0]):
        t = tets[elems[i]]
        A = np.empty((3, 3))
        B = np.empty((3, 3))
        for k in range(3):
            for j in range(3):
                A[k, j] = x[t[j + 1], k] - x[t[0], k]
                B[k, j] = dx[t[j + 1], k] - dx[t[0], k]
        d0 = _det3(A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2], A[2, 0], A[2, 1], A[2, 2])
        if d0 <= 0.0:
            continue
        lo = 0.0
        for s in range(1, samples + 1):
            al = s / samples
            C = A + al * B
            d = _det3(C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2])
            if d <= 0.0:
                hi = al
                for _ in range(40):
                    mid = 0.5 * (lo + hi)
                    C = A + mid * B
                    dm = _det3(C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2])
                    if dm > 0.0:
                        lo = mid
                    else:
                        hi = mid
                out[i] = lo
                break
            lo = al
    return out.min() if out.shape[0] else 1.0
