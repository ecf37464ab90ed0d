"""facesim.importing.frame and .landmarks: the anatomical frame and the landmarks, found on the
procedural template (an input made independently of this code), on the same meshes moved by a
random rigid motion and written in metres or centimetres, and on the ArtiSynth Badin face."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import facesim
from facesim._kernels.importing import front_depth
from facesim._files import MESHES
from facesim.errors import FacesimError
from facesim.importing import frame as fr
from facesim.importing.landmarks import (LANDMARK_NAMES, Mesh, bone_landmarks, find_landmarks,
                                         jaw_geometry_from_landmarks, load_landmarks, write_landmarks)
from facesim.importing.meshes import (clean_surface, infer_units, read_surface, read_volume, split_skin,
                                      volume_boundary)
from facesim.model import FaceModel

ANATOMY = Path(os.environ.get("FACESIM_ANATOMY", Path(facesim.__file__).resolve().parents[2] / "shared" / "anatomy"))
BADIN = ANATOMY / "badin"
needs_badin = pytest.mark.skipif(not (BADIN / "flesh.vtu").is_file(), reason=f"no Badin data at {BADIN}")
ROLES = ("mandible", "cranium", "teeth_upper", "teeth_lower", "skin")


@pytest.fixture(scope="module")
def template():
    """The procedural model's surfaces as a user would give them (mm, facesim frame)."""
    model = FaceModel.load(MESHES / "face_coarse.npz")
    by = {s.name: s for s in model.bones + model.colliders}
    src = {"mandible": by["mandible"], "cranium": by["cranium"], "teeth_upper": by["upper_teeth"],
           "teeth_lower": by["lower_teeth"]}
    surfaces = {r: clean_surface(s.vertices, s.faces, f"{r}.obj", r) for r, s in src.items()}
    surfaces["skin"] = clean_surface(model.X, model.skin, "skin.obj", "skin")
    return model, surfaces


def _fit(s, scale=1.0, units="mm", **kw):
    return fr.anatomical_frame(s["mandible"], [s["cranium"]], skin=s["skin"], teeth_upper=s["teeth_upper"],
                               teeth_lower=s["teeth_lower"], scale_to_mm=scale, units=units, **kw)


def _landmarks(fit, s):
    return find_landmarks(fit, s["mandible"], [s["cranium"]], s["skin"], s["teeth_upper"], s["teeth_lower"])


@pytest.fixture(scope="module")
def template_fit(template):
    model, s = template
    fit = _fit(s)
    return fit, *_landmarks(fit, s)


# ====================================================================================== kernel
def test_front_depth_matches_a_plain_numpy_oracle():
    rng = np.random.default_rng(3)
    mesh = trimesh.creation.icosphere(2, radius=10.0)
    V = mesh.vertices + rng.normal(0, 0.5, mesh.vertices.shape)
    F = mesh.faces.astype(np.int64)
    x0, y0, h = -12.0, -11.0, 0.7
    z = np.full((35, 33), -np.inf)
    front_depth(V, F, x0, y0, h, z)
    gx, gy = np.meshgrid(x0 + h * np.arange(35), y0 + h * np.arange(33), indexing="ij")
    P = np.stack([gx.ravel(), gy.ravel()], axis=1)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    den = (B[:, 1] - C[:, 1]) * (A[:, 0] - C[:, 0]) + (C[:, 0] - B[:, 0]) * (A[:, 1] - C[:, 1])
    l1 = ((B[:, 1] - C[:, 1])[None] * (P[:, :1] - C[:, 0]) + (C[:, 0] - B[:, 0])[None] * (P[:, 1:] - C[:, 1])) / den
    l2 = ((C[:, 1] - A[:, 1])[None] * (P[:, :1] - C[:, 0]) + (A[:, 0] - C[:, 0])[None] * (P[:, 1:] - C[:, 1])) / den
    l3 = 1 - l1 - l2
    zz = l1 * A[:, 2] + l2 * B[:, 2] + l3 * C[:, 2]
    inside = (l1 >= -1e-12) & (l2 >= -1e-12) & (l3 >= -1e-12)
    oracle = np.where(inside, zz, -np.inf).max(axis=1).reshape(35, 33)
    assert np.isfinite(oracle).sum() > 300
    assert np.array_equal(np.isfinite(z), np.isfinite(oracle))
    assert np.allclose(z[np.isfinite(z)], oracle[np.isfinite(oracle)])


# =================================================================================== template
def test_template_reference_directions_are_the_templates(template):
    """The sagittal reference of the frame is the template's own landmarks by these rules."""
    _, s = template
    mesh = {r: Mesh(x.vertices, x.faces) for r, x in s.items()}
    found, _ = bone_landmarks(mesh["mandible"], mesh["cranium"], mesh["teeth_upper"], mesh["teeth_lower"])
    origin = 0.5 * (found["condyle_left"] + found["condyle_right"])
    for name, ref in fr.TEMPLATE_SAGITTAL.items():
        assert np.allclose((found[name] - origin)[[1, 2]], ref, atol=0.3), name
    found, how = bone_landmarks(mesh["mandible"], mesh["cranium"], None, None)        # no teeth: on bone
    origin = 0.5 * (found["condyle_left"] + found["condyle_right"])
    for name, ref in fr.TEMPLATE_SAGITTAL_BONE.items():
        assert "no " in how[name] and np.allclose((found[name] - origin)[[1, 2]], ref, atol=0.3), name


def test_template_frame_without_teeth_or_skin(template):
    _, s = template
    for fit in (fr.anatomical_frame(s["mandible"], [s["cranium"]]), fr.anatomical_frame(s["mandible"])):
        assert np.degrees(Rotation.from_matrix(fit.R).magnitude()) < 1.0            # achieved < 0.01
        assert np.linalg.norm(fit.T[:3, 3]) < 1.5                                    # ~0.7


def test_template_frame_is_the_identity(template, template_fit):
    model, _ = template
    fit, found, how = template_fit
    angle = np.degrees(Rotation.from_matrix(fit.R).magnitude())
    assert angle < 1.5                                             # achieved ~1 degree
    assert np.linalg.norm(fit.T[:3, 3]) < 1.5                      # mm; achieved ~0.7
    assert fit.symmetry_rms_mm < 1.5
    for side in ("left", "right"):
        assert np.linalg.norm(found[f"condyle_{side}"] - getattr(model.jaw, f"condyle_{side}")) < 2.0   # ~0.7
    assert np.linalg.norm(found["incisor"] - model.jaw.incisor) < 2.0                                 # ~1.4
    assert set(found) == set(LANDMARK_NAMES) and set(how) == set(found)
    # the textbook spots of docs/physics.md section 6, loosely (the phantom's shapes are simple)
    assert np.linalg.norm(found["upper_incisor"] - [0, -38, 82]) < 3.0
    assert np.linalg.norm(found["pogonion"] - [0, -78, 79]) < 5.0
    assert abs(found["menton"][1] + 88) < 3.0
    assert found["pronasale"][2] == pytest.approx(np.max(model.X[np.unique(model.skin), 2]), abs=1.0)
    assert found["nasion"][1] > found["pronasale"][1] + 15 > found["subnasale"][1] + 15
    assert found["labiale_superius"][1] > found["stomion"][1] > found["labiale_inferius"][1]
    assert abs(found["stomion"][1] + 39.5) < 3.0
    for side, sign in (("left", 1), ("right", -1)):
        c = found[f"cheilion_{side}"]
        assert 15 < sign * c[0] < 32 and abs(c[1] + 40) < 6          # physics.md: (+-26, -40, 88)


def test_jaw_geometry_from_the_template_landmarks(template, template_fit):
    model, _ = template
    _, found, _ = template_fit
    jaw = jaw_geometry_from_landmarks(found)
    assert np.allclose(jaw.track_direction, model.jaw.track_direction, atol=0.03)
    assert abs(jaw.track_direction @ jaw.u) < 1e-12
    assert (jaw.track_length, jaw.max_opening) == (16.0, 0.62)
    assert jaw.intercondylar_distance == pytest.approx(100.0, abs=2.0)
    assert np.linalg.norm(jaw.incisor - model.jaw.incisor) < 2.0
    with pytest.raises(FacesimError, match="incisor missing"):
        jaw_geometry_from_landmarks({k: v for k, v in found.items() if k != "incisor"})


@pytest.mark.parametrize("units,scale,formats", [("m", 1e-3, (".obj", ".ply", ".stl", ".obj", ".ply")),
                                                 ("cm", 0.1, (".ply", ".stl", ".obj", ".off", ".stl"))])
def test_moved_and_rescaled_inputs_give_the_same_landmarks(tmp_path, template, template_fit, units, scale, formats):
    _, s = template
    _, reference, _ = template_fit
    rng = np.random.default_rng(7 if units == "m" else 11)
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-300, 300, 3)
    files = {}
    for role, suffix in zip(ROLES, formats):
        path = tmp_path / f"{role}{suffix}"
        trimesh.Trimesh(scale * (s[role].vertices @ R.T + t), s[role].faces, process=False).export(path)
        files[role] = read_surface(path, role)
    k, name, reason = infer_units(np.concatenate([f.vertices for f in files.values()]))
    assert name == units and "auto" in reason
    fit = _fit(files, scale=k, units=name)
    found, _ = _landmarks(fit, files)
    assert set(found) == set(reference)
    err = {n: float(np.linalg.norm(found[n] - reference[n])) for n in reference}
    assert max(err.values()) < 1.0, err                            # achieved ~0.1-0.5 mm
    # the fit undoes the motion: its transform composed with the motion is the template's own
    back = fit.to_input(found["pronasale"][None])[0]
    assert np.allclose(back, scale * (fit.to_input(found["pronasale"][None])[0] / scale), atol=1e-9)
    assert np.allclose(fit.to_facesim(fit.to_input(found["menton"][None])), found["menton"], atol=1e-9)


def test_frame_spec():
    R = fr.parse_frame_spec("x=-forward,y=right,z=up")             # Badin's frame
    assert np.array_equal(R, [[0, -1, 0], [0, 0, 1], [-1, 0, 0]])
    assert np.array_equal(fr.parse_frame_spec("x=backward, z=up"), R)           # the third follows
    assert np.array_equal(fr.parse_frame_spec("y=up,z=forward"), np.eye(3))
    for bad, msg in (("x=-forward,y=left,z=up", "mirrored"), ("x=up,y=up", "twice"), ("x=sideways,y=up", "unknown"),
                     ("z=up", "at least two"), ("w=up,x=left", "axis must be")):
        with pytest.raises(FacesimError, match=msg):
            fr.parse_frame_spec(bad)


def test_frame_spec_on_the_template(template):
    _, s = template
    fit = _fit(s, spec="x=left,y=up")
    assert np.allclose(fit.R, np.eye(3)) and fit.how.startswith("spec")
    assert np.linalg.norm(fit.T[:3, 3]) < 1.5


# ==================================================================================== files
def test_landmark_files_round_trip(tmp_path, template_fit):
    fit, found, how = template_fit
    path = write_landmarks(tmp_path / "lm.json", found, how, fit)
    doc = json.loads(path.read_text())
    assert doc["units"] == "mm" and doc["frame"] == "facesim" and set(doc["landmarks"]) == set(found)
    assert np.allclose(doc["input_frame"]["T_facesim_from_input_mm"], fit.T, atol=1e-8)
    back = load_landmarks(path)
    assert back.frame == "facesim" and all(np.allclose(back.in_facesim()[n], found[n], atol=1e-6) for n in found)
    # a user's file in the input frame and units
    user = tmp_path / "user.json"
    p_in = fit.to_input(found["pronasale"][None])[0] + [0.0, 0.0, 1.0]
    user.write_text(json.dumps({"frame": "input", "units": "input", "landmarks": {"pronasale": p_in.tolist()}}))
    lf = load_landmarks(user)
    assert np.allclose(lf.in_facesim(fit)["pronasale"], fit.to_facesim(p_in[None])[0])
    with pytest.raises(FacesimError, match="need the anatomical frame"):
        lf.in_facesim()
    for content, msg in (({"landmarks": {"nose": [0, 0, 0]}}, "unknown landmark 'nose'; known: condyle_left"),
                         ({"landmarks": {"menton": [0, 0]}}, "landmarks.menton': expected"),
                         ({"landmarks": {}, "frame": "world"}, "field 'frame'"), ([1, 2], "field 'landmarks'")):
        user.write_text(json.dumps(content))
        with pytest.raises(FacesimError, match=msg) as e:
            load_landmarks(user)
        assert str(user) in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(FacesimError, match="no such file"):
        load_landmarks(tmp_path / "none.json")


def test_frame_fit_maps_back_and_forth(template_fit):
    fit, _, _ = template_fit
    P = np.random.default_rng(0).normal(size=(5, 3)) * 50
    assert np.allclose(fit.to_input(fit.to_facesim(P)), P)
    assert np.allclose(fit.inverse @ fit.T, np.eye(4))
    assert np.allclose(np.linalg.det(fit.R), 1.0)
    assert json.dumps(fit.meta())


# ======================================================================================== Badin
@pytest.fixture(scope="module")
def badin():
    names = ("mandible", "maxilla", "teeth_lower", "teeth_upper")
    s = {n: read_surface(BADIN / f"{n}.obj", n) for n in names}
    v = read_volume(BADIN / "flesh.vtu")
    scale, units, _ = infer_units(np.concatenate([v.X] + [b.vertices for b in s.values()]))
    X = scale * v.X
    split = split_skin(X, volume_boundary(X, v.tets), [b.transformed(np.eye(4), scale) for b in s.values()])
    s["skin"] = clean_surface(v.X, split.outer, v.path, "skin")
    fit = fr.anatomical_frame(s["mandible"], [s["maxilla"]], skin=s["skin"], teeth_upper=s["teeth_upper"],
                              teeth_lower=s["teeth_lower"], scale_to_mm=scale, units=units)
    found, how = find_landmarks(fit, s["mandible"], [s["maxilla"]], s["skin"], s["teeth_upper"], s["teeth_lower"])
    return s, units, fit, found, how


@needs_badin
def test_badin_frame(badin):
    _, units, fit, _, _ = badin
    assert units == "m"

    def angle(a, b):
        return np.degrees(np.arccos(np.clip(a @ b, -1, 1)))

    assert angle(fit.axis("up"), np.array([0, 0, 1.0])) < 3.0            # achieved ~0.6
    assert angle(fit.axis("forward"), np.array([-1.0, 0, 0])) < 3.0       # achieved ~0.6
    assert angle(fit.axis("left"), np.array([0, -1.0, 0])) < 3.0          # +y is the subject's right
    assert fit.symmetry_rms_mm < 1.5
    assert fit.occlusal_deg is not None and 3 < fit.occlusal_deg < 12     # a real occlusal plane's tilt
    spec = fr.anatomical_frame(badin[0]["mandible"], [badin[0]["maxilla"]], scale_to_mm=1000.0,
                               spec="x=backward,y=right,z=up")
    assert np.degrees(Rotation.from_matrix(spec.R @ fit.R.T).magnitude()) < 3.0
    assert np.linalg.norm(spec.T[:3, 3] - fit.T[:3, 3]) < 3.0


@needs_badin
def test_badin_landmarks(badin):
    s, _, fit, found, how = badin
    assert set(found) == set(LANDMARK_NAMES)
    left, right = found["condyle_left"], found["condyle_right"]
    assert 90 < np.linalg.norm(left - right) < 110
    assert abs(left[0] + right[0]) < 3 and np.allclose(left[1:], right[1:], atol=3)   # symmetric
    for name in ("gonion", "cheilion"):
        l, r = found[f"{name}_left"], found[f"{name}_right"]
        assert l[0] > 20 and r[0] < -20 and abs(l[0] + r[0]) < 4 and np.allclose(l[1:], r[1:], atol=4), name
    inc = found["incisor"]
    assert inc[2] > 60 and inc[1] < -25                                  # in front of and below the condyles
    assert found["upper_incisor"][1] > inc[1] - 1
    assert found["menton"][1] < found["pogonion"][1] < inc[1]
    skin = fit.to_facesim(s["skin"].vertices)
    assert found["pronasale"][2] == pytest.approx(skin[:, 2].max(), abs=1.0)   # the most forward skin point
    assert found["nasion"][1] > found["pronasale"][1] > found["subnasale"][1] > found["stomion"][1]
    assert found["labiale_superius"][1] > found["stomion"][1] > found["labiale_inferius"][1] > found["soft_pogonion"][1]
    assert found["soft_pogonion"][2] > found["pogonion"][2] + 5            # soft tissue over the chin
    assert all(isinstance(how[n], str) and how[n] for n in found)


def _slit_face(lower_back: float, half_width: float = 25.0) -> Mesh:
    """A height-field face (1 mm grid, nose at the origin) whose lower lip and chin sit
    ``lower_back`` mm behind the upper lip, with a 2 mm slit between the lips at y = -40."""
    xs, ys = np.arange(-60.0, 61.0), np.arange(-110.0, 61.0)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    Z = 100.0 - 0.004 * X**2 - np.where(Y < -40.0, lower_back, 0.0) + 15.0 * np.exp(-(X**2 + Y**2) / 60.0)
    V = np.c_[X.ravel(), Y.ravel(), Z.ravel()]
    idx = np.arange(len(V)).reshape(X.shape)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    F = np.r_[np.c_[a.ravel(), b.ravel(), c.ravel()], np.c_[a.ravel(), c.ravel(), d.ravel()]]
    centre = V[F].mean(axis=1)
    slit = (np.abs(centre[:, 0]) < half_width) & (np.abs(centre[:, 1] + 40.0) < 1.0)
    return Mesh(V, F[~slit])


@pytest.mark.parametrize("lower_back", [0.0, 3.0, 6.0, 10.0])
def test_stomion_across_a_gap_whatever_the_lips_depths(lower_back):
    """The lips' slit is found from the gap in the profile, however far the lower lip sits behind
    the upper one (a 5 mm 'deep' threshold used to swallow a lower lip 5 mm back, and with it the
    stomion and the mouth corners: one in four fTetWild meshes of the Badin face)."""
    from facesim.importing.landmarks import skin_landmarks

    bones = {"incisor": np.array([0.0, -43.0, 85.0]), "upper_incisor": np.array([0.0, -39.0, 88.0]),
             "menton": np.array([0.0, -85.0, 70.0])}
    found, how = skin_landmarks(_slit_face(lower_back), bones)
    assert "gap" in how["stomion"]
    np.testing.assert_allclose(found["stomion"][:2], [0.0, -40.0], atol=1.0)
    assert found["stomion"][2] == pytest.approx(100.0 - lower_back / 2, abs=0.6)   # between the lips' edges
    for name, side in (("cheilion_left", 1), ("cheilion_right", -1)):
        assert side * found[name][0] == pytest.approx(25.0, abs=1.5), name
    assert found["labiale_inferius"][1] < -40.0 < found["labiale_superius"][1]
