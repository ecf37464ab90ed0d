"""``facesim jaw markerless {dataset,train,retarget,predict,eval}``: markerless jaw tracking
(Zoss, Beeler, Gross & Bradley 2019) from the command line; parse, call, print.

- ``dataset`` simulates one subject's capture database (:mod:`facesim.jaw.markerless_dataset`);
- ``train`` fits the predictor on one dataset, or several (the multi-subject mapping);
- ``retarget`` adapts a predictor to a new subject from a few calibration frames;
- ``predict`` writes the jaw of a dataset (poses not needed) or of a folder of skin meshes;
- ``eval`` prints the predictor's and the Procrustes baseline's jaw errors side by side.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np

from facesim.errors import FacesimError


def _data(path):
    from facesim.jaw.markerless_data import load_data

    return load_data(path)


#: the shipped multi-subject predictor (trained on simulated subjects for the shipped faces' layout)
SHIPPED = "markerless_jaw.npz"


def _predictor(path):
    """The predictor file ``path``, or the shipped one (``meshes/markerless_jaw.npz``) for None."""
    from facesim.jaw.markerless import load_predictor

    if path is None:
        from facesim._files import MESHES

        path = MESHES / SHIPPED
    return load_predictor(path)


def _posed(path, purpose: str):
    """The dataset ``path``, which must hold jaw poses (``purpose``: what needs them)."""
    d = _data(path)
    if d.poses is None:
        raise FacesimError(f"{path}: no jaw poses; {purpose} needs frames with known jaw poses")
    return d


def _in(path, what: str):
    """Run ``what`` with one-line errors prefixed by the file they concern."""
    try:
        return what()
    except FacesimError as exc:
        msg = str(exc)
        raise FacesimError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None


def cmd_dataset(args) -> int:
    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.markerless_dataset import build_dataset

    poses = args.poses
    if poses is not None:
        from facesim.jaw.cli import read_poses

        poses = read_poses(poses).poses
    expressions = args.expressions
    if expressions not in ("random", "none") and not Path(expressions).is_file():
        raise FacesimError(f"--expressions: expected random, none or an activations CSV file, got {expressions!r} "
                           "(no such file)")
    options = EquilibriumOptions(teeth_contact=args.teeth_contact, lip_contact=args.lip_contact)
    d = build_dataset(args.model, args.output, poses=poses, frames=args.frames, expressions=expressions,
                      seed=args.seed, n_skin=args.features, options=options, workers=args.workers,
                      scheduler=args.scheduler, resume=not args.overwrite, progress=not args.quiet)
    failed = int((~d.ok).sum())
    print(f"dataset: {d.n_frames} frames x {d.n_features} skin features, {len(d.bone_rest)} bone points "
          f"({failed} frames did not converge{', flagged' if failed else ''}; "
          f"{d.meta.get('seconds_per_frame', float('nan')):.2f} s per frame) -> {args.output}")
    return 0


def cmd_train(args) -> int:
    from facesim.jaw.markerless import save_predictor, train

    data = [_posed(p, "training") for p in args.data]
    if args.markers is not None and args.features != "markers":
        raise FacesimError("--markers: only with --features markers")
    if args.features == "markers":
        names = _marker_names(args.markers, data[0])
        data = [_in(p, lambda d=d: d.marker_features(names)) for p, d in zip(args.data, data)]
    n = data[0].n_features
    for p, d in zip(args.data, data):
        if d.n_features != n:
            raise FacesimError(f"{p}: {d.n_features} {args.features} features, but {args.data[0]} has {n}; expected "
                               "datasets of the same feature layout")
    pred = train(data, cv_folds=args.cv_folds)
    save_predictor(pred, args.output, single=args.float32)
    hp = pred.meta.get("hyper", {})
    print(f"trained on {len(data)} subject(s), {sum(int(d.ok.sum()) for d in data)} frames "
          f"({', '.join(f'{k}={v:g}' for k, v in hp.items() if isinstance(v, (int, float)))}) -> {args.output}")
    return 0


def _marker_names(spec, data):
    """The markers of ``train --markers``: None (all the dataset recorded), comma-separated names,
    or a capture file (.c3d, .trc) whose markers the dataset has, in the dataset's order."""
    if spec is None:
        return None
    path = Path(spec)
    if path.suffix.lower() in (".c3d", ".trc") or path.is_file():
        from facesim.mocap.io import read_markers

        have = set(read_markers(path).names)
        recorded = data.markers.names if data.markers is not None else ()
        names = [n for n in recorded if n in have]
        if len(names) < 3:
            raise FacesimError(f"{path}: {len(names)} of its {len(have)} markers are among the dataset's "
                               f"{len(recorded)}; expected a capture of the model's marker names")
        return names
    return [n.strip() for n in spec.split(",") if n.strip()]


def cmd_retarget(args) -> int:
    from facesim.jaw.markerless import retarget, save_predictor

    pred = _predictor(args.predictor)
    cal = _posed(args.calibration, "retargeting")
    if args.frames is not None:
        cal = cal.subset(_frame_list(args.frames, cal.n_frames, args.calibration))
    out = _in(args.calibration, lambda: retarget(pred, cal, smoothness=args.smoothness, identity=args.identity))
    save_predictor(out, args.output)
    print(f"retargeted {args.predictor or 'the shipped predictor'} to {args.calibration} from {int(cal.ok.sum())} calibration frames "
          f"-> {args.output}")
    return 0


def _frame_list(text: str, n: int, path) -> np.ndarray:
    try:
        idx = np.array([int(v) for v in text.split(",") if v.strip()])
    except ValueError:
        raise FacesimError(f"--frames: expected comma-separated frame indices, got {text!r}") from None
    if not len(idx) or idx.min() < 0 or idx.max() >= n:
        raise FacesimError(f"--frames: expected indices in 0..{n - 1} of {path}, got {text!r}")
    return idx


def _skin_folder(folder, model_path):
    """Frames ``(F,)`` and skin feature points ``(F, P, 3)`` from the per-frame skin meshes in
    ``folder`` (``frame_KKKKK.ply`` as ``simulate`` writes, the model's skin topology)."""
    import meshio

    from facesim.jaw.markerless_features import feature_layout, skin_features
    from facesim.model import load_model

    if model_path is None:
        raise FacesimError("--skin: give --model M.npz, the model whose skin topology the meshes have")
    folder = Path(folder)
    if not folder.is_dir():
        raise FacesimError(f"{folder}: no such folder of skin meshes (--skin expects e.g. OUT/skin of simulate)")
    files = sorted(p for p in folder.iterdir() if re.fullmatch(r"frame_\d+\.(ply|obj)", p.name))
    if not files:
        raise FacesimError(f"{folder}: no frame_KKKKK.ply or .obj skin meshes (as simulate writes to OUT/skin)")
    layout = feature_layout(load_model(model_path))
    frames, P = [], []
    for f in files:
        try:
            mesh = meshio.read(f)
        except Exception as exc:  # noqa: BLE001 (meshio raises many kinds for a bad file)
            raise FacesimError(f"{f}: unreadable mesh ({type(exc).__name__})") from None
        P.append(_in(f, lambda: skin_features(layout, mesh.points)))
        frames.append(int(re.findall(r"\d+", f.stem)[-1]))
    return np.array(frames), np.stack(P), layout


def _write_jaw(path, frames, poses, ok, midpoint) -> None:
    """``frame,rx,ry,rz,tx,ty,tz,ok``: the rigid jaw form ``simulate --jaw`` reads (rotation vector
    about the condyle midpoint, rad, then translation, mm), and the poses as ``<stem>_poses.npz``."""
    from scipy.spatial.transform import Rotation

    from facesim._files import atomic_write

    R, t = poses[:, :3, :3], poses[:, :3, 3]
    rv = Rotation.from_matrix(R).as_rotvec()
    c = np.asarray(midpoint, dtype=np.float64)
    trans = t - c + np.einsum("nij,j->ni", R, c)           # x' = R (x - c) + c + trans
    lines = ["frame,rx,ry,rz,tx,ty,tz,ok"]
    lines += [",".join([str(int(k)), *(f"{v:.9g}" for v in (*r, *s)), str(int(o))])
              for k, r, s, o in zip(frames, rv, trans, ok)]
    path = Path(path)
    atomic_write(path, lambda tmp: tmp.write_text("\n".join(lines) + "\n"))
    np.savez_compressed(path.with_name(path.stem + "_poses.npz"), poses=poses)


def cmd_predict(args) -> int:
    from facesim.jaw.markerless import predict_poses
    from facesim.model import load_model

    if (args.data is None) == (args.skin is None):
        raise FacesimError("predict: give --data D.npz or --skin DIR (one of them)")
    pred = _predictor(args.predictor)
    if args.data is not None:
        d = _data(args.data)
        poses = _in(args.data, lambda: predict_poses(pred, d))
        frames, ok = np.arange(d.n_frames), d.ok
        model_path = args.model or (d.meta.get("model") or {}).get("path")
    else:
        frames, P, _ = _skin_folder(args.skin, args.model)
        poses = _in(args.skin, lambda: predict_poses(pred, P))
        ok, model_path = np.ones(len(frames), bool), args.model
    midpoint = np.zeros(3)
    note = "about the origin (facesim's frame: between the condyles); give --model for the exact condyle midpoint"
    if model_path is not None and Path(model_path).is_file():
        midpoint, note = load_model(model_path).jaw.midpoint, f"about the condyle midpoint of {model_path}"
    _write_jaw(args.output, frames, poses, ok, midpoint)
    print(f"predicted the jaw of {len(frames)} frames -> {args.output} (rotation vectors {note}) and "
          f"{Path(args.output).with_name(Path(args.output).stem + '_poses.npz')}")
    return 0


def cmd_eval(args) -> int:
    from facesim.jaw.markerless import evaluate

    pred = _predictor(args.predictor)
    d = _posed(args.data, "eval")
    r = _in(args.data, lambda: evaluate(pred, d))
    if args.json:
        print(json.dumps(r))
        return 0
    print(f"jaw error over the bone feature points, {r['frames']} frames of {args.data}"
          + (f" ({len(r.get('excluded', []))} not converged, left out)" if r.get("excluded") else ""))
    print(f"{'':<11}{'mean mm':>9}{'p95 mm':>9}{'max mm':>9}")
    for k in ("predictor", "baseline"):
        s = r[k]
        print(f"{k:<11}{s['mean_mm']:>9.3f}{s['p95_mm']:>9.3f}{s['max_mm']:>9.3f}")
    return 0


SHIPPED_HELP = (f"predictor file (default: the shipped multi-subject predictor meshes/{SHIPPED}, for the shipped "
                "faces' feature layout)")


def add_markerless_commands(jaw_sub, at_least) -> None:
    """``facesim jaw markerless ...`` under the ``jaw`` command's subparsers ``jaw_sub``."""
    ml = jaw_sub.add_parser(
        "markerless", help="jaw pose from the skin alone (Zoss et al. 2019): dataset, train, retarget, predict, eval",
        description="Markerless jaw tracking (Zoss, Beeler, Gross & Bradley 2019): skin features (displacements of "
                    "~240 skin points over the mandible, in the skull frame) -> one RBF SVR per bone-point "
                    "coordinate -> the rigid jaw pose; the Procrustes baseline of the same features; retargeting to "
                    "a new subject from ~5 calibration poses; one predictor trained on several subjects. Quick "
                    "start: 'facesim jaw markerless dataset --model M.npz --frames 400 -o D.npz', "
                    "'facesim jaw markerless train --data D.npz -o PRED.npz', "
                    "'facesim jaw markerless eval --predictor PRED.npz --data D2.npz'.")
    sub = ml.add_subparsers(dest="markerless_command", metavar="SUBCOMMAND", required=True)

    ds = sub.add_parser("dataset", help="simulate a subject's capture database (skin and jaw per frame)",
                        description="Simulate frames of a face model that combine jaw poses with random "
                                    "expressions, each a quasistatic equilibrium with the jaw placed rigidly at its "
                                    "pose, and record the skin features and the jaw: the training data of the "
                                    "markerless predictor. Written as it goes (D.npz.parts/); an interrupted "
                                    "build resumes where it stopped.")
    ds.add_argument("--model", required=True, metavar="M.npz", help="the subject's face model")
    ds.add_argument("--poses", metavar="P.npz", help="jaw poses (N, 4, 4), the format 'facesim jaw fit' reads "
                                                     "(default: generated from the model's TMJ)")
    ds.add_argument("--frames", type=at_least(1, int), default=None, metavar="N",
                    help="frames (default: 2000; with --poses, all of them, or N sampled evenly)")
    ds.add_argument("--expressions", default="random", metavar="random|none|A.csv",
                    help="the expression of each frame: random sparse activations, none, or an activations CSV "
                         "(default: random)")
    ds.add_argument("--seed", type=at_least(0, int), default=0, help="seed of the generated poses and expressions")
    ds.add_argument("--features", type=at_least(20, int), default=240, metavar="P",
                    help="about how many skin features (default: %(default)s)")
    ds.add_argument("--teeth-contact", action="store_true", help="keep the lips out of the teeth")
    ds.add_argument("--lip-contact", action="store_true", help="keep the lips out of each other")
    par = ds.add_mutually_exclusive_group()
    par.add_argument("--workers", type=at_least(1, int), default=1, metavar="N",
                     help="solve chunks of frames on N local dask worker processes (default: 1, here)")
    par.add_argument("--scheduler", metavar="ADDRESS", help="solve on a running dask.distributed cluster")
    ds.add_argument("--overwrite", action="store_true", help="start again instead of resuming D.npz.parts/")
    ds.add_argument("-o", "--output", required=True, metavar="D.npz", help="dataset file to write")
    ds.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    ds.set_defaults(func=cmd_dataset)

    tr = sub.add_parser("train", help="train the predictor on one or more datasets",
                        description="One RBF SVR per bone-point coordinate on the skin features (hyper-parameters "
                                    "by cross-validation, recorded in the predictor). Several datasets: the "
                                    "multi-subject mapping, each subject aligned to the first by one rigid "
                                    "transform.")
    tr.add_argument("--data", required=True, nargs="+", metavar="D.npz", help="dataset(s); the first is the primary")
    tr.add_argument("--features", choices=("skin", "markers"), default="skin",
                    help="what the predictor reads: the skin feature points (Zoss et al.; default), or the model's "
                         "markers, for 'solve-mocap --jaw-prior' on a marker capture of that layout")
    tr.add_argument("--markers", metavar="NAMES|CAPTURE",
                    help="with --features markers: only these markers (comma-separated), or those a capture file "
                         "(.c3d, .trc) has -- a predictor for captures with fewer markers (default: all)")
    tr.add_argument("--cv-folds", type=at_least(2, int), default=3, help="cross-validation folds (default: 3)")
    tr.add_argument("--float32", action="store_true",
                    help="store the support vectors in single precision (half the file; the shipped predictor)")
    tr.add_argument("-o", "--output", required=True, metavar="PRED.npz", help="predictor file to write")
    tr.set_defaults(func=cmd_train)

    rt = sub.add_parser("retarget", help="adapt a predictor to a new subject from a few calibration frames",
                        description="Per-feature rotation and scale maps from the new subject's features to the "
                                    "predictor's, solved so that the predictor reproduces the calibration frames' "
                                    "known jaw, with smoothness and closeness-to-identity regularisers.")
    rt.add_argument("--predictor", metavar="PRED.npz", help=SHIPPED_HELP)
    rt.add_argument("--calibration", required=True, metavar="C.npz",
                    help="a few frames of the new subject with known jaw poses (a dataset file)")
    rt.add_argument("--frames", metavar="I,J,...", help="use only these frames of C.npz (indices)")
    rt.add_argument("--smoothness", type=at_least(0.0), default=1.0, help="weight of the smoothness term")
    rt.add_argument("--identity", type=at_least(0.0), default=0.1, help="weight of the closeness to identity")
    rt.add_argument("-o", "--output", required=True, metavar="PRED2.npz")
    rt.set_defaults(func=cmd_retarget)

    pr = sub.add_parser("predict", help="the jaw of a dataset or of a folder of skin meshes",
                        description="Predict the jaw pose of every frame and write jaw.csv in the rigid form "
                                    "'simulate --jaw' reads (frame,rx,ry,rz,tx,ty,tz: rotation vector about the "
                                    "condyle midpoint, rad, then translation, mm; and an ok column) plus the poses "
                                    "(N, 4, 4) as <stem>_poses.npz, the format 'facesim jaw fit' reads.")
    pr.add_argument("--predictor", metavar="PRED.npz", help=SHIPPED_HELP)
    pr.add_argument("--data", metavar="D.npz", help="a dataset (its poses are not needed)")
    pr.add_argument("--skin", metavar="DIR", help="a folder of frame_KKKKK.ply skin meshes of --model's topology "
                                                  "(what simulate writes to OUT/skin), in the skull frame")
    pr.add_argument("--model", metavar="M.npz", help="the model of --skin (and the condyle midpoint of jaw.csv)")
    pr.add_argument("-o", "--output", required=True, metavar="jaw.csv")
    pr.set_defaults(func=cmd_predict)

    ev = sub.add_parser("eval", help="jaw error of the predictor and the Procrustes baseline on a dataset",
                        description="Mean, 95th percentile and max of the per-frame mean distance over the bone "
                                    "feature points (mm) between predicted and true jaw, for the predictor and the "
                                    "Procrustes baseline (Zoss et al. 2019 Table 1).")
    ev.add_argument("--predictor", metavar="PRED.npz", help=SHIPPED_HELP)
    ev.add_argument("--data", required=True, metavar="D.npz")
    ev.add_argument("--json", action="store_true", help='print {"predictor": {...}, "baseline": {...}, "frames": N}')
    ev.set_defaults(func=cmd_eval)


__all__ = ["add_markerless_commands"]
