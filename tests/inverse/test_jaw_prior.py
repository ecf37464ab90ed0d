"""The markerless jaw prior in the Gauss-Newton fit (facesim.inverse.jaw_prior): its residual rows'
derivatives, that a prior of the true mandible points pins a jaw the markers leave loose, and the
checks of a predictor bound to a model."""

import numpy as np
import pytest

from facesim import se3
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import ControlSpace
from facesim.inverse.gauss_newton import FitOptions, fit_frame
from facesim.inverse.jaw_prior import JawPrior, PriorRows
from facesim.kinematics.condyle import SlidingCondyleJaw

# points on the box model's mandible block (tests/conftest.py), mm
BONE = np.array([[0.0, -22.0, -2.5], [15.0, -22.0, -10.0], [-15.0, -22.0, -10.0], [0.0, -27.0, -10.0],
                 [0.0, -17.0, -17.0]])


@pytest.fixture(scope="module")
def box_sim(box_model):
    options = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
    return FaceSimulator(box_model, options, jaw_model=SlidingCondyleJaw(box_model.jaw))


def _bone_points(jaw_model, q):
    return se3.transform_points(jaw_model.transform(q), BONE)


def test_prior_rows_derivative_matches_central_differences(box_model):
    jm = SlidingCondyleJaw(box_model.jaw)
    rng = np.random.default_rng(3)
    rows = PriorRows(BONE, BONE + rng.normal(0, 1.0, BONE.shape), 4.0)
    for _ in range(3):
        q = np.array([rng.uniform(0.02, 0.3), rng.uniform(0.5, 6.0), rng.uniform(-1.0, 1.0)])
        J = rows.jacobian(jm, q)
        assert J.shape == (15, 3) and np.linalg.norm(J) > 1.0
        h = 1e-6
        fd = np.stack([(rows.residual(jm, q + h * e) - rows.residual(jm, q - h * e)) / (2 * h) for e in np.eye(3)], 1)
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)
    # at the target the residual vanishes
    q = np.array([0.1, 2.0, 0.5])
    assert np.abs(PriorRows(BONE, _bone_points(jm, q), 1.0).residual(jm, q)).max() < 1e-12


def test_prior_of_the_true_mandible_pins_a_jaw_the_markers_leave_loose(box_sim, box_model):
    """Only the head and cheek markers (which barely see the jaw), with 0.1 mm noise: without the
    prior the mandible is ~2 mm off; with a prior of the true mandible points it is within 0.15 mm,
    and a prior of a wrong jaw pulls the fit towards that jaw (the prior acts, in mm, against the
    markers)."""
    truth = Controls([0.5, 0.4], jaw=[0.2, 3.0, 1.0])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    loose = T.copy()
    loose[[0, 1, 2]] = np.nan                       # mouth and chin markers missing
    loose += np.random.default_rng(0).normal(0.0, 0.1, loose.shape)
    start = Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0])
    opts = FitOptions(noise=0.1, max_steps=8)
    jm = box_sim.jaw_model
    plain = fit_frame(box_sim, loose, start, options=opts)
    exact = fit_frame(box_sim, loose, start, options=opts,
                      jaw_prior=PriorRows(BONE, _bone_points(jm, truth.jaw), (0.1 / 0.1) ** 2))
    err = lambda f: np.abs(_bone_points(jm, f.controls.jaw) - _bone_points(jm, truth.jaw)).max()  # noqa: E731
    assert exact.report.stop_reason == "converged"
    assert err(exact) < 0.15
    assert err(plain) > 0.8
    # a prior of another jaw (opening 0.1) moves the solution towards it
    other = np.array([0.1, 1.5, 0.5])
    wrong = fit_frame(box_sim, loose, start, options=opts,
                      jaw_prior=PriorRows(BONE, _bone_points(jm, other), 1.0))
    assert abs(wrong.controls.jaw[0] - other[0]) < abs(wrong.controls.jaw[0] - truth.jaw[0])
    # with all markers the prior of the truth changes nothing that matters
    full = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01),
                     jaw_prior=PriorRows(BONE, _bone_points(jm, truth.jaw), 1.0))
    np.testing.assert_allclose(full.controls.a, truth.a, atol=3e-3)
    assert err(full) < 0.02


def test_prior_needs_jaw_parameters_in_the_space(box_sim, box_model):
    T = box_model.marker_positions(box_sim.equilibrium(Controls([0.2, 0.1], jaw=[0.0, 0.0, 0.0])).x)
    with pytest.raises(FacesimError, match="no jaw parameters"):
        fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]), space=ControlSpace.of(box_sim, jaw=False),
                  jaw_prior=PriorRows(BONE, BONE, 1.0))


class _Pred:
    """The parts of a predictor JawPrior checks."""

    def __init__(self, kind, names, n_bone=5):
        self.meta = {"features": {"kind": kind, "names": list(names)}}
        self.n_bone = n_bone


def test_jaw_prior_checks_the_predictor_against_the_model():
    names = ("a", "b", "c")
    assert JawPrior(_Pred("markers", names), BONE, names).index.tolist() == [0, 1, 2]
    # a predictor of some of the model's markers (those a capture has) reads them where they are
    assert JawPrior(_Pred("markers", ("c", "a")), BONE, ("a", "b", "c", "d")).index.tolist() == [2, 0]
    with pytest.raises(FacesimError, match="reads skin features"):
        JawPrior(_Pred("skin", ()), BONE, names)
    with pytest.raises(FacesimError, match="has no b"):
        JawPrior(_Pred("markers", names), BONE, ("a", "c", "d"))
    with pytest.raises(FacesimError, match="bone points"):
        JawPrior(_Pred("markers", names), BONE[:3], names)
    with pytest.raises(FacesimError, match="sigma"):
        JawPrior(_Pred("markers", names), BONE, names, sigma=0.0)
