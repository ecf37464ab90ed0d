"""Colliders as signed distance functions: closed forms, mesh grids, derivatives, poses, paths."""

import numpy as np
import pytest
import trimesh
from scipy.ndimage import map_coordinates
from scipy.spatial.transform import Rotation

from facesim.contact import Capsule, Collider, KinematicPath, MeshSDF, Plane, Sphere
from facesim.errors import FacesimError


def rigid(seed, shift=(3.0, -2.0, 5.0)):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = shift
    return T


def oracle_capsule(p, a, b, r):
    ab = b - a
    s = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1) - r


def torus_distance(p, R, r):
    return np.hypot(np.hypot(p[:, 0], p[:, 1]) - R, p[:, 2]) - r


@pytest.fixture(scope="module")
def sphere_grid():
    """MeshSDF of an icosphere (radius 15 mm, 5120 faces) at 1 mm spacing."""
    m = trimesh.creation.icosphere(4, 15.0)
    return MeshSDF.from_mesh(m.vertices, m.faces, spacing=1.0, margin=5.0)


def fd_gradient(f, p, h=1e-6):
    G = np.empty_like(p)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        G[:, k] = (f(p + e) - f(p - e)) / (2 * h)
    return G


def check_derivatives(shape, p, hessian=True, h=1e-6):
    """Gradient and Hessian of ``shape`` at ``p`` against central differences."""
    _, G, H = shape.evaluate(p, hessian=True)
    assert np.linalg.norm(G, axis=1).min() > 0.5
    np.testing.assert_allclose(fd_gradient(shape.distance, p, h), G, atol=1e-6)
    if hessian:
        H_fd = np.stack([fd_gradient(lambda q, k=k: shape.gradient(q)[:, k], p, h) for k in range(3)], axis=1)
        np.testing.assert_allclose(H_fd, H, atol=2e-5)
        np.testing.assert_allclose(H, np.transpose(H, (0, 2, 1)), atol=1e-14)
    return H


def test_closed_forms():
    rng = np.random.default_rng(0)
    p = rng.uniform(-20, 20, (300, 3))
    c, a, b = np.array([1.0, -2.0, 3.0]), np.array([-5.0, 1.0, 0.0]), np.array([6.0, 2.0, -3.0])
    np.testing.assert_allclose(Sphere(c, 4.0).distance(p), np.linalg.norm(p - c, axis=1) - 4.0, atol=1e-12)
    n = np.array([1.0, 2.0, -2.0])
    np.testing.assert_allclose(Plane(c, n).distance(p), (p - c) @ (n / 3.0), atol=1e-12)
    np.testing.assert_allclose(Capsule(a, b, 2.5).distance(p), oracle_capsule(p, a, b, 2.5), atol=1e-12)
    # a degenerate capsule is a sphere
    np.testing.assert_allclose(Capsule(c, c, 4.0).distance(p), Sphere(c, 4.0).distance(p), atol=1e-12)
    # signs: the centre is inside, points along the plane normal outside
    assert Sphere(c, 4.0).distance(c)[0] == -4.0
    assert Capsule(a, b, 2.5).distance((a + b) / 2)[0] == -2.5
    assert Plane(c, n).distance(c + n)[0] == pytest.approx(3.0)


@pytest.mark.parametrize("which", ["sphere", "plane", "capsule", "capsule_caps", "posed_capsule"])
def test_closed_form_derivatives(which):
    rng = np.random.default_rng(1)
    p = rng.uniform(-10, 10, (40, 3))
    a, b = np.array([-4.0, 0.0, 0.0]), np.array([4.0, 1.0, 0.0])
    shape = {"sphere": Sphere([0.5, 0.0, 1.0], 3.0), "plane": Plane([0, 0, 1.0], [0.3, -1.0, 2.0]),
             "capsule": Capsule(a, b, 2.0), "capsule_caps": Capsule(a, b, 2.0),
             "posed_capsule": Collider(Capsule(a, b, 2.0), rigid(3))}[which]
    if which == "capsule_caps":   # points beyond the ends: the spherical caps
        p = np.r_[a + rng.normal(size=(20, 3)) - [4, 0, 0], b + rng.normal(size=(20, 3)) + [4, 0, 0]]
    H = check_derivatives(shape, p)
    if which == "plane":
        assert np.abs(H).max() == 0.0
    else:
        assert np.abs(H).max() > 1e-3


def test_mesh_sdf_matches_sphere(sphere_grid):
    sdf, h = sphere_grid, sphere_grid.spacing
    rng = np.random.default_rng(2)
    u = rng.normal(size=(4000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = rng.uniform(15.0 - 2.0, 15.0 + 2.0, (4000, 1))
    p = u * r
    err = sdf.distance(p) - (r[:, 0] - 15.0)
    assert np.abs(err).max() < 0.1 * h
    # gradient of the interpolant points along the radius near the surface
    G = sdf.gradient(p)
    assert np.einsum("ij,ij->i", G / np.linalg.norm(G, axis=1, keepdims=True), u).min() > 0.98
    # deep inside and far outside: right sign and within half a cell of the exact distance
    q = rng.uniform(*sdf.bounds, (4000, 3))
    exact = np.linalg.norm(q, axis=1) - 15.0
    clear = np.abs(exact) > 0.1   # the facets lie up to 0.03 mm inside the exact sphere
    assert np.all(np.sign(sdf.distance(q))[clear] == np.sign(exact)[clear])
    assert np.abs(sdf.distance(q) - exact).max() < 0.5 * h
    # outside the grid box: distance to the box plus the boundary value (an upper bound)
    far = np.array([[40.0, 0.0, 0.0], [0.0, -35.0, 30.0]])
    assert np.all(sdf.distance(far) >= np.linalg.norm(far, axis=1) - 15.0 - 0.1)
    assert sdf.distance(far)[0] == pytest.approx(25.0, abs=0.1)


def test_mesh_sdf_non_convex_torus():
    """A torus (non-convex, with a hole): the sign needs containment, not normals of one side."""
    m = trimesh.creation.torus(12.0, 4.0, major_sections=128, minor_sections=48)
    m.invert()   # face orientation must not matter
    sdf = MeshSDF.from_mesh(m.vertices, m.faces, spacing=0.5, margin=3.0)
    q = np.random.default_rng(3).uniform(*sdf.bounds, (20000, 3))
    exact = torus_distance(q, 12.0, 4.0)
    d = sdf.distance(q)
    near = np.abs(exact) < 1.5
    assert near.sum() > 1000
    assert np.abs(d - exact)[near].max() < 0.1 * sdf.spacing
    clear = np.abs(exact) > 0.1
    assert np.all(np.sign(d)[clear] == np.sign(exact)[clear])
    # the hole is outside; its centre is a kink of the distance (a cone's apex), which the cubic
    # spline rounds by a fraction of a cell, the trilinear grid reproduces
    assert sdf.distance([0.0, 0.0, 0.0])[0] == pytest.approx(8.0, abs=0.4)
    linear = MeshSDF(sdf.origin, sdf.spacing, sdf.values, interpolation="linear")
    assert linear.distance([0.0, 0.0, 0.0])[0] == pytest.approx(8.0, abs=0.05)


def test_grid_kernels_against_scipy_splines(sphere_grid):
    """Cubic (default): the cubic B-spline with the samples as coefficients, continued linearly
    beyond the box; linear: trilinear interpolation, exact at the nodes."""
    sdf = sphere_grid
    assert sdf.interpolation == "cubic"
    rng = np.random.default_rng(4)
    lo, hi = sdf.bounds
    q = rng.uniform(lo + 2 * sdf.spacing, hi - 2 * sdf.spacing, (500, 3))   # the boundary rule aside
    idx = ((q - sdf.origin) / sdf.spacing).T
    np.testing.assert_allclose(sdf.distance(q), map_coordinates(sdf.values, idx, order=3, prefilter=False),
                               atol=1e-12)
    # a linear field is reproduced everywhere in the box, up to its faces
    ramp = sdf.origin[None, None, None] + sdf.spacing * np.stack(np.indices(sdf.shape), -1)
    ramp = ramp @ np.array([0.3, -0.5, 0.8])
    line = MeshSDF(sdf.origin, sdf.spacing, ramp)
    q = rng.uniform(lo, hi, (500, 3))
    np.testing.assert_allclose(line.distance(q), q @ np.array([0.3, -0.5, 0.8]), atol=1e-9)
    np.testing.assert_allclose(line.gradient(q), np.tile([0.3, -0.5, 0.8], (500, 1)), atol=1e-9)
    linear = MeshSDF(sdf.origin, sdf.spacing, sdf.values, interpolation="linear")
    np.testing.assert_allclose(linear.distance(q), map_coordinates(sdf.values, ((q - sdf.origin) / sdf.spacing).T,
                                                                  order=1), atol=1e-12)
    # grid nodes reproduce the stored values (linear)
    ijk = np.array([[0, 0, 0], [5, 7, 9], [s - 1 for s in sdf.shape]])
    np.testing.assert_allclose(linear.distance(sdf.origin + sdf.spacing * ijk), sdf.values[tuple(ijk.T)], atol=1e-12)
    with pytest.raises(FacesimError, match="interpolation"):
        MeshSDF(sdf.origin, sdf.spacing, sdf.values, interpolation="quintic")


def test_cubic_grid_gradient_is_continuous_across_cell_faces(sphere_grid):
    """C2: no jump of the gradient where a point crosses a cell face (the trilinear one jumps)."""
    sdf = sphere_grid
    linear = MeshSDF(sdf.origin, sdf.spacing, sdf.values, interpolation="linear")
    rng = np.random.default_rng(7)
    p = rng.normal(size=(200, 3))
    p = p / np.linalg.norm(p, axis=1, keepdims=True) * rng.uniform(13.0, 17.0, (200, 1))
    p[:, 0] = sdf.origin[0] + np.round((p[:, 0] - sdf.origin[0]) / sdf.spacing) * sdf.spacing
    e = np.array([1e-9, 0.0, 0.0])
    assert np.abs(sdf.gradient(p + e) - sdf.gradient(p - e)).max() < 1e-6
    assert np.abs(sdf.hessian(p + e) - sdf.hessian(p - e)).max() < 1e-5
    assert np.abs(linear.gradient(p + e) - linear.gradient(p - e)).max() > 1e-3


def test_mesh_sdf_derivatives(sphere_grid):
    """Gradient and Hessian of the grid SDF, inside cells (away from the faces where the trilinear
    gradient would jump) and outside the grid box."""
    sdf = sphere_grid
    rng = np.random.default_rng(5)
    cells = rng.integers(0, np.array(sdf.shape) - 1, (60, 3))
    p = sdf.origin + sdf.spacing * (cells + rng.uniform(0.1, 0.9, (60, 3)))
    H = check_derivatives(sdf, p)
    assert np.abs(H).max() > 1e-3
    lo, hi = sdf.bounds
    outside = np.array([[lo[0] - 3.0, 0.37, 2.61],            # beyond one face
                        [hi[0] + 2.0, hi[1] + 1.0, -4.42],    # beyond an edge
                        hi + [2.0, 1.0, 4.0]])                # beyond a corner
    check_derivatives(sdf, outside)
    T = rigid(6)
    check_derivatives(Collider(sdf, T), p[:10] @ T[:3, :3].T + T[:3, 3])


def test_mesh_sdf_build_errors():
    m = trimesh.creation.icosphere(2, 5.0)
    with pytest.raises(FacesimError, match="not a closed surface") as e:
        MeshSDF.from_mesh(m.vertices, m.faces[1:], name="teeth")
    assert "\n" not in str(e.value) and "teeth" in str(e.value)
    with pytest.raises(FacesimError, match="spacing"):
        MeshSDF.from_mesh(m.vertices, m.faces, spacing=0.0)
    with pytest.raises(FacesimError, match="indices"):
        MeshSDF.from_mesh(m.vertices, m.faces + 1000)


def test_moved_colliders_equal_moved_closed_forms(sphere_grid):
    T = rigid(7)
    R, t = T[:3, :3], T[:3, 3]
    p = np.random.default_rng(8).uniform(-20, 20, (200, 3))
    c, a, b = np.array([1.0, 2.0, 0.5]), np.array([-3.0, 0.0, 1.0]), np.array([2.0, 4.0, -1.0])
    n = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(Collider(Sphere(c, 3.0), T).distance(p), np.linalg.norm(p - (R @ c + t), axis=1) - 3.0,
                               atol=1e-12)
    np.testing.assert_allclose(Collider(Capsule(a, b, 2.0), T).distance(p),
                               oracle_capsule(p, R @ a + t, R @ b + t, 2.0), atol=1e-12)
    np.testing.assert_allclose(Collider(Plane(c, n), T).distance(p), (p - (R @ c + t)) @ (R @ n), atol=1e-12)
    # the mesh grid follows its pose: compare with the exact moved sphere near its surface
    u = np.random.default_rng(9).normal(size=(500, 3))
    u *= np.random.default_rng(10).uniform(13.5, 16.5, (500, 1)) / np.linalg.norm(u, axis=1, keepdims=True)
    moved = Collider(sphere_grid, T)
    np.testing.assert_allclose(moved.distance(u + t), np.linalg.norm(u, axis=1) - 15.0, atol=0.1)
    # gradients rotate with the pose
    G_local = Sphere(c, 3.0).gradient((p - t) @ R)
    np.testing.assert_allclose(Collider(Sphere(c, 3.0), T).gradient(p), G_local @ R.T, atol=1e-12)
    # at() is absolute, moved_by() composes
    base = Collider(Sphere(np.zeros(3), 1.0), rigid(0, (1.0, 0.0, 0.0)))
    np.testing.assert_allclose(base.at(T).transform, T)
    np.testing.assert_allclose(base.moved_by(T).transform, T @ base.transform)
    assert base.transform[0, 3] == 1.0   # unchanged


def test_non_rigid_pose_is_rejected():
    with pytest.raises(FacesimError, match="rigid"):
        Collider(Sphere(np.zeros(3), 1.0), np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(FacesimError, match="rigid"):
        Collider(Sphere(np.zeros(3), 1.0)).at(np.diag([-1.0, 1.0, 1.0, 1.0]))   # a reflection


def test_kinematic_path_from_csv(tmp_path):
    f = tmp_path / "ball.csv"
    f.write_text("frame,x,y,z\n0,0,0,10\n10,0,0,0\n20,5,0,0\n")
    path = KinematicPath.from_csv(f, Sphere(np.zeros(3), 2.0))
    assert len(path) == 3
    np.testing.assert_allclose(path.at_frame(0).transform[:3, 3], [0, 0, 10])
    np.testing.assert_allclose(path.at_frame(5).transform[:3, 3], [0, 0, 5])
    np.testing.assert_allclose(path.at_frame(15).transform[:3, 3], [2.5, 0, 0])
    np.testing.assert_allclose(path.at_frame(-3).transform[:3, 3], [0, 0, 10])   # holds before the first
    np.testing.assert_allclose(path.at_frame(99).transform[:3, 3], [5, 0, 0])    # and after the last
    assert path.at_frame(5).distance([0.0, 0.0, 0.0])[0] == pytest.approx(3.0)
    # rotations are interpolated on SO(3)
    T0, T1 = np.eye(4), np.eye(4)
    T1[:3, :3] = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    mid = KinematicPath(Capsule([0, 0, 0], [1, 0, 0], 0.5), [0, 2], [T0, T1]).transform_at(1)
    np.testing.assert_allclose(mid[:3, :3], Rotation.from_rotvec([0, 0, np.pi / 4]).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("text, message", [
    ("frame,x,y\n0,1,2\n", "missing column"),
    ("frame,x,y,z\n0,1,two,3\n", "line 2, column 'y'"),
    ("frame,x,y,z\n3,0,0,0\n1,0,0,0\n", "increasing"),
    ("x,y,z\n1,2,3\n", "'frame'"),
    ("", "empty"),
])
def test_kinematic_path_bad_files(tmp_path, text, message):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(FacesimError, match=message) as e:
        KinematicPath.from_csv(f, Sphere(np.zeros(3), 1.0))
    assert "\n" not in str(e.value) and "bad.csv" in str(e.value)
    with pytest.raises(FacesimError, match="no such"):
        KinematicPath.from_csv(tmp_path / "missing.csv", Sphere(np.zeros(3), 1.0))


def test_inputs_are_copied_and_checked():
    c = np.array([1.0, 2.0, 3.0])
    T = np.eye(4)
    s = Collider(Sphere(c, 1.0), T)
    c[0] = 100.0
    T[0, 3] = 50.0
    assert s.distance([1.0, 2.0, 3.0])[0] == -1.0
    assert T.flags.writeable
    with pytest.raises(FacesimError, match="finite"):
        s.distance([[np.nan, 0.0, 0.0]])
    with pytest.raises(FacesimError, match=r"\(k, 3\)"):
        s.distance(np.zeros((4, 2)))


def test_mesh_sdf_of_the_shipped_teeth_with_degenerate_triangles():
    """Marching-cubes surfaces carry zero-area triangles; the grid build must not divide by zero."""
    from pathlib import Path

    from facesim.model import load_model

    model = load_model(Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz")
    teeth = model.surface("upper_teeth")
    v = teeth.vertices[teeth.faces]
    assert (np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) < 1e-12).any()
    sdf = MeshSDF.from_mesh(teeth.vertices, teeth.faces, spacing=1.0)
    d = sdf.distance(teeth.vertices)
    assert np.isfinite(d).all() and np.abs(d).max() < 0.6   # vertices lie on the surface (grid error)
    centre = teeth.vertices.mean(axis=0) + np.array([0.0, 0.0, 40.0])   # well in front of the teeth
    assert sdf.distance(centre[None])[0] > 10.0
