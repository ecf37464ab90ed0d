"""Runs that stop and resume: ``track`` (solve-mocap) and ``simulate`` interrupted by SIGINT or
SIGKILL in a subprocess and resumed give the CSVs of an uninterrupted run byte for byte; a folder
holding a run is never silently replaced, never resumed with other inputs, never written by two
runs at once; a failed write names its file and leaves no cut line behind.

Everything runs on the synthetic box model with direct solvers on one thread (deterministic
solves), in chunks of 4 frames so that resumed runs start inside a chunk and at a chunk's start.
"""

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import one_numba_thread

from facesim.errors import FacesimError
from facesim.model import Tissue, load_model

ROOT = Path(__file__).resolve().parent.parent
N_FRAMES = 10


# ------------------------------------------------------------------ the two runs
def run(kind: str, folder, out, resume: bool = False, overwrite: bool = False, model: str = "model.npz",
        shift: float = 0.0, progress: bool = False) -> dict:
    """The run of ``kind`` (``"track"`` or ``"simulate"``) on the inputs in ``folder`` (see the
    ``inputs`` fixture) into ``out``; the same in this process and in a subprocess."""
    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.fem.newton import NewtonOptions
    from facesim.inverse.gauss_newton import FitOptions
    from facesim.inverse.parallel import SimulatorSpec
    from facesim.inverse.tracking import TrackOptions, track
    from facesim.simulate import SimulateOptions, simulate

    folder = Path(folder)
    newton = NewtonOptions(linear_solver="direct", rtol=1e-8)
    with np.load(folder / "inputs.npz") as z:
        P, A, jaw = z["P"] + shift, z["A"] + shift, z["jaw"]
    if kind == "track":
        spec = SimulatorSpec.of(folder / model, EquilibriumOptions(newton=newton))
        options = TrackOptions(fit=FitOptions(noise=0.05), head="none", chunk_size=4)
        return track(spec, np.arange(N_FRAMES), P, out, options=options, resume=resume, overwrite=overwrite,
                     progress=progress)
    return simulate(load_model(folder / model), A, out, jaw=jaw, jaw_model="sliding-condyle",
                    options=SimulateOptions(newton=newton), resume=resume, overwrite=overwrite, progress=progress)


one_thread = pytest.fixture(scope="module", autouse=True)(one_numba_thread)


@pytest.fixture(scope="module")
def inputs(box_model, tmp_path_factory):
    """The model file and a 10-frame sequence made by forward simulation: activations and
    sliding-condyle jaw parameters (simulate's input) and their markers with 0.05 mm noise
    (track's input)."""
    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.fem.newton import NewtonOptions
    from facesim.kinematics.condyle import SlidingCondyleJaw

    folder = tmp_path_factory.mktemp("resume_inputs")
    box_model.save(folder / "model.npz")
    t = np.linspace(0.0, 1.0, N_FRAMES)
    A = np.stack([0.6 * np.sin(np.pi * t) ** 2, 0.4 * t], axis=1)
    jaw = np.stack([0.05 * t, 0.8 * t, 0.6 * t], axis=1)
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct", rtol=1e-8)),
                        jaw_model=SlidingCondyleJaw(box_model.jaw))
    P = np.array([box_model.marker_positions(sim.equilibrium(Controls(a, jaw=q)).x) for a, q in zip(A, jaw)])
    P += np.random.default_rng(5).normal(scale=0.05, size=P.shape)
    np.savez(folder / "inputs.npz", P=P, A=A, jaw=jaw)
    return folder


@pytest.fixture(scope="module")
def reference(inputs, tmp_path_factory):
    """Both runs uninterrupted: ``{kind: output folder}`` (do not modify; copy)."""
    folders = {}
    for kind in ("track", "simulate"):
        folders[kind] = tmp_path_factory.mktemp(f"{kind}_reference")
        s = run(kind, inputs, folders[kind])
        assert s["status"] == "complete"
    return folders


LOGS = {"track": ("activations.csv", "jaw.csv", "residuals.csv", "frames.csv"),
        "simulate": ("markers.csv", "frames.csv")}


def without_seconds(text: str) -> list[list[str]]:
    """The rows of a frames.csv without its wall-clock column (the only one that may differ)."""
    rows = [line.split(",") for line in text.splitlines()]
    drop = rows[0].index("seconds")
    return [r[:drop] + r[drop + 1:] for r in rows]


def assert_same_results(kind: str, got: Path, want: Path) -> None:
    for name in LOGS[kind]:
        a, b = (got / name).read_text(), (want / name).read_text()
        if name == "frames.csv":
            assert without_seconds(a) == without_seconds(b), name
        else:
            assert a == b, name   # byte for byte
    if kind == "simulate":
        for k in range(N_FRAMES):
            with np.load(got / "state" / f"frame_{k:05d}.npz") as z, \
                    np.load(want / "state" / f"frame_{k:05d}.npz") as z0:
                assert np.array_equal(z["x"], z0["x"]), k   # the equilibria bit for bit


def rows(path: Path) -> int:
    try:
        return max(0, path.read_text().count("\n") - 1)
    except OSError:
        return 0


def start_run(kind: str, inputs: Path, out: Path, *, fsize: int | None = None) -> subprocess.Popen:
    """The run in a subprocess (one solver thread; SIGINT raising KeyboardInterrupt whatever this
    process ignores; with ``fsize``, a file size limit in bytes and SIGXFSZ ignored, so writes past
    it fail with EFBIG); its stderr goes to ``out``'s sibling ``stderr.txt``."""
    limit = "" if fsize is None else (
        f"import resource, signal; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
        f"resource.setrlimit(resource.RLIMIT_FSIZE, ({fsize}, {fsize})); ")
    # SIGINT back to KeyboardInterrupt: a child inherits an ignored SIGINT (a pytest-xdist worker's,
    # after some library set it so), and then ran to its end through the test's Ctrl-C
    code = (f"import signal; signal.signal(signal.SIGINT, signal.default_int_handler); {limit}"
            f"from tests.test_resume import run; run({kind!r}, {str(inputs)!r}, {str(out)!r})")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    with open(out.parent / "stderr.txt", "w") as err:
        return subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                                stderr=err)


def stderr_of(out: Path) -> str:
    return (out.parent / "stderr.txt").read_text()


def wait_for_frames(proc: subprocess.Popen, out: Path, n: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while rows(out / "frames.csv") < n:
        if proc.poll() is not None:
            pytest.fail(f"the run ended before {n} frames were written: {stderr_of(out)[-2000:]}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"no {n} frames within {timeout} s")
        time.sleep(0.005)


# ------------------------------------------------------------------ interrupted and resumed
@pytest.mark.parametrize("kind", ["track", "simulate"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["SIGINT", "SIGKILL"])
def test_interrupted_run_resumes_to_the_uninterrupted_result(kind, sig, inputs, reference, tmp_path):
    out = tmp_path / "out"
    proc = start_run(kind, inputs, out)
    # SIGINT inside the first chunk (the resume continues it), SIGKILL inside the second
    wait_for_frames(proc, out, 3 if sig == signal.SIGINT else 6)
    if sig == signal.SIGKILL:   # while it writes, a second run into the folder is refused at once
        with pytest.raises(FacesimError, match=rf"another facesim run \(pid {proc.pid}\) is writing into this folder"):
            run(kind, inputs, out, resume=True)
    proc.send_signal(sig)
    assert proc.wait(timeout=60) != 0
    written = rows(out / "frames.csv")
    assert 0 < written < N_FRAMES
    if sig == signal.SIGKILL:
        assert (out / ".lock").exists()   # left behind by the killed run: no obstacle to the resume
    else:
        assert json.loads((out / "report.json").read_text())["status"] == "interrupted"
    s = run(kind, inputs, out, resume=True)
    assert s["status"] == "complete" and s["reused_frames"] == written
    if kind == "track":   # the resume continues a chunk of 4 from its saved warm start, or starts one cold
        assert s["solved_frames"] == N_FRAMES - written and s["warm_starts_restored"] == int(written % 4 != 0)
        assert not (out / "state").exists()   # the warm starts go with the finished run
    assert_same_results(kind, out, reference[kind])
    assert not (out / ".lock").exists()


def test_a_resumed_complete_run_solves_nothing_and_changes_nothing(inputs, reference, tmp_path):
    out = shutil.copytree(reference["track"], tmp_path / "out")
    s = run("track", inputs, out, resume=True)
    assert s["solved_frames"] == 0 and s["reused_frames"] == N_FRAMES
    assert_same_results("track", out, reference["track"])


# ------------------------------------------------------------------ refusals
@pytest.mark.parametrize("kind", ["track", "simulate"])
def test_a_folder_holding_a_run_needs_resume_or_overwrite(kind, inputs, reference, tmp_path):
    out = shutil.copytree(reference[kind], tmp_path / "out")
    before = {name: (out / name).read_text() for name in LOGS[kind]}
    with pytest.raises(FacesimError) as err:
        run(kind, inputs, out, shift=0.01)
    message = str(err.value)
    assert "\n" not in message and str(out) in message and "--resume" in message and "--overwrite" in message
    assert {name: (out / name).read_text() for name in LOGS[kind]} == before   # untouched
    with pytest.raises(FacesimError, match="exclude each other"):
        run(kind, inputs, out, resume=True, overwrite=True)


@pytest.mark.parametrize("kind", ["track", "simulate"])
def test_resume_with_other_inputs_is_refused_naming_them(kind, box_model, inputs, reference, tmp_path):
    out = shutil.copytree(reference[kind], tmp_path / "out")
    (out / "frames.csv").write_text("".join((out / "frames.csv").read_text().splitlines(keepends=True)[:4]))
    stiffer = box_model.with_tissues([Tissue("fat", 1e-3, 0.0, 0.1), Tissue("muscle", 2.5e-3, 0.0, 0.2)])
    stiffer.save(inputs / f"stiffer_{kind}.npz")   # one tissue parameter, nothing else
    with pytest.raises(FacesimError, match=r"other inputs: model \(tissues\) differ") as err:
        run(kind, inputs, out, resume=True, model=f"stiffer_{kind}.npz")
    assert "\n" not in str(err.value) and str(out) in str(err.value) and "--overwrite" in str(err.value)
    changed = "markers" if kind == "track" else "activations"
    with pytest.raises(FacesimError, match=rf"other inputs: {changed} differ"):
        run(kind, inputs, out, resume=True, shift=0.001)
    assert json.loads((out / "run.json").read_text())["command"] == ("solve-mocap" if kind == "track" else kind)


def test_model_fingerprint_covers_the_whole_model(box_model):
    from facesim.runfolder import fingerprint, parts

    base = parts(box_model)
    muscles = box_model.with_muscle_strength(box_model.muscles.sigma_max * 1.01)
    tissues = box_model.with_tissues([Tissue("fat", 1e-3, 0.0, 0.1), Tissue("muscle", 2e-3, 0.0, 0.21)])
    colliders = box_model.with_(colliders=box_model.colliders[:1])
    for other, field in ((muscles, "muscles"), (tissues, "tissues"), (colliders, "colliders")):
        got = parts(other)
        assert [k for k in base if base[k] != got[k]] == [field]
    assert fingerprint(box_model) == fingerprint(box_model.with_())   # the content, not the object


# ------------------------------------------------------------------ write failures
def test_frame_log_cuts_a_failed_write_back_to_the_last_complete_line(tmp_path):
    """A file size limit reached in the middle of a line: one-line error naming the file, and the
    file ends with the last complete line."""
    path = tmp_path / "log.csv"
    code = ("import resource, signal\n"
            "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))\n"
            "from facesim.framelog import FrameLog\n"
            "from facesim.errors import FacesimError\n"
            f"log = FrameLog({str(path)!r}, 'frame,value\\n')\n"
            "try:\n"
            "    for k in range(100):\n"
            "        log.add(f'{k},' + '7' * 60 + '\\n')\n"
            "except FacesimError as exc:\n"
            "    print(exc)\n"
            "log.close()\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    message = done.stdout.strip()
    assert message == f"{path}: cannot write (File too large)", done.stderr
    text = path.read_text()
    assert text.endswith("\n") and len(text) <= 1000
    lines = text.splitlines()
    assert lines[0] == "frame,value" and len(lines) > 5
    assert lines[1:] == [f"{k}," + "7" * 60 for k in range(len(lines) - 1)]   # whole lines only


def test_a_failed_log_write_names_its_file_and_the_run_resumes_faithfully(inputs, reference, tmp_path, monkeypatch):
    """residuals.csv fails in the middle of frame 5's line (half of it written, then EFBIG): the
    error names it, no cut line stays, and the resumed run writes what the uninterrupted one did."""
    import types

    import facesim.framelog as framelog

    out = tmp_path / "out"
    count = {"residuals": 0}

    def failing_write(fd, data):
        if os.fstat(fd).st_ino == os.stat(out / "residuals.csv").st_ino:
            count["residuals"] += 1
            if count["residuals"] == 6:
                os.write(fd, bytes(data[: len(data) // 2]))
                raise OSError(errno.EFBIG, "File too large")
        return os.write(fd, data)

    monkeypatch.setattr(framelog, "os", types.SimpleNamespace(**{**vars(os), "write": failing_write}))
    with pytest.raises(FacesimError) as err:
        run("track", inputs, out)
    monkeypatch.undo()
    assert str(err.value) == f"{out / 'residuals.csv'}: cannot write (File too large)"
    assert (out / "residuals.csv").read_text().endswith("\n") and rows(out / "residuals.csv") == 5
    assert json.loads((out / "report.json").read_text())["status"] == "failed: FacesimError"
    s = run("track", inputs, out, resume=True)
    assert s["status"] == "complete" and s["reused_frames"] == 5
    assert_same_results("track", out, reference["track"])


def test_a_write_failure_in_a_subprocess_names_the_file(inputs, tmp_path):
    """A file size limit (RLIMIT_FSIZE, SIGXFSZ ignored) fails simulate's first file larger than
    it: the one-line error names that file."""
    out = tmp_path / "out"
    proc = start_run("simulate", inputs, out, fsize=4000)
    proc.wait(timeout=120)
    err = stderr_of(out)
    last = err.strip().splitlines()[-1]
    assert proc.returncode != 0 and "FacesimError" in last and "cannot write (File too large)" in last, err
    failed = Path(last.split("FacesimError: ", 1)[1].split(": cannot write")[0])
    assert failed.parent.parent == out and failed.suffix in (".npz", ".ply")


def test_cleanup_errors_do_not_mask_the_first_error(inputs, tmp_path, monkeypatch):
    """A full disk fails frames.csv, then the TRC and report.json written on the way out: the
    error raised is the first one."""
    import facesim.framelog as framelog
    import facesim.mocap.io as mocap_io
    import facesim.simulate as simulate_module

    out = tmp_path / "out"
    add, atomic_write = framelog.FrameLog.add, simulate_module.atomic_write
    disk_full = []

    def full_after_two_frames(self, line):
        if self.path.name == "frames.csv" and rows(self.path) == 2:
            disk_full.append(self.path)
            raise FacesimError(f"{self.path}: cannot write (No space left on device)")
        add(self, line)

    def no_space(path, *args, **kwargs):
        raise FacesimError(f"{path}: cannot write (No space left on device)")

    def report_on_a_full_disk(path, write):
        if disk_full and Path(path).name == "report.json":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return atomic_write(path, write)

    monkeypatch.setattr(framelog.FrameLog, "add", full_after_two_frames)
    monkeypatch.setattr(mocap_io, "write_trc", no_space)
    monkeypatch.setattr(simulate_module, "atomic_write", report_on_a_full_disk)
    with pytest.raises(FacesimError) as err:
        run("simulate", inputs, out)
    assert str(err.value) == f"{out / 'frames.csv'}: cannot write (No space left on device)"


def test_an_uninterrupted_run_factorises_no_tangent_for_its_warm_starts(inputs, tmp_path, monkeypatch):
    """Every Jacobian records where its factorised tangent was assembled (tangent_at), so an
    uninterrupted run needs no extra factorisation to make its warm starts resumable (before
    tangent_at, 11 of 12 frames of the coarse demo paid one)."""
    import facesim.inverse.tracking as tracking

    calls = []
    real = tracking.factorised_tangent
    monkeypatch.setattr(tracking, "factorised_tangent", lambda *a, **k: calls.append(a[1:]) or real(*a, **k))
    s = run("track", inputs, tmp_path / "out")
    assert s["status"] == "complete" and calls == []
