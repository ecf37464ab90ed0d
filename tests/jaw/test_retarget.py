"""Retargeting a Posselt rig to a new subject from five extremal poses (facesim.jaw.retarget, Zoss
et al. 2018 section 5)."""

import numpy as np
import pytest

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.evaluate import pose_errors
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Subject
from facesim.jaw.points import front_weights, mandible_points
from facesim.jaw.posselt import Shield, fit_posselt
from facesim.jaw.retarget import (
    EXTREMES,
    deform_shield,
    identify_extremes,
    retarget_posselt,
)
from facesim.se3 import similarity

LATENT = {"rest": (0.0, 0.0, 0.0), "open": (1.0, 0.0, 0.0), "protrusion": (0.0, 1.0, 0.0),
          "left": (0.0, 0.0, 1.0), "right": (0.0, 0.0, -1.0)}


@pytest.fixture(scope="module")
def case():
    """A source rig (subject 3), and subject 4: five noisy extremal poses, a training session (for
    the rig fitted on the full data) and a test session."""
    source = fit_posselt(JawMotion(subject=Subject.random(3)).session(seed=1, noise=0.03))
    target = JawMotion(subject=Subject.random(4))
    rng = np.random.default_rng(0)
    names = ["open", "protrusion", "left", "right"]
    extremes = target.poses(np.array([LATENT[n] for n in names])) @ se3.exp(
        np.c_[rng.normal(scale=3e-4, size=(4, 3)), rng.normal(scale=0.03, size=(4, 3))])
    train, test = target.session(seed=1, noise=0.03), target.session(seed=2, noise=0.03)
    points = mandible_points(count=300)
    return source, target, names, extremes, train, test, points


def _errors(rig, case):
    _, _, _, _, _, test, points = case
    weights = front_weights(points, rig.frame)
    return pose_errors(rig.reproduce(test.poses), test.poses, points, weights)


def test_full_beats_reduced_beats_unadapted(case):
    source, _, _, extremes, train, _, _ = case
    ref = train.reference_point
    e = {mode: _errors(retarget_posselt(source, extremes, ref, mode=mode), case) for mode in ("none", "reduced", "full")}
    e["fitted"] = _errors(fit_posselt(train), case)
    print("\nretargeting subject 3 -> 4 from 5 poses, test-session error mean / p95 / max (mm): " +
          "; ".join(f"{k} {v.mean:.3f} / {v.p95:.3f} / {v.max:.3f}" for k, v in e.items()))
    assert e["full"].mean < e["reduced"].mean < e["none"].mean
    assert e["full"].mean < 0.5 * e["none"].mean and e["full"].p95 < 0.6 * e["none"].p95
    assert e["reduced"].p95 < e["none"].p95
    # close to the rig fitted on the whole new session: within a quarter millimetre on average
    assert e["fitted"].mean < e["full"].mean < e["fitted"].mean + 0.25


def test_new_extremes_are_hit(case):
    source, _, names, extremes, train, _, points = case
    rig = retarget_posselt(source, extremes, train.reference_point, names=names)
    sliders = np.array([EXTREMES[n] for n in names])
    placed = se3.transform_points(rig.pose_from_sliders(sliders), rig.reference_point)[:, 0]
    captured = se3.transform_points(extremes, rig.reference_point)[:, 0]
    assert np.abs(placed - captured).max() < 0.05                     # the shield passes through them
    assert se3.vertex_errors(rig.pose_from_sliders(sliders), extremes, points).max() < 0.5
    assert rig.bijectivity() > 0.99
    # the unadapted source rig misses the new subject's maximum opening by millimetres
    far = source.pose_from_sliders(sliders[:1])
    assert np.linalg.norm(se3.transform_points(far, source.reference_point)[0, 0] - captured[0]) > 1.0


def test_extremes_are_recognised():
    rng = np.random.default_rng(1)
    displacement = {"rest": [0.01, 0.02, -0.03], "open": [0.3, -48.0, -12.0], "protrusion": [0.1, -2.5, 8.5],
                    "left": [10.0, -2.0, -1.0], "right": [-10.5, -2.2, -0.8]}
    order = rng.permutation(list(displacement))
    assert identify_extremes(np.array([displacement[n] for n in order])) == list(order)
    assert identify_extremes(np.array([displacement["left"], displacement["open"]])) == ["left", "open"]


def test_similarity_and_shield_deformation(case):
    rng = np.random.default_rng(2)
    X = rng.normal(size=(6, 3)) * 20
    Q = se3.so3_exp(np.array([0.1, -0.2, 0.3]))
    c, R, b = similarity(X, 1.1 * X @ Q.T + [1.0, 2.0, 3.0])
    assert c == pytest.approx(1.1) and np.allclose(R, Q) and np.allclose(b, [1.0, 2.0, 3.0])
    shield = case[0].shield
    s = np.array([[0.5, 1.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.4, 0.7]])
    target = shield.point(s) + np.array([[0.0, -2.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    moved = Shield(deform_shield(shield.curves, s, target))
    assert np.abs(moved.point(s) - target).max() < 0.01
    assert np.abs(moved.curves - shield.curves).max() > 1.0
    assert np.abs(deform_shield(shield.curves, s, shield.point(s)) - shield.curves).max() < 1e-9


def test_bad_input(case):
    source, _, names, extremes, train, _, _ = case
    with pytest.raises(FacesimError, match="unknown mode"):
        retarget_posselt(source, extremes, mode="partial")
    with pytest.raises(FacesimError, match="at least three extremal poses"):
        retarget_posselt(source, extremes[:2], names=names[:2])
    with pytest.raises(FacesimError, match="names among"):
        retarget_posselt(source, extremes, names=["open", "wide", "left", "right"])
    with pytest.raises(FacesimError, match="values in"):
        retarget_posselt(source, extremes, sliders=np.full((4, 3), 1.5))
    frame = JawFrame.from_poses(train.poses, train.reference_point)
    same = retarget_posselt(source, extremes, mode="none", frame=frame)
    assert np.array_equal(same.shield.curves, source.shield.curves) and same.frame is frame
