"""The z-buffer kernel against a plain numpy oracle (ray-triangle intersection per pixel)."""

import numpy as np

from facesim.teeth.cameras import look_at
from facesim.teeth.raster import pixel_points, project_vertices, render_ids, render_ids_window


def _oracle(camera, V, F):
    """Per pixel: the nearest triangle hit by the ray through the pixel centre (camera frame),
    found by solving ``o + s d = a + u (b - a) + v (c - a)`` for every triangle."""
    Y = camera.to_camera(V)
    depth = np.full((camera.height, camera.width), np.inf)
    ids = np.full((camera.height, camera.width), -1)
    Kinv = np.linalg.inv(camera.K)
    for i in range(camera.height):
        for j in range(camera.width):
            d = Kinv @ np.array([j, i, 1.0])
            for f, (a, b, c) in enumerate(F):
                A = np.column_stack([d, Y[a] - Y[b], Y[a] - Y[c]])
                if abs(np.linalg.det(A)) < 1e-12:
                    continue
                s, u, v = np.linalg.solve(A, Y[a])
                if u >= 0 and v >= 0 and u + v <= 1 and s > 0:
                    z = s * d[2]
                    if z < depth[i, j]:
                        depth[i, j], ids[i, j] = z, f
    return depth, ids


def _scene(seed):
    rng = np.random.default_rng(seed)
    K = np.array([[60.0, 0.0, 19.5], [0.0, 60.0, 14.5], [0.0, 0.0, 1.0]])
    cam = look_at("c", eye=(5.0, 3.0, 100.0), target=(0.0, 0.0, 0.0), K=K, size=(40, 30))
    V = rng.uniform([-25, -20, -20], [25, 20, 20], size=(12, 3))
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11], [0, 4, 8], [2, 6, 10]], dtype=np.int32)
    return cam, V, F


def test_kernel_matches_the_oracle():
    for seed in range(3):
        cam, V, F = _scene(seed)
        depth, ids = render_ids(cam, V, F)
        d0, i0 = _oracle(cam, V, F)
        covered = i0 >= 0
        assert covered.sum() > 100 and len(np.unique(i0[covered])) >= 4     # not a trivial scene
        same = ids == i0
        # pixel centres exactly on an edge may go either way: almost all must agree
        assert same.mean() > 0.995, seed
        both = same & covered
        assert np.abs(depth[both] - d0[both]).max() < 1e-9
        assert np.isinf(depth[~covered & same]).all()


def test_window_render_matches_the_full_image():
    cam, V, F = _scene(4)
    _, ids = render_ids(cam, V, F)
    _, w, r0, c0 = render_ids_window(cam, V, F)
    full = np.full(ids.shape, -1)
    full[r0:r0 + w.shape[0], c0:c0 + w.shape[1]] = w
    assert (full == ids).all() and (ids >= 0).sum() > 100


def test_pixel_points_lie_on_their_triangles_and_rays():
    cam, V, F = _scene(5)
    depth, ids = render_ids(cam, V, F)
    rows, cols = np.nonzero(ids >= 0)
    bary = pixel_points(cam, V, F, ids[rows, cols], rows, cols)
    assert (bary >= -1e-12).all() and np.allclose(bary.sum(axis=1), 1.0)
    X = np.einsum("kc,kcx->kx", bary, V[F[ids[rows, cols]]])
    P = project_vertices(cam, X)
    assert np.abs(P[:, 0] - cols).max() < 1e-6 and np.abs(P[:, 1] - rows).max() < 1e-6
    assert np.abs(P[:, 2] - depth[rows, cols]).max() < 1e-6


def test_contour_points_match_the_numpy_route():
    """The fused kernel against the z-buffer's inner boundary (numpy) and :func:`pixel_points`."""
    from facesim.teeth.raster import contour_points

    cam, V, F = _scene(6)
    X = V * 2.0 + 1.0                          # points interpolated over other vertices
    _, ids = render_ids(cam, V, F)
    m = ids >= 0
    inner = m.copy()
    inner[1:, :] &= m[:-1, :]
    inner[:-1, :] &= m[1:, :]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    edge = m & ~inner
    edge[0, :] = edge[-1, :] = edge[:, 0] = edge[:, -1] = False    # the image's border is left out
    rows, cols = np.nonzero(edge)
    bary = pixel_points(cam, V, F, ids[rows, cols], rows, cols)
    ref = np.einsum("kc,kcx->kx", bary, X[F[ids[rows, cols]]])
    r, c, tri, pts = contour_points(cam, V, F, X)
    assert len(r) > 30 and (r == rows).all() and (c == cols).all() and (tri == ids[rows, cols]).all()
    assert np.abs(pts - ref).max() < 1e-9
