"""Teeth tracking accuracy and speed (issue 19): 3 cameras at 1280x720, noise, blur, lip occlusion.

Prints per dentition (the shipped teeth; the Badin scans in metres, frame from their mandible):
lower-teeth pose error at the lower incisal point (mm) and in degrees (mean, max over the trusted
frames), flagged frames, seconds per frame.

    python benchmarks/bench_teeth.py [--frames 120] [--every 4] [--out /tmp/bench_teeth] [--badin DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--out", default="bench_teeth")
    ap.add_argument("--badin", default=None, help="folder of teeth_upper.obj, teeth_lower.obj, mandible.obj")
    args = ap.parse_args(argv)
    from facesim.cli import main as facesim
    from facesim.jaw.cli import read_poses
    from facesim.jaw.motion import JawMotion

    import importlib

    pose_errors = importlib.import_module("07_teeth_tracking").pose_errors
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    s = JawMotion().session(seed=0)
    idx = np.arange(0, len(s.poses), args.every)[:args.frames]
    np.savez(out / "session.npz", poses=s.poses[idx], reference_point=s.reference_point)
    cases = [("shipped", [])]
    if args.badin:
        b = Path(args.badin)
        cases.append(("badin", ["--upper", str(b / "teeth_upper.obj"), "--lower", str(b / "teeth_lower.obj"),
                                "--mandible", str(b / "mandible.obj")]))
    rows = []
    for name, teeth in cases:
        cap = out / name
        facesim(["teeth", "render", "-o", str(cap), "--poses", str(out / "session.npz"), "--every", "1", "-q", *teeth])
        t0 = time.perf_counter()
        facesim(["teeth", "track", "--cameras", str(cap / "cameras.json"), "--images", str(cap), "-o",
                 str(cap / "tracked.npz"), "-q", *teeth])
        sec = (time.perf_counter() - t0) / len(idx)
        pf = read_poses(cap / "tracked.npz")
        flagged = np.load(cap / "tracked.npz")["flagged"]
        mm, deg = pose_errors(pf.poses, np.load(cap / "truth.npz")["poses"], pf.reference_point)
        ok = ~flagged
        rows.append((name, len(mm), int(flagged.sum()), mm[ok].mean(), mm[ok].max(), deg[ok].mean(), deg[ok].max(),
                     mm.mean(), sec))
    print("| teeth | frames | flagged | mm mean (trusted) | mm max | deg mean | deg max | mm mean (all) | s/frame |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.3f} | {r[4]:.3f} | {r[5]:.3f} | {r[6]:.3f} | {r[7]:.3f} | {r[8]:.2f} |")


if __name__ == "__main__":
    main()
