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
synced to disk; ``resume`` keeps the frames already written and solves only the others):

* ``activations.csv`` ``frame,<muscle>,...``; ``jaw.csv`` ``frame,<jaw parameter>,...``: the
  controls clipped to the bounds ([0, 1]; the jaw model's ``bounds``), which the penalty schedule
  leaves violated by ~1e-5, so ``simulate`` takes them as they are; only the written values are
  clipped (the warm start keeps the solver's state: the solve is the one an unclipped run makes),
  ``report.json``'s ``clipped`` says how much and ``frames.csv``'s ``worst_violation`` stays the
  solver's;
* ``residuals.csv`` ``frame,rms,<marker>,...`` (mm, NaN for missing markers);
* ``frames.csv`` the solver log per frame (counts summed over the frame's fits);
* ``report.json`` the summary (rewritten when the run ends, also when interrupted), with the jaw
  model the controls are for (``jaw_model_used``: name, spec, fingerprint) for ``simulate
  --controls-from``;
* with ``write_meshes``, what ``simulate`` writes (:func:`facesim.simulate.write_frame`):
  ``skin/frame_KKKKK.ply`` and ``state/frame_KKKKK.npz`` per frame, written before the frame's log
  lines, at the fit's equilibrium moved to first order to the clipped controls (no equilibrium is
  solved again; a failed frame's files hold the state it was left in, ``converged`` 0), and when
  the run ends ``markers.csv`` / ``markers.trc`` / ``markers.c3d`` of the model's markers at those
  states; the skin and marker files in the ``output_frame`` (facesim's, or the input frame and
  units of an imported model: :mod:`facesim.output_frame`), the state files in facesim's;
* ``chunks/`` while frames finish out of order: the four logs of the frames solved after a
  still unfinished one. The files above always hold the longest finished prefix of the sequence,
  in frame order; a frame moves there as soon as every frame before it is written, and
  ``chunks/`` is removed when the run completes;
* ``state/warm_KKKKK.npz`` while the run is unfinished: the warm start the last finished frame
  of each chunk hands to the next one (full-precision controls, equilibrium, Jacobian and where
  its factorised tangent was taken), written before the frame's log lines; at most two per chunk
  at any time, all removed when the run completes;
* ``run.json`` the inputs' fingerprints and ``.lock`` while the run writes
  (:class:`facesim.runfolder.RunFolder`): a folder holding a run needs ``resume`` or
  ``overwrite``, a resume with other inputs (model, capture, frames, jaw model, options) is
  refused, naming them, and a second run into a folder being written stops at once.

Resume is faithful: a run continues from the warm start of the frame before, as restored from
``state/``, so the frames it solves are those an uninterrupted run would have written -- bit for
bit where the solves are deterministic (direct or PARDISO linear solvers on one thread). Two things
cannot be restored and make a resumed frame differ within the solvers' tolerances: the AMG
hierarchy a simulator reuses across solves (``NewtonOptions(linear_solver="amg")``), and, on a
cluster, the factorised tangent a Jacobian carries only while consecutive frames stay on one worker.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.budget import TIME_LIMIT, time_budget
from facesim.controls import Controls
from facesim.errors import FacesimError, SolverError
from facesim.framelog import FrameLog, csv_line, read_lines
from facesim.inverse.gauss_newton import Fit, FitOptions, FitReport, fit_frame
from facesim.controls_io import HEAD_COLUMNS, head_pose
from facesim.inverse.head_frame import HeadFrame
from facesim.inverse.jacobian import ControlSpace, EquilibriumJacobian, factorised_tangent
from facesim.inverse.parallel import SimulatorSpec, solve_on_cluster
from facesim.mocap.binding import bind_neutral
from facesim.mocap.stabilise import check_window, stabilise
from facesim.output_frame import output_frame as resolve_output_frame
from facesim.runfolder import UNRECORDED, RunFolder, describe, fingerprint, finish, parts

LOSSES = ("l2", "huber", "cauchy")
HEAD_MODES = ("procrustes", "none", "solve")
LOG_COLUMNS = ("frame", "converged", "stop_reason", "gn_steps", "equilibria", "newton_iterations", "linear_solves",
               "marker_rms", "worst_violation", "markers_used", "outliers", "fits", "penetration_mm",
               "lip_penetration_mm", "teeth_penetration_mm", "seconds", "error")
LOGS = ("activations", "jaw", "residuals", "frames")
HEAD_LOG = "head"   # the fifth log, of a run that solves the head frame (``head="solve"``)
CHUNKS = "chunks"
STATE = "state"


@dataclass(frozen=True)
class TrackOptions:
    """fit : per-frame :class:`FitOptions`; head : ``"procrustes"`` (stabilise with the head
    markers), ``"none"`` (the capture is already in the model's head frame) or ``"solve"`` (the
    skull's affine frame solved with the other controls under the rigidity penalty, Sifakis 2005
    section 8: :mod:`facesim.inverse.head_frame`); outlier_factor,
    outlier_floor (mm) : outlier test; robust : refit frames without their outliers; loss :
    ``"l2"``, ``"huber"`` or ``"cauchy"`` on each marker's distance; loss_scale : its scale, mm
    (None: 3x ``fit.noise``); irls_steps : most reweighted passes of a robust loss; chunk_size :
    frames per independently (cold-) started chunk (None: one chunk, or with a cluster the frames
    divided evenly among its workers); head_smoothing : with ``"procrustes"``, smooth the head
    transforms over this many frames (odd, >= 3; 0: off; see :func:`facesim.mocap.stabilise.stabilise`);
    write_meshes : also write each frame's skin and state as ``simulate`` does (the module doc);
    jaw_prior : a :class:`~facesim.inverse.jaw_prior.JawPrior`: each frame's jaw predicted from its
    markers starts a cold frame and is a prior of every frame's jaw parameters (None: none);
    coarse_model : path of a coarser model of the same face: a cold frame (a chunk's first, or one
    after a failed frame) is fitted on it first and refined on the full model
    (:mod:`facesim.inverse.coarse`; None: cold frames on the full model alone); several paths (a
    tuple): a chain, each level's cold fit started on the next coarser one
    (:meth:`~facesim.inverse.coarse.CoarseStart.chain`)."""

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
    write_meshes: bool = False
    jaw_prior: object = None
    coarse_model: str | tuple[str, ...] | None = None

    def __post_init__(self):
        if self.head not in HEAD_MODES:
            raise FacesimError(f"head: expected one of {', '.join(HEAD_MODES)}, got {self.head!r}")
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
                options: TrackOptions | None = None, jacobian=None, frame: float = 0.0,
                head_frame=None) -> tuple[Fit, list[int], list[Fit]]:
    """One frame as the tracker fits it: ``targets (r, 3)`` mm (NaN missing) under ``options.loss``
    (reweighted passes of :func:`fit_frame` from ``controls`` / ``x0``), the outlier test and, with
    ``options.robust``, the refit without the outliers. Returns the final fit, the outliers'
    marker indices and every fit made (for the frame's solver counts). ``jacobian``: the previous
    frame's ``Fit.jacobian`` (reused by :func:`fit_frame` while it stays accurate; each pass hands
    its own on to the next). ``frame``: the frame number the simulator's scripted colliders are
    posed at. ``head_frame``: the head frame to start from when it is solved (4x4 affine, the
    model's head frame -> the capture's; :func:`~facesim.inverse.gauss_newton.fit_frame`), each
    pass starting from the last one's."""
    return _fit_markers(sim, targets, controls, x0, space, options or TrackOptions(), jacobian, frame, head_frame)


def _fit_markers(sim, targets, controls, x0, space, options: TrackOptions, jacobian, frame, head_frame=None,
                 prior=None, coarse=None):
    """:func:`fit_markers` (the module doc); ``prior``: the frame's jaw prior rows
    (:class:`~facesim.inverse.jaw_prior.PriorRows`) or None; ``coarse``: a
    :class:`~facesim.inverse.coarse.CoarseStart` a cold frame (no ``x0``) is fitted on first, with
    the same loss and outlier handling, then refined here from its result (its fits come first in
    the fits returned)."""
    fits: list[Fit] = []
    targets = np.asarray(targets, dtype=np.float64)

    def fit_from(target, c, x, J, weights=None, screen=None, head=None, finish=False):
        fit = fit_frame(sim, target, c, x, space, options.fit, weights=weights, jacobian=J, screen=screen,
                        frame=frame, head_frame=fits[-1].head_frame if fits else head, jaw_prior=prior,
                        finish_start=finish)
        fits.append(fit)
        return fit

    def solve(target, c, x, J, screen=None, finish=False):
        fit = fit_from(target, c, x, J, screen=screen, head=head_frame, finish=finish)
        w = np.ones(len(target))
        for _ in range(options.irls_steps if options.loss != "l2" else 0):
            w_new = loss_weights(np.linalg.norm(fit.markers - target, axis=1), options.loss, options.scale)
            if np.max(np.abs(w_new - w) / w_new) < 0.02:   # the weights settled: so has the reweighted fit
                break
            w = w_new
            if fit.report.stop_reason == "equilibrium_failed":
                break
            fit = fit_from(target, fit.controls, fit.x, fit.jacobian, weights=w)
        return fit

    # the frame's wall-clock budget covers all its fits (an inner fit's budget cannot extend it)
    with time_budget(options.fit.max_seconds):
        refined = coarse is not None and x0 is None
        if refined:   # x0, if any, is the refinement's: solved to START_RTOL, finished by the fit
            controls, x0, jacobian, head_frame = _coarse_first(coarse, targets, controls, space, options, frame,
                                                               head_frame, prior, fits)
        # a tracked frame (one with the previous frame's Jacobian) screens for outliers on the first
        # step's linear prediction, which lands close to the fit: the outliers then cost no refit
        screen = functools.partial(_outliers, target=targets, options=options) \
            if options.robust and jacobian is not None else None
        fit = solve(targets, controls, x0, jacobian, screen, finish=refined and x0 is not None)
        if fit.report.stop_reason == "equilibrium_failed" or not fit.equilibrium:
            return fit, [], fits
        outliers = _outliers(fit.markers, targets, options)
        if outliers != fit.report.screened and options.robust and fit.report.stop_reason != TIME_LIMIT:
            cleaned = targets.copy()   # the screen missed some, or was wrong
            cleaned[outliers] = np.nan
            fit = solve(cleaned, fit.controls, fit.x, fit.jacobian)
    return fit, outliers, fits


def _coarse_first(coarse, targets, controls, space, options: TrackOptions, frame, head_frame, prior, fits):
    """A cold frame's start from the coarse model (:class:`~facesim.inverse.coarse.CoarseStart`):
    its fit (the tracker's, with the loss and outlier refit) and the refinement to the full model.
    Appends the fits made to ``fits`` (the refinement as a fit of no steps) and returns the full
    model's ``(controls, x0, jacobian, head_frame)`` -- ``x0`` and ``jacobian`` None, and the
    original ``controls`` and ``head_frame``, where the coarse fit or the refinement failed."""
    cfit, _, cfits = _fit_markers(coarse.sim, targets, coarse.down(controls), None, coarse.space(space), options,
                                  None, frame, head_frame, prior, coarse.nested)
    fits.extend(cfits)
    controls, x, J, head_frame, rep = coarse.start(cfit, controls, head_frame, space, options.fit, frame)
    if x is not None:
        fits.append(Fit(controls, x, _in_capture(coarse.fine_sim.model, x, head_frame), rep, J, head_frame=head_frame))
    return controls, x, J, head_frame


def _in_capture(model, x, head) -> np.ndarray:
    """Marker positions of ``x`` in the capture's frame (moved by the 4x4 ``head`` when solved)."""
    P = model.marker_positions(x)
    return P if head is None else P @ head[:3, :3].T + head[:3, 3]


@dataclass(frozen=True)
class _Solved:
    """One solved frame as the client needs it: its line in each of :data:`LOGS` and the summary;
    ``clipped``: how much its written controls were clipped to the bounds, ``(values, largest)`` of
    the activations then of the jaw parameters; ``files``: with ``write_meshes``, what its state
    file holds, ``(x (n, 3), a, jaw, converged, error)``."""

    index: int
    lines: tuple[str, ...]
    gn_steps: int
    rms: float
    outliers: tuple[str, ...]
    stop_reason: str = "converged"
    clipped: tuple = (0, 0.0, 0, 0.0)
    files: tuple | None = None

    @property
    def converged(self) -> bool:
        return self.stop_reason == "converged"


@dataclass(frozen=True)
class _Start:
    """The warm start a frame hands to the next frame of its chunk: its controls (full precision),
    equilibrium ``x (n, 3)`` (None: solve it) and Jacobian (None: evaluate one; its ``tangent_at``
    says where its factorised tangent was assembled)."""

    controls: Controls
    x: np.ndarray | None = None
    jacobian: EquilibriumJacobian | None = None
    head_frame: np.ndarray | None = None   # the solved head frame (4x4 affine) with head="solve"


def _solve_frame(sim, space, options, target, k: int, i: int, start: _Start) -> tuple[_Solved, _Start]:
    """Fit frame ``k`` (position ``i``) from ``start``; returns the :class:`_Solved` and the start of
    the next frame. A frame whose equilibrium failed (or whose solve raised a
    :class:`SolverError`) is written flagged, and the next frame starts from the state this one
    started from, never from the failed one.

    The Jacobian handed on carries where its factorised tangent was assembled
    (``EquilibriumJacobian.tangent_at``), so a resume can factorise it again there from the frame's
    saved warm start."""
    model = sim.model
    controls, x, jacobian = start.controls, start.x, start.jacobian
    head = None
    if options.head == "solve":   # from the previous frame's head frame, or one found from this frame's markers
        head = start.head_frame if start.head_frame is not None else initial_head_frame(model, target)
    prior = None
    if options.jaw_prior is not None:
        controls, prior = _with_prior(sim, space, options, target, head, controls, x)
    coarse = None
    if options.coarse_model is not None and x is None and jacobian is None:
        from facesim.inverse.coarse import coarse_start_for

        coarse = coarse_start_for(sim, options.coarse_model)
    try:
        fit, outliers, fits = _fit_markers(sim, target, controls, x, space, options, jacobian, k, head, prior,
                                           coarse)
    except SolverError as exc:
        attached = sim.attached_positions(controls, x)
        P = _in_capture(model, attached, head)
        rep = FitReport(stop_reason="equilibrium_failed", error=" ".join(str(exc).split()))
        fit, outliers, fits = Fit(controls, attached, P, rep, None, equilibrium=False, head_frame=head), [], []
    rep = fit.report
    r = np.linalg.norm(fit.markers - target, axis=1)
    if not np.isfinite(rep.marker_rms):
        ok = np.isfinite(r)
        rep.marker_rms = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan")
    total = {name: sum(getattr(f.report, name) for f in fits)
             for name in ("gn_steps", "equilibria", "newton_iterations", "linear_solves", "seconds")}
    used = int(np.isfinite(target).all(axis=1).sum()) - (len(outliers) if options.robust else 0)
    measures = sim.contact_measures(fit.x, fit.controls, k)
    a, jaw, clipped = _written(fit.controls, space, sim.jaw_model)
    lines = (
        *_control_lines(k, a, jaw, sim.jaw_model),
        csv_line([k, _fmt(rep.marker_rms), *map(_fmt, r)]),
        csv_line([k, int(rep.converged), rep.stop_reason, total["gn_steps"], total["equilibria"],
               total["newton_iterations"], total["linear_solves"], _fmt(rep.marker_rms), _fmt(rep.worst_violation),
               used, len(outliers), len(fits), *(_fmt(measures[c]) for c in _MEASURES), f"{total['seconds']:.3f}",
               rep.error]),
    )
    if head is not None:
        lines += (_head_line(k, model, fit.head_frame),)
    failed = rep.stop_reason == "equilibrium_failed" or not fit.equilibrium
    files = None
    if options.write_meshes:
        q = jaw if space.n_jaw else np.asarray(sim.jaw_model.rest)
        x = fit.x if failed else _at_written(fit, space, a, jaw)
        files = (np.asarray(x, dtype=np.float64), a, q, not failed, rep.error)
    solved = _Solved(i, lines, total["gn_steps"], rep.marker_rms, tuple(model.markers.names[j] for j in outliers),
                     rep.stop_reason, clipped, files)
    if failed:
        return solved, start
    J = fit.jacobian
    return solved, _Start(fit.controls, fit.x, J, fit.head_frame)


def _with_prior(sim, space, options: TrackOptions, target, head, controls, x):
    """The frame's jaw prior rows from its markers (in the skull frame: undone by ``head`` when the
    head frame is solved), and its start: a cold frame (``x`` None) starts at the predicted jaw.
    Returns ``(controls, rows)``."""
    model, jp = sim.model, options.jaw_prior
    m = np.asarray(target, dtype=np.float64)
    if head is not None:
        A = np.asarray(head, dtype=np.float64)
        m = (m - A[:3, 3]) @ np.linalg.inv(A[:3, :3]).T
    fallback = None if x is None else model.marker_positions(x)
    points = jp.predict(model, m, fallback)
    if x is None and space.n_jaw:
        q = jp.start(sim.jaw_model, points)
        controls = dataclasses.replace(controls, jaw=q)
    return controls, jp.rows(points, options.fit.noise)


def initial_head_frame(model, target) -> np.ndarray:
    """A first head frame (4x4, the model's head frame -> the capture's) for a frame with no
    previous one: the rigid fit of the model's rest head markers onto the capture's where at least
    three are present, else of all present markers (the expression then biases it, and the fit
    corrects it)."""
    from facesim.se3 import rigid_fit

    target = np.asarray(target, dtype=np.float64)
    rest = model.marker_positions()
    ok = np.isfinite(target).all(axis=1)
    use = ok & model.markers.head if (ok & model.markers.head).sum() >= 3 else ok
    return rigid_fit(rest[use], target[use])


def _head_line(k: int, model, T) -> str:
    """Frame ``k``'s line of ``head.csv``: the rigid head pose nearest the solved frame ``T`` and
    the frame's strain (:data:`facesim.controls_io.HEAD_COLUMNS`)."""
    hf = HeadFrame.of(model)
    R, strain = hf.rigid(hf.coefficients(T))
    return csv_line([k, *(f"{v:.9g}" for v in R[:3, :3].ravel()), *(f"{v:.6f}" for v in R[:3, 3]), f"{strain:.3e}"])


_MEASURES = ("penetration_mm", "lip_penetration_mm", "teeth_penetration_mm")


def _written(controls: Controls, space: ControlSpace, jaw_model) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The controls as the files hold them: activations ``(n_muscles,)`` clipped to [0, 1] and jaw
    parameters ``(n_jaw,)`` to ``jaw_model.bounds`` -- the penalty schedule enforces the bounds only
    to ~1e-5, and ``simulate`` refuses any value outside them. Only what is written is clipped: the
    warm start keeps the solver's own state (controls, equilibrium and Jacobian agree with each
    other), so the solve is the same as without clipping. Also returns ``(values clipped, largest
    clip)`` of the activations, then of the jaw."""
    a = np.asarray(controls.a, dtype=np.float64)
    q = np.atleast_1d(np.asarray(controls.jaw, dtype=np.float64)) if space.n_jaw else np.zeros(0)
    lo, hi = _jaw_bounds(jaw_model, len(q))
    a_out, q_out = np.clip(a, 0.0, 1.0) + 0.0, np.clip(q, lo, hi) + 0.0   # + 0.0: no '-0' in the files

    def amount(v, w):
        d = np.abs(v - w)
        return int(np.count_nonzero(d)), float(d.max(initial=0.0))

    return a_out, q_out, (*amount(a, a_out), *amount(q, q_out))


def _at_written(fit: Fit, space: ControlSpace, a, jaw) -> np.ndarray:
    """The equilibrium ``(n, 3)`` of the written (clipped) controls ``a``, ``jaw``, to first order
    from the fit's: ``x + dx/dc (c_written - c)`` with the fit's Jacobian -- the clip is ~1e-5, so the
    error is of order 1e-10 and no equilibrium is solved again; what ``simulate`` makes of the
    written controls is then these positions, not those of the unclipped ones."""
    dc = space.vector(Controls(a, jaw=jaw if space.n_jaw else None)) - space.vector(fit.controls)
    if fit.jacobian is None or not dc.any():
        return fit.x
    return fit.x + (fit.jacobian.dx @ dc).reshape(-1, 3)


def _jaw_bounds(jaw_model, n: int) -> tuple[np.ndarray, np.ndarray]:
    if not n:
        return np.zeros(0), np.zeros(0)
    lo, hi = np.asarray(jaw_model.bounds, dtype=np.float64).reshape(n, 2).T
    return lo, hi


def _control_lines(k: int, a, jaw, jaw_model) -> tuple[str, str]:
    """Frame ``k``'s lines of ``activations.csv`` and ``jaw.csv`` for controls within the bounds:
    6 significant digits, or all 17 where rounding to 6 would step outside a bound (a jaw
    parameter on an upper bound such as 0.6234567 rad), so every value read back is within them."""
    lo, hi = _jaw_bounds(jaw_model, len(jaw))
    return (csv_line([k, *(_fmt_within(v, 0.0, 1.0) for v in a)]),
            csv_line([k, *(_fmt_within(v, l, h) for v, l, h in zip(jaw, lo, hi))]))


def _fmt_within(v: float, lo: float, hi: float) -> str:
    text = _fmt(v)
    return text if not np.isfinite(v) or lo <= float(text) <= hi else repr(float(v))


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
        self.names = tuple(headers)   # LOGS, and HEAD_LOG when the head is solved; a frame's lines in this order
        self.headers = {name: csv_line(headers[name]) for name in self.names}
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
        rows = [read_lines(folder / f"{name}.csv", self.headers[name]) for name in self.names]
        if not all(rows):
            return {}
        common = set.intersection(*(set(r) for r in rows))
        return {k: tuple(r[k] for r in rows) for k in common}

    def _open(self, folder: Path, frames) -> dict[str, FrameLog]:
        return {name: FrameLog(folder / f"{name}.csv", self.headers[name], (self.done[k][j] for k in frames))
                for j, name in enumerate(self.names)}

    def _write(self, logs: dict[str, FrameLog], lines) -> None:
        for name, ln in zip(self.names, lines):
            logs[name].add(ln)

    def add(self, i: int, lines) -> None:
        """Write frame ``frames[i]``: into the merged logs if every frame before it is written
        (then also the frames after it that were waiting), else into ``chunks/``."""
        k = self.frames[i]
        self.done[k] = tuple(lines)
        try:
            if i != self.n_merged:
                if self.ahead is None:
                    self.ahead = self._open(self.out / CHUNKS, [])
                self._write(self.ahead, lines)
                return
            while self.n_merged < len(self.frames) and self.frames[self.n_merged] in self.done:
                self._write(self.merged, self.done[self.frames[self.n_merged]])
                self.n_merged += 1
        except BaseException:   # not written (all four lines): not a finished frame
            if i >= self.n_merged:
                del self.done[k]
            raise

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

    def head_frame(self, k: int) -> np.ndarray | None:
        """The head pose written for frame ``k`` (4x4; None when the run does not solve the head)."""
        if HEAD_LOG not in self.names:
            return None
        return head_pose([float(v) for v in next(csv.reader([self.done[k][self.names.index(HEAD_LOG)]]))[1:13]])


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
    """Solve the ``runs`` one after the other in this process, each from its :class:`_Start`;
    yields ``(_Solved, the _Start it hands on)`` per frame."""
    for (first, stop, _), start in zip(runs, starts):
        for i in range(first, stop):
            solved, start = _solve_frame(sim, space, options, P[i], int(frames[i]), i, start)
            yield solved, start


def track(sim, frames, P, out_dir, *, names=None, options: TrackOptions | None = None, start: Controls | None = None,
          resume: bool = False, overwrite: bool = False, progress: bool = True, client=None, neutral=None,
          info: dict | None = None, fps: float = 30.0, output_frame="facesim") -> dict:
    """Fit every frame of ``P (F, r, 3)`` (mm, the model's marker order, NaN missing; frame numbers
    ``frames (F,)``, unique) and write the results into ``out_dir`` (see the module doc).

    ``sim``: a :class:`~facesim.fem.equilibrium.FaceSimulator` or a
    :class:`~facesim.inverse.parallel.SimulatorSpec`;
    ``client``: a ``distributed.Client`` solving the chunks in parallel (needs a spec). ``start``:
    controls each chunk starts from (default rest). ``resume``: keep the frames in ``out_dir``
    and solve only the others, each run of them continuing from the saved warm start of the frame
    before it (as an uninterrupted run would); refused when the run in the folder was made with
    other inputs (model, simulator options, jaw model, ``P``, ``frames``, ``neutral``, ``start``,
    ``options``; without ``options.chunk_size`` the run's own chunks are kept). ``overwrite``:
    remove the run in ``out_dir`` first. Without either, a folder holding a run is refused, and so
    is a folder another run is writing into. ``info``: entries recorded in ``run.json`` and
    ``report.json`` as they are (e.g. the input file names); they are not compared on resume.
    ``neutral (r, 3)`` or ``(k, r, 3)``: capture frames of the neutral face (model
    marker order, NaN missing, same coordinates as ``P``; several: the per-marker median after
    stabilisation); the model's markers are first rebound to where it puts
    them (:func:`facesim.mocap.binding.rebind_markers`, Sifakis 2005's binding of the capture to
    the skin). ``fps``: the frame rate (Hz) of ``markers.trc`` with ``options.write_meshes``.
    ``output_frame``: ``"facesim"``, ``"input"`` or an :class:`~facesim.output_frame.OutputFrame`,
    the frame of the ``write_meshes`` skin and marker files (recorded: a resume in another frame
    is refused; ``report.json``'s ``output_frame`` says which).
    Returns the summary (also written to ``report.json``)."""
    options = options or TrackOptions()
    folder = RunFolder(out_dir, "solve-mocap", resume, overwrite)
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
    record = _inputs(local, P, frames, neutral, start)
    frame = resolve_output_frame(model, output_frame, (info or {}).get("model"))
    if options.write_meshes and not frame.is_identity:   # recorded only then: older records still resume
        record["output_frame"] = frame.name
    rebinding = None
    if neutral is not None:
        bound, rebinding = bind_neutral(local, neutral, options.head)
    if options.head == "procrustes":
        P, _ = stabilise(model, P, options.head_smoothing)   # with "solve", the capture stays as it is
    if rebinding is not None:   # after stabilising: the head frame is the model's own rest head markers
        local = bound
    n_workers = len(client.scheduler_info()["workers"]) if client is not None else 1
    with folder:   # one run at a time in the folder, until report.json is written
        chunk = options.chunk_size or (_recorded_chunk(folder.previous) if resume else None) or \
            math.ceil(len(frames) / max(n_workers, 1)) or 1
        # write_meshes is recorded only when on: a run of an older facesim (without it) still resumes
        skip = () if options.write_meshes else ("write_meshes",)
        # the coarse model by its content (as the model), not its path; recorded only when used
        record["options"] = describe(dataclasses.replace(options, chunk_size=chunk),
                                     UNRECORDED + skip + ("coarse_model",))
        if options.coarse_model is not None:
            from facesim.inverse.coarse import coarse_paths
            from facesim.model import load_model

            paths = coarse_paths(options.coarse_model)   # one: recorded as before this could be several
            record["coarse_model"] = parts(load_model(paths[0])) if len(paths) == 1 else \
                [parts(load_model(p)) for p in paths]
        folder.start(record, functools.partial(_holds_a_run, folder.root), functools.partial(_clear, folder.root),
                     info=info)
        return _track(local, spec, client, options, frames, P, folder.root, chunk, start, rebinding, resume, progress,
                      info, n_workers, fps, frame)


def _inputs(sim, P, frames, neutral, start) -> dict:
    """The run record's inputs (:mod:`facesim.runfolder`): what the results depend on, but the
    options (added with the chunk size the run uses)."""
    return {"model": parts(sim.model), "simulator": describe(sim.options),
            "jaw_model": {"name": sim.jaw_model.name, "content": fingerprint(sim.jaw_model)},
            "gain": fingerprint(getattr(sim.muscle, "gain", None)), "markers": fingerprint(P),
            "frames": fingerprint(frames), "neutral": None if neutral is None else fingerprint(np.asarray(neutral)),
            "start": None if start is None else describe(start)}


def _recorded_chunk(record: dict | None) -> int | None:
    chunk = ((record or {}).get("inputs") or {}).get("options", {}).get("chunk_size")
    return chunk if isinstance(chunk, int) and chunk >= 1 else None


def _holds_a_run(out: Path) -> bool:
    return any((folder / f"{name}.csv").exists() for folder in (out, out / CHUNKS) for name in (*LOGS, HEAD_LOG))


def _clear(out: Path) -> None:
    """Remove what a run writes (and nothing else) from the folder ``out``."""
    for name in (*LOGS, HEAD_LOG):
        (out / f"{name}.csv").unlink(missing_ok=True)
    (out / "report.json").unlink(missing_ok=True)
    shutil.rmtree(out / CHUNKS, ignore_errors=True)
    for path in (out / STATE).glob("warm_*.npz"):
        path.unlink()
    from facesim.simulate import clear_frame_files

    clear_frame_files(out)   # what --write-meshes wrote


def _track(local, spec, client, options, frames, P, out: Path, chunk: int, start, rebinding, resume, progress, info,
           n_workers, fps, frame) -> dict:
    """The frames of :func:`track` in a claimed folder."""
    from tqdm import tqdm

    model = local.model
    space = ControlSpace.of(local)
    jaw_names = list(local.jaw_model.param_names)
    headers = {"activations": ["frame", *model.muscles.names], "jaw": ["frame", *jaw_names],
               "residuals": ["frame", "rms", *model.markers.names], "frames": list(LOG_COLUMNS)}
    if options.head == "solve":
        headers[HEAD_LOG] = ["frame", *HEAD_COLUMNS]
    n = len(frames)
    previous, clipped_before = {}, {}
    if resume and (out / "report.json").is_file():
        try:
            old = json.loads((out / "report.json").read_text())
            previous = old.get("outliers", {})
            clipped_before = (old.get("clipped") or {}).get("per_frame", {})
        except (ValueError, AttributeError):
            previous, clipped_before = {}, {}
    outputs = _Outputs(out, headers, frames, resume)
    done = [int(k) in outputs.done for k in frames]
    if options.write_meshes:
        from facesim.simulate import redraw_skin, write_frame, write_marker_files

        for k in outputs.done:   # a skin lost since: drawn again from its state
            redraw_skin(out, model, k, frame)
    runs = _runs(n, chunk, done)
    cold = _Start(start or Controls(np.zeros(model.n_muscles), jaw=_rest_jaw(space)))
    starts, restored = [], 0
    for first, _, warm in runs:
        if not warm:
            starts.append(cold)
            continue
        k = int(frames[first - 1])
        saved = _load_warm(_warm_path(out, k), k, outputs.done[k], space, model, local.jaw_model)
        if saved is None:   # no warm start on disk (a run of an older facesim): the written controls
            starts.append(_Start(outputs.controls(k, space), head_frame=outputs.head_frame(k)))
            continue
        restored += 1
        J = saved.jacobian
        if J is not None and J.tangent_at is not None:
            if client is None:   # factorised again where it was: the same factors as the run had
                J = dataclasses.replace(J, tangent=factorised_tangent(local, *J.tangent_at,
                                                                      linear_solver=options.fit.linear_solver))
            else:                # a factorisation does not travel to a worker (see EquilibriumJacobian)
                J = dataclasses.replace(J, tangent_at=None)
        starts.append(dataclasses.replace(saved, jacobian=J))
    # the warm start each chunk's next frame needs: the saved one before each run; all others go
    last_warm = {(first - 1) // chunk: int(frames[first - 1]) for first, _, warm in runs if warm}
    keep = {_warm_path(out, k) for k in last_warm.values()}
    for path in (out / STATE).glob("warm_*.npz"):
        if path not in keep:
            path.unlink(missing_ok=True)
    summary = {**(info or {}), "frames": n, "reused_frames": int(sum(done)), "chunk_size": chunk,
               "workers": n_workers if client is not None else 0, "loss": options.loss, "rebinding": rebinding,
               "outliers": {k: v for k, v in previous.items() if k.lstrip("-").isdigit() and int(k) in outputs.done},
               "warm_starts_restored": restored, "status": "running",
               "jaw_model_used": _jaw_record(local, spec)}
    if options.write_meshes:
        summary["output_frame"] = {**frame.describe(), "files": "skin/*.ply, markers.csv, markers.trc, markers.c3d; "
                                                                "state/*.npz stay in facesim's frame (mm)"}
    clipped = {k: v for k, v in clipped_before.items() if k.lstrip("-").isdigit() and int(k) in outputs.done}
    t_start = time.perf_counter()
    solved: dict[int, _Solved] = {}
    if client is not None:
        results = solve_on_cluster(client, _solve_frame, spec, space, options, frames, P, runs, starts,
                                   None if rebinding is None else model.markers)
    else:
        results = _solve_here(local, space, options, frames, P, runs, starts)
    try:
        with tqdm(total=n, initial=int(sum(done)), desc="solve-mocap", unit="frame", disable=not progress) as bar:
            for s, handed_on in results:
                k, c = int(frames[s.index]), s.index // chunk
                if s.files is not None:   # before the lines: a written frame has its files
                    write_frame(out, model, k, *s.files, frame=frame)
                _save_warm(_warm_path(out, k), k, handed_on)   # before the lines: a written frame has its warm start
                outputs.add(s.index, s.lines)
                if s.clipped[0] or s.clipped[2]:
                    clipped[str(k)] = list(s.clipped)
                if c in last_warm:
                    _warm_path(out, last_warm[c]).unlink(missing_ok=True)
                last_warm[c] = k
                solved[s.index] = s
                if s.outliers:
                    summary["outliers"][str(k)] = list(s.outliers)
                bar.set_postfix(rms=f"{s.rms:.2f}", steps=s.gn_steps, refresh=False)
                bar.update(1)
        summary["status"] = "complete"
    except BaseException as exc:
        summary["status"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed: {type(exc).__name__}"
        raise
    finally:
        results.close()
        outputs.close()
        failed = summary["status"] != "complete"

        def tidy():
            if outputs.n_merged == n:   # nothing left to resume: the warm starts go
                for path in (out / STATE).glob("warm_*.npz"):
                    path.unlink(missing_ok=True)
                if (out / STATE).is_dir() and not any((out / STATE).iterdir()):
                    (out / STATE).rmdir()

        order = sorted(solved)
        position = {int(k): i for i, k in enumerate(frames)}
        summary.update({
            "solved_frames": len(solved), "written_in_order": outputs.n_merged,
            "seconds": round(time.perf_counter() - t_start, 3),
            "gn_steps": [solved[i].gn_steps for i in order], "marker_rms": [round(solved[i].rms, 4) for i in order],
            "outliers": dict(sorted(summary["outliers"].items(), key=lambda kv: position.get(int(kv[0]), 0))),
            **_stop_summary(outputs, frames),
        })

        summary["clipped"] = _clip_summary(clipped, position)

        def markers():
            if options.write_meshes:
                write_marker_files(out, model, [k for k in map(int, frames) if k in outputs.done], fps, frame)

        def report():
            atomic_write(out / "report.json", lambda tmp: tmp.write_text(json.dumps(summary, indent=2) + "\n"))

        # a failed run reports its own error, not a consequence of it in these writes (a full disk)
        finish((tidy, markers, report), failed)
    return summary


def _jaw_record(sim, spec) -> dict:
    """The jaw model of the written controls, as ``simulate --controls-from`` rebuilds it: its name,
    the spec it was made from (rig files as absolute paths; None for a jaw model given as an
    object) and its content fingerprint."""
    return {"name": sim.jaw_model.name, "spec": spec.jaw_model if spec is not None else
            (sim.jaw_model.name if sim.jaw_model.name in ("rigid", "sliding-condyle", "affine-condyle") else None),
            "content": fingerprint(sim.jaw_model)}


def _clip_summary(per_frame: dict, position: dict) -> dict:
    """``report.json``'s ``clipped``: over the written frames, the values clipped to the bounds
    and the largest clip, of the activations and of the jaw, and ``per_frame`` (frame: activations
    clipped, largest, jaw clipped, largest; frames with a clip only)."""
    rows = list(per_frame.values())

    def total(j):
        return {"values": int(sum(r[j] for r in rows)), "largest": float(max((r[j + 1] for r in rows), default=0.0)),
                "frames": int(sum(r[j] > 0 for r in rows))}

    return {"activations": total(0), "jaw": total(2),
            "per_frame": dict(sorted(per_frame.items(), key=lambda kv: position.get(int(kv[0]), 0)))}


# ------------------------------------------------------------------ warm starts on disk
def _warm_path(out: Path, k: int) -> Path:
    return out / STATE / f"warm_{k:05d}.npz"


def _put_controls(arrays: dict, prefix: str, c: Controls) -> None:
    arrays[f"{prefix}_a"] = c.a
    if c.jaw is not None:
        arrays[f"{prefix}_jaw"] = np.asarray(c.jaw, dtype=np.float64)
    if c.head is not None:
        arrays[f"{prefix}_head"] = c.head


def _get_controls(z, prefix: str) -> Controls:
    def get(name):
        return np.array(z[f"{prefix}_{name}"]) if f"{prefix}_{name}" in z.files else None

    return Controls(get("a"), jaw=get("jaw"), head=get("head"))


def _save_warm(path: Path, k: int, start: _Start) -> None:
    """Write the warm start ``start`` that frame ``k`` hands on (atomically; uncompressed, it is
    written every frame): controls, equilibrium, the Jacobian without its factorised tangent but
    with where that was assembled (``EquilibriumJacobian.tangent_at``)."""
    arrays = {"frame": np.int64(k)}
    _put_controls(arrays, "c", start.controls)
    if start.head_frame is not None:
        arrays["head_frame"] = start.head_frame
    if start.x is not None:
        arrays["x"] = start.x
    J = start.jacobian
    if J is not None:
        _put_controls(arrays, "J", J.controls)
        arrays.update(J_x=J.x, J_dx=J.dx, J_dP=J.dP, J_age=np.int64(J.age), J_nearby=np.bool_(J.nearby))
        if J.tangent is not None and J.tangent_at is not None:
            controls, x, frame = J.tangent_at
            _put_controls(arrays, "T", controls)
            arrays.update(T_x=x, T_frame=np.int64(frame))

    def write(tmp: Path):
        with open(tmp, "wb") as f:   # a file object: numpy adds no ".npz" to the name
            np.savez(f, **arrays)

    atomic_write(path, write)


def _load_warm(path: Path, k: int, lines, space: ControlSpace, model, jaw_model) -> _Start | None:
    """The warm start saved for frame ``k``, or None when the file is missing, unreadable, of
    another frame or shape, or its controls are not those written in the frame's ``lines``."""
    import zipfile

    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["frame"]) != k:
                return None
            controls = _get_controls(z, "c")
            x = np.array(z["x"]) if "x" in z.files else None
            head = np.array(z["head_frame"]) if "head_frame" in z.files else None
            J = at = None
            if "J_a" in z.files:
                if "T_a" in z.files:   # where the tangent was assembled: factorised there again on resume
                    at = (_get_controls(z, "T"), np.array(z["T_x"]), int(z["T_frame"]))
                J = EquilibriumJacobian(space, _get_controls(z, "J"), np.array(z["J_x"]), np.array(z["J_dx"]),
                                        np.array(z["J_dP"]), age=int(z["J_age"]), tangent_at=at,
                                        nearby=bool(z["J_nearby"]) if "J_nearby" in z.files else False)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile, FacesimError):
        return None
    n3 = (model.n_nodes, 3)
    if (controls.a.shape != (model.n_muscles,) or (x is not None and x.shape != n3) or
            (J is not None and (J.x.shape != n3 or J.dx.shape != (3 * model.n_nodes, space.size)
                                or J.dP.shape != (3 * model.n_markers, space.size)))
            or (at is not None and at[1].shape != n3) or (head is not None and head.shape != (4, 4))):
        return None
    a, jaw, _ = _written(controls, space, jaw_model)
    if _control_lines(k, a, jaw, jaw_model) != tuple(lines[:2]):
        return None
    if len(lines) > len(LOGS) and (head is None or _head_line(k, model, head) != lines[len(LOGS)]):
        return None   # a run that solves the head: the saved frame must be the one written
    return _Start(controls, x, J, head)


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
