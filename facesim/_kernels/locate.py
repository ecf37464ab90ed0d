"""Kernels of the template transfer (:mod:`facesim.importing.template`): point location in a tet
mesh (a uniform grid over tet bounding boxes and a barycentric test), the thin-plate-spline
warp (value, Jacobian, Newton inverse), the per-tet muscle accumulation and the closest point of
a triangle mesh.

Conventions: points ``P (k, 3)`` mm; tets ``(m, 4)`` int32 positively oriented; ``Tinv (m, 3, 3)``
the inverse of each tet's edge matrix ``[x1 - x0, x2 - x0, x3 - x0]`` (columns), so the
barycentric coordinates of ``p`` are ``l[1:] = Tinv (p - x0)``, ``l[0] = 1 - sum(l[1:])``.
"""

import math

import numpy as np
from numba import njit, prange

from facesim._kernels import JIT_FLAGS
from facesim._kernels.contact import triangle_closest_point


# ----------------------------------------------------------------------------------- tet grid
@njit(**JIT_FLAGS)
def _cell_range(lo, hi, origin, h, shape, a, b):
    """Grid cells ``a (3,)`` .. ``b (3,)`` (inclusive) covered by the box ``lo``..``hi`` (mm)."""
    for k in range(3):
        a[k] = min(max(int(math.floor((lo[k] - origin[k]) / h)), 0), shape[k] - 1)
        b[k] = min(max(int(math.floor((hi[k] - origin[k]) / h)), 0), shape[k] - 1)


@njit(**JIT_FLAGS)
def tet_grid(X, tets, pad, origin, h, shape):
    """Cell lists of a uniform grid (``origin (3,)`` mm, cell ``h`` mm, ``shape (3,)`` int64 cells)
    over the bounding boxes of ``tets`` grown by ``pad`` mm. Returns CSR ``(ptr (c + 1,) int64,
    idx (nnz,) int32)``: the tets of cell ``(i, j, k)`` (flat ``(i * ny + j) * nz + k``) are
    ``idx[ptr[c]:ptr[c + 1]]``. Two passes: count, then fill."""
    n_cells = shape[0] * shape[1] * shape[2]
    count = np.zeros(n_cells + 1, dtype=np.int64)
    lo = np.empty(3)
    hi = np.empty(3)
    a = np.empty(3, dtype=np.int64)
    b = np.empty(3, dtype=np.int64)
    idx = np.empty(0, dtype=np.int32)
    fill = np.empty(0, dtype=np.int64)
    for sweep in range(2):
        if sweep == 1:
            for c in range(n_cells):
                count[c + 1] += count[c]
            idx = np.empty(count[n_cells], dtype=np.int32)
            fill = count[:n_cells].copy()
        for t in range(tets.shape[0]):
            for k in range(3):
                lo[k] = min(X[tets[t, 0], k], X[tets[t, 1], k], X[tets[t, 2], k], X[tets[t, 3], k]) - pad
                hi[k] = max(X[tets[t, 0], k], X[tets[t, 1], k], X[tets[t, 2], k], X[tets[t, 3], k]) + pad
            _cell_range(lo, hi, origin, h, shape, a, b)
            for i in range(a[0], b[0] + 1):
                for j in range(a[1], b[1] + 1):
                    for m in range(a[2], b[2] + 1):
                        c = (i * shape[1] + j) * shape[2] + m
                        if sweep == 0:
                            count[c + 1] += 1
                        else:
                            idx[fill[c]] = t
                            fill[c] += 1
    return count, idx


@njit(**JIT_FLAGS)
def _barycentric(X, tets, Tinv, t, p0, p1, p2, lam):
    x0 = X[tets[t, 0]]
    d0, d1, d2 = p0 - x0[0], p1 - x0[1], p2 - x0[2]
    s = 0.0
    for r in range(3):
        lam[r + 1] = Tinv[t, r, 0] * d0 + Tinv[t, r, 1] * d1 + Tinv[t, r, 2] * d2
        s += lam[r + 1]
    lam[0] = 1.0 - s


#: the faces of a tet (local vertex indices), one opposite each vertex
_FACE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)


@njit(parallel=True, **JIT_FLAGS)
def locate_points(P, X, tets, Tinv, origin, h, shape, ptr, idx, snap, tet, bary):
    """The tet of ``(X, tets)`` holding each point of ``P (k, 3)`` and its barycentric coordinates.

    Writes ``tet (k,)`` int32 (-1 outside) and ``bary (k, 4)``. A point is inside when every
    barycentric coordinate is >= -1e-10. A point outside every tet but within ``snap`` mm of one
    (the grid must be built with ``pad >= snap``) goes to the nearest such tet, with the
    barycentric coordinates of the tet's closest point (on one of its faces).
    """
    for i in prange(P.shape[0]):
        lam = np.empty(4)
        best_lam = np.empty(4)
        p0, p1, p2 = P[i, 0], P[i, 1], P[i, 2]
        tet[i] = -1
        inside = True
        for k in range(3):
            c = int(math.floor((P[i, k] - origin[k]) / h))
            if c < 0 or c >= shape[k]:
                inside = False
        if not inside:
            continue
        c = (int(math.floor((p0 - origin[0]) / h)) * shape[1]
             + int(math.floor((p1 - origin[1]) / h))) * shape[2] + int(math.floor((p2 - origin[2]) / h))
        best = -1
        best_min = -1e300
        for e in range(ptr[c], ptr[c + 1]):
            t = idx[e]
            _barycentric(X, tets, Tinv, t, p0, p1, p2, lam)
            mn = min(lam[0], lam[1], lam[2], lam[3])
            if mn > best_min:
                best_min = mn
                best = t
                for r in range(4):
                    best_lam[r] = lam[r]
            if mn >= -1e-10:
                break
        if best < 0:
            continue
        if best_min >= -1e-10:
            tet[i] = best
            for r in range(4):
                bary[i, r] = best_lam[r]
            continue
        if snap <= 0.0:
            continue
        # outside every tet: the exact closest point of the nearest candidate (its four faces)
        best_d2 = snap * snap
        for e in range(ptr[c], ptr[c + 1]):
            t = idx[e]
            for f in range(4):
                ia = tets[t, _FACE[f, 0]]
                ib = tets[t, _FACE[f, 1]]
                ic = tets[t, _FACE[f, 2]]
                b0, b1, b2, _ = triangle_closest_point(X, ia, ib, ic, p0, p1, p2)
                d2 = 0.0
                for k in range(3):
                    d2 += (b0 * X[ia, k] + b1 * X[ib, k] + b2 * X[ic, k] - P[i, k]) ** 2
                if d2 <= best_d2:
                    best_d2 = d2
                    tet[i] = t
                    for r in range(4):
                        bary[i, r] = 0.0
                    bary[i, _FACE[f, 0]] = b0
                    bary[i, _FACE[f, 1]] = b1
                    bary[i, _FACE[f, 2]] = b2


# --------------------------------------------------------------------------- thin-plate spline
@njit(**JIT_FLAGS)
def _tps_at(p0, p1, p2, C, W, M, t, f, J, want_j):
    """``f (3,)`` = t + M p + sum_i W_i phi(|p - C_i|), phi(r) = r^2 log r, and its Jacobian
    ``J (3, 3)`` (d f_j / d p_k) if ``want_j``: grad phi = (2 log r + 1)(p - C_i), 0 at r = 0."""
    for j in range(3):
        f[j] = t[j] + M[j, 0] * p0 + M[j, 1] * p1 + M[j, 2] * p2
        if want_j:
            for k in range(3):
                J[j, k] = M[j, k]
    for i in range(C.shape[0]):
        d0, d1, d2 = p0 - C[i, 0], p1 - C[i, 1], p2 - C[i, 2]
        r2 = d0 * d0 + d1 * d1 + d2 * d2
        if r2 <= 0.0:
            continue
        lr = 0.5 * math.log(r2)
        phi = r2 * lr
        for j in range(3):
            f[j] += W[i, j] * phi
        if want_j:
            g = 2.0 * lr + 1.0
            for j in range(3):
                wg = W[i, j] * g
                J[j, 0] += wg * d0
                J[j, 1] += wg * d1
                J[j, 2] += wg * d2


@njit(parallel=True, **JIT_FLAGS)
def tps_evaluate(P, C, W, M, t, out, J, want_j):
    """The thin-plate-spline map at ``P (k, 3)``: ``out (k, 3)`` and, if ``want_j``, its Jacobian
    ``J (k, 3, 3)`` (``J[i, j, k] = d out_j / d P_k``); centres ``C (l, 3)`` mm, weights ``W (l, 3)``,
    affine part ``M (3, 3)``, ``t (3,)``."""
    for i in prange(P.shape[0]):
        f = np.empty(3)
        Ji = np.empty((3, 3))
        _tps_at(P[i, 0], P[i, 1], P[i, 2], C, W, M, t, f, Ji, want_j)
        for j in range(3):
            out[i, j] = f[j]
            if want_j:
                for k in range(3):
                    J[i, j, k] = Ji[j, k]


@njit(**JIT_FLAGS)
def _solve3(A, r, dx):
    """``dx = A^-1 r`` by Cramer's rule; False if ``A`` is singular."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    if det == 0.0 or not math.isfinite(det):
        return False
    c10 = A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]
    c11 = A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]
    c12 = A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]
    c20 = A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]
    c21 = A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]
    c22 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    dx[0] = (c00 * r[0] + c10 * r[1] + c20 * r[2]) / det
    dx[1] = (c01 * r[0] + c11 * r[1] + c21 * r[2]) / det
    dx[2] = (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det
    return True


@njit(parallel=True, **JIT_FLAGS)
def tps_inverse(Y, X0, C, W, M, t, iterations, tol, X, residual, JX):
    """Points ``X (k, 3)`` with ``tps(X) = Y (k, 3)``, by Newton from ``X0 (k, 3)`` (same map
    parameters as :func:`tps_evaluate`): ``x <- x - J(x)^-1 (tps(x) - y)``, halving a step that
    does not reduce the residual (up to 30 times), at most ``iterations`` steps or until
    ``|tps(x) - y| <= tol`` mm. Writes the final ``residual (k,)`` mm and the map's Jacobian at
    ``X``, ``JX (k, 3, 3)`` (as :func:`tps_evaluate`'s)."""
    for i in prange(Y.shape[0]):
        f = np.empty(3)
        J = np.empty((3, 3))
        r = np.empty(3)
        dx = np.empty(3)
        x = np.empty(3)
        xt = np.empty(3)
        for k in range(3):
            x[k] = X0[i, k]
        _tps_at(x[0], x[1], x[2], C, W, M, t, f, J, True)
        for k in range(3):
            r[k] = f[k] - Y[i, k]
        res = math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
        Jt = np.empty((3, 3))
        for _ in range(iterations):
            if res <= tol or not _solve3(J, r, dx):
                break
            step = 1.0
            improved = False
            for _h in range(30):
                for k in range(3):
                    xt[k] = x[k] - step * dx[k]
                # the Jacobian costs little next to the kernel's log: take it at every trial point
                _tps_at(xt[0], xt[1], xt[2], C, W, M, t, f, Jt, True)
                rn = math.sqrt((f[0] - Y[i, 0]) ** 2 + (f[1] - Y[i, 1]) ** 2 + (f[2] - Y[i, 2]) ** 2)
                if rn < res:
                    improved = True
                    break
                step *= 0.5
            if not improved:
                break
            for k in range(3):
                x[k] = xt[k]
                r[k] = f[k] - Y[i, k]
                for j in range(3):
                    J[k, j] = Jt[k, j]
            res = rn
        for k in range(3):
            X[i, k] = x[k]
            for j in range(3):
                JX[i, k, j] = J[k, j]
        residual[i] = res


# ---------------------------------------------------------------------------- muscle transfer
@njit(**JIT_FLAGS)
def accumulate_muscles(sample_tet, weight, F, ptr, e_muscle, e_fraction, e_fibre, n_muscles):
    """Per-tet muscle fractions and fibres from samples located in a template mesh.

    ``sample_tet (c, q)`` int32: the template tet of sample ``s`` of target tet ``i`` (-1: outside);
    ``weight (q,)`` quadrature weights (sum 1); ``F (c, q, 3, 3)`` the warp Jacobian at each
    sample; template entries grouped by tet in CSR form (``ptr (m + 1,)``, ``e_muscle``,
    ``e_fraction``, ``e_fibre (e, 3)`` unit). For each target tet and muscle: fraction = sum_s w_s
    rho(tau_s); fibre = the fraction-weighted sum of the pushed-forward template fibres
    ``F d / |F d|``, each sign-aligned with the first one met (fibres are directions up to sign),
    normalised. Returns ``(tet (k,) int32 into 0..c-1, muscle (k,) int32, fraction (k,), fibre
    (k, 3))``, sorted by tet then muscle; entries with a zero fibre sum are left out."""
    c, q = sample_tet.shape
    frac = np.zeros(n_muscles)
    fib = np.zeros((n_muscles, 3))
    ref = np.zeros((n_muscles, 3))
    seen = np.zeros(n_muscles, dtype=np.bool_)
    g = np.empty(3)
    count = 0
    out_t = np.empty(0, dtype=np.int32)
    out_m = np.empty(0, dtype=np.int32)
    out_f = np.empty(0)
    out_d = np.empty((0, 3))
    for sweep in range(2):
        if sweep == 1:
            out_t = np.empty(count, dtype=np.int32)
            out_m = np.empty(count, dtype=np.int32)
            out_f = np.empty(count)
            out_d = np.empty((count, 3))
            count = 0
        for i in range(c):
            frac[:] = 0.0
            fib[:, :] = 0.0
            seen[:] = False
            for s in range(q):
                tau = sample_tet[i, s]
                if tau < 0:
                    continue
                for e in range(ptr[tau], ptr[tau + 1]):
                    m = e_muscle[e]
                    w = weight[s] * e_fraction[e]
                    frac[m] += w
                    if sweep == 0:
                        seen[m] = True
                        continue
                    for j in range(3):
                        g[j] = (F[i, s, j, 0] * e_fibre[e, 0] + F[i, s, j, 1] * e_fibre[e, 1]
                                + F[i, s, j, 2] * e_fibre[e, 2])
                    n = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
                    if n <= 0.0:
                        continue
                    if not seen[m]:
                        seen[m] = True
                        for j in range(3):
                            ref[m, j] = g[j] / n
                    sign = 1.0 if g[0] * ref[m, 0] + g[1] * ref[m, 1] + g[2] * ref[m, 2] >= 0.0 else -1.0
                    for j in range(3):
                        fib[m, j] += w * sign * g[j] / n
            for m in range(n_muscles):
                if sweep == 0:
                    if seen[m] and frac[m] > 0.0:
                        count += 1
                    continue
                if frac[m] <= 0.0:
                    continue
                n = math.sqrt(fib[m, 0] ** 2 + fib[m, 1] ** 2 + fib[m, 2] ** 2)
                if n <= 1e-12 * frac[m]:
                    continue
                out_t[count] = i
                out_m[count] = m
                out_f[count] = frac[m]
                for j in range(3):
                    out_d[count, j] = fib[m, j] / n
                count += 1
    return out_t[:count], out_m[:count], out_f[:count], out_d[:count]


# ----------------------------------------------------------------------- closest skin point
@njit(parallel=True, **JIT_FLAGS)
def closest_on_triangles(V, F, Fn, P, Pn, min_cos, tri, bary, region, dist):
    """For each point ``P (k, 3)`` the closest point of the triangles ``F (s, 3)`` of ``V (n, 3)``
    whose unit normal ``Fn (s, 3)`` agrees with the point's ``Pn (k, 3)`` (dot >= ``min_cos``;
    zero-area triangles, given a zero normal, are skipped: their edges belong to their
    neighbours). Writes ``tri (k,)`` int32 (-1: no triangle agrees), ``bary (k, 3)``, ``region (k,)`` (the bit mask of
    :func:`facesim._kernels.contact.triangle_closest_point`: 7 interior, 3/5/6 an edge, 1/2/4 a
    vertex) and ``dist (k,)`` mm. Brute force over the triangles (tens of markers)."""
    for i in prange(P.shape[0]):
        best = 1e300
        tri[i] = -1
        dist[i] = np.inf
        x, y, z = P[i, 0], P[i, 1], P[i, 2]
        for f in range(F.shape[0]):
            if Fn[f, 0] * Fn[f, 0] + Fn[f, 1] * Fn[f, 1] + Fn[f, 2] * Fn[f, 2] == 0.0:
                continue
            if Fn[f, 0] * Pn[i, 0] + Fn[f, 1] * Pn[i, 1] + Fn[f, 2] * Pn[i, 2] < min_cos:
                continue
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            # a cheap bound first: the distance to the triangle's bounding box
            d2 = 0.0
            for k in range(3):
                lo = min(V[a, k], V[b, k], V[c, k])
                hi = max(V[a, k], V[b, k], V[c, k])
                p = P[i, k]
                if p < lo:
                    d2 += (lo - p) ** 2
                elif p > hi:
                    d2 += (p - hi) ** 2
            if d2 >= best:
                continue
            b0, b1, b2, code = triangle_closest_point(V, a, b, c, x, y, z)
            d2 = 0.0
            for k in range(3):
                d2 += (b0 * V[a, k] + b1 * V[b, k] + b2 * V[c, k] - P[i, k]) ** 2
            if d2 < best:
                best = d2
                tri[i] = f
                bary[i, 0] = b0
                bary[i, 1] = b1
                bary[i, 2] = b2
                region[i] = code
        if tri[i] >= 0:
            dist[i] = math.sqrt(best)
