"""Up-front plausibility checks: impossible jaw poses and colliders are refused before any solve."""

import numpy as np
import pytest

from facesim.contact import Collider, KinematicPath, Sphere
from facesim.errors import FacesimError
from facesim.fem.plausible import check_colliders, check_jaw, jaw_limits
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.kinematics.jaw_models import RigidJaw


def test_jaw_limits_follow_the_model(box_model):
    angle, shift = jaw_limits(box_model)          # max_opening 0.5 rad, track 10 mm
    assert angle == pytest.approx(0.75) and shift == pytest.approx(30.0)


@pytest.mark.parametrize("opening, translation, what", [
    (10.0, (0, 0, 0), "rotated"),     # 10 rad = 1.6 turns: 2.57 rad away from rest
    (-3.0, (0, 0, 0), "rotated"),
    (0.0, (0, 0, 1e30), "moved"),
    (0.0, (0, 40.0, 0), "moved"),
])
def test_impossible_rigid_jaw_poses_are_refused(box_model, opening, translation, what):
    jaw = RigidJaw()
    good = [RigidJaw.from_rotation(box_model, 0.3), RigidJaw.from_rotation(box_model, -0.05, translation=(0, 0, 2))]
    check_jaw(box_model, jaw, [0, 1], good, "jaw.csv")       # plausible poses pass
    bad = RigidJaw.from_rotation(box_model, opening, translation=translation)
    with pytest.raises(FacesimError) as err:
        check_jaw(box_model, jaw, [0, 1, 7], good + [bad], "jaw.csv")
    message = str(err.value)
    assert message.startswith("jaw.csv: frame 7:") and what in message and "\n" not in message


def test_sliding_condyle_poses_within_bounds_pass(box_model):
    jaw = SlidingCondyleJaw(box_model.jaw)
    lo, hi = np.asarray(jaw.bounds).T
    check_jaw(box_model, jaw, [0, 1], [lo, hi], "jaw.csv")


def test_a_collider_that_engulfs_the_head_is_refused(box_model):
    huge = Collider(Sphere((0.0, 0.0, 0.0), 200.0), name="moon")
    scene = (huge,)
    with pytest.raises(FacesimError, match=r"collider 'moon' at frame 0 reaches .* mm into flesh attached"):
        check_colliders(box_model, scene, [0])


def test_a_collider_that_holds_most_of_the_skin_but_no_bone_is_refused(box_model):
    # a thin slab over the whole front of the box: no bone inside, but most of the skin
    X = box_model.X
    front = X[:, 2].max()
    slab = Collider(Sphere((0.0, 0.0, front + 1e4 - 12.0), 1e4), name="wall")   # ~ a half-space z > front - 12
    scene = (slab,)
    skin = np.unique(box_model.skin)
    assert np.mean(X[skin, 2] > front - 12.0) < 0.5   # the slab holds fewer than half: accepted
    check_colliders(box_model, scene, [0])
    deep = Collider(Sphere((0.0, 0.0, front + 1e4 - 25.0), 1e4), name="wall")
    scene = (deep,)
    assert np.mean(X[skin, 2] > front - 25.0) > 0.5
    with pytest.raises(FacesimError, match="holds .*% of the skin"):
        check_colliders(box_model, scene, [0])


def test_a_ball_pressing_the_cheek_passes_and_a_path_is_checked_per_frame(box_model):
    front = box_model.X[:, 2].max()
    ball = Collider(Sphere((0.0, 0.0, 0.0), 6.0), name="ball")
    centres = np.array([[10.0, 0.0, front + 4.0], [10.0, 0.0, front - 2.0], [10.0, 5.0, -12.0]])
    path = KinematicPath.from_centres(ball, [0, 1, 2], centres)
    scene = (path,)
    check_colliders(box_model, scene, [0, 1])                   # outside, then 2 mm into the skin
    with pytest.raises(FacesimError, match="at frame 2 reaches"):   # then through the flesh to the bone
        check_colliders(box_model, scene, [0, 1, 2])


def test_colliders_carried_by_the_jaw_follow_the_frames_controls(box_model):
    """A collider on the jaw is posed with each frame's jaw: checked with the controls given."""
    from facesim.contact.scene import SceneCollider

    ball = SceneCollider(Collider(Sphere((0.0, -20.0, 40.0), 5.0), name="bite"), bone="jaw", name="bite")
    scene = (ball,)
    check_colliders(box_model, scene, [0])
    # a jaw moved up and back carries the ball into the skull's attachment
    T = RigidJaw.from_rotation(box_model, 0.0, translation=(0.0, 25.0, -50.0))
    with pytest.raises(FacesimError, match="'bite' at frame 3"):
        check_colliders(box_model, scene, [3], RigidJaw(), [T])
