"""Gauss-Newton fit of one frame: recovery of known controls, the penalty schedule, stopping rules."""

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import ControlSpace
from facesim.inverse.gauss_newton import FitOptions, _Bounds, fit_frame, schedule_penalty
from facesim.kinematics.condyle import SlidingCondyleJaw


@pytest.fixture(scope="module")
def box_sim(box_model):
    options = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
    return FaceSimulator(box_model, options, jaw_model=SlidingCondyleJaw(box_model.jaw))


def test_schedule_drives_a_violating_model_onto_the_bound():
    """Linear model whose unconstrained minimum is a = 1.5: the schedule ends with the penalty
    weight >= 1e6 times the data term and the activation within 1e-4 of 1."""
    space = ControlSpace(1)
    bounds = _Bounds(space, None)
    J = np.array([[1.0], [2.0]])
    r = -J[:, 0] * 1.5                     # r + J dc = 0 at dc = 1.5
    options = FitOptions(noise=0.5)
    dc, mu, nested = schedule_penalty(r, J, np.zeros(1), bounds, options)
    model = r + J @ dc
    data = 0.5 * model @ model
    assert mu >= 1e6 * data and nested > 10
    assert 1.0 < dc[0] < 1.0 + 1e-4
    # the start is below the noise level: the first nested step barely feels the bound
    mu0 = options.start_ratio * options.noise ** 2
    assert mu0 < options.noise ** 2
    # inside the bounds the schedule changes nothing: the linear least-squares step
    dc_in, _, _ = schedule_penalty(-J[:, 0] * 0.4, J, np.zeros(1), bounds, options)
    assert dc_in[0] == pytest.approx(0.4, rel=1e-5)   # up to the 1e-6 Levenberg-Marquardt damping


def test_recovers_activations_and_jaw_from_exact_markers(box_sim, box_model):
    truth = Controls([0.6, 0.5], jaw=[0.15, 2.0, 1.5])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    fit = fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]), options=FitOptions(noise=0.01))
    rep = fit.report
    assert rep.gn_steps <= 5 and rep.marker_rms < 1e-3
    np.testing.assert_allclose(fit.controls.a, truth.a, atol=2e-3)
    assert np.all(np.abs(fit.controls.jaw - truth.jaw) < [2e-3, 0.05, 0.05])
    assert rep.equilibria >= 3 * rep.gn_steps   # golden-section trial points
    assert all(np.diff(rep.objective) < 0)


def test_activation_on_its_bound_stays_within_1e4(box_sim, box_model):
    """Truth pushes the orbicularis to 1 and the markers ask for more (noise-free markers of a
    stronger muscle): after the schedule the activation is within 1e-4 of [0, 1]."""
    strong = box_sim.with_gain([1.0, 1.4])
    T = box_model.marker_positions(strong.equilibrium(Controls([0.3, 1.0], jaw=[0.05, 0.5, 0.5])).x)
    fit = fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]), options=FitOptions(noise=0.1))
    assert fit.controls.a[1] > 0.99
    assert fit.report.worst_violation < 1e-4
    assert fit.report.penalty_weight > 0


def test_missing_markers_are_dropped_and_too_few_refused(box_sim, box_model):
    truth = Controls([0.4, 0.2], jaw=[0.05, 0.0, 0.0])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    T[0] = np.nan
    space = ControlSpace(2)   # activations only, the jaw held at the start's
    fit = fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.05, 0.0, 0.0]), space=space,
                    options=FitOptions(noise=0.01))
    np.testing.assert_allclose(fit.controls.a, truth.a, atol=5e-3)
    T[1:4] = np.nan
    with pytest.raises(FacesimError, match="only 2 markers present"):
        fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]))
