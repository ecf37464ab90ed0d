"""Per-tet mesh quality: signed volume, extreme dihedral angles and volume ratio.

Arrays in, arrays out; the public, validating entry point is
:func:`facesim.anatomy.quality.tet_quality`.
"""

import math

from numba import njit, prange

from facesim._kernels import JIT_FLAGS

# V_regular(l) = l^3 / (6 sqrt 2): volume of the regular tet with edge length l.
_REGULAR_VOLUME_FACTOR = 1.0 / (6.0 * math.sqrt(2.0))


@njit(**JIT_FLAGS)
def _dihedral(ax, ay, az, bx, by, bz):
    """Interior dihedral angle (rad) between faces with area vectors a, b of common orientation."""
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if na * nb == 0.0:
        return 0.0
    c = -(ax * bx + ay * by + az * bz) / (na * nb)
    return math.acos(min(1.0, max(-1.0, c)))


@njit(parallel=True, **JIT_FLAGS)
def tet_quality_kernel(X, tets, volume, min_dihedral, max_dihedral, volume_ratio):
    """Fill the per-tet quality arrays in place.

    X : (n, 3) float64 node positions; tets : (m, 4) int32;
    volume, min_dihedral, max_dihedral, volume_ratio : (m,) float64 outputs
    (volume in X's units cubed, dihedral angles in radians, ratio dimensionless).

    With E = [e1 e2 e3] = [p1-p0, p2-p0, p3-p0], the face area vectors
    a1 = e2 x e3, a2 = e3 x e1, a3 = e1 x e2, a0 = -(a1 + a2 + a3) equal det(E) grad(lambda_i):
    they are normal to the face opposite vertex i, all with the same orientation, so the
    dihedral angle at the edge shared by faces i and j is arccos(-a_i.a_j / (|a_i||a_j|)) for
    either sign of the volume. A face of zero area gives dihedral angles of 0 at its edges.
    """
    m = tets.shape[0]
    for t in prange(m):
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        x0, y0, z0 = X[i0, 0], X[i0, 1], X[i0, 2]
        e1x, e1y, e1z = X[i1, 0] - x0, X[i1, 1] - y0, X[i1, 2] - z0
        e2x, e2y, e2z = X[i2, 0] - x0, X[i2, 1] - y0, X[i2, 2] - z0
        e3x, e3y, e3z = X[i3, 0] - x0, X[i3, 1] - y0, X[i3, 2] - z0

        a1x, a1y, a1z = e2y * e3z - e2z * e3y, e2z * e3x - e2x * e3z, e2x * e3y - e2y * e3x
        a2x, a2y, a2z = e3y * e1z - e3z * e1y, e3z * e1x - e3x * e1z, e3x * e1y - e3y * e1x
        a3x, a3y, a3z = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        a0x, a0y, a0z = -(a1x + a2x + a3x), -(a1y + a2y + a3y), -(a1z + a2z + a3z)

        vol = (e1x * a1x + e1y * a1y + e1z * a1z) / 6.0

        d01 = _dihedral(a0x, a0y, a0z, a1x, a1y, a1z)
        d02 = _dihedral(a0x, a0y, a0z, a2x, a2y, a2z)
        d03 = _dihedral(a0x, a0y, a0z, a3x, a3y, a3z)
        d12 = _dihedral(a1x, a1y, a1z, a2x, a2y, a2z)
        d13 = _dihedral(a1x, a1y, a1z, a3x, a3y, a3z)
        d23 = _dihedral(a2x, a2y, a2z, a3x, a3y, a3z)

        # squared edge lengths: three from vertex 0, three between the others
        sq = (e1x * e1x + e1y * e1y + e1z * e1z) + (e2x * e2x + e2y * e2y + e2z * e2z) \
            + (e3x * e3x + e3y * e3y + e3z * e3z) \
            + (e2x - e1x) ** 2 + (e2y - e1y) ** 2 + (e2z - e1z) ** 2 \
            + (e3x - e1x) ** 2 + (e3y - e1y) ** 2 + (e3z - e1z) ** 2 \
            + (e3x - e2x) ** 2 + (e3y - e2y) ** 2 + (e3z - e2z) ** 2
        ref = _REGULAR_VOLUME_FACTOR * (sq / 6.0) ** 1.5

        volume[t] = vol
        min_dihedral[t] = min(min(min(d01, d02), min(d03, d12)), min(d13, d23))
        max_dihedral[t] = max(max(max(d01, d02), max(d03, d12)), max(d13, d23))
        volume_ratio[t] = vol / ref if ref > 0.0 else 0.0
