"""The ``facesim`` command.

Every sub-command has ``--help``. User mistakes (missing or malformed files, bad options)
print one line ``facesim: error: <message>`` to stderr and exit with status 2, never a
traceback. Heavy modules (the anatomy builder, pyvista) are imported only by the commands
that need them, so ``facesim --help`` and ``facesim model info`` start fast.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import facesim
from facesim._files import MESHES, require_suffix
from facesim import _argtypes as argtypes
from facesim.constants import CONTACT_STIFFNESS
from facesim.errors import FacesimError, ModelFileError, SolverError
from facesim.anim.cli import add_parsers as add_edit_commands
from facesim.jaw.cli import add_jaw_commands
from facesim.teeth.cli import add_teeth_commands

RESOLUTIONS = ("test", "coarse", "medium", "paper")
#: Environment variable naming the model ``facesim demo`` uses instead of the shipped one.
MODEL_ENV = "FACESIM_MODEL"
EXIT_USAGE = 2
EXIT_SOLVER = 1   # a numerical failure outside a frame
EXIT_INTERNAL = 3   # a bug: an exception facesim did not expect
#: Environment variable that lets an unexpected exception show its traceback.
DEBUG_ENV = "FACESIM_DEBUG"


# ------------------------------------------------------------------ helpers
class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line (sub-parsers inherit the class)."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def default_model_path() -> Path:
    """The model ``facesim demo`` runs on: ``$FACESIM_MODEL`` if set, else the shipped
    ``meshes/face_coarse.npz`` of the repository holding the ``facesim`` package."""
    env = os.environ.get(MODEL_ENV)
    if env:
        return Path(env)
    return MESHES / "face_coarse.npz"


def _size(text: str) -> tuple[int, int]:
    """argparse type for ``WIDTHxHEIGHT`` in pixels."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 1200x1200, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"expected a size between 16 and 8192 pixels per side, got {text!r}")
    return w, h


_positive = argtypes.positive   # argparse types: a number > 0 and <= a maximum, an integer in a range
_count = argtypes.integer


def _span(text: str) -> str:
    """argparse type for FIRST:LAST frame ranges: not empty (checked against the frames later)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected FIRST:LAST frame numbers, e.g. 0:9, got an empty range")
    return text


def _folder(text: str) -> str:
    """argparse type for an output folder: not empty (an empty name would write into the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return text


def _opacity(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return v


def _fps(text: str) -> float:
    """argparse type for a frame rate in Hz."""
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not (0.0 < v <= 10000.0):
        raise argparse.ArgumentTypeError(f"expected a frame rate in Hz > 0, got {text!r}")
    return v


def _load(path):
    """The model at ``path`` (:func:`facesim.model.load_model`: any unreadable file is one line)."""
    from facesim.model import load_model

    return load_model(path)


# ------------------------------------------------------------------ model info
def model_summary(model, path=None) -> dict:
    """JSON-serialisable description of a model: sizes, names, attachments, quality, bounds (mm)."""
    from facesim.anatomy.quality import quality_summary

    lo, hi = model.bounding_box()
    volumes = model.tet_volumes()
    mus = model.muscles
    tets_per_muscle = mus.tets_per_muscle()
    volume_per_muscle = mus.volume_per_muscle(volumes)
    summary = {
        "file": str(path) if path is not None else None,
        "n_nodes": model.n_nodes,
        "n_tets": model.n_tets,
        "n_simulated_tets": model.n_simulated,
        "n_muscles": model.n_muscles,
        "n_markers": model.n_markers,
        "n_head_markers": int(model.markers.head.sum()),
        "n_cranium_nodes": int(len(model.cranium_nodes)),
        "n_jaw_nodes": int(len(model.jaw_nodes)),
        "n_free_nodes": int(model.n_nodes - len(model.cranium_nodes) - len(model.jaw_nodes)),
        "n_skin_triangles": int(len(model.skin)),
        "volume_mm3": float(volumes.sum()),
        "muscles": [
            {"name": name, "side": side, "n_tets": int(tets_per_muscle[i]),
             "volume_mm3": float(volume_per_muscle[i]), "sigma_max_mpa": float(mus.sigma_max[i])}
            for i, (name, side) in enumerate(zip(mus.names, mus.sides))
        ],
        "markers": [{"name": name, "head": bool(head)} for name, head in zip(model.markers.names, model.markers.head)],
        "tissues": [{"name": t.name, "n_tets": int((model.tissue == i).sum()), "c10_mpa": t.c10, "c01_mpa": t.c01,
                     "kappa_mpa": t.kappa} for i, t in enumerate(model.tissues)],
        "surfaces": [{"name": s.name, "bone": s.bone, "kind": kind, "n_triangles": int(len(s.faces))}
                     for kind, group in (("bone", model.bones), ("collider", model.colliders)) for s in group],
        "quality": quality_summary(model.X, model.tets) if model.n_tets else None,
        "bounding_box_mm": {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist()},
        "build": model.meta,
    }
    return summary


def _fmt_names(items: list[str], width: int = 96, indent: str = "  ") -> str:
    lines, line = [], indent
    for item in items:
        if len(line) + len(item) + 2 > width and line.strip():
            lines.append(line.rstrip())
            line = indent
        line += item + "  "
    lines.append(line.rstrip())
    return "\n".join(lines)


def format_summary(s: dict) -> str:
    """Human-readable table of :func:`model_summary`."""
    q = s["quality"]
    bb = s["bounding_box_mm"]
    rows = [
        ("model", s["file"] or "(in memory)"),
        ("nodes", f"{s['n_nodes']:,}  (cranium-attached {s['n_cranium_nodes']:,}, jaw-attached "
                  f"{s['n_jaw_nodes']:,}, free {s['n_free_nodes']:,})"),
        ("tets", f"{s['n_tets']:,}  (simulated {s['n_simulated_tets']:,})"),
        ("volume", f"{s['volume_mm3'] / 1e3:,.1f} cm^3"),
        ("skin", f"{s['n_skin_triangles']:,} triangles"),
        ("muscles", f"{s['n_muscles']}"),
        ("markers", f"{s['n_markers']}  (head {s['n_head_markers']})"),
        ("tissues", ", ".join(f"{t['name']} ({t['n_tets']:,} tets)" for t in s["tissues"])),
        ("surfaces", ", ".join(f"{x['name']} ({x['kind']}, {x['bone']})" for x in s["surfaces"]) or "none"),
        ("bounding box", "  ".join(f"{a} [{lo:.1f}, {hi:.1f}]" for a, lo, hi in zip("xyz", bb["min"], bb["max"]))
         + " mm  (size " + " x ".join(f"{v:.1f}" for v in bb["size"]) + " mm)"),
    ]
    if q:
        rows.append(("mesh quality", f"dihedral angles {q['min_dihedral_deg']:.1f}..{q['max_dihedral_deg']:.1f} deg, "
                                     f"volume ratio worst {q['worst_volume_ratio']:.3f} mean "
                                     f"{q['mean_volume_ratio']:.3f}"))
        rows.append(("", f"inverted {q['n_inverted']}, degenerate {q['n_degenerate']}, "
                         f"smallest tet {q['min_volume_mm3']:.3g} mm^3"))
    if s["build"]:
        rows.append(("build", ", ".join(f"{k}={v}" for k, v in s["build"].items()
                                        if isinstance(v, (str, int, float, bool)))))
    imported = s["build"].get("import") if s["build"] else None
    if isinstance(imported, dict):   # facesim model import: where it came from
        inputs = {k: v for k, v in imported.get("inputs", {}).items() if v}
        rows.append(("imported from", "; ".join(f"{k} {', '.join(v) if isinstance(v, list) else v}"
                                                for k, v in inputs.items())))
        frame = imported.get("input_frame", {})
        rows.append(("", f"{imported.get('route', {}).get('route')} route; units {imported.get('units', {}).get('name')}"
                         f"; frame {frame.get('how')}; fix-boundary {imported.get('fix_boundary')}"))
    out = [f"{k:<14}{v}" for k, v in rows]
    if s["muscles"]:
        out.append("")
        out.append(f"{'muscle':<44}{'side':>5}{'tets':>9}{'volume mm^3':>14}{'sigma_max MPa':>15}")
        for m in s["muscles"]:
            out.append(f"{m['name']:<44}{m['side']:>5}{m['n_tets']:>9,}{m['volume_mm3']:>14,.0f}"
                       f"{m['sigma_max_mpa']:>15.3f}")
    if s["markers"]:
        out.append("")
        out.append("markers (* = head marker, used to stabilise the head):")
        out.append(_fmt_names([m["name"] + ("*" if m["head"] else "") for m in s["markers"]]))
    return "\n".join(out)


# ------------------------------------------------------------------ commands
def cmd_model_build(args) -> int:
    out = require_suffix(args.output, (".npz",), "a model file name")
    import facesim.anatomy as anatomy

    build_head = getattr(anatomy, "build_head", None)
    if build_head is None:
        raise FacesimError("model build: this installation has no anatomy builder (facesim.anatomy.build_head)")
    mesh = None
    if args.refine and not args.mesh_from:
        raise FacesimError("--refine: refines the mesh of --mesh-from OLD.npz; name that model")
    if args.refine < 0:
        raise FacesimError(f"--refine: expected a number of 1:8 refinements >= 0, got {args.refine}")
    if args.mesh_from:
        src = _load(args.mesh_from)
        # a refined mesh may serve another resolution (e.g. paper from medium); its seed must match
        same_resolution = args.refine or src.meta.get("resolution") in (None, args.resolution)
        if src.meta.get("seed") not in (None, args.seed) or not same_resolution:
            raise FacesimError(f"{args.mesh_from}: --mesh-from model was built with seed {src.meta.get('seed')} at "
                               f"resolution {src.meta.get('resolution')}, expected seed {args.seed} at {args.resolution}")
        mesh = (src.X, src.tets)
        if args.refine:
            from facesim.anatomy.meshing import refine_tets

            for _ in range(args.refine):
                mesh = refine_tets(*mesh)
    t0 = time.perf_counter()

    def say(msg):
        print(f"[{time.perf_counter() - t0:7.1f} s] {msg}", file=sys.stderr, flush=True)

    model = build_head(resolution=args.resolution, seed=args.seed, progress=None if args.quiet else say,
                       mesh=mesh)
    if args.refine:
        model.meta["mesher"] = f"{Path(args.mesh_from).name}'s mesh refined 1:8 {args.refine}x (meshing.refine_tets)"
    seconds = time.perf_counter() - t0
    model.save(out)
    print(f"built {args.resolution} head (seed {args.seed}) in {seconds:.1f} s: {model.n_nodes:,} nodes, "
          f"{model.n_tets:,} tets ({model.n_simulated:,} simulated), {model.n_muscles} muscles, "
          f"{model.n_markers} markers -> {out}")
    return 0


def cmd_model_info(args) -> int:
    summary = model_summary(_load(args.model), args.model)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(format_summary(summary))
    return 0


def cmd_model_export(args) -> int:
    from facesim.export import export_skin, export_surfaces, export_volume

    if args.output is None and args.surfaces is None:
        raise FacesimError("model export: nothing to do; give -o OUT.{vtu,ply,obj} and/or --surfaces DIR")
    out = None
    if args.output is not None:
        out = require_suffix(args.output, (".vtu", ".ply", ".obj"), "an export file name")
    model = _load(args.model)
    frame = _output_frame(args, model)
    where = "" if frame.is_identity else f" in {frame.said()}"
    if out is not None:
        if out.suffix.lower() == ".vtu":
            export_volume(model, out, frame=frame)
            print(f"wrote volume mesh ({model.n_tets:,} tets){where} -> {out}")
        else:
            export_skin(model, out, frame=frame)
            print(f"wrote skin ({len(model.skin):,} triangles){where} -> {out}")
    if args.surfaces is not None:
        paths = export_surfaces(model, args.surfaces, frame=frame)
        print(f"wrote {len(paths)} rigid surfaces{where} -> {args.surfaces}")
        for p in paths:
            print(f"  {p}")
    return 0


def _layers(hide: str | None) -> tuple[str, ...]:
    from facesim.viz.render import LAYERS

    hidden = [h.strip() for h in (hide or "").split(",") if h.strip()]
    unknown = [h for h in hidden if h not in LAYERS]
    if unknown:
        raise FacesimError(f"--hide: unknown layer {unknown[0]!r}; expected some of {','.join(LAYERS)}")
    return tuple(layer for layer in LAYERS if layer not in hidden)


def cmd_model_render(args) -> int:
    out = require_suffix(args.output, (".png",), "a picture file name")
    show = _layers(args.hide)
    from facesim.viz.render import render_contact_sheet, render_model

    if args.color_by != "none":
        raise FacesimError(f"--color-by {args.color_by}: a model at rest has no "
                           f"{'activations' if args.color_by == 'activation' else 'displacement'}; colour a solved "
                           "or simulated frame with 'facesim simulate --render --color-by ...' or 'facesim solve-mocap "
                           "--render --color-by ...'")
    _warn_ignored(args, [("opacity", "skin" not in show, "with --hide skin"), ("view", args.sheet, "with --sheet")])
    model = _load(args.model)
    if args.sheet:
        size = args.size or (600, 600)
        render_contact_sheet(model, out, show=show, skin_opacity=args.opacity, tile_size=size,
                             progress=not args.quiet, legend=not args.no_legend)
    else:
        render_model(model, out, view=args.view, show=show, skin_opacity=args.opacity,
                     size=args.size or (1200, 1200), legend=not args.no_legend)
    print(f"wrote {out}")
    return 0


def cmd_simulate(args) -> int:
    from facesim.controls_io import check_same_frames, read_activations_csv, read_jaw_csv

    render = args.render or args.video
    contact = args.teeth_contact or args.lip_contact or args.collider or args.controls_from is not None
    _warn_ignored(args, [("view", not render, "without --render or --video"),
                         ("size", not render, "without --render or --video"),
                         ("color_by", not render, "without --render or --video"),
                         ("contact_stiffness", not contact, "without --teeth-contact, --lip-contact or --collider"),
                         *((name, not args.dynamic, "without --dynamic")
                           for name in ("substeps", "soften", "density", "damping", "integrator"))])
    model = _load(args.model)
    frame = _output_frame(args, model)
    if args.controls_from is not None:
        return _simulate_solved(args, model, frame)
    if args.activations is None:
        raise FacesimError("simulate: give the controls: --activations A.csv (and --jaw J.csv), or --controls-from "
                           "OUT_DIR of a solve-mocap run")
    frames, A = read_activations_csv(args.activations, model.muscles.names)
    jaw_model = args.jaw_model or "rigid"
    if jaw_model == "posselt":   # the model's own rig: the file beside the model, or the shipped one
        from facesim.kinematics.jaw_models import make_jaw_model

        jaw_model = make_jaw_model(model, "posselt", model_path=args.model)
    T = None
    if args.jaw:
        jaw_frames, T = read_jaw_csv(args.jaw, model, jaw_model)
        check_same_frames(args.jaw, jaw_frames, args.activations, frames)
    colliders = _colliders(args, Path(args.activations).parent)   # simulate() checks poses and colliders
    options = _simulate_options(args, model)
    head = _head_motion(args, frames, args.activations)
    info = {"model": str(args.model), "activations": str(args.activations),
            "jaw": str(args.jaw) if args.jaw else None, "collider_specs": list(args.collider),
            "head": None if head is None else str(args.head)}
    return _run_simulate(args, model, A, frames, T, jaw_model, colliders, options, info, head=head, frame=frame)


def _output_frame(args, model):
    """The :class:`~facesim.output_frame.OutputFrame` of ``--output-frame`` for ``model`` (the file
    ``args.model``): a model that was not imported has no input frame (one line)."""
    from facesim.output_frame import output_frame

    return output_frame(model, args.output_frame, args.model)


def _head_motion(args, frames, reference, default=None):
    """simulate --head: the head poses ``(F, 4, 4)`` of the file (its frames those of
    ``reference``), None for ``--head rest``, or ``default`` (a path) when --head is not given."""
    from facesim.controls_io import check_same_frames, read_head_csv

    path = args.head if args.head is not None else default
    if path is None or path == "rest":
        return None
    head_frames, H = read_head_csv(path)
    check_same_frames(path, head_frames, reference, frames)
    args.head = str(path)
    return H


def _simulate_options(args, model, teeth: bool = False, lips: bool = False, stiffness=None):
    from facesim.fem.newton import NewtonOptions
    from facesim.simulate import SimulateOptions

    return SimulateOptions(newton=NewtonOptions(linear_solver=args.solver, max_seconds=_frame_seconds(args, model)),
                           fps=args.fps, render=args.render or args.video, video=args.video, view=args.view,
                           size=args.size, teeth_contact=args.teeth_contact or teeth,
                           lip_contact=args.lip_contact or lips, contact_stiffness=stiffness or args.contact_stiffness,
                           color_by=args.color_by, dynamic=args.dynamic, substeps=args.substeps, damping=args.damping,
                           soften=tuple(args.soften), density=tuple(args.density), integrator=args.integrator)


def _simulate_solved(args, model, frame) -> int:
    """simulate --controls-from OUT_DIR: the frames a solve-mocap run solved, with its jaw model and
    contact set-up, in the model frame (the solve stabilised the head)."""
    from facesim.controls_io import read_replay

    given = [name for name, v in (("--activations", args.activations), ("--jaw", args.jaw),
                                  ("--jaw-model", args.jaw_model)) if v is not None]
    if given:
        raise FacesimError(f"--controls-from: excludes {', '.join(given)} (the solve's controls and jaw model are "
                           "read from OUT_DIR)")
    r = read_replay(args.controls_from, model, args.model)
    colliders = _colliders(args, Path(args.controls_from))
    if len(colliders) != r.n_colliders:
        raise FacesimError(f"--controls-from: the run was solved with {r.n_colliders} collider(s), {len(colliders)} "
                           "given; give the solve's --collider specs again")
    if r.rebound:
        print("note: the solve bound its markers to the capture (--bind-frames); the markers written here are the "
              "model's own placement")
    options = _simulate_options(args, model, r.teeth_contact, r.lip_contact, r.contact_stiffness)
    info = {"model": str(args.model), "controls_from": str(args.controls_from),
            "activations": str(Path(args.controls_from) / "activations.csv"),
            "jaw": str(Path(args.controls_from) / "jaw.csv") if r.jaw is not None else None,
            "collider_specs": list(args.collider)}
    solved = Path(args.controls_from) / "head.csv"
    head = _head_motion(args, r.frames, Path(args.controls_from) / "activations.csv",
                        solved if solved.is_file() else None)
    info["head"] = None if head is None else str(args.head)
    return _run_simulate(args, model, r.A, r.frames, r.jaw, r.jaw_model, colliders, options, info, gain=r.gain,
                         head=head, frame=frame)


def _run_simulate(args, model, A, frames, T, jaw_model, colliders, options, info, gain=None, head=None,
                  frame=None) -> int:
    from facesim.simulate import simulate

    s = simulate(model, A, args.output, frames=frames, jaw=T, jaw_model=jaw_model, colliders=colliders,
                 options=options, resume=args.resume, overwrite=args.overwrite, progress=not args.quiet, info=info,
                 gain=gain, head=head, output_frame=frame or "facesim")
    reused = f", {s['reused_frames']} reused from the earlier run" if s["reused_frames"] else ""
    where = "" if frame is None or frame.is_identity else f"; skin and markers in {frame.said()}"
    print(f"simulated {s['frames']} frames ({s['converged']} of {s['finished_frames']} converged{reused}) in "
          f"{s['wall_seconds']:.1f} s -> {args.output}{where}")
    if s.get("video_note"):
        print(f"video: {s['video_note']}")
    elif "video" in s["outputs"]:
        print(f"video: {s['outputs']['video']}")
    _warn_unconverged(s, Path(args.output) / "frames.csv")
    return 0


def cmd_export_cache(args) -> int:
    from facesim.caches import export_cache

    model = _load(args.model)
    frame = _output_frame(args, model)
    s = export_cache(args.run, model, usd=args.usd, pvd=args.pvd, c3d=args.c3d, fps=args.fps, output_frame=frame)
    skipped = f"; {len(s['unconverged_frames'])} did not converge and show the last converged frame" \
        if s["unconverged_frames"] else ""
    where = "" if frame.is_identity else f" in {frame.said()}"
    print(f"cached {s['frames']} frames of {args.run} at {s['fps']:g} fps{where}{skipped}")
    for kind in ("usd", "pvd", "c3d"):
        if s[kind]:
            print(f"  {kind}: {s[kind]}")
    return 0


def _jaw_prior(args, markers, spec):
    """The :class:`~facesim.inverse.jaw_prior.JawPrior` of ``--jaw-prior`` (None without it), for a
    model whose markers are ``markers`` (a FaceModel or a MarkerSet)."""
    if args.jaw_prior is None:
        return None
    from facesim.inverse.jaw_prior import JawPrior
    from facesim.jaw.markerless import load_predictor
    from facesim.jaw.markerless_features import bone_rest_points

    if spec.build().jaw_model.n_params == 0:
        raise FacesimError(f"--jaw-prior: the jaw model {args.jaw_model!r} has no parameters to draw to the predicted "
                           "jaw; use e.g. --jaw-model sliding-condyle")
    pred = load_predictor(args.jaw_prior)
    names = tuple(getattr(markers, "markers", markers).names)
    try:
        return JawPrior(pred, bone_rest_points(_load(args.model)), names, sigma=args.jaw_prior_sigma)
    except FacesimError as exc:
        raise FacesimError(f"{args.jaw_prior}: {exc}") from None


def cmd_solve_mocap(args) -> int:
    from contextlib import nullcontext

    import numpy as np

    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.fem.newton import NewtonOptions
    from facesim.inverse.gauss_newton import FitOptions
    from facesim.inverse.parallel import SimulatorSpec, dask_client
    from facesim.fem.plausible import check_colliders
    from facesim.inverse.tracking import TrackOptions, track
    from facesim.mocap.binding import bind_neutral, match_markers, with_markers
    from facesim.mocap.io import check_capture_scale, frame_mask, marker_spread, read_markers
    from facesim.viz.plots import plot_track

    _warn_ignored(args, [("loss_scale", args.loss == "l2", "with --loss l2"),
                         ("head_smoothing", args.head != "procrustes", f"with --head {args.head}"),
                         ("color_by", not args.render, "without --render"),
                         ("output_frame", not args.write_meshes, "without --write-meshes"),
                         ("contact_stiffness", args.no_contact and not args.collider,
                          "with --no-contact and no --collider")])
    model = _load(args.model)
    frame = _output_frame(args, model) if args.write_meshes else None
    data = read_markers(args.markers, units=args.units)
    index, extra, missing = match_markers(model.markers.names, data.names)
    layout = None
    if _capture_layout(args, int((index >= 0).sum())):
        layout = _fit_capture_layout(args, model, data)
        P, frames, neutral = layout.to_model(data.P), data.frames, None   # bound to the neutral frames already
    else:
        if (index >= 0).sum() < 3:
            raise FacesimError(f"{args.markers}: only {int((index >= 0).sum())} of the model's {model.n_markers} "
                               f"marker names found (file has {', '.join(data.names[:5])}...); expected the model's "
                               "names ('facesim model info' lists them), or --layout capture")
        matched = index >= 0   # the capture's size against the model's, on the markers both have (a unit mistake)
        check_capture_scale(data.select([data.names[j] for j in index[matched]]),
                            marker_spread(model.marker_positions()[matched])[0], args.markers, units_given=args.units)
        if extra or missing:
            print(f"markers: {int((index >= 0).sum())} matched; not in the model: {', '.join(extra) or '-'}; "
                  f"not in the file: {', '.join(missing) or '-'}")
        P = np.full((len(data.frames), model.n_markers, 3), np.nan)
        P[:, index >= 0] = data.P[:, index[index >= 0]]
        frames = data.frames
        # rebind the model's markers to the capture's neutral frames
        neutral = P[frame_mask(args.bind_frames, frames, "--bind-frames")] if args.bind_frames is not None else None
    if args.frames is not None:
        keep = frame_mask(args.frames, frames, "--frames")
        frames, P = frames[keep], P[keep]
    # workers build their simulator from the spec (model path, options); built here first, so a bad
    # jaw model fails before any worker starts
    setup = EquilibriumOptions(newton=NewtonOptions(linear_solver=args.solver),
                               **_mocap_contact(args, model, Path(args.markers).parent))
    spec = SimulatorSpec.of(args.model, setup, args.jaw_model)
    check_colliders(model, setup.colliders, frames)
    spec.build()
    options = TrackOptions(fit=FitOptions(noise=args.noise, max_steps=args.max_steps,
                                          max_seconds=_frame_seconds(args, model)), head=args.head,
                           robust=not args.no_robust, loss=args.loss, loss_scale=args.loss_scale,
                           chunk_size=args.chunk_size, head_smoothing=args.head_smoothing,
                           write_meshes=args.write_meshes,
                           jaw_prior=_jaw_prior(args, model if layout is None else layout.markers, spec),
                           coarse_model=_coarse_model(args, spec, layout))
    parallel = args.workers is not None or args.scheduler is not None
    if layout is not None and parallel:
        raise FacesimError("--workers/--scheduler: not yet supported with the capture's own marker layout; "
                           "solve it without them")
    solver = spec if layout is None else with_markers(spec.build(), layout.markers)
    with dask_client(args.workers, args.scheduler) if parallel else nullcontext() as client:
        s = track(solver, frames, P, args.output, options=options, resume=args.resume, overwrite=args.overwrite,
                  progress=not args.quiet, client=client, neutral=neutral,
                  info={"model": str(args.model), "markers": str(args.markers), "jaw_model": args.jaw_model,
                        **({"coarse_model": options.coarse_model} if options.coarse_model else {}),
                        "frames": args.frames, "bind_frames": args.bind_frames, "units": args.units},
                  fps=data.rate or 30.0, output_frame=frame or "facesim")
    plot_track(args.output)
    if layout is not None:
        _write_placement(args.output, solver.model, layout)
    if args.render:
        from facesim.viz.solve import render_solve

        sim = solver if layout is not None else \
            spec.build() if neutral is None else bind_neutral(spec.build(), neutral, args.head)[0]   # as solved
        video = render_solve(sim, args.output, frames, P, head=args.head, head_smoothing=args.head_smoothing,
                             fps=data.rate or 30.0, color_by=args.color_by,
                             progress=not args.quiet)
        print(f"video: {video}")
    if s["outliers"]:
        print(f"outlier markers: {sum(map(len, s['outliers'].values()))} in {len(s['outliers'])} of {len(frames)} "
              f"frames ({'dropped, frames refitted' if options.robust else 'kept in the fit'}; see report.json)")
    rms = s["marker_rms"]
    quality = f"; marker RMS median {np.median(rms):.3f} mm" if rms else ""
    print(f"solved {s['solved_frames']} frames ({s['reused_frames']} reused) in {s['seconds']:.1f} s{quality} "
          f"-> {args.output}")
    _warn_unconverged(s, Path(args.output) / "frames.csv")
    return 0


#: solve-mocap suggests --coarse-model for models of at least this many simulated tets (the
#: paper-size face has 824K; on the medium face, 103K, a coarse start gained or lost a third)
COARSE_HINT_ABOVE = 300_000


def _coarse_model(args, spec, layout) -> str | tuple[str, ...] | None:
    """``--coarse-model``'s path (or paths, when repeated), checked here against the model (same
    muscles and jaw, its mesh covering the model's, the markers placeable on its skin; several:
    each coarser than the next) so a mismatch fails before any frame."""
    if not args.coarse_model:
        n = spec.build().model.n_simulated
        if n >= COARSE_HINT_ABOVE and not args.quiet:
            print(f"facesim: note: a large model ({n:,} simulated tets): a cold frame (the first, each chunk's "
                  "first) takes minutes on it; --coarse-model COARSE.npz (a coarser model of the same face, e.g. the "
                  "one it was refined from) fits them there first, 2.6x faster on the paper-size face (docs/cli.md)",
                  file=sys.stderr)
        return None
    from facesim.inverse.coarse import CoarseStart
    from facesim.mocap.binding import with_markers

    paths = [str(p) for p in args.coarse_model]
    resolved = [Path(p).resolve() for p in paths]
    for path, where in zip(paths, resolved):
        if where == Path(args.model).resolve():
            raise FacesimError(f"--coarse-model: {path} is the model itself; name a coarser model of "
                               "the same face (e.g. the one it was refined from with 'model build --refine')")
    for k, path in enumerate(paths):
        if resolved[k] in resolved[:k]:
            raise FacesimError(f"--coarse-model: {path} is named twice")
    sim = spec.build() if layout is None else with_markers(spec.build(), layout.markers)
    CoarseStart.chain(sim, [_load(p) for p in paths], paths)
    return paths[0] if len(paths) == 1 else tuple(paths)


def _capture_layout(args, matched: int) -> bool:
    """solve-mocap on the capture's own markers (registered and bound to the skin) rather than the
    model's: --layout capture, --head-markers or --marker-map, or (--layout auto) fewer than 3 of
    the capture's names are the model's."""
    if args.layout == "model":
        for name, value in (("--head-markers", args.head_markers), ("--marker-map", args.marker_map)):
            if value:
                raise FacesimError(f"{name}: needs the capture's own layout; leave out --layout model")
        return False
    return args.layout == "capture" or bool(args.head_markers) or bool(args.marker_map) or matched < 3


def _fit_capture_layout(args, model, data):
    """The capture's own layout on the model (:func:`facesim.mocap.layout.fit_layout`), printed."""
    import numpy as np

    from facesim.mocap.io import check_capture_scale, frame_mask, marker_spread
    from facesim.mocap.layout import DEFAULT_BIND_FRAMES, fit_layout, read_marker_map

    if model.n_markers >= 3:   # a unit mistake: the capture's size against the model's markers'
        check_capture_scale(data, marker_spread(model.marker_positions())[0], args.markers, units_given=args.units)
    if args.bind_frames is not None:
        bind, said = frame_mask(args.bind_frames, data.frames, "--bind-frames"), f"--bind-frames {args.bind_frames}"
    else:
        bind = np.arange(len(data.frames)) < DEFAULT_BIND_FRAMES
        said = f"the first {int(bind.sum())} frames (--bind-frames to choose)"
    heads = [h.strip() for h in args.head_markers.split(",") if h.strip()] if args.head_markers else None
    mapping = read_marker_map(args.marker_map) if args.marker_map else None
    layout = fit_layout(model, data.names, data.P, bind, head_names=heads, marker_map=mapping,
                        similarity=args.similarity, noise=args.noise, min_head=0 if args.head == "solve" else 3)
    r = layout.registration
    print(f"layout: the capture's own {len(data.names)} markers; neutral: {said}")
    print(f"head markers ({layout.head_source}): {', '.join(layout.head) or 'none (the head is solved)'}")
    print(f"registration to the skin: RMS {r.rms:.2f} mm, max {r.max:.2f} mm over {int(r.kept.sum())} markers "
          f"(rotation {r.summary()['rotation_deg']:.1f} deg" + (f", scale {r.scale:.4f}" if args.similarity else "")
          + ")" + (f"; {len(layout.mapped)} mapped to the model's markers" if layout.mapped else ""))
    skin = [row["distance_mm"] for row in layout.rows if row["role"] == "skin"]
    print(f"placed {layout.markers.n_markers} markers ({int(layout.markers.head.sum())} head, {len(skin)} skin; skin "
          f"markers {np.median(skin) if skin else 0:.2f} mm from the skin (median), {max(skin, default=0):.2f} max)")
    for name, why in layout.rejected.items():
        print(f"  refused {name}: {why}")
    _warn_head_spread(model.with_(markers=layout.markers))
    return layout


#: Second principal spread (RMS, mm) of the head markers below which the head's rotation is poorly
#: determined by them (markers nearly on a line; the model's own six spread 112, 68 and 40 mm).
HEAD_SPREAD_MM = 10.0


def _warn_head_spread(model) -> None:
    """One warning line when the head markers lie nearly on a line (the stabilisation's rotation
    about that line rests on their noise)."""
    import numpy as np

    P = model.marker_positions()[model.markers.head]
    if len(P) < 3:
        return
    spread = np.linalg.svd(P - P.mean(axis=0), compute_uv=False) / np.sqrt(len(P))
    if spread[1] < HEAD_SPREAD_MM:
        print(f"facesim: warning: the {len(P)} head markers lie nearly on a line (spreads "
              f"{', '.join(f'{v:.1f}' for v in spread)} mm): the head's rotation about it is poorly determined; "
              f"spread them out (forehead and temples, {HEAD_SPREAD_MM:g} mm or more across the line)", file=sys.stderr)


def _write_placement(out, model, layout) -> None:
    """OUT/markers_placed.csv and OUT/markers_placed.png (the placed markers on the face)."""
    from facesim.mocap.layout import write_placement
    from facesim.viz.render import render_model

    path = write_placement(Path(out) / "markers_placed.csv", layout.rows)
    png = render_model(model, Path(out) / "markers_placed.png", title="placed markers (head: yellow)")
    print(f"placement: {path}, {png}")


def _mocap_contact(args, model, base: Path) -> dict:
    """The contact set-up of solve-mocap: lip and teeth contact on where the model has the surfaces
    (as Sifakis 2005 tracked), unless --no-contact; --lip-contact / --teeth-contact insist on them."""
    from facesim.fem.equilibrium import has_lips, has_teeth

    if args.no_contact and (args.lip_contact or args.teeth_contact):
        raise FacesimError("--no-contact: excludes --lip-contact and --teeth-contact")
    lips = args.lip_contact or (not args.no_contact and has_lips(model))
    teeth = args.teeth_contact or (not args.no_contact and has_teeth(model))
    state = "off (--no-contact)" if args.no_contact else \
        f"lips {'on' if lips else 'off (no lip surfaces)'}, teeth {'on' if teeth else 'off (no teeth)'}"
    colliders = _colliders(args, base)
    print(f"contact: {state}" + (f", {len(colliders)} collider(s)" if colliders else ""))
    return {"lip_contact": lips, "teeth_contact": teeth, "colliders": tuple(colliders),
            "contact_stiffness": args.contact_stiffness}


def _add_output_frame_option(parser, files: str, note: str = "") -> None:
    """``--output-frame`` (one meaning in simulate, model export, export-cache and solve-mocap)."""
    parser.add_argument("--output-frame", choices=("facesim", "input"), default="facesim",
                        help=f"the frame of {files}: facesim (mm; x left, y up, z forward; origin between the "
                             "condyles), or input: the frame and units of the meshes an imported model was made from "
                             "('facesim model import' stores the transform in the model; this is its exact inverse; "
                             "TRC/C3D declare the unit). A model built by 'facesim model build' has no input frame"
                             f"{'. ' + note if note else ''} (default: %(default)s)")


def _add_color_by_option(parser, where: str) -> None:
    """``--color-by`` (one meaning in model render, simulate and solve-mocap)."""
    from facesim.viz.render import COLOR_BY

    parser.add_argument("--color-by", choices=COLOR_BY, default="none",
                        help="colour the skin by its displacement |x - X| (mm, colour bar from 0 to the frame's "
                             "largest), or each muscle by its activation in the frame (0 to 1, colour bar; the skin "
                             f"then translucent), instead of one colour per muscle; {where} (default: %(default)s)")


def _warn_ignored(args, rules) -> None:
    """One warning line on stderr per option given that the command ignores: ``rules`` are
    ``(dest, ignored, why)``; an option counts as given when its value differs from its default."""
    for dest, ignored, why in rules:
        if ignored and getattr(args, dest) != args.command_parser.get_default(dest):
            flag = "--" + dest.replace("_", "-")
            print(f"facesim: warning: {flag} is ignored {why}", file=sys.stderr)


def _frame_seconds(args, model) -> float:
    """The wall-clock budget of a frame: --max-seconds-per-frame, or the model's default."""
    from facesim.budget import default_frame_seconds

    return args.max_seconds_per_frame or default_frame_seconds(model)


def _warn_unconverged(s: dict, log: Path) -> None:
    """One warning line naming the frames that did not converge (with why, where known)."""
    bad = s.get("unconverged_frames", [])
    why = s.get("unconverged_reasons", {})
    if bad:
        shown = ", ".join(f"{k}" + (f" ({why[str(k)]})" if why.get(str(k)) else "") for k in bad[:10]) + \
            (", ..." if len(bad) > 10 else "")
        total = s.get("finished_frames", s.get("frames"))
        print(f"facesim: warning: {len(bad)} of {total} frames did not converge (frame {shown}); flagged in {log}",
              file=sys.stderr)


def cmd_demo(args) -> int:
    from facesim.demo import DEMO_CLIP, format_score, run_demo

    path = default_model_path()
    if not path.is_file():
        raise FacesimError(
            f"{path}: no such file; the demo needs a model: build one with 'facesim model build "
            f"--resolution coarse -o {path}' or set {MODEL_ENV}=M.npz")
    model = _load(path)
    print(f"model {path}: {model.n_nodes:,} nodes, {model.n_tets:,} tets, {model.n_muscles} muscles, "
          f"{model.n_markers} markers")
    r = run_demo(args.output, model, args.clip or DEMO_CLIP, frames=args.frames, render=args.render,
                 progress=not args.quiet)
    t = r["track"]
    print(f"solved {t['solved_frames']} frames in {t['seconds']:.0f} s "
          f"({t['seconds'] / max(1, t['solved_frames']):.1f} s per frame), recovery against the known truth:")
    print(format_score(r["score"]))
    shown = [Path(p).relative_to(args.output).as_posix() for p in r["outputs"] if Path(p).suffix != ".json"]
    print(f"wrote {args.output}/: activations.csv, jaw.csv, residuals.csv, report.json, recovery.json, "
          + ", ".join(shown))
    return 0


# ------------------------------------------------------------------ parser
def _add_contact_options(parser, relative_to: str, default_on: bool = False) -> None:
    """The contact options of ``simulate`` and ``solve-mocap`` (one meaning in both)."""
    parser.add_argument("--collider", action="append", default=[], metavar="SPEC",
                        help="an external rigid object the skin cannot enter (repeatable): KIND:key=value,... "
                             "e.g. 'sphere:radius=12,path=ball.csv' (centre per frame from frame,x,y,z rows, mm), "
                             "'sphere:radius=12,centre=55:-30:70', 'capsule:radius=4,a=0:-40:90,b=0:-40:130', "
                             "'plane:point=0:-70:0,normal=0:1:0', 'mesh:file=cup.stl,path=cup.csv'; optional "
                             "bone=cranium|jaw carries it with a bone, name=LABEL. Relative files are looked up "
                             f"next to {relative_to}")
    on = " (default: on where the model has the surfaces)" if default_on else ""
    parser.add_argument("--teeth-contact", action="store_true", help=f"keep the lips out of the teeth{on}")
    parser.add_argument("--lip-contact", action="store_true",
                        help=f"keep the upper and lower lips out of each other (self-contact){on}")
    if default_on:
        parser.add_argument("--no-contact", action="store_true",
                            help="no lip and no teeth contact (the lips may pass through each other and the teeth)")
    parser.add_argument("--contact-stiffness", type=_positive(1e6), default=CONTACT_STIFFNESS, metavar="K",
                        help="penalty stiffness of all contact, N/mm^3 (default: %(default)s)")


def _seconds(text: str) -> float:
    """argparse type for a wall-clock budget in seconds (> 0)."""
    from facesim.budget import check_seconds

    try:
        return check_seconds(text, "seconds")
    except FacesimError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _add_budget_option(parser) -> None:
    """``--max-seconds-per-frame`` (one meaning in simulate and solve-mocap)."""
    from facesim.budget import FRAME_SECONDS, SECONDS_PER_UNKNOWN

    parser.add_argument("--max-seconds-per-frame", type=_seconds, metavar="S",
                        help="wall-clock budget of one frame: a frame still unsolved after S seconds stops, is flagged "
                             "(stop_reason time_limit in frames.csv and report.json) and the run goes on with the next "
                             f"(default: {FRAME_SECONDS:g} s plus {1e3 * SECONDS_PER_UNKNOWN:g} ms per unknown of the "
                             "model, 330 s for the coarse face)")


def _colliders(args, base: Path) -> list:
    from facesim.contact.scene import parse_collider_spec

    return [parse_collider_spec(spec, base, i) for i, spec in enumerate(args.collider)]


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="facesim",
        description="Anatomical finite-element face simulator. Units: mm, N, MPa, s. Coordinates: x toward the "
                    "subject's left, y up, z toward the nose.",
        epilog="Run 'facesim COMMAND --help' for the options of a command.")
    parser.add_argument("--version", action="version", version=f"facesim {facesim.__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    demo = commands.add_parser(
        "demo", help="the main job on shipped data: solve the demo capture and print how well it is recovered",
        description="Solve the shipped capture meshes/demo_clip.c3d -- made by simulating a known performance "
                    "(talking, smiling, frowning, jaw open wide, a little head motion) on the finer "
                    "meshes/face_medium.npz, sampled at its markers with 0.5 mm noise, a few outliers and gaps -- "
                    "on the shipped coarse model (meshes/face_coarse.npz, or the file named by "
                    f"${MODEL_ENV}) as solve-mocap does, then print the recovery against the known truth: marker "
                    "RMS, activation error of the muscles the markers can see, jaw error and the planted outliers "
                    "found. Writes OUT/ as solve-mocap does, plus recovery.png (true and solved curves) and "
                    "recovery.json. A few minutes for the whole clip on 2 cores.",
        epilog="Pictures of a model: 'facesim model render M.npz -o front.png' (--sheet for several views). "
               "Regenerate the clip: 'python -m facesim.demo --make'.")
    demo.add_argument("-o", "--output", default="facesim_demo", metavar="OUT_DIR",
                      help="folder for the results (default: %(default)s)")
    demo.add_argument("--frames", type=_span, metavar="FIRST:LAST", help="solve only these frames of the clip (inclusive), e.g. 5:15")
    demo.add_argument("--clip", metavar="F.c3d",
                      help="another clip made by 'python -m facesim.demo --make' (its truth F_truth.npz beside "
                           "it; default: the shipped meshes/demo_clip.c3d)")
    demo.add_argument("--render", action="store_true",
                      help="also render the solve side by side with the capture into OUT/render/ (see solve-mocap "
                           "--render)")
    demo.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    demo.set_defaults(func=cmd_demo)

    model = commands.add_parser("model", help="build, inspect, export and render face models",
                                description="Build, inspect, export and render face models (.npz files).")
    sub = model.add_subparsers(dest="model_command", metavar="SUBCOMMAND", required=True)

    build = sub.add_parser(
        "build", help="build a procedural head model",
        description="Build a procedural anatomical head (flesh tets, muscles, skull, jaw, teeth, markers) and "
                    "save it as a model .npz. Resolutions: test (smallest), coarse (~40K tets, ~31K simulated), "
                    "medium (~138K, ~103K simulated), paper (>= 350K simulated tets, slow).")
    build.add_argument("--resolution", choices=RESOLUTIONS, default="coarse",
                       help="mesh resolution (default: %(default)s)")
    build.add_argument("--seed", type=_count(0, 2**32 - 1), default=0,
                       help="random seed of the procedural anatomy (default: %(default)s)")
    build.add_argument("-o", "--output", required=True, metavar="M.npz", help="model file to write")
    build.add_argument("--mesh-from", metavar="OLD.npz",
                       help="reuse the flesh tet mesh of an earlier model of the same seed and resolution instead "
                            "of running fTetWild (whose output differs from run to run): the rebuilt model is "
                            "then identical to OLD.npz's arrays")
    build.add_argument("--refine", type=_count(0, 3), default=0, metavar="N",
                       help="refine the --mesh-from mesh N times 1:8 (edge midpoints; deterministic, no fTetWild), "
                            "e.g. a paper-size model from the medium one: --resolution paper --mesh-from "
                            "meshes/face_medium.npz --refine 1 (default: %(default)s)")
    build.add_argument("-q", "--quiet", action="store_true", help="no progress output while building")
    build.set_defaults(func=cmd_model_build)
    from facesim.importing.cli import add_import_parser

    add_import_parser(sub)

    info = sub.add_parser(
        "info", help="print sizes, names, mesh quality and bounds of a model",
        description="Print node, tet, simulated-tet, muscle, marker and attachment counts, muscle and marker "
                    "names (head markers starred), mesh quality (dihedral angles in degrees, volume ratio "
                    "V/V_regular: 1 regular, 0 sliver, <0 inverted) and the bounding box in mm.")
    info.add_argument("model", metavar="M.npz", help="model file")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    info.set_defaults(func=cmd_model_info)

    export = sub.add_parser(
        "export", help="write a model as VTU (volume) or PLY/OBJ (skin) and its rigid surfaces as PLY",
        description="Export a model for other tools, positions in mm in facesim's frame (with --output-frame "
                    "input: in the frame and units of the meshes an imported model was made from). OUT.vtu: the "
                    "flesh tets with cell data tissue, simulated, muscle (dominant muscle index, -1 none), "
                    "muscle_fraction, muscle_total_fraction, fibre, and point data attachment (0 free, 1 cranium, "
                    "2 jaw). "
                    "OUT.ply / OUT.obj: the skin surface. --surfaces DIR: every bone and collider as DIR/NAME.ply.")
    export.add_argument("model", metavar="M.npz", help="model file")
    export.add_argument("-o", "--output", metavar="OUT", help="output file: .vtu (volume), .ply or .obj (skin)")
    export.add_argument("--surfaces", metavar="DIR", help="folder for the bone and collider surfaces (.ply)")
    _add_output_frame_option(export, "the positions (and OUT.vtu's fibre directions)")
    export.set_defaults(func=cmd_model_export)

    from facesim.viz.render import LAYERS, VIEWS  # cheap: pyvista itself is imported on first render

    render = sub.add_parser(
        "render", help="render a model to a PNG (off screen)",
        description="Render a model off screen: semi-transparent skin, ivory bones, teeth and eyes, muscles "
                    "(one colour per muscle, shared by a left/right pair, with a legend) and markers (head "
                    "markers yellow). Views: front looks from +z (the nose side) with +y up; side looks from +x "
                    "(the subject's left); top and bottom look along -y and +y with the nose up.")
    render.add_argument("model", metavar="M.npz", help="model file")
    render.add_argument("-o", "--output", required=True, metavar="OUT.png", help="picture to write")
    render.add_argument("--view", choices=tuple(VIEWS), default="front",
                        help="camera direction (default: %(default)s)")
    render.add_argument("--hide", metavar="LAYERS", default="",
                        help=f"comma-separated layers not to draw, some of {','.join(LAYERS)}")
    render.add_argument("--sheet", action="store_true",
                        help="contact sheet of the front, side, three-quarter and top views instead of one view")
    render.add_argument("--size", type=_size, default=None, metavar="WxH",
                        help="picture size in pixels, per view with --sheet (default: 1200x1200, with --sheet 600x600)")
    render.add_argument("--opacity", type=_opacity, default=None,
                        help="skin opacity, 0 (invisible) to 1 (opaque) (default: 1, opaque; the muscle legend is "
                             "drawn when the muscles show: use e.g. --opacity 0.35 or --hide skin)")
    _add_color_by_option(render, "only 'none' here: a model at rest has no displacement and no activations; "
                                 "colour a frame with simulate --render or solve-mocap --render")
    render.add_argument("--no-legend", action="store_true", help="no muscle legend")
    render.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    render.set_defaults(func=cmd_model_render, command_parser=render)

    simulate = commands.add_parser(
        "simulate", help="simulate a sequence of frames from muscle activations (and jaw poses)",
        description="Quasistatic forward simulation: for every row of the activations file, the equilibrium of "
                    "the face under those activations and jaw pose, warm-started from the previous frame. Writes "
                    "frame by frame into OUT/: skin/frame_KKKKK.ply (deformed skin, mm), state/frame_KKKKK.npz "
                    "(node positions x, mm), markers.csv (frame,<name>_x,<name>_y,<name>_z, mm) and markers.trc, "
                    "frames.csv (per frame: converged, Newton iterations, relative residual, seconds, linear "
                    "iterations) and report.json. With --output-frame input the skin and marker files are in the "
                    "frame and units of the meshes an imported model was made from. A frame that does not converge "
                    "is flagged in frames.csv and report.json and its markers are written as NaN. An interrupted "
                    "run loses no finished frame: "
                    "run again with --resume to continue.",
        epilog="Activations CSV: header 'frame,<muscle>,...' with muscle names of the model ('facesim model info' "
               "lists them; muscles without a column stay 0), values in [0, 1], one row per frame in increasing "
               "frame order. Jaw CSV, same frames: 'frame,rx,ry,rz,tx,ty,tz' (rotation vector in rad about the "
               "condyle midpoint, then translation in mm) or 'frame,opening' (rad about the intercondylar axis, "
               "positive opens the mouth).")
    simulate.add_argument("--model", required=True, metavar="M.npz", help="model file")
    simulate.add_argument("--activations", metavar="A.csv", help="muscle activations per frame (or --controls-from)")
    simulate.add_argument("--jaw", metavar="J.csv", help="jaw pose per frame (default: jaw at rest)")
    simulate.add_argument("--controls-from", metavar="OUT_DIR",
                          help="simulate the frames a solve-mocap run (or facesim edit) wrote: OUT_DIR/activations.csv "
                               "and jaw.csv with the jaw model and contact set-up the run recorded, and its head.csv "
                               "(solve-mocap --head solve) as head motion unless --head rest; without head.csv in the "
                               "model frame (the solve stabilised the head); the run must have been solved with this "
                               "--model; excludes --activations, --jaw and --jaw-model")
    simulate.add_argument("--head", metavar="H.csv|rest",
                          help="head motion per frame, the skull's rigid pose in the world: "
                               "'frame,r00,r01,r02,r10,r11,r12,r20,r21,r22,tx,ty,tz' (R row-major, t in mm; a "
                               "strain column is ignored), the same frames as the activations; the format "
                               "solve-mocap --head solve writes to head.csv. The bones move with it (moving Dirichlet "
                               "conditions; with --dynamic the flesh lags and swings: a head shake). 'rest': a fixed "
                               "head even when --controls-from OUT_DIR has a head.csv (default: fixed head)")
    simulate.add_argument("--jaw-model", default=None,
                          metavar="{rigid,sliding-condyle,affine-condyle,posselt,posselt:RIG.npz,nlpca:RIG.npz}",
                          help="how J.csv describes the jaw: rigid (frame,rx,ry,rz,tx,ty,tz or frame,opening), "
                               "sliding-condyle (frame,opening,right_slide,left_slide in rad, mm, mm; Sifakis 2005), "
                               "affine-condyle (frame,m00,...,m22,tx,ty,tz: the mandible's affine frame, M row-major "
                               "and t in mm, as solve-mocap --jaw-model affine-condyle writes it), or a fitted jaw rig (facesim jaw fit): posselt:RIG.npz with frame,sx,sy,sz sliders in "
                               "[0, 1], nlpca:RIG.npz with frame,d1,d2,d3; posselt alone is the model's own rig "
                               "(M_posselt.npz beside the model, or the shipped rig of the same TMJ) (default: rigid)")
    _add_contact_options(simulate, "A.csv")
    simulate.add_argument("-o", "--output", required=True, type=_folder, metavar="OUT_DIR", help="output folder")
    simulate.add_argument("--render", action="store_true",
                          help="also render every frame to OUT/png/frame_KKKKK.png (off screen)")
    simulate.add_argument("--video", action="store_true",
                          help="also make OUT/video.mp4 of the rendered frames (implies --render; an animated "
                               "GIF OUT/video.gif when imageio-ffmpeg is not installed)")
    simulate.add_argument("--view", choices=tuple(VIEWS), default="front",
                          help="camera of --render (default: %(default)s)")
    simulate.add_argument("--size", type=_size, default=(640, 640), metavar="WxH",
                          help="picture size of --render in pixels (default: 640x640)")
    _add_color_by_option(simulate, "in the --render pictures")
    simulate.add_argument("--fps", type=_fps, default=30.0,
                          help="frame rate in Hz of the TRC time column and the video, and with --dynamic the "
                               "physical frame rate of the controls (default: %(default)g)")
    simulate.add_argument("--dynamic", action="store_true",
                          help="integrate in time (BDF2: inertia from tissue densities, Rayleigh damping, the same "
                               "energy and contact) instead of a quasistatic equilibrium per frame; the first frame "
                               "is the quasistatic equilibrium, at rest")
    simulate.add_argument("--substeps", type=_count(1, 1000), default=2, metavar="N",
                          help="with --dynamic: time steps per frame (default: %(default)s; 4 or more for ballistic "
                               "detail)")
    simulate.add_argument("--soften", action="append", default=[], metavar="TISSUE:FACTOR",
                          help="with --dynamic: scale a tissue's stiffness (c10, c01, kappa), e.g. nose:0.2; "
                               "repeatable")
    simulate.add_argument("--density", action="append", default=[], metavar="TISSUE:VALUE",
                          help="with --dynamic: a tissue's density, t/mm^3 (default 1.06e-9; nose cartilage "
                               "1.1e-9); repeatable")
    simulate.add_argument("--damping", default="0,1e-3", metavar="ALPHA,BETA",
                          help="with --dynamic: Rayleigh damping C = ALPHA M + BETA K, 1/s and s "
                               "(default: %(default)s)")
    simulate.add_argument("--integrator", choices=("bdf2", "euler"), default="bdf2",
                          help="with --dynamic: time integrator (default: %(default)s)")
    again = simulate.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the run in OUT_DIR after its last complete frame (frames whose activations "
                            "or jaw pose changed since are recomputed)")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the results of an earlier run in OUT_DIR (without --resume or --overwrite, a "
                            "folder holding a run is an error)")
    simulate.add_argument("--solver", choices=("amg", "direct", "pardiso"), default="amg",
                          help="linear solver of the Newton steps: algebraic multigrid + CG, sparse LU (SuperLU), "
                               "or MKL PARDISO (pip install 'facesim[pardiso]') (default: %(default)s)")
    _add_budget_option(simulate)
    _add_output_frame_option(simulate, "OUT/skin/*.ply, markers.csv, markers.trc and markers.c3d",
                             "OUT/state/*.npz, the solver's resume state, stay in facesim's frame; report.json's "
                             "output_frame says which frame the files are in; --resume must give the run's")
    simulate.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    simulate.set_defaults(func=cmd_simulate, command_parser=simulate)

    cache = commands.add_parser(
        "export-cache", help="animation caches of a finished run: USD, ParaView .pvd series, C3D of the markers",
        description="Write caches of the run in OUT_DIR (a folder written by simulate, or solve-mocap --write-meshes: "
                    "state/frame_KKKKK.npz) for other tools: --usd a USD stage (skin as a time-sampled mesh, cranium "
                    "and jaw surfaces with time-sampled transforms, markers; mm, y up, or with --output-frame input "
                    "the imported model's input frame and units; pip install usd-core), --pvd "
                    "a ParaView collection of per-frame .vtu volumes (point data displacement, cell data activation, "
                    "active_stress, tissue, muscle), --c3d the simulated markers. Frames that did not converge show "
                    "the last converged frame and are listed in the caches.")
    cache.add_argument("run", metavar="OUT_DIR", help="the run folder")
    cache.add_argument("--model", required=True, metavar="M.npz", help="the model the run was made with")
    cache.add_argument("--usd", metavar="OUT.usd", help="USD stage to write (.usd, .usdc binary; .usda text)")
    cache.add_argument("--pvd", metavar="OUT.pvd", help="ParaView collection to write; the .vtu files go in OUT/ beside it")
    cache.add_argument("--c3d", metavar="OUT.c3d", help="C3D of the simulated markers (from OUT_DIR/markers.csv)")
    cache.add_argument("--fps", type=_fps, help="frame rate in Hz (default: the run's, from report.json, else 30)")
    _add_output_frame_option(cache, "the caches", "USD's metersPerUnit and upAxis follow it; from any run, whatever "
                                                  "frame the run wrote its own files in")
    cache.set_defaults(func=cmd_export_cache)

    solve = commands.add_parser(
        "solve-mocap", help="muscle activations and jaw pose per frame from a marker capture",
        description="Inverse simulation (Sifakis 2005): for every frame of a motion capture, the muscle "
                    "activations and jaw parameters whose quasistatic equilibrium puts the model's markers on the "
                    "captured ones (Gauss-Newton with implicit Jacobians, penalty schedule on the bounds, golden-"
                    "section search), warm-started from the previous frame. Writes frame by frame into OUT/: "
                    "activations.csv, jaw.csv, residuals.csv (per frame and marker, mm), frames.csv (solver log), "
                    "report.json, and at the end activations.png and residuals.png. --resume continues an "
                    "interrupted run. With --workers or --scheduler the sequence is split into chunks solved in "
                    "parallel by dask.distributed, each chunk starting cold; the files still hold the frames in "
                    "order (frames finished ahead of an unfinished one wait in OUT/chunks/).",
        epilog="Marker names are matched to the model's (exactly, then ignoring case); unmatched names are "
               "reported. Missing markers (NaN or empty) are dropped per frame. Outliers (residual above the frame's median "
               "plus 5 robust standard deviations, and above 2 mm) are reported in report.json and, unless --no-robust, "
               "the frame is refitted without them; --loss huber or cauchy also down-weights far markers during "
               "the fit (iteratively reweighted Gauss-Newton).")
    solve.add_argument("--model", required=True, metavar="M.npz", help="model file")
    solve.add_argument("--markers", required=True, metavar="F", help="capture: .c3d, .trc or .csv (mm unless stated)")
    solve.add_argument("-o", "--output", required=True, type=_folder, metavar="OUT_DIR", help="output folder")
    solve.add_argument("--units", choices=("mm", "cm", "m"), help="override the file's length unit")
    solve.add_argument("--jaw-model", default="sliding-condyle",
                       metavar="{sliding-condyle,affine-condyle,posselt,posselt:RIG.npz,nlpca:RIG.npz}",
                       help="jaw parameterisation solved for: sliding-condyle's 3 natural parameters, or "
                            "affine-condyle, the jaw frame's 12 affine coefficients with the condyle-track and "
                            "rigidity constraints as penalties in the progressive schedule (Sifakis 2005 section 8; "
                            "same accuracy on the demo clip, ~20-40%% slower); posselt alone is the model's own Posselt rig "
                            "(M_posselt.npz beside the model, or the shipped rig of the same TMJ) (default: %(default)s)")
    solve.add_argument("--head", choices=("procrustes", "none", "solve"), default="procrustes",
                       help="procrustes: stabilise the head with the head markers first; none: the capture is "
                            "already in the model's head frame; solve: the skull's frame solved with the other "
                            "controls per frame (12 affine coefficients under the rigidity penalty, Sifakis 2005 "
                            "section 8), for captures whose head markers are few or noisy: the poses go to "
                            "OUT/head.csv, everything else stays in the model's head frame (default: %(default)s)")
    solve.add_argument("--head-smoothing", type=_count(0, 10001), default=0, metavar="FRAMES",
                       help="smooth the head stabilisation over this many frames (odd, >= 3; 0: off): the few head "
                            "markers' noise otherwise shakes the whole face; keep the window shorter than the "
                            "head's fastest motion (default: %(default)s)")
    solve.add_argument("--frames", type=_span, metavar="FIRST:LAST",
                       help="solve only these frames (inclusive; either end may be left out, e.g. 10: ; one number: "
                            "that frame)")
    solve.add_argument("--bind-frames", type=_span, metavar="FIRST:LAST",
                       help="frames of the capture showing the neutral face: the model's markers are first bound "
                            "to the skin where these frames put them (per-marker median; Sifakis 2005), instead "
                            "of the model's own marker placement")
    solve.add_argument("--layout", choices=("auto", "model", "capture"), default="auto",
                       help="whose markers: the model's (the capture uses its names), the capture's own (registered "
                            "to the skin and bound where its neutral frames put them; see docs/cli.md), or auto: "
                            "the capture's own when fewer than 3 of its names are the model's (default: %(default)s)")
    solve.add_argument("--head-markers", metavar="NAME,NAME,...",
                       help="the capture's markers that move with the skull (a headband, nose bridge); implies "
                            "--layout capture (default: the largest group moving rigidly together, listed)")
    solve.add_argument("--marker-map", metavar="FILE",
                       help="CSV 'capture,model': capture markers that are the model's markers (they keep the "
                            "model's binding); implies --layout capture")
    solve.add_argument("--similarity", action="store_true",
                       help="with the capture's own layout, fit a uniform scale in the registration too")
    solve.add_argument("--noise", type=_positive(50.0), default=0.5,
                       help="marker noise level, mm (default: %(default)s)")
    solve.add_argument("--jaw-prior", metavar="PRED.npz",
                       help="a markerless jaw predictor trained on this model's markers ('facesim jaw markerless "
                            "train --features markers'): each frame's predicted jaw starts cold frames and is a prior "
                            "of the solved jaw parameters (for captures with few markers on the chin)")
    solve.add_argument("--jaw-prior-sigma", type=_positive(100.0, "a distance"), default=1.0, metavar="MM",
                       help="the prior's standard deviation per predicted mandible point coordinate, mm (default: "
                            "%(default)s; against the markers' --noise)")
    solve.add_argument("--coarse-model", metavar="COARSE.npz", action="append",
                       help="a coarser model of the same face (the same muscles and jaw; e.g. the model a paper-size "
                            "one was refined from): each cold frame (the first, a chunk's first) is fitted on it "
                            "first and refined on --model from there -- the paper-size face's cold frame in 40%% of "
                            "the time with the medium face (benchmarks/RESULTS.md); the model's markers are bound "
                            "to its skin, so its own marker layout does not matter. Repeat for a chain (any order): "
                            "each level's cold fit starts on the next coarser one")
    solve.add_argument("--max-steps", type=_count(1, 1000), default=5,
                       help="Gauss-Newton steps per frame (default: %(default)s)")
    solve.add_argument("--no-robust", action="store_true",
                       help="keep outlier markers in the fit (still reported); by default a frame with outliers is "
                            "refitted without them")
    solve.add_argument("--loss", choices=("l2", "huber", "cauchy"), default="l2",
                       help="per-marker loss on the marker distance: l2 (least squares), huber (linear beyond "
                            "--loss-scale) or cauchy (logarithmic beyond it), the robust ones by iteratively "
                            "reweighted Gauss-Newton (default: %(default)s)")
    solve.add_argument("--loss-scale", type=_positive(1000.0), metavar="MM",
                       help="distance where the robust loss starts discounting a marker, mm (default: 3 x --noise)")
    engine = solve.add_mutually_exclusive_group()
    engine.add_argument("--workers", type=_count(1, 1024), metavar="N",
                        help="solve chunks of the sequence in parallel on a local dask cluster of N processes")
    engine.add_argument("--scheduler", metavar="ADDRESS",
                        help="solve chunks in parallel on a running dask.distributed cluster (e.g. tcp://host:8786); "
                             "its workers must see the model file at the same path")
    solve.add_argument("--chunk-size", type=_count(1, 10**9), metavar="FRAMES",
                       help="frames per chunk, each starting cold (default: the frames divided evenly among the "
                            "workers; one chunk without --workers/--scheduler)")
    solve.add_argument("--solver", choices=("amg", "direct", "pardiso"), default="amg",
                       help="linear solver of the equilibria (the Jacobians use MKL PARDISO when pypardiso is "
                            "installed, else SuperLU or, above 150K unknowns, AMG) (default: %(default)s)")
    again = solve.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="continue the interrupted run in OUT_DIR (refused when the model, capture or options "
                            "differ from the run's: the message names them); the frames solved after the resume "
                            "point are those of an uninterrupted run")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the results of an earlier run in OUT_DIR (without --resume or --overwrite, a "
                            "folder holding a run is an error)")
    solve.add_argument("--render", action="store_true",
                       help="also render the solved frames side by side with the capture (left: the captured "
                            "markers, stabilised; right: the simulated face with its markers and lines to the "
                            "captured ones) into OUT/render/frame_KKKKK.png and OUT/render/video.mp4 (an animated "
                            "GIF video.gif when imageio-ffmpeg is not installed)")
    solve.add_argument("--write-meshes", action="store_true",
                       help="also write per frame what simulate writes: OUT/skin/frame_KKKKK.ply (the solved skin, mm) "
                            "and OUT/state/frame_KKKKK.npz (x, a, jaw, converged, error), from the solve's own "
                            "equilibria (no re-solve), and at the end OUT/markers.csv, markers.trc and markers.c3d of "
                            "the solved markers (model frame; see --output-frame)")
    _add_color_by_option(solve, "in the simulated panel of the --render pictures")
    _add_contact_options(solve, "F", default_on=True)
    _add_budget_option(solve)
    _add_output_frame_option(solve, "the --write-meshes files OUT/skin/*.ply, markers.csv, markers.trc and "
                                    "markers.c3d", "OUT/state/*.npz stay in facesim's frame; --resume must give "
                                                   "the run's")
    solve.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    solve.set_defaults(func=cmd_solve_mocap, command_parser=solve)
    add_edit_commands(commands)
    from facesim.markerless_cli import add_markerless_commands

    add_jaw_commands(commands, more=(add_markerless_commands,))
    add_teeth_commands(commands)
    return parser


def main(argv=None) -> int:
    """Run the ``facesim`` command with ``argv`` (default: ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except SystemExit as exc:  # argparse: --help, --version, usage errors
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else EXIT_USAGE)
    except FacesimError as exc:
        print(f"facesim: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USAGE
    except SolverError as exc:   # a numerical failure outside a frame (frames catch their own)
        print(f"facesim: solver failed: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_SOLVER
    except OSError as exc:  # unwritable output folder, disk full, a folder where a file is expected ...
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"facesim: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("facesim: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 (a bug, not a user mistake: one line; the traceback on request)
        if os.environ.get(DEBUG_ENV):
            raise
        print(f"facesim: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} (a bug in facesim, not "
              f"in your input: run again with {DEBUG_ENV}=1 for the traceback and please report it)", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
