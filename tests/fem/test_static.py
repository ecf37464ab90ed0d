"""solve_static on boxes: patch test, uniaxial tension (closed form), fibre force-length,
recovery from inverted elements, quadratic convergence, input checks."""

import numpy as np
import pytest

from facesim._kernels.fibre import active_curve
from facesim.errors import FacesimError
from facesim.fem import ElasticTerm, MooneyRivlin, MuscleTerm, NewtonOptions, RestShape, box_mesh, solve_static
from facesim.fem.newton import Problem, newton
from facesim.fem.system import DofSystem
from tests.fem.conftest import inverted_count

MAT = MooneyRivlin(6e-3, 2e-3, 0.4)
L = 10.0


def _rollers(X, stretch):
    """Uniaxial tension along x: symmetry rollers on x=0, y=0, z=0; x=L pulled to stretch*L."""
    fixed = np.zeros((len(X), 3), bool)
    for k in range(3):
        fixed[X[:, k] < 1e-9, k] = True
    right = X[:, 0] > L - 1e-9
    fixed[right, 0] = True
    xp = X.copy()
    xp[right, 0] = stretch * L
    return fixed, xp, right


@pytest.mark.parametrize("solver", ["direct", "amg"])
def test_patch_test_affine_field_is_an_equilibrium(solver):
    X, T = box_mesh((L, L, L), (3, 3, 3))
    A = np.array([[1.1, 0.05, -0.02], [0.03, 0.95, 0.04], [-0.01, 0.02, 1.05]])
    boundary = np.flatnonzero(np.any((X < 1e-9) | (X > L - 1e-9), axis=1))
    interior = np.setdiff1d(np.arange(len(X)), boundary)
    assert len(interior) == 8
    y = X @ A.T
    # the affine field has uniform F = A and no residual at interior nodes ...
    rest = RestShape(X, T)
    F = np.stack([y[T[:, j]] - y[T[:, 0]] for j in (1, 2, 3)], -1) @ rest.Bm
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), atol=1e-13)
    g = ElasticTerm(rest, MAT.c10, MAT.c01, MAT.kappa).gradient(y)
    assert np.abs(g[interior]).max() < 1e-12 * np.abs(g[boundary]).max()
    # ... and the solver finds it from a perturbed start
    x0 = y + 0.3 * np.random.default_rng(0).normal(size=y.shape)
    x, rep = solve_static(X, T, MAT, boundary, y[boundary], x0=x0,
                          options=NewtonOptions(linear_solver=solver, rtol=1e-10))
    assert rep.converged
    np.testing.assert_allclose(x, y, atol=1e-8)


@pytest.mark.parametrize("volumetric", ["log", "quadratic"])
def test_uniaxial_stretch_matches_the_closed_form(volumetric):
    mat = MooneyRivlin(6e-3, 2e-3, 0.4, volumetric)
    X, T = box_mesh((L, L, L), (3, 3, 3))
    for stretch in (0.8, 1.3):
        fixed, xp, right = _rollers(X, stretch)
        x, rep = solve_static(X, T, mat, fixed, xp, options=NewtonOptions(linear_solver="direct", rtol=1e-12))
        assert rep.converged
        g = ElasticTerm(RestShape(X, T), mat.c10, mat.c01, mat.kappa, volumetric=volumetric).gradient(x)
        P11 = g[right, 0].sum() / L ** 2          # reaction / reference area: nominal stress
        P_exact, lateral = mat.uniaxial_nominal_stress(stretch)
        assert abs(P11) > 1e-4
        assert P11 == pytest.approx(P_exact, rel=1e-6)
        assert x[:, 1].max() / L == pytest.approx(lateral, rel=1e-8)   # homogeneous lateral contraction


@pytest.mark.parametrize("stretch", [1.0, 0.85, 1.5])
def test_fibre_block_reaction_is_sigma_max_times_force_length(stretch):
    """Fibres along x, activation 1, held at stretch: active reaction = sigma_max f_L(stretch) A.

    (On the descending limb between about 1.05 and 1.4 an active fibre softens faster than this
    flesh stiffens: the homogeneous state is unstable and the block necks, as real muscle would;
    the curve there is checked on prescribed homogeneous states below.)"""
    X, T = box_mesh((L, L, L), (2, 2, 2))
    rest = RestShape(X, T)
    sigma = 0.2
    muscle = MuscleTerm(rest, np.arange(len(T)), np.zeros(len(T), int), np.ones(len(T)),
                        np.tile([1.0, 0.0, 0.0], (len(T), 1)), np.array([sigma]))
    flesh = ElasticTerm(rest, MAT.c10, MAT.c01, MAT.kappa)
    fixed, xp, right = _rollers(X, stretch)
    reactions = []
    for a in (0.0, 1.0):
        sysm = DofSystem(T, len(X), fixed, np.arange(len(T)))
        x, rep = newton(Problem([flesh, muscle], sysm, xp, np.array([a])),
                        NewtonOptions(linear_solver="direct", rtol=1e-12), force_scale=1.0)
        assert rep.converged
        reactions.append(muscle.gradient(x, np.array([a]))[right, 0].sum() + flesh.gradient(x)[right, 0].sum())
    active = (reactions[1] - reactions[0]) / L ** 2
    expected = sigma * active_curve(stretch - 1.0)[0]
    assert active == pytest.approx(expected, rel=1e-8, abs=1e-12)
    if stretch == 1.0:
        assert active == pytest.approx(sigma, rel=1e-10)


def test_fibre_force_length_curve_on_homogeneous_states():
    X, T = box_mesh((L, L, L), (2, 2, 2))
    rest = RestShape(X, T)
    sigma = 0.15
    muscle = MuscleTerm(rest, np.arange(len(T)), np.zeros(len(T), int), np.full(len(T), 0.5),
                        np.tile([1.0, 0.0, 0.0], (len(T), 1)), np.array([sigma]))
    right = X[:, 0] > L - 1e-9
    for stretch in np.linspace(0.3, 1.7, 15):
        x = X * np.array([stretch, 1.0, 1.0])
        active = (muscle.gradient(x, np.array([1.0])) - muscle.gradient(x, np.array([0.0])))[right, 0].sum() / L ** 2
        assert active == pytest.approx(0.5 * sigma * active_curve(stretch - 1.0)[0], rel=1e-10, abs=1e-14)


def test_ten_percent_inverted_elements_recover():
    X, T = box_mesh((L, L, L), (5, 5, 5))
    rest = RestShape(X, T)
    boundary = np.flatnonzero(np.any((X < 1e-9) | (X > L - 1e-9), axis=1))
    interior = np.setdiff1d(np.arange(len(X)), boundary)
    rng = np.random.default_rng(3)
    x0 = X.copy()
    moved = rng.choice(interior, 12, replace=False)
    x0[moved] += rng.normal(size=(12, 3)) * 3.5
    frac = inverted_count(rest, x0) / len(T)
    assert frac >= 0.1
    # 62 Newton steps at the 0.01 clamp (20 at Teran et al.'s 0.1): a tet crushed through inversion
    # pushes back harder but the continued energy has no curvature there (docs/physics.md)
    x, rep = solve_static(X, T, MAT, boundary, X[boundary], x0=x0,
                          options=NewtonOptions(rtol=1e-10, max_iterations=100))
    assert rep.converged
    assert inverted_count(rest, x) == 0
    np.testing.assert_allclose(x, X, atol=1e-6)


def test_newton_converges_quadratically_near_the_solution():
    X, T = box_mesh((L, L, L), (3, 3, 3))
    fixed, xp, _ = _rollers(X, 1.4)
    x, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(linear_solver="direct", rtol=1e-13))
    r = np.array(rep.residuals)
    r = r[(r < 1e-1 * r[0]) & (r > 1e-13 * r[0])]
    assert len(r) >= 3
    # log r_{k+1} = p log r_k + c: p is the order of convergence
    p = np.polyfit(np.log(r[:-1]), np.log(r[1:]), 1)[0]
    assert p > 1.8, (p, r)


def test_true_tangent_near_equilibrium_keeps_amg_newton_fast():
    X, T = box_mesh((L, L, L), (3, 3, 3))
    fixed, xp, _ = _rollers(X, 0.7)
    _, auto = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(rtol=1e-10))
    _, projected = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(rtol=1e-10, project=True))
    assert auto.converged and projected.converged
    assert auto.iterations <= projected.iterations
    assert any(auto.projected) and not all(auto.projected)


def test_index_and_mask_forms_of_fixed_agree():
    X, T = box_mesh((L, L, L), (2, 2, 2))
    idx = np.flatnonzero(X[:, 2] < 1e-9)
    top = np.flatnonzero(X[:, 2] > L - 1e-9)
    fixed_idx = np.r_[idx, top]
    pos = X[fixed_idx].copy()
    pos[len(idx):, 2] += 2.0
    x1, r1 = solve_static(X, T, MAT, fixed_idx, pos)
    mask = np.zeros((len(X), 3), bool)
    mask[fixed_idx] = True
    full = X.copy()
    full[fixed_idx] = pos
    x2, r2 = solve_static(X, T, MAT, mask, full)
    assert r1.converged and r2.converged
    np.testing.assert_allclose(x1, x2, atol=1e-8)


def test_bad_inputs_give_clear_errors():
    X, T = box_mesh((1, 1, 1), (1, 1, 1))
    with pytest.raises(FacesimError, match="fixed_positions"):
        solve_static(X, T, MAT, [0, 1], np.zeros((3, 3)))
    with pytest.raises(FacesimError, match="indices"):
        solve_static(X, T, MAT, [99], np.zeros((1, 3)))
    with pytest.raises(FacesimError, match="rest volumes"):
        solve_static(X, T[:, [0, 2, 1, 3]], MAT, [0], X[:1])
    with pytest.raises(FacesimError, match="linear_solver"):
        NewtonOptions(linear_solver="magic")


def test_newtons_linear_solves_are_no_tighter_than_the_tolerance_needs(monkeypatch):
    """The forcing term min(linear_rtol, relative residual) has a floor: a tenth of what is left
    to the tolerance (LAST_STEP_SHARE). The solve reaches the same tolerance in as many steps,
    with fewer CG iterations than without the floor."""
    from facesim.fem import linear as lin
    from facesim.fem import newton as newton_mod

    X, T = box_mesh((L, L, L), (10, 10, 10))   # big enough for AMG-CG to take several iterations
    fixed, xp, _ = _rollers(X, 1.3)
    asked = []
    solve = lin.AMGSolver.solve
    monkeypatch.setattr(lin.AMGSolver, "solve", lambda self, A, b, B=None, rtol=1e-8: asked.append(rtol)
                        or solve(self, A, b, B, rtol=rtol))
    runs = {}
    for share in (0.0, newton_mod.LAST_STEP_SHARE):
        monkeypatch.setattr(newton_mod, "LAST_STEP_SHARE", share)
        asked.clear()
        x, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(rtol=1e-8))
        runs[share] = (x, rep, list(asked))
    (x0, rep0, asked0), (x1, rep1, asked1) = runs[0.0], runs[newton_mod.LAST_STEP_SHARE]
    assert rep0.converged and rep1.converged
    tol = 1e-8 * rep1.force_scale + NewtonOptions().atol
    assert rep1.residuals[-1] <= tol and rep1.iterations <= rep0.iterations
    # the last step asked for no more than a tenth of the way to the tolerance, the old rule for more
    last = rep1.residuals[-2]
    assert asked1[-1] == pytest.approx(min(1e-2, 0.1 * tol / last), rel=1e-9)
    assert asked0[-1] < asked1[-1]
    assert sum(rep1.linear_iterations) < sum(rep0.linear_iterations)
    np.testing.assert_allclose(x1, x0, atol=1e-6 * L)


def test_a_solve_settling_at_its_iteration_limit_gets_more_steps_once():
    """At max_iterations a solve whose relative residual is already below SETTLE_BELOW gets
    settle_iterations more (once) and converges to the same answer as an unlimited solve; one
    still far from equilibrium, or with settle_iterations 0, stops flagged as before."""
    from facesim.fem.newton import SETTLE_BELOW

    X, T = box_mesh((L, L, L), (3, 3, 3))
    fixed, xp, _ = _rollers(X, 1.4)
    opts = dict(linear_solver="direct", rtol=1e-12, project=True)   # projected: linear convergence
    x_ref, ref = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(**opts, max_iterations=500))
    assert ref.converged
    r = np.array(ref.residuals) / ref.force_scale
    first_settled = int(np.argmax(r <= SETTLE_BELOW))   # iterations done when it first is below
    assert 2 <= first_settled < ref.iterations - 2, r
    # limit where it is settling: more steps, converged, the same answer
    limit = first_settled + 1
    x, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(**opts, max_iterations=limit,
                                                                      settle_iterations=500))
    assert rep.converged and rep.iterations == ref.iterations > limit
    np.testing.assert_allclose(x, x_ref, atol=1e-9 * L)
    # only once: a settle allowance too small stops at max_iterations + settle_iterations
    _, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(**opts, max_iterations=limit,
                                                                      settle_iterations=1))
    assert not rep.converged and rep.stop_reason == "iteration_limit" and rep.iterations == limit + 1
    # switched off, or not yet settling: stops at the limit
    _, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(**opts, max_iterations=limit,
                                                                      settle_iterations=0))
    assert not rep.converged and rep.stop_reason == "iteration_limit" and rep.iterations == limit
    _, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(**opts, max_iterations=first_settled - 1))
    assert not rep.converged and rep.iterations == first_settled - 1
    with pytest.raises(FacesimError, match="settle_iterations"):
        NewtonOptions(settle_iterations=-1)


def test_the_true_tangent_is_tried_again_after_a_few_projected_steps(monkeypatch):
    """A failed true-tangent step lowers the threshold tenfold; true_tangent_retry projected steps
    later it is tried again (0: as before, only once the residual has dropped tenfold)."""
    from facesim.fem import newton as newton_mod

    X, T = box_mesh((L, L, L), (3, 3, 3))
    fixed, xp, _ = _rollers(X, 1.4)
    tried = []
    hessian = newton_mod.Problem.hessian

    def failing_true(self, x, project=True):
        # every true-tangent step "fails" (not a descent direction); projected steps a third of
        # Newton's, so the residual falls by ~2/3 a step: slowly enough for the retry to show
        tried.append(project)
        A = hessian(self, x, project)
        return 3.0 * A if project else -A
    monkeypatch.setattr(newton_mod.Problem, "hessian", failing_true)
    runs = {}
    for retry in (0, 3):
        tried.clear()
        _, rep = solve_static(X, T, MAT, fixed, xp, options=NewtonOptions(
            linear_solver="direct", rtol=1e-10, max_iterations=30, settle_iterations=0, true_tangent_retry=retry))
        runs[retry] = (rep, list(tried))
    (rep0, tried0), (rep3, tried3) = runs[0], runs[3]
    assert all(rep0.projected) and all(rep3.projected)   # no true step was ever accepted
    # retried: a true attempt after every 3 projected steps once below the threshold
    attempts0, attempts3 = tried0.count(False), tried3.count(False)
    assert attempts3 > attempts0 >= 1, (attempts0, attempts3)
    first = tried3.index(False)
    pattern = tried3[first:first + 9]
    assert pattern == [False, True, True, True, False, True, True, True, False], pattern
    with pytest.raises(FacesimError, match="true_tangent_retry"):
        NewtonOptions(true_tangent_retry=-1)
