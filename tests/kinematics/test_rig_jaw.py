"""Fitted jaw rigs as the simulator's jaw model (facesim.kinematics.rig_jaw) on the shipped model."""

import numpy as np
import pytest

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.classic import fit_classic
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion
from facesim.jaw.nlpca import fit_nlpca
from facesim.jaw.points import front_weights, mandible_points
from facesim.jaw.posselt import CURVES, fit_posselt
from facesim.kinematics.rig_jaw import RigJaw, rig_jaw_from_spec



@pytest.fixture(scope="module")
def rigs(model, tmp_path_factory):
    """Posselt, NLPCA and 3-DOF rigs fitted to motion generated for the model's own TMJ, saved."""
    session = JawMotion(model.jaw).session(seed=5, noise=0.03)
    frame = JawFrame.from_poses(session.poses, session.reference_point)
    points = mandible_points(model, count=200)
    weights = front_weights(points, frame)
    folder = tmp_path_factory.mktemp("rigs")
    fitted = {"posselt": fit_posselt(session, frame=frame),
              "nlpca": fit_nlpca(session.poses, frame, points=points, weights=weights, iterations=250),
              "classic": fit_classic(session.poses, "3dof", frame, points, weights).rig}
    paths = {kind: rig.save(folder / f"{kind}.npz") for kind, rig in fitted.items()}
    return fitted, paths, points, session


def _interior(jaw, rng, n=1):
    lo, hi = jaw.bounds.T
    q = lo + (hi - lo) * rng.uniform(0.15, 0.85, (n, jaw.n_params))
    if jaw.kind == "posselt":                         # away from the midline crease of the shield
        q[:, 0] = np.where(np.abs(q[:, 0] - 0.5) < 0.05, 0.3, q[:, 0])
    if jaw.kind == "nlpca":
        q = np.array([jaw.clamp(x) for x in q])
    return q


@pytest.mark.parametrize("kind", ["posselt", "nlpca", "classic"])
def test_rest_controls_give_the_rest_pose(model, rigs, kind):
    _, paths, points, _ = rigs
    jaw = rig_jaw_from_spec(model, f"{kind}:{paths[kind]}")
    assert jaw.frame is None                              # fitted in the model's own skull frame
    T = jaw.transform(None)
    assert T.shape == (4, 4) and se3.rigidity_error(T) < 1e-9
    assert se3.vertex_errors(T, np.eye(4), points) < 0.1
    assert np.array_equal(T, jaw.transform(jaw.rest))
    if kind == "posselt":
        assert np.allclose(jaw.rest, [0.5, 0.0, 0.0], atol=0.05)
        assert np.array_equal(jaw.bounds, [[0.0, 1.0]] * 3)
    else:
        assert np.array_equal(jaw.rest, np.zeros(3))
        assert np.all(jaw.bounds[:, 0] <= 0.0) and np.all(jaw.bounds[:, 1] >= 0.0)


@pytest.mark.parametrize("kind", ["posselt", "nlpca", "classic"])
def test_transform_follows_the_rig(rigs, kind):
    rig = rigs[0][kind]
    jaw = RigJaw(rig)
    q = _interior(jaw, np.random.default_rng(0), 4)
    expected = rig.pose_from_sliders(q) if kind == "posselt" else rig.transform(q)
    assert np.allclose(np.stack([jaw.transform(x) for x in q]), expected, atol=1e-12)
    # and parameters() inverts it
    for x in q:
        assert np.abs(jaw.parameters(jaw.transform(x)) - x).max() < 1e-4


@pytest.mark.parametrize("kind", ["posselt", "nlpca", "classic"])
def test_jacobian_matches_central_differences(rigs, kind):
    jaw = RigJaw(rigs[0][kind])
    rng = np.random.default_rng(1)
    for q in _interior(jaw, rng, 3):
        J = jaw.jacobian(q)
        assert J.shape == (4, 4, jaw.n_params) and np.abs(J[3]).max() == 0.0
        assert np.linalg.norm(J, axis=(0, 1)).min() > 1e-3
        h = 1e-4 * (jaw.bounds[:, 1] - jaw.bounds[:, 0])
        for k in range(jaw.n_params):
            e = np.zeros(jaw.n_params)
            e[k] = h[k]
            fd = (jaw.transform(q + e) - jaw.transform(q - e)) / (2 * h[k])
            assert np.abs(fd - J[..., k]).max() < 1e-5 * max(1.0, np.abs(J[..., k]).max())


@pytest.mark.parametrize("kind", ["posselt", "nlpca", "classic"])
def test_penalty_is_zero_inside_with_exact_derivatives_outside(rigs, kind):
    jaw = RigJaw(rigs[0][kind], penalty_weight=[2.0, 3.0, 5.0])
    rng = np.random.default_rng(2)
    for q in _interior(jaw, rng, 3):
        value, grad, hess = jaw.penalty(q)
        assert value == 0.0 and not grad.any() and not hess.any()
    lo, hi = jaw.bounds.T
    width = hi - lo
    states = [lo - 0.1 * width, hi + 0.2 * width, np.array([lo[0] + 0.5 * width[0], hi[1] + 0.3 * width[1],
                                                            lo[2] - 0.2 * width[2]])]
    if kind == "nlpca":                # d1 inside its range: d2, d3 measured against the d1-dependent ranges
        rig = jaw.rig
        d1 = rig.grid[10]
        low, high = rig.ranges(d1)
        states.append(np.array([d1, high[0] + 0.3, low[1] - 0.2]))
    for q in states:
        value, grad, hess = jaw.penalty(q)
        assert value > 0 and np.linalg.norm(grad) > 0
        h = 1e-6 * max(1.0, np.abs(q).max())
        g_fd = np.array([(jaw.penalty(q + h * e)[0] - jaw.penalty(q - h * e)[0]) / (2 * h) for e in np.eye(3)])
        H_fd = np.stack([(jaw.penalty(q + h * e)[1] - jaw.penalty(q - h * e)[1]) / (2 * h) for e in np.eye(3)], 1)
        assert np.allclose(grad, g_fd, rtol=1e-6, atol=1e-6 * np.abs(grad).max())
        assert np.allclose(hess, H_fd, rtol=1e-5, atol=1e-5 * np.abs(hess).max())
    if kind == "nlpca":
        assert np.abs(jaw.penalty(states[-1])[1][0]) > 0          # the range curves pull on d1 too


def test_rig_from_another_skull_frame_is_placed_on_the_model(model, rigs, tmp_path):
    """A rig fitted to the same motion expressed in a skull frame shifted by 30 mm is placed by the
    model's jaw frame: its poses are its jaw-frame motion moved into that frame."""
    fitted, _, points, session = rigs
    G = se3.from_rt(np.eye(3), np.array([30.0, -5.0, 10.0]))
    shifted = fit_posselt(poses=G @ session.poses @ se3.inverse(G), reference_point=session.reference_point + G[:3, 3],
                          border={c: session.frames(c) for c in CURVES})
    path = shifted.save(tmp_path / "shifted.npz")
    jaw = rig_jaw_from_spec(model, f"posselt:{path}")
    model_frame = JawFrame.from_geometry(model.jaw)
    assert np.array_equal(jaw.frame.matrix, model_frame.matrix)
    q = np.array([0.3, 0.6, 0.4])
    expected = model_frame.pose_to_world(shifted.frame.pose_to_local(shifted.pose_from_sliders(q[None])))[0]
    assert np.allclose(jaw.transform(q), expected, atol=1e-9)
    # and it agrees with the rig fitted in the model's frame up to the two frames' small difference
    assert se3.vertex_errors(jaw.transform(q), fitted["posselt"].pose_from_sliders(q[None])[0], points) < 1.0


def test_spec_errors(model, rigs, tmp_path):
    paths = rigs[1]
    with pytest.raises(FacesimError, match="expected posselt:RIG.npz"):
        rig_jaw_from_spec(model, "posselt")
    with pytest.raises(FacesimError, match="no such file"):
        rig_jaw_from_spec(model, f"nlpca:{tmp_path / 'missing.npz'}")
    with pytest.raises(FacesimError, match="expected a 'nlpca' rig, got 'posselt'"):
        rig_jaw_from_spec(model, f"nlpca:{paths['posselt']}")
    assert rig_jaw_from_spec(model, f"rig:{paths['nlpca']}").kind == "nlpca"
    jaw = RigJaw(rigs[0]["posselt"])
    with pytest.raises(FacesimError, match="expected 3 finite posselt-rig parameters"):
        jaw.transform(np.zeros(2))
    with pytest.raises(FacesimError, match="PosseltRig, NlpcaRig or ClassicRig"):
        RigJaw(object())
