"""Coarse-to-fine cold frames (facesim.inverse.coarse): the prolongation, the muscle and control
mapping, the refusals of a model of another face, and the recovery of known activations from a
cold frame fitted on a coarser box first -- against the fine model's own cold fit."""

import dataclasses

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse.coarse import START_RTOL, CoarseStart
from facesim.inverse.gauss_newton import FitOptions, fit_frame
from facesim.inverse.jacobian import ControlSpace
from facesim.inverse.tracking import TrackOptions, track
from facesim.kinematics.condyle import SlidingCondyleJaw

from tests.conftest import make_box_model

DIRECT = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
TRUTH = Controls([0.3, 0.2], jaw=[0.04, 0.3, 0.5])


@pytest.fixture(scope="module")
def fine_box():
    """The box of the shared fixture meshed at half its spacing (5,760 tets): the fine model."""
    return make_box_model((12, 10, 8), 5.0)


@pytest.fixture(scope="module")
def fine_sim(fine_box):
    return FaceSimulator(fine_box, DIRECT, jaw_model=SlidingCondyleJaw(fine_box.jaw))


@pytest.fixture(scope="module")
def targets(fine_sim):
    """Markers of the fine box's equilibrium of TRUTH, with 0.05 mm noise."""
    x = fine_sim.equilibrium(TRUTH).x
    rng = np.random.default_rng(3)
    return fine_sim.model.marker_positions(x) + 0.05 * rng.normal(size=(fine_sim.model.n_markers, 3))


def reversed_muscles(model):
    """``model`` with its two muscles listed the other way round (same muscles, other indices)."""
    m = model.muscles
    muscle = 1 - m.muscle
    order = np.lexsort((m.tet, muscle))   # entries sorted by (muscle, tet), as a MuscleSet keeps them
    return model.with_(muscles=dataclasses.replace(m, names=m.names[::-1], sides=m.sides[::-1],
                                                   sigma_max=m.sigma_max[::-1], muscle=muscle[order],
                                                   tet=m.tet[order], fraction=m.fraction[order],
                                                   fibre=m.fibre[order]))


def test_prolongation_is_exact_for_an_affine_motion(fine_sim, box_model):
    start = CoarseStart(fine_sim, box_model)
    A = np.array([[1.05, 0.02, 0.0], [-0.03, 0.97, 0.04], [0.01, 0.0, 1.02]])
    b = np.array([0.5, -1.0, 2.0])
    x = start.prolong(box_model.X @ A.T + b)
    np.testing.assert_allclose(x, fine_sim.model.X @ A.T + b, atol=1e-9)


def test_muscles_map_by_name_not_index(fine_sim, box_model):
    flipped = reversed_muscles(box_model)
    start = CoarseStart(fine_sim, flipped)
    c = Controls([0.3, 0.1], jaw=[0.02, 0.0, 0.0])
    down = start.down(c)
    np.testing.assert_array_equal(down.a, [0.1, 0.3])
    np.testing.assert_array_equal(start.up(down).a, c.a)
    space = start.space(ControlSpace.of(fine_sim, muscles=[0]))
    assert space.muscles == (1,) and space.n_jaw == 3
    # the flipped coarse model under the mapped controls is the coarse box under the original ones
    plain = FaceSimulator(box_model, DIRECT, jaw_model=fine_sim.jaw_model)
    # (the coarse level solves to START_RTOL, its fit only seeds the fine one: compared at the full tolerance)
    assert start.sim.options.newton.rtol == START_RTOL and plain.options.newton.rtol < START_RTOL
    np.testing.assert_allclose(start.sim.equilibrium(down, newton_options=plain.options.newton).x,
                               plain.equilibrium(c).x, atol=1e-6)


def test_the_coarse_model_takes_the_fine_models_materials_and_markers(fine_sim, box_model):
    fine = fine_sim.model
    soft = fine.with_tissues([dataclasses.replace(t, c10=0.5 * t.c10) for t in fine.tissues])
    strong = soft.with_muscle_strength(2.0 * soft.muscles.sigma_max)
    start = CoarseStart(FaceSimulator(strong, DIRECT, jaw_model=fine_sim.jaw_model), box_model)
    assert [t.c10 for t in start.sim.model.tissues] == [t.c10 for t in strong.tissues]
    np.testing.assert_allclose(start.sim.model.muscles.sigma_max, strong.muscles.sigma_max)
    # the fine markers, bound to the coarse skin, sit where they are on the fine model at rest
    np.testing.assert_allclose(start.sim.model.marker_positions(box_model.X), fine.marker_positions(fine.X),
                               atol=1e-6)


@pytest.mark.parametrize("change, message", [
    (lambda m: m.with_(muscles=dataclasses.replace(m.muscles, names=("zygomaticus_major_L", "risorius_L"))),
     "muscles are not the model's"),
    (lambda m: m.with_(jaw=dataclasses.replace(m.jaw, incisor=m.jaw.incisor + [0.0, 0.0, 5.0])),
     "jaw incisor is 5.00 mm"),
    (lambda m: m.with_(X=m.X + [0.0, 0.0, 30.0]), "outside its mesh"),
    (lambda m: m.with_(X=m.X / 10.0), "same units"),
    (lambda m: make_box_model((12, 10, 8), 5.0), "not coarser"),   # a copy of the model itself
])
def test_a_model_of_another_face_is_refused(fine_sim, box_model, change, message):
    with pytest.raises(FacesimError, match=message):
        CoarseStart(fine_sim, change(box_model), name="other.npz")


def test_a_cold_frame_coarse_to_fine_recovers_the_activations(fine_sim, box_model, targets):
    space = ControlSpace.of(fine_sim)
    options = FitOptions(noise=0.05)
    neutral = Controls(np.zeros(2), jaw=np.zeros(3))
    start = CoarseStart(fine_sim, box_model)
    fit = start.fit_frame(targets, neutral, space, options)
    cold = fit_frame(fine_sim, targets, neutral, None, space, options)
    assert fit.report.converged and cold.report.converged
    np.testing.assert_allclose(fit.controls.a, TRUTH.a, atol=0.02)
    # six markers leave the box's jaw loosely determined (both fits open it 0.09 rad, not 0.04):
    # the coarse-to-fine fit lands where the full model's own cold fit does
    np.testing.assert_allclose(fit.controls.a, cold.controls.a, atol=0.01)
    # ... within what the stopping rule resolves: along that loose jaw direction a change of the
    # opening by 0.006 rad moves the objective by less than the rule's resolution (0.5 (2 noise)^2
    # = 0.005 mm^2; measured: 0.0882 rad at 0.0185 against the cold fit's 0.0947 rad at 0.0200)
    resolution = 0.5 * (options.resolution * options.noise) ** 2
    assert fit.report.objective[-1] <= cold.report.objective[-1] + resolution
    assert np.all(np.abs(np.subtract(fit.controls.jaw, cold.controls.jaw)) <= [0.01, 0.2, 0.2]), \
        (fit.controls.jaw, cold.controls.jaw)
    assert fit.report.marker_rms <= cold.report.marker_rms + 0.01
    assert fit.report.timing["coarse"] > 0.0
    assert fit.report.jacobians >= 2   # the coarse fit's and the refinement's at least
    # the refinement hands the fine fit an equilibrium and a Jacobian: it starts as a tracked frame
    coarse = fit_frame(start.sim, targets, start.down(neutral), None, start.space(space), options)
    ctrl, x, J, rep = start.refine(coarse.controls, coarse.x, space, options)
    assert x is not None and J is not None and J.age == 1 and rep.equilibria == 1
    # the fine equilibrium to START_RTOL, a Newton step or two from the full tolerance
    newton = fine_sim.options.newton
    g = fine_sim.equilibrium(ctrl, x0=x, newton_options=dataclasses.replace(newton, rtol=START_RTOL))
    assert g.converged and g.iterations == 0
    g = fine_sim.equilibrium(ctrl, x0=x)
    assert g.converged and 1 <= g.iterations <= 3
    assert J.tangent is not None   # the factor the fit's trial equilibria start with
    assert J.tangent_at is not None   # where a resumed run factorises it again
    # a fit from there that keeps no step (the markers already on their targets) finishes the
    # start to the full tolerance, and its Jacobian moves there with it
    on = fine_sim.model.marker_positions(x)
    done = fit_frame(fine_sim, on, ctrl, x, space, options, jacobian=J, finish_start=True)
    assert done.report.gn_steps == 0 and done.report.converged and done.x is not x
    assert fine_sim.equilibrium(ctrl, x0=done.x).iterations == 0
    assert done.jacobian is not None and done.jacobian.x is done.x
    np.testing.assert_allclose(done.markers, fine_sim.model.marker_positions(done.x))
    kept = fit_frame(fine_sim, on, ctrl, x, space, options, jacobian=J)
    assert kept.x is x   # without finish_start the start is returned as given


def test_a_track_with_a_coarse_model_matches_one_without(fine_sim, fine_box, box_model, tmp_path, monkeypatch):
    refined = []
    refine = CoarseStart.refine
    monkeypatch.setattr(CoarseStart, "refine", lambda self, *a, **k: refined.append(a) or refine(self, *a, **k))
    truth = [Controls([0.1 + 0.05 * k, 0.2 - 0.05 * k], jaw=[0.02 * k, 0.2, 0.2]) for k in range(3)]
    P = np.array([fine_box.marker_positions(fine_sim.equilibrium(c).x) for c in truth])
    path = box_model.save(tmp_path / "coarse.npz")
    results = {}
    for name, coarse in (("plain", None), ("coarse", str(path))):
        options = TrackOptions(fit=FitOptions(noise=0.01), head="none", coarse_model=coarse)
        s = track(fine_sim, np.arange(3), P, tmp_path / name, options=options, progress=False)
        assert s["status"] == "complete" and s["solved_frames"] == 3
        results[name] = np.loadtxt(tmp_path / name / "activations.csv", delimiter=",", skiprows=1)[:, 1:]
    assert len(refined) == 1   # the cold first frame only: the others start from their previous frame
    # a resume checks the coarse model by content, not by path
    copy = box_model.save(tmp_path / "copy.npz")
    options = TrackOptions(fit=FitOptions(noise=0.01), head="none", coarse_model=str(copy))
    s = track(fine_sim, np.arange(3), P, tmp_path / "coarse", options=options, progress=False, resume=True)
    assert s["status"] == "complete" and s["reused_frames"] == 3
    moved = box_model.with_(X=box_model.X + 0.1).save(tmp_path / "moved.npz")
    with pytest.raises(FacesimError, match="coarse_model"):
        track(fine_sim, np.arange(3), P, tmp_path / "coarse", progress=False, resume=True,
              options=TrackOptions(fit=FitOptions(noise=0.01), head="none", coarse_model=str(moved)))
    np.testing.assert_allclose(results["coarse"], [c.a for c in truth], atol=0.02)
    np.testing.assert_allclose(results["coarse"], results["plain"], atol=0.01)


def test_solve_mocap_with_a_coarse_model(fine_sim, fine_box, box_model, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    truth = [Controls([0.2, 0.1], jaw=[0.02, 0.2, 0.2]), Controls([0.25, 0.1], jaw=[0.03, 0.2, 0.2])]
    P = np.array([fine_box.marker_positions(fine_sim.equilibrium(c).x) for c in truth])
    write_trc(tmp_path / "m.trc", np.arange(2), list(fine_box.markers.names), P, fps=30.0)
    fine, coarse = fine_box.save(tmp_path / "fine.npz"), box_model.save(tmp_path / "coarse.npz")
    base = ["solve-mocap", "--model", str(fine), "--markers", str(tmp_path / "m.trc"), "--head", "none",
            "--noise", "0.01", "--no-contact", "--solver", "direct", "-q"]
    assert main([*base, "-o", str(tmp_path / "out"), "--coarse-model", str(coarse)]) == 0
    A = np.loadtxt(tmp_path / "out" / "activations.csv", delimiter=",", skiprows=1)[:, 1:]
    np.testing.assert_allclose(A, [c.a for c in truth], atol=0.02)
    report = (tmp_path / "out" / "report.json").read_text()
    assert "coarse.npz" in report   # the run records its coarse model with its options
    capsys.readouterr()
    other = box_model.with_(X=box_model.X + [0.0, 0.0, 30.0]).save(tmp_path / "other.npz")
    for path, words in ((tmp_path / "missing.npz", ["missing.npz"]), (fine, ["is the model itself"]),
                        (other, ["other.npz", "outside its mesh"])):
        assert main([*base, "-o", str(tmp_path / "bad"), "--coarse-model", str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert all(w in err for w in words), err
        assert not (tmp_path / "bad" / "frames.csv").exists()


def _refined_start(fine_sim, box_model, targets):
    """``(space, controls, x, J)``: the box fitted coarse from rest and refined on ``fine_sim``
    (``J`` the refinement's nearby Jacobian)."""
    space = ControlSpace.of(fine_sim)
    start = CoarseStart(fine_sim, box_model)
    options = FitOptions(noise=0.05)
    coarse = fit_frame(start.sim, targets, start.down(Controls(np.zeros(2), jaw=np.zeros(3))), None,
                       start.space(space), options)
    ctrl, x, J, _ = start.refine(coarse.controls, coarse.x, space, options)
    return space, ctrl, x, J


def test_a_jacobian_of_a_nearby_tangent_takes_no_extension_trials(fine_sim, box_model, targets, monkeypatch):
    """A kept full step is lengthened where the markers moved less than ``J dc`` predicted; a
    Jacobian solved with a nearby tangent (the refinement's) mispredicts by itself, so its steps
    are kept as they are -- the secant updates carry the flag, an exact evaluation drops it."""
    from facesim.inverse import gauss_newton

    calls = []
    extend = gauss_newton._extend
    monkeypatch.setattr(gauss_newton, "_extend", lambda *a: calls.append(1) or extend(*a))
    space, ctrl, x, J = _refined_start(fine_sim, box_model, targets)
    assert J.nearby and J.secant_update(np.ones(space.size) * 1e-3, x, J.dP[:, 0] * 1e-3, ctrl).nearby
    one = FitOptions(noise=0.05, max_steps=1)   # the step taken with that Jacobian
    calls.clear()
    fit = fit_frame(fine_sim, targets, ctrl, x, space, one, jacobian=J)
    assert fit.report.full_steps == 1 and not calls
    fit = fit_frame(fine_sim, targets, ctrl, x, space, one, jacobian=dataclasses.replace(J, nearby=False))
    assert fit.report.full_steps == 1 and calls == [1]


def test_a_jacobian_of_a_nearby_tangent_starts_its_step_from_the_equilibrium(fine_sim, box_model, targets,
                                                                            monkeypatch):
    """The full step's trial equilibrium starts from the Jacobian's first-order prediction, with
    the last equilibrium (bones moved) as the other candidate -- but with a nearby tangent's
    Jacobian from that equilibrium alone, its prediction left out. Both reach the same fit."""
    from facesim.inverse import gauss_newton

    starts = []
    near = gauss_newton.near_equilibrium

    def recording(sim, controls, x0, tangent, *args, previous=None, **kwargs):
        starts.append((x0, previous))
        return near(sim, controls, x0, tangent, *args, previous=previous, **kwargs)

    monkeypatch.setattr(gauss_newton, "near_equilibrium", recording)
    space, ctrl, x, J = _refined_start(fine_sim, box_model, targets)
    one = FitOptions(noise=0.05, max_steps=1)
    fits = []
    for jacobian in (J, dataclasses.replace(J, nearby=False)):
        starts.clear()
        fits.append(fit_frame(fine_sim, targets, ctrl, x, space, one, jacobian=jacobian))
        assert fits[-1].report.full_steps == 1 and len(starts) >= 1
        x0, previous = starts[0]
        if jacobian.nearby:
            assert x0 is x and previous is None
        else:
            assert previous is x and np.abs(x0 - x).max() > 1e-3   # the prediction moved it
    np.testing.assert_allclose(fits[0].controls.a, fits[1].controls.a, atol=1e-6)
    scale = np.abs(fits[0].x - x).max()
    np.testing.assert_allclose(fits[0].x, fits[1].x, atol=1e-5 * scale)


@pytest.fixture(scope="module")
def coarsest_box():
    """The box meshed coarser still (144 tets, 15-20 mm cells): the third level of a chain."""
    return make_box_model((4, 3, 2), np.array([15.0, 50.0 / 3.0, 20.0]))


def test_a_chain_fits_each_level_on_the_next_coarser_one(fine_sim, box_model, coarsest_box, targets, monkeypatch):
    refined = []
    refine = CoarseStart.refine
    monkeypatch.setattr(CoarseStart, "refine",
                        lambda self, *a, **k: refined.append(self.fine_sim.model.n_tets) or refine(self, *a, **k))
    # given coarsest first: the chain orders them finest first
    chain = CoarseStart.chain(fine_sim, [coarsest_box, box_model], ["coarsest.npz", "box.npz"])
    assert [c.name for c in chain.levels] == ["box.npz", "coarsest.npz"]
    assert chain.nested.fine_sim is chain.sim and chain.nested.nested is None
    # the middle level's markers are the fine model's, bound to its skin, and so are the coarsest's
    fine_markers = fine_sim.model.marker_positions(fine_sim.model.X)
    for level in chain.levels:
        np.testing.assert_allclose(level.sim.model.marker_positions(level.sim.model.X), fine_markers, atol=1e-6)
    space = ControlSpace.of(fine_sim)
    options = FitOptions(noise=0.05)
    neutral = Controls(np.zeros(2), jaw=np.zeros(3))
    two = CoarseStart(fine_sim, box_model).fit_frame(targets, neutral, space, options)
    refined.clear()
    three = chain.fit_frame(targets, neutral, space, options)
    # refined twice: coarsest -> box, box -> the fine model
    assert refined == [box_model.n_tets, fine_sim.model.n_tets]
    assert three.report.converged
    np.testing.assert_allclose(three.controls.a, TRUTH.a, atol=0.02)
    np.testing.assert_allclose(three.controls.a, two.controls.a, atol=0.01)
    assert three.report.marker_rms <= two.report.marker_rms + 0.005
    assert three.report.jacobians >= 3   # the coarsest fit's and both refinements' at least


def test_a_chain_refuses_two_models_of_one_size(fine_sim, box_model):
    with pytest.raises(FacesimError, match="b.npz: not coarser than a.npz"):
        CoarseStart.chain(fine_sim, [box_model, box_model], ["a.npz", "b.npz"])
    with pytest.raises(FacesimError, match="no coarse model"):
        CoarseStart.chain(fine_sim, [])


def test_solve_mocap_with_a_chain_of_coarse_models(fine_sim, fine_box, box_model, coarsest_box, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    truth = [Controls([0.2, 0.1], jaw=[0.02, 0.2, 0.2]), Controls([0.25, 0.1], jaw=[0.03, 0.2, 0.2])]
    P = np.array([fine_box.marker_positions(fine_sim.equilibrium(c).x) for c in truth])
    write_trc(tmp_path / "m.trc", np.arange(2), list(fine_box.markers.names), P, fps=30.0)
    fine, coarse = fine_box.save(tmp_path / "fine.npz"), box_model.save(tmp_path / "coarse.npz")
    coarsest = coarsest_box.save(tmp_path / "coarsest.npz")
    base = ["solve-mocap", "--model", str(fine), "--markers", str(tmp_path / "m.trc"), "--head", "none",
            "--noise", "0.01", "--no-contact", "--solver", "direct", "-q"]
    chain = ["--coarse-model", str(coarsest), "--coarse-model", str(coarse)]
    assert main([*base, "-o", str(tmp_path / "out"), *chain]) == 0
    A = np.loadtxt(tmp_path / "out" / "activations.csv", delimiter=",", skiprows=1)[:, 1:]
    np.testing.assert_allclose(A, [c.a for c in truth], atol=0.02)
    report = (tmp_path / "out" / "report.json").read_text()
    assert "coarsest.npz" in report and "coarse.npz" in report
    # a resume with the same chain reuses every frame; with one level fewer it is another run
    assert main([*base, "-o", str(tmp_path / "out"), *chain, "--resume"]) == 0
    assert "(2 reused)" in capsys.readouterr().out
    assert main([*base, "-o", str(tmp_path / "out"), "--coarse-model", str(coarse), "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "coarse_model" in err, err
    for args, words in (([str(coarse), str(coarse)], ["named twice"]),
                        ([str(coarse), str(fine_box.save(tmp_path / "copy.npz"))], ["copy.npz", "not coarser"])):
        assert main([*base, "-o", str(tmp_path / "bad"), *[a for p in args for a in ("--coarse-model", p)]]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert all(w in err for w in words), err
        assert not (tmp_path / "bad" / "frames.csv").exists()


def test_solve_mocap_suggests_a_coarse_model_for_a_large_model(fine_sim, fine_box, tmp_path, capsys, monkeypatch):
    from facesim import cli
    from facesim.mocap.io import write_trc

    P = fine_box.marker_positions(fine_sim.equilibrium(Controls([0.2, 0.1], jaw=[0.02, 0.2, 0.2])).x)[None]
    write_trc(tmp_path / "m.trc", np.arange(1), list(fine_box.markers.names), P, fps=30.0)
    fine = fine_box.save(tmp_path / "fine.npz")
    base = ["solve-mocap", "--model", str(fine), "--markers", str(tmp_path / "m.trc"), "--head", "none",
            "--noise", "0.01", "--no-contact", "--solver", "direct"]
    monkeypatch.setattr(cli, "COARSE_HINT_ABOVE", fine_box.n_simulated)   # this box counts as large
    for extra, hinted in (([], True), (["-q"], False), (["--coarse-model", str(make_box_model().save(
            tmp_path / "coarse.npz"))], False)):
        assert cli.main([*base, "-o", str(tmp_path / f"out{len(extra)}"), *extra]) == 0
        err = capsys.readouterr().err
        assert ("--coarse-model COARSE.npz" in err) == hinted, err
    monkeypatch.setattr(cli, "COARSE_HINT_ABOVE", fine_box.n_simulated + 1)   # not large
    assert cli.main([*base, "-o", str(tmp_path / "small")]) == 0
    assert "--coarse-model" not in capsys.readouterr().err
