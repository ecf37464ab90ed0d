"""Solving a capture on a ``dask.distributed`` cluster: the workers' simulator and the frame tasks.

Workers build their simulator from a :class:`SimulatorSpec` (model file with its SHA-256, the
equilibrium options and the jaw model name; small and picklable), once per worker process and spec.
:func:`solve_on_cluster` submits every frame as a task chained on the previous frame of its run,
so the worker holding that frame's equilibrium warm-starts from it, and yields the frames as they
finish; :func:`dask_client` makes a client (a new local cluster, or an existing scheduler). The
tracker (:func:`facesim.inverse.tracking.track`) decides the runs and writes the frames.
"""

from __future__ import annotations

import functools
import hashlib
import os
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.mocap.binding import with_markers


@dataclass(frozen=True)
class SimulatorSpec:
    """What a worker process needs to build the simulator of a run: the model file (absolute path
    as the workers see it, and the SHA-256 of its bytes, checked there so every worker solves the
    client's model), the equilibrium options (with the contact set-up) and the jaw model name
    (:func:`facesim.kinematics.jaw_models.make_jaw_model`). Small and picklable."""

    model: str
    sha256: str
    options: EquilibriumOptions = EquilibriumOptions()
    jaw_model: str = "sliding-condyle"

    @staticmethod
    def of(path, options: EquilibriumOptions | None = None, jaw_model: str = "sliding-condyle") -> SimulatorSpec:
        path = Path(path).resolve()
        if not path.is_file():
            raise FacesimError(f"{path}: no such model file")
        kind, sep, rig = jaw_model.partition(":")
        if sep:   # rig files too must resolve the same on the workers
            jaw_model = f"{kind}:{Path(rig).resolve()}"
        return SimulatorSpec(str(path), _sha256(path), options or EquilibriumOptions(), jaw_model)

    def build(self) -> FaceSimulator:
        """The simulator (built once per process and spec, then shared: it is never mutated)."""
        return _simulator(self)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@functools.lru_cache(maxsize=2)
def _simulator(spec: SimulatorSpec) -> FaceSimulator:
    from facesim.kinematics.jaw_models import make_jaw_model
    from facesim.model import load_model

    path = Path(spec.model)
    if not path.is_file():
        raise FacesimError(f"{path}: no such model file on this worker (workers must see the model at the "
                           "client's path)")
    if _sha256(path) != spec.sha256:
        raise FacesimError(f"{path}: the model file on this worker differs from the client's")
    model = load_model(path)
    return FaceSimulator(model, spec.options, jaw_model=make_jaw_model(model, spec.jaw_model, model_path=path))


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: on a new LocalCluster of ``workers`` processes (one thread each,
    numba's threads shared out among them) or connected to the scheduler at ``scheduler``
    (e.g. ``tcp://host:8786``). Closed, with its cluster, on leaving the block."""
    if (workers is None) == (scheduler is None):
        raise FacesimError("parallel tracking: give either a number of workers or a scheduler address")
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise FacesimError("parallel tracking needs dask.distributed: pip install 'dask[distributed]'") from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise FacesimError(f"cannot reach the dask scheduler at {scheduler} ({' '.join(str(exc).split())})") \
                from None
        except (ValueError, TypeError) as exc:   # distributed's address parsing: "missing port number" ...
            raise FacesimError(f"--scheduler {scheduler!r}: not a dask scheduler address ({' '.join(str(exc).split())}); "
                               "expected e.g. tcp://host:8786") from None
        with client:
            yield client
        return
    if workers < 1:
        raise FacesimError(f"workers: expected >= 1, got {workers}")
    threads = max(1, (os.cpu_count() or 1) // workers)
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      env={"NUMBA_NUM_THREADS": str(threads)}) as cluster, Client(cluster) as client:
        yield client


# ------------------------------------------------------------------ frame tasks
def _solve_task(solve, spec: SimulatorSpec, space, options, target, k: int, i: int, state, markers=None):
    """A worker's task: frame ``k`` solved by ``solve`` (the tracker's one-frame solver, sent by
    reference) from the warm start of ``state = (_, start)``, what the task before it returned (a
    Jacobian that crossed processes lost its factorisation; fit_frame copes), on the spec's
    simulator with the run's ``markers`` (None: the model's own)."""
    return solve(with_markers(spec.build(), markers), space, options, target, k, i, state[1])


def solve_on_cluster(client, solve, spec: SimulatorSpec, space, options, frames, P, runs, starts, markers=None):
    """Solve the runs of frames on the cluster of ``client``: every frame a task chained on the frame
    before it in its run (earlier frames first), solved on a worker by
    ``solve(sim, space, options, P[i], frames[i], i, start) -> (row, start of the next frame)`` (a
    module-level function: tasks carry it by reference) from the start the previous task handed
    on; each run ``(first, stop, _)`` of ``runs`` starts from its entry of ``starts``.
    ``markers``: the run's rebound markers (None: the model's). Yields ``(row, start handed on)``
    as the frames finish (the tracker saves the start: a resume continues from it); each result
    is released once yielded, and the tasks still pending are cancelled when the caller stops
    early."""
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]
    pending = {}
    for (first, stop, _), start in zip(runs, starts):
        state = (None, start)
        for i in range(first, stop):
            # the scheduler keeps each result while the next frame needs it or until it is read here
            state = client.submit(_solve_task, solve, spec, space, options, P[i], int(frames[i]), i, state, markers,
                                  key=f"facesim-frame-{token}-{i}", priority=-i)
            pending[state.key] = state
        state = None
    finished = False
    try:
        for fut in as_completed(list(pending.values())):
            result = fut.result()
            del pending[fut.key]
            fut.release()
            yield result
        finished = True
    finally:
        if not finished:
            client.cancel(list(pending.values()))


__all__ = ["SimulatorSpec", "dask_client", "solve_on_cluster"]
