"""The face model's own Posselt rig (facesim.jaw.model_rig): motion generated for the model's TMJ
within its limits, the shipped rig, ``--jaw-model posselt`` and ``facesim jaw fit-model``."""

import numpy as np
import pytest

from facesim import se3
from facesim._files import MESHES
from facesim.jaw.evaluate import pose_errors
from facesim.jaw.model_rig import (
    TEST_SEED,
    find_model_rig,
    fit_model_rig,
    model_motion,
    model_rig_path,
)
from facesim.jaw.motion import JawMotion, Subject, subject_for
from facesim.jaw.points import front_weights, mandible_points
from facesim.jaw.posselt import PosseltRig
from facesim.model import FaceModel
from facesim.kinematics.jaw_models import make_jaw_model
from tests.jaw.test_jaw_cli import run

SHIPPED_RIG = MESHES / "face_coarse_posselt.npz"
MODELS = [p for p in (MESHES / "face_coarse.npz", MESHES / "face_medium.npz") if p.is_file()]


@pytest.fixture(scope="module")
def coarse():
    return FaceModel.load(MESHES / "face_coarse.npz")


@pytest.fixture(scope="module")
def shipped():
    return PosseltRig.load(SHIPPED_RIG)


def test_motion_for_the_model_tmj_stays_within_its_limits(coarse):
    """``subject_for``: the rotation at the maximum opening is the geometry's maximum opening and
    the condyles slide no farther than the tracks allow."""
    g = coarse.jaw
    subject = subject_for(g)
    motion = JawMotion(g, subject)
    assert motion.max_rotation == pytest.approx(g.max_opening, abs=1e-9)
    assert subject.hinge_opening / subject.max_opening == pytest.approx(Subject().hinge_opening /
                                                                       Subject().max_opening)
    assert 40.0 < subject.max_opening < 55.0
    poses = model_motion(g, seed=3).poses
    opening = se3.so3_log(poses[:, :3, :3]) @ g.u            # rotation about the intercondylar axis, rad
    assert opening.max() <= g.max_opening + 1e-6 and opening.max() > g.max_opening - 0.01
    assert motion.measures(poses)["condyle_slide"].max() <= g.track_length


def test_shipped_rig_reproduces_motion_generated_for_the_model_tmj(coarse, shipped):
    """The shipped rig on a session it was not fitted to (another seed, capture noise): < 1 mm mean."""
    assert shipped.made_for(coarse.jaw)
    assert np.allclose(shipped.reference_point, coarse.jaw.incisor)
    test = model_motion(coarse.jaw, seed=TEST_SEED + 5, noise=0.03)
    points = mandible_points(coarse)
    e = pose_errors(shipped.reproduce(test.poses), test.poses, points, front_weights(points, shipped.frame))
    assert e.mean < 1.0 and e.mean < 0.2 and e.p95 < 0.5, e.as_dict()
    assert shipped.bijectivity() > 0.99


def test_shipped_rig_is_up_to_date(coarse, shipped):
    """The shipped file is what ``facesim jaw fit-model`` makes today (regenerate it with
    ``facesim jaw fit-model --model meshes/face_coarse.npz`` after changing the motion or the fit)."""
    fresh = fit_model_rig(coarse.jaw)
    assert np.allclose(fresh.shield.curves, shipped.shield.curves, atol=1e-6)
    assert np.allclose(fresh.coefficients, shipped.coefficients, atol=1e-6)


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_posselt_jaw_model_of_the_shipped_models(path, shipped):
    """Every shipped model has the same TMJ, so ``--jaw-model posselt`` finds the one shipped rig."""
    model = FaceModel.load(path)
    assert find_model_rig(model.jaw) == SHIPPED_RIG
    jaw = make_jaw_model(model, "posselt")
    assert jaw.kind == "posselt" and jaw.frame is None
    q = np.array([0.5, 1.0, 0.0])                        # maximum opening
    assert np.array_equal(jaw.transform(q), shipped.pose_from_sliders(q[None])[0])
    drop = jaw.rig.frame.origin[1] - se3.transform_points(jaw.transform(q), jaw.rig.frame.origin)[0, 1]
    assert drop == pytest.approx(subject_for(model.jaw).max_opening, abs=0.5)


def test_fit_model_command(box_model, tmp_path, capsys):
    model_path = box_model.save(tmp_path / "box.npz")
    assert run(["jaw", "fit-model", "--model", str(model_path)]) == 0
    out = capsys.readouterr().out
    assert "box_posselt.npz" in out and "mean" in out
    rig = PosseltRig.load(model_rig_path(model_path))
    assert rig.made_for(box_model.jaw) and not rig.made_for(FaceModel.load(MESHES / "face_coarse.npz").jaw)
    assert find_model_rig(box_model.jaw, model_path) == model_rig_path(model_path)
    assert find_model_rig(box_model.jaw) is None
    capsys.readouterr()
    assert run(["jaw", "fit-model", "--model", str(tmp_path / "missing.npz")]) == 2
    assert "missing.npz: no such file" in capsys.readouterr().err


def test_generate_for_a_model_tmj(box_model, tmp_path):
    model_path = box_model.save(tmp_path / "box.npz")
    out = tmp_path / "poses.npz"
    assert run(["jaw", "generate", "--model", str(model_path), "--kinds", "border", "-o", str(out)]) == 0
    with np.load(out) as z:
        assert np.allclose(z["reference_point"], box_model.jaw.incisor)
        opening = se3.so3_log(z["poses"][:, :3, :3]) @ box_model.jaw.u
    assert opening.max() == pytest.approx(box_model.jaw.max_opening, abs=0.01)
