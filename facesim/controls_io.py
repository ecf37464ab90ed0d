"""The controls files of a sequence: activations and jaw per frame, as ``facesim simulate`` reads them
and ``facesim solve-mocap`` writes them.

* activations: header ``frame,<muscle>,...`` (any subset of the model's muscles, in any order; the
  others stay 0), one row per frame, values in [0, 1] (:func:`read_activations_csv`);
* jaw: ``frame,rx,ry,rz,tx,ty,tz`` or ``frame,opening`` for the rigid jaw, ``frame,<parameter>,...``
  for every other jaw model (:func:`read_jaw_csv`);
* a solve-mocap folder's ``activations.csv`` and ``jaw.csv`` read back as the controls of each
  frame (:func:`read_solution`), or, checked against the run's record, as the input of ``simulate
  --controls-from`` (:func:`read_replay`; also the folders ``facesim edit`` writes, in the same
  formats);
* gains: ``muscle,gain``, one row per muscle, the scale (> 0) of its active force-length curve
  (:func:`read_gain_csv`; ``gain.csv`` of a ``facesim edit gain`` folder).

Every error is one line naming the file, the line and the column (:mod:`facesim._csv`): besides
the checks below, frame numbers that are not integers from 0 to 2**53-1 or do not increase, rows
with too few or too many fields (a file cut short), values that are not finite numbers (``inf``,
``1e400``, ``nan``, ``12.`` cut short), duplicate or empty column names, and files that are not
UTF-8 text (binary, UTF-16) are refused.
"""

from __future__ import annotations

import difflib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._csv import frame_numbers, numbers, read_table
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.framelog import read_log
from facesim.model import FaceModel

JAW_FULL = ("rx", "ry", "rz", "tx", "ty", "tz")
JAW_OPENING = ("opening",)
#: the per-muscle gains of a controls folder (:func:`read_gain_csv`); absent: every gain 1
GAIN_FILE = "gain.csv"
#: the commands whose output folders ``simulate --controls-from`` replays (:func:`read_replay`)
REPLAYABLE = ("solve-mocap", "edit")


def _closest(name: str, muscle_names) -> str:
    """The hint of an unknown muscle ``name``: the closest of ``muscle_names``, or the first few."""
    close = difflib.get_close_matches(name, muscle_names, n=3, cutoff=0.5)
    return f"closest: {', '.join(close)}" if close else \
        f"the model's muscles are {', '.join(muscle_names[:6])}{', ...' if len(muscle_names) > 6 else ''}"


def read_activations_csv(path, muscle_names) -> tuple[np.ndarray, np.ndarray]:
    """Read an activations CSV: header ``frame,<muscle>,...``, one row per frame, values in [0, 1].

    Columns may name any subset of ``muscle_names`` in any order; muscles without a column stay
    at 0. Returns ``frames (F,) int64`` (increasing) and ``A (F, n_muscles) float64`` in the order
    of ``muscle_names``. Raises a one-line :class:`FacesimError` naming the file, line and
    column for a missing or empty file, a missing ``frame`` column, an unknown muscle (with the
    closest names), a duplicate column, a value that is not a finite number or is outside [0, 1],
    a bad frame number (see the module). A header of ``frame`` alone is accepted: every muscle
    at rest in each frame (a jaw-only sequence).
    """
    muscle_names = tuple(muscle_names)
    table = read_table(path, "activations file", example="frame," + ",".join(muscle_names[:2]) + ",...")
    columns = table.header[1:]
    for c in columns:
        if c not in muscle_names:
            raise FacesimError(f"{table.path}: line {table.header_line}, column {c!r}: unknown muscle; "
                               f"{_closest(c, muscle_names)}")
    values = numbers(table, columns)
    bad = np.argwhere((values < 0.0) | (values > 1.0))
    if len(bad):
        i, j = bad[0]
        raise FacesimError(f"{table.where(i, columns[j])}: activation {table.rows[i][j + 1]} outside [0, 1]")
    frames = frame_numbers(table)
    A = np.zeros((len(frames), len(muscle_names)))
    A[:, [muscle_names.index(c) for c in columns]] = values
    return frames, A


def read_gain_csv(path, muscle_names) -> np.ndarray:
    """Read a gains CSV: header ``muscle,gain``, one row per muscle, its gain: the scale (> 0,
    dimensionless) of the muscle's active force-length curve (Sifakis 2005 Fig. 8; 1 = as built).

    Returns ``(n_muscles,) float64`` in the order of ``muscle_names``; muscles without a row keep 1.
    One-line :class:`FacesimError` naming the file and line for a missing or empty file, another
    header, an unknown muscle (with the closest names), a muscle listed twice, or a gain that is
    not a finite number > 0.
    """
    muscle_names = tuple(muscle_names)
    table = read_table(path, "gain file", first="muscle", example="muscle,gain")
    if table.header != ("muscle", "gain"):
        raise FacesimError(f"{table.path}: line {table.header_line}: columns {','.join(table.header)}; expected "
                           "'muscle,gain'")
    values = numbers(table, ("gain",))[:, 0]
    gain, seen = np.ones(len(muscle_names)), set()
    for i, row in enumerate(table.rows):
        name = row[0]
        if name not in muscle_names:
            raise FacesimError(f"{table.where(i, 'muscle')}: unknown muscle {name!r}; {_closest(name, muscle_names)}")
        if name in seen:
            raise FacesimError(f"{table.where(i, 'muscle')}: muscle {name!r} again; expected one row per muscle")
        if not values[i] > 0.0:
            raise FacesimError(f"{table.where(i, 'gain')}: gain {row[1]} of {name}; expected a number > 0")
        seen.add(name)
        gain[muscle_names.index(name)] = values[i]
    return gain


def read_jaw_csv(path, model: FaceModel, jaw_model="rigid") -> tuple[np.ndarray, np.ndarray]:
    """Read a jaw CSV and return ``frames (F,) int64`` and the jaw controls of ``jaw_model`` (a
    :class:`~facesim.kinematics.jaw_models.JawModel` or its name): ``(F, 4, 4)`` mandible
    transforms for the rigid jaw, ``(F, n_params)`` parameters for every other jaw model.

    Rigid jaw, two forms: ``frame,rx,ry,rz,tx,ty,tz`` -- a rotation vector (rad) about the condyle
    midpoint ``model.jaw.midpoint``, then a translation (mm); or ``frame,opening`` -- a rotation (rad,
    positive opens the mouth) about the intercondylar axis. Both through
    :meth:`facesim.kinematics.jaw_models.RigidJaw.from_rotation`.
    Any other jaw model: ``frame,<param_names>`` -- for the sliding-condyle jaw
    ``frame,opening,right_slide,left_slide`` (rad, mm, mm; Sifakis 2005 section 8), for a Posselt rig
    ``frame,sx,sy,sz``, for an NLPCA rig ``frame,d1,d2,d3`` -- each value within the model's bounds.
    Columns are matched by name, in any order.
    """
    from facesim.kinematics.jaw_models import RigidJaw, make_jaw_model

    jaw_model = make_jaw_model(model, jaw_model)
    if jaw_model.n_params:
        return _read_parameter_csv(path, jaw_model)
    table = read_table(path, "jaw file", example="frame,rx,ry,rz,tx,ty,tz' or 'frame,opening")
    columns = set(table.header[1:])
    if columns == set(JAW_OPENING):
        opening = numbers(table, JAW_OPENING)[:, 0]
        T = np.array([RigidJaw.from_rotation(model, float(v)) for v in opening])
    elif columns == set(JAW_FULL):
        q = numbers(table, JAW_FULL)
        T = np.array([RigidJaw.from_rotation(model, rotvec=r[:3], translation=r[3:]) for r in q])
    else:
        unknown = sorted(columns - set(JAW_FULL) - set(JAW_OPENING))
        what = f"unknown column {unknown[0]!r}" if unknown else f"columns {','.join(table.header[1:])}"
        raise FacesimError(f"{table.path}: line {table.header_line}: {what}; expected 'frame,rx,ry,rz,tx,ty,tz' "
                           "(rotation vector in rad about the condyle midpoint, translation in mm) or 'frame,opening' "
                           "(rad)")
    return frame_numbers(table), T.reshape(-1, 4, 4)


def _read_parameter_csv(path, jaw) -> tuple[np.ndarray, np.ndarray]:
    """``frame,<jaw.param_names>``: the parameters of a jaw model within its bounds."""
    names = tuple(jaw.param_names)
    table = read_table(path, "jaw file", example="frame," + ",".join(names))
    if set(table.header[1:]) != set(names):
        raise FacesimError(f"{table.path}: line {table.header_line}: columns {','.join(table.header[1:])}; expected "
                           f"'frame,{','.join(names)}' for the {jaw.name} jaw")
    q = numbers(table, names)
    lo, hi = np.asarray(jaw.bounds, dtype=np.float64).T
    tol = 1e-9 + 1e-6 * (hi - lo)
    bad = np.argwhere((q < lo - tol) | (q > hi + tol))
    if len(bad):
        r, c = bad[0]
        raise FacesimError(f"{table.path}: data row {r + 1}, column {names[c]!r}: {q[r, c]:g} outside "
                           f"[{lo[c]:g}, {hi[c]:g}]")
    return frame_numbers(table), np.ascontiguousarray(q)


def check_same_frames(path, frames, reference_path, reference_frames) -> None:
    """One-line error unless ``frames`` (of ``path``) equal ``reference_frames`` (of ``reference_path``)."""
    frames, ref = np.asarray(frames), np.asarray(reference_frames)
    if len(frames) != len(ref):
        raise FacesimError(f"{path}: {len(frames)} frames, but {reference_path} has {len(ref)}; expected the "
                           "same frame column")
    diff = np.flatnonzero(frames != ref)
    if len(diff):
        i = diff[0]
        raise FacesimError(f"{path}: data row {i + 1} is frame {frames[i]}, but {reference_path} has frame {ref[i]} "
                           "there; expected the same frame column")


def read_solution(out_dir, model) -> tuple[np.ndarray, list[Controls]]:
    """Frames ``(k,)`` solved in both ``OUT/activations.csv`` and ``OUT/jaw.csv`` and their controls
    (activations in the model's muscle order, jaw parameters as written; None without any)."""
    out = Path(out_dir)
    header, A = read_log(out / "activations.csv")
    if header[1:] != list(model.muscles.names):
        raise FacesimError(f"{out / 'activations.csv'}: its muscles are not the model's; expected the run made with "
                           "this model")
    _, J = read_log(out / "jaw.csv")
    jaw = {int(r[0]): r[1:] for r in J}
    frames = [int(f) for f in A[:, 0] if int(f) in jaw]
    rows = {int(r[0]): r[1:] for r in A}
    controls = [Controls(np.clip(rows[f], 0.0, 1.0), jaw=jaw[f] if len(jaw[f]) else None) for f in frames]
    return np.array(frames, dtype=np.int64), controls


#: columns of head.csv after ``frame``: the rigid head pose (the model's head frame -> the capture's, mm)
#: and the strain of the frame it was solved as (0 for a pose given rigid)
HEAD_COLUMNS = ("r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22", "tx", "ty", "tz", "strain")


def head_pose(values) -> np.ndarray:
    """The 4x4 pose of one head.csv row's values after ``frame`` (:data:`HEAD_COLUMNS`: R row-major, t)."""
    v = np.asarray(values, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = v[:9].reshape(3, 3), v[9:12]
    return T


def read_head_csv(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a head-motion CSV (``frame,r00,...,r22,tx,ty,tz[,strain]``: :data:`HEAD_COLUMNS`, the
    skull's rigid pose in the world per frame, R row-major then t in mm; what ``solve-mocap --head
    solve`` writes to ``head.csv``). Returns ``frames (F,) int64`` (increasing) and ``H (F, 4, 4)``.
    One-line errors name the file, line and column: a missing column, a value that is not a finite
    number, a rotation that is not one (naming the row). Rotations written with few digits
    (orthonormal within 1e-3) are taken as the nearest rotation."""
    from facesim import se3

    table = read_table(path, "head file", example="frame," + ",".join(HEAD_COLUMNS))
    missing = [c for c in HEAD_COLUMNS[:12] if c not in table.header]
    if missing:
        raise FacesimError(f"{table.path}: line {table.header_line}: column {missing[0]!r} missing; expected "
                           f"'frame,{','.join(HEAD_COLUMNS)}' (strain optional)")
    values = numbers(table, HEAD_COLUMNS[:12])
    H = np.array([head_pose(v) for v in values])
    try:
        se3.check_rigid(H, "head", tolerance=1e-3)
    except FacesimError as exc:
        raise FacesimError(f"{table.path}: {exc}") from None
    loose = se3.rigidity_error(H) > se3.RIGID_TOLERANCE
    if loose.any():                # only those: a file of full-precision rotations reads back as written
        U, _, Vt = np.linalg.svd(H[loose, :3, :3])
        H[loose, :3, :3] = U @ Vt  # det +1: check_rigid refused reflections
    return frame_numbers(table), H


def read_head_poses(out_dir) -> dict[int, np.ndarray]:
    """The head poses ``OUT/head.csv`` of a ``solve-mocap --head solve`` run holds: frame -> 4x4
    rigid transform (the model's head frame -> the capture's); empty when the run did not solve
    the head."""
    path = Path(out_dir) / "head.csv"
    if not path.is_file():
        return {}
    frames, H = read_head_csv(path)
    return {int(k): T for k, T in zip(frames, H)}


@dataclass(frozen=True)
class Replay:
    """The controls of a ``solve-mocap`` folder as ``simulate`` takes them (:func:`read_replay`):
    ``frames (F,) int64``, ``A (F, n_muscles)`` in [0, 1], ``jaw`` the jaw model's controls per frame
    (None for a jaw model without parameters: the jaw at rest), ``jaw_model`` the jaw model the
    solve used; the solve's contact set-up ``teeth_contact``, ``lip_contact``,
    ``contact_stiffness`` (N/mm^3; None: not recorded) and ``n_colliders``; ``rebound``: the solve rebound the markers to
    the capture (``--bind-frames``), so its markers are not the model's own; ``gain (n_muscles,)``
    the per-muscle force-length scale of the folder's ``gain.csv`` (None without one: all 1)."""

    frames: np.ndarray
    A: np.ndarray
    jaw: np.ndarray | None
    jaw_model: object
    teeth_contact: bool
    lip_contact: bool
    contact_stiffness: float | None
    n_colliders: int
    rebound: bool
    gain: np.ndarray | None = None


def read_replay(out_dir, model: FaceModel, model_path=None, where: str | None = None) -> Replay:
    """The controls a ``solve-mocap`` run wrote into ``out_dir``, for ``simulate --controls-from``:
    ``activations.csv``, ``jaw.csv`` read with the jaw model recorded in ``report.json``
    (``jaw_model_used``; a run of an older facesim: ``run.json``'s name of a built-in jaw model), and
    the run's contact set-up from ``run.json``. One-line errors: a folder that holds no
    ``solve-mocap`` run, a run made with another model than ``model`` (naming both fingerprints
    and the parts that differ), a jaw model that cannot be rebuilt or differs from the solve's.
    ``model_path``: where ``model`` was read (for ``posselt``, the model's own rig beside it).
    A folder written by ``facesim edit`` (the same files, :mod:`facesim.anim.sequence`) replays
    too, with its ``gain.csv`` if it has one (``gain``). ``where`` starts the messages (default
    ``--controls-from OUT_DIR``)."""
    from facesim.kinematics.jaw_models import make_jaw_model
    from facesim.runfolder import RUN_RECORD, differences, fingerprint, parts

    out = Path(out_dir)
    where = where or f"--controls-from {out}"
    record = _json(out / RUN_RECORD, where)
    if record.get("command") not in REPLAYABLE:
        raise FacesimError(f"{where}: {out / RUN_RECORD} records a {record.get('command')} run; expected the folder "
                           "of a solve-mocap run (or of facesim edit)")
    inputs = record.get("inputs") or {}
    mine, theirs = parts(model), inputs.get("model") or {}
    if mine != theirs:
        changed = ", ".join(differences(theirs, mine)) or "all"
        name = model_path if model_path is not None else "the model"
        raise FacesimError(f"{where}: solved with another model (fingerprint {fingerprint(theirs)}, {out / RUN_RECORD}) "
                           f"than {name} (fingerprint {fingerprint(mine)}); they differ in {changed}; simulate with "
                           "the model the run was solved with")
    report = _json(out / "report.json", where) if (out / "report.json").is_file() else {}
    used = report.get("jaw_model_used") or {}
    recorded = inputs.get("jaw_model") or {}
    spec = used.get("spec") or (recorded.get("name") if recorded.get("name") in ("rigid", "sliding-condyle", "affine-condyle") else None)
    if spec is None:
        raise FacesimError(f"{where}: {out / 'report.json'} does not say how to rebuild the jaw model "
                           f"{recorded.get('name')!r} of the solve (a run of an older facesim?); simulate with "
                           "--activations and --jaw and that jaw model's --jaw-model")
    jaw_model = make_jaw_model(model, spec, model_path=model_path)
    if recorded.get("content") not in (None, fingerprint(jaw_model)):
        raise FacesimError(f"{where}: the jaw model {spec!r} is not the one the run was solved with (its rig file "
                           "changed since?); simulate with the rig of the solve")
    frames, A = read_activations_csv(out / "activations.csv", model.muscles.names)
    jaw = None
    if jaw_model.n_params:
        jaw_frames, jaw = read_jaw_csv(out / "jaw.csv", model, jaw_model)
        check_same_frames(out / "jaw.csv", jaw_frames, out / "activations.csv", frames)
    setup = inputs.get("simulator") or {}
    colliders = setup.get("colliders") or []
    gain = read_gain_csv(out / GAIN_FILE, model.muscles.names) if (out / GAIN_FILE).is_file() else None
    return Replay(frames, A, jaw, jaw_model, bool(setup.get("teeth_contact")), bool(setup.get("lip_contact")),
                  float(setup.get("contact_stiffness") or 0.0) or None, len(colliders),
                  inputs.get("neutral") is not None, gain)


def _json(path: Path, where: str) -> dict:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FacesimError(f"{where}: no {path.name} in the folder; expected the output folder of a solve-mocap "
                           "run") from None
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise FacesimError(f"{where}: {path} is not readable ({type(exc).__name__}); expected the record of a "
                           "solve-mocap run") from None
    if not isinstance(value, dict):
        raise FacesimError(f"{where}: {path} is not a run record (a JSON object)")
    return value


__all__ = ["GAIN_FILE", "JAW_FULL", "JAW_OPENING", "REPLAYABLE", "Replay", "check_same_frames", "read_activations_csv",
           "read_gain_csv", "read_jaw_csv", "read_replay", "read_solution"]
