"""Self-contact kernels: a spatial hash of triangles, node-to-surface closest points with signed
distances, and the penalty energy / gradient / sparse Hessian of node-triangle pairs.

Conventions: ``x (n, 3)`` float64 positions (mm); a contact *node* ``i`` is ``nodes[i]`` with its
surface ``node_side[i]`` (0 or 1); triangles ``tris (s, 3)`` index ``x`` and belong to surface
``tri_side``; a node is only ever paired with triangles of the other surface.

Closest-point regions are bit masks of the triangle's vertices the closest point depends on:
``7`` face, ``3 / 5 / 6`` edges (a, b) / (a, c) / (b, c), ``1 / 2 / 4`` vertices a / b / c. The
lowest set bit is the base vertex of that sub-simplex (used by the exact Hessian).

All kernels are serial. Threading does not pay at lip sizes: on the coarse model (224 nodes,
375 triangles) the candidate search took ~2 ms serially and ~23 ms with ``prange`` on 2 OpenMP
threads (thread wake-up dominates); it now takes ~1 ms in one pass (bucket sizes bound the
candidate counts). :func:`nearest_triangles` writes only per-node outputs, should a paper-size
model ever make ``prange`` worth it there.
"""

import math

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS
from facesim._kernels.contact import FACE, triangle_closest_point

RAMP = 8
"""Bit added to the region code where the sign of the distance ramps (see :func:`nearest_triangles`)."""

_P1 = 73856093   # Teschner et al. 2003, "Optimized spatial hashing for collision detection of
_P2 = 19349663   # deformable objects": h(i, j, k) = (i p1 xor j p2 xor k p3) mod table size
_P3 = 83492791


@njit(**JIT_FLAGS)
def _bucket(i, j, k, mask):
    return ((i * _P1) ^ (j * _P2) ^ (k * _P3)) & mask


@njit(**JIT_FLAGS)
def _triangle_cells(x, tris, t, h, inflate, lo, hi):
    """Integer cell range ``lo..hi (3,)`` of triangle ``t``'s bounding box inflated by ``inflate``."""
    for k in range(3):
        a, b, c = x[tris[t, 0], k], x[tris[t, 1], k], x[tris[t, 2], k]
        lo[k] = math.floor((min(a, b, c) - inflate) / h)
        hi[k] = math.floor((max(a, b, c) + inflate) / h)


@njit(**JIT_FLAGS)
def build_hash(x, tris, h, inflate):
    """Spatial hash of ``tris (s, 3)``: each triangle is entered into every cell of edge ``h`` (mm)
    that its bounding box inflated by ``inflate`` (mm) overlaps. Counting-sort layout: bucket ``b``
    holds ``items[start[b]:start[b + 1]]`` (triangle ids, ascending, a triangle repeated only
    consecutively when two of its cells collide). Returns ``(start (size + 1,), items, mask)``
    with ``size = mask + 1`` a power of two >= the number of insertions."""
    s = tris.shape[0]
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    total = 0
    for t in range(s):
        _triangle_cells(x, tris, t, h, inflate, lo, hi)
        total += (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1)
    size = 1
    while size < total:
        size *= 2
    mask = size - 1
    start = np.zeros(size + 1, dtype=np.int64)
    for t in range(s):
        _triangle_cells(x, tris, t, h, inflate, lo, hi)
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    start[_bucket(i, j, k, mask) + 1] += 1
    for b in range(size):
        start[b + 1] += start[b]
    fill = start[:size].copy()
    items = np.empty(total, dtype=np.int64)
    for t in range(s):   # triangles in order: a bucket's items ascend, duplicates are adjacent
        _triangle_cells(x, tris, t, h, inflate, lo, hi)
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    b = _bucket(i, j, k, mask)
                    items[fill[b]] = t
                    fill[b] += 1
    return start, items, mask


@njit(**JIT_FLAGS)
def closest_point(x, p, a, b, c):
    """Closest point of triangle ``(a, b, c)`` (node ids into ``x``) to node ``p``: barycentric
    ``(b0, b1, b2)`` and the region code (:func:`~facesim._kernels.contact.triangle_closest_point`)."""
    return triangle_closest_point(x, a, b, c, x[p, 0], x[p, 1], x[p, 2])


@njit(**JIT_FLAGS)
def _offset(x, p, tris, t, b0, b1, b2, k):
    """Component ``k`` of ``p - c`` with ``c = sum_j b_j x_j`` the closest point on triangle ``t``."""
    return x[p, k] - (b0 * x[tris[t, 0], k] + b1 * x[tris[t, 1], k] + b2 * x[tris[t, 2], k])


@njit(**JIT_FLAGS)
def _candidate(x, nodes, node_side, tris, tri_side, tri_normal, i, t, radius):
    """The exact candidate test: ``t`` is on the other surface, not degenerate (zero normal), not
    incident to node ``i``, and within ``radius`` of it."""
    p = nodes[i]
    if tri_side[t] == node_side[i] or tris[t, 0] == p or tris[t, 1] == p or tris[t, 2] == p:
        return False
    if tri_normal[t, 0] == 0.0 and tri_normal[t, 1] == 0.0 and tri_normal[t, 2] == 0.0:
        return False   # no side to be behind (and Ericson's weights would divide by zero)
    for k in range(3):   # cheap reject: outside the inflated bounding box (most hash collisions)
        a, b, c = x[tris[t, 0], k], x[tris[t, 1], k], x[tris[t, 2], k]
        if x[p, k] < min(a, b, c) - radius or x[p, k] > max(a, b, c) + radius:
            return False
    b0, b1, b2, _ = closest_point(x, p, tris[t, 0], tris[t, 1], tris[t, 2])
    r2 = 0.0
    for k in range(3):
        o = _offset(x, p, tris, t, b0, b1, b2, k)
        r2 += o * o
    return r2 <= radius * radius


@njit(**JIT_FLAGS)
def _node_bucket(x, p, h, mask):
    return _bucket(math.floor(x[p, 0] / h), math.floor(x[p, 1] / h), math.floor(x[p, 2] / h), mask)


HASH_CELLS_PER_TRIANGLE = 64
"""Above this many hash insertions per triangle on average, :func:`candidate_pairs` tests every
pair instead of hashing."""


@njit(**JIT_FLAGS)
def hash_insertions(x, tris, h, inflate):
    """How many cells :func:`build_hash` would fill (float; ``inf`` for non-finite positions)."""
    total = 0.0
    for t in range(tris.shape[0]):
        cells = 1.0
        for k in range(3):
            a, b, c = x[tris[t, 0], k], x[tris[t, 1], k], x[tris[t, 2], k]
            lo, hi = min(a, b, c) - inflate, max(a, b, c) + inflate
            if not (math.isfinite(lo) and math.isfinite(hi)):
                return math.inf
            cells *= math.floor(hi / h) - math.floor(lo / h) + 1.0
        total += cells
    return total


@njit(**JIT_FLAGS)
def candidate_pairs(x, nodes, node_side, tris, tri_side, tri_normal, radius, h):
    """Every (node, triangle) pair passing the exact candidate test (other surface, not degenerate
    (``tri_normal`` of :func:`surface_normals` zero), not incident, closest-point distance <=
    ``radius`` mm), found through a spatial hash of cell size ``h`` mm
    rebuilt from ``x``: a triangle within ``radius`` of a node has its box inflated by ``radius``
    over the node's cell, so the node's bucket holds it, whatever ``h`` (about ``radius`` keeps
    both the buckets and the insertions per triangle few). Returns ``(ptr (k + 1,), tri)``: node
    ``i``'s candidates are ``tri[ptr[i]:ptr[i + 1]]``, ascending.

    When the triangles' boxes would fill more than :data:`HASH_CELLS_PER_TRIANGLE` cells each on
    average -- a line-search trial that throws a lip node metres away stretches its triangles over
    millions of cells (examples/02_jaw_and_contact.py on the coarse face: 24 GB, killed for lack of
    memory) -- or positions are not finite, every pair is tested instead (the same pairs)."""
    k = nodes.shape[0]
    if hash_insertions(x, tris, h, radius) > HASH_CELLS_PER_TRIANGLE * max(tris.shape[0], 1):
        out = []
        ptr = np.zeros(k + 1, dtype=np.int64)
        for i in range(k):
            for t in range(tris.shape[0]):
                if _candidate(x, nodes, node_side, tris, tri_side, tri_normal, i, t, radius):
                    out.append(t)
            ptr[i + 1] = len(out)
        tri = np.empty(len(out), dtype=np.int64)
        for q in range(len(out)):
            tri[q] = out[q]
        return ptr, tri
    start, items, mask = build_hash(x, tris, h, radius)
    bound = np.zeros(k + 1, dtype=np.int64)   # bucket sizes bound the candidate counts: one pass
    for i in range(k):
        b = _node_bucket(x, nodes[i], h, mask)
        bound[i + 1] = bound[i] + start[b + 1] - start[b]
    tri = np.empty(bound[k], dtype=np.int64)
    ptr = np.zeros(k + 1, dtype=np.int64)
    n = 0
    for i in range(k):
        b = _node_bucket(x, nodes[i], h, mask)
        for q in range(start[b], start[b + 1]):
            t = items[q]
            if q > start[b] and items[q - 1] == t:
                continue   # the same triangle through two of its cells
            if _candidate(x, nodes, node_side, tris, tri_side, tri_normal, i, t, radius):
                tri[n] = t
                n += 1
        ptr[i + 1] = n
    return ptr, tri[:n].copy()


@njit(**JIT_FLAGS)
def surface_normals(x, tris, tri_slot, n_slots):
    """Unit triangle normals ``(s, 3)`` (zero for degenerate triangles) and area-weighted unit
    vertex normals ``(n_slots, 3)``, vertex ``tri_slot[t, j]`` collecting triangle ``t``."""
    s = tris.shape[0]
    tn = np.zeros((s, 3))
    vn = np.zeros((n_slots, 3))
    for t in range(s):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        f0, f1, f2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        n0, n1, n2 = e1 * f2 - e2 * f1, e2 * f0 - e0 * f2, e0 * f1 - e1 * f0
        for j in range(3):
            vn[tri_slot[t, j], 0] += n0
            vn[tri_slot[t, j], 1] += n1
            vn[tri_slot[t, j], 2] += n2
        L = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        scale = math.sqrt((e0 * e0 + e1 * e1 + e2 * e2) * (f0 * f0 + f1 * f1 + f2 * f2))
        if L > 1e-12 * scale:
            tn[t, 0], tn[t, 1], tn[t, 2] = n0 / L, n1 / L, n2 / L
    for v in range(n_slots):
        L = math.sqrt(vn[v, 0] ** 2 + vn[v, 1] ** 2 + vn[v, 2] ** 2)
        if L > 0.0:
            for k in range(3):
                vn[v, k] /= L
    return tn, vn


@njit(**JIT_FLAGS)
def _plane_coordinates(x, p, tris, t):
    """Affine barycentrics ``(b0, b1, b2)`` (summing to 1, unclamped) of the projection of node ``p``
    onto the plane of triangle ``t``."""
    a = tris[t, 0]
    e00, e01, e02 = x[tris[t, 1], 0] - x[a, 0], x[tris[t, 1], 1] - x[a, 1], x[tris[t, 1], 2] - x[a, 2]
    e10, e11, e12 = x[tris[t, 2], 0] - x[a, 0], x[tris[t, 2], 1] - x[a, 1], x[tris[t, 2], 2] - x[a, 2]
    q0, q1, q2 = x[p, 0] - x[a, 0], x[p, 1] - x[a, 1], x[p, 2] - x[a, 2]
    g00 = e00 * e00 + e01 * e01 + e02 * e02
    g11 = e10 * e10 + e11 * e11 + e12 * e12
    g01 = e00 * e10 + e01 * e11 + e02 * e12
    r0 = e00 * q0 + e01 * q1 + e02 * q2
    r1 = e10 * q0 + e11 * q1 + e12 * q2
    det = g00 * g11 - g01 * g01
    b1 = (g11 * r0 - g01 * r1) / det
    b2 = (g00 * r1 - g01 * r0) / det
    return 1.0 - b1 - b2, b1, b2


@njit(**JIT_FLAGS)
def nearest_triangles(x, nodes, tris, tri_normal, node_facing, tri_facing, ptr, cand, max_depth, max_cos, cone_out,
                      cone_in):
    """For each node ``p``, the nearest (closest-point distance ``|r|``, ``r = p - c``) of its
    candidate triangles that faces it (``node_facing[i] . tri_facing[t] <= max_cos``: unit normals
    of the node and the triangle, e.g. at rest) and that it is not deeper behind than ``max_depth``
    mm, with the signed distance ``d`` to it. With ``n = tri_normal[t]`` (current unit normal; the
    candidates from :func:`candidate_pairs` are not degenerate) and ``cos = n . r / |r|``:

        d = n . r                                on the face region (= +-|r|)
        d = |r|                                  if cos >= -cone_out   (in front of or beside it)
        d = -|r|                                 if cos <= -cone_in    (behind it)
        d = |r| (1 - 2 (-cos - cone_out) / w)    in between, w = cone_in - cone_out

    Ericson's ``sign(n . r) |r|`` jumps by ``2 |r|`` when a node beside a triangle (past an open
    rim, or where the other surface folds away) crosses the triangle's plane, at any distance;
    that stalled Newton's line search on the face. Here a node counts as behind only within
    ``acos(cone_in)`` of the inward normal (as a node behind a smooth surface is), the sign ramps
    continuously between the two cones, and beside is outside: the surface past a rim is taken to
    turn away from the gap. ``d = +-|r|`` on both sides keeps ``d`` continuous when the nearest
    triangle changes; when two triangles are equally near (their shared edge or vertex is the
    closest point) the smaller ``d`` is taken, so the choice does not flip with round-off.

    ``d = coef[i, 0] delta[i, 0] + coef[i, 1] delta[i, 1]``: part 0 the distance to the closest
    point (``delta = +-|r|``, ``n . r`` on the face), part 1 the plane distance ``n . r`` (in the
    ramp only; ``d = (1 + 2 cone_out / w) |r| + (2 / w) n . r`` there). Part ``m`` has gradient
    ``U[i, m]`` w.r.t. ``p`` and ``-B[i, m, j] U[i, m]`` w.r.t. vertex ``j`` (envelope theorem:
    closest-point barycentrics for part 0, the plane projection's affine ones for part 1; ``U =
    r / delta``, ``n`` on the face, for part 1, or at ``r = 0``).

    Returns ``tri (k,)`` (-1: none), ``d (k,)`` mm (+inf: none), ``coef (k, 2)``, ``delta (k, 2)``,
    ``U (k, 2, 3)``, ``B (k, 2, 3)``, ``region (k,)`` (of the closest point, plus the :data:`RAMP`
    bit in the ramp) and ``dist (k,) = |r|``."""
    k = nodes.shape[0]
    tri = np.full(k, -1, dtype=np.int64)
    dist = np.full(k, np.inf)
    d = np.full(k, np.inf)
    coef = np.zeros((k, 2))
    delta = np.zeros((k, 2))
    U = np.zeros((k, 2, 3))
    B = np.zeros((k, 2, 3))
    region = np.zeros(k, dtype=np.int64)
    w = cone_in - cone_out
    for i in range(k):
        p = nodes[i]
        for q in range(ptr[i], ptr[i + 1]):
            t = cand[q]
            nt0, nt1, nt2 = tri_normal[t, 0], tri_normal[t, 1], tri_normal[t, 2]
            if (node_facing[i, 0] * tri_facing[t, 0] + node_facing[i, 1] * tri_facing[t, 1]
                    + node_facing[i, 2] * tri_facing[t, 2] > max_cos):
                continue   # does not face the node (e.g. the lip's own side facing the teeth)
            b0, b1, b2, reg = closest_point(x, p, tris[t, 0], tris[t, 1], tris[t, 2])
            r0 = _offset(x, p, tris, t, b0, b1, b2, 0)
            r1 = _offset(x, p, tris, t, b0, b1, b2, 1)
            r2 = _offset(x, p, tris, t, b0, b1, b2, 2)
            r = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            if r > dist[i] * (1.0 + 1e-12):
                continue
            s = nt0 * r0 + nt1 * r1 + nt2 * r2
            d0 = r
            ramp = False
            if reg == FACE:
                d0 = s
            elif s <= -cone_in * r:
                d0 = -r
            elif s < -cone_out * r:
                ramp = True
            dt = (1.0 + 2.0 * cone_out / w) * r + 2.0 * s / w if ramp else d0
            if dt < -max_depth:
                continue
            if r >= dist[i] * (1.0 - 1e-12) and dt >= d[i]:
                continue   # a tie (shared closest edge or vertex): keep the smaller distance
            dist[i] = r
            tri[i] = t
            d[i] = dt
            region[i] = reg | (RAMP if ramp else 0)
            coef[i, 0] = 1.0 + 2.0 * cone_out / w if ramp else 1.0
            delta[i, 0] = d0
            B[i, 0, 0], B[i, 0, 1], B[i, 0, 2] = b0, b1, b2
            if reg == FACE or r == 0.0:
                U[i, 0, 0], U[i, 0, 1], U[i, 0, 2] = nt0, nt1, nt2
            else:
                U[i, 0, 0], U[i, 0, 1], U[i, 0, 2] = r0 / d0, r1 / d0, r2 / d0
            coef[i, 1] = 2.0 / w if ramp else 0.0
            delta[i, 1] = s
            U[i, 1, 0], U[i, 1, 1], U[i, 1, 2] = nt0, nt1, nt2
            b0, b1, b2 = _plane_coordinates(x, p, tris, t) if ramp else (0.0, 0.0, 0.0)
            B[i, 1, 0], B[i, 1, 1], B[i, 1, 2] = b0, b1, b2
    return tri, d, coef, delta, U, B, region, dist


@njit(**JIT_FLAGS)
def _distance_gradient(coef, U, B, g12):
    """``g12 (12,)``: gradient of ``d`` w.r.t. ``(p, x_a, x_b, x_c)`` from its parts."""
    g12[:] = 0.0
    for m in range(2):
        if coef[m] == 0.0:
            continue
        for k in range(3):
            g12[k] += coef[m] * U[m, k]
            for j in range(3):
                g12[3 * (j + 1) + k] -= coef[m] * B[m, j] * U[m, k]


@njit(**JIT_FLAGS)
def penalty_gradient(nodes, tris, tri, d, coef, U, B, weights, margins, stiffness, g, want_grad):
    """Energy ``sum_i w_i k/2 max(0, m_i - d_i)^2`` (mJ) of the node-triangle pairs; if ``want_grad``
    adds its gradient (N) into ``g (n, 3)``: ``-w_i k pen_i grad d_i`` on the node and the
    triangle's vertices."""
    E = 0.0
    g12 = np.empty(12)
    for i in range(nodes.shape[0]):
        t = tri[i]
        if t < 0:
            continue
        pen = margins[i] - d[i]
        if pen <= 0.0:
            continue
        kw = stiffness * weights[i]
        E += 0.5 * kw * pen * pen
        if want_grad:
            _distance_gradient(coef[i], U[i], B[i], g12)
            for k in range(3):
                g[nodes[i], k] -= kw * pen * g12[k]
                for j in range(3):
                    g[tris[t, j], k] -= kw * pen * g12[3 * (j + 1) + k]
    return E


@njit(**JIT_FLAGS)
def _distance_hessian(x, tris, t, b, nu, d, region, Hd, scale):
    """Adds ``scale`` times the exact Hessian ``(12, 12)`` w.r.t. ``z = (p, x_a, x_b, x_c)`` of a
    distance part ``d`` (``+-|r|`` or the plane distance) into ``Hd``. For ``|r| = |p - sum_j b_j
    x_j|`` minimised over the sub-simplex ``region`` (edge vectors ``E`` from its base vertex, the
    lowest set bit; the whole plane for the plane distance), implicit differentiation of the
    stationary barycentrics gives, with ``J = dr/dz = [I, -b_a I, -b_b I, -b_c I]``, ``nu = r / d``,
    ``P = I - nu nu^T``, ``G = (E^T E)^-1``, ``A = E^T J`` and ``M`` holding ``+nu`` at the base
    vertex and ``-nu`` at the other vertex of each edge:

        Hd = J^T (P - E G E^T) J / d + A^T G M + M^T G A - d M^T G M

    On the face the first term vanishes identically (``P`` projects onto the plane of ``E``), so
    it stays smooth through ``d = 0``; on edges and vertices it is the ``1 / d`` curvature of
    the distance to a line or a point (left out where ``|d|`` is round-off)."""
    c = np.empty(4)
    c[0] = 1.0
    for j in range(3):
        c[j + 1] = -b[j]
    base = 0
    while not (region >> base) & 1:
        base += 1
    others = np.zeros(2, dtype=np.int64)
    r = 0
    for j in range(base + 1, 3):
        if (region >> j) & 1:
            others[r] = j
            r += 1
    E = np.zeros((3, 2))
    for m in range(r):
        for k in range(3):
            E[k, m] = x[tris[t, others[m]], k] - x[tris[t, base], k]
    G = np.zeros((2, 2))
    if r == 1:
        G[0, 0] = 1.0 / (E[0, 0] ** 2 + E[1, 0] ** 2 + E[2, 0] ** 2)
    elif r == 2:
        g00 = E[0, 0] ** 2 + E[1, 0] ** 2 + E[2, 0] ** 2
        g11 = E[0, 1] ** 2 + E[1, 1] ** 2 + E[2, 1] ** 2
        g01 = E[0, 0] * E[0, 1] + E[1, 0] * E[1, 1] + E[2, 0] * E[2, 1]
        det = g00 * g11 - g01 * g01
        G[0, 0], G[1, 1], G[0, 1], G[1, 0] = g11 / det, g00 / det, -g01 / det, -g01 / det
    if r < 2 and abs(d) > 1e-12:
        S = np.empty((3, 3))
        for a in range(3):
            for e in range(3):
                q = 0.0
                for m in range(r):
                    for mm in range(r):
                        q += E[a, m] * G[m, mm] * E[e, mm]
                S[a, e] = scale * ((1.0 if a == e else 0.0) - nu[a] * nu[e] - q) / d
        for al in range(4):
            for be in range(4):
                f = c[al] * c[be]
                for a in range(3):
                    for e in range(3):
                        Hd[3 * al + a, 3 * be + e] += f * S[a, e]
    if r >= 1:
        A = np.zeros((2, 12))
        M = np.zeros((2, 12))
        for m in range(r):
            for al in range(4):
                for k in range(3):
                    A[m, 3 * al + k] = c[al] * E[k, m]
            for k in range(3):
                M[m, 3 * (base + 1) + k] = nu[k]
                M[m, 3 * (others[m] + 1) + k] = -nu[k]
        GM = G @ M
        GA = G @ A
        for q in range(12):
            for s in range(12):
                v = 0.0
                for m in range(r):
                    v += A[m, q] * GM[m, s] + M[m, q] * GA[m, s] - d * M[m, q] * GM[m, s]
                Hd[q, s] += scale * v


@njit(**JIT_FLAGS)
def penalty_hessian(x, nodes, tris, tri, d, coef, delta, U, B, region, weights, margins, stiffness, row_of,
                    free_dof, exact):
    """COO triplets ``(rows, cols, vals)`` (N/mm) of the penalty Hessian over a system's dofs: per
    active pair the 12x12 ``w k (grad d grad d^T - pen hess d)``, the Gauss-Newton part (PSD) only
    unless ``exact``. Node ``v`` maps to dofs ``3 row_of[v] + (0, 1, 2)``; nodes with row -1 and
    dofs with ``free_dof`` False are dropped, as are the triangle's vertices ``d`` does not depend
    on (their rows are zero); duplicates are summed by the COO -> CSR conversion."""
    k = nodes.shape[0]
    n_pairs = 0
    for i in range(k):
        if tri[i] >= 0 and margins[i] - d[i] > 0.0:
            n_pairs += 1
    rows = np.empty(144 * n_pairs, dtype=np.int64)
    cols = np.empty(144 * n_pairs, dtype=np.int64)
    vals = np.empty(144 * n_pairs)
    H = np.empty((12, 12))
    g12 = np.empty(12)
    node = np.empty(4, dtype=np.int64)
    used = np.empty(4, dtype=np.bool_)
    used[0] = True
    n = 0
    for i in range(k):
        t = tri[i]
        if t < 0:
            continue
        pen = margins[i] - d[i]
        if pen <= 0.0:
            continue
        kw = stiffness * weights[i]
        node[0] = nodes[i]
        for j in range(3):
            node[j + 1] = tris[t, j]
            used[j + 1] = (region[i] >> j) & 1 == 1 or coef[i, 1] != 0.0   # vertices d depends on
        _distance_gradient(coef[i], U[i], B[i], g12)
        for q in range(12):
            for s in range(12):
                H[q, s] = kw * g12[q] * g12[s]
        if exact:
            _distance_hessian(x, tris, t, B[i, 0], U[i, 0], delta[i, 0], region[i] & FACE, H, -kw * pen * coef[i, 0])
            if coef[i, 1] != 0.0:
                _distance_hessian(x, tris, t, B[i, 1], U[i, 1], delta[i, 1], FACE, H, -kw * pen * coef[i, 1])
        for al in range(4):
            ra = row_of[node[al]]
            if ra < 0 or not used[al]:
                continue
            for be in range(4):
                rb = row_of[node[be]]
                if rb < 0 or not used[be]:
                    continue
                for a in range(3):
                    if not free_dof[3 * ra + a]:
                        continue
                    for e in range(3):
                        if not free_dof[3 * rb + e]:
                            continue
                        rows[n] = 3 * ra + a
                        cols[n] = 3 * rb + e
                        vals[n] = H[3 * al + a, 3 * be + e]
                        n += 1
    return rows[:n], cols[:n], vals[:n]
