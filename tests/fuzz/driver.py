"""Run fuzz cases through ``facesim.cli.main`` in subprocesses, and judge what came out.

The driver process (``python -m tests.fuzz.driver``) imports facesim once and runs the cases it
reads from stdin, one JSON object per line (``argv``, ``env``, ``cwd``, ``timeout``), each with
its stdout and stderr captured at the file-descriptor level into ``cwd/stdout.txt`` and
``cwd/stderr.txt``, and answers one ``RESULT {...}`` line per case. A case that outlives its
timeout makes faulthandler dump the stacks into its stderr and end the process; a crash (VTK or
numba aborting) ends it too. :class:`Runner` (the parent side) starts a new driver after either
and records the case as ``timeout`` or ``crash``; it kills a driver that stops answering.

:func:`judge` applies issue 14's rule: a one-line error starting ``facesim`` and a non-zero exit,
or exit 0 on an input that may be accepted (``facesim: warning:`` lines allowed); never a
traceback, a timeout, a crash or exit 0 on garbage -- and, for inputs the documentation accepts,
no refusal.
"""

from __future__ import annotations

import json
import os
import queue
import select
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: seconds a parent waits beyond a case's own timeout before killing its driver
GRACE = 30.0


# ------------------------------------------------------------------ the driver process
def _run_case(case: dict, proto) -> None:
    import faulthandler
    import traceback

    from facesim.cli import main

    cwd = Path(case["cwd"])
    out = open(cwd / "stdout.txt", "wb")
    err = open(cwd / "stderr.txt", "wb")
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {k: os.environ.get(k) for k in case.get("env", {})}
    here = os.getcwd()
    os.dup2(out.fileno(), 1)
    os.dup2(err.fileno(), 2)
    faulthandler.enable(file=err, all_threads=True)
    faulthandler.dump_traceback_later(case["timeout"], exit=True, file=err)
    os.environ.update(case.get("env", {}))
    os.chdir(cwd)
    rc, exception = None, None
    t0 = time.perf_counter()
    try:
        rc = main(list(case["argv"]))
    except BaseException as exc:  # noqa: BLE001 (anything escaping main is a finding)
        traceback.print_exc()
        exception = f"{type(exc).__name__}: {exc}"[:500]
    finally:
        seconds = time.perf_counter() - t0
        faulthandler.cancel_dump_traceback_later()
        sys.stdout.flush()
        sys.stderr.flush()
        os.chdir(here)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        os.dup2(proto["stdout"], 1)
        os.dup2(proto["stderr"], 2)
        faulthandler.enable(file=sys.__stderr__, all_threads=True)
        out.close()
        err.close()
    proto["out"].write("RESULT " + json.dumps({"id": case["id"], "rc": rc, "exception": exception,
                                                "seconds": round(seconds, 3)}) + "\n")
    proto["out"].flush()


def serve() -> None:
    """The driver's loop: a case per stdin line, a ``RESULT`` line per case on the original stdout."""
    import resource

    # a case that asks for absurd memory fails inside this process, not on the shared machine
    limit = 8 << 30
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    proto = {"stdout": os.dup(1), "stderr": os.dup(2)}
    proto["out"] = os.fdopen(os.dup(1), "w")
    proto["out"].write("READY\n")
    proto["out"].flush()
    for line in sys.stdin:
        if line.strip():
            _run_case(json.loads(line), proto)


# ------------------------------------------------------------------ the parent side
@dataclass
class Result:
    """What a case did. ``rc``: exit status (None: none returned); ``status``: ``"done"``,
    ``"exception"`` (escaped main), ``"timeout"`` or ``"crash"`` (the driver died: ``signal``)."""

    id: str
    status: str
    rc: int | None
    stdout: str
    stderr: str
    seconds: float
    exception: str | None = None
    signal: int | None = None


class _Driver:
    def __init__(self, log: Path):
        env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                   NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   PYTHONFAULTHANDLER="1")
        env.pop("FACESIM_MODEL", None)
        self.log = open(log, "ab")
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.fuzz.driver"], cwd=REPO, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log)
        if self._line(120.0) != "READY":
            self.close()
            raise RuntimeError(f"fuzz driver did not start (see {log})")

    def _line(self, timeout: float) -> str | None:
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self.proc.stdout], [], [], left)
            if ready:
                line = self.proc.stdout.readline()
                return line.decode().strip() if line else ""

    def run(self, case: dict) -> tuple[str, dict | None]:
        """("done", result) | ("dead", None) | ("hung", None)."""
        try:
            self.proc.stdin.write((json.dumps(case) + "\n").encode())
            self.proc.stdin.flush()
        except BrokenPipeError:
            return "dead", None
        while True:
            line = self._line(case["timeout"] + GRACE)
            if line is None:
                return "hung", None
            if line == "":
                self.proc.wait(timeout=30)
                return "dead", None
            if line.startswith("RESULT "):
                return "done", json.loads(line[len("RESULT "):])

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.log.close()


def _read(path: Path) -> str:
    try:
        return path.read_bytes().decode(errors="replace")
    except OSError:
        return ""


def _result(case: dict, how: str, r: dict | None, returncode: int | None, seconds: float) -> Result:
    cwd = Path(case["cwd"])
    out, err = _read(cwd / "stdout.txt"), _read(cwd / "stderr.txt")
    if how == "done":
        status = "exception" if r["exception"] else "done"
        return Result(case["id"], status, r["rc"], out, err, r["seconds"], r["exception"])
    if how == "hung" or "Timeout (" in err:
        return Result(case["id"], "timeout", None, out, err, seconds)
    return Result(case["id"], "crash", None, out, err, seconds, signal=returncode)


class Runner:
    """Runs cases on ``workers`` drivers (threads feeding subprocesses); ``log`` collects the
    drivers' own stderr."""

    def __init__(self, work: Path, workers: int = 2):
        self.work, self.workers = Path(work), workers

    def _worker(self, todo: queue.Queue, done: dict, k: int) -> None:
        driver = None
        while True:
            try:
                case = todo.get_nowait()
            except queue.Empty:
                break
            if driver is None:
                driver = _Driver(self.work / f"driver{k}.log")
            t0 = time.monotonic()
            how, r = driver.run(case)
            returncode = None
            if how != "done":
                if how == "hung":
                    driver.proc.kill()
                driver.proc.wait()
                returncode = driver.proc.returncode
                driver.close()
                driver = None
            done[case["id"]] = _result(case, how, r, returncode, time.monotonic() - t0)
        if driver is not None:
            driver.proc.stdin.close()
            driver.close()

    def run(self, cases: list[dict]) -> dict[str, Result]:
        todo: queue.Queue = queue.Queue()
        for case in cases:
            todo.put(case)
        done: dict[str, Result] = {}
        threads = [threading.Thread(target=self._worker, args=(todo, done, k)) for k in range(self.workers)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return done


# ------------------------------------------------------------------ the rule
def judge(verdict: str, r: Result) -> str | None:
    """None if ``r`` is an allowed outcome for an input of ``verdict`` (mutations.GARBAGE,
    EITHER, VALID), else the failure class: ``traceback``, ``timeout``, ``crash``,
    ``not one line``, ``exit 0 on garbage``, ``refused valid input``, ``stray stderr``."""
    if r.status == "timeout":
        return "timeout"
    if r.status == "crash":
        return "crash"
    if r.status == "exception" or "Traceback (most recent call last)" in r.stderr:
        return "traceback"
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    other = [line for line in lines if not line.startswith("facesim: warning:")]
    if r.rc != 0:
        if len(other) != 1 or not other[0].startswith("facesim") or r.rc not in (1, 2):
            return "not one line"
        return "refused valid input" if verdict == "valid" else None
    if verdict == "garbage":
        return "exit 0 on garbage"
    if other:
        return "stray stderr"
    return None


def _hung_at(stderr: str) -> str:
    """Where a timed-out case was: the innermost frame of the thread running the command, and its
    innermost facesim frame (faulthandler's dump, most recent call first)."""
    for block in stderr.split("\n\n"):
        frames = [line.strip() for line in block.splitlines() if line.strip().startswith("File ")]
        if any("facesim/cli.py" in f for f in frames):
            ours = [f for f in frames if "/facesim/" in f and "/tests/" not in f]
            return frames[0] + (f" (from {ours[0]})" if ours and ours[0] != frames[0] else "")
    return "?"


def last_line(r: Result) -> str:
    """The line of stderr that says most about a failure (a traceback's last line, the error)."""
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    if r.exception:
        return r.exception
    if r.status == "timeout":
        return "timeout in " + _hung_at(r.stderr)
    if r.status == "crash":
        return f"driver died (returncode {r.signal}); " + (lines[0] if lines else "")
    tb = [line for line in lines if not line.startswith((" ", "Traceback"))]
    return (tb[-1] if tb else "(no stderr)")[:300]


if __name__ == "__main__":
    serve()
