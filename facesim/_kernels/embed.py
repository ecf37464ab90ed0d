"""Kernels that embed muscles in a tet mesh: point-in-swept-ribbon tests with fibre directions."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from facesim._kernels import JIT_FLAGS


@njit(parallel=True, **JIT_FLAGS)
def ribbon_inside(P, C, Tn, Nn, W, H, closed, inside, fibre):
    """For points ``P (q, 3)``: are they inside the ribbon swept along polyline ``C (k, 3)``?

    At each polyline vertex: unit tangent ``Tn``, unit normal ``Nn`` (thickness direction),
    half width ``W`` (across, along Tn x Nn) and half thickness ``H``; interpolated linearly
    along segments. Each segment is capped by half-ellipsoids of length H (at the ends of open
    ribbons and, overlapping the next segment, at interior vertices). Writes ``inside (q,)``
    (bool) and the interpolated unit tangent of the closest segment into ``fibre (q, 3)``.
    """
    k = C.shape[0]
    nseg = k if closed else k - 1
    for i in prange(P.shape[0]):
        best = 1e30
        bt = np.zeros(3)
        for s in range(nseg):
            a = s
            b = (s + 1) % k
            ab0 = C[b, 0] - C[a, 0]
            ab1 = C[b, 1] - C[a, 1]
            ab2 = C[b, 2] - C[a, 2]
            L2 = ab0 * ab0 + ab1 * ab1 + ab2 * ab2
            d0 = P[i, 0] - C[a, 0]
            d1 = P[i, 1] - C[a, 1]
            d2 = P[i, 2] - C[a, 2]
            t = (d0 * ab0 + d1 * ab1 + d2 * ab2) / L2
            # the offset along the path beyond a segment's end counts at every vertex: dropping it
            # at interior vertices made each vertex grow a ray along its tangent
            excess = 0.0
            if t < 0.0:
                excess = -t * np.sqrt(L2)
                t = 0.0
            elif t > 1.0:
                excess = (t - 1.0) * np.sqrt(L2)
                t = 1.0
            r0 = d0 - t * ab0
            r1 = d1 - t * ab1
            r2 = d2 - t * ab2
            tx = Tn[a, 0] + t * (Tn[b, 0] - Tn[a, 0])
            ty = Tn[a, 1] + t * (Tn[b, 1] - Tn[a, 1])
            tz = Tn[a, 2] + t * (Tn[b, 2] - Tn[a, 2])
            tl = np.sqrt(tx * tx + ty * ty + tz * tz)
            tx /= tl
            ty /= tl
            tz /= tl
            nx = Nn[a, 0] + t * (Nn[b, 0] - Nn[a, 0])
            ny = Nn[a, 1] + t * (Nn[b, 1] - Nn[a, 1])
            nz = Nn[a, 2] + t * (Nn[b, 2] - Nn[a, 2])
            # remove the tangential part so (t, n, b) is orthonormal
            dn = nx * tx + ny * ty + nz * tz
            nx -= dn * tx
            ny -= dn * ty
            nz -= dn * tz
            nl = np.sqrt(nx * nx + ny * ny + nz * nz)
            nx /= nl
            ny /= nl
            nz /= nl
            bx = ty * nz - tz * ny
            by = tz * nx - tx * nz
            bz = tx * ny - ty * nx
            w = W[a] + t * (W[b] - W[a])
            h = H[a] + t * (H[b] - H[a])
            # component across the ribbon (b) and through it (n); along-offsets beyond the ends via excess
            cb = r0 * bx + r1 * by + r2 * bz
            cn = r0 * nx + r1 * ny + r2 * nz
            val = (cb / w) ** 2 + (cn / h) ** 2 + (excess / h) ** 2
            if val < best:
                best = val
                bt[0] = tx
                bt[1] = ty
                bt[2] = tz
        inside[i] = best <= 1.0
        fibre[i, 0] = bt[0]
        fibre[i, 1] = bt[1]
        fibre[i, 2] = bt[2]
