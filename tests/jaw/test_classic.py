"""Traditional 1/3/5/6-DOF jaw rigs (facesim.jaw.classic)."""

import numpy as np
import pytest

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw.classic import DOF, ClassicRig, fit_classic, pivot_estimate
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion
from facesim.jaw.points import front_weights, mandible_points

PIVOT = np.array([0.0, 38.0, -84.0])      # jaw frame: near the condyles, behind and above the incisor


@pytest.fixture(scope="module")
def setup():
    motion = JawMotion()
    frame = JawFrame.from_geometry(motion.geometry)
    points = mandible_points(count=300)
    return motion, frame, points, front_weights(points, frame)


def _random_q(rng, dof, n):
    scale = {"pitch": 0.4, "yaw": 0.1, "roll": 0.05, "tx": 2.0, "ty": 3.0, "tz": 6.0}
    return np.stack([rng.uniform(-1, 1, n) * scale[name] for name in DOF[dof]], axis=1)


@pytest.mark.parametrize("dof", list(DOF))
def test_rig_reproduces_its_own_poses(setup, dof):
    _, frame, points, weights = setup
    rng = np.random.default_rng(0)
    rig = ClassicRig(dof, frame, PIVOT)
    q = _random_q(rng, dof, 50)
    poses = rig.transform(q)
    assert poses.shape == (50, 4, 4) and se3.rigidity_error(poses).max() < 1e-12
    q_fit = rig.fit_parameters(poses, points, weights)
    assert np.abs(q_fit - q).max() < 1e-8
    assert se3.vertex_errors(rig.reproduce(poses, points, weights), poses, points).max() < 1e-8


@pytest.mark.parametrize("dof", ["3dof", "6dof"])
def test_pose_derivatives_match_central_differences(setup, dof):
    _, frame, _, _ = setup
    rig = ClassicRig(dof, frame, PIVOT)
    full = rig._full(_random_q(np.random.default_rng(3), dof, 4))
    _, dT = rig._local(full)
    assert np.linalg.norm(dT) > 1.0
    h = 1e-6
    for j in range(6):
        step = np.zeros(6)
        step[j] = h
        fd = (rig._local(full + step)[0] - rig._local(full - step)[0]) / (2 * h)
        assert np.abs(fd - dT[j]).max() < 1e-7 * max(1.0, np.abs(dT[j]).max())


def test_parameter_meaning(setup):
    """Pitch opens about the pivot's x axis (chin down), tz slides forward, in the jaw frame."""
    _, frame, _, _ = setup
    rig = ClassicRig("3dof", frame, PIVOT)
    incisor = frame.origin
    opened = se3.transform_points(rig.transform(np.array([0.3, 0.0, 0.0])), incisor)[0]
    local = frame.to_local(opened)
    arm = -PIVOT                                                        # pivot -> incisor
    expected = se3.so3_exp(np.array([0.3, 0.0, 0.0])) @ arm + PIVOT
    assert np.allclose(local, expected) and local[1] < -10
    slid = frame.to_local(se3.transform_points(rig.transform(np.array([0.0, 0.0, 4.0])), incisor)[0])
    assert np.allclose(slid, [0.0, 0.0, 4.0])


def test_pivot_is_recovered(setup):
    """Poses made by a 3-DOF rig about a known pivot: fitting from a prior 8 mm away, without the
    regulariser, finds the pivot and the parameters (Zoss eqs. 6-8)."""
    _, frame, points, weights = setup
    rng = np.random.default_rng(1)
    true = ClassicRig("3dof", frame, PIVOT)
    q = _random_q(rng, "3dof", 80)
    fit = fit_classic(true.transform(q), "3dof", frame, points, weights,
                      origin0=PIVOT + np.array([3.0, -5.0, 5.5]), regularization=0.0)
    assert np.abs(fit.rig.origin - PIVOT).max() < 1e-4
    assert fit.cost < 1e-12 and np.abs(fit.q - q).max() < 1e-6
    assert np.allclose(fit.rig.bounds, np.stack([q.min(0), q.max(0)], axis=1), atol=1e-6)
    # a strong regulariser keeps the pivot at the prior instead
    prior = PIVOT + np.array([0.0, -5.0, 5.0])
    held = fit_classic(true.transform(q), "3dof", frame, points, weights, origin0=prior, regularization=1e4)
    assert np.linalg.norm(held.rig.origin - prior) < 0.05 < held.cost


def test_pivot_estimate_of_a_hinge(setup):
    _, frame, _, _ = setup
    rig = ClassicRig("1dof", frame, PIVOT)
    local = frame.pose_to_local(rig.transform(np.linspace(0.05, 0.6, 12)[:, None]))
    assert np.allclose(pivot_estimate(local)[1:], PIVOT[1:], atol=1e-6)    # along x: unidentifiable


def test_more_freedom_fits_better(setup):
    """On generated motion each richer rig fits at least as well, and 6-DOF is exact."""
    motion, frame, points, weights = setup
    poses = motion.session(seed=4, kinds=("border", "chewing")).poses
    costs = [fit_classic(poses, dof, frame, points, weights).cost for dof in DOF]
    assert costs[0] > costs[1] > costs[2] > costs[3]
    assert costs[3] < 1e-16 and costs[0] > 1.0


def test_save_load(setup, tmp_path):
    frame = setup[1]
    rig = ClassicRig("5dof", frame, PIVOT, np.tile([-1.0, 2.0], (5, 1)))
    path = rig.save(tmp_path / "five.npz")
    back = ClassicRig.load(path)
    q = _random_q(np.random.default_rng(2), "5dof", 5)
    assert back.dof == "5dof" and np.array_equal(back.transform(q), rig.transform(q))
    assert np.array_equal(back.bounds, rig.bounds)
    assert np.isinf(ClassicRig("1dof", frame, PIVOT).bounds).all()
    with pytest.raises(ModelFileError, match="'classic' rig"):
        from facesim.jaw.rigfile import save_rig
        save_rig(tmp_path / "other.npz", "posselt", {}, {})
        ClassicRig.load(tmp_path / "other.npz")
    with pytest.raises(ModelFileError, match="no such file"):
        ClassicRig.load(tmp_path / "missing.npz")


def test_bad_input(setup):
    _, frame, points, _ = setup
    with pytest.raises(FacesimError, match="unknown dof"):
        ClassicRig("4dof", frame, PIVOT)
    with pytest.raises(FacesimError, match="parameters"):
        ClassicRig("3dof", frame, PIVOT).transform(np.zeros(2))
    with pytest.raises(FacesimError, match="poses"):
        fit_classic(np.eye(4), "1dof", frame, points)
