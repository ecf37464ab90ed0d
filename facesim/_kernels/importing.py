"""Kernels of the mesh importer (facesim.importing): a depth map of a surface seen from the front."""

from __future__ import annotations

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def front_depth(V, F, x0, y0, h, out):
    """The largest z of the triangles ``F (m, 3)`` of ``V (n, 3)`` over the grid points
    ``(x0 + i h, y0 + j h)``, written into ``out (nx, ny)`` (which the caller fills with -inf:
    points no triangle covers keep it). A point on an edge belongs to both triangles; triangles
    seen edge-on are skipped. A z-buffer rasteriser: orthographic view along -z."""
    nx, ny = out.shape
    for t in range(F.shape[0]):
        ax, ay, az = V[F[t, 0], 0], V[F[t, 0], 1], V[F[t, 0], 2]
        bx, by, bz = V[F[t, 1], 0], V[F[t, 1], 1], V[F[t, 1], 2]
        cx, cy, cz = V[F[t, 2], 0], V[F[t, 2], 1], V[F[t, 2], 2]
        den = (by - cy) * (ax - cx) + (cx - bx) * (ay - cy)
        scale = abs(ax - cx) + abs(ay - cy) + abs(bx - cx) + abs(by - cy)
        if abs(den) <= 1e-12 * scale * scale or scale == 0.0:
            continue
        i0 = max(int(np.ceil((min(ax, bx, cx) - x0) / h)), 0)
        i1 = min(int(np.floor((max(ax, bx, cx) - x0) / h)), nx - 1)
        j0 = max(int(np.ceil((min(ay, by, cy) - y0) / h)), 0)
        j1 = min(int(np.floor((max(ay, by, cy) - y0) / h)), ny - 1)
        eps = -1e-12
        for i in range(i0, i1 + 1):
            px = x0 + i * h
            for j in range(j0, j1 + 1):
                py = y0 + j * h
                l1 = ((by - cy) * (px - cx) + (cx - bx) * (py - cy)) / den
                l2 = ((cy - ay) * (px - cx) + (ax - cx) * (py - cy)) / den
                l3 = 1.0 - l1 - l2
                if l1 >= eps and l2 >= eps and l3 >= eps:
                    z = l1 * az + l2 * bz + l3 * cz
                    if z > out[i, j]:
                        out[i, j] = z
