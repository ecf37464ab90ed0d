"""Forward simulation of a sequence: per-frame activations (and jaw poses) -> equilibria on disk.

Each frame is a quasistatic equilibrium warm-started from the previous converged frame. Results
are written frame by frame into ``OUT/``:

* ``skin/frame_KKKKK.ply`` the skin triangles at the deformed positions (mm);
* ``state/frame_KKKKK.npz`` ``x (n, 3) float64`` node positions (mm), the frame's controls
  ``a (n_muscles,)`` and ``jaw`` (the jaw model's parameters: a 4x4 transform for the rigid jaw,
  (opening, right slide, left slide) for the sliding-condyle jaw), ``converged`` and ``error``
  (the resume warm start);
* ``png/frame_KKKKK.png`` with ``render`` (and ``video.mp4`` or ``video.gif`` with ``video``);
* ``markers.csv`` (``frame,<name>_x,<name>_y,<name>_z``, mm), ``markers.trc`` and ``markers.c3d``;
* ``frames.csv`` the solver log, one row per frame; ``report.json`` the summary.

Skin and markers are written in facesim's frame (mm), or with ``output_frame="input"`` in the
user's input frame and units of an imported model (:mod:`facesim.output_frame`; ``report.json``'s
``output_frame`` says which, the TRC and C3D declare the unit). The state files stay in facesim's
frame: they are the solver's state.

Crash safety: per-frame files are written to a temporary file and renamed; ``frames.csv`` and
``markers.csv`` are append-only logs (:mod:`facesim.framelog`), one complete line per write,
synced to disk. A frame is complete once its state file and both log rows exist (the
``frames.csv`` row is written last); ``resume`` keeps the longest run of complete frames at the
start of the sequence, redraws missing skin or PNG files of those from their state, and computes
the rest, warm-started from the last converged state on disk (the full-precision ``x``), so a
resumed run writes what an uninterrupted one would. A frame that does not converge is kept on disk
for inspection but flagged (``converged`` 0 in ``frames.csv``, listed in ``report.json``), its
markers are written as NaN (missing), and the next frame starts from the last converged one.

Dynamic runs (``SimulateOptions(dynamic=True)``, :mod:`facesim.fem.dynamics`): the first frame is
the quasistatic equilibrium of its controls, at rest; every later frame is ``substeps`` implicit
(BDF2) time steps of ``1 / fps`` s per frame interval, with inertia, Rayleigh damping and the
per-tissue density and stiffness overrides, on the same energy and contact. The files are the same;
the state files also hold the velocities ``v (n, 3)`` mm/s, the previous step's ``x_prev`` and
``v_prev`` and its length ``h_prev`` s, so a resume restarts the integration exactly where it
stopped, and ``frames.csv`` has two more columns, ``substeps`` and ``kinetic_energy_mJ``. The
integration options and ``fps`` are inputs of a dynamic run. A frame whose steps did not all
converge is flagged like a quasistatic one and the integration goes on from it; a step that fails
numerically (non-finite positions, a linear solver failing) restarts the integration at rest from
the frame's quasistatic equilibrium (the frame is flagged, its ``error`` says so).

The folder (:class:`facesim.runfolder.RunFolder`): one run at a time (``OUT/.lock``); a folder
holding a run needs ``resume`` or ``overwrite``; ``OUT/run.json`` records the inputs (model,
activations, jaw, frames, jaw model, solver and contact options, the output frame), and a resume
with other inputs is refused, naming them. Render options (``render``, ``video``, ``view``,
``size``, ``fps``) are not inputs: a resume may add pictures to a finished run.
"""

from __future__ import annotations

import csv
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import facesim
from facesim._files import atomic_write
from facesim.constants import CONTACT_STIFFNESS
from facesim.errors import FacesimError
from facesim.fem.newton import NewtonOptions
from facesim.framelog import FrameLog, csv_line, read_lines
from facesim.model import FaceModel
from facesim.output_frame import FACESIM, output_frame as resolve_output_frame
from facesim.runfolder import RunFolder, describe, fingerprint, finish, parts

FRAME_LOG_COLUMNS = ("frame", "converged", "stop_reason", "iterations", "relative_residual", "residual_N", "seconds",
                     "linear_iterations", "penetration_mm", "lip_penetration_mm", "teeth_penetration_mm",
                     "inverted_tets", "min_J", "error")
DYNAMIC_LOG_COLUMNS = FRAME_LOG_COLUMNS + ("substeps", "kinetic_energy_mJ")
"""``frames.csv`` of a dynamic run: time steps of the frame and kinetic energy at its end (mJ)."""
COLOR_BY = ("none", "displacement", "activation")
_OUTPUT_FILES = ("markers.csv", "markers.trc", "markers.c3d", "frames.csv", "report.json", "video.mp4", "video.gif")
_FRAME_FILE = re.compile(r"frame_\d+\.(ply|npz|png)$")


# ------------------------------------------------------------------ options and paths
@dataclass(frozen=True)
class SimulateOptions:
    """newton : solver options (``linear_solver`` "amg" or "direct"); fps : frame rate of the TRC
    time column and the video (Hz); render : a PNG per frame; video : also a movie of the PNGs
    (implies render); view, size : camera (see :data:`facesim.viz.render.VIEWS`) and pixels;
    color_by : ``"none"``, ``"displacement"`` (skin coloured by |x - X|) or ``"activation"``
    (muscles by the frame's activations) in the renders; teeth_contact, lip_contact, contact_stiffness : contact of the lips with the teeth and with
    each other, penalty stiffness in N/mm^3 (also used for external colliders).

    dynamic : integrate in time (:mod:`facesim.fem.dynamics`) instead of a quasistatic equilibrium
    per frame; ``fps`` is then the physical frame rate. With it: substeps (time steps per frame),
    damping (``(alpha 1/s, beta s)`` or ``"ALPHA,BETA"``), soften (``TISSUE:FACTOR`` specs such as
    ``"nose:0.2"``), density (``TISSUE:VALUE`` t/mm^3), integrator (``"bdf2"`` or ``"euler"``);
    see :class:`~facesim.fem.dynamics.DynamicsOptions`. Ignored without ``dynamic``."""

    newton: NewtonOptions = field(default_factory=NewtonOptions)
    fps: float = 30.0
    render: bool = False
    video: bool = False
    view: str = "front"
    size: tuple[int, int] = (640, 640)
    color_by: str = "none"
    teeth_contact: bool = False
    lip_contact: bool = False
    contact_stiffness: float = CONTACT_STIFFNESS
    dynamic: bool = False
    substeps: int = 2
    damping: tuple = (0.0, 1e-3)
    soften: tuple = ()
    density: tuple = ()
    integrator: str = "bdf2"

    def __post_init__(self):
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise FacesimError(f"fps: expected a frame rate > 0, got {self.fps}")
        dyn = self.dynamics()   # checks the dynamic options and normalises them (specs as pairs)
        for name in ("substeps", "damping", "soften", "density"):
            object.__setattr__(self, name, getattr(dyn, name))
        if self.color_by not in COLOR_BY:
            raise FacesimError(f"color_by: expected one of {', '.join(COLOR_BY)}, got {self.color_by!r}")
        if self.video:
            object.__setattr__(self, "render", True)

    def dynamics(self):
        """The :class:`~facesim.fem.dynamics.DynamicsOptions` of these options."""
        from facesim.fem.dynamics import DynamicsOptions

        return DynamicsOptions(method=self.integrator, substeps=self.substeps, damping=self.damping,
                               density=self.density, soften=self.soften)


class _Out:
    """The files of an output folder."""

    def __init__(self, root):
        self.root = Path(root)
        self.frames_csv = self.root / "frames.csv"
        self.markers_csv = self.root / "markers.csv"
        self.trc = self.root / "markers.trc"
        self.report = self.root / "report.json"

    def skin(self, k: int) -> Path:
        return self.root / "skin" / f"frame_{k:05d}.ply"

    def state(self, k: int) -> Path:
        return self.root / "state" / f"frame_{k:05d}.npz"

    def png(self, k: int) -> Path:
        return self.root / "png" / f"frame_{k:05d}.png"

    def holds_a_run(self) -> bool:
        return self.frames_csv.exists() or self.markers_csv.exists() or any((self.root / "state").glob("frame_*.npz"))

    def clear(self) -> None:
        """Remove what a run writes (and nothing else) from the folder."""
        for name in _OUTPUT_FILES:
            (self.root / name).unlink(missing_ok=True)
        clear_frame_files(self.root)


def _save_state(path: Path, k: int, x, a, jaw, converged: bool, error: str, extra=None) -> None:
    atomic_write(path, lambda tmp: np.savez(tmp, x=np.asarray(x, dtype=np.float64), a=a, jaw=jaw, frame=k,
                                            converged=converged, error=error, **(extra or {})))


def write_frame(out_dir, model: FaceModel, k: int, x, a, jaw, converged: bool, error: str = "", extra=None,
                frame=None) -> None:
    """The files of frame ``k`` as ``simulate`` writes them into ``out_dir`` (also ``solve-mocap
    --write-meshes``): ``state/frame_KKKKK.npz`` (``x (n, 3)`` mm at full precision, ``a
    (n_muscles,)``, ``jaw`` the jaw model's controls, ``frame``, ``converged``, ``error``), then
    ``skin/frame_KKKKK.ply`` (the skin at ``x``; rest positions where ``x`` is not finite, so a
    diverged frame still has its files); ``extra``: more arrays for the state file (a dynamic run's
    velocities and history); ``frame``: the :class:`~facesim.output_frame.OutputFrame` of the skin
    (None: facesim's; the state is always in facesim's). Each file is written atomically."""
    out = _Out(out_dir)
    _save_state(out.state(k), k, x, a, jaw, converged, error, extra)
    _draw(out, model, k, x, SimulateOptions(), png=False, frame=frame)


def frame_state(out_dir, k: int, model: FaceModel) -> tuple[np.ndarray, bool] | None:
    """``(x (n, 3), converged)`` of frame ``k`` in ``out_dir/state``, None without a readable state
    file of the model's shape."""
    import zipfile

    try:
        with np.load(_Out(out_dir).state(k), allow_pickle=False) as z:
            x, converged = np.array(z["x"], dtype=np.float64), bool(z["converged"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    return (x, converged) if x.shape == model.X.shape else None


def redraw_skin(out_dir, model: FaceModel, k: int, frame=None) -> bool:
    """Write frame ``k``'s missing skin PLY from its state file (in the output ``frame``, None:
    facesim's); False when it has neither."""
    out = _Out(out_dir)
    if out.skin(k).is_file():
        return True
    state = frame_state(out_dir, k, model)
    if state is None:
        return False
    _draw(out, model, k, state[0], SimulateOptions(), png=False, frame=frame)
    return True


def write_marker_files(out_dir, model: FaceModel, frames, fps: float, frame=None) -> int:
    """``markers.csv``, ``markers.trc`` (at ``fps`` Hz) and ``markers.c3d`` of ``out_dir`` from the
    state files of ``frames``: the model's markers at each frame's ``x``, NaN for a frame that did
    not converge; frames without a state file are left out. In the output ``frame`` (an
    :class:`~facesim.output_frame.OutputFrame`; None: facesim's, mm), the TRC and C3D declaring its
    unit. Returns the number of frames written."""
    from facesim.caches import write_markers_c3d
    from facesim.mocap.io import write_markers_csv, write_trc

    out = _Out(out_dir)
    rows, P = [], []
    for k in map(int, frames):
        state = frame_state(out_dir, k, model)
        if state is None:
            continue
        x, converged = state
        rows.append(k)
        P.append(model.marker_positions(x) if converged else np.full((model.n_markers, 3), np.nan))
    if rows:
        frame = frame or FACESIM
        P, units = frame.points_mm(np.array(P)), frame.units
        write_markers_csv(out.markers_csv, rows, model.markers.names, P, units)
        write_trc(out.trc, rows, model.markers.names, P, fps, units)
        write_markers_c3d(out.root / "markers.c3d", rows, model.markers.names, P, fps, units)
    return len(rows)


def clear_frame_files(out_dir) -> None:
    """Remove the per-frame files (``skin/``, ``state/``, ``png/`` ``frame_KKKKK.*``) and the marker
    files of a run from ``out_dir``, and nothing else."""
    out = _Out(out_dir)
    for path in (out.markers_csv, out.trc, out.root / "markers.c3d"):
        path.unlink(missing_ok=True)
    for sub in ("skin", "state", "png"):
        folder = out.root / sub
        if folder.is_dir():
            for path in folder.iterdir():
                if _FRAME_FILE.match(path.name):
                    path.unlink()


def _frame_row(k: int, f, seconds: float) -> dict:
    """The ``frames.csv`` row of the :class:`~facesim.session.Frame` ``f`` solved as frame ``k``."""
    report = f.report
    residual = float(report.residuals[-1]) if report is not None and report.residuals else math.nan
    # SolveReport.relative_residual divides by the cold-start force, which is 0 for a frame at rest
    relative = residual / report.force_scale if report is not None and report.force_scale > 0 else math.nan
    reason = "solver_failed" if report is None else report.stop_reason   # Newton's, or "non_finite"
    return {"frame": k, "converged": int(f.converged), "stop_reason": reason, "iterations": 0 if report is None else int(report.iterations),
            "relative_residual": relative, "residual_N": residual, "seconds": seconds,
            "linear_iterations": 0 if report is None else int(sum(report.linear_iterations)),
            **{c: f.measures.get(c, math.nan) for c in _MEASURES}, "inverted_tets": int(f.inverted),
            "min_J": f.min_J, "error": f.error}


_MEASURES = ("penetration_mm", "lip_penetration_mm", "teeth_penetration_mm")
_FORMATS = {"relative_residual": "{:.3e}", "residual_N": "{:.3e}", "seconds": "{:.3f}", "min_J": "{:.4g}",
            **dict.fromkeys(_MEASURES, "{:.4f}"), "kinetic_energy_mJ": "{:.6e}"}


def _row_line(row: dict, columns=FRAME_LOG_COLUMNS) -> str:
    return csv_line([_FORMATS.get(c, "{}").format(row[c]) for c in columns])


def _parse_row(line: str, columns=FRAME_LOG_COLUMNS) -> dict:
    values = next(csv.reader([line]))
    row = dict(zip(columns, values))
    for c in ("frame", "converged", "iterations", "linear_iterations", "inverted_tets", "substeps"):
        if c in row:
            row[c] = int(row[c])
    for c in ("relative_residual", "residual_N", "seconds", "min_J", *_MEASURES, "kinetic_energy_mJ"):
        if c in row:
            row[c] = float(row[c])
    return row


# ------------------------------------------------------------------ the run
def _validate(model: FaceModel, activations, frames, jaw, jaw_model):
    A = np.asarray(activations, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] != model.n_muscles or not len(A):
        raise FacesimError(f"activations: expected shape (frames, {model.n_muscles}), got {A.shape}")
    if not np.isfinite(A).all() or A.min() < 0.0 or A.max() > 1.0:
        raise FacesimError("activations: expected finite values in [0, 1]")
    frames = np.arange(len(A)) if frames is None else np.asarray(frames)
    if frames.shape != (len(A),) or not np.all(frames == np.round(frames)) or frames.min() < 0 or \
            np.any(np.diff(frames) <= 0):
        raise FacesimError(f"frames: expected {len(A)} increasing integer frame numbers >= 0")
    frames = frames.astype(np.int64)
    shape = np.shape(jaw_model.rest)
    what = "4x4 transforms" if not jaw_model.n_params else \
        f"rows of {jaw_model.n_params} {jaw_model.name} jaw parameters"
    if jaw is None:
        J = np.broadcast_to(jaw_model.rest, (len(A), *shape))
    else:
        J = np.asarray(jaw, dtype=np.float64)
        if J.shape != (len(A), *shape) or not np.isfinite(J).all():
            raise FacesimError(f"jaw: expected {len(A)} finite {what}, got shape {J.shape}")
    return A, frames, J


def _complete_frames(out: _Out, frames, A, J, model: FaceModel, mk_header: str, log_header: str):
    """Number of leading frames already complete in ``out`` and their log lines."""
    rows = read_lines(out.frames_csv, log_header)
    marks = read_lines(out.markers_csv, mk_header, 1 + 3 * model.n_markers)
    n = 0
    for i, k in enumerate(frames):
        k = int(k)
        if k not in rows or k not in marks or not out.state(k).is_file():
            break
        try:
            with np.load(out.state(k)) as z:
                same = np.array_equal(z["a"], A[i]) and np.array_equal(z["jaw"], J[i])
        except (OSError, KeyError, ValueError):
            same = False
        if not same:
            break
        n += 1
    done = [int(k) for k in frames[:n]]
    return n, [rows[k] for k in done], [marks[k] for k in done]


def _load_x(out: _Out, k: int, model: FaceModel) -> np.ndarray:
    with np.load(out.state(k)) as z:
        x = np.array(z["x"], dtype=np.float64)
    if x.shape != model.X.shape:
        raise FacesimError(f"{out.state(k)}: positions of shape {x.shape}, the model has {model.X.shape}; "
                           "the folder holds a run of another model")
    return x


def _gain(model: FaceModel, gain) -> np.ndarray | None:
    """``gain`` as ``(n_muscles,)`` float64 of finite values > 0, or None for no gain (None or all 1:
    the muscles as built, the same equilibria)."""
    if gain is None:
        return None
    g = np.array(gain, dtype=np.float64).ravel()
    if g.shape != (model.n_muscles,) or not np.isfinite(g).all() or not (g > 0).all():
        got = f"shape {np.shape(gain)}" if g.shape != (model.n_muscles,) else f"values down to {np.nanmin(g):g}" \
            if np.isfinite(g).all() else "non-finite values"
        raise FacesimError(f"gain: expected {model.n_muscles} finite per-muscle force-length scales > 0, got {got}")
    return None if (g == 1.0).all() else g


def _inputs(model: FaceModel, A, frames, J, jaw_model, setup, gain=None, dynamics=None, fps=None, head=None,
            frame=None) -> dict:
    """The run record's inputs (:mod:`facesim.runfolder`): what the results depend on. The gain
    and the head motion only when there are some, the integration options (with the frame rate)
    only in a dynamic run and the output frame only when it is not facesim's, so the record of a
    quasistatic run without them reads as before."""
    inputs = {"model": parts(model), "activations": fingerprint(A), "frames": fingerprint(frames),
              "jaw": fingerprint(np.ascontiguousarray(J)),
              "jaw_model": {"name": jaw_model.name, "content": fingerprint(jaw_model)}, "simulator": describe(setup)}
    if gain is not None:
        inputs["gain"] = fingerprint(gain)
    if dynamics is not None:
        inputs["dynamics"] = {**describe(dynamics), "fps": fps}
    if head is not None:
        inputs["head"] = fingerprint(np.ascontiguousarray(head))
    if frame is not None and not frame.is_identity:
        inputs["output_frame"] = frame.name
    return inputs


def _draw(out: _Out, model: FaceModel, k: int, x, options: SimulateOptions, caption: str = "",
          skin: bool = True, png: bool = True, colliders=(), a=None, frame=None) -> None:
    """The skin PLY (in the output ``frame``, None: facesim's) and, with ``options.render``, the
    PNG of frame ``k`` at positions ``x`` (with the posed external ``colliders``; ``a``: the
    frame's activations, for ``color_by="activation"``)."""
    from facesim.export import export_skin

    x = np.where(np.isfinite(x), x, model.X)   # a diverged solve must not break the files
    if skin:
        export_skin(model, out.skin(k), x, frame=frame)
    if png and options.render:
        from facesim.viz.render import render_model

        render_model(model, out.png(k), view=options.view, x=x, size=options.size, title=f"frame {k}{caption}",
                     frame_on=model.X, extra=[c.surface() for c in colliders], color_by=options.color_by,
                     a=a if options.color_by == "activation" else None)


def simulate(model: FaceModel, activations, out_dir, *, frames=None, jaw=None, jaw_model="rigid", colliders=(),
             options: SimulateOptions | None = None, resume: bool = False, overwrite: bool = False,
             progress: bool = True, info: dict | None = None, gain=None, head=None,
             output_frame="facesim") -> dict:
    """Simulate a sequence of frames and write the results into ``out_dir`` (see the module doc).

    Parameters
    ----------
    model : FaceModel.
    activations : (F, n_muscles) float64 in [0, 1], one row per frame.
    out_dir : output folder (created if needed).
    frames : (F,) increasing integer frame numbers (default 0..F-1); they name the files.
    jaw : the jaw model's controls per frame, or None for the rest pose: ``(F, 4, 4)`` mandible
        transforms relative to the skull (mm) for the rigid jaw, ``(F, 3)`` (opening rad, right
        slide mm, left slide mm) for ``jaw_model="sliding-condyle"``.
    jaw_model : ``"rigid"``, ``"sliding-condyle"`` or a jaw-model object (see :class:`~facesim.session.Simulation`).
    colliders : external colliders (see :class:`~facesim.session.Simulation`); scripted ones are
        posed at each frame number.
    options : :class:`SimulateOptions`.
    resume : continue a run in ``out_dir`` after its last complete frame (a run of the same inputs:
        another model, other controls, frames or solver options are refused, naming them).
    overwrite : remove the results of an earlier run in ``out_dir`` first. Without ``resume`` or
        ``overwrite`` a folder holding a run is an error, as is a folder another run is writing into.
    progress : tqdm bar over frames on stderr.
    info : extra entries for ``report.json`` (e.g. the input file names).
    gain : ``(n_muscles,)`` per-muscle scale (> 0, dimensionless) of the active force-length curve
        (Sifakis 2005 Fig. 8: exaggeration beyond what activation 1 reaches); None or all 1: the
        muscles as built. Recorded in ``run.json`` (a resume with another gain is refused) and
        ``report.json`` (``gain``: the muscles whose gain is not 1).
    head : ``(F, 4, 4)`` rigid transforms of the skull in the world per frame (mm; the mandible
        moves with it, posed relative to it by ``jaw``), or None for a fixed head: moving Dirichlet
        conditions on the bones (Sifakis 2005 section 9's head shake; what ``solve-mocap --head
        solve`` writes to ``head.csv``). Markers and meshes are written in the world.
    output_frame : ``"facesim"`` (default), ``"input"`` (the input frame and units of an imported
        model) or an :class:`~facesim.output_frame.OutputFrame`: the frame of the skin PLYs and the
        marker files (the state files stay in facesim's). Recorded in ``run.json`` (a resume in
        another frame is refused) and ``report.json`` (``output_frame``).

    With ``options.dynamic`` the frames are integrated in time (see the module doc and
    :mod:`facesim.fem.dynamics`).

    Returns the summary written to ``report.json``: frame counts, converged count, the frames
    that did not converge, seconds, options and output paths.
    """
    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.fem.plausible import check_colliders, check_jaw
    from facesim.kinematics.jaw_models import make_jaw_model
    from facesim.session import Simulation

    options = options or SimulateOptions()
    frame = resolve_output_frame(model, output_frame, (info or {}).get("model"))
    setup = EquilibriumOptions(newton=options.newton, teeth_contact=options.teeth_contact,
                               lip_contact=options.lip_contact, colliders=tuple(colliders),
                               contact_stiffness=options.contact_stiffness)   # checked before anything runs
    jaw_model = make_jaw_model(model, jaw_model)
    A, frames, J = _validate(model, activations, frames, jaw, jaw_model)
    H = _head(head, len(A))
    gain = _gain(model, gain)
    # what no solve could balance is refused before any (facesim.fem.plausible), naming the input
    # files the caller recorded in ``info`` (the CLI's --jaw file, its --collider specs)
    posed = J if jaw is not None else None
    if posed is not None:
        check_jaw(model, jaw_model, frames, posed, (info or {}).get("jaw") or "jaw")
    check_colliders(model, setup.colliders, frames, jaw_model, posed,
                    "--collider" if (info or {}).get("collider_specs") else "colliders")
    dynamics = options.dynamics() if options.dynamic else None
    if dynamics is not None:   # tissue names are checked against the model before anything runs
        from facesim.fem.dynamics import softened_model, tissue_densities

        softened_model(model, dynamics.soften)
        tissue_densities(model, dynamics.density)
    sim = None

    def simulation() -> Simulation:   # built on first use: a run with nothing left to do skips the setup
        nonlocal sim
        if sim is None:
            if dynamics is not None:
                from facesim.fem.dynamics import DynamicSimulator

                sim = DynamicSimulator(model, setup, jaw_model=jaw_model, gain=gain, dynamics=dynamics)
            else:
                sim = Simulation(model, jaw_model, options=setup, gain=gain)
        return sim

    if options.render:
        from facesim.viz.render import VIEWS

        if options.view not in VIEWS:
            raise FacesimError(f"view: unknown view {options.view!r}; expected one of {', '.join(VIEWS)}")
    out = _Out(out_dir)
    folder = RunFolder(out.root, "simulate", resume, overwrite)
    with folder:   # one run at a time in the folder, from here until report.json is written
        folder.start(_inputs(model, A, frames, J, jaw_model, setup, gain, dynamics, options.fps, H, frame),
                     out.holds_a_run,
                     out.clear,
                     info={**(info or {}), "model_fingerprint": fingerprint(model)})
        gains = None if gain is None else {n: float(g) for n, g in zip(model.muscles.names, gain) if g != 1.0}
        return _run(out, model, A, frames, J, jaw is not None, jaw_model, colliders, options, resume, progress,
                    {**(info or {}), "gain": gains, "head_motion": H is not None}, simulation, H, frame)


def _head(head, n: int):
    """``head`` of :func:`simulate` checked: None, or ``(n, 4, 4)`` rigid transforms."""
    if head is None:
        return None
    from facesim import se3

    H = np.asarray(head, dtype=np.float64)
    if H.shape != (n, 4, 4):
        raise FacesimError(f"head: expected {n} 4x4 rigid transforms (one per frame), got shape {H.shape}")
    return se3.check_poses(H, "head")


def _run(out: _Out, model: FaceModel, A, frames, J, posed_jaw: bool, jaw_model, colliders, options: SimulateOptions,
         resume: bool, progress: bool, info: dict | None, simulation, H=None, frame=FACESIM) -> dict:
    """The frames of :func:`simulate` in a claimed folder: the reused ones redrawn where needed, the
    others solved and written; returns the summary."""
    from tqdm import tqdm

    from facesim.controls import Controls
    from facesim.caches import write_markers_c3d
    from facesim.mocap.io import marker_csv_header, marker_csv_line, read_markers_csv, write_trc

    mk_header = marker_csv_header(model.markers.names)
    columns = DYNAMIC_LOG_COLUMNS if options.dynamic else FRAME_LOG_COLUMNS
    log_header = ",".join(columns) + "\n"
    n_done, old_rows, old_marks = (_complete_frames(out, frames, A, J, model, mk_header, log_header) if resume
                                   else (0, [], []))

    wall0 = time.perf_counter()
    summary = {
        "facesim_version": facesim.__version__, "status": "running", **(info or {}),
        "model_fingerprint": fingerprint(model), "n_nodes": model.n_nodes, "n_muscles": model.n_muscles,
        "n_markers": model.n_markers,
        "options": {"solver": options.newton.linear_solver, "rtol": options.newton.rtol,
                    "max_iterations": options.newton.max_iterations, "fps": options.fps, "render": options.render,
                    "video": options.video, "view": options.view, "size": list(options.size), "resume": resume,
                    "jaw_model": jaw_model.name,
                    "teeth_contact": options.teeth_contact, "lip_contact": options.lip_contact,
                    "contact_stiffness": options.contact_stiffness, "colliders": len(colliders),
                    **({"dynamic": {"integrator": options.integrator, "substeps": options.substeps,
                                    "damping": list(options.damping), "soften": dict(options.soften),
                                    "density": dict(options.density)}} if options.dynamic else {})},
        "frames": len(frames), "first_frame": int(frames[0]), "last_frame": int(frames[-1]),
        "resumed_at_frame": int(frames[n_done]) if resume and n_done < len(frames) else None,
        "reused_frames": n_done,
        "output_frame": {**frame.describe(), "files": "skin/*.ply, markers.csv, markers.trc, markers.c3d; state/*.npz "
                                                      "stay in facesim's frame (mm)"},
    }
    atomic_write(out.report, lambda tmp: tmp.write_text(json.dumps(summary, indent=2) + "\n"))

    rows = [_parse_row(line, columns) for line in old_rows]
    # Warm start: the last converged complete frame (a diverged state is a poor starting guess),
    # its positions as solved (the state file holds them at full precision: the same warm start
    # as in an uninterrupted run)
    converged_before = [r["frame"] for r in rows if r["converged"]]
    x_warm = _load_x(out, converged_before[-1], model) if converged_before else None
    # under head motion the warm start is carried along with the head (the previous frame's shape
    # in the new head pose), not left where the head was
    i_warm = int(np.searchsorted(frames, converged_before[-1])) if converged_before else None

    def warm(i):
        if x_warm is None or H is None:
            return x_warm
        M = H[i] @ np.linalg.inv(H[i_warm])
        return x_warm @ M[:3, :3].T + M[:3, 3]
    # a dynamic run goes on from the state of the last complete frame, converged or not (None: the
    # first frame starts at rest from its quasistatic equilibrium)
    jaw_at = (lambda i: J[i]) if posed_jaw else (lambda i: None)
    head_at = (lambda i: H[i]) if H is not None else (lambda i: None)
    state = _load_dynamic_state(out, model, int(frames[n_done - 1]), A[n_done - 1], jaw_at(n_done - 1),
                                head_at(n_done - 1)) if options.dynamic and n_done else None
    for i, k in enumerate(map(int, frames[:n_done])):   # files derived from complete frames' states: redraw missing
        skin, png = not out.skin(k).is_file(), options.render and not out.png(k).is_file()
        if skin or png:
            posed = simulation().posed_colliders(k, Controls(A[i], jaw=jaw_at(i), head=head_at(i))) \
                if png and colliders else ()
            _draw(out, model, k, _load_x(out, k, model), options, skin=skin, png=png, colliders=posed, a=A[i],
                  frame=frame)

    frame_log = FrameLog(out.frames_csv, log_header, old_rows)
    marker_log = FrameLog(out.markers_csv, mk_header, old_marks)
    status = "running"
    try:
        with tqdm(total=len(frames), initial=n_done, desc="simulate", unit="frame", disable=not progress) as bar:
            for i in range(n_done, len(frames)):
                k = int(frames[i])
                t0 = time.perf_counter()
                extra = None
                if options.dynamic:
                    f, state, n_steps = _dynamic_frame(simulation(), state, A[i], jaw_at(i), k, options, head_at(i))
                    extra = {key: v for key, v in state.arrays().items() if key != "x"}
                else:
                    f = simulation().step(A[i], jaw=jaw_at(i), head=head_at(i), frame=k, x0=warm(i))
                x, converged = f.x, f.converged
                seconds = f.seconds if f.report is not None else time.perf_counter() - t0
                write_frame(out.root, model, k, x, A[i], J[i], converged, f.error, extra, frame)
                _draw(out, model, k, x, options, "" if converged else " (not converged)", skin=False,
                      colliders=f.colliders, a=A[i])
                P = model.marker_positions(x) if converged else np.full((model.n_markers, 3), np.nan)
                marker_log.add(marker_csv_line(k, frame.points_mm(P), frame.units))
                row = _frame_row(k, f, seconds)
                if options.dynamic:
                    row.update(substeps=n_steps, kinetic_energy_mJ=simulation().kinetic_energy(state.v))
                frame_log.add(_row_line(row, columns))   # last: the frame is complete once this row is on disk
                rows.append(row)
                if converged:
                    x_warm, i_warm = x, i
                bar.set_postfix(iterations=row["iterations"], converged=converged, refresh=False)
                bar.update(1)
        status = "complete"
    except BaseException as exc:
        status = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed: {type(exc).__name__}"
        raise
    finally:
        frame_log.close()
        marker_log.close()
        summary.update(_summarise(rows, status, time.perf_counter() - wall0, out))
        if options.render:
            summary["outputs"]["png"] = str(out.root / "png")

        def trc():
            if rows:
                data = read_markers_csv(out.markers_csv, frame.units)   # mm, in the output frame's axes
                write_trc(out.trc, data.frames, data.names, data.P, options.fps, frame.units)
                write_markers_c3d(out.root / "markers.c3d", data.frames, data.names, data.P, options.fps, frame.units)

        def video():
            if status == "complete" and options.video:
                from facesim.viz.video import write_video

                path, note = write_video([out.png(int(k)) for k in frames], out.root, options.fps)
                summary["outputs"]["video"] = str(path)
                summary["video_note"] = note

        def report():
            atomic_write(out.report, lambda tmp: tmp.write_text(json.dumps(summary, indent=2) + "\n"))

        # a failed run reports its own error, not a consequence of it in these writes (a full disk)
        finish((trc, video, report), failed=status != "complete")
    return summary


def _load_dynamic_state(out: _Out, model: FaceModel, k: int, a, jaw, head=None):
    """The :class:`~facesim.fem.dynamics.DynamicState` a dynamic run left after frame ``k`` (its
    state file at full precision: the integration goes on exactly as it would have)."""
    from facesim.controls import Controls
    from facesim.fem.dynamics import DynamicState

    _load_x(out, k, model)   # the model's shape
    try:
        with np.load(out.state(k)) as z:
            return DynamicState.from_arrays(z, Controls(a, jaw=jaw, head=head), k)
    except KeyError:
        raise FacesimError(f"{out.state(k)}: no velocities (v, x_prev, v_prev, h_prev): not the state of a dynamic "
                           "run; use --overwrite") from None


def _dynamic_frame(dyn, state, a, jaw, k: int, options: SimulateOptions, head=None):
    """Frame ``k`` of a dynamic run from ``state`` (None: the first frame, the quasistatic
    equilibrium at rest): ``substeps`` time steps per frame interval of ``1 / fps`` s. A step that
    fails numerically restarts at rest from the frame's quasistatic equilibrium, flagged. Returns
    ``(Frame, state, time steps taken)``."""
    from facesim.controls import Controls
    from facesim.errors import SolverError
    from facesim.session import Frame

    controls = Controls(a, jaw=jaw, head=head)
    steps, error = 0, ""
    if state is None:
        state, report, error = dyn.restart(controls, None, k)
        converged = report is not None and report.converged
    else:
        gap = k - state.frame   # frame numbers may skip: the step stays 1 / (fps substeps)
        try:
            steps = options.substeps * int(round(gap))
            state, rep = dyn.advance(state, controls, gap / options.fps, k, substeps=steps)
            report, converged = rep.solve_report(), rep.converged
        except SolverError as exc:
            state, report, error = dyn.restart(controls, state.x, k)
            error = f"dynamic step failed ({' '.join(str(exc).split())}); restarted at rest" + (f"; {error}" if error
                                                                                              else "")
            converged = False
    sim = dyn.sim
    x = state.x
    inverted, min_J = sim.element_quality(x)
    f = Frame(float(k), x, controls, converged, report, sim.posed_colliders(controls, k),
              sim.contact_measures(x, controls, k), inverted, min_J, error, dyn.model)
    return f, state, steps


def _summarise(rows: list[dict], status: str, wall: float, out: _Out) -> dict:
    failed = [r for r in rows if not r["converged"]]
    return {
        "status": status,
        "finished_frames": len(rows),
        "converged": len(rows) - len(failed),
        "unconverged_frames": [r["frame"] for r in failed],
        "unconverged_reasons": {str(r["frame"]): r["stop_reason"] for r in failed},
        "stop_reasons": {c: sum(r["stop_reason"] == c for r in rows) for c in sorted({r["stop_reason"] for r in rows})},
        "errors": {str(r["frame"]): r["error"] for r in failed if r["error"]},
        "newton_iterations": int(sum(r["iterations"] for r in rows)),
        "frames_with_inverted_tets": [r["frame"] for r in rows if r["inverted_tets"] != 0],
        "min_J": float(min((r["min_J"] for r in rows), default=math.nan)),
        **{f"max_{c}": float(np.nanmax([r[c] for r in rows] + [0.0])) for c in _MEASURES},
        **({"time_steps": int(sum(r["substeps"] for r in rows)),
            "max_kinetic_energy_mJ": float(max(r["kinetic_energy_mJ"] for r in rows))}
           if rows and "substeps" in rows[0] else {}),
        "solve_seconds": round(float(sum(r["seconds"] for r in rows)), 3),
        "wall_seconds": round(wall, 3),
        "outputs": {"skin": str(out.root / "skin"), "state": str(out.root / "state"),
                    "markers_csv": str(out.markers_csv), "markers_trc": str(out.trc),
                    "markers_c3d": str(out.root / "markers.c3d"),
                    "frames_csv": str(out.frames_csv)},
    }


__all__ = ["FRAME_LOG_COLUMNS", "SimulateOptions", "clear_frame_files", "frame_state", "redraw_skin", "simulate",
           "write_frame", "write_marker_files"]
