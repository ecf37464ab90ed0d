"""Teeth tracking accuracy and speed (issue 19): 3 cameras at 1280x720, noise, blur, lip occlusion.

Camera layout: the default (:func:`facesim.teeth.cameras.default_layout`): 1280x720, focal 2400
px, 300 mm from the mouth, straight on and turned +-30 degrees about the vertical (0.125 mm a
pixel at the mouth). Session: the border movements of generated session 0 (frames 0-1146 at 30
fps: posterior, anterior, the four lateral verticals, protrusion, laterals, the contact rim), every
``--every``-th frame (default 4: 287 frames at 7.5 fps, up to 9.7 mm of incisor motion between
frames), lips on, the lower teeth hidden (``--hide-lower``) over three frames a third of the way in. Per dentition (the shipped teeth; the Badin scans in
metres, frame from their mandible, ``--badin-frames`` of the same session): lower-teeth pose
error at the lower incisal point (mm) and in degrees over the trusted frames, over all frames
(held poses where flagged), the fitted poses of unflagged frames more than 1 mm off, flagged
frames, restarts, seconds per frame (wall, segmentation included), and the NLPCA rig
(``fit_nlpca``, 3 parameters) fitted to the trusted tracked poses, reconstructing the TRUE poses.

    python benchmarks/bench_teeth.py [--every 4] [--out /tmp/bench_teeth] [--badin DIR] [--badin-frames 60]
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))

#: The border movements of generated session 0 (frames).
BORDER = (0, 1147)


def run(name, teeth, poses_file, out, facesim, pose_errors, iterations):
    from facesim.jaw.cli import read_poses
    from facesim.jaw.frame import JawFrame
    from facesim.jaw.nlpca import fit_nlpca

    cap = out / name
    n = len(np.load(poses_file)["poses"])
    hide = f"{n // 3}:{n // 3 + 2}"          # three frames whose lower teeth the lower lip hides
    assert facesim(["teeth", "render", "-o", str(cap), "--poses", str(poses_file), "--every", "1", "--hide-lower",
                    hide, "-q", *teeth]) == 0
    t0 = time.perf_counter()
    assert facesim(["teeth", "track", "--cameras", str(cap / "cameras.json"), "--images", str(cap), "-o",
                    str(cap / "tracked.npz"), "-q", *teeth]) == 0
    truth = np.load(cap / "truth.npz")["poses"]
    sec = (time.perf_counter() - t0) / len(truth)
    pf = read_poses(cap / "tracked.npz")
    data = np.load(cap / "tracked.npz")
    flagged = data["flagged"]
    mm, deg = pose_errors(pf.poses, truth, pf.reference_point)
    fit_mm, _ = pose_errors(data["fitted"], truth, pf.reference_point)
    ok = ~flagged
    rig_mean = rig_max = float("nan")
    if ok.sum() >= 20:
        ref = pf.reference_point
        rig = fit_nlpca(pf.poses[ok], JawFrame.from_poses(pf.poses[ok], ref), points=pf.mandible,
                        iterations=iterations)
        rec = rig.reproduce(truth)
        e, _ = pose_errors(rec, truth, ref)
        rig_mean, rig_max = float(e.mean()), float(e.max())
    return dict(name=name, frames=len(mm), flagged=int(flagged.sum()), restarted=int((data["starts"] > 1).sum()),
                mean=mm[ok].mean(), max=mm[ok].max(), deg=deg[ok].mean(), degmax=deg[ok].max(), all=mm.mean(),
                allmax=mm.max(), lost=int(((fit_mm > 1.0) & ok).sum()), sec=sec, rig=rig_mean, rigmax=rig_max)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--out", default="bench_teeth")
    ap.add_argument("--badin", default=None, help="folder of teeth_upper.obj, teeth_lower.obj, mandible.obj")
    ap.add_argument("--badin-frames", type=int, default=60, help="frames of the session for the Badin scans")
    ap.add_argument("--only", choices=("shipped", "badin"), default=None)
    ap.add_argument("--iterations", type=int, default=1000, help="NLPCA training iterations")
    args = ap.parse_args(argv)
    from facesim.cli import main as facesim
    from facesim.jaw.motion import JawMotion

    pose_errors = importlib.import_module("07_teeth_tracking").pose_errors
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    s = JawMotion().session(seed=0)
    idx = np.arange(*BORDER, args.every)
    np.savez(out / "session.npz", poses=s.poses[idx], reference_point=s.reference_point)
    np.savez(out / "session_badin.npz", poses=s.poses[idx[:args.badin_frames]], reference_point=s.reference_point)
    cases = [] if args.only == "badin" else [("shipped", [], out / "session.npz")]
    if args.badin and args.only != "shipped":
        b = Path(args.badin)
        cases.append(("badin", ["--upper", str(b / "teeth_upper.obj"), "--lower", str(b / "teeth_lower.obj"),
                                "--mandible", str(b / "mandible.obj")], out / "session_badin.npz"))
    rows = [run(name, teeth, poses, out, facesim, pose_errors, args.iterations) for name, teeth, poses in cases]
    print("| teeth | frames | flagged | restarted | mm mean / max (trusted) | deg mean / max | mm mean / max (all, "
          "held) | unflagged fits > 1 mm | s/frame | rig vs truth mm mean / max |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['frames']} | {r['flagged']} | {r['restarted']} | {r['mean']:.3f} / {r['max']:.3f} | "
              f"{r['deg']:.3f} / {r['degmax']:.3f} | {r['all']:.3f} / {r['allmax']:.3f} | {r['lost']} | "
              f"{r['sec']:.2f} | {r['rig']:.3f} / {r['rigmax']:.3f} |")


if __name__ == "__main__":
    main()
