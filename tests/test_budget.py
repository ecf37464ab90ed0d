"""Wall-clock budgets: nesting, and Newton and Gauss-Newton stopping, flagged, when time runs out."""

import time

import numpy as np
import pytest

from facesim import budget
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse.gauss_newton import STOP_REASONS, FitOptions, fit_frame
from facesim.kinematics.condyle import SlidingCondyleJaw


@pytest.fixture(scope="module")
def box_sim(box_model):
    options = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
    return FaceSimulator(box_model, options, jaw_model=SlidingCondyleJaw(box_model.jaw))


def test_budgets_nest_and_the_earlier_deadline_wins():
    assert not budget.expired() and budget.remaining() == np.inf
    with budget.time_budget(100.0):
        assert 99.0 < budget.remaining() <= 100.0
        with budget.time_budget(1000.0):            # an inner budget never extends an outer one
            assert budget.remaining() <= 100.0
        with budget.time_budget(0.01):
            time.sleep(0.02)
            assert budget.expired() and budget.remaining() == 0.0
        assert not budget.expired()                  # the outer one is back
        with budget.time_budget(None):               # None adds no limit of its own
            assert 90.0 < budget.remaining() <= 100.0
    assert budget.remaining() == np.inf


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "soon"])
def test_a_budget_must_be_a_positive_number_of_seconds(bad):
    with pytest.raises(FacesimError, match="expected a number of seconds > 0"):
        budget.check_seconds(bad, "--max-seconds-per-frame")
    with pytest.raises(FacesimError, match="max_seconds"):
        FitOptions(max_seconds=bad)
    with pytest.raises(FacesimError, match="max_seconds"):
        NewtonOptions(max_seconds=bad)


def test_newton_out_of_time_stops_flagged(box_sim):
    """An expired budget stops Newton before its first iteration: not converged, time_limit."""
    controls = Controls([0.8, 0.7], jaw=[0.2, 1.0, 1.0])
    free = box_sim.equilibrium(controls)
    assert free.converged and free.iterations > 2
    with budget.time_budget(1e-9):
        time.sleep(1e-3)
        eq = box_sim.equilibrium(controls)
    assert not eq.converged and eq.report.stop_reason == budget.TIME_LIMIT and eq.iterations == 0
    # the solver's own option bounds one equilibrium the same way
    slow = box_sim.equilibrium(controls, newton_options=NewtonOptions(linear_solver="direct", max_seconds=1e-9))
    assert slow.report.stop_reason == budget.TIME_LIMIT


def test_fit_out_of_time_stops_at_its_last_accepted_step(box_sim, box_model, monkeypatch):
    """A fit whose budget runs out between steps returns the controls of its last accepted step,
    with their equilibrium, flagged time_limit (one of the stop reasons every log knows)."""
    assert budget.TIME_LIMIT in STOP_REASONS
    truth = Controls([0.6, 0.5], jaw=[0.15, 2.0, 1.5])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    start = Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0])
    full = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01))
    assert full.report.converged and full.report.gn_steps >= 2

    # expire the budget after the first accepted step: the clock jumps once one step is in
    import facesim.inverse.gauss_newton as gn
    real = gn.expired
    steps = {"seen": 0}

    def expired_after_first_step():
        return real() or steps["seen"] >= 1

    original_update = gn.EquilibriumJacobian.secant_update

    def counting_update(self, *args, **kwargs):
        steps["seen"] += 1
        return original_update(self, *args, **kwargs)

    monkeypatch.setattr(gn, "expired", expired_after_first_step)
    monkeypatch.setattr(gn.EquilibriumJacobian, "secant_update", counting_update)
    fit = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01))
    assert fit.report.stop_reason == budget.TIME_LIMIT and not fit.report.converged
    assert fit.report.gn_steps == 1 and fit.equilibrium
    # the result is a consistent state: x is the equilibrium of the returned controls
    eq = box_sim.equilibrium(fit.controls, x0=fit.x)
    assert eq.iterations <= 1 and np.abs(eq.x - fit.x).max() < 1e-6
    assert fit.report.marker_rms > full.report.marker_rms   # stopped early: a worse fit, honestly flagged


def test_fit_out_of_time_before_any_equilibrium(box_sim, box_model):
    T = box_model.marker_positions(box_sim.equilibrium(Controls([0.3, 0.2], jaw=[0.05, 0.0, 0.0])).x)
    with budget.time_budget(1e-9):
        time.sleep(1e-3)
        fit = fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]))
    assert fit.report.stop_reason == budget.TIME_LIMIT and not fit.equilibrium
    assert "time budget" in fit.report.error
    np.testing.assert_array_equal(fit.controls.a, [0.0, 0.0])
