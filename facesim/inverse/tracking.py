"""Sequences: fit every frame of a marker capture, warm-started from the previous one.

``track(sim, frames, P, out_dir)`` fits the capture's frames (already in the model's marker
order) with :func:`~facesim.inverse.gauss_newton.fit_frame`, each warm-started from the previous
frame's controls and equilibrium, after stabilising the head (rigid Procrustes of the head markers
onto the model's rest head markers, :func:`facesim.mocap.stabilise.stabilise`) or leaving it as
captured, and with ``neutral`` frames after rebinding the model's markers to them
(:func:`facesim.mocap.binding.bind_neutral`).

Per frame (:func:`fit_markers`): missing markers (NaN) are dropped; the marker distance is plain
least squares (``loss="l2"``) or a robust loss on each marker's distance ``r`` (mm), minimised by
iteratively reweighted Gauss-Newton -- each pass a ``fit_frame`` with per-marker weights
``w = rho'(r) / r`` from the previous pass's residuals:

* ``huber``  ``rho = r^2/2`` for ``r <= s``, ``s r - s^2/2`` beyond: ``w = min(1, s / r)``;
* ``cauchy`` ``rho = s^2/2 log(1 + (r/s)^2)``: ``w = 1 / (1 + (r/s)^2)``;

``s`` the loss scale (default 3x the marker noise: the 3-D distance of a marker with per-axis
noise ``sigma`` stays below ``2.8 sigma`` 95% of the time). After the fit, markers whose residual
is far above the frame's robust spread (``outlier_factor`` x 1.4826 MAD, at least
``outlier_floor`` mm) are reported as outliers and, with ``robust``, the frame is refitted without
them.

Chunks: with ``chunk_size`` the sequence is split into chunks of that many frames, each starting
cold (from ``start``, default rest) -- so chunks are independent and can be solved in parallel on
a ``dask.distributed`` cluster (``client``; :func:`facesim.inverse.parallel.dask_client` makes one).
Every task solves one frame, chained on the previous frame of its chunk so the worker holding that
frame's equilibrium warm-starts from it; workers build their simulator from a
:class:`~facesim.inverse.parallel.SimulatorSpec` (model file and options, cached per worker
process). The client writes every frame as it arrives.

Files in ``out_dir`` (append-only logs, :mod:`facesim.framelog`: one complete line per frame,
flushed and synced; ``resume`` keeps the frames already written and solves only the others):

* ``activations.csv`` ``frame,<muscle>,...``; ``jaw.csv`` ``frame,<jaw parameter>,...``;
* ``residuals.csv`` ``frame,rms,<marker>,...`` (mm, NaN for missing markers);
* ``frames.csv`` the solver log per frame (counts summed over the frame's fits);
* ``report.json`` the summary (rewritten when the run ends, also when interrupted);
* ``chunks/`` while frames finish out of order: the four logs of the frames solved after a
  still unfinished one. The files above always hold the longest finished prefix of the sequence,
  in frame order; a frame moves there as soon as every frame before it is written, and
  ``chunks/`` is removed when the run completes.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.framelog import FrameLog, csv_line, read_lines
from facesim.inverse.gauss_newton import Fit, FitOptions, FitReport, fit_frame
from facesim.inverse.jacobian import ControlSpace
from facesim.inverse.parallel import SimulatorSpec, solve_on_cluster
from facesim.mocap.binding import bind_neutral
from facesim.mocap.stabilise import check_window, stabilise

LOSSES = ("l2", "huber", "cauchy")
LOG_COLUMNS = ("frame", "converged", "stop_reason", "gn_steps", "equilibria", "newton_iterations", "linear_solves",
               "marker_rms", "worst_violation", "markers_used", "outliers", "fits", "penetration_mm",
               "lip_penetration_mm", "teeth_penetration_mm", "seconds", "error")
LOGS = ("activations", "jaw", "residuals", "frames")
CHUNKS = "chunks"


@dataclass(frozen=True)
class TrackOptions:
    """fit : per-frame :class:`FitOptions`; head : ``"procrustes"`` (stabilise with the head
    markers) or ``"none"`` (the capture is already in the model's head frame); outlier_factor,
    outlier_floor (mm) : outlier test; robust : refit frames without their outliers; loss :
    ``"l2"``, ``"huber"`` or ``"cauchy"`` on each marker's distance; loss_scale : its scale, mm
    (None: 3x ``fit.noise``); irls_steps : most reweighted passes of a robust loss; chunk_size :
    frames per independently (cold-) started chunk (None: one chunk, or with a cluster the frames
    divided evenly among its workers); head_smoothing : with ``"procrustes"``, smooth the head
    transforms over this many frames (odd, >= 3; 0: off; see :func:`facesim.mocap.stabilise.stabilise`)."""

    fit: FitOptions = FitOptions()
    head: str = "procrustes"
    outlier_factor: float = 5.0
    outlier_floor: float = 2.0
    robust: bool = True
    loss: str = "l2"
    loss_scale: float | None = None
    irls_steps: int = 5
    chunk_size: int | None = None
    head_smoothing: int = 0

    def __post_init__(self):
        if self.head not in ("procrustes", "none"):
            raise FacesimError(f"head: expected 'procrustes' or 'none', got {self.head!r}")
        if self.loss not in LOSSES:
            raise FacesimError(f"loss: expected one of {', '.join(LOSSES)}, got {self.loss!r}")
        if self.loss_scale is not None and not self.loss_scale > 0:
            raise FacesimError(f"loss scale: expected a distance > 0 mm, got {self.loss_scale}")
        if self.irls_steps < 1:
            raise FacesimError(f"irls_steps: expected >= 1, got {self.irls_steps}")
        if self.chunk_size is not None and self.chunk_size < 1:
            raise FacesimError(f"chunk size: expected >= 1 frames, got {self.chunk_size}")
        if self.head_smoothing:
            check_window(self.head_smoothing)

    @property
    def scale(self) -> float:
        """The robust loss scale, mm."""
        return self.loss_scale if self.loss_scale is not None else 3.0 * self.fit.noise


# ------------------------------------------------------------------ one frame
def loss_weights(r, loss: str, scale: float) -> np.ndarray:
    """Reweighting ``w = rho'(r) / r`` of the robust ``loss`` (see the module doc) for marker
    distances ``r (k,)`` mm with scale ``scale`` mm; 1 for missing (NaN) markers."""
    r = np.nan_to_num(np.asarray(r, dtype=np.float64), nan=0.0)
    if loss == "l2":
        return np.ones_like(r)
    if loss == "huber":
        return np.minimum(1.0, scale / np.maximum(r, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (r / scale) ** 2)
    raise FacesimError(f"loss: expected one of {', '.join(LOSSES)}, got {loss!r}")


def fit_markers(sim, targets, controls: Controls, x0=None, space: ControlSpace | None = None,
                options: TrackOptions | None = None, jacobian=None, frame: float = 0.0) -> tuple[Fit, list[int], list[Fit]]:
    """One frame as the tracker fits it: ``targets (r, 3)`` mm (NaN missing) under ``options.loss``
    (reweighted passes of :func:`fit_frame` from ``controls`` / ``x0``), the outlier test and, with
    ``options.robust``, the refit without the outliers. Returns the final fit, the outliers'
    marker indices and every fit made (for the frame's solver counts). ``jacobian``: the previous
    frame's ``Fit.jacobian`` (reused by :func:`fit_frame` while it stays accurate; each pass hands
    its own on to the next). ``frame``: the frame number the simulator's scripted colliders are
    posed at."""
    options = options or TrackOptions()
    fits: list[Fit] = []
    targets = np.asarray(targets, dtype=np.float64)
    # a tracked frame (one with the previous frame's Jacobian) screens for outliers on the first
    # step's linear prediction, which lands close to the fit: the outliers then cost no refit
    screen = functools.partial(_outliers, target=targets, options=options) \
        if options.robust and jacobian is not None else None

    def solve(target, c, x, J, screen=None):
        fit = fit_frame(sim, target, c, x, space, options.fit, jacobian=J, screen=screen, frame=frame)
        fits.append(fit)
        w = np.ones(len(target))
        for _ in range(options.irls_steps if options.loss != "l2" else 0):
            w_new = loss_weights(np.linalg.norm(fit.markers - target, axis=1), options.loss, options.scale)
            if np.max(np.abs(w_new - w) / w_new) < 0.02:   # the weights settled: so has the reweighted fit
                break
            w = w_new
            if fit.report.stop_reason == "equilibrium_failed":
                break
            fit = fit_frame(sim, target, fit.controls, fit.x, space, options.fit, weights=w, jacobian=fit.jacobian,
                            frame=frame)
            fits.append(fit)
        return fit

    fit = solve(targets, controls, x0, jacobian, screen)
    if fit.report.stop_reason == "equilibrium_failed":
        return fit, [], fits
    outliers = _outliers(fit.markers, targets, options)
    if outliers != fit.report.screened and options.robust:   # the screen missed some, or was wrong
        cleaned = targets.copy()
        cleaned[outliers] = np.nan
        fit = solve(cleaned, fit.controls, fit.x, fit.jacobian)
    return fit, outliers, fits


@dataclass(frozen=True)
class _Solved:
    """One solved frame as the client needs it: its line in each of :data:`LOGS` and the summary."""

    index: int
    lines: tuple[str, ...]
    gn_steps: int
    rms: float
    outliers: tuple[str, ...]
    stop_reason: str = "converged"

    @property
    def converged(self) -> bool:
        return self.stop_reason == "converged"


def _solve_frame(sim, space, options, target, k: int, i: int, controls, x, jacobian=None):
    """Fit frame ``k`` (position ``i``); returns the :class:`_Solved` and the state for the next
    frame (controls, equilibrium, Jacobian). A frame whose equilibrium failed (or whose solve
    raised a :class:`SolverError`) is written flagged, and the next frame starts from the state
    this one started from, never from the failed one."""
    model = sim.model
    try:
        fit, outliers, fits = fit_markers(sim, target, controls, x, space, options, jacobian, frame=k)
    except SolverError as exc:
        start = sim.attached_positions(controls, x)
        P = model.marker_positions(start)
        rep = FitReport(stop_reason="equilibrium_failed", error=" ".join(str(exc).split()))
        fit, outliers, fits = Fit(controls, start, P, rep, None), [], []
    rep = fit.report
    r = np.linalg.norm(fit.markers - target, axis=1)
    if not np.isfinite(rep.marker_rms):
        ok = np.isfinite(r)
        rep.marker_rms = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan")
    total = {name: sum(getattr(f.report, name) for f in fits)
             for name in ("gn_steps", "equilibria", "newton_iterations", "linear_solves", "seconds")}
    used = int(np.isfinite(target).all(axis=1).sum()) - (len(outliers) if options.robust else 0)
    jaw = np.atleast_1d(fit.controls.jaw) if space.n_jaw else []
    measures = sim.contact_measures(fit.x, fit.controls, k)
    lines = (
        csv_line([k, *map(_fmt, fit.controls.a)]),
        csv_line([k, *map(_fmt, jaw)]),
        csv_line([k, _fmt(rep.marker_rms), *map(_fmt, r)]),
        csv_line([k, int(rep.converged), rep.stop_reason, total["gn_steps"], total["equilibria"],
               total["newton_iterations"], total["linear_solves"], _fmt(rep.marker_rms), _fmt(rep.worst_violation),
               used, len(outliers), len(fits), *(_fmt(measures[c]) for c in _MEASURES), f"{total['seconds']:.3f}",
               rep.error]),
    )
    solved = _Solved(i, lines, total["gn_steps"], rep.marker_rms, tuple(model.markers.names[j] for j in outliers),
                     rep.stop_reason)
    if rep.stop_reason == "equilibrium_failed":
        return solved, controls, x, jacobian
    return solved, fit.controls, fit.x, fit.jacobian


_MEASURES = ("penetration_mm", "lip_penetration_mm", "teeth_penetration_mm")


def _outliers(P, target, options: TrackOptions) -> list[int]:
    r = np.linalg.norm(P - target, axis=1)
    ok = np.isfinite(r)
    if ok.sum() < 5:
        return []
    med = np.median(r[ok])
    spread = 1.4826 * np.median(np.abs(r[ok] - med))
    limit = max(med + options.outlier_factor * spread, options.outlier_floor)
    return [int(j) for j in np.flatnonzero(ok & (r > limit))]


# ------------------------------------------------------------------ files
def _fmt(v) -> str:
    return "nan" if not np.isfinite(v) else f"{v:.6g}"


class _Outputs:
    """The four logs of a run (see the module doc): ``OUT/<log>.csv`` hold the longest finished
    prefix of the sequence in frame order, ``OUT/chunks/<log>.csv`` the frames finished after a
    gap. ``done`` maps each finished frame number to its lines."""

    def __init__(self, out: Path, headers: dict[str, list[str]], frames, resume: bool):
        self.out = out
        self.frames = [int(k) for k in frames]
        self.headers = {name: csv_line(headers[name]) for name in LOGS}
        self.done: dict[int, tuple[str, ...]] = {}
        if resume:
            for folder in (out / CHUNKS, out):   # the merged files' lines win
                self.done.update(self._read(folder))
        wanted = set(self.frames)
        self.done = {k: v for k, v in self.done.items() if k in wanted}
        self.n_merged = 0
        while self.n_merged < len(self.frames) and self.frames[self.n_merged] in self.done:
            self.n_merged += 1
        ahead = [k for k in self.frames[self.n_merged:] if k in self.done]
        self.merged = self._open(out, self.frames[:self.n_merged])
        self.ahead = None
        if ahead:
            self.ahead = self._open(out / CHUNKS, ahead)
        else:
            shutil.rmtree(out / CHUNKS, ignore_errors=True)

    def _read(self, folder: Path) -> dict[int, tuple[str, ...]]:
        """Frames with a complete line in all four logs of ``folder`` (matching headers)."""
        rows = [read_lines(folder / f"{name}.csv", self.headers[name]) for name in LOGS]
        if not all(rows):
            return {}
        common = set.intersection(*(set(r) for r in rows))
        return {k: tuple(r[k] for r in rows) for k in common}

    def _open(self, folder: Path, frames) -> dict[str, FrameLog]:
        return {name: FrameLog(folder / f"{name}.csv", self.headers[name], (self.done[k][j] for k in frames))
                for j, name in enumerate(LOGS)}

    @staticmethod
    def _write(logs: dict[str, FrameLog], lines) -> None:
        for name, ln in zip(LOGS, lines):
            logs[name].add(ln)

    def add(self, i: int, lines) -> None:
        """Write frame ``frames[i]``: into the merged logs if every frame before it is written
        (then also the frames after it that were waiting), else into ``chunks/``."""
        k = self.frames[i]
        self.done[k] = tuple(lines)
        if i != self.n_merged:
            if self.ahead is None:
                self.ahead = self._open(self.out / CHUNKS, [])
            self._write(self.ahead, lines)
            return
        while self.n_merged < len(self.frames) and self.frames[self.n_merged] in self.done:
            self._write(self.merged, self.done[self.frames[self.n_merged]])
            self.n_merged += 1

    def close(self) -> None:
        for logs in (self.merged, self.ahead or {}):
            for log in logs.values():
                log.close()
        if self.n_merged == len(self.frames):
            shutil.rmtree(self.out / CHUNKS, ignore_errors=True)

    def controls(self, k: int, space: ControlSpace) -> Controls:
        """The controls written for frame ``k``."""
        a = np.array([float(v) for v in next(csv.reader([self.done[k][0]]))[1:]])
        q = np.array([float(v) for v in next(csv.reader([self.done[k][1]]))[1:]])
        return Controls(a, jaw=q if space.n_jaw else None)


# ------------------------------------------------------------------ sequences
def _runs(n: int, chunk: int, done) -> list[tuple[int, int, bool]]:
    """The unfinished frames as runs ``(first, stop, warm)`` of positions inside one chunk;
    ``warm``: the frame before the run is in the same chunk (and finished: it starts the run)."""
    runs = []
    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        i = lo
        while i < hi:
            if done[i]:
                i += 1
                continue
            j = i
            while j < hi and not done[j]:
                j += 1
            runs.append((i, j, i > lo))
            i = j
    return runs


def _solve_here(sim, space, options, frames, P, runs, starts):
    for (first, stop, _), controls in zip(runs, starts):
        x = J = None
        for i in range(first, stop):
            solved, controls, x, J = _solve_frame(sim, space, options, P[i], int(frames[i]), i, controls, x, J)
            yield solved


def track(sim, frames, P, out_dir, *, names=None, options: TrackOptions | None = None, start: Controls | None = None,
          resume: bool = False, progress: bool = True, client=None, neutral=None) -> dict:
    """Fit every frame of ``P (F, r, 3)`` (mm, the model's marker order, NaN missing; frame numbers
    ``frames (F,)``, unique) and write the results into ``out_dir`` (see the module doc).

    ``sim``: a :class:`~facesim.fem.equilibrium.FaceSimulator` or a
    :class:`~facesim.inverse.parallel.SimulatorSpec`;
    ``client``: a ``distributed.Client`` solving the chunks in parallel (needs a spec). ``start``:
    controls each chunk starts from (default rest). ``resume``: keep the frames in ``out_dir``
    and solve only the others (a run continues from its last written frame, warm-started from
    its controls). ``neutral (r, 3)`` or ``(k, r, 3)``: capture frames of the neutral face (model
    marker order, NaN missing, same coordinates as ``P``; several: the per-marker median after
    stabilisation); the model's markers are first rebound to where it puts
    them (:func:`facesim.mocap.binding.rebind_markers`, Sifakis 2005's binding of the capture to
    the skin). Returns the summary (also written to ``report.json``)."""
    from tqdm import tqdm

    options = options or TrackOptions()
    spec = sim if isinstance(sim, SimulatorSpec) else None
    if client is not None and spec is None:
        raise FacesimError("parallel tracking: pass a SimulatorSpec (model file and options) for the workers to "
                           "build their simulator from")
    local = spec.build() if spec is not None else sim
    model = local.model
    P = np.asarray(P, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    if P.ndim != 3 or P.shape[1:] != (model.n_markers, 3) or len(frames) != len(P):
        raise FacesimError(f"markers: expected ({len(frames)}, {model.n_markers}, 3) positions, got {P.shape}")
    if len(np.unique(frames)) != len(frames):
        raise FacesimError("frames: expected unique frame numbers")
    rebinding = None
    if neutral is not None:
        bound, rebinding = bind_neutral(local, neutral, options.head)
    if options.head == "procrustes":
        P, _ = stabilise(model, P, options.head_smoothing)
    if rebinding is not None:   # after stabilising: the head frame is the model's own rest head markers
        local = bound
        model = local.model
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    space = ControlSpace.of(local)
    jaw_names = list(local.jaw_model.param_names)
    headers = {"activations": ["frame", *model.muscles.names], "jaw": ["frame", *jaw_names],
               "residuals": ["frame", "rms", *model.markers.names], "frames": list(LOG_COLUMNS)}
    n = len(frames)
    n_workers = len(client.scheduler_info()["workers"]) if client is not None else 1
    chunk = options.chunk_size or math.ceil(n / max(n_workers, 1)) or 1
    previous = {}
    if resume and (out / "report.json").is_file():
        try:
            previous = json.loads((out / "report.json").read_text()).get("outliers", {})
        except (ValueError, AttributeError):
            previous = {}
    outputs = _Outputs(out, headers, frames, resume)
    done = [int(k) in outputs.done for k in frames]
    runs = _runs(n, chunk, done)
    cold = start or Controls(np.zeros(model.n_muscles), jaw=_rest_jaw(space))
    starts = [outputs.controls(int(frames[first - 1]), space) if warm else cold for first, _, warm in runs]
    summary = {"frames": n, "reused_frames": int(sum(done)), "chunk_size": chunk,
               "workers": n_workers if client is not None else 0, "loss": options.loss, "rebinding": rebinding,
               "outliers": {k: v for k, v in previous.items() if k.lstrip("-").isdigit() and int(k) in outputs.done},
               "status": "running"}
    t_start = time.perf_counter()
    solved: dict[int, _Solved] = {}
    if client is not None:
        results = solve_on_cluster(client, _solve_frame, spec, space, options, frames, P, runs, starts,
                                   None if rebinding is None else model.markers)
    else:
        results = _solve_here(local, space, options, frames, P, runs, starts)
    try:
        with tqdm(total=n, initial=int(sum(done)), desc="solve-mocap", unit="frame", disable=not progress) as bar:
            for s in results:
                outputs.add(s.index, s.lines)
                solved[s.index] = s
                if s.outliers:
                    summary["outliers"][str(int(frames[s.index]))] = list(s.outliers)
                bar.set_postfix(rms=f"{s.rms:.2f}", steps=s.gn_steps, refresh=False)
                bar.update(1)
        summary["status"] = "complete"
    except BaseException as exc:
        summary["status"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed: {type(exc).__name__}"
        raise
    finally:
        results.close()
        outputs.close()
        order = sorted(solved)
        position = {int(k): i for i, k in enumerate(frames)}
        summary.update({
            "solved_frames": len(solved), "written_in_order": outputs.n_merged,
            "seconds": round(time.perf_counter() - t_start, 3),
            "gn_steps": [solved[i].gn_steps for i in order], "marker_rms": [round(solved[i].rms, 4) for i in order],
            "outliers": dict(sorted(summary["outliers"].items(), key=lambda kv: position.get(int(kv[0]), 0))),
            **_stop_summary(outputs, frames),
        })
        atomic_write(out / "report.json", lambda tmp: tmp.write_text(json.dumps(summary, indent=2) + "\n"))
    return summary


def _stop_summary(outputs, frames) -> dict:
    """``stop_reasons`` (count per reason) and ``unconverged_frames`` over every written frame
    (solved now or reused), from their ``frames.csv`` lines."""
    column = LOG_COLUMNS.index("stop_reason")
    counts: dict[str, int] = {}
    unconverged = {}
    for k in map(int, frames):
        if k in outputs.done:
            reason = next(csv.reader([outputs.done[k][3]]))[column]
            counts[reason] = counts.get(reason, 0) + 1
            if reason != "converged":
                unconverged[str(k)] = reason
    return {"stop_reasons": counts, "converged": counts.get("converged", 0),
            "unconverged_frames": [int(k) for k in unconverged], "unconverged_reasons": unconverged}


def _rest_jaw(space: ControlSpace):
    if not space.n_jaw:
        return None
    return np.zeros(space.n_jaw) if space.jaw_rest is None else np.array(space.jaw_rest)


__all__ = ["LOG_COLUMNS", "LOGS", "LOSSES", "TrackOptions", "fit_markers", "loss_weights", "track"]
