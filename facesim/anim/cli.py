"""``facesim edit {blend,keyframe,scale,gain,splice,retime,mirror}``: new performances from solved
ones, edited in activation space (Sifakis et al. 2005 section 9; :mod:`facesim.anim.edits`).

``add_parsers(subparsers)`` adds the ``edit`` command group to the ``facesim`` parser; the
handlers (``cmd_<operation>``) read the sources, edit, write ``OUT_DIR`` in the formats
``solve-mocap`` writes (:func:`facesim.anim.sequence.write_sequence`: ``simulate --controls-from
OUT_DIR`` replays it) and with ``--simulate`` run :func:`facesim.simulate.simulate` on the result
into ``OUT_DIR/sim`` (with the gains). User mistakes raise :class:`~facesim.errors.FacesimError`,
which ``facesim.cli.main`` prints as one line with exit status 2. Heavy modules are imported by the
handlers.

Sources: a solve-mocap (or facesim edit) output folder, or an activations CSV (its jaw from a
``--jaw`` CSV in ``--jaw-model``, else at rest); either followed by ``@FIRST:LAST`` for the frames
FIRST to LAST only.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from facesim._argtypes import number, whole
from facesim.anim.curves import METHODS
from facesim.errors import FacesimError, ModelFileError

OPERATIONS = ("blend", "keyframe", "scale", "gain", "splice", "retime", "mirror")

SOURCE_HELP = ("a solve-mocap (or facesim edit) output folder, or an activations CSV (frame,<muscle>,...); "
               "append @FIRST:LAST for those frames only")
SOURCES_EPILOG = (
    "Sources: a folder written by solve-mocap or facesim edit (activations.csv, jaw.csv, report.json, run.json; "
    "head.csv and gain.csv when present), checked to be of --model; or an activations CSV, whose jaw comes from a "
    "--jaw CSV in --jaw-model (else at rest). Sources combined must share the model, the jaw model, the frame rate, "
    "the gains, and head poses in both or neither. Output: OUT_DIR/activations.csv, jaw.csv, report.json, run.json "
    "(and head.csv, gain.csv), the formats solve-mocap writes: 'facesim simulate --model M.npz --controls-from "
    "OUT_DIR -o SIM' replays the result, or --simulate does it into OUT_DIR/sim.")


# ------------------------------------------------------------------ argparse types
_number = number()   # argparse types: any finite number, any integer
_whole = whole()


def _weight(text: str):
    """``T`` (one weight for every frame) or ``T0:T1`` (a ramp from the first frame to the last)."""
    parts = text.split(":")
    if len(parts) not in (1, 2):
        raise argparse.ArgumentTypeError(f"expected T or T0:T1 with numbers in [0, 1], got {text!r}")
    values = tuple(_number(p) for p in parts)
    return values[0] if len(values) == 1 else values


def _folder(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return text


def _muscle_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("expected comma-separated muscle names, got none")
    return names


# ------------------------------------------------------------------ the parsers
def _common(p: argparse.ArgumentParser) -> None:
    """The options every operation has."""
    p.add_argument("--model", required=True, metavar="M.npz", help="the model the controls are for (required)")
    p.add_argument("-o", "--output", required=True, type=_folder, metavar="OUT_DIR",
                   help="output folder (refused when not empty, unless --overwrite or --resume)")
    p.add_argument("--jaw", action="append", default=[], metavar="J.csv",
                   help="jaw CSV of an activations CSV source (same frames), one per CSV source in order; "
                        "default: the jaw at rest")
    p.add_argument("--jaw-model", default=None, metavar="JM",
                   help="jaw model of the --jaw CSVs: rigid (frame,rx,ry,rz,tx,ty,tz rad about the condyle midpoint "
                        "and mm, or frame,opening rad), sliding-condyle (frame,opening,right_slide,left_slide in rad, "
                        "mm, mm), affine-condyle, posselt, posselt:RIG.npz, nlpca:RIG.npz, classic:RIG.npz "
                        "(default: rigid); folders record their own")
    p.add_argument("--source-fps", type=_number, default=None, metavar="HZ",
                   help="frame rate of sources that do not record one (solve-mocap folders, CSV files), Hz "
                        "(default: 30); facesim edit folders record theirs")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--overwrite", action="store_true",
                       help="replace what an earlier edit wrote into OUT_DIR (and its sim/); other files stay")
    again.add_argument("--resume", action="store_true",
                       help="the same edit again into OUT_DIR (refused if the result differs) and continue its "
                            "--simulate run after its last complete frame")
    p.add_argument("--simulate", action="store_true",
                   help="also simulate the result into OUT_DIR/sim (as facesim simulate --controls-from OUT_DIR, "
                        "with the gains and the sources' contact set-up)")
    p.add_argument("--solver", choices=("amg", "direct", "pardiso"), default="amg",
                   help="linear solver of --simulate: algebraic multigrid + CG, sparse LU, or MKL PARDISO "
                        "(default: %(default)s)")
    p.add_argument("--output-frame", choices=("facesim", "input"), default="facesim",
                   help="the frame of --simulate's skin and marker files, as in facesim simulate: facesim (mm) or "
                        "input, the frame and units of the meshes an imported model was made from "
                        "(default: %(default)s)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar (--simulate)")


def _method(p: argparse.ArgumentParser, default: str, what: str) -> None:
    p.add_argument("--method", choices=METHODS, default=default,
                   help=f"{what}: linear, smoothstep (eases in and out of every key) or catmull-rom (C1 through the "
                        "keys; its overshoot clamped to [0, 1] and the jaw's bounds) (default: %(default)s)")


def _operation(ops, name: str, summary: str, description: str) -> argparse.ArgumentParser:
    return ops.add_parser(name, help=summary, description=description, epilog=SOURCES_EPILOG)


def _done(p: argparse.ArgumentParser, func) -> None:
    """Add the common options and the handler to the parser of an operation."""
    _common(p)
    p.set_defaults(func=func, command_parser=p)


def add_parsers(subparsers) -> argparse.ArgumentParser:
    """Add ``facesim edit {blend,keyframe,scale,gain,splice,retime,mirror}`` to the ``subparsers`` of
    the ``facesim`` parser; returns the ``edit`` parser."""
    edit = subparsers.add_parser(
        "edit", help="edit performances in activation space: blend, keyframe, scale, gain, splice, retime, mirror",
        description="New performances from solved ones, edited in the space of the controls (Sifakis, Neverov, "
                    "Fedkiw 2005, section 9): every in-between of two expressions is physically attainable, as the "
                    "equilibrium of interpolated controls. Activations stay in [0, 1], jaw parameters within the jaw "
                    "model's bounds; rigid jaw and head poses are interpolated on SE(3).",
        epilog=SOURCES_EPILOG)
    ops = edit.add_subparsers(dest="edit_command", metavar="OPERATION", required=True)

    p = _operation(ops, "blend", "(1 - t) A + t B, frame by frame",
                   "Blend two sources frame by frame: (1 - t) A + t B (activations, jaw parameters; "
                   "poses along the SE(3) geodesic). A and B have the same number of frames, or one "
                   "of them a single frame (e.g. SRC@40:40), blended into every frame of the other.")
    p.add_argument("a", metavar="A", help=SOURCE_HELP)
    p.add_argument("b", metavar="B", help="the second source, as A")
    p.add_argument("--t", required=True, type=_weight, metavar="T|T0:T1",
                   help="weight of B in [0, 1]: one number for every frame, or T0:T1 ramping linearly from the first "
                        "frame to the last (0:1 morphs A into B)")
    _done(p, cmd_blend)

    p = _operation(ops, "keyframe", "a sequence through expressions at given frames",
                   "A sequence through key expressions: --key SRC FRAME AT puts frame FRAME of SRC at "
                   "frame AT of the result (increasing); every frame from the first AT to the last "
                   "is interpolated, each key reached exactly.")
    p.add_argument("--key", nargs=3, action="append", required=True, metavar=("SRC", "FRAME", "AT"),
                   help="a key: frame FRAME of the source SRC at frame AT of the result (give at least two)")
    _method(p, "catmull-rom", "interpolation between the keys")
    _done(p, cmd_keyframe)

    p = _operation(ops, "scale", "exaggerate or de-emphasise: activations times a factor, clamped to [0, 1]",
                   "Scale the activations by --factor (> 1 exaggerates, < 1 de-emphasises, 0 is the "
                   "rest), clamped to [0, 1]; beyond activation 1 use 'facesim edit gain'.")
    p.add_argument("source", metavar="SRC", help=SOURCE_HELP)
    p.add_argument("--factor", required=True, type=_number, metavar="F", help="scale factor, 0 to 100")
    p.add_argument("--muscles", type=_muscle_list, default=None, metavar="NAMES",
                   help="comma-separated muscles to scale, names or base names for both sides "
                        "(zygomaticus_major = _L and _R) (default: all)")
    p.add_argument("--with-jaw", action="store_true",
                   help="also scale the jaw's motion from rest (parameters rest + F (q - rest), clamped to the "
                        "bounds; rigid poses exp(F log T))")
    _done(p, cmd_scale)

    p = _operation(ops, "gain", "scale muscles' force-length curves: beyond what activation 1 can do",
                   "Set the gain of muscles: the scale of their active force-length curve (Sifakis "
                   "2005 Fig. 8: 2 doubled, 4 quadrupled), so the same activations pull harder. "
                   "Written to OUT_DIR/gain.csv (muscle,gain); --simulate and simulate "
                   "--controls-from OUT_DIR apply it.")
    p.add_argument("source", metavar="SRC", help=SOURCE_HELP)
    p.add_argument("--factor", required=True, type=_number, metavar="G", help="the gain, > 0 and <= 100 (1: as built)")
    p.add_argument("--muscles", type=_muscle_list, default=None, metavar="NAMES",
                   help="comma-separated muscles, names or base names for both sides (default: all)")
    _done(p, cmd_gain)

    p = _operation(ops, "splice", "segments one after the other, with an optional crossfade",
                   "Without --at: the sources one after the other, each starting the frame after the "
                   "previous one ends (or overlapping its last K frames with --crossfade K). With "
                   "--at FRAME (two sources): A's frames before FRAME, then B renumbered to start at "
                   "FRAME; --crossfade K blends B's first K frames with A's K frames from FRAME on.")
    p.add_argument("sources", nargs="+", metavar="SRC", help=SOURCE_HELP + " (at least two)")
    p.add_argument("--at", type=_whole, default=None, metavar="FRAME",
                   help="frame of the first source where the second one starts (two sources only)")
    p.add_argument("--crossfade", type=_whole, default=0, metavar="K",
                   help="frames over which one source fades into the next (default: %(default)s, a cut)")
    _done(p, cmd_splice)

    p = _operation(ops, "retime", "resample to another frame rate",
                   "Resample the source at --fps: frame f at time f / fps s as in the source; the "
                   "first and last frames keep the source's first and last controls, and the frames "
                   "at times both rates share keep its values exactly.")
    p.add_argument("source", metavar="SRC", help=SOURCE_HELP)
    p.add_argument("--fps", required=True, type=_number, metavar="HZ", help="the new frame rate, Hz")
    _method(p, "linear", "interpolation between the source's frames")
    _done(p, cmd_retime)

    p = _operation(ops, "mirror", "left for right across the midsagittal plane",
                   "Mirror the performance: every _L muscle takes its _R partner's activations and "
                   "gain and back, the sliding-condyle jaw swaps its right and left slides (other jaw "
                   "models: the pose mirrored across the plane x = condyle midpoint), head poses are "
                   "mirrored about the first frame's.")
    p.add_argument("source", metavar="SRC", help=SOURCE_HELP)
    _done(p, cmd_mirror)
    return edit


# ------------------------------------------------------------------ sources
def _load_model(path):
    """The model at ``path`` (:func:`facesim.model.load_model`: any unreadable file is one line)."""
    from facesim.model import load_model

    return load_model(path)


def _split(text: str) -> tuple[Path, tuple[int, int] | None]:
    """``SRC[@FIRST:LAST]`` as the path and the frame range (None: every frame)."""
    path, at, span = text.rpartition("@")
    if at and not Path(text).exists():
        m = re.fullmatch(r"(\d+):(\d+)", span)
        if not m:
            raise FacesimError(f"{text}: expected SRC@FIRST:LAST with frame numbers after the @, got {span!r}")
        first, last = int(m.group(1)), int(m.group(2))
        if first > last:
            raise FacesimError(f"{text}: the range {first}:{last} is empty; expected FIRST <= LAST")
        return Path(path), (first, last)
    return Path(text), None


class _Sources:
    """Reads the sources of one command: the ``--jaw`` CSVs go to the CSV sources in order."""

    def __init__(self, args, model, texts):
        self.args, self.model = args, model
        self.specs = [_split(t) for t in texts]
        csvs = sum(p.is_file() for p, _ in self.specs)
        if args.jaw and len(args.jaw) != csvs:
            raise FacesimError(f"--jaw: {len(args.jaw)} given for {csvs} activations CSV source(s); expected one per "
                               "CSV source, in order (a folder has its own jaw.csv)")
        if args.jaw_model is not None and not csvs:
            raise FacesimError("--jaw-model: applies to activations CSV sources; every source is a folder, which "
                               "records its jaw model")
        jaws = iter(args.jaw)
        self.jaw = [next(jaws, None) if p.is_file() else None for p, _ in self.specs]
        out = Path(args.output).resolve()
        for p, _ in self.specs:
            if p.resolve() == out:
                raise FacesimError(f"{args.output}: also a source; write the edit into another folder")

    def read(self, i: int):
        from facesim.anim.sequence import read_sequence

        (path, span), a = self.specs[i], self.args
        seq = read_sequence(path, self.model, jaw=self.jaw[i], jaw_model=a.jaw_model if path.is_file() else None,
                            fps=a.source_fps, model_path=a.model)
        return seq if span is None else seq.segment(*span)

    def all(self):
        return [self.read(i) for i in range(len(self.specs))]


# ------------------------------------------------------------------ the commands
def cmd_blend(args) -> int:
    import numpy as np

    from facesim.anim.edits import blend

    model = _load_model(args.model)
    a, b = _Sources(args, model, [args.a, args.b]).all()
    t = args.t
    if isinstance(t, tuple):
        n = max(a.n_frames, b.n_frames)
        t = np.linspace(t[0], t[1], n) if n > 1 else np.array([t[0]])
    return _finish(args, model, blend(a, b, t), {"operation": "blend", "sources": [args.a, args.b], "t": args.t})


def cmd_keyframe(args) -> int:
    from facesim.anim.edits import keyframes

    model = _load_model(args.model)
    sources = _Sources(args, model, [k[0] for k in args.key])
    keys, times = [], []
    for i, (src, frame, at) in enumerate(args.key):
        frame, at = _key_number(frame, "FRAME", src), _key_number(at, "AT", src)
        keys.append(sources.read(i).at(frame))
        times.append(at)
    seq = keyframes(keys, times, args.method)
    return _finish(args, model, seq, {"operation": "keyframe", "method": args.method,
                                      "keys": [{"source": s, "frame": int(f), "at": int(t)} for s, f, t in args.key]})


def _key_number(text: str, what: str, src: str) -> int:
    if not re.fullmatch(r"\d+", text.strip()):
        raise FacesimError(f"--key {src}: {what} {text!r}; expected a frame number (a whole number >= 0)")
    return int(text)


def cmd_scale(args) -> int:
    from facesim.anim.edits import scale

    model = _load_model(args.model)
    (src,) = _Sources(args, model, [args.source]).all()
    seq = scale(src, args.factor, args.muscles, jaw=args.with_jaw)
    return _finish(args, model, seq, {"operation": "scale", "sources": [args.source], "factor": args.factor,
                                      "muscles": args.muscles, "with_jaw": args.with_jaw})


def cmd_gain(args) -> int:
    from facesim.anim.edits import gain

    model = _load_model(args.model)
    (src,) = _Sources(args, model, [args.source]).all()
    seq = gain(src, args.factor, args.muscles)
    return _finish(args, model, seq, {"operation": "gain", "sources": [args.source], "factor": args.factor,
                                      "muscles": args.muscles})


def cmd_splice(args) -> int:
    from facesim.anim.edits import concatenate, splice

    model = _load_model(args.model)
    if len(args.sources) < 2:
        raise FacesimError("splice: expected at least two sources")
    if args.at is not None and len(args.sources) != 2:
        raise FacesimError(f"splice --at: expected two sources, got {len(args.sources)} (without --at, any number "
                           "follow one another)")
    seqs = _Sources(args, model, args.sources).all()
    seq = splice(*seqs, args.at, args.crossfade) if args.at is not None else concatenate(seqs, args.crossfade)
    return _finish(args, model, seq, {"operation": "splice", "sources": list(args.sources), "at": args.at,
                                      "crossfade": args.crossfade})


def cmd_retime(args) -> int:
    from facesim.anim.edits import retime

    model = _load_model(args.model)
    (src,) = _Sources(args, model, [args.source]).all()
    seq = retime(src, args.fps, args.method)
    return _finish(args, model, seq, {"operation": "retime", "sources": [args.source], "from_fps": src.fps,
                                      "fps": args.fps, "method": args.method})


def cmd_mirror(args) -> int:
    from facesim.anim.symmetry import mirror

    model = _load_model(args.model)
    (src,) = _Sources(args, model, [args.source]).all()
    return _finish(args, model, mirror(src, model, args.model), {"operation": "mirror", "sources": [args.source]})


# ------------------------------------------------------------------ output
def _finish(args, model, seq, info: dict) -> int:
    """Write ``seq`` into ``args.output`` and, with ``--simulate``, simulate it into ``OUT/sim``."""
    from facesim.anim.sequence import SIM_FOLDER, write_sequence

    contact = json.loads(seq.setup) if seq.setup else {}
    colliders = contact.get("colliders") or []
    frame = None
    if args.simulate:   # before anything is written: a model without an input frame is one line
        from facesim.output_frame import output_frame

        frame = output_frame(model, args.output_frame, args.model)
    elif args.output_frame != "facesim":
        print("facesim: warning: --output-frame is ignored without --simulate", file=sys.stderr)
    if args.simulate and colliders:
        raise FacesimError(f"--simulate: the sources were solved with {len(colliders)} external collider(s), which a "
                           "controls folder does not carry; run 'facesim simulate --controls-from OUT_DIR' with the "
                           "solve's --collider specs instead")
    out = write_sequence(args.output, seq, model, overwrite=args.overwrite, resume=args.resume, info=info)
    files = ["activations.csv", "jaw.csv"] + (["head.csv"] if seq.head is not None else []) + \
        (["gain.csv"] if (seq.gain != 1.0).any() else []) + ["report.json", "run.json"]
    print(f"edit {info['operation']}: {seq.n_frames} frames ({seq.frames[0]}..{seq.frames[-1]}) at {seq.fps:g} Hz -> "
          f"{out}/: {', '.join(files)}")
    if seq.jaw_model.posed and seq.jaw is not None:
        print(f"note: the rigid jaw poses are in {out}/jaw.csv (frame,rx,ry,rz,tx,ty,tz); simulate --controls-from "
              "keeps a rigid jaw at rest: use --simulate, or simulate --activations/--jaw/--jaw-model rigid")
    if seq.rebound:
        print("note: a source bound its markers to the capture (--bind-frames); simulations use the model's markers")
    if not args.simulate:
        return 0
    return _simulate(args, model, seq, out / SIM_FOLDER, contact, frame)


def _simulate(args, model, seq, folder: Path, contact: dict, frame=None) -> int:
    from facesim.budget import default_frame_seconds
    from facesim.constants import CONTACT_STIFFNESS
    from facesim.fem.newton import NewtonOptions
    from facesim.simulate import SimulateOptions, simulate

    options = SimulateOptions(newton=NewtonOptions(linear_solver=args.solver, max_seconds=default_frame_seconds(model)),
                              fps=seq.fps, teeth_contact=bool(contact.get("teeth_contact")),
                              lip_contact=bool(contact.get("lip_contact")),
                              contact_stiffness=float(contact.get("contact_stiffness") or CONTACT_STIFFNESS))
    jaw_model = seq.jaw_model.build(model, args.model)
    s = simulate(model, seq.A, folder, frames=seq.frames, jaw=seq.jaw, jaw_model=jaw_model, options=options,
                 resume=args.resume, overwrite=args.overwrite, progress=not args.quiet, gain=seq.gain,
                 info={"model": str(args.model), "controls_from": str(args.output),
                       "activations": str(Path(args.output) / "activations.csv"),
                       "jaw": str(Path(args.output) / "jaw.csv") if seq.jaw is not None else None},
                 output_frame=frame or "facesim")
    reused = f", {s['reused_frames']} reused from the earlier run" if s["reused_frames"] else ""
    print(f"simulated {s['frames']} frames ({s['converged']} of {s['finished_frames']} converged{reused}) in "
          f"{s['wall_seconds']:.1f} s -> {folder}")
    if s["unconverged_frames"]:
        print(f"facesim: warning: {len(s['unconverged_frames'])} frame(s) did not converge "
              f"({', '.join(map(str, s['unconverged_frames'][:10]))}); see {folder / 'frames.csv'}", file=sys.stderr)
    return 0


__all__ = ["OPERATIONS", "add_parsers", "cmd_blend", "cmd_gain", "cmd_keyframe", "cmd_mirror", "cmd_retime",
           "cmd_scale", "cmd_splice"]
