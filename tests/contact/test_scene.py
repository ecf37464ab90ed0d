"""External colliders: the --collider syntax, motion with bones and scripted paths, drawing surfaces."""

import numpy as np
import pytest
import trimesh

from facesim.contact import Capsule, Collider, KinematicPath, MeshSDF, Plane, Sphere, translation
from facesim.contact.scene import SceneCollider, as_scene_collider, parse_collider_spec
from facesim.controls import rotation_about
from facesim.errors import FacesimError


def test_sphere_with_centre_is_fixed_in_the_world():
    c = parse_collider_spec("sphere:radius=12,centre=55:-30:70,name=ball")
    assert c.name == "ball" and c.bone == "world"
    posed = c.at(3)
    np.testing.assert_allclose(posed.distance(np.array([[55.0, -30.0, 70.0], [55.0, -30.0, 90.0]])), [-12.0, 8.0])


def test_sphere_on_a_path_is_interpolated_between_rows(tmp_path):
    (tmp_path / "ball.csv").write_text("frame,x,y,z\n0,0,0,100\n10,0,0,80\n")
    c = parse_collider_spec("sphere:radius=5,path=ball.csv", base=tmp_path, index=2)
    assert c.name == "sphere2" and isinstance(c.shape, KinematicPath)
    np.testing.assert_allclose(c.at(5).distance(np.array([[0.0, 0.0, 90.0]])), [-5.0])
    np.testing.assert_allclose(c.at(20).distance(np.array([[0.0, 0.0, 80.0]])), [-5.0])   # holds the last pose


def test_capsule_plane_and_mesh(tmp_path):
    cap = parse_collider_spec("capsule:radius=4,a=0:0:0,b=0:0:40").at(0)
    np.testing.assert_allclose(cap.distance(np.array([[10.0, 0.0, 20.0]])), [6.0])
    plane = parse_collider_spec("plane:point=0:-70:0,normal=0:2:0").at(0)
    np.testing.assert_allclose(plane.distance(np.array([[3.0, -60.0, 1.0]])), [10.0])
    trimesh.creation.box((20, 20, 20)).export(tmp_path / "cube.stl")
    mesh = parse_collider_spec(f"mesh:file={tmp_path / 'cube.stl'},spacing=1,scale=0.5").at(0)
    assert isinstance(mesh.sdf, MeshSDF)
    # 2 mm inside the top face and 3 mm above it (the centre is the distance's apex, rounded by the spline)
    np.testing.assert_allclose(mesh.distance(np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 8.0]])), [-2.0, 3.0], atol=0.05)


def test_bone_carried_collider_moves_with_its_bone():
    c = parse_collider_spec("sphere:radius=3,centre=0:-40:80,bone=jaw")
    Hj = rotation_about([0.3, 0.0, 0.0], [0.0, 0.0, 0.0])
    posed = c.at(0, cranium=np.eye(4), jaw=Hj)
    centre = Hj[:3, :3] @ np.array([0.0, -40.0, 80.0])
    np.testing.assert_allclose(posed.distance(centre[None]), [-3.0], atol=1e-12)
    head = parse_collider_spec("sphere:radius=3,centre=0:0:0,bone=cranium").at(0, cranium=translation([5, 0, 0]))
    np.testing.assert_allclose(head.distance(np.array([[5.0, 0.0, 0.0]])), [-3.0])


@pytest.mark.parametrize("spec, words", [
    ("cube:size=3", "KIND one of sphere"),
    ("sphere", "KIND:key=value"),
    ("sphere:centre=0:0:0", "missing radius"),
    ("sphere:radius=-1", "radius='-1': expected a positive number"),
    ("sphere:radius=2,centre=1:2", "centre='1:2': expected three numbers"),
    ("sphere:radius=2,colour=red", "unknown or malformed entry 'colour=red'"),
    ("sphere:radius=2,radius=3", "radius given twice"),
    ("sphere:radius=2,centre=0:0:0,path=p.csv", "either centre or path"),
    ("sphere:radius=2,path=nowhere.csv", "no such file"),
    ("sphere:radius=2,bone=skull", "bone must be one of world, cranium, jaw"),
    ("mesh:file=nowhere.stl", "no such file"),
])
def test_bad_specs_say_what_is_wrong(spec, words, tmp_path):
    with pytest.raises(FacesimError, match=words):
        parse_collider_spec(spec, base=tmp_path)


def test_unreadable_mesh_file(tmp_path):
    (tmp_path / "junk.stl").write_text("not a mesh")
    with pytest.raises(FacesimError, match="junk.stl"):
        parse_collider_spec("mesh:file=junk.stl", base=tmp_path)


def test_as_scene_collider_accepts_shapes_colliders_and_paths():
    s = as_scene_collider(Sphere((0, 0, 0), 2), 4)
    assert s.name == "collider4" and isinstance(s.shape, Collider)
    path = KinematicPath.from_centres(Collider(Sphere((0, 0, 0), 2), name="ball"), [0, 1], [[0, 0, 0], [0, 0, 1]])
    assert as_scene_collider(path).name == "ball"
    with pytest.raises(FacesimError, match="expected a Collider"):
        as_scene_collider("sphere")
    with pytest.raises(FacesimError, match="bone must be"):
        SceneCollider(Sphere((0, 0, 0), 1), bone="hand")


@pytest.mark.parametrize("shape", [Sphere((1, 2, 3), 5), Capsule((0, 0, 0), (0, 10, 10), 2), Plane((0, 0, 0), (1, 1, 0))])
def test_surfaces_lie_on_the_zero_level_set(shape):
    c = Collider(shape, rotation_about([0.1, 0.2, 0.3], [1, 1, 1]))
    V, F = c.surface()
    assert F.shape[1] == 3 and F.max() < len(V)
    np.testing.assert_allclose(c.distance(V), 0.0, atol=1e-9)


def test_mesh_sdf_surface_without_source_mesh_is_its_level_set():
    box = trimesh.creation.box((10, 10, 10))
    sdf = MeshSDF.from_mesh(box.vertices, box.faces, spacing=1.0)
    assert sdf.surface()[0] is sdf.mesh[0]
    grid_only = MeshSDF(sdf.origin, sdf.spacing, sdf.values)
    V, F = grid_only.surface()
    assert len(F) > 100
    np.testing.assert_allclose(np.abs(V).max(axis=0), 5.0, atol=0.1)
