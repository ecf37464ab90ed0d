"""A simulated capture database for the markerless jaw tracker (Zoss et al. 2019): skin and jaw of
a face model over thousands of frames, every frame a quasistatic equilibrium.

:func:`build_dataset` makes one subject's :class:`~facesim.jaw.markerless_data.MarkerlessData`:

* **Jaw poses** -- given ``(N, 4, 4)`` (e.g. a poses file's, ``facesim.jaw.cli.read_poses``), or
  generated for the model's TMJ by the TMJ motion generator (:func:`facesim.jaw.model_rig.model_motion`:
  border movements, chewing, speech, free moves), sessions ``seed``, ``seed + 1``, ... in a row,
  subsampled evenly in time to ``frames`` (:func:`jaw_poses`), so the frames cover the whole range
  in the motion's own order.
* **The jaw in the simulation** -- the rigid jaw model (:class:`~facesim.kinematics.jaw_models.RigidJaw`):
  its controls are the pose itself, so the simulated mandible is exactly the recorded pose
  (``meta["jaw_node_error_mm"]``: how far the solved jaw nodes are from the pose, 0 up to rounding).
* **Expressions** -- ``"random"`` (:func:`random_expressions`: sparse performances of 0-4 muscles
  at levels up to 0.7, mirrored pairs half of the time, each rising and falling over 8-40
  frames, neutral between them), ``"none"``, an activations array ``(N, n_muscles)`` or an
  activations CSV (``frame,<muscle>,...``).
* **Frames** -- each an equilibrium of the one set-up (:class:`~facesim.fem.equilibrium.FaceSimulator`,
  default :class:`~facesim.fem.equilibrium.EquilibriumOptions`), warm-started from the last
  converged frame before it (consecutive frames are close: the motion's order, smooth
  expressions), recording the skin feature points (:mod:`facesim.jaw.markerless_features`).
  A frame that does not converge is kept with ``ok`` False (its skin at the state the solver
  left, or the bones' prediction where that is not finite), never dropped.
* **Parallel** -- ``workers`` processes (or a dask ``scheduler``) solve contiguous chunks of
  frames, each chunk starting cold (:func:`facesim.inverse.parallel.solve_on_cluster`, the
  machinery of ``solve-mocap``); the default one process solves one chunk.

Resume. The build writes as it goes into ``<out>.parts/`` (a :class:`~facesim.runfolder.RunFolder`:
``run.json`` records the inputs, ``.lock`` while it writes): ``frames/frame_KKKKK.npz`` per solved
frame (skin points, ok, solver counts; written atomically) and ``state/warm_KKKKK.npz``, the
positions of the last converged frame of each chunk (written before that frame's record), so an
interrupted build continues each chunk from the warm start the next frame would have had: the
resumed dataset is the uninterrupted one, bit for bit with deterministic linear solvers (direct
or PARDISO, one thread; the AMG hierarchy a simulator reuses across frames is not saved, so with
AMG a resumed frame differs within the solver's tolerance). A resume with other inputs (model,
poses, expressions, options, feature count) is refused, naming them; ``resume=False`` starts
again. When every frame is solved, ``out`` is written (atomically) and ``<out>.parts/`` removed.

Cost: consecutive frames of a generated build take 2-4 Newton steps, ~0.8 s a frame on the
coarse face (two threads), so thousands of frames take an hour or less per subject; frames far
apart (a short build sampling a long motion, random expressions) take 10-30 s each.

The module runs the FEM, so it sits above ``fem/`` and ``inverse/`` with ``simulate``, not in
``jaw/`` (which stays independent of the FEM: ``tests/test_architecture.py``).

Phantom subjects: :func:`phantom_subject_model` builds (once, then reads from disk) a procedural
head of explicit proportions (:class:`facesim.anatomy.phantom.Subject`: width, height, depth, jaw
length, soft-tissue depth, ...); :data:`SUBJECTS` names the database's subjects, four for
training and a fifth held out, one of them of thicker soft tissue (a higher BMI).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import shutil
import time
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.errors import FacesimError, SolverError
from facesim.jaw.markerless_data import MarkerlessData, MarkerTrack, load_data
from facesim.jaw.markerless_features import LAYOUT_VERSION, FeatureLayout, feature_layout, skin_features

#: Frames of a generated dataset when ``frames`` is not given (the paper: 2000 train, 1539 test).
DEFAULT_FRAMES = 2000
#: :func:`random_expressions`: muscles active at once, highest level, frames an expression lasts.
MAX_ACTIVE = 4
MAX_LEVEL = 0.7
EVENT_FRAMES = (8, 40)
#: The database's phantom subjects (proportions of :class:`facesim.anatomy.phantom.Subject`): four
#: to train on, ``heldout`` never trained on; ``bmi`` has 45 % deeper soft tissue.
SUBJECTS = {
    "canonical": {},
    "wide": {"width": 1.06, "height": 0.95, "depth": 0.98, "jaw_length": 0.94, "tissue": 0.9, "lips": 0.95},
    "long": {"width": 0.95, "height": 1.06, "depth": 1.03, "jaw_length": 1.08, "tissue": 1.05, "nose": 1.1},
    "bmi": {"width": 1.03, "depth": 1.02, "tissue": 1.45, "lips": 1.1},
    "heldout": {"width": 1.03, "height": 1.03, "depth": 0.97, "jaw_length": 1.04, "tissue": 1.2, "nose": 0.92,
                "lips": 1.05},
}
TRAINING_SUBJECTS = ("canonical", "wide", "long", "bmi")
HELDOUT_SUBJECT = "heldout"
PARTS_SUFFIX = ".parts"
_COMMAND = "jaw markerless dataset"


# ------------------------------------------------------------------ phantom subjects
def phantom_subject(name_or_seed=0, **proportions):
    """The :class:`~facesim.anatomy.phantom.Subject` of a name of :data:`SUBJECTS` or a seed
    (:func:`~facesim.anatomy.phantom.subject_from_seed`), with ``proportions`` (``tissue``,
    ``width``, ``height``, ``depth``, ``jaw_length``, ``nose``, ``lips``, ``lip_gap``) replaced."""
    from facesim.anatomy import phantom

    if isinstance(name_or_seed, str):
        if name_or_seed not in SUBJECTS:
            raise FacesimError(f"phantom subject: unknown name {name_or_seed!r}; known: {', '.join(SUBJECTS)} "
                               "(or give a seed)")
        base = phantom.Subject(**SUBJECTS[name_or_seed])
    else:
        base = phantom.subject_from_seed(int(name_or_seed))
    known = {f.name for f in dataclasses.fields(base)}
    unknown = sorted(set(proportions) - known)
    if unknown:
        raise FacesimError(f"phantom subject: unknown proportion {unknown[0]!r}; known: {', '.join(sorted(known))}")
    changes = {k: float(v) for k, v in proportions.items() if v is not None}
    for k, v in changes.items():
        if not (math.isfinite(v) and v > 0):
            raise FacesimError(f"phantom subject: {k} must be a positive number, got {v}")
    return dataclasses.replace(base, **changes)


def subject_cache_dir() -> Path:
    """Where :func:`phantom_subject_model` keeps built subjects by default: ``$FACESIM_CACHE/subjects``,
    else ``$XDG_CACHE_HOME/facesim/subjects``, else ``~/.cache/facesim/subjects``."""
    root = os.environ.get("FACESIM_CACHE")
    if root:
        return Path(root) / "subjects"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "facesim" / "subjects"


def phantom_subject_model(name_or_seed=0, *, resolution: str = "coarse", path=None, progress=None, threads: int = 0,
                          **proportions) -> Path:
    """The model file of a procedural subject (:func:`phantom_subject`), built by
    :func:`facesim.anatomy.build_head` the first time and read from ``path`` after (default
    ``subject_cache_dir() / "<name>_<resolution>.npz"``, the name a :data:`SUBJECTS` name, a seed
    or ``custom``). A file there of another subject or resolution is rebuilt. Building takes
    minutes (fields on a 1 mm grid, then fTetWild); ``progress`` takes one-line messages."""
    from facesim.anatomy.build import build_head
    from facesim.model import load_model

    sub = phantom_subject(name_or_seed, **proportions)
    if path is None:
        name = name_or_seed if isinstance(name_or_seed, str) else f"seed{int(name_or_seed)}"
        if any(v is not None for v in proportions.values()):
            from facesim.runfolder import fingerprint

            name = f"{name}-{fingerprint(sub)[:8]}"
        path = subject_cache_dir() / f"{name}_{resolution}.npz"
    path = Path(path)
    if path.is_file():
        try:
            meta = load_model(path).meta
        except FacesimError:
            meta = {}
        if meta.get("subject") == dataclasses.asdict(sub) and meta.get("resolution") == resolution:
            return path
    seed = 0 if isinstance(name_or_seed, str) else int(name_or_seed)
    model = build_head(resolution, seed=seed, progress=progress, threads=threads, subject=sub)
    model = model.with_(meta={**model.meta, "subject_name": str(name_or_seed)})
    return model.save(path)


# ------------------------------------------------------------------ poses and expressions
def jaw_poses(geometry, frames: int, seed: int = 0) -> np.ndarray:
    """``(frames, 4, 4)`` mandible poses relative to the skull (mm) for the TMJ ``geometry``: TMJ
    motion sessions ``seed``, ``seed + 1``, ... (:func:`facesim.jaw.model_rig.model_motion`) one
    after the other until there are enough, sampled evenly in time (in the motion's order)."""
    from facesim.jaw.model_rig import model_motion

    frames = int(frames)
    if frames < 1:
        raise FacesimError(f"frames: expected at least 1, got {frames}")
    sessions, total = [], 0
    while total < frames:
        sessions.append(model_motion(geometry, seed=seed + len(sessions)).poses)
        total += len(sessions[-1])
    poses = np.concatenate(sessions)
    return poses[np.round(np.linspace(0, len(poses) - 1, frames)).astype(int)]


def _units(names) -> list[list[int]]:
    """Muscle units: each left muscle with its right twin (``X_L`` / ``X_R``), midline ones alone."""
    index = {n: i for i, n in enumerate(names)}
    units, seen = [], set()
    for i, n in enumerate(names):
        if i in seen:
            continue
        twin = None
        if n.endswith(("_L", "_R")):
            twin = index.get(n[:-1] + ("R" if n.endswith("_L") else "L"))
        unit = [i] if twin is None else sorted([i, twin])
        seen.update(unit)
        units.append(unit)
    return units


def random_expressions(muscles, frames: int, seed: int = 0, max_active: int = MAX_ACTIVE,
                       max_level: float = MAX_LEVEL, event_frames=EVENT_FRAMES) -> np.ndarray:
    """``(frames, n_muscles)`` activations in [0, max_level]: one expression after another, each
    lasting ``event_frames`` (range) frames and rising and falling as sin² (neutral between them);
    an expression activates 0 to ``max_active`` muscles at levels drawn from [0.1, max_level],
    a left/right pair (``X_L``, ``X_R``) together at one level half of the time, else one side.
    ``muscles``: a :class:`~facesim.model.MuscleSet` (or a model's: ``model.muscles``)."""
    names = tuple(muscles.names)
    units = _units(names)
    rng = np.random.default_rng([int(seed), 17])
    A = np.zeros((int(frames), len(names)))
    start = 0
    while start < frames:
        n = int(rng.integers(event_frames[0], event_frames[1] + 1))
        count = int(rng.integers(0, max_active + 1))
        active: dict[int, float] = {}
        for u in rng.permutation(len(units)):
            if len(active) >= count:
                break
            level = float(rng.uniform(0.1, max_level))
            unit = units[u]
            if len(unit) == 2 and (rng.uniform() >= 0.5 or len(active) + 2 > count):
                unit = [unit[int(rng.integers(2))]]
            for m in unit:
                active[m] = level
        t = np.arange(min(n, frames - start))
        envelope = np.sin(np.pi * (t + 0.5) / n) ** 2
        for m, level in active.items():
            A[start:start + len(t), m] = level * envelope
        start += n
    return A


def _expressions(expressions, model, n: int, seed: int) -> tuple[np.ndarray, str]:
    if isinstance(expressions, str) and expressions in ("random", "none"):
        if expressions == "none":
            return np.zeros((n, model.n_muscles)), "none"
        return random_expressions(model.muscles, n, seed), f"random (seed {seed})"
    if isinstance(expressions, (str, Path)):
        from facesim.controls_io import read_activations_csv

        _, A = read_activations_csv(expressions, model.muscles.names)
        where = str(expressions)
    else:
        A = np.asarray(expressions, dtype=np.float64)
        where = "given"
    if A.shape != (n, model.n_muscles):
        raise FacesimError(f"expressions ({where}): expected ({n}, {model.n_muscles}) activations, one row per frame, "
                           f"got {A.shape}")
    if not np.isfinite(A).all() or A.min(initial=0) < 0 or A.max(initial=0) > 1:
        raise FacesimError(f"expressions ({where}): expected finite activations in [0, 1]")
    return A, where


def _poses(poses, model, frames, seed) -> tuple[np.ndarray, str]:
    from facesim import se3

    if poses is None:
        n = DEFAULT_FRAMES if frames is None else int(frames)
        return jaw_poses(model.jaw, n, seed), f"TMJ motion of the model's joints (sessions from seed {seed})"
    where = "given"
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not len(poses):
        raise FacesimError(f"poses ({where}): expected (N, 4, 4) mandible-to-skull transforms, got {poses.shape}")
    se3.check_poses(poses, f"poses ({where})")
    if frames is not None and int(frames) != len(poses):
        if not 1 <= int(frames) <= len(poses):
            raise FacesimError(f"frames: expected 1 to {len(poses)} (the poses given), got {frames}")
        poses = poses[np.round(np.linspace(0, len(poses) - 1, int(frames))).astype(int)]
        where += f", {int(frames)} evenly sampled"
    return poses, where


# ------------------------------------------------------------------ one frame
def _solve_frame(sim, layout: FeatureLayout, newton, target, k: int, i: int, start):
    """Frame ``i``: the equilibrium at ``target = (pose (4, 4), a (n_muscles,))`` warm-started from
    ``start`` (positions ``(n, 3)`` of the last converged frame, or None: cold). Returns the frame's
    record and the warm start of the next frame (this frame's positions if it converged). A
    module-level function: dask tasks carry it by reference (:func:`solve_on_cluster`)."""
    from facesim.controls import Controls

    pose, a = target
    controls = Controls(a, jaw=pose)
    t0 = time.perf_counter()
    error, stop = "", ""
    try:
        eq = sim.equilibrium(controls, x0=start, newton_options=newton)
        x, ok, iterations, stop = eq.x, eq.converged, eq.iterations, eq.report.stop_reason
    except SolverError as exc:   # a numerical failure of this frame: flagged, the run goes on
        x, ok, iterations, error = None, False, 0, " ".join(str(exc).split())
    if x is None or not np.isfinite(x).all():
        x, ok = sim.predict(controls, start), False
        error = error or "non-finite positions"
    m = sim.model
    jaw = m.X[m.jaw_nodes] @ np.asarray(pose)[:3, :3].T + np.asarray(pose)[:3, 3]
    inverted, min_J = sim.element_quality(x)
    row = {"i": int(i), "skin": skin_features(layout, x), "markers": m.marker_positions(x), "ok": bool(ok),
           "iterations": int(iterations),
           "seconds": time.perf_counter() - t0, "stop_reason": str(stop), "error": error,
           "inverted": int(inverted), "min_J": float(min_J),
           "jaw_error": float(np.abs(x[m.jaw_nodes] - jaw).max(initial=0.0))}
    return row, (x if ok else start)


# ------------------------------------------------------------------ the parts folder
def parts_folder(out_path) -> Path:
    """The sidecar folder an unfinished build of ``out_path`` writes into: ``<out_path>.parts``."""
    out_path = Path(out_path)
    return out_path.with_name(out_path.name + PARTS_SUFFIX)


def _frame_path(root: Path, i: int) -> Path:
    return root / "frames" / f"frame_{i:05d}.npz"


def _warm_path(root: Path, i: int) -> Path:
    return root / "state" / f"warm_{i:05d}.npz"


def _save(path: Path, **arrays) -> None:
    atomic_write(path, lambda tmp: np.savez(tmp, **arrays))


def _write_row(root: Path, row: dict) -> None:
    _save(_frame_path(root, row["i"]), **{k: v for k, v in row.items() if k != "i"})


def _read_row(root: Path, i: int, P: int) -> dict | None:
    import zipfile

    try:
        with np.load(_frame_path(root, i), allow_pickle=False) as z:
            row = {k: z[k][()] if z[k].ndim == 0 else np.array(z[k]) for k in z.files}
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    if np.shape(row.get("skin")) != (P, 3) or np.ndim(row.get("markers")) != 2:
        return None   # unreadable, or written before frames recorded the markers: solved again
    row["i"] = i
    return row


def _read_warm(root: Path, i: int, shape) -> np.ndarray | None:
    import zipfile

    try:
        with np.load(_warm_path(root, i), allow_pickle=False) as z:
            x = np.array(z["x"], dtype=np.float64)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    return x if x.shape == shape else None


def _holds_a_run(root: Path) -> bool:
    return (root / "frames").is_dir() and any((root / "frames").glob("frame_*.npz"))


def _clear(root: Path) -> None:
    shutil.rmtree(root / "frames", ignore_errors=True)
    shutil.rmtree(root / "state", ignore_errors=True)
    (root / "model.npz").unlink(missing_ok=True)


# ------------------------------------------------------------------ the build
def build_dataset(model, out_path, *, poses=None, frames: int | None = None, expressions="random", seed: int = 0,
                  n_skin: int = 240, options=None, workers: int = 1, scheduler: str | None = None,
                  chunk_size: int | None = None, resume: bool = True, progress=True, on_frame=None,
                  name: str | None = None) -> MarkerlessData:
    """Simulate one subject's capture database and write it to ``out_path`` (module docstring).

    Parameters
    ----------
    model : a :class:`~facesim.model.FaceModel` or its file.
    out_path : the dataset ``.npz`` (:meth:`MarkerlessData.save`); ``<out_path>.parts/`` while building.
    poses : ``(N, 4, 4)`` mandible-to-skull transforms (mm); None: generated
        (:func:`jaw_poses`, ``frames`` of them, default :data:`DEFAULT_FRAMES`).
    frames : with given poses, that many of them sampled evenly (default all).
    expressions : ``"random"``, ``"none"``, ``(N, n_muscles)`` activations or an activations CSV.
    seed : of the generated poses and expressions.
    n_skin : about how many skin features (:func:`~facesim.jaw.markerless_features.grid_shape`).
    options : :class:`~facesim.fem.equilibrium.EquilibriumOptions` (Newton, linear solver, contact).
    workers, scheduler : solve chunks of frames on that many local dask worker processes, or on
        the cluster of a dask scheduler (``tcp://host:8786``; workers must see the model file);
        ``workers=1`` without a scheduler solves here.
    chunk_size : frames per chunk (each chunk starts cold); default all frames on one process,
        ``ceil(N / workers)`` on a cluster; a resume keeps the chunks of the run it continues.
    resume : continue the build in ``<out_path>.parts`` (refused if made with other inputs);
        False: start again. A finished ``out_path`` made with the same inputs is read, not rebuilt.
    progress : a progress bar (tqdm) on stderr; on_frame : called as ``on_frame(row)`` after each
        frame is written (``row``: ``i``, ``skin``, ``ok``, ``iterations``, ``seconds``, ...).
    name : the subject's name in ``meta`` (default: the model file's stem, or the model's
        ``meta["subject_name"]``).

    Returns the dataset (also written to ``out_path``).
    """
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.model import FaceModel, load_model
    from facesim.runfolder import RunFolder, describe, fingerprint, parts

    model_path = None
    if not isinstance(model, FaceModel):
        model_path = Path(model)
        model = load_model(model_path)
    options = options or EquilibriumOptions()
    if not isinstance(options, EquilibriumOptions):
        raise FacesimError(f"options: expected EquilibriumOptions, got {type(options).__name__}")
    out_path = Path(out_path)
    poses, poses_from = _poses(poses, model, frames, seed)
    n = len(poses)
    A, expressions_from = _expressions(expressions, model, n, seed)
    layout = feature_layout(model, n_skin)
    parallel = scheduler is not None or int(workers) > 1
    if int(workers) < 1:
        raise FacesimError(f"workers: expected >= 1, got {workers}")
    inputs = {"model": parts(model), "poses": fingerprint(poses), "activations": fingerprint(A),
              "options": describe(options), "layout": {"version": LAYOUT_VERSION, "n_skin": layout.n_features},
              "jaw_model": "rigid"}
    key = fingerprint(inputs)
    if resume and out_path.is_file():
        try:
            done = load_data(out_path)
        except FacesimError:
            done = None
        if done is not None and done.meta.get("inputs") == key:
            return done
    root = parts_folder(out_path)
    folder = RunFolder(root, _COMMAND, resume=resume, overwrite=not resume)
    with contextlib.ExitStack() as stack:
        client = None
        if parallel:
            from facesim.inverse.parallel import dask_client

            client = stack.enter_context(dask_client(None if scheduler is not None else int(workers), scheduler))
        stack.enter_context(folder)
        previous = ((folder.previous or {}).get("inputs") or {}) if resume else {}
        recorded = previous.get("chunk_size") if isinstance(previous.get("chunk_size"), int) else None
        n_workers = len(client.scheduler_info()["workers"]) if client is not None else 1
        chunk = int(chunk_size or (recorded if _holds_a_run(root) else None) or math.ceil(n / max(n_workers, 1)))
        if chunk < 1:
            raise FacesimError(f"chunk_size: expected >= 1, got {chunk_size}")
        folder.start({**inputs, "chunk_size": chunk}, functools.partial(_holds_a_run, root),
                     functools.partial(_clear, root))
        rows = {i: row for i in range(n) if (row := _read_row(root, i, layout.n_features)) is not None}
        runs, starts = _runs(root, rows, n, chunk, model.X.shape)
        targets = [(poses[i], A[i]) for i in range(n)]
        newton = options.newton
        t_start = time.perf_counter()
        reused = len(rows)
        if runs and client is not None:
            from facesim.inverse.parallel import SimulatorSpec, solve_on_cluster

            spec = SimulatorSpec.of(model_path if model_path is not None else model.save(root / "model.npz"),
                                    options, "rigid")
            results = solve_on_cluster(client, _solve_frame, spec, layout, newton, np.arange(n), targets, runs, starts)
            _collect(results, root, rows, chunk, n, reused, progress, on_frame)
        elif runs:
            sim = FaceSimulator(model, options, jaw_model="rigid")
            _collect(_solve_here(sim, layout, newton, targets, runs, starts), root, rows, chunk, n, reused, progress,
                     on_frame)
        seconds = time.perf_counter() - t_start
        data = _assemble(model, model_path, layout, poses, A, rows, {
            "name": name or model.meta.get("subject_name") or (model_path.stem if model_path else "model"),
            "poses": poses_from, "expressions": expressions_from, "seed": int(seed), "chunk_size": chunk,
            "workers": n_workers if client is not None else 1, "inputs": key,
            "build_seconds": round(seconds, 2), "solved_frames": n - reused, "reused_frames": reused})
        data.save(out_path)
    shutil.rmtree(root, ignore_errors=True)
    return data


def _runs(root: Path, rows: dict, n: int, chunk: int, shape) -> tuple[list, list]:
    """The frames still to solve, per chunk of ``chunk`` frames: ``runs`` ``(first, stop, warm)``
    and each run's warm start (positions of the last converged frame before it in its chunk, or
    None: cold). Records after a chunk's first missing frame are dropped from ``rows`` (a chunk is
    solved in order, so they are strays); so are a chunk's records when the warm start they hand on
    was lost. Warm starts no run needs are deleted."""
    runs, starts, keep = [], [], set()
    for first in range(0, n, chunk):
        stop = min(first + chunk, n)
        begin = next((i for i in range(first, stop) if i not in rows), None)
        if begin is None:
            continue
        for i in range(begin, stop):
            rows.pop(i, None)
        converged = [i for i in range(first, begin) if bool(rows[i]["ok"])]
        warm = None
        if converged:
            warm = _read_warm(root, converged[-1], shape)
            if warm is None:      # lost: the chunk is solved again from its start
                for i in range(first, begin):
                    rows.pop(i, None)
                begin = first
            else:
                keep.add(_warm_path(root, converged[-1]))
        runs.append((begin, stop, warm is not None))
        starts.append(warm)
    for path in (root / "state").glob("warm_*.npz") if (root / "state").is_dir() else ():
        if path not in keep:
            path.unlink(missing_ok=True)
    return runs, starts


def _solve_here(sim, layout, newton, targets, runs, starts):
    """The runs solved in this process, in order: ``(row, warm start handed on)`` per frame."""
    for (first, stop, _), start in zip(runs, starts):
        for i in range(first, stop):
            row, start = _solve_frame(sim, layout, newton, targets[i], i, i, start)
            yield row, start


def _collect(results, root: Path, rows: dict, chunk: int, n: int, reused: int, progress, on_frame) -> None:
    """Write every finished frame (its warm start first, then its record) and drop the warm start
    its chunk no longer needs."""
    from tqdm import tqdm

    last_warm: dict[int, int] = {}
    for path in (root / "state").glob("warm_*.npz") if (root / "state").is_dir() else ():
        i = int(path.stem.split("_")[1])
        last_warm[i // chunk] = i
    bar = tqdm(total=n, initial=reused, desc="markerless dataset", unit="frame", disable=not progress)
    try:
        for row, handed_on in results:
            i, c = row["i"], row["i"] // chunk
            if row["ok"]:
                _save(_warm_path(root, i), x=handed_on)
            _write_row(root, row)
            if row["ok"]:
                if c in last_warm and last_warm[c] != i:
                    _warm_path(root, last_warm[c]).unlink(missing_ok=True)
                last_warm[c] = i
            rows[i] = row
            bar.set_postfix(ok=f"{sum(bool(r['ok']) for r in rows.values())}/{len(rows)}", refresh=False)
            bar.update(1)
            if on_frame is not None:
                on_frame(row)
    finally:
        bar.close()
        close = getattr(results, "close", None)
        if close is not None:
            close()


def _assemble(model, model_path, layout: FeatureLayout, poses, A, rows: dict, info: dict) -> MarkerlessData:
    n = len(poses)
    skin = np.stack([np.asarray(rows[i]["skin"], dtype=np.float64) for i in range(n)])
    ok = np.array([bool(rows[i]["ok"]) for i in range(n)])
    seconds = np.array([float(rows[i]["seconds"]) for i in range(n)])
    iterations = np.array([int(rows[i]["iterations"]) for i in range(n)])
    inverted = np.array([int(rows[i]["inverted"]) for i in range(n)])
    source = {"path": None if model_path is None else str(model_path), "builder": model.meta.get("builder"),
              "resolution": model.meta.get("resolution"), "seed": model.meta.get("seed"),
              "subject": model.meta.get("subject"), "nodes": int(model.n_nodes), "tets": int(model.n_tets)}
    meta = {**info, "model": source, "layout": layout.meta(), "jaw_model": "rigid",
            "bone_names": list(layout.bone_names), "failed_frames": [int(i) for i in np.flatnonzero(~ok)],
            "frames_with_inverted_tets": int((inverted > 0).sum()),
            "jaw_node_error_mm": float(max(float(rows[i]["jaw_error"]) for i in range(n))),
            "seconds_per_frame": round(float(seconds.mean()), 3), "iterations_per_frame": round(float(iterations.mean()), 2)}
    markers = np.stack([np.asarray(rows[i]["markers"], dtype=np.float64) for i in range(n)])
    return MarkerlessData(skin=skin, skin_rest=np.array(layout.skin_rest), bone_rest=np.array(layout.bone_rest),
                          poses=np.array(poses), ok=ok, feature_tri=np.array(layout.triangle),
                          feature_bary=np.array(layout.bary), activations=np.array(A),
                          muscles=tuple(model.muscles.names), meta=meta,
                          markers=MarkerTrack(markers, model.marker_positions(), tuple(model.markers.names),
                                              np.array(model.markers.triangle, dtype=np.int64),
                                              np.array(model.markers.bary)))


__all__ = ["DEFAULT_FRAMES", "HELDOUT_SUBJECT", "SUBJECTS", "TRAINING_SUBJECTS", "build_dataset", "jaw_poses",
           "parts_folder", "phantom_subject", "phantom_subject_model", "random_expressions", "subject_cache_dir"]
