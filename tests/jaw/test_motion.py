"""Synthetic TMJ motion (facesim.jaw.motion): rigidity, anatomical ranges, hinge then
translation, Bennett movement, hysteresis, reproducibility."""

import dataclasses

import numpy as np
import pytest

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.motion import BORDER_CURVES, JawMotion, Subject
from facesim.model import JawGeometry


@pytest.fixture(scope="module")
def motion():
    return JawMotion()                                  # the shipped model's TMJ, default subject


def test_poses_are_rigid_with_noise(motion):
    session = motion.session(seed=3, noise=0.05)
    assert len(session.poses) > 1000
    assert se3.rigidity_error(session.poses).max() < 1e-12
    assert np.allclose(session.poses[0], np.eye(4), atol=0.5)        # starts at rest (plus noise)
    assert np.array_equal(motion.poses(np.zeros(3)), np.eye(4))


@pytest.mark.parametrize("subject_seed", [None, 0, 1, 2, 3])
def test_ranges_are_anatomical(subject_seed):
    """docs/physics.md section 3: maximum incisal opening 46-51 mm, protrusion ~8-9 mm, lateral
    excursion ~9-12 mm per side, condylar translation at maximum opening 12-20 mm."""
    subject = Subject() if subject_seed is None else Subject.random(subject_seed)
    motion = JawMotion(subject=subject)
    session = motion.session(seed=11)
    m = motion.measures(session.poses)
    assert 46.0 <= m["opening"].max() <= 51.0
    assert abs(m["opening"].max() - subject.max_opening) < 0.1
    assert 8.0 <= m["protrusion"].max() <= 9.0
    assert 9.0 <= m["lateral"].max() <= 12.0 and 9.0 <= -m["lateral"].min() <= 12.0
    at_max = np.argmax(m["opening"])
    assert 12.0 <= m["condyle_slide"][at_max].mean() <= 20.0
    # ramus rotation at the maximum opening, about 36-39 degrees for typical subjects
    assert 30.0 < np.degrees(motion.max_rotation) < 44.0


def test_hinge_then_translation():
    subject = Subject(distraction=0.0)
    motion = JawMotion(subject=subject)
    session = motion.session(seed=5, kinds=("border",))
    frames = session.frames("posterior")
    opening_pass = frames[: np.argmax(session.latent[frames, 0]) + 1]
    m = motion.measures(session.poses[opening_pass])
    slide = m["condyle_slide"].mean(axis=1)
    hinge = m["opening"] < subject.hinge_opening - 0.5
    assert hinge.sum() > 10 and (~hinge).sum() > 10
    assert slide[hinge].max() < 1e-9                                   # pure rotation
    assert np.all(np.diff(slide[~hinge]) >= -1e-9)                     # then the condyles slide out
    chord = np.linalg.norm(motion.path(subject.condyle_translation))    # arc length 15 mm on a curved path
    assert chord < subject.condyle_translation and abs(slide[-1] - chord) < 0.01
    # the condyles descend the eminence at its inclination (30-45 degrees below horizontal)
    moved = se3.transform_points(session.poses[opening_pass[-1]], motion.cR)[0] - motion.cR
    incline = np.degrees(np.arctan2(-moved @ motion.up, moved @ motion.forward))
    assert 30.0 <= incline <= 45.0


def test_lateral_excursion_bennett_movement(motion):
    """Left laterotrusion: the right (balancing) condyle travels forward and down the eminence,
    the left (working) condyle turns nearly in place and shifts outward (Bennett shift)."""
    pose = motion.poses(np.array([0.0, 0.0, 1.0]))
    balancing = se3.transform_points(pose, motion.cR)[0] - motion.cR
    working = se3.transform_points(pose, motion.cL)[0] - motion.cL
    assert balancing @ motion.forward > 5.0 and balancing @ motion.up < -3.0
    assert np.linalg.norm(working) < 2.0
    assert working @ motion.u > 0.5 * motion.subject.bennett_shift          # outward, to the left
    assert motion.measures(pose[None])["lateral"][0] == pytest.approx(motion.subject.lateral_excursion)
    # symmetric anatomy: the right excursion mirrors the left one
    right = motion.measures(motion.poses(np.array([[0.0, 0.0, -1.0]])))["lateral"][0]
    assert right == pytest.approx(-motion.subject.lateral_excursion, abs=1e-6)


def test_opening_closing_hysteresis(motion):
    latent = np.array([[0.8, 0.0, 0.0], [0.8, 0.0, 0.0]])
    opening, closing = motion.poses(latent, direction=np.array([1.0, -1.0]))
    slides = [motion.measures(T[None])["condyle_slide"][0].mean() for T in (opening, closing)]
    assert slides[0] - slides[1] > 0.5 * motion.subject.hysteresis       # condyles lead on opening
    # in a session, the same opening is reached with different poses going down and coming up
    session = motion.session(seed=2, kinds=("border",))
    frames = session.frames("posterior")
    o = session.latent[frames, 0]
    down, up = frames[: np.argmax(o)], frames[np.argmax(o):]
    i, j = down[np.argmin(abs(o[: len(down)] - 0.6))], up[np.argmin(abs(o[len(down):] - 0.6))]
    assert se3.vertex_errors(session.poses[i], session.poses[j], np.stack([motion.cR, motion.cL])) > 0.2


def test_sessions_reproducible_by_seed(motion):
    a, b, c = motion.session(seed=7, noise=0.02), motion.session(seed=7, noise=0.02), motion.session(seed=8)
    assert np.array_equal(a.poses, b.poses) and a.segments == b.segments
    assert len(a.poses) != len(c.poses) or not np.allclose(a.poses, c.poses)
    assert Subject.random(4) == Subject.random(4) and Subject.random(4) != Subject.random(5)


def test_session_content(motion, tmp_path):
    session = motion.session(seed=1)
    names = {s.name for s in session.segments}
    assert set(BORDER_CURVES) <= names and {"chewing", "speech", "free"} <= names
    m = motion.measures(session.poses)
    assert m["opening"][session.frames("speech")].max() < 20.0          # speech: small openings
    chew = m["opening"][session.frames("chewing")]
    assert 8.0 < chew.max() < 25.0
    # border tracings reach the maximum opening
    assert m["opening"][session.frames("anterior")].max() == pytest.approx(motion.subject.max_opening, abs=0.05)
    session.save(tmp_path / "poses.npz")
    with np.load(tmp_path / "poses.npz") as data:
        assert np.array_equal(data["poses"], session.poses)
        assert list(data["segment_names"]) == [s.name for s in session.segments]


def test_explicit_geometry_without_model():
    geometry = JawGeometry(condyle_right=np.array([-48.0, 0.0, 0.0]), condyle_left=np.array([48.0, 0.0, 0.0]),
                           track_direction=np.array([0.0, -np.sin(0.6), np.cos(0.6)]), track_length=15.0,
                           max_opening=0.6, incisor=np.array([0.0, -42.0, 84.0]))
    motion = JawMotion(geometry, Subject.random(9))
    m = motion.measures(motion.session(seed=0).poses)
    assert 46.0 <= m["opening"].max() <= 51.0


def test_bad_input_is_refused(motion):
    with pytest.raises(FacesimError, match="latent"):
        motion.poses(np.array([1.5, 0.0, 0.0]))
    with pytest.raises(FacesimError, match="hinge_opening"):
        Subject(hinge_opening=60.0)
    with pytest.raises(FacesimError, match="unknown movement"):
        motion.session(kinds=("yawning",))
    with pytest.raises(FacesimError, match="max_opening"):
        JawMotion(subject=dataclasses.replace(Subject(), max_opening=95.0))
