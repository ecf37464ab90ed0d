"""Rasterising meshes into a camera: the public front of :mod:`facesim._kernels.raster`.

:func:`render_ids` projects world vertices into a :class:`~facesim.teeth.cameras.Camera` and
returns the z-buffer (camera depth, mm) and the id of the triangle seen at every pixel.
:func:`pixel_points` turns pixels back into points on the triangles they see;
:func:`contour_points` does both for the silhouette's contour pixels in one kernel (the
tracker's hot path: no full-window masks or index arrays in numpy). Our own numba z-buffer rather than pyvista/VTK: the tracker renders a
few dozen silhouettes per frame and needs the triangle under every pixel; off-screen VTK on a
headless 2-core machine costs tens of milliseconds of context set-up and read-back per image
(OSMesa), the numba kernel a few milliseconds for the teeth at 1280x720.
"""

from __future__ import annotations

import numpy as np

from facesim._kernels.raster import rasterise, silhouette_contour

#: Triangles with a vertex nearer to the camera than this (mm) are not drawn.
NEAR_MM = 1.0


def project_vertices(camera, V) -> np.ndarray:
    """``(n, 3)`` (u px, v px, z mm) of world vertices ``V (n, 3)`` mm in ``camera``."""
    Y = camera.to_camera(V)
    h = Y @ camera.K.T
    z = Y[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[:, :2] / np.where(np.abs(z) > 1e-12, z, 1e-12)[:, None]
    return np.ascontiguousarray(np.column_stack([uv, z]))


def render_ids(camera, V, F) -> tuple[np.ndarray, np.ndarray]:
    """``(depth (h, w) float64 mm, ids (h, w) int32)``: the z-buffer of triangles ``F (m, 3)`` over
    world vertices ``V (n, 3)`` mm seen by ``camera`` (ids -1 and depth inf where empty)."""
    P = project_vertices(camera, np.asarray(V, dtype=np.float64))
    return rasterise(P, np.ascontiguousarray(F, dtype=np.int32), camera.width, camera.height, NEAR_MM)


def _window(camera, P, margin: int):
    """``(row0, col0, width, height)`` of the image window around the projected vertices ``P``
    in front of the camera (``margin`` px more), or None when none is in the image."""
    front = P[:, 2] > NEAR_MM
    if not front.any():
        return None
    lo = np.floor(P[front, :2].min(axis=0)).astype(int) - margin
    hi = np.ceil(P[front, :2].max(axis=0)).astype(int) + margin
    c0, r0 = max(0, lo[0]), max(0, lo[1])
    c1, r1 = min(camera.width - 1, hi[0]), min(camera.height - 1, hi[1])
    if c1 < c0 or r1 < r0:
        return None
    return r0, c0, c1 - c0 + 1, r1 - r0 + 1


def _shifted(P, r0, c0) -> np.ndarray:
    P = P.copy()
    P[:, 0] -= c0
    P[:, 1] -= r0
    return P


def render_ids_window(camera, V, F, margin: int = 2) -> tuple[np.ndarray, np.ndarray, int, int]:
    """``(depth, ids, row0, col0)``: :func:`render_ids` restricted to the window of the image
    around the projected vertices (``margin`` px more): pixel ``(i, j)`` of the window is
    ``(row0 + i, col0 + j)`` of the image. Much cheaper for a small object in a large image."""
    P = project_vertices(camera, np.asarray(V, dtype=np.float64))
    w = _window(camera, P, margin)
    if w is None:
        return np.full((1, 1), np.inf), np.full((1, 1), -1, np.int32), 0, 0
    r0, c0, width, height = w
    depth, ids = rasterise(_shifted(P, r0, c0), np.ascontiguousarray(F, dtype=np.int32), width, height, NEAR_MM)
    return depth, ids, r0, c0


def contour_points(camera, V, F, X, margin: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(rows (k,), cols (k,), tri (k,) int32, points (k, 3))``: the contour pixels of the
    triangles ``F`` over world vertices ``V (n, 3)`` mm in ``camera`` (covered pixels with a
    4-neighbour that is not, leaving out the image's border rows and columns, where the mesh may
    go on beyond the image), the triangle each sees, and the point of it the pixel's ray meets,
    interpolated over ``X (n, 3)`` (e.g. the rest vertices: the point on the rest mesh)."""
    P = project_vertices(camera, np.asarray(V, dtype=np.float64))
    w = _window(camera, P, margin)
    if w is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3))
    r0, c0, width, height = w
    rows, cols, tri, points = silhouette_contour(_shifted(P, r0, c0), np.ascontiguousarray(F, dtype=np.int32),
                                                 np.ascontiguousarray(X, dtype=np.float64), width, height, NEAR_MM)
    rows, cols = rows + r0, cols + c0
    inside = (rows > 0) & (rows < camera.height - 1) & (cols > 0) & (cols < camera.width - 1)
    return rows[inside], cols[inside], tri[inside], points[inside]


def pixel_points(camera, V, F, ids, rows, cols) -> np.ndarray:
    """``(k, 3)`` barycentric coordinates, on the triangles ``ids (k,)`` of ``F`` over world
    vertices ``V (n, 3)``, of the points where the rays through the pixel centres ``(rows,
    cols) (k,)`` meet them (camera ``camera``). A point on the rest mesh is then
    ``bary @ V_rest[F[ids]]`` whatever pose the mesh was drawn in."""
    tri = camera.to_camera(V[F[ids].reshape(-1)]).reshape(-1, 3, 3)      # (k, corner, xyz)
    d = camera.rays(np.column_stack([cols, rows]).astype(np.float64))     # (k, 3), camera frame
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a
    # Moller-Trumbore: origin at the camera centre (0 in camera coordinates)
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    det = np.where(np.abs(det) > 1e-15, det, 1e-15)
    s = -a
    u = np.einsum("ij,ij->i", s, p) / det
    q = np.cross(s, e1)
    v = np.einsum("ij,ij->i", d, q) / det
    u, v = np.clip(u, 0.0, 1.0), np.clip(v, 0.0, 1.0)
    over = u + v > 1.0
    u[over], v[over] = u[over] / (u[over] + v[over]), v[over] / (u[over] + v[over])
    return np.column_stack([1.0 - u - v, u, v])


__all__ = ["NEAR_MM", "contour_points", "pixel_points", "project_vertices", "render_ids", "render_ids_window"]
