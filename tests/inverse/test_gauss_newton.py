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


class _BoxJaw:
    """A jaw model stand-in with a box penalty on three parameters (as the sliding-condyle's),
    unit weights but the slides' 4."""
    n_params = 3
    bounds = np.array([[0.0, 0.4], [0.0, 5.0], [0.0, 5.0]])
    weight = np.array([1.0, 4.0, 4.0])

    def penalty(self, q):
        e = np.maximum(q - self.bounds[:, 1], 0.0) + np.minimum(q - self.bounds[:, 0], 0.0)
        return float(self.weight @ e ** 2), 2.0 * self.weight * e, np.diag(2.0 * self.weight * (e != 0))

    def penalty_box(self):
        return self.bounds[:, 0], self.bounds[:, 1], self.weight


@pytest.mark.parametrize("seed", range(6))
def test_compiled_schedule_takes_the_python_schedule_s_steps(seed):
    """The compiled box schedule against the Python one on random linear models whose minimum
    leaves the box on several activations and jaw parameters (the piece changes, streaks and the
    landing on the target all exercised): the same step to 1e-10, weight and nested count."""
    rng = np.random.default_rng(seed)
    space = ControlSpace(8, n_jaw=3)
    bounds = _Bounds(space, _BoxJaw())
    assert bounds.box() is not None
    J = rng.normal(size=(60, 11)) * rng.uniform(0.1, 3.0, 11)
    target = np.r_[rng.uniform(-0.6, 1.6, 8), rng.uniform(-0.2, 0.6), rng.uniform(-2.0, 7.0, 2)]
    c = np.r_[rng.uniform(0, 1, 8), 0.1, 1.0, 1.0]
    r = -J @ (target - c) + rng.normal(scale=0.3, size=60)
    w = rng.uniform(0.5, 2.0, 60)
    options = FitOptions(noise=0.5)
    ref = schedule_penalty(r, J, c, bounds, options, w, compiled=False)
    got = schedule_penalty(r, J, c, bounds, options, w)
    assert ref[2] > 20 and got[2] == ref[2]
    assert got[1] == pytest.approx(ref[1], rel=1e-12)
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-10 * (1 + np.abs(ref[0]).max()))
    # the bounds held: within 1e-4 of the box, some unknowns on it
    lower, upper, _ = bounds.box()
    at = c + got[0]
    assert (at > lower - 1e-4).all() and (at < upper + 1e-4).all()
    assert ((np.abs(at - lower) < 1e-4) | (np.abs(at - upper) < 1e-4)).sum() >= 2


def test_schedule_box_form_only_for_box_bounds(box_model):
    """The compiled path takes boxes only: a sliding-condyle jaw's ranges, or no jaw; not a solved
    head frame's rigidity nor a jaw model without ``penalty_box``."""
    jaw = SlidingCondyleJaw(box_model.jaw)
    lower, upper, weight = _Bounds(ControlSpace(2, n_jaw=3), jaw).box()
    np.testing.assert_array_equal(lower, np.r_[0, 0, jaw.bounds[:, 0]])
    np.testing.assert_array_equal(upper, np.r_[1, 1, jaw.bounds[:, 1]])
    np.testing.assert_array_equal(weight, np.r_[1, 1, [jaw.penalty_weight] * 3])
    assert _Bounds(ControlSpace(2), None).box() is not None
    # the jaw models that give a box: their penalty is the box penalty of it, inside and out
    from facesim.jaw.model_rig import fit_model_rig
    from facesim.kinematics.rig_jaw import RigJaw

    rng = np.random.default_rng(4)
    for model in (jaw, RigJaw(fit_model_rig(box_model.jaw))):
        lo, hi, wt = model.penalty_box()
        for _ in range(20):
            q = lo + (hi - lo) * rng.uniform(-0.4, 1.4, len(lo))
            e = np.maximum(q - hi, 0.0) + np.minimum(q - lo, 0.0)
            v, g, H = model.penalty(q)
            assert v == pytest.approx(float(wt @ e ** 2), rel=1e-12, abs=1e-15)
            np.testing.assert_allclose(g, 2 * wt * e, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(H, np.diag(2 * wt * (e != 0)), rtol=1e-12, atol=1e-15)

    curved = _BoxJaw()
    curved.penalty_box = lambda: None   # e.g. an NLPCA rig: its ranges move with d1
    assert _Bounds(ControlSpace(2, n_jaw=3), curved).box() is None
    assert _Bounds(ControlSpace(2), None, head=object()).box() is None


def test_a_kept_step_is_lengthened_only_while_the_gain_left_exceeds_the_resolution():
    """``_extend`` on a step whose markers moved 0.9 of the prediction: the linear model leaves
    ``1/2 (1 - 0.9)^2 |J dc|^2`` to gain by lengthening it; below the resolution no trial is
    solved, above it the secant step to the predicted motion is tried (at alpha 1 + 0.1 / 0.9)."""
    from facesim.inverse.gauss_newton import FitOptions, _extend

    linear = np.full(12, 2.0)            # |J dc|^2 = 48: the gain left at phi 0.9 is 0.24
    w = np.ones(12)
    trials = []

    def solve(ctrl, warm, J):
        trials.append(warm.copy())
        return warm

    x0, x1 = np.zeros((4, 3)), np.ones((4, 3))
    moved = lambda x: 0.9 * linear * float(x.mean())   # noqa: E731  (phi = 0.9 at x1)
    objective = lambda c, x, mu: 10.0 - float(x.mean())   # noqa: E731  (longer is better)
    args = (solve, objective, lambda c: c, np.zeros(2), np.ones(2), x0, x1, 9.0, 0.0, FitOptions(), linear,
            moved, w, None)
    assert _extend(*args, resolution=0.25) == (1.0, 9.0, x1) and not trials
    alpha, F, x = _extend(*args, resolution=0.2)
    assert len(trials) >= 1 and alpha == pytest.approx(1.0 + 0.1 / 0.9) and F < 9.0


def test_recovers_activations_and_jaw_from_exact_markers(box_sim, box_model):
    truth = Controls([0.6, 0.5], jaw=[0.15, 2.0, 1.5])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    fit = fit_frame(box_sim, T, Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0]), options=FitOptions(noise=0.01))
    rep = fit.report
    assert rep.gn_steps <= 5 and rep.marker_rms < 1e-3
    np.testing.assert_allclose(fit.controls.a, truth.a, atol=2e-3)
    assert np.all(np.abs(fit.controls.jaw - truth.jaw) < [2e-3, 0.05, 0.05])
    assert rep.equilibria >= rep.gn_steps       # each step solved its trial points (see the line-search tests)
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


def test_tracked_frames_take_one_step_and_reuse_the_jacobian(box_sim, box_model):
    """Tracking (issue 5: "in tracking, most frames need 1 step"): six frames of smoothly varying
    activations (jaw held) with 0.02 mm marker noise, each frame started from the previous fit, its
    equilibrium and its Jacobian. Most frames take exactly one Gauss-Newton step, kept without a
    golden-section search; the Jacobian is re-evaluated in fewer frames than not; the activations
    are those of the truth, and those of the paper's scheme (a new Jacobian and a golden-section
    search at every step) from the same start."""
    space = ControlSpace(2)
    jaw = [0.05, 0.5, 0.4]
    truth = [np.array([0.3 + 0.04 * k, 0.2 + 0.02 * k]) for k in range(6)]
    rng = np.random.default_rng(1)
    x, targets = None, []
    for a in truth:
        x = box_sim.equilibrium(Controls(a, jaw=jaw), x0=x).x
        targets.append(box_model.marker_positions(x) + 0.02 * rng.normal(size=(box_model.n_markers, 3)))
    options = FitOptions(noise=0.02)
    start = Controls(truth[0], jaw=jaw)
    controls, x, jacobian = start, box_sim.equilibrium(start).x, None
    fits = []
    for T in targets:
        fit = fit_frame(box_sim, T, controls, x, space, options, jacobian=jacobian)
        fits.append(fit)
        controls, x, jacobian = fit.controls, fit.x, fit.jacobian
    tracked = [f.report for f in fits[1:]]
    steps = [r.gn_steps for r in tracked]
    assert sum(s == 1 for s in steps) > len(steps) / 2 and max(steps) <= 2, steps
    assert all(r.full_steps == r.gn_steps for r in tracked)            # no golden-section fallback
    assert sum(r.jacobians for r in tracked) < len(tracked) / 2        # Jacobians carried over
    for fit, a in zip(fits, truth):
        np.testing.assert_allclose(fit.controls.a, a, atol=0.01)
        assert fit.report.marker_rms < 0.05                            # noise: 0.035 mm RMS in 3-D
        assert fit.report.worst_violation == 0.0
    reference = fit_frame(box_sim, targets[3], fits[2].controls, fits[2].x, space,
                          FitOptions(noise=0.02, line_search="golden", jacobian_max_age=0))
    assert reference.report.equilibria > 2 * fits[3].report.equilibria
    np.testing.assert_allclose(fits[3].controls.a, reference.controls.a, atol=1e-3)


def test_a_drifted_step_stops_on_its_updated_jacobian_and_hands_it_on(box_sim, box_model):
    """With every step counted as drifted (jacobian_drift 1e-12), the secant-updated Jacobian
    first decides whether another step is worth taking: a frame that stops after its steps has
    evaluated one exact Jacobian per step, not one more only to stop, and hands the updated one to
    the next frame, which starts from it (its first step then evaluates an exact one, the last
    step having drifted). The controls are those of an undrifted fit."""
    space = ControlSpace(2)
    jaw = [0.05, 0.5, 0.4]
    truth = [np.array([0.3, 0.2]), np.array([0.34, 0.22])]
    x, targets = None, []
    for a in truth:
        x = box_sim.equilibrium(Controls(a, jaw=jaw), x0=x).x
        targets.append(box_model.marker_positions(x))
    start = Controls(np.array([0.1, 0.1]), jaw=jaw)
    x0 = box_sim.equilibrium(start).x
    drifty = FitOptions(noise=0.02, jacobian_drift=1e-12)
    fit = fit_frame(box_sim, targets[0], start, x0, space, drifty)
    rep = fit.report
    assert rep.stop_reason == "converged" and rep.gn_steps >= 1
    assert rep.jacobians == rep.gn_steps, (rep.jacobians, rep.gn_steps)
    assert fit.jacobian is not None and fit.jacobian.age >= 1          # updated, not re-evaluated
    np.testing.assert_allclose(fit.controls.a, truth[0], atol=1e-3)
    plain = fit_frame(box_sim, targets[0], start, x0, space, FitOptions(noise=0.02))
    np.testing.assert_allclose(fit.controls.a, plain.controls.a, atol=1e-3)
    nxt = fit_frame(box_sim, targets[1], fit.controls, fit.x, space, drifty, jacobian=fit.jacobian)
    assert nxt.report.stop_reason == "converged"
    np.testing.assert_allclose(nxt.controls.a, truth[1], atol=1e-3)


def test_line_search_backtracks_extends_and_falls_back_to_golden_section(box_sim, box_model, monkeypatch):
    """From the neutral face the first Gauss-Newton step overshoots into the nonlinear jaw range:
    the full step fails the ratio test and one backtracking trial is kept; later steps are kept
    whole or lengthened where the markers moved less than predicted (stiffening flesh). Same
    answer as the paper's scheme (golden section on every step, a new Jacobian at every step) with
    far fewer equilibria; when the backtracking trial fails too, the golden-section search on
    [0, 1] takes over."""
    import facesim.inverse.gauss_newton as gn

    truth = Controls([0.6, 0.5], jaw=[0.15, 2.0, 1.5])
    T = box_model.marker_positions(box_sim.equilibrium(truth).x)
    start = Controls([0.0, 0.0], jaw=[0.0, 0.0, 0.0])
    fit = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01))
    rep = fit.report
    assert rep.gn_steps <= 5 and rep.marker_rms < 1e-3
    assert rep.ratios[0] < 0.1 and 0 < rep.step_lengths[0] < 1          # backtracked
    assert max(rep.step_lengths[1:]) > 1.2 and rep.full_steps == rep.gn_steps - 1   # lengthened
    assert rep.timing["line_search"] > 0 and rep.jacobians >= 2
    paper = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01, line_search="golden", jacobian_max_age=0))
    # the stop rule ends a fit once a step would move the estimate by less than one standard
    # deviation of its noise: both fits sit well inside the declared 0.01 mm noise
    assert paper.report.marker_rms < 5e-3 and paper.report.full_steps == 0
    assert rep.equilibria < paper.report.equilibria / 2
    np.testing.assert_allclose(fit.controls.a, paper.controls.a, atol=2e-3)
    np.testing.assert_allclose(fit.controls.a, truth.a, atol=2e-3)
    # no backtracking step is ever good enough: the golden-section search on [0, 1] decides
    monkeypatch.setattr(gn, "ARMIJO", 1e9)
    golden = fit_frame(box_sim, T, start, options=FitOptions(noise=0.01, max_steps=1))
    assert 0 < golden.report.step_lengths[0] < 1 and golden.report.equilibria >= 5
    assert golden.report.objective[-1] < golden.report.objective[0]
    with pytest.raises(FacesimError, match="line_search"):
        FitOptions(line_search="armijo")
