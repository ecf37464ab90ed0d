"""A performance as controls per frame: :class:`ControlsSequence`, read from and written to the
files ``facesim solve-mocap`` writes, so that ``solve-mocap -> edit -> simulate --controls-from``
is a pipeline.

A sequence holds, per frame ``k`` of ``frames (F,)``: the activations ``A[k] (m,)`` in [0, 1] of the
model's ``muscles``, the jaw controls ``jaw[k]`` in the jaw model's own parameters (``(F,
n_params)``; for the rigid jaw, which has no parameters, ``(F, 4, 4)`` mandible poses relative to
the skull in mm, or None: at rest), and optionally the head pose ``head[k] (4, 4)`` (the model's
head frame -> the capture's, mm, from ``solve-mocap --head solve``). Per sequence: the frame rate
``fps`` (Hz), the per-muscle ``gain (m,)`` (the scale of each muscle's active force-length curve,
Sifakis 2005 Fig. 8; 1 = as built), the jaw model (:class:`JawSpec`, as ``report.json``'s
``jaw_model_used`` records it), the model the controls are for (``model_parts``, the fingerprints of
:func:`facesim.runfolder.parts`) and the contact set-up they were solved with (``setup``, the
solve's ``run.json`` ``inputs.simulator``; "" when not known, e.g. a hand-written CSV).

Folder files (:func:`write_sequence`, read by :func:`read_sequence`, by ``simulate --controls-from``
through :func:`facesim.controls_io.read_replay`, and by every tool reading solve-mocap folders):

* ``activations.csv`` ``frame,<muscle>,...`` (every muscle, the model's order);
* ``jaw.csv`` ``frame,<jaw parameter>,...`` (:func:`facesim.controls_io.read_jaw_csv`); for the
  rigid jaw ``frame`` alone (at rest, as solve-mocap writes it) or ``frame,rx,ry,rz,tx,ty,tz``
  (rotation vector rad about the condyle midpoint, translation mm: ``simulate --jaw OUT/jaw.csv``
  reads it; ``simulate --controls-from`` does not, it keeps a rigid jaw at rest);
* ``head.csv`` ``frame,r00,...,r22,tx,ty,tz,strain`` when the sequence has head poses (strain 0:
  edited poses are rigid);
* ``gain.csv`` ``muscle,gain`` when a gain is not 1 (:func:`facesim.controls_io.read_gain_csv`);
* ``report.json``: ``jaw_model_used`` (name, spec, content), ``fps``, the frame range, the gains
  and what was done (``edit``); ``run.json``: the record ``simulate --controls-from`` checks (the
  model's fingerprints, the jaw model, the contact set-up) with ``command`` "edit".

Values are written with all the digits of a float64 (``repr``), so a sequence read back is the one
written, bit for bit (rigid jaw poses: to ~1e-15, through the rotation vector).
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim import se3
from facesim._files import atomic_write
from facesim.controls_io import HEAD_COLUMNS
from facesim.errors import FacesimError
from facesim.framelog import csv_line

#: the files of a controls folder that :func:`write_sequence` writes (and an overwrite removes)
FILES = ("activations.csv", "jaw.csv", "head.csv", "gain.csv", "report.json")
#: the folder ``facesim edit --simulate`` simulates into, inside the output folder
SIM_FOLDER = "sim"
#: frame rate assumed for sources that do not record one (solve-mocap folders, CSV files), Hz
DEFAULT_FPS = 30.0


# ------------------------------------------------------------------ the jaw model of a sequence
@dataclass(frozen=True, eq=False)
class JawSpec:
    """The jaw model a sequence's jaw controls are for: ``name`` (:attr:`JawModel.name`), ``spec``
    (what :func:`~facesim.kinematics.jaw_models.make_jaw_model` rebuilds it from: ``"rigid"``,
    ``"sliding-condyle"``, ``"posselt:RIG.npz"``, ...; None for a jaw model given as an object),
    ``content`` (its :func:`~facesim.runfolder.fingerprint`), and, to edit without rebuilding it,
    ``param_names``, ``bounds (n_params, 2)`` and ``rest (n_params,)``. Two are the same jaw model
    when name and content agree."""

    name: str
    spec: str | None
    content: str
    param_names: tuple[str, ...]
    bounds: np.ndarray
    rest: np.ndarray

    @staticmethod
    def of(jaw_model, spec: str | None = None) -> "JawSpec":
        """The spec of a :class:`~facesim.kinematics.jaw_models.JawModel` made from ``spec``
        (default: its name for the built-in jaw models, else None)."""
        from facesim.runfolder import fingerprint

        if spec is None and jaw_model.name in ("rigid", "sliding-condyle", "affine-condyle"):
            spec = jaw_model.name
        names = tuple(jaw_model.param_names)
        bounds = np.array(jaw_model.bounds, dtype=np.float64).reshape(len(names), 2)
        rest = np.array(jaw_model.rest, dtype=np.float64).reshape(-1) if names else np.zeros(0)
        for a in (bounds, rest):
            a.setflags(write=False)
        return JawSpec(jaw_model.name, spec, fingerprint(jaw_model), names, bounds, rest)

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def posed(self) -> bool:
        """Whether the controls are 4x4 poses (the rigid jaw, without parameters)."""
        return not self.param_names

    def record(self) -> dict:
        """``report.json``'s ``jaw_model_used``."""
        return {"name": self.name, "spec": self.spec, "content": self.content}

    def build(self, model, model_path=None):
        """The jaw model, rebuilt from ``spec`` for ``model`` (``model_path``: where the model was read,
        for the model's own Posselt rig); one-line error when it cannot be, or is another one now."""
        from facesim.kinematics.jaw_models import make_jaw_model
        from facesim.runfolder import fingerprint

        if self.spec is None:
            raise FacesimError(f"jaw model {self.name!r}: not recorded how to rebuild it (a jaw model given as an "
                               "object); give the jaw model itself")
        jaw_model = make_jaw_model(model, self.spec, model_path=model_path)
        if fingerprint(jaw_model) != self.content:
            raise FacesimError(f"jaw model {self.spec!r}: not the one the controls are for (its rig file changed "
                               "since?)")
        return jaw_model

    def __eq__(self, other) -> bool:
        return isinstance(other, JawSpec) and (self.name, self.content) == (other.name, other.content)

    __hash__ = None


# ------------------------------------------------------------------ the sequence
def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ControlsSequence:
    """Controls per frame (module doc). Fields:

    frames : (F,) int64, increasing frame numbers >= 0, F >= 1.
    fps : frame rate, Hz (> 0).
    muscles : (m,) muscle names, the model's order.
    A : (F, m) float64 activations in [0, 1].
    jaw_model : :class:`JawSpec`.
    jaw : (F, n_params) jaw parameters within ``jaw_model.bounds`` (None: at rest, filled in), or
        for the rigid jaw (F, 4, 4) mandible poses relative to the skull, mm (None: at rest).
    head : (F, 4, 4) rigid head poses, mm, or None.
    gain : (m,) per-muscle force-length scale > 0 (default ones).
    model_parts : ((field, fingerprint), ...) of the model (:func:`facesim.runfolder.parts`).
    setup : the contact set-up the controls were solved with, JSON text ("" not known).
    rebound : the solve rebound the markers to its capture (``--bind-frames``).

    Construct with :meth:`of` from a model; operations (:mod:`facesim.anim.edits`) return new
    sequences. Equal (``==``) when every field is equal, arrays bit for bit.
    """

    frames: np.ndarray
    fps: float
    muscles: tuple[str, ...]
    A: np.ndarray
    jaw_model: JawSpec
    jaw: np.ndarray | None = None
    head: np.ndarray | None = None
    gain: np.ndarray | None = None
    model_parts: tuple = ()
    setup: str = ""
    rebound: bool = False

    def __post_init__(self):
        frames = np.asarray(self.frames)
        if frames.ndim != 1 or not len(frames) or frames.dtype.kind not in "iuf" or \
                not np.all(frames == np.round(frames)) or frames.min() < 0 or np.any(np.diff(frames) <= 0):
            raise FacesimError(f"frames: expected at least one increasing integer frame number >= 0, got "
                               f"{np.shape(frames)} values")
        frames = np.array(frames, dtype=np.int64)
        frames.setflags(write=False)
        F = len(frames)
        fps = float(self.fps)
        if not (math.isfinite(fps) and fps > 0):
            raise FacesimError(f"fps: expected a frame rate > 0 Hz, got {self.fps}")
        muscles = tuple(str(n) for n in self.muscles)
        if len(set(muscles)) != len(muscles):
            raise FacesimError("muscles: expected unique muscle names")
        A = _frozen(self.A)
        if A.shape != (F, len(muscles)) or not np.isfinite(A).all() or A.min(initial=0) < 0 or A.max(initial=0) > 1:
            raise FacesimError(f"activations: expected ({F}, {len(muscles)}) finite values in [0, 1], got shape "
                               f"{A.shape}")
        if not isinstance(self.jaw_model, JawSpec):
            raise FacesimError(f"jaw_model: expected a JawSpec, got {type(self.jaw_model).__name__}")
        jm = self.jaw_model
        jaw = self.jaw
        if jm.posed:
            if jaw is not None:
                jaw = _frozen(se3.check_poses(jaw, "jaw: rigid jaw poses"))
                if len(jaw) != F:
                    raise FacesimError(f"jaw: expected {F} rigid jaw poses, got {len(jaw)}")
        else:
            jaw = np.broadcast_to(jm.rest, (F, jm.n_params)) if jaw is None else jaw
            jaw = _frozen(jaw)
            lo, hi = jm.bounds.T
            tol = 1e-9 + 1e-6 * (hi - lo)
            if jaw.shape != (F, jm.n_params) or not np.isfinite(jaw).all():
                raise FacesimError(f"jaw: expected ({F}, {jm.n_params}) finite {jm.name} parameters "
                                   f"({','.join(jm.param_names)}), got shape {jaw.shape}")
            bad = np.argwhere((jaw < lo - tol) | (jaw > hi + tol))
            if len(bad):
                r, c = bad[0]
                raise FacesimError(f"jaw: frame {frames[r]}, {jm.param_names[c]} = {jaw[r, c]:g} outside "
                                   f"[{lo[c]:g}, {hi[c]:g}]")
        head = self.head
        if head is not None:
            head = _frozen(se3.check_poses(head, "head: head poses"))
            if len(head) != F:
                raise FacesimError(f"head: expected {F} head poses, got {len(head)}")
        gain = np.ones(len(muscles)) if self.gain is None else np.asarray(self.gain, dtype=np.float64).ravel()
        if gain.shape != (len(muscles),) or not np.isfinite(gain).all() or not (gain > 0).all():
            raise FacesimError(f"gain: expected {len(muscles)} finite per-muscle force-length scales > 0")
        checked = {"frames": frames, "fps": fps, "muscles": muscles, "A": A, "jaw": jaw, "head": head,
                   "gain": _frozen(gain), "model_parts": tuple(map(tuple, self.model_parts)),
                   "setup": str(self.setup or ""), "rebound": bool(self.rebound)}
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    # -------------------------------------------------------------- construction
    @staticmethod
    def of(model, A, frames=None, fps: float = DEFAULT_FPS, jaw=None, jaw_model="rigid", head=None, gain=None,
           model_path=None) -> "ControlsSequence":
        """A sequence of ``model``'s controls: ``A (F, n_muscles)`` in [0, 1], ``frames (F,)`` (default
        0..F-1), ``fps`` Hz, ``jaw`` in ``jaw_model`` (a name or a
        :class:`~facesim.kinematics.jaw_models.JawModel`; ``model_path`` for ``"posselt"``), ``head
        (F, 4, 4)`` mm, ``gain (n_muscles,)``."""
        from facesim.kinematics.jaw_models import make_jaw_model
        from facesim.runfolder import parts

        A = np.asarray(A, dtype=np.float64)
        frames = np.arange(len(A)) if frames is None else frames
        spec = jaw_model if isinstance(jaw_model, str) else None
        jm = make_jaw_model(model, jaw_model, model_path=model_path)
        return ControlsSequence(frames, fps, model.muscles.names, A, JawSpec.of(jm, spec), jaw, head, gain,
                                tuple(parts(model).items()))

    def replace(self, **changes) -> "ControlsSequence":
        """A copy with ``changes`` (checked again)."""
        return dataclasses.replace(self, **changes)

    # -------------------------------------------------------------- views
    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def n_muscles(self) -> int:
        return len(self.muscles)

    @property
    def times(self) -> np.ndarray:
        """``(F,)`` time of each frame, s (frame number / fps)."""
        return self.frames / self.fps

    def rows(self, index) -> "ControlsSequence":
        """The frames at the row positions ``index`` (a slice or integer array)."""
        pick = np.arange(self.n_frames)[index]
        if not len(pick):
            raise FacesimError("frames: the selection is empty")
        return self.replace(frames=self.frames[pick], A=self.A[pick],
                            jaw=None if self.jaw is None else self.jaw[pick],
                            head=None if self.head is None else self.head[pick])

    def at(self, frame: int) -> "ControlsSequence":
        """The one frame numbered ``frame`` (an expression), as a sequence of one frame."""
        hit = np.flatnonzero(self.frames == int(frame))
        if not len(hit):
            raise FacesimError(f"frame {frame}: not in the sequence (frames {self.frames[0]}..{self.frames[-1]}, "
                               f"{self.n_frames} of them)")
        return self.rows(hit)

    def segment(self, first: int, last: int) -> "ControlsSequence":
        """The frames numbered ``first`` to ``last`` (inclusive)."""
        keep = np.flatnonzero((self.frames >= first) & (self.frames <= last))
        if not len(keep):
            raise FacesimError(f"frames {first}:{last}: no frame of the sequence in this range (its frames are "
                               f"{self.frames[0]}..{self.frames[-1]})")
        return self.rows(keep)

    def jaw_controls(self, i: int):
        """The jaw controls of row ``i`` as a simulator takes them (None: the rigid jaw at rest)."""
        return None if self.jaw is None else np.array(self.jaw[i])

    def __eq__(self, other) -> bool:
        if not isinstance(other, ControlsSequence):
            return NotImplemented

        def same(a, b):
            if a is None or b is None:
                return a is b
            return np.array_equal(a, b)

        return (np.array_equal(self.frames, other.frames) and self.fps == other.fps
                and self.muscles == other.muscles and same(self.A, other.A) and self.jaw_model == other.jaw_model
                and same(self.jaw, other.jaw) and same(self.head, other.head) and same(self.gain, other.gain)
                and self.model_parts == other.model_parts and self.setup == other.setup
                and self.rebound == other.rebound)

    __hash__ = None


# ------------------------------------------------------------------ reading
def _check_model(seq_muscles, model, where: str) -> None:
    if tuple(seq_muscles) != tuple(model.muscles.names):
        raise FacesimError(f"{where}: its muscles are not the model's; expected controls of this model")


def read_sequence(path, model, *, jaw=None, jaw_model=None, fps: float | None = None,
                  model_path=None) -> ControlsSequence:
    """Read the controls at ``path`` for ``model``:

    * a folder written by ``facesim solve-mocap`` or ``facesim edit``: ``activations.csv``,
      ``jaw.csv`` in the jaw model of ``report.json``'s ``jaw_model_used``, ``head.csv`` and
      ``gain.csv`` when present, checked against the run's ``run.json`` (the same model; see
      :func:`facesim.controls_io.read_replay`); its contact set-up is kept (``setup``);
    * an activations CSV (``frame,<muscle>,...``), with ``jaw`` a jaw CSV of the same frames in
      ``jaw_model`` (a name, default ``"rigid"``; without ``jaw``: at rest).

    ``fps`` : the frame rate, Hz, when the source does not record one (a folder written by ``facesim
    edit`` does; solve-mocap folders and CSV files do not: default 30). ``model_path``: where the
    model was read (for ``"posselt"``, the model's own rig). One-line :class:`FacesimError` for a
    missing or empty folder, a folder without ``activations.csv``, controls of another model, and
    every malformed file (naming file, line and column).
    """
    from facesim.controls_io import check_same_frames, read_activations_csv, read_jaw_csv
    from facesim.kinematics.jaw_models import make_jaw_model
    from facesim.runfolder import parts

    path = Path(path)
    if not path.exists():
        raise FacesimError(f"{path}: no such folder or file; expected a solve-mocap (or facesim edit) output folder "
                           "or an activations CSV")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise FacesimError(f"fps: expected a frame rate > 0 Hz, got {fps}")
    model_parts = tuple(parts(model).items())
    if path.is_file():
        frames, A = read_activations_csv(path, model.muscles.names)
        jm = make_jaw_model(model, jaw_model or "rigid", model_path=model_path)
        J = None
        if jaw is not None:
            jaw_frames, J = read_jaw_csv(jaw, model, jm)
            check_same_frames(jaw, jaw_frames, path, frames)
        spec = JawSpec.of(jm, jaw_model if isinstance(jaw_model, str) else "rigid" if jaw_model is None else None)
        return ControlsSequence(frames, fps or DEFAULT_FPS, model.muscles.names, A, spec, J, None, None, model_parts)
    if jaw is not None or jaw_model is not None:
        raise FacesimError(f"{path}: a folder records its jaw model and jaw.csv; the jaw CSV and jaw model options "
                           "are for an activations CSV")
    if not (path / "activations.csv").is_file():
        what = "an empty folder" if not any(path.iterdir()) else "no activations.csv in the folder"
        raise FacesimError(f"{path}: {what}; expected a solve-mocap (or facesim edit) output folder or an "
                           "activations CSV")
    return _read_folder(path, model, fps, model_path, model_parts)


def _read_folder(path: Path, model, fps, model_path, model_parts) -> ControlsSequence:
    from facesim.controls_io import check_same_frames, read_jaw_csv, read_replay
    from facesim.runfolder import RUN_RECORD

    r = read_replay(path, model, model_path, where=str(path))
    record = json.loads((path / RUN_RECORD).read_text(encoding="utf-8"))   # read_replay read it already
    report = _report(path)
    spec = (report.get("jaw_model_used") or {}).get("spec") or r.jaw_model.name
    jaw = r.jaw
    if not r.jaw_model.n_params and _header(path / "jaw.csv")[1:]:   # rigid poses, as facesim edit writes them
        jaw_frames, jaw = read_jaw_csv(path / "jaw.csv", model, r.jaw_model)
        check_same_frames(path / "jaw.csv", jaw_frames, path / "activations.csv", r.frames)
    head = _read_head(path, r.frames)
    recorded = report.get("fps", (report.get("options") or {}).get("fps")) if fps is None else fps
    rate = float(recorded) if isinstance(recorded, (int, float)) and math.isfinite(recorded) and recorded > 0 \
        else DEFAULT_FPS
    setup = (record.get("inputs") or {}).get("simulator") or {}
    return ControlsSequence(r.frames, rate, model.muscles.names, r.A, JawSpec.of(r.jaw_model, spec), jaw, head,
                            r.gain, model_parts, json.dumps(setup, sort_keys=True) if setup else "", r.rebound)


def _report(path: Path) -> dict:
    try:
        report = json.loads((path / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return {}
    return report if isinstance(report, dict) else {}


def _header(path: Path) -> list[str]:
    """The header fields of a CSV file (none for a missing or empty file)."""
    import csv

    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            return next(csv.reader(fh), [])
    except (OSError, UnicodeDecodeError):
        return []


def _read_head(path: Path, frames) -> np.ndarray | None:
    """The head poses of ``frames`` in ``path/head.csv`` (None without the file); every frame needs one."""
    from facesim.controls_io import read_head_poses

    poses = read_head_poses(path)
    if not poses:
        return None
    missing = [int(k) for k in frames if int(k) not in poses]
    if missing:
        raise FacesimError(f"{path / 'head.csv'}: no head pose for frame {missing[0]} ({len(missing)} frames without "
                           "one); expected a row for every frame of activations.csv")
    H = np.array([poses[int(k)] for k in frames])
    return se3.check_poses(H, f"{path / 'head.csv'}")


# ------------------------------------------------------------------ writing
def _number(v: float) -> str:
    """All the digits of a float64 (the shortest text that reads back to the same number)."""
    v = float(v) + 0.0   # no '-0'
    return repr(v)


def _rigid_columns(model, T) -> np.ndarray:
    """``(F, 6)`` rotation vectors (rad) about the condyle midpoint and translations (mm) of the
    rigid jaw poses ``T (F, 4, 4)``: the inverse of
    :meth:`facesim.kinematics.jaw_models.RigidJaw.from_rotation` (``frame,rx,ry,rz,tx,ty,tz``)."""
    c = np.asarray(model.jaw.midpoint, dtype=np.float64)
    R = T[:, :3, :3]
    translation = T[:, :3, 3] - (c - R @ c)
    return np.concatenate([se3.so3_log(R), translation], axis=1)


def inputs_record(seq: ControlsSequence) -> dict:
    """The ``inputs`` of a controls folder's ``run.json``: what ``simulate --controls-from`` checks
    (the model's fingerprints, the jaw model, the contact set-up, whether the markers were rebound)
    and the fingerprint of the controls themselves."""
    from facesim.runfolder import fingerprint

    return {"model": dict(seq.model_parts), "jaw_model": {"name": seq.jaw_model.name, "content": seq.jaw_model.content},
            "simulator": json.loads(seq.setup) if seq.setup else {}, "neutral": "rebound" if seq.rebound else None,
            "controls": fingerprint((seq.frames, seq.fps, seq.muscles, seq.A, seq.jaw, seq.head, seq.gain))}


def write_sequence(folder, seq: ControlsSequence, model=None, *, overwrite: bool = False, resume: bool = False,
                   info: dict | None = None) -> Path:
    """Write ``seq`` into ``folder`` in the formats ``solve-mocap`` writes (module doc); returns the
    folder.

    ``model`` : the model of the controls; needed only for a rigid jaw with poses (their rotation
    vectors are about its condyle midpoint) and checked against ``seq`` when given. ``info`` :
    what the sequence is (recorded in ``report.json`` as ``edit`` and in ``run.json``).
    A folder that is not empty is refused unless ``overwrite`` (the files an edit writes, and
    ``sim/`` of ``--simulate``, are removed first; other files stay) or ``resume`` (the same
    controls again: refused, naming what differs, when they are not). One run at a time:
    :class:`facesim.runfolder.RunFolder`.
    """
    import facesim
    from facesim.runfolder import LOCK, RunFolder, parts

    folder = Path(folder)
    if model is not None:
        _check_model(seq.muscles, model, str(folder))
        if not seq.model_parts:   # a sequence made without its model: it is this one's
            seq = seq.replace(model_parts=tuple(parts(model).items()))
        if dict(seq.model_parts) != parts(model):
            raise FacesimError(f"{folder}: the controls are for another model than the one given")
    if seq.jaw_model.posed and seq.jaw is not None and model is None:
        raise FacesimError(f"{folder}: writing rigid jaw poses needs the model (their rotation is about its condyle "
                           "midpoint)")
    run = RunFolder(folder, "edit", resume, overwrite)
    inputs = inputs_record(seq)

    def holds_a_run() -> bool:
        return any(p.name != LOCK for p in folder.iterdir())

    def clear() -> None:
        for name in FILES:
            (folder / name).unlink(missing_ok=True)
        sim = folder / SIM_FOLDER
        if sim.is_dir() and _is_simulate_run(sim):
            shutil.rmtree(sim)

    if folder.is_dir() and any(folder.iterdir()) and not (overwrite or resume):
        raise FacesimError(f"{folder}: not empty; use --overwrite to replace what an edit wrote there (other files "
                           "stay), or another folder")
    with run:
        run.start(inputs, holds_a_run, clear, info={"edit": info or {}})
        muscles = ["frame", *seq.muscles]
        _write_csv(folder / "activations.csv", muscles, seq.frames, seq.A)
        jm = seq.jaw_model
        if jm.posed:
            if seq.jaw is None:
                _write_csv(folder / "jaw.csv", ["frame"], seq.frames, np.zeros((seq.n_frames, 0)))
            else:
                _write_csv(folder / "jaw.csv", ["frame", "rx", "ry", "rz", "tx", "ty", "tz"], seq.frames,
                           _rigid_columns(model, seq.jaw))
        else:
            _write_csv(folder / "jaw.csv", ["frame", *jm.param_names], seq.frames, seq.jaw)
        if seq.head is not None:
            H = seq.head
            values = np.concatenate([H[:, :3, :3].reshape(-1, 9), H[:, :3, 3], np.zeros((seq.n_frames, 1))], axis=1)
            _write_csv(folder / "head.csv", ["frame", *HEAD_COLUMNS], seq.frames, values)
        else:
            (folder / "head.csv").unlink(missing_ok=True)
        if (seq.gain != 1.0).any():
            text = "muscle,gain\n" + "".join(csv_line([n, _number(g)]) for n, g in zip(seq.muscles, seq.gain))
            atomic_write(folder / "gain.csv", lambda tmp: tmp.write_text(text, encoding="utf-8"))
        else:
            (folder / "gain.csv").unlink(missing_ok=True)
        report = {"command": "edit", "facesim_version": facesim.__version__, "edit": info or {},
                  "frames": seq.n_frames, "first_frame": int(seq.frames[0]), "last_frame": int(seq.frames[-1]),
                  "fps": seq.fps, "jaw_model_used": jm.record(), "head": seq.head is not None,
                  "gain": {n: float(g) for n, g in zip(seq.muscles, seq.gain) if g != 1.0},
                  "contact": _contact_summary(seq.setup), "rebound": seq.rebound}
        atomic_write(folder / "report.json", lambda tmp: tmp.write_text(json.dumps(report, indent=2) + "\n"))
    return folder


def _contact_summary(setup: str) -> dict | None:
    """The contact part of a recorded set-up, for ``report.json`` (None: not recorded)."""
    if not setup:
        return None
    d = json.loads(setup)
    return {"teeth_contact": bool(d.get("teeth_contact")), "lip_contact": bool(d.get("lip_contact")),
            "contact_stiffness": d.get("contact_stiffness"), "colliders": len(d.get("colliders") or [])}


def _is_simulate_run(folder: Path) -> bool:
    try:
        return json.loads((folder / "run.json").read_text(encoding="utf-8")).get("command") == "simulate"
    except (OSError, ValueError, AttributeError):
        return False


def _write_csv(path: Path, header, frames, values) -> None:
    text = csv_line(header) + "".join(csv_line([int(k), *map(_number, row)]) for k, row in zip(frames, values))
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def muscle_indices(seq: ControlsSequence, muscles) -> np.ndarray:
    """Indices of ``muscles`` (names of ``seq.muscles``, or base names for both sides:
    ``zygomaticus_major`` is ``zygomaticus_major_L`` and ``_R``) in ``seq``; None: all. One-line
    error for an unknown name (with the closest) or an empty list."""
    if muscles is None:
        return np.arange(seq.n_muscles)
    if isinstance(muscles, str):
        muscles = [muscles]
    picked = []
    for key in muscles:
        hits = [i for i, n in enumerate(seq.muscles) if n == key or (n.rsplit("_", 1)[0] == key and
                                                                     n.rsplit("_", 1)[-1] in ("L", "R"))]
        if not hits:
            close = difflib.get_close_matches(key, seq.muscles, n=3, cutoff=0.5)
            hint = f"closest: {', '.join(close)}" if close else f"the muscles are {', '.join(seq.muscles[:6])}" + \
                (", ..." if seq.n_muscles > 6 else "")
            raise FacesimError(f"muscle {key!r}: unknown muscle; {hint}")
        picked += hits
    if not picked:
        raise FacesimError("muscles: expected at least one muscle name")
    return np.unique(picked)


__all__ = ["ControlsSequence", "DEFAULT_FPS", "FILES", "JawSpec", "SIM_FOLDER", "inputs_record", "muscle_indices",
           "read_sequence", "write_sequence"]
