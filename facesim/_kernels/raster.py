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


@njit(**JIT_FLAGS)
def silhouette_contour(P, F, X, width, height, near):
    """The inner boundary of the union of the triangles' coverage, and the points it sees.

    ``P (n, 3)``, ``F (m, 3) int32``, ``width``, ``height``, ``near``: as :func:`rasterise`;
    ``X (n, 3) float64`` the vertices to interpolate (e.g. the rest mesh, mm). A contour pixel is
    covered and has a 4-neighbour that is not, or lies on the image's edge.

    Returns ``rows (k,) int64``, ``cols (k,) int64``, ``tri (k,) int32`` (the triangle seen) and
    ``points (k, 3) float64``: ``X`` interpolated at the pixel centre with the perspective-correct
    barycentric weights (``w_i / z_i`` normalised), the point of the triangle the pixel's ray meets.
    """
    depth, ids = rasterise(P, F, width, height, near)
    k = 0
    for i in range(height):
        for j in range(width):
            if ids[i, j] >= 0 and (i == 0 or j == 0 or i == height - 1 or j == width - 1 or ids[i - 1, j] < 0
                                   or ids[i + 1, j] < 0 or ids[i, j - 1] < 0 or ids[i, j + 1] < 0):
                k += 1
    rows = np.empty(k, np.int64)
    cols = np.empty(k, np.int64)
    tri = np.empty(k, np.int32)
    points = np.empty((k, 3))
    k = 0
    for i in range(height):
        for j in range(width):
            f = ids[i, j]
            if f >= 0 and (i == 0 or j == 0 or i == height - 1 or j == width - 1 or ids[i - 1, j] < 0
                           or ids[i + 1, j] < 0 or ids[i, j - 1] < 0 or ids[i, j + 1] < 0):
                a, b, c = F[f, 0], F[f, 1], F[f, 2]
                ua, va, ub, vb, uc, vc = P[a, 0], P[a, 1], P[b, 0], P[b, 1], P[c, 0], P[c, 1]
                inv = 1.0 / ((ub - ua) * (vc - va) - (vb - va) * (uc - ua))
                wa = ((ub - j) * (vc - i) - (vb - i) * (uc - j)) * inv
                wb = ((uc - j) * (va - i) - (vc - i) * (ua - j)) * inv
                wc = 1.0 - wa - wb
                pa, pb, pc = wa / P[a, 2], wb / P[b, 2], wc / P[c, 2]
                s = pa + pb + pc
                pa, pb, pc = pa / s, pb / s, pc / s
                for x in range(3):
                    points[k, x] = pa * X[a, x] + pb * X[b, x] + pc * X[c, x]
                rows[k], cols[k], tri[k] = i, j, f
                k += 1
    return rows, cols, tri, points
