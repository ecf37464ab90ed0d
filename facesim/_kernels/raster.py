"""Z-buffer rasterisation of triangles (the teeth renders and silhouettes of facesim.teeth).

Pixel centres are at integer coordinates (OpenCV's convention): pixel ``(row i, column j)``
covers the point ``u = j, v = i``. A pixel belongs to a triangle when its centre lies inside
or on the triangle's edges (either winding: the teeth scans are open surfaces, so nothing is
culled). Depth is interpolated perspective-correctly (``1/z`` is affine in the image plane).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def rasterise(P, F, width, height, near):
    """Depth and triangle ids of the triangles ``F (m, 3) int32`` over the projected vertices
    ``P (n, 3) float64 = (u px, v px, z mm)`` in an image ``height x width``.

    Returns ``depth (height, width) float64`` (camera z, mm; inf where empty) and ``ids
    (height, width) int32`` (triangle index; -1 where empty). Triangles with a vertex at
    ``z <= near`` mm are skipped (they would cross the camera plane).
    """
    depth = np.full((height, width), np.inf)
    ids = np.full((height, width), -1, dtype=np.int32)
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        za, zb, zc = P[a, 2], P[b, 2], P[c, 2]
        if za <= near or zb <= near or zc <= near:
            continue
        ua, va = P[a, 0], P[a, 1]
        ub, vb = P[b, 0], P[b, 1]
        uc, vc = P[c, 0], P[c, 1]
        area = (ub - ua) * (vc - va) - (vb - va) * (uc - ua)
        if abs(area) < 1e-12:
            continue
        j0 = max(0, int(np.ceil(min(ua, ub, uc))))
        j1 = min(width - 1, int(np.floor(max(ua, ub, uc))))
        i0 = max(0, int(np.ceil(min(va, vb, vc))))
        i1 = min(height - 1, int(np.floor(max(va, vb, vc))))
        if j0 > j1 or i0 > i1:
            continue
        inv = 1.0 / area
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                # barycentric weights from the signed sub-areas (edge functions)
                wa = ((ub - j) * (vc - i) - (vb - i) * (uc - j)) * inv
                wb = ((uc - j) * (va - i) - (vc - i) * (ua - j)) * inv
                wc = 1.0 - wa - wb
                if wa < 0.0 or wb < 0.0 or wc < 0.0:
                    continue
                z = 1.0 / (wa / za + wb / zb + wc / zc)
                if z < depth[i, j]:
                    depth[i, j] = z
                    ids[i, j] = f
    return depth, ids
