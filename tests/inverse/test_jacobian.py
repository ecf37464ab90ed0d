"""Implicit Jacobians against central differences of full equilibria (issue 5)."""

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import ControlSpace, equilibrium_jacobian, marker_jacobian
from facesim.kinematics.condyle import SlidingCondyleJaw

TIGHT = NewtonOptions(linear_solver="direct", rtol=1e-11, atol=1e-13)


@pytest.fixture(scope="module")
def face_model():
    from pathlib import Path

    from facesim.model import load_model

    return load_model(Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz")


def central_marker_differences(sim, space, controls, x, h=1e-4):
    c0 = space.vector(controls)
    cols = []
    for k in range(space.size):
        P = []
        for s in (1.0, -1.0):
            c = c0.copy()
            c[k] += s * h
            eq = sim.equilibrium(space.apply(controls, c), x0=x)
            assert eq.converged
            P.append(sim.model.marker_positions(eq.x).ravel())
        cols.append((P[0] - P[1]) / (2 * h))
    return np.column_stack(cols)


def test_marker_jacobian_matches_central_differences(box_model):
    rng = np.random.default_rng(0)
    x = box_model.X + 0.5 * rng.normal(size=box_model.X.shape)
    M = marker_jacobian(box_model, x)
    assert M.shape == (3 * box_model.n_markers, 3 * box_model.n_nodes)
    for _ in range(3):
        v = rng.normal(size=x.shape)
        fd = (box_model.marker_positions(x + 1e-6 * v) - box_model.marker_positions(x - 1e-6 * v)).ravel() / 2e-6
        np.testing.assert_allclose(M @ v.ravel(), fd, rtol=1e-7, atol=1e-9 * np.abs(fd).max())


def test_box_jacobian_for_activations_jaw_and_head(box_model):
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=TIGHT), jaw_model=SlidingCondyleJaw(box_model.jaw))
    controls = Controls([0.4, 0.3], jaw=[0.1, 2.0, 1.0])
    eq = sim.equilibrium(controls)
    assert eq.converged
    space = ControlSpace.of(sim, head=True)
    assert space.size == 2 + 3 + 6
    assert space.names(box_model)[:3] == ["zygomaticus_major_L", "orbicularis_oris", "jaw_0"]
    J = equilibrium_jacobian(sim, controls, eq.x, space)
    fd = central_marker_differences(sim, space, controls, eq.x)
    err = np.linalg.norm(J.dP - fd, axis=0) / np.linalg.norm(fd, axis=0)
    assert err.max() < 1e-4, err
    # the activation columns are not trivially small: the markers move
    assert np.linalg.norm(J.dP[:, :2], axis=0).min() > 1.0
    # first-order prediction of a small change lands close to the solved equilibrium
    dc = np.r_[0.02, -0.02, 0.005, 0.15, 0.1, np.zeros(6)]
    moved = sim.equilibrium(space.apply(controls, space.vector(controls) + dc), x0=eq.x)
    assert np.abs(J.predict(dc) - moved.x).max() < 0.1 * np.abs(moved.x - eq.x).max()


def test_face_marker_jacobian_against_full_equilibria(face_model):
    """The issue's check on the shipped face: a few activations and the three sliding-condyle
    parameters, relative error < 1e-4 per column."""
    model = face_model
    jaw = SlidingCondyleJaw(model.jaw)
    sim = FaceSimulator(model, EquilibriumOptions(newton=NewtonOptions(rtol=1e-10, atol=1e-12,
                                                                       linear_solver="direct")), jaw_model=jaw)
    names = model.muscles.names
    pick = [names.index(n) for n in ("zygomaticus_major_L", "orbicularis_oris_upper_L", "depressor_anguli_oris_R")]
    a = np.zeros(model.n_muscles)
    a[pick] = [0.4, 0.3, 0.2]
    controls = Controls(a, jaw=[0.1, 1.0, 1.0])
    eq = sim.equilibrium(controls)
    assert eq.converged
    space = ControlSpace(model.n_muscles, tuple(pick), 3)
    J = equilibrium_jacobian(sim, controls, eq.x, space)
    fd = central_marker_differences(sim, space, controls, eq.x, h=1e-4)
    err = np.linalg.norm(J.dP - fd, axis=0) / np.linalg.norm(fd, axis=0)
    assert err.max() < 1e-4, err


def test_a_jacobian_solved_with_a_given_nearby_tangent(box_model):
    """``tangent=``: the columns solved with a factor assembled elsewhere -- the exact Jacobian
    when that is this equilibrium's tangent, first-order close when it is a nearby one; age 1."""
    from facesim.fem.linear import DirectSolver
    from facesim.fem.newton import Problem

    sim = FaceSimulator(box_model, EquilibriumOptions(newton=TIGHT), jaw_model=SlidingCondyleJaw(box_model.jaw))
    controls = Controls([0.4, 0.3], jaw=[0.1, 2.0, 1.0])
    x = sim.equilibrium(controls).x
    space = ControlSpace.of(sim)
    exact = equilibrium_jacobian(sim, controls, x, space, linear_solver="direct")

    def given(c, at):
        K = Problem(sim.terms, sim.system, at, c.a).hessian(at, project=False)
        return DirectSolver().factorize(K)

    here = equilibrium_jacobian(sim, controls, x, space, tangent=given(controls, x), tangent_at=(controls, x, 0.0))
    np.testing.assert_allclose(here.dP, exact.dP, atol=1e-8 * np.abs(exact.dP).max())
    assert here.age == 1 and exact.age == 0 and here.tangent_at[1] is x
    errors = []
    for step in (0.1, 0.05):   # the tangent of a nearby equilibrium: the error shrinks with the distance
        near = Controls([0.4 - step, 0.3 + step], jaw=[0.1, 2.0, 1.0])
        xn = sim.equilibrium(near, x0=x).x
        J = equilibrium_jacobian(sim, controls, x, space, tangent=given(near, xn), tangent_at=(near, xn, 0.0))
        errors.append(np.linalg.norm(J.dP - exact.dP) / np.linalg.norm(exact.dP))
    assert 0 < errors[1] < 0.7 * errors[0] and errors[0] < 0.2, errors


def test_control_space_errors(box_model):
    with pytest.raises(FacesimError, match="distinct and in"):
        ControlSpace(2, (0, 0))
    sim = FaceSimulator(box_model)
    with pytest.raises(FacesimError, match="no parameters to solve for"):
        ControlSpace.of(sim, jaw=True)
    space = ControlSpace.of(sim, jaw=False)
    with pytest.raises(FacesimError, match="expected 2 values"):
        space.apply(Controls([0.0, 0.0]), [1.0])


def test_secant_update_is_exact_along_the_step_and_unchanged_across(box_model):
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=TIGHT), jaw_model=SlidingCondyleJaw(box_model.jaw))
    controls = Controls([0.3, 0.2], jaw=[0.05, 0.5, 0.5])
    eq = sim.equilibrium(controls)
    space = ControlSpace.of(sim)
    J = equilibrium_jacobian(sim, controls, eq.x, space)
    assert J.age == 0 and J.tangent is not None            # direct solve: the factorisation is kept
    dc = np.array([0.1, -0.05, 0.01, 0.3, 0.0])
    moved = sim.equilibrium(space.apply(controls, space.vector(controls) + dc), x0=J.predict(dc))
    dP = (box_model.marker_positions(moved.x) - box_model.marker_positions(eq.x)).ravel()
    assert np.linalg.norm(J.dP @ dc - dP) > 1e-3 * np.linalg.norm(dP)   # the step is not linear
    U = J.secant_update(dc, moved.x, dP, moved.controls)
    assert U.age == 1 and U.tangent is J.tangent and U.x is not J.x
    np.testing.assert_allclose(U.dP @ dc, dP, atol=1e-12 * np.abs(dP).max())
    np.testing.assert_allclose(U.predict(dc * 0), moved.x)
    np.testing.assert_allclose(U.dx @ dc, (moved.x - eq.x).ravel(), atol=1e-10)
    across = np.array([0.05, 0.1, 0.0, 0.0, 0.0])
    across -= dc * (across @ dc) / (dc @ dc)
    np.testing.assert_allclose(U.dP @ across, J.dP @ across, atol=1e-12)
    # it travels to another process without its factorisation (SuperLU does not pickle)
    import pickle

    back = pickle.loads(pickle.dumps(U))
    assert back.tangent is None and U.tangent is not None and back.age == 1
    np.testing.assert_array_equal(back.dP, U.dP)


def _near_case(box_model):
    """A tight direct-solver simulator, an equilibrium ``eq``, its Jacobian ``J``, a control change
    ``dc`` and the controls ``target`` it leads to."""
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-9)),
                        jaw_model=SlidingCondyleJaw(box_model.jaw))
    controls = Controls([0.3, 0.2], jaw=[0.05, 0.5, 0.5])
    eq = sim.equilibrium(controls)
    space = ControlSpace.of(sim)
    J = equilibrium_jacobian(sim, controls, eq.x, space)
    dc = np.array([0.05, 0.04, 0.01, 0.2, -0.1])
    return sim, eq, J, dc, space.apply(controls, space.vector(controls) + dc)


def test_near_equilibrium_reuses_the_tangent(box_model):
    """Chord / preconditioned-Newton iterations on the Jacobian's factorised tangent reach the same
    equilibrium as Newton from the first-order prediction; a far-away state is refused, not
    mis-solved."""
    from facesim.inverse.jacobian import near_equilibrium

    sim, eq, J, dc, target = _near_case(box_model)
    x, iterations, solves, ok = near_equilibrium(sim, target, J.predict(dc), J.tangent)
    newton = sim.equilibrium(target, x0=J.predict(dc))
    assert ok and 1 <= iterations <= 8 and solves >= iterations
    scale = np.abs(newton.x - eq.x).max()
    assert scale > 0.1
    np.testing.assert_allclose(x, newton.x, atol=1e-6 * scale)
    # a large change from a bad start: no convergence claimed, the best iterate returned
    far = Controls([1.0, 1.0], jaw=[0.4, 8.0, -8.0])
    x_far, _, _, ok_far = near_equilibrium(sim, far, eq.x, J.tangent, max_iterations=2)
    assert not ok_far and np.isfinite(x_far).all()


def test_near_equilibrium_cuts_back_an_overshooting_newton_step(box_model, monkeypatch):
    """A Newton step of near_equilibrium that does not shrink the residual enough is cut back along
    its direction (each trial one gradient) rather than giving the solve up: with CG's answer
    doubled (an overshoot) the solve still converges, through half steps, to Newton's equilibrium;
    without the cut-back it gives up."""
    import facesim.inverse.jacobian as jac

    sim, eq, J, dc, target = _near_case(box_model)
    newton = sim.equilibrium(target, x0=J.predict(dc))
    exact_cg = jac.counted_cg

    def overshooting_cg(*args, **kwargs):
        du, info, its = exact_cg(*args, **kwargs)
        return 2.0 * du, info, its

    monkeypatch.setattr(jac, "counted_cg", overshooting_cg)
    # chord_rate 0: one chord iteration, then Newton steps (each one doubled)
    x, iterations, _, ok = jac.near_equilibrium(sim, target, J.predict(dc), J.tangent, chord_rate=0.0)
    assert ok and iterations >= 2
    scale = np.abs(newton.x - eq.x).max()
    np.testing.assert_allclose(x, newton.x, atol=1e-6 * scale)
    monkeypatch.setattr(jac, "NEWTON_BACKTRACK", ())
    _, _, _, ok_without = jac.near_equilibrium(sim, target, J.predict(dc), J.tangent, chord_rate=0.0)
    assert not ok_without


def test_pardiso_superlu_and_amg_jacobians_agree(box_model):
    """The three linear solvers behind the Jacobian give the same columns, and the PARDISO
    factorisation serves near_equilibrium's chord iterations like SuperLU's."""
    pytest.importorskip("pypardiso")
    from facesim.inverse.jacobian import DIRECT_COLUMN_RTOL, near_equilibrium

    sim = FaceSimulator(box_model, EquilibriumOptions(newton=TIGHT), jaw_model=SlidingCondyleJaw(box_model.jaw))
    controls = Controls([0.4, 0.3], jaw=[0.1, 2.0, 1.0])
    x = sim.equilibrium(controls).x
    space = ControlSpace.of(sim)
    J = {kind: equilibrium_jacobian(sim, controls, x, space, linear_solver=kind) for kind in ("direct", "pardiso", "amg")}
    scale = np.abs(J["direct"].dP).max()
    # PARDISO factorises in single precision, its columns kept within DIRECT_COLUMN_RTOL (~1e-6 here)
    assert np.abs(J["pardiso"].dP - J["direct"].dP).max() < DIRECT_COLUMN_RTOL * scale
    assert np.abs(J["amg"].dP - J["direct"].dP).max() < 1e-6 * scale
    dc = np.array([0.02, -0.02, 0.005, 0.1, 0.1])
    near = space.apply(controls, space.vector(controls) + dc)
    xp, its, _, ok = near_equilibrium(sim, near, J["pardiso"].predict(dc), J["pardiso"].tangent)
    xs, _, _, ok_s = near_equilibrium(sim, near, J["direct"].predict(dc), J["direct"].tangent)
    assert ok and ok_s and its >= 1
    np.testing.assert_allclose(xp, xs, atol=1e-6)
    with pytest.raises(FacesimError, match="linear_solver"):
        equilibrium_jacobian(sim, controls, x, space, linear_solver="mumps")


def _crushed(sim, x):
    """``x (n, 3)`` with one free node of a simulated tet reflected through the plane of the tet's
    other three nodes: that tet inverted (volume ratio about -1)."""
    model = sim.model
    free = ~sim.fixed.all(axis=1)
    tets = model.tets[sim.elems]
    k = int(np.flatnonzero(free[tets[:, 0]])[0])
    a, b, c, d = (x[i] for i in tets[k])
    n = np.cross(c - b, d - b)
    n /= np.linalg.norm(n)
    out = x.copy()
    out[tets[k, 0]] = a - 2.0 * np.dot(a - b, n) * n
    assert sim.element_quality(out)[1] < -0.5
    return out


def test_near_equilibrium_drops_a_crushed_start_when_it_has_another(box_model, monkeypatch):
    """With the previous equilibrium to fall back on, a start x0 with an inverted tet is dropped
    (FaceSimulator.predict(repair=False) gives None), not refined by as-rigid-as-possible steps
    only to lose to the other start, and the solve reaches Newton's equilibrium from the other one;
    alone, the crushed start is refined as before."""
    import facesim.fem.equilibrium as equilibrium_module
    from facesim.inverse.jacobian import near_equilibrium

    sim, eq, J, dc, target = _near_case(box_model)
    newton = sim.equilibrium(target, x0=J.predict(dc))
    crushed = _crushed(sim, J.predict(dc))
    assert sim.predict(target, crushed, repair=False) is None
    np.testing.assert_array_equal(sim.predict(target, J.predict(dc), repair=False), sim.predict(target, J.predict(dc)))
    refine = equilibrium_module.FaceSimulator._as_rigid_as_possible
    refined = []

    def counting(self, *args, **kwargs):
        refined.append(1)
        return refine(self, *args, **kwargs)

    monkeypatch.setattr(equilibrium_module.FaceSimulator, "_as_rigid_as_possible", counting)
    scale = np.abs(newton.x - eq.x).max()
    x, _, _, ok = near_equilibrium(sim, target, crushed, J.tangent, previous=eq.x)
    assert ok and not refined
    np.testing.assert_allclose(x, newton.x, atol=1e-6 * scale)
    x, _, _, _ = near_equilibrium(sim, target, crushed, J.tangent)   # (its caller goes on with Newton)
    assert len(refined) == 1 and np.isfinite(x).all()


def _recorded_near_solve(box_model, monkeypatch):
    """near_equilibrium on :func:`_near_case` (one chord iteration, then Newton steps) with its CG
    calls ``(|b|, A, rtol)``, its tolerance and its Hessian assemblies recorded; checks that it
    reaches the equilibrium Newton reaches from the same start."""
    import facesim.fem.newton as fem_newton
    import facesim.inverse.jacobian as jac

    sim, eq, J, dc, target = _near_case(box_model)
    newton = sim.equilibrium(target, x0=J.predict(dc))
    exact_cg, exact_scale, exact_hessian = jac.counted_cg, type(sim).force_scale, fem_newton.Problem.hessian
    calls, scales, assembled = [], [], []

    def recording_cg(A, b, rtol, maxiter, M):
        calls.append((float(np.linalg.norm(b)), A, rtol))
        return exact_cg(A, b, rtol, maxiter, M)

    def recording_scale(self, *args, **kwargs):
        scales.append(exact_scale(self, *args, **kwargs))
        return scales[-1]

    def counting_hessian(self, *args, **kwargs):
        assembled.append(exact_hessian(self, *args, **kwargs))
        return assembled[-1]

    monkeypatch.setattr(jac, "counted_cg", recording_cg)
    monkeypatch.setattr(type(sim), "force_scale", recording_scale)
    monkeypatch.setattr(fem_newton.Problem, "hessian", counting_hessian)
    x, _, _, ok = jac.near_equilibrium(sim, target, J.predict(dc), J.tangent, chord_rate=0.0)
    assert ok and len(calls) >= 2, [c[0] for c in calls]
    np.testing.assert_allclose(x, newton.x, atol=1e-6 * np.abs(newton.x - eq.x).max())
    return calls, sim.options.newton.rtol * scales[-1] + sim.options.newton.atol, len(assembled)


def test_near_equilibrium_newton_steps_solve_cg_to_a_forcing_term(box_model, monkeypatch):
    """The Newton steps of near_equilibrium solve CG only as far as the step can use: the first
    to CHORD_NEWTON_RTOL, each later one to CHORD_NEWTON_GAMMA times the square of the last
    Newton step's rate (Eisenstat-Walker), never tighter than CHORD_LAST_SHARE of what is left to
    the tolerance -- and reach the equilibrium Newton reaches from the same start."""
    import facesim.inverse.jacobian as jac

    calls, tol, _ = _recorded_near_solve(box_model, monkeypatch)
    for k, (res, _, rtol) in enumerate(calls):
        eta = jac.CHORD_NEWTON_RTOL if k == 0 else min(jac.CHORD_NEWTON_RTOL,
                                                       jac.CHORD_NEWTON_GAMMA * (res / calls[k - 1][0]) ** 2)
        assert rtol == pytest.approx(max(eta, jac.CHORD_LAST_SHARE * tol / res), rel=1e-12), (k, calls)
    # the later steps are solved tighter than the first: the forcing term follows the convergence
    assert calls[-1][2] < calls[0][2]


def test_near_equilibrium_last_newton_step_reuses_the_tangent(box_model, monkeypatch):
    """A Newton step of near_equilibrium whose predecessor's rate would take it within
    CHORD_LAST_SHARE of the tolerance reuses that step's tangent (the same matrix, no assembly);
    every other Newton step assembles its own. The solve still reaches Newton's equilibrium."""
    import facesim.inverse.jacobian as jac

    calls, tol, assembled = _recorded_near_solve(box_model, monkeypatch)
    reuse = [k > 0 and (res / calls[k - 1][0]) * res <= jac.CHORD_LAST_SHARE * tol
             for k, (res, _, _) in enumerate(calls)]
    assert any(reuse) and not all(reuse), [c[0] for c in calls]   # the case exercises both
    for k, (_, A, _) in enumerate(calls):
        assert (A is calls[k - 1][1]) == reuse[k], (k, [c[0] for c in calls])
    assert assembled == len(calls) - sum(reuse)
