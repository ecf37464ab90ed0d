"""``facesim model import``: the command line of :func:`facesim.importing.build.import_model`."""

from __future__ import annotations

import sys
import time
from pathlib import Path



def add_import_parser(sub) -> None:
    """Register ``model import`` on the ``model`` command's subparsers ``sub``."""
    from facesim.importing.build import FIX_BOUNDARY, REMESH, RESOLUTIONS

    p = sub.add_parser(
        "import", help="build a simulation-ready face from your own meshes (skin or flesh volume, bones, teeth)",
        description="Build a face model from real anatomy: a skin surface (--skin; closed, or repaired closed) or "
                    "a flesh volume mesh (--flesh: tets, hexahedra, wedges in any meshio format) plus the bone "
                    "surfaces (--mandible, --cranium) and optionally the teeth, in any format meshio or trimesh "
                    "reads, in any unit and frame. Units and the head's frame are found from the anatomy "
                    "(stated in the output); the template's 32 muscles, fibres and markers are carried onto the "
                    "new anatomy by a warp through landmarks found on the bones and skin (written to "
                    "M_landmarks.json; --landmarks overrides any). See docs/cli.md.",
        epilog="Example (the ArtiSynth Badin face, metres, x backward, z up): facesim model import -o badin.npz "
               "--flesh flesh.vtu --mandible mandible.obj --cranium maxilla.obj --teeth-upper teeth_upper.obj "
               "--teeth-lower teeth_lower.obj")
    p.add_argument("-o", "--output", required=True, metavar="M.npz", help="model file to write")
    route = p.add_mutually_exclusive_group(required=True)
    route.add_argument("--skin", metavar="FILE", help="skin surface (surfaces route): the flesh is its inside "
                                                      "minus the bones, tetrahedralised at --resolution")
    route.add_argument("--flesh", metavar="FILE", help="volume mesh of the soft tissue (volume route)")
    p.add_argument("--mandible", required=True, metavar="FILE", help="the mandible's surface")
    p.add_argument("--cranium", nargs="+", default=[], metavar="FILE",
                   help="bone surfaces rigid with the skull (braincase, maxilla, ...)")
    p.add_argument("--teeth-upper", metavar="FILE", help="upper dentition surface (a collider once closed)")
    p.add_argument("--teeth-lower", metavar="FILE", help="lower dentition surface (a collider once closed)")
    p.add_argument("--units", choices=("auto", "m", "cm", "mm"), default="auto",
                   help="the inputs' length unit; auto: from the anatomy's size (default: %(default)s)")
    p.add_argument("--frame", metavar="SPEC",
                   help="the inputs' axes instead of finding them, e.g. 'x=backward,y=right,z=up' (two axes are "
                        "enough; the frame must be right-handed)")
    p.add_argument("--resolution", default="coarse", metavar="{" + ",".join(RESOLUTIONS) + ",MM}",
                   help="tet edge length of the meshed flesh: coarse (8 mm), medium (5 mm) or a length in mm "
                        "(default: %(default)s)")
    p.add_argument("--remesh", choices=REMESH, default="auto",
                   help="with --flesh: re-mesh the volume from its boundary; auto: when its tets are slivers "
                        "(dihedral angle < 5 deg or volume ratio < 0.05), which invert under motion "
                        "(default: %(default)s)")
    p.add_argument("--landmarks", metavar="FILE",
                   help="landmarks JSON overriding the ones found ({\"landmarks\": {name: [x, y, z]}, \"frame\": "
                        "\"facesim\"|\"input\", \"units\": ...}); names as in M_landmarks.json")
    p.add_argument("--fix-boundary", choices=FIX_BOUNDARY, default="cut",
                   help="cut: the flesh's inner surface that lies on no given bone (where a face mask ends, or "
                        "on a skull the input lacks) is fixed to the cranium, except near the mandible; none: "
                        "only flesh on the given bones is attached (default: %(default)s)")
    p.add_argument("--template", metavar="T.npz",
                   help="template model whose muscles and markers are carried over (default: the shipped "
                        "coarse face)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=cmd_model_import)


def cmd_model_import(args) -> int:
    from facesim._files import require_suffix
    from facesim.importing.build import import_model
    from facesim.importing.landmarks import write_landmarks

    out = Path(require_suffix(args.output, (".npz",), "a model file name"))
    t0 = time.perf_counter()

    def say(msg):
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    model, report = import_model(skin=args.skin, flesh=args.flesh, cranium=args.cranium, mandible=args.mandible,
                                 teeth_upper=args.teeth_upper, teeth_lower=args.teeth_lower, units=args.units,
                                 frame=args.frame, resolution=args.resolution, landmarks=args.landmarks,
                                 fix_boundary=args.fix_boundary, remesh=args.remesh, template=args.template,
                                 progress=say)
    model.save(out)
    lm_path = write_landmarks(out.with_name(out.stem + "_landmarks.json"), report["landmarks"], report["landmark_how"],
                              extra={"input_frame": report["input_frame"]})
    carried = report["template"]
    for name, why in carried["muscles"]["flagged"].items():
        print(f"  muscle {name}: {why}")
    for name, why in carried["markers"]["dropped"].items():
        print(f"  marker {name} dropped: {why}")
    heads = int(model.markers.head.sum())
    print(f"lips: {report['lips']}")
    for note in report["colliders"]:
        print(f"teeth: {note}")
    q = report["quality"]
    print(f"imported ({report['route']['route']} route, units {report['units']['name']}) in "
          f"{time.perf_counter() - t0:.1f} s: {model.n_nodes:,} nodes, {model.n_tets:,} tets (min dihedral "
          f"{q['min_dihedral_deg']:.1f} deg), {model.n_muscles} muscles ({len(carried['muscles']['flagged'])} "
          f"flagged), {model.n_markers} markers ({heads} head) -> {out}; landmarks -> {lm_path}")
    if heads < 3:
        print(f"facesim: warning: only {heads} head markers could be placed: solve captures of this model with "
              "solve-mocap --head solve", file=sys.stderr)
    return 0


__all__ = ["add_import_parser", "cmd_model_import"]
