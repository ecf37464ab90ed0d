"""``facesim teeth {render,track}``: synthetic multi-view captures of the teeth, and teeth tracking.

``add_teeth_commands(subparsers)`` adds the ``teeth`` group to the ``facesim`` parser. Handlers
import the heavy modules (OpenCV, the importer) lazily and raise
:class:`~facesim.errors.FacesimError` for user mistakes, which ``facesim.cli.main`` prints as
one line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from facesim._argtypes import in_range, integer
from facesim.errors import FacesimError


_number = in_range   # argparse types: a number in a range, an integer in a range
_integer = integer


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 1280x720, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"expected a size between 16 and 8192 pixels per side, got {text!r}")
    return w, h


def _span(text: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST:LAST frame numbers, e.g. 10:14, got {text!r}") from None
    if a < 0 or b < a:
        raise argparse.ArgumentTypeError(f"expected 0 <= FIRST <= LAST, got {text!r}")
    return a, b


def _dentition(args):
    """The teeth of ``--upper/--lower`` (with units, frame, mandible), or the shipped model's."""
    from facesim.teeth.dentition import read_dentition, shipped_dentition

    if (args.upper is None) != (args.lower is None):
        raise FacesimError("--upper and --lower go together: give both teeth files, or neither for the shipped teeth")
    if args.upper is None:
        if args.mandible is not None:
            raise FacesimError("--mandible: only with --upper and --lower (the shipped teeth are in facesim's frame)")
        return shipped_dentition()
    for p in (args.upper, args.lower, args.mandible):
        if p is not None and not Path(p).is_file():
            raise FacesimError(f"{p}: no such file (expected a teeth or mandible mesh)")
    return read_dentition(args.upper, args.lower, units=args.units, frame=args.frame, mandible=args.mandible)


def _jaw_poses(args):
    """``(poses (N, 4, 4), source frame numbers (N,))`` of ``--poses`` or ``--session``, thinned
    by ``--every`` or ``--frames``."""
    if args.poses is not None:
        from facesim.jaw.cli import read_poses

        poses = read_poses(args.poses).poses
    else:
        from facesim.jaw.motion import JawMotion

        poses = JawMotion().session(seed=args.session).poses
    n = len(poses)
    if args.every is not None:
        idx = np.arange(0, n, args.every)
    else:
        idx = np.unique(np.linspace(0, n - 1, min(args.frames, n)).round().astype(int))
    return poses[idx], idx


def cmd_teeth_render(args) -> int:
    from facesim.teeth.cameras import default_layout, read_cameras
    from facesim.teeth.render import CaptureOptions, head_motion, render_capture

    out = Path(args.output)
    dentition = _dentition(args)
    jaw, idx = _jaw_poses(args)
    if args.cameras is not None:
        if args.size is not None:
            raise FacesimError("--size: the image size comes from --cameras; give one or the other")
        cameras = read_cameras(args.cameras)
    else:
        cameras = default_layout(mouth_target(dentition), size=args.size or (1280, 720))
    hide = ()
    if args.hide_lower is not None:
        a, b = args.hide_lower
        if a >= len(jaw):
            raise FacesimError(f"--hide-lower {a}:{b}: the capture has {len(jaw)} frames (0:{len(jaw) - 1})")
        hide = tuple(range(a, min(b, len(jaw) - 1) + 1))
    options = CaptureOptions(noise=args.noise, blur=args.blur, lips=not args.no_lips, cover_upper=args.cover_upper,
                             cover_lower=args.cover_lower, lip_jitter=args.lip_jitter, hide_lower=hide,
                             seed=args.seed)
    head = head_motion(len(jaw), args.head_motion, seed=args.seed) if args.head_motion > 0 else None
    info = render_capture(out, dentition, jaw, cameras, options, head=head, frames=idx, write_masks=args.write_masks,
                          progress=not args.quiet)
    print(f"rendered {info['frames']} frames x {len(cameras)} cameras ({', '.join(info['cameras'])}, "
          f"{cameras[0].width}x{cameras[0].height}) -> {out}/ (cameras.json, truth.npz, teeth_upper.obj, "
          f"teeth_lower.obj)")
    return 0


def mouth_target(dentition) -> np.ndarray:
    """(3,) mm: where the default cameras look: 20 mm below the upper incisal edge (the middle of
    an opening mouth), 5 mm behind it."""
    return np.asarray(dentition.upper_incisor) + np.array([0.0, -20.0, -5.0])


def cmd_teeth_track(args) -> int:
    from facesim._files import require_suffix
    from facesim.teeth.cameras import read_cameras
    from facesim.teeth.capture import Capture
    from facesim.teeth.track import TrackOptions, log_path, track_capture

    out = require_suffix(args.output, (".npz",), "a poses file name")
    if (args.images is None) == (args.masks is None):
        raise FacesimError("track: give the images (--images DIR) or masks segmented elsewhere (--masks DIR), one")
    cameras = read_cameras(args.cameras)
    capture = Capture(args.images or args.masks, cameras, masks=args.masks is not None)
    dentition = _dentition(args)
    options = TrackOptions(track_head=not args.still_head, min_confidence=args.min_confidence,
                           max_sigma_mm=args.max_sigma)
    first = None
    if args.start != "rest":
        from facesim.jaw.cli import read_poses

        if not Path(args.start).is_file():
            raise FacesimError(f"--start {args.start}: no such file (expected 'rest' or a poses file .npz)")
        first = read_poses(args.start).poses[0]
    info = track_capture(capture, dentition, out, options, resume=args.resume, progress=not args.quiet, first=first)
    heads = f", {info['head_flagged']} with the head held too" if info["head_flagged"] else ""
    print(f"tracked {info['frames']} frames ({info['resumed']} resumed) in {len(cameras)} cameras, "
          f"{info['seconds_per_frame']:.2f} s a frame; {info['restarted']} re-fitted from other starts; "
          f"{info['flagged']} flagged (jaw held{heads}) -> {out} "
          f"(log {log_path(out).name})")
    return 0


def _teeth_inputs(p) -> None:
    p.add_argument("--upper", metavar="U.obj", help="upper teeth mesh (any format trimesh/meshio reads; default: the "
                                                     "shipped model's teeth)")
    p.add_argument("--lower", metavar="L.obj", help="lower teeth mesh (with --upper)")
    p.add_argument("--units", default="auto", choices=("auto", "m", "cm", "mm"),
                   help="units of the teeth files (default: %(default)s, from their size)")
    p.add_argument("--frame", default="auto", metavar="SPEC",
                   help="axes of the teeth files: auto (from the anatomy), facesim (already in facesim's frame), or a "
                        "spec such as 'x=backward,z=up' (default: %(default)s)")
    p.add_argument("--mandible", metavar="M.obj",
                   help="the mandible of the same scan: facesim's frame from the importer (origin between the condyles)")


def add_teeth_commands(subparsers) -> argparse.ArgumentParser:
    """Add ``facesim teeth {render,track}`` to the ``subparsers`` of the facesim parser."""
    teeth = subparsers.add_parser(
        "teeth", help="teeth tracking from multi-view images (Yang et al. 2018)",
        description="Teeth tracking from calibrated multi-view images (Yang et al. 2018 section 4): render synthetic "
                    "captures of the teeth with noise, blur and lip occlusion, and track the upper (head) and lower "
                    "(jaw) teeth in images by their silhouettes. The tracked poses are a poses file for "
                    "'facesim jaw fit --rig nlpca'. Quick start: 'facesim teeth render -o CAP', 'facesim teeth track "
                    "--cameras CAP/cameras.json --images CAP -o P.npz'.")
    sub = teeth.add_subparsers(dest="teeth_command", metavar="SUBCOMMAND", required=True)

    r = sub.add_parser("render", help="render a synthetic multi-view capture of the teeth",
                       description="Render the upper and lower teeth from N calibrated cameras for a sequence of jaw "
                                   "poses (a poses file, or a generated session), with image noise, blur and partial "
                                   "occlusion by procedural lips whose opening follows the jaw. Writes "
                                   "OUT/<camera>/frame_NNNNN.png, OUT/cameras.json, OUT/truth.npz (true poses) and the "
                                   "teeth drawn (OUT/teeth_upper.obj, teeth_lower.obj, mm, facesim's frame). Default "
                                   "cameras: 3 at 1280x720, focal 2400 px, 300 mm from the mouth, straight on and "
                                   "turned 30 degrees to each side.")
    r.add_argument("-o", "--output", required=True, metavar="OUT_DIR", help="output folder")
    src = r.add_mutually_exclusive_group()
    src.add_argument("--poses", metavar="P.npz", help="jaw poses file (as 'facesim jaw fit' reads)")
    src.add_argument("--session", type=_integer(0, 2**31 - 1), default=0, metavar="SEED",
                     help="seed of a generated jaw session (facesim.jaw.motion; default: %(default)s)")
    thin = r.add_mutually_exclusive_group()
    thin.add_argument("--frames", type=_integer(1, 100000), default=60, metavar="N",
                      help="frames spread evenly over the poses (default: %(default)s)")
    thin.add_argument("--every", type=_integer(1, 100000), metavar="K", help="every K-th pose instead")
    r.add_argument("--cameras", metavar="C.json", help="calibration file (default: the 3-camera layout)")
    r.add_argument("--size", type=_size, metavar="WxH", help="image size of the default layout (default 1280x720)")
    r.add_argument("--noise", type=_number(0, 100, "grey levels"), default=4.0,
                   help="image noise std, grey levels (default: %(default)s)")
    r.add_argument("--blur", type=_number(0, 20, "pixels"), default=0.8, help="blur sigma, px (default: %(default)s)")
    r.add_argument("--no-lips", action="store_true", help="no lip occluder")
    r.add_argument("--cover-upper", type=_number(-20, 30, "mm"), default=6.0,
                   help="upper lip edge above the upper incisal point, mm (default: %(default)s)")
    r.add_argument("--cover-lower", type=_number(-20, 30, "mm"), default=5.0,
                   help="lower lip edge below the lower incisal point, mm (default: %(default)s)")
    r.add_argument("--lip-jitter", type=_number(0, 10, "mm"), default=1.0,
                   help="amplitude of the lips' slow random motion, mm (default: %(default)s)")
    r.add_argument("--hide-lower", type=_span, metavar="FIRST:LAST",
                   help="frames (of the capture) where the lower lip rises over the lower teeth")
    r.add_argument("--head-motion", type=_number(0, 20, "mm (and degrees)"), default=0.0, metavar="MM",
                   help="smooth random head motion, about MM mm and MM degrees (default: still)")
    r.add_argument("--seed", type=_integer(0, 2**31 - 1), default=0, help="seed of noise, lips, head (default: 0)")
    r.add_argument("--write-masks", action="store_true", help="also write the true labels (OUT/masks/<camera>/)")
    _teeth_inputs(r)
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_teeth_render)

    t = sub.add_parser("track", help="track the upper and lower teeth in calibrated images",
                       description="Per frame, the upper-teeth pose (the head) and then the lower-teeth pose that "
                                   "minimise a silhouette energy in all cameras (Gauss-Newton on contour distances, "
                                   "golden-section line search, coarse to fine, warm start from the previous frame; "
                                   "the first frame starts at rest). Frames whose lower teeth are mostly hidden are "
                                   "flagged and hold the last trusted jaw pose. Writes P.npz (poses (N,4,4) mandible "
                                   "relative to skull, mm, with reference_point and mandible points: a poses file for "
                                   "'facesim jaw fit'; plus head, residual_px, confidence, sigma_mm, flagged) and, "
                                   "frame by frame, P.frames.csv (--resume goes on from it).")
    t.add_argument("--cameras", required=True, metavar="C.json", help="calibration file")
    t.add_argument("--images", metavar="DIR", help="images: DIR/<camera>/<frame>.png")
    t.add_argument("--masks", metavar="DIR", help="masks segmented elsewhere, same layout (255 teeth, 128 occluder)")
    t.add_argument("-o", "--output", required=True, metavar="P.npz", help="poses file to write")
    _teeth_inputs(t)
    t.add_argument("--still-head", action="store_true", help="the head does not move (upper teeth at rest)")
    t.add_argument("--min-confidence", type=_number(0, 1), default=0.5,
                   help="flag a jaw whose share of the visible model contour that matches the images is below "
                        "this (default: %(default)s)")
    t.add_argument("--max-sigma", type=_number(0, 100, "mm"), default=0.15,
                   help="flag a jaw whose incisal point's formal std exceeds this, mm (default: %(default)s)")
    t.add_argument("--start", default="rest", metavar="rest|P.npz",
                   help="the first frame's jaw start: rest, or the first pose of a poses file (default: rest)")
    t.add_argument("--resume", action="store_true", help="keep the frames of an earlier run's P.frames.csv")
    t.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=cmd_teeth_track)
    return teeth


__all__ = ["add_teeth_commands", "mouth_target"]
