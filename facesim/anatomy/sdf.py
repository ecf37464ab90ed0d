"""Signed-distance building blocks for the procedural head, evaluated on a regular grid.

Every primitive takes broadcastable coordinate arrays ``x, y, z`` (mm) and returns an
approximate signed distance (mm, negative inside). Exact distances are only needed where
soft-tissue depths are laid over bone; there :func:`exact_sdf` replaces the approximation by a
Euclidean distance transform of the occupancy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class Grid:
    """Axis-aligned sampling grid. ``lo (3,)`` first sample, ``h`` spacing (mm), ``shape (3,)``."""

    lo: tuple[float, float, float]
    h: float
    shape: tuple[int, int, int]

    @staticmethod
    def around(lo, hi, h: float) -> "Grid":
        lo = np.asarray(lo, float)
        hi = np.asarray(hi, float)
        shape = tuple(int(np.ceil((b - a) / h)) + 1 for a, b in zip(lo, hi))
        return Grid(tuple(float(v) for v in lo), float(h), shape)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Broadcastable coordinate arrays ``x (nx,1,1), y (1,ny,1), z (1,1,nz)`` as float32."""
        ax = [np.float32(self.lo[i]) + np.float32(self.h) * np.arange(self.shape[i], dtype=np.float32)
              for i in range(3)]
        return ax[0][:, None, None], ax[1][None, :, None], ax[2][None, None, :]

    def to_world(self, ijk: np.ndarray) -> np.ndarray:
        """(k, 3) continuous grid indices -> (k, 3) world coordinates, mm."""
        return np.asarray(self.lo) + self.h * np.asarray(ijk, float)

    def sample(self, field: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Trilinear interpolation of ``field`` (grid shape) at points ``p (k, 3)``; clamps outside."""
        ijk = (np.asarray(p, float) - np.asarray(self.lo)) / self.h
        return ndimage.map_coordinates(field, ijk.T, order=1, mode="nearest")

    def gradient_at(self, field: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(k, 3) central-difference gradient of ``field`` at points ``p (k, 3)``."""
        g = np.empty((len(p), 3))
        for a in range(3):
            e = np.zeros(3)
            e[a] = self.h
            g[:, a] = (self.sample(field, p + e) - self.sample(field, p - e)) / (2 * self.h)
        return g


# ------------------------------------------------------------------ primitives
def _f(v):
    """Parameters as Python floats so float32 grids are not promoted to float64."""
    return [float(t) for t in np.ravel(v)]


def sphere(x, y, z, c, r):
    c = _f(c)
    return np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) - np.float32(r)


def ellipsoid(x, y, z, c, radii):
    """Ellipsoid, distance bound of Quilez (exact on the axes, good near the surface)."""
    c, radii = _f(c), _f(radii)
    px, py, pz = (x - c[0]) / radii[0], (y - c[1]) / radii[1], (z - c[2]) / radii[2]
    k0 = np.sqrt(px * px + py * py + pz * pz)
    k1 = np.sqrt((px / radii[0]) ** 2 + (py / radii[1]) ** 2 + (pz / radii[2]) ** 2)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-6)


def superellipsoid(x, y, z, c, radii, p: float):
    """Superellipsoid ``sum |x_i / r_i|^p = 1``; the level value is scaled to mm by the mean radius."""
    c, radii, p = _f(c), _f(radii), float(p)
    s = (np.abs((x - c[0]) / radii[0]) ** p + np.abs((y - c[1]) / radii[1]) ** p
         + np.abs((z - c[2]) / radii[2]) ** p) ** (1.0 / p)
    return (s - 1.0) * float(np.mean(radii))


def box(x, y, z, c, half, rounding: float = 0.0):
    """Rounded axis-aligned box with half extents ``half`` (mm)."""
    c, half, rounding = _f(c), _f(half), float(rounding)
    q = [np.abs(v - c[i]) - (half[i] - rounding) for i, v in enumerate((x, y, z))]
    outside = np.sqrt(sum(np.maximum(qi, 0.0) ** 2 for qi in q))
    inside = np.minimum(np.maximum(np.maximum(q[0], q[1]), q[2]), 0.0)
    return outside + inside - rounding


def capsule_chain(x, y, z, points, radii):
    """Union of capsules along a polyline ``points (k, 3)`` with radii ``(k,)`` interpolated per segment."""
    points = np.asarray(points, np.float32)
    radii = np.broadcast_to(np.asarray(radii, np.float32), (len(points),))
    d = None
    for a, b, ra, rb in zip(points[:-1], points[1:], radii[:-1], radii[1:]):
        ab = _f(b - a)
        L2 = ab[0] ** 2 + ab[1] ** 2 + ab[2] ** 2
        a, ra, rb = _f(a), float(ra), float(rb)
        t = ((x - a[0]) * ab[0] + (y - a[1]) * ab[1] + (z - a[2]) * ab[2]) * (1.0 / L2)
        t = np.clip(t, 0.0, 1.0)
        dist = np.sqrt((x - a[0] - t * ab[0]) ** 2 + (y - a[1] - t * ab[1]) ** 2 + (z - a[2] - t * ab[2]) ** 2)
        di = dist - (ra + t * (rb - ra))
        d = di if d is None else np.minimum(d, di)
    return d


def halfspace(x, y, z, point, normal):
    """Points on the side of ``normal`` are outside: signed distance to the plane."""
    n = np.asarray(normal, float)
    n = _f(n / np.linalg.norm(n))
    point = _f(point)
    return (x - point[0]) * n[0] + (y - point[1]) * n[1] + (z - point[2]) * n[2]


def arch_sweep(x, y, z, curve, half_thickness, y_low, y_high, rounding: float):
    """Solid swept along a horizontal arch.

    ``curve (k, 2)`` is the arch centreline in the (x, z) plane; at each point of the arch the
    cross-section is a rounded rectangle of half width ``half_thickness`` (across the arch) and
    vertical extent ``[y_low, y_high]``; each of the three is a scalar or ``(k,)`` per curve
    point, interpolated along the arch. The ends are capped flat.
    """
    curve = np.asarray(curve, np.float64)
    k = len(curve)
    ht = np.broadcast_to(np.asarray(half_thickness, float), (k,))
    lo = np.broadcast_to(np.asarray(y_low, float), (k,))
    hi = np.broadcast_to(np.asarray(y_high, float), (k,))
    best = None
    for i in range(k - 1):
        a, b = curve[i], curve[i + 1]
        ab = _f(b - a)
        L2 = ab[0] ** 2 + ab[1] ** 2
        a = _f(a)
        t = ((x - a[0]) * ab[0] + (z - a[1]) * ab[1]) * (1.0 / L2)
        tc = np.clip(t, 0.0, 1.0)
        dx = x - (a[0] + tc * ab[0])
        dz = z - (a[1] + tc * ab[1])
        lateral = np.sqrt(dx * dx + dz * dz)
        # past the ends of the arch the distance along the arch counts too (flat caps)
        along = np.zeros_like(t)
        if i == 0:
            along = np.maximum(along, -t)
        if i == k - 2:
            along = np.maximum(along, t - 1.0)
        along *= float(np.sqrt(L2))
        th = float(ht[i]) + tc * float(ht[i + 1] - ht[i])
        ylo = float(lo[i]) + tc * float(lo[i + 1] - lo[i])
        yhi = float(hi[i]) + tc * float(hi[i + 1] - hi[i])
        yc, yh = 0.5 * (ylo + yhi), 0.5 * (yhi - ylo)
        perp = np.sqrt(np.maximum(lateral * lateral - along * along, 0.0))
        q0 = perp - (th - rounding)
        q1 = np.abs(y - yc) - (yh - rounding)
        q2 = along - rounding
        outside = np.sqrt(np.maximum(q0, 0) ** 2 + np.maximum(q1, 0) ** 2 + np.maximum(q2, 0) ** 2)
        inside = np.minimum(np.maximum(np.maximum(q0, q1), q2), 0.0)
        d = outside + inside - rounding
        best = d if best is None else np.minimum(best, d)
    return best


# ------------------------------------------------------------------ operators
def smooth_union(a, b, k: float):
    """Polynomial smooth minimum with blend radius ``k`` (mm)."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def smooth_subtract(a, b, k: float):
    """``a`` minus ``b`` with a blend radius ``k`` (mm)."""
    return -smooth_union(-a, b, k)


def smooth_intersect(a, b, k: float):
    return -smooth_union(-a, -b, k)


def closing(inside: np.ndarray, r: float, h: float) -> np.ndarray:
    """Morphological closing of an occupancy grid by a ball of radius ``r`` mm (via two EDTs)."""
    pad = int(np.ceil(r / h)) + 2
    big = np.pad(inside, pad, constant_values=False)
    dilated = ndimage.distance_transform_edt(~big, sampling=h) <= r
    closed = ndimage.distance_transform_edt(dilated, sampling=h) > r
    return closed[pad:-pad, pad:-pad, pad:-pad] | inside


def exact_sdf(inside: np.ndarray, h: float) -> np.ndarray:
    """Euclidean signed distance (mm, float32) of a boolean occupancy grid (True inside)."""
    out = ndimage.distance_transform_edt(~inside, sampling=h).astype(np.float32)
    ins = ndimage.distance_transform_edt(inside, sampling=h).astype(np.float32)
    # half a voxel on each side puts the zero level between the last inside and first outside sample
    return np.where(inside, -ins + 0.5 * h, out - 0.5 * h).astype(np.float32)
