"""Sequence tracking: warm starts, missing markers, outliers and the robust loss, files written per
frame and resume, chunks solved in parallel by dask.distributed."""

import json

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import tracking
from facesim.inverse.gauss_newton import FitOptions
from facesim.inverse.jacobian import ControlSpace
from facesim.inverse.parallel import SimulatorSpec, dask_client
from facesim.inverse.tracking import TrackOptions, fit_markers, loss_weights, track
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import MarkerSet

from tests.conftest import interrupt_frame_solves

DIRECT = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8))
#: 4 frames in chunks of 2, with few Gauss-Newton steps: the parallel tests compare runs, not recovery
CHUNKED = TrackOptions(fit=FitOptions(noise=0.01, max_steps=2, golden_tolerance=0.3), head="none", chunk_size=2)


@pytest.fixture(scope="module")
def sequence(box_model):
    sim = FaceSimulator(box_model, DIRECT, jaw_model=SlidingCondyleJaw(box_model.jaw))
    truth = [Controls([0.2 * k, 0.1 * k], jaw=[0.03 * k, 0.5 * k, 0.5 * k]) for k in range(4)]
    P = np.array([box_model.marker_positions(sim.equilibrium(c).x) for c in truth])
    return sim, truth, P


def test_track_recovers_a_sequence_and_writes_every_frame(sequence, box_model, tmp_path):
    sim, truth, P = sequence
    P = P.copy()
    P[2, 0] = np.nan                        # a gap
    options = TrackOptions(fit=FitOptions(noise=0.01), head="none", outlier_floor=1.0)
    s = track(sim, np.arange(4), P, tmp_path, options=options, progress=False)
    assert s["status"] == "complete" and s["solved_frames"] == 4
    A = np.loadtxt(tmp_path / "activations.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(A[:, 1:], [c.a for c in truth], atol=0.02)
    J = np.loadtxt(tmp_path / "jaw.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(J[:, 1], [c.jaw[0] for c in truth], atol=0.01)
    assert s["outliers"] == {}
    R = np.genfromtxt(tmp_path / "residuals.csv", delimiter=",", names=True)
    assert np.isnan(R["mouth_L"][2]) and R["rms"].max() < 0.05
    # warm starts: after the first frame, frames need few Gauss-Newton steps
    assert max(s["gn_steps"][1:]) <= 5
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["status"] == "complete"


def test_resume_continues_after_the_last_written_frame(sequence, box_model, tmp_path, monkeypatch):
    sim, truth, P = sequence
    options = TrackOptions(fit=FitOptions(noise=0.01), head="none")
    interrupt_frame_solves(monkeypatch, at=3)
    with pytest.raises(KeyboardInterrupt):
        track(sim, np.arange(4), P, tmp_path, options=options, progress=False)
    monkeypatch.undo()
    # the capture of another run (here: fewer frames) does not continue this one
    with pytest.raises(FacesimError, match="other inputs: markers, frames differ"):
        track(sim, np.arange(2), P[:2], tmp_path, options=options, resume=True, progress=False)
    s = track(sim, np.arange(4), P, tmp_path, options=options, resume=True, progress=False)
    assert s["reused_frames"] == 2 and s["solved_frames"] == 2 and s["warm_starts_restored"] == 1
    A = np.loadtxt(tmp_path / "activations.csv", delimiter=",", skiprows=1)
    assert list(A[:, 0]) == [0, 1, 2, 3]
    assert not (tmp_path / "state").exists()   # the warm starts go with the finished run


def test_outlier_test_flags_far_residuals_only():
    from facesim.inverse.tracking import _outliers

    rng = np.random.default_rng(3)
    target = rng.normal(size=(40, 3))
    P = target + 0.3 * rng.normal(size=(40, 3))
    P[7] += [0.0, 6.0, 0.0]
    P[9] = np.nan
    assert _outliers(P, target, TrackOptions(outlier_floor=1.0)) == [7]
    assert _outliers(P, target, TrackOptions(outlier_floor=10.0)) == []


def test_bad_shapes(sequence, tmp_path):
    sim, _, P = sequence
    with pytest.raises(FacesimError, match="expected"):
        track(sim, np.arange(3), P, tmp_path, progress=False)


def test_solve_mocap_cli_on_a_trc(sequence, box_model, box_model_path, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    _, truth, P = sequence
    names = list(box_model.markers.names)
    names[0] = "EXTRA"                           # a name the model does not have: reported, its column unused
    write_trc(tmp_path / "m.trc", np.arange(3), names, P[:3], fps=30.0)
    out = tmp_path / "out"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.01", "--solver", "direct", "-q"]) == 0
    printed = capsys.readouterr().out
    assert "not in the model: EXTRA" in printed and "not in the file: mouth_L" in printed
    A = np.loadtxt(out / "activations.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(A[:, 1:], [c.a for c in truth[:3]], atol=0.03)
    assert (out / "activations.png").stat().st_size > 1000 and (out / "residuals.png").is_file()
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "nope.c3d"),
                 "-o", str(out)]) == 2
    assert "no such C3D file" in capsys.readouterr().err
    for bad, message in (("a:b", "expected FIRST:LAST frame numbers"), ("40:50", "no frames in that range")):
        assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"),
                     "-o", str(out), "--frames", bad]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


# ------------------------------------------------------------------ files: frames in order, resume
def test_frames_finished_out_of_order_wait_in_chunks_then_merge_in_order(tmp_path):
    headers = {"activations": ["frame", "a"], "jaw": ["frame", "q"], "residuals": ["frame", "rms"],
               "frames": list(tracking.LOG_COLUMNS)}

    def lines(k):
        return tuple(",".join([str(k)] + ["0.5"] * (len(headers[name]) - 1)) + "\n" for name in tracking.LOGS)

    def frames_in(path):
        return [int(ln.split(",")[0]) for ln in path.read_text().splitlines()[1:]]

    frames = [10, 11, 12, 13]
    out = tracking._Outputs(tmp_path, headers, frames, resume=False)
    out.add(2, lines(12))                      # a later chunk finishes first: it waits in chunks/
    out.add(0, lines(10))
    out.close()
    assert frames_in(tmp_path / "activations.csv") == [10]
    assert frames_in(tmp_path / "chunks" / "jaw.csv") == [12]
    with open(tmp_path / "frames.csv", "a") as fh:
        fh.write("11,0.1")                     # a line cut by the interruption: not a finished frame
    out = tracking._Outputs(tmp_path, headers, frames, resume=True)
    assert sorted(out.done) == [10, 12] and out.n_merged == 1
    out.add(1, lines(11))                      # closes the gap: 11 and the waiting 12 move to the files
    assert frames_in(tmp_path / "residuals.csv") == [10, 11, 12]
    out.add(3, lines(13))
    out.close()
    for name in tracking.LOGS:
        assert frames_in(tmp_path / f"{name}.csv") == frames
    assert not (tmp_path / "chunks").exists()


def test_runs_split_unfinished_frames_by_chunk():
    done = [True, False, False, True, False, False, False]
    # chunks [0, 3), [3, 6), [6, 7): runs after a finished frame of their chunk start warm
    assert tracking._runs(7, 3, done) == [(1, 3, True), (4, 6, True), (6, 7, False)]
    assert tracking._runs(3, 3, [False] * 3) == [(0, 3, False)]


# ------------------------------------------------------------------ parallel chunks
@pytest.fixture(scope="module")
def spec(box_model_path):
    return SimulatorSpec.of(box_model_path, DIRECT)


@pytest.fixture(scope="module")
def client():
    pytest.importorskip("distributed")
    with dask_client(workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def chunked(spec, sequence, tmp_path_factory):
    """The reference: the sequence in chunks of 2, solved one chunk after the other in this process."""
    _, _, P = sequence
    out = tmp_path_factory.mktemp("serial_chunks")
    s = track(spec, np.arange(4), P, out, options=CHUNKED, progress=False)
    assert s["status"] == "complete" and s["workers"] == 0
    return out


def _results(out):
    return {name: np.loadtxt(out / f"{name}.csv", delimiter=",", skiprows=1, ndmin=2)
            for name in ("activations", "jaw", "residuals")}


def test_chunks_start_cold(chunked, spec, sequence, tmp_path):
    _, _, P = sequence
    track(spec, [2], P[2:3], tmp_path, options=CHUNKED, progress=False)
    alone, in_chunk = _results(tmp_path), _results(chunked)
    for name in alone:
        np.testing.assert_allclose(alone[name][0], in_chunk[name][2], atol=1e-9)


def test_parallel_chunks_equal_serial_chunks_in_frame_order(chunked, spec, sequence, client, tmp_path):
    _, _, P = sequence
    s = track(spec, np.arange(4), P, tmp_path, options=CHUNKED, progress=False, client=client)
    assert s["status"] == "complete" and s["workers"] == 2 and s["chunk_size"] == 2 and s["solved_frames"] == 4
    got, want = _results(tmp_path), _results(chunked)
    for name in got:
        assert list(got[name][:, 0]) == [0, 1, 2, 3]
        np.testing.assert_allclose(got[name], want[name], atol=1e-7)
    assert list(np.loadtxt(tmp_path / "frames.csv", delimiter=",", skiprows=1, usecols=(0, 1))[:, 0]) == [0, 1, 2, 3]
    assert not (tmp_path / "chunks").exists()


def test_interrupted_parallel_run_resumes_to_the_uninterrupted_result(chunked, spec, sequence, client, tmp_path,
                                                                      monkeypatch):
    _, _, P = sequence
    add = tracking._Outputs.add
    written = []

    def add_then_interrupt(self, i, lines):
        if len(written) == 2:
            raise KeyboardInterrupt
        written.append(i)
        add(self, i, lines)

    monkeypatch.setattr(tracking._Outputs, "add", add_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        track(spec, np.arange(4), P, tmp_path, options=CHUNKED, progress=False, client=client)
    monkeypatch.undo()
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["status"] == "interrupted" and report["solved_frames"] == 2
    on_disk = list(np.loadtxt(tmp_path / "activations.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0])
    if (tmp_path / "chunks").exists():         # a frame of the second chunk finished before the first chunk
        on_disk += list(np.loadtxt(tmp_path / "chunks" / "activations.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0])
    assert sorted(on_disk) == sorted(written)

    s = track(spec, np.arange(4), P, tmp_path, options=CHUNKED, progress=False, client=client, resume=True)
    assert s["status"] == "complete" and s["reused_frames"] == 2 and s["solved_frames"] == 2
    got, want = _results(tmp_path), _results(chunked)
    for name in got:
        assert list(got[name][:, 0]) == [0, 1, 2, 3]
        # resumed frames start from the written (6-digit) controls: equal within the solver's tolerance
        np.testing.assert_allclose(got[name], want[name], atol=1e-4)
    assert not (tmp_path / "chunks").exists()


def test_parallel_tracking_needs_a_spec(sequence, client, tmp_path):
    sim, _, P = sequence
    with pytest.raises(FacesimError, match="SimulatorSpec"):
        track(sim, np.arange(4), P, tmp_path, options=CHUNKED, progress=False, client=client)


def test_solve_mocap_cli_on_a_running_scheduler(sequence, box_model, box_model_path, client, tmp_path, capsys):
    from facesim.cli import main
    from facesim.mocap.io import write_trc

    _, truth, P = sequence
    write_trc(tmp_path / "m.trc", np.arange(4), list(box_model.markers.names), P, fps=30.0)
    out = tmp_path / "out"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.01", "--solver", "direct", "--scheduler", client.scheduler.address,
                 "--chunk-size", "2", "--loss", "huber", "-q"]) == 0
    assert "solved 4 frames" in capsys.readouterr().out
    A = np.loadtxt(out / "activations.csv", delimiter=",", skiprows=1)
    assert list(A[:, 0]) == [0, 1, 2, 3]
    np.testing.assert_allclose(A[:, 1:], [c.a for c in truth], atol=0.03)
    report = json.loads((out / "report.json").read_text())
    assert report["workers"] == 2 and report["loss"] == "huber" and (out / "activations.png").is_file()


# ------------------------------------------------------------------ missing markers, outliers, robust loss
@pytest.fixture(scope="module")
def dense(box_model):
    """The box with 50 markers spread over its front face, and 3 frames made on it."""
    rng = np.random.default_rng(0)
    front = np.flatnonzero(box_model.X[box_model.skin].mean(axis=1)[:, 2] > 19.9)
    r = 50
    markers = MarkerSet(names=[f"m{j:02d}" for j in range(r)], triangle=rng.choice(front, r, replace=False),
                        bary=rng.dirichlet(np.ones(3), r), offset=np.zeros(r), head=np.zeros(r, bool))
    model = box_model.with_(markers=markers)
    sim = FaceSimulator(model, DIRECT, jaw_model=SlidingCondyleJaw(model.jaw))
    truth = [Controls([0.15 * k, 0.1 * k], jaw=[0.02 * k, 0.3 * k, 0.3 * k]) for k in range(1, 4)]
    P = np.array([model.marker_positions(sim.equilibrium(c).x) for c in truth])
    return sim, truth, P


def test_loss_weights_closed_forms():
    r = np.array([0.0, 0.5, 2.0, np.nan])
    np.testing.assert_allclose(loss_weights(r, "l2", 1.0), 1.0)
    np.testing.assert_allclose(loss_weights(r, "huber", 1.0), [1.0, 1.0, 0.5, 1.0])
    np.testing.assert_allclose(loss_weights(r, "cauchy", 1.0), [1.0, 0.8, 0.2, 1.0])
    with pytest.raises(FacesimError, match="loss"):
        TrackOptions(loss="tukey")


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_loss_discounts_a_gross_outlier(dense, loss):
    sim, truth, P = dense
    space = ControlSpace.of(sim)
    target = P[1].copy()
    j = int(np.argmax(np.linalg.norm(P[1] - P[0], axis=1)))   # the marker that moves most, 8 mm off
    target[j] += [0.0, 8.0, 0.0]
    fit = FitOptions(noise=0.01)

    def error(options):
        result, outliers, _ = fit_markers(sim, target, truth[0], None, space, options)
        assert outliers == [j]                 # reported whatever the loss
        return np.abs(space.vector(result.controls) - space.vector(truth[1])).max()

    plain = error(TrackOptions(fit=fit, robust=False))
    robust = error(TrackOptions(fit=fit, robust=False, loss=loss, loss_scale=0.5))
    assert plain > 0.1 and robust < 0.3 * plain


def test_missing_and_outlier_markers_still_converge_and_outliers_are_reported(dense, tmp_path):
    sim, truth, P = dense
    rng = np.random.default_rng(1)
    F, r = P.shape[:2]
    noisy = P + rng.normal(scale=0.1, size=P.shape)
    names = sim.model.markers.names
    expected = {}
    for f in range(F):                         # 10% of the markers missing, 2% far off (1 of 50 per frame)
        gone, far = np.split(rng.choice(r, 6, replace=False), [5])
        noisy[f, gone] = np.nan
        direction = rng.normal(size=3)
        noisy[f, far[0]] += 6.0 * direction / np.linalg.norm(direction)
        expected[str(f)] = [names[far[0]]]
    options = TrackOptions(fit=FitOptions(noise=0.1), head="none")
    s = track(sim, np.arange(F), noisy, tmp_path, options=options, progress=False)
    assert s["status"] == "complete" and s["outliers"] == expected
    assert max(s["marker_rms"]) < 0.3          # 3-D noise RMS sqrt(3) x 0.1 mm, outliers dropped
    A = np.loadtxt(tmp_path / "activations.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(A[:, 1:], [c.a for c in truth], atol=0.03)
    log = np.genfromtxt(tmp_path / "frames.csv", delimiter=",", names=True)
    assert list(log["markers_used"]) == [r - 6] * F and list(log["outliers"]) == [1] * F
    R = np.genfromtxt(tmp_path / "residuals.csv", delimiter=",", names=True)
    assert np.isnan([R[names[j]][f] for f in range(F) for j in np.flatnonzero(np.isnan(noisy[f, :, 0]))]).all()
