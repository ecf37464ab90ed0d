"""The Posselt-envelope rig (facesim.jaw.posselt) and the rig comparison (facesim.jaw.evaluate)."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw import load_rig
from facesim.jaw.evaluate import compare_rigs, format_table, pose_errors
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Subject
from facesim.jaw.points import front_weights, mandible_points, synthetic_mandible
from facesim.jaw.posselt import CURVES, PosseltRig, Shield, detect_border, fit_posselt


@pytest.fixture(scope="module")
def motion():
    return JawMotion(subject=Subject.random(21))


@pytest.fixture(scope="module")
def train(motion):
    return motion.session(seed=1, noise=0.03)


@pytest.fixture(scope="module")
def rig(train):
    return fit_posselt(train)


@pytest.fixture(scope="module")
def points():
    return mandible_points(count=300)


def _envelope_boundary(motion, frame, n=50):
    """Reference-point positions (jaw frame) on the six faces of the generator's control box."""
    c = np.linspace(0.0, 1.0, n)
    a, b = (v.ravel() for v in np.meshgrid(c, c, indexing="ij"))
    lo, hi = np.array([0.0, 0.0, -1.0]), np.array([1.0, 1.0, 1.0])
    faces = []
    for axis in range(3):
        for value in (0.0, 1.0):
            latent = np.empty((len(a), 3))
            other = [k for k in range(3) if k != axis]
            latent[:, axis] = lo[axis] + value * (hi[axis] - lo[axis])
            latent[:, other] = lo[other] + np.c_[a, b] * (hi[other] - lo[other])
            faces.append(frame.pose_to_local(motion.poses(latent))[:, :3, 3])
    return np.concatenate(faces)


def test_jaw_frame_from_data(rig, motion):
    """Zoss section 3.1: origin at the rest reference point, x the opening axis (the condyle
    axis), y up, z forward."""
    assert np.allclose(rig.frame.origin, motion.geometry.incisor)
    assert np.degrees(np.arccos(rig.frame.axes[0] @ motion.u)) < 2.0
    assert rig.frame.axes[1] @ motion.up > 0.999 and rig.frame.axes[2] @ motion.forward > 0.999


def test_reproduces_training_data():
    """On clean data (no capture noise, no joint play) the rig reproduces its training poses."""
    motion = JawMotion(subject=Subject(distraction=0.0))
    session = motion.session(seed=3)
    rig = fit_posselt(session)
    P = mandible_points(count=300)
    errors = se3.vertex_errors(rig.reproduce(session.poses), session.poses, P, front_weights(P, rig.frame))
    assert errors.mean() < 0.1 and errors.max() < 1.0


def test_direct_manipulation_places_the_reference_point(rig, motion):
    latent = np.array([[0.3, 0.4, 0.2], [0.6, 0.1, -0.5], [0.1, 0.9, 0.0]])
    targets = se3.transform_points(motion.poses(latent), motion.geometry.incisor)[:, 0]
    poses = rig.pose_at(targets)
    assert se3.rigidity_error(poses).max() < 1e-12
    placed = se3.transform_points(poses, rig.reference_point)[:, 0]
    assert np.abs(placed - targets).max() < 1e-9                       # inside: the point is kept exactly
    assert se3.vertex_errors(poses, motion.poses(latent), mandible_points(count=200)).max() < 0.3


def test_cube_faces_map_onto_the_envelope(rig, motion):
    """The six faces of the unit cube land on the envelope's boundary (and cover it)."""
    shield = rig.shield
    boundary = _envelope_boundary(motion, rig.frame)
    size = np.ptp(boundary, axis=0).max()
    to_boundary = cKDTree(boundary).query(shield.point(shield.face_samples(30)))[0]
    assert size > 40.0
    assert to_boundary.mean() < 0.5 and to_boundary.max() < 1.5
    to_faces = cKDTree(shield.point(shield.face_samples(120))).query(boundary)[0]
    assert to_faces.mean() < 0.5 and to_faces.max() < 1.5


def test_slider_extremes_reach_the_border_movements(rig, motion, points):
    cases = {                                       # sliders (s_x, s_y, s_z) -> control (o, p, l)
        "rest": ([0.5, 0.0, 0.0], [0.0, 0.0, 0.0]),
        "maximum opening": ([0.5, 1.0, 0.0], [1.0, 0.0, 0.0]),
        "maximum protrusion": ([0.5, 0.0, 1.0], [0.0, 1.0, 0.0]),
        "right laterotrusion": ([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]),
        "left laterotrusion": ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        "left protrusive corner": ([1.0, 0.0, 1.0], [0.0, 1.0, 1.0]),
        "right lateral opening": ([0.0, 1.0, 0.0], [1.0, 0.0, -1.0]),
    }
    sliders = np.array([s for s, _ in cases.values()])
    truth = motion.poses(np.array([c for _, c in cases.values()]))
    errors = se3.vertex_errors(rig.pose_from_sliders(sliders), truth, points)
    assert errors.max() < 0.3, dict(zip(cases, errors.round(3)))
    m = motion.measures(rig.pose_from_sliders(np.array([[0.5, 1.0, 0.5], [0.5, 0.0, 1.0], [1.0, 0.0, 0.0]])))
    assert m["opening"][0] == pytest.approx(motion.subject.max_opening, abs=0.3)
    assert m["protrusion"][1] == pytest.approx(motion.subject.protrusion, abs=0.3)
    assert m["lateral"][2] == pytest.approx(motion.subject.lateral_excursion, abs=0.3)


def test_cube_map_jacobian_matches_central_differences(rig):
    s = np.random.default_rng(4).uniform(0.05, 0.95, (50, 3))
    s[:, 0] = np.where(np.abs(s[:, 0] - 0.5) < 0.01, 0.3, s[:, 0])    # away from the midline crease
    J = rig.shield.jacobian(s)
    assert np.linalg.norm(J, axis=(1, 2)).min() > 1.0
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (rig.shield.point(s + e) - rig.shield.point(s - e)) / (2 * h)
        assert np.abs(fd - J[:, :, k]).max() < 1e-5 * np.abs(J).max()


def test_sliders_invert_the_cube_map(rig):
    rng = np.random.default_rng(5)
    s = rng.uniform(0.02, 0.98, (300, 3))
    s[:, 1] *= 0.9                      # the sections shrink to a line at the maximum opening
    s_back, distance = rig.shield.sliders(rig.shield.point(s))
    assert distance.max() < 1e-8 and np.abs(s_back - s).max() < 1e-6
    assert np.abs(rig.sliders_of(rig.pose_from_sliders(s[:20])) - s[:20]).max() < 1e-6


def test_outside_points_project_onto_the_shield(rig):
    shield = rig.shield
    rng = np.random.default_rng(6)
    centre = shield.point(np.full(3, 0.5))
    outside = centre + rng.normal(size=(60, 3)) * np.array([25.0, 40.0, 25.0])
    s, distance = shield.sliders(outside)
    far = distance > 1.0
    assert far.sum() > 30
    projected = shield.project(outside)
    # the projection is the closest shield point (checked against a dense sample of the faces)
    dense = shield.point(shield.face_samples(150))
    nearest = cKDTree(dense).query(outside[far])[0]
    assert np.allclose(np.linalg.norm(projected[far] - outside[far], axis=1), nearest, atol=0.1)
    on_face = np.isclose(s[far], 0.0) | np.isclose(s[far], 1.0)
    assert on_face.any(axis=1).all()
    inside = shield.point(rng.uniform(0.1, 0.9, (20, 3)))
    assert np.array_equal(shield.project(inside), inside)
    # the rig driven outside the envelope returns the pose at the projected point
    poses = rig.pose_at(rig.frame.to_world(outside[far][:5]))
    assert np.allclose(se3.transform_points(poses, rig.reference_point)[:, 0],
                       rig.frame.to_world(projected[far][:5]), atol=1e-9)


def test_bijectivity_measure(rig):
    """Zoss eq. 15: 1 for the fitted shield; a shield whose posterior corners are swapped
    (the cube folded over itself) scores far lower."""
    assert rig.bijectivity() > 0.99
    c = (np.arange(12) + 0.5) / 12
    det = np.linalg.det(rig.shield.jacobian(np.stack(np.meshgrid(c, c, c, indexing="ij"), -1).reshape(-1, 3)))
    assert np.all(det < 0) or np.all(det > 0)                        # no fold anywhere
    curves = np.array(rig.shield.curves)
    right, left = CURVES.index("right_posterior"), CURVES.index("left_posterior")
    curves[[right, left]] = curves[[left, right]]
    assert Shield(curves).bijectivity() < 0.7


def test_save_load_round_trip(rig, tmp_path):
    path = rig.save(tmp_path / "rig.npz")
    back = PosseltRig.load(path)
    assert isinstance(load_rig(path), PosseltRig)
    s = np.random.default_rng(7).uniform(0, 1, (10, 3))
    assert np.array_equal(back.pose_from_sliders(s), rig.pose_from_sliders(s))

    def rewrite(name, **changes):
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays["meta"]))
        meta.update(changes.pop("meta", {}))
        arrays["meta"] = np.array(json.dumps(meta))
        arrays.update(changes)
        for key in [k for k, v in changes.items() if v is None]:
            del arrays[key]
        np.savez(tmp_path / name, **arrays)
        return tmp_path / name

    with pytest.raises(ModelFileError, match="meta.version"):
        PosseltRig.load(rewrite("v9.npz", meta={"version": 9}))
    with pytest.raises(ModelFileError, match="'centres' missing"):
        PosseltRig.load(rewrite("nocentres.npz", centres=None))
    with pytest.raises(ModelFileError, match="'coefficients'"):
        PosseltRig.load(rewrite("badshape.npz", coefficients=np.zeros((3, 3))))
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(ModelFileError, match="junk.npz: not a readable"):
        PosseltRig.load(tmp_path / "junk.npz")


def test_border_found_in_unlabelled_poses(rig, train, motion, points):
    """Without movement labels the six border curves are found in the reference-point cloud: the
    shield then lies within 0.2 mm (mean) and 1 mm (max) of the one fitted to the labelled border
    movements, both ways, and the rig is as good on a held-out session."""
    local = rig.frame.pose_to_local(train.poses)[:, :3, 3]
    found = detect_border(local)
    for c in CURVES:                   # the curves run along the frames of that very border movement
        near = cKDTree(local[train.frames(c)]).query(found[c])[0]
        assert len(found[c]) >= 20 and (near < 1.0).mean() > 0.9 and np.median(near) < 0.4, c
    shield = Shield.from_cloud(local)
    labelled = rig.shield
    for a, b in ((shield, labelled), (labelled, shield)):
        d = cKDTree(b.point(b.face_samples(120))).query(a.point(a.face_samples(40)))[0]
        assert d.mean() < 0.2 and d.max() < 1.0, (d.mean(), d.max())
    assert shield.bijectivity() > 0.99
    detected = fit_posselt(poses=train.poses, reference_point=train.reference_point, frame=rig.frame)
    assert np.array_equal(detected.shield.curves, shield.curves)
    assert np.array_equal(fit_posselt(train, frame=rig.frame, border="detect").shield.curves, shield.curves)
    test = motion.session(seed=2, noise=0.03)
    w = front_weights(points, rig.frame)
    e_labelled = pose_errors(rig.reproduce(test.poses), test.poses, points, w)
    e_found = pose_errors(detected.reproduce(test.poses), test.poses, points, w)
    assert e_found.mean < 0.2 and e_found.mean < e_labelled.mean + 0.05, (e_found.mean, e_labelled.mean)


def test_border_detection_needs_border_movements(motion):
    speech = motion.session(seed=4, kinds=("speech",))
    with pytest.raises(FacesimError, match="border detection: "):
        detect_border(JawFrame.from_geometry(motion.geometry).pose_to_local(speech.poses)[:, :3, 3])


def test_fit_needs_the_border_movements(train):
    with pytest.raises(FacesimError, match="border movements missing: right_anterior"):
        fit_posselt(poses=train.poses, reference_point=train.reference_point,
                    border={c: train.frames(c) for c in CURVES if c != "right_anterior"})


def test_rigs_ranked_on_a_held_out_session(motion, train, points):
    """Zoss Fig. 8 on generated motion: fitted on one session, evaluated on another of the same
    subject with the front-weighted error, 1-DOF > 3-DOF > 5-DOF > Posselt rig, the latter < 1 mm."""
    test = motion.session(seed=2, noise=0.03)
    frame = JawFrame.from_poses(train.poses, train.reference_point)
    weights = front_weights(points, frame)
    assert weights[np.argmax(frame.to_local(points)[:, 2])] == 1.0 and weights.min() == pytest.approx(0.1)
    reports = compare_rigs(train, test, points, weights, rigs=("1dof", "3dof", "5dof", "posselt"), frame=frame)
    mean = {name: r.test.mean for name, r in reports.items()}
    assert mean["1dof"] > mean["3dof"] > mean["5dof"] > mean["posselt"], format_table(reports)
    assert mean["posselt"] < 1.0 and reports["posselt"].test.p95 < 1.0
    assert mean["posselt"] < 0.2                                       # the RBF matters: affine alone gives ~0.25
    assert reports["posselt"].train.mean < 0.1                         # and it reproduces its training poses
    assert mean["5dof"] > 2 * mean["posselt"]
    for r in reports.values():
        assert r.test.p95 <= r.test.max and r.test.mean <= r.test.max


def test_synthetic_mandible_without_model(motion):
    P = synthetic_mandible(motion.geometry, count=150)
    frame = JawFrame.from_geometry(motion.geometry)
    local = frame.to_local(P)
    assert P.shape == (150, 3)
    assert local[:, 2].max() > -5 and local[:, 2].min() < -70                 # incisors to condyles
    assert np.abs(local[:, 0]).max() > 40
    top = np.argmax(local[:, 1])
    assert local[top, 1] > 30 and abs(abs(local[top, 0]) - 50) < 10         # the condyles are highest
    assert local[:, 1].min() < -20                                          # the body lies below the incisor
