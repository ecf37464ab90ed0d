"""``facesim jaw ...``: fit, evaluate, retarget, pose and draw empirical jaw rigs.

``add_jaw_commands(subparsers)`` adds the ``jaw`` command group to the ``facesim`` parser; the
handlers raise :class:`~facesim.errors.FacesimError` for user mistakes, which ``facesim.cli.main``
prints as one line. Heavy modules (the rigs, matplotlib) are imported by the handlers.

Poses file (``.npz``): ``poses (N, 4, 4)`` mandible relative to skull (mm, rest = identity) and
optionally ``reference_point (3,)`` mm (the lower incisal point at rest; default the shipped
model's incisor), ``mandible (P, 3)`` mm and ``weights (P,)`` (the points the errors are measured
on; default the shipped model's mandible with front weights, Zoss et al. 2018 Fig. 8),
``segment_names (S,)`` and ``segment_bounds (S, 2)`` (labelled movements, as written by
``facesim jaw generate``; a Posselt rig uses the six border movements among them, or finds them
in unlabelled poses), and for
``retarget`` ``names (K,)`` (rest, open, protrusion, left, right) or ``sliders (K, 3)``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim import se3
from facesim._argtypes import at_least
from facesim._files import atomic_write, open_npz, require_suffix
from facesim.errors import FacesimError, ModelFileError

FIT_RIGS = ("posselt", "nlpca", "1dof", "3dof", "5dof", "6dof")


# ------------------------------------------------------------------ poses files
@dataclass(frozen=True)
class PosesFile:
    """The fields of a poses file (module docstring); absent optional fields are None."""

    path: Path
    poses: np.ndarray
    reference_point: np.ndarray
    mandible: np.ndarray | None
    weights: np.ndarray | None
    segments: dict | None          # {name: frame indices}
    names: list | None
    sliders: np.ndarray | None

    def points(self, frame):
        """Mandible points ``(P, 3)`` and weights ``(P,)``: the file's, or the shipped model's mandible
        with front weights in ``frame``."""
        from facesim.jaw.points import front_weights, mandible_points

        if self.mandible is not None:
            w = self.weights if self.weights is not None else front_weights(self.mandible, frame)
            return self.mandible, w
        P = mandible_points()
        return P, front_weights(P, frame)


#: The largest magnitude a number of a poses file may have (mm: 100 m, far beyond any head).
MAX_VALUE = 1e5


def _field(data, path, key, shape_ok, expected: str, dtype=np.float64):
    """The array ``key`` of a poses file as ``dtype`` (None: as stored), of a shape ``shape_ok``
    accepts; numbers stored as numbers (integers for an integer ``dtype``: frame indices stored as
    floats are refused, not cast) and finite."""
    try:
        a = data[key]
    except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, ValueError ...)
        raise ModelFileError(path, f"field {key!r} unreadable ({type(exc).__name__})") from None
    if dtype is not None:
        kinds = "iu" if np.dtype(dtype).kind in "iu" else "fiu"
        if a.dtype.kind not in kinds:
            raise ModelFileError(path, f"field {key!r}: expected {expected}, got dtype {a.dtype}")
        if not np.isfinite(a).all():
            bad = ~np.isfinite(a).reshape(len(a), -1).all(axis=1) if a.ndim else np.ones(1, bool)
            raise ModelFileError(path, f"field {key!r}: expected finite values, got NaN or inf in "
                                       f"{int(bad.sum()):,} of {len(bad):,} rows (first: row {int(np.argmax(bad))})")
        if a.size and np.abs(a).max() > MAX_VALUE:   # positions of a head in mm are far below it
            bad = (np.abs(a).reshape(len(a), -1) > MAX_VALUE).any(axis=1) if a.ndim else np.ones(1, bool)
            raise ModelFileError(path, f"field {key!r}: expected values within +-{MAX_VALUE:g} (mm), got "
                                       f"{np.abs(a).max():g} in {int(bad.sum()):,} of {len(bad):,} rows "
                                       f"(first: row {int(np.argmax(bad))})")
        a = a.astype(dtype)
    if not shape_ok(a.shape):
        raise ModelFileError(path, f"field {key!r}: expected {expected}, got shape {a.shape}")
    return a


def read_poses(path) -> PosesFile:
    """Read and check a poses file (module docstring); one-line errors name the file and field."""
    path = Path(path)
    with open_npz(path, "a poses .npz with 'poses (N, 4, 4)'") as data:
        if "poses" not in data.files:
            raise ModelFileError(path, "field 'poses' missing (expected (N, 4, 4) mandible-to-skull transforms, mm)")
        poses = _field(data, path, "poses", lambda s: len(s) == 3 and s[1:] == (4, 4) and s[0] > 0,
                       "(N, 4, 4) transforms with N >= 1")
        try:
            se3.check_poses(poses, "field 'poses'")
        except FacesimError as exc:
            raise ModelFileError(path, str(exc)) from None
        files = set(data.files)
        if "reference_point" in files:
            ref = _field(data, path, "reference_point", lambda s: s == (3,), "(3,) mm")
        else:
            from facesim.jaw._shipped import shipped_model

            ref = shipped_model().jaw.incisor.copy()
        mandible = weights = None
        if "mandible" in files:
            mandible = _field(data, path, "mandible", lambda s: len(s) == 2 and s[1] == 3 and s[0] >= 3,
                              "(P, 3) points, P >= 3, mm")
        if "weights" in files:
            if mandible is None:
                raise ModelFileError(path, "field 'weights' given without 'mandible' (weights are per mandible point)")
            weights = _field(data, path, "weights", lambda s: s == (len(mandible),), f"({len(mandible)},) weights")
            if (weights < 0).any() or not weights.sum() > 0:
                raise ModelFileError(path, "field 'weights': expected non-negative values with a positive sum")
        segments = None
        if "segment_names" in files or "segment_bounds" in files:
            if not {"segment_names", "segment_bounds"} <= files:
                raise ModelFileError(path, "fields 'segment_names' and 'segment_bounds' go together; one is missing")
            names = _field(data, path, "segment_names", lambda s: len(s) == 1, "(S,) strings", dtype=None)
            bounds = _field(data, path, "segment_bounds", lambda s: s == (len(names), 2),
                            f"({len(names)}, 2) frame ranges", dtype=np.int64)
            if names.dtype.kind not in "US" or (bounds[:, 0] < 0).any() or (bounds[:, 1] > len(poses)).any() or \
                    (bounds[:, 0] > bounds[:, 1]).any():
                raise ModelFileError(path, f"fields 'segment_names'/'segment_bounds': expected names and "
                                           f"[start, stop) ranges within the {len(poses)} frames")
            segments = {}
            for name, (a, b) in zip(names.astype(str), bounds):
                segments.setdefault(str(name), []).append(np.arange(a, b))
            segments = {k: np.concatenate(v) for k, v in segments.items()}
        extreme_names = sliders = None
        if "names" in files:
            arr = _field(data, path, "names", lambda s: s == (len(poses),), f"({len(poses)},) pose names", dtype=None)
            if arr.dtype.kind not in "US":
                raise ModelFileError(path, f"field 'names': expected strings, got dtype {arr.dtype}")
            extreme_names = [str(n) for n in arr]
        if "sliders" in files:
            sliders = _field(data, path, "sliders", lambda s: s == (len(poses), 3), f"({len(poses)}, 3) slider values")
    return PosesFile(path, poses, ref, mandible, weights, segments, extreme_names, sliders)


def _load_rig(path):
    from facesim.jaw.rigs import load_rig

    return load_rig(path)


def _frame(pf: PosesFile):
    from facesim.jaw.frame import JawFrame

    try:
        return JawFrame.from_poses(pf.poses, pf.reference_point)
    except FacesimError as exc:
        raise FacesimError(f"{pf.path}: {exc}") from None


def _errors(rig, pf: PosesFile):
    """:class:`~facesim.jaw.evaluate.ErrorStats` of ``rig`` on the poses of ``pf``."""
    from facesim.jaw.evaluate import pose_errors

    points, weights = pf.points(rig.frame)
    return pose_errors(rig.reproduce(pf.poses, points, weights), pf.poses, points, weights)


def _kind(rig) -> str:
    from facesim.jaw.rigs import KINDS

    return KINDS[type(rig)] if KINDS[type(rig)] != "classic" else rig.dof


# ------------------------------------------------------------------ handlers
def cmd_jaw_fit(args) -> int:
    out = require_suffix(args.output, (".npz",), "a rig file name")
    pf = read_poses(args.poses)
    frame = _frame(pf)
    start = time.perf_counter()
    if args.rig == "posselt":
        from facesim.jaw.posselt import CURVES, fit_posselt

        labelled = pf.segments is not None and all(len(pf.segments.get(c, ())) for c in CURVES)
        if not labelled:
            print(f"{pf.path}: no labels for the six border movements ({', '.join(CURVES)}); finding them in the "
                  f"poses (the capture must trace the borders)")
        try:
            rig = fit_posselt(poses=pf.poses, reference_point=pf.reference_point, frame=frame,
                              border={c: pf.segments[c] for c in CURVES} if labelled else "detect")
        except FacesimError as exc:
            raise FacesimError(f"{pf.path}: {exc}") from None
    elif args.rig == "nlpca":
        from facesim.jaw.nlpca import fit_nlpca

        if len(pf.poses) < 10:
            raise FacesimError(f"{pf.path}: field 'poses': an nlpca rig needs at least 10 frames, got {len(pf.poses)}")
        points, weights = pf.points(frame)
        rig = fit_nlpca(pf.poses, frame, points=points, weights=weights, iterations=args.iterations, seed=args.seed)
    else:
        from facesim.jaw.classic import fit_classic

        points, weights = pf.points(frame)
        rig = fit_classic(pf.poses, args.rig, frame, points, weights).rig
    seconds = time.perf_counter() - start
    path = rig.save(out)
    e = _errors(rig, pf)
    print(f"fitted a {args.rig} rig on {len(pf.poses)} frames in {seconds:.1f} s -> {path}")
    print(f"error on the fitted poses (weighted mandible vertices, mm): mean {e.mean:.3f}, 95th percentile "
          f"{e.p95:.3f}, max {e.max:.3f}")
    return 0


def cmd_jaw_eval(args) -> int:
    rig = _load_rig(args.rig)
    pf = read_poses(args.poses)
    e = _errors(rig, pf)
    if args.json:
        print(json.dumps({"rig": str(args.rig), "kind": _kind(rig), "poses": str(args.poses), "frames": len(pf.poses),
                          "mean_mm": e.mean, "p95_mm": e.p95, "max_mm": e.max}, indent=2))
    else:
        print(f"{_kind(rig)} rig {args.rig} on {len(pf.poses)} frames of {args.poses}: weighted mandible-vertex "
              f"error mean {e.mean:.3f} mm, 95th percentile {e.p95:.3f} mm, max {e.max:.3f} mm")
    return 0


def cmd_jaw_retarget(args) -> int:
    from facesim.jaw.posselt import PosseltRig
    from facesim.jaw.retarget import retarget_posselt

    out = require_suffix(args.output, (".npz",), "a rig file name")
    rig = _load_rig(args.rig)
    if not isinstance(rig, PosseltRig):
        raise FacesimError(f"{args.rig}: retargeting needs a posselt rig, got a {_kind(rig)} rig")
    pf = read_poses(args.poses)
    try:
        new = retarget_posselt(rig, pf.poses, pf.reference_point, names=pf.names, sliders=pf.sliders, mode=args.mode)
    except FacesimError as exc:
        raise FacesimError(f"{pf.path}: {exc}") from None
    path = new.save(out)
    print(f"retargeted {args.rig} to the {len(pf.poses)} poses of {args.poses} ({args.mode} adaptation) -> {path}")
    return 0


def cmd_jaw_pose(args) -> int:
    from facesim.jaw.posselt import PosseltRig

    rig = _load_rig(args.rig)
    q = np.array(args.sliders, dtype=np.float64)
    n = getattr(rig, "n_params", 3)
    if q.shape != (n,) or not np.isfinite(q).all():
        raise FacesimError(f"--sliders: the {_kind(rig)} rig takes {n} finite values, got {len(q)}")
    if isinstance(rig, PosseltRig):
        if (q < 0).any() or (q > 1).any():
            raise FacesimError("--sliders: expected values in [0, 1] (s_x right -> left, s_y closed -> open, "
                               "s_z retruded -> protruded)")
        T = rig.pose_from_sliders(q[None])[0]
    elif hasattr(rig, "clamp"):
        inside = rig.clamp(q)
        if np.abs(inside - q).max() > 1e-9:
            raise FacesimError(f"--sliders: ({', '.join(f'{v:g}' for v in q)}) is outside the valid ranges; "
                               f"the nearest valid parameters are ({', '.join(f'{v:.3g}' for v in inside)})")
        T = rig.transform(q)
    else:
        bounds = getattr(rig, "bounds", None)
        if bounds is not None:   # the range of the fitted parameters (a rig fitted without one is unbounded)
            lo, hi = np.asarray(bounds, dtype=np.float64).T
            outside = (q < lo) | (q > hi)
            if outside.any():
                j = int(np.argmax(outside))
                names = getattr(rig, "names", None) or [f"q{i + 1}" for i in range(n)]
                raise FacesimError(f"--sliders: {names[j]} = {q[j]:g} is outside the rig's range [{lo[j]:.3g}, "
                                   f"{hi[j]:.3g}] (rad or mm, the range of the poses it was fitted to)")
        T = rig.transform(q)
    rest = rig.frame.origin                       # the reference point at rest (skull frame)
    incisor = se3.transform_points(T, rest)[0]
    print("mandible transform relative to the skull (mm):")
    for row in T:
        print("  " + " ".join(f"{v:12.6f}" for v in row))
    print(f"incisor (reference point) at {' '.join(f'{v:.3f}' for v in incisor)} mm "
          f"(moved {np.linalg.norm(incisor - rest):.3f} mm from rest)")
    return 0


def cmd_jaw_envelope(args) -> int:
    from facesim.jaw.classic import ClassicRig

    out = require_suffix(args.output, (".png",), "a picture file name")
    rig = _load_rig(args.rig)
    if isinstance(rig, ClassicRig):
        raise FacesimError(f"{args.rig}: a {rig.dof} rig has no envelope; expected a posselt or nlpca rig")
    data = read_poses(args.poses).poses if args.poses else None
    from facesim.jaw.figures import envelope_figure

    envelope_figure(rig, out, data, title=f"{_kind(rig)} rig {Path(args.rig).name}: envelope of the incisal point")
    print(f"wrote {out}")
    return 0


def cmd_jaw_generate(args) -> int:
    from facesim.jaw.motion import JawMotion, Subject
    from facesim.jaw.retarget import EXTREMES

    out = require_suffix(args.output, (".npz",), "a poses file name")
    if args.model:
        from facesim.jaw.motion import subject_for
        from facesim.model import FaceModel

        geometry = FaceModel.load(args.model).jaw
        subject = subject_for(geometry) if args.subject is None else Subject.random(args.subject)
    else:
        geometry, subject = None, Subject() if args.subject is None else Subject.random(args.subject)
    motion = JawMotion(geometry, subject)
    if args.extremes:
        latent = {"rest": (0.0, 0.0, 0.0), "open": (1.0, 0.0, 0.0), "protrusion": (0.0, 1.0, 0.0),
                  "left": (0.0, 0.0, 1.0), "right": (0.0, 0.0, -1.0)}
        names = list(EXTREMES)
        poses = motion.poses(np.array([latent[n] for n in names]))
        if args.noise > 0:
            rng = np.random.default_rng(args.session)
            poses = poses @ se3.exp(np.c_[rng.normal(scale=args.noise / 100, size=(len(poses), 3)),
                                          rng.normal(scale=args.noise, size=(len(poses), 3))])
        path = atomic_write(out, lambda tmp: np.savez_compressed(tmp, poses=poses, names=np.array(names),
                                                                 reference_point=motion.incisor0))
        print(f"wrote {len(poses)} extremal poses ({', '.join(names)}) of subject "
              f"{'default' if args.subject is None else args.subject} -> {path}")
        return 0
    session = motion.session(seed=args.session, kinds=tuple(args.kinds), noise=args.noise)
    path = atomic_write(out, lambda tmp: session.save(tmp))
    counts = {}
    for s in session.segments:
        counts[s.name] = counts.get(s.name, 0) + s.stop - s.start
    print(f"wrote a session of {len(session.poses)} poses ({len(session.poses) / 30.0:.0f} s at 30 fps) of subject "
          f"{'default' if args.subject is None else args.subject} -> {path}")
    print("  frames per movement: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0


def cmd_jaw_fit_model(args) -> int:
    from facesim.jaw.evaluate import pose_errors
    from facesim.jaw.model_rig import (
        TEST_SEED,
        fit_model_rig,
        model_motion,
        model_rig_path,
    )
    from facesim.jaw.motion import subject_for
    from facesim.jaw.points import front_weights, mandible_points
    from facesim.model import FaceModel

    model = FaceModel.load(args.model)
    out = require_suffix(args.output, (".npz",), "a rig file name") if args.output else model_rig_path(args.model)
    start = time.perf_counter()
    rig = fit_model_rig(model.jaw, seed=args.session, noise=args.noise)
    seconds = time.perf_counter() - start
    path = rig.save(out)
    test = model_motion(model.jaw, TEST_SEED if args.session != TEST_SEED else TEST_SEED + 1, args.noise)
    points = mandible_points(model)
    e = pose_errors(rig.reproduce(test.poses), test.poses, points, front_weights(points, rig.frame))
    subject = subject_for(model.jaw)
    print(f"fitted the posselt rig of {args.model}'s TMJ (maximum opening {np.degrees(model.jaw.max_opening):.1f} "
          f"degrees = {subject.max_opening:.1f} mm at the incisor, condylar translation "
          f"{subject.condyle_translation:g} mm) in {seconds:.1f} s -> {path}")
    print(f"error on a second generated session of {len(test.poses)} frames (weighted mandible vertices, mm): "
          f"mean {e.mean:.3f}, 95th percentile {e.p95:.3f}, max {e.max:.3f}")
    return 0


# ------------------------------------------------------------------ parser
#: The largest capture noise a generated session may have, mm (a noise beyond it buries the motion).
MAX_NOISE_MM = 10.0


_at_least = at_least   # argparse type: a finite number (or integer) >= a minimum (and <= a maximum)


def add_jaw_commands(subparsers, more=()) -> argparse.ArgumentParser:
    """Add ``facesim jaw {fit,eval,retarget,pose,envelope,fit-model,generate}`` to the ``subparsers`` of the
    ``facesim`` parser, then the commands each of ``more`` adds (called as ``add(jaw_subparsers,
    at_least)``: packages that may use the FEM, which this one must not import); returns the ``jaw``
    parser."""
    poses_help = ("poses .npz: poses (N, 4, 4) mandible relative to skull, mm; optional reference_point (3,), "
                  "mandible (P, 3), weights (P,), segment labels")
    jaw = subparsers.add_parser(
        "jaw", help="fit, evaluate, retarget and pose empirical jaw rigs",
        description="Data-driven jaw rigs (Zoss et al. 2018 Posselt-envelope rig, Yang et al. 2018 NLPCA rig, "
                    "traditional 1/3/5/6-DOF rigs) fitted to captured or generated mandible poses. Quick start: "
                    "'facesim jaw generate -o P.npz', 'facesim jaw fit --rig posselt --poses P.npz -o RIG.npz', "
                    "'facesim jaw eval --rig RIG.npz --poses P.npz'.",
        epilog="Poses file (.npz): poses (N, 4, 4) mandible relative to the skull (mm, rest = identity); optional "
               "reference_point (3,) mm (default: the shipped model's incisor), mandible (P, 3) mm and weights (P,) "
               "(default: the shipped model's mandible, front-weighted), segment_names (S,) and segment_bounds (S, 2) "
               "(labelled movements; a posselt rig uses the six border movements, found in the poses when "
               "unlabelled), names (K,) or sliders (K, 3) "
               "for retarget.")
    sub = jaw.add_subparsers(dest="jaw_command", metavar="SUBCOMMAND", required=True)

    fit = sub.add_parser("fit", help="fit a rig to poses",
                         description="Fit a rig to the poses of a poses file and write it as a rig .npz; prints the "
                                     "fit time and the error on the fitted poses.")
    fit.add_argument("--rig", required=True, choices=FIT_RIGS, help="the rig to fit")
    fit.add_argument("--poses", required=True, metavar="P.npz", help=poses_help)
    fit.add_argument("-o", "--output", required=True, metavar="RIG.npz", help="rig file to write")
    fit.add_argument("--iterations", type=_at_least(1, int), default=1000,
                     help="nlpca: L-BFGS iterations of the autoencoder (default: %(default)s)")
    fit.add_argument("--seed", type=_at_least(0, int), default=0, help="nlpca: seed of the hidden layers (default: %(default)s)")
    fit.set_defaults(func=cmd_jaw_fit)

    ev = sub.add_parser("eval", help="error of a rig on poses (mean, 95th percentile, max, mm)",
                        description="Drive the rig to every pose of the file (Posselt: by the reference point; "
                                    "NLPCA: inverse kinematics; classic: best parameters) and print the mean, 95th "
                                    "percentile and maximum over the frames of the weighted mean distance of the "
                                    "mandible points, mm.")
    ev.add_argument("--rig", required=True, metavar="RIG.npz", help="rig file")
    ev.add_argument("--poses", required=True, metavar="P.npz", help=poses_help)
    ev.add_argument("--json", action="store_true", help="print JSON instead of a line")
    ev.set_defaults(func=cmd_jaw_eval)

    rt = sub.add_parser("retarget", help="adapt a posselt rig to a new subject from a few extremal poses",
                        description="Retarget a posselt rig (Zoss et al. 2018 section 5) to the subject of a few "
                                    "extremal poses (rest, maximum opening, maximum protrusion, left and right "
                                    "laterotrusion; named by the file's 'names' or 'sliders', else recognised from "
                                    "the incisal point's displacement).")
    rt.add_argument("--rig", required=True, metavar="RIG.npz", help="source posselt rig")
    rt.add_argument("--poses", required=True, metavar="EXTREMES.npz", help="the new subject's extremal poses")
    rt.add_argument("-o", "--output", required=True, metavar="NEW.npz", help="rig file to write")
    rt.add_argument("--mode", choices=("full", "reduced", "none"), default="full",
                    help="full: envelope and pose map adapted; reduced: envelope only; none: the source rig moved "
                         "to the new jaw frame (default: %(default)s)")
    rt.set_defaults(func=cmd_jaw_retarget)

    pose = sub.add_parser("pose", help="print the pose of slider values",
                          description="Print the 4x4 mandible transform (relative to the skull, mm) of a rig's "
                                      "controls and where it puts the incisor. Posselt: sliders s_x (right -> left), "
                                      "s_y (closed -> open), s_z (retruded -> protruded) in [0, 1]; NLPCA: d1 d2 d3; "
                                      "classic: its parameters (rad, mm).")
    pose.add_argument("--rig", required=True, metavar="RIG.npz", help="rig file")
    pose.add_argument("--sliders", required=True, nargs="+", type=float, metavar="S", help="the rig's controls")
    pose.set_defaults(func=cmd_jaw_pose)

    env = sub.add_parser("envelope", help="draw a rig's envelope (PNG)",
                         description="Draw the envelope of the incisal point (the Posselt shield, or the valid range "
                                     "of an NLPCA rig) in the jaw frame, with the reference points of --poses.")
    env.add_argument("--rig", required=True, metavar="RIG.npz", help="posselt or nlpca rig file")
    env.add_argument("-o", "--output", required=True, metavar="env.png", help="picture to write")
    env.add_argument("--poses", metavar="P.npz", help="poses whose incisal points to draw")
    env.set_defaults(func=cmd_jaw_envelope)

    fm = sub.add_parser("fit-model", help="fit a face model's own posselt rig (for --jaw-model posselt)",
                        description="Generate jaw motion for the TMJ of a face model (its condyles, tracks, "
                                    "maximum opening and incisor; facesim.jaw.motion.subject_for) and fit a posselt "
                                    "rig to it, recording the TMJ in the rig. Written next to the model as "
                                    "M_posselt.npz, where '--jaw-model posselt' (no file) finds it; the shipped "
                                    "models' rig is meshes/face_coarse_posselt.npz.")
    fm.add_argument("--model", required=True, metavar="M.npz", help="face model file")
    fm.add_argument("-o", "--output", metavar="RIG.npz", help="rig file to write (default: M_posselt.npz next to "
                                                              "the model)")
    fm.add_argument("--session", type=_at_least(0, int), default=1, metavar="SEED",
                    help="seed of the generated session the rig is fitted to (default: %(default)s)")
    fm.add_argument("--noise", type=_at_least(0.0, maximum=MAX_NOISE_MM), default=0.0,
                    help="capture noise added to the generated poses, mm (default: %(default)s)")
    fm.set_defaults(func=cmd_jaw_fit_model)

    gen = sub.add_parser("generate", help="write a synthetic capture session (no data needed)",
                         description="Generate mandible poses from the TMJ anatomy of the shipped model "
                                     "(facesim.jaw.motion): a capture-like session with labelled border movements, "
                                     "chewing, speech and free moves, or with --extremes the five extremal poses "
                                     "retargeting needs.")
    gen.add_argument("--subject", type=_at_least(0, int), default=None, metavar="SEED",
                     help="random subject (TMJ and incisal ranges) of this seed (default: the default subject)")
    gen.add_argument("--model", metavar="M.npz",
                     help="the face model whose TMJ moves (default: the shipped model's); without --subject its own "
                          "subject (maximum opening and condylar translation within the model's limits)")
    gen.add_argument("--session", type=_at_least(0, int), default=0, metavar="SEED",
                     help="seed of the session's durations, amplitudes and noise (default: %(default)s)")
    gen.add_argument("--kinds", nargs="+", choices=("border", "chewing", "speech", "free"),
                     default=["border", "chewing", "speech", "free"], help="movements, in order (default: all)")
    gen.add_argument("--noise", type=_at_least(0.0, maximum=MAX_NOISE_MM), default=0.03,
                     help="capture noise, mm (rotation noise/100 rad) (default: %(default)s)")
    gen.add_argument("--extremes", action="store_true", help="write the five extremal poses instead of a session")
    gen.add_argument("-o", "--output", required=True, metavar="P.npz", help="poses file to write")
    gen.set_defaults(func=cmd_jaw_generate)
    for add in more:
        add(sub, _at_least)
    return jaw


__all__ = ["FIT_RIGS", "PosesFile", "add_jaw_commands", "read_poses"]
