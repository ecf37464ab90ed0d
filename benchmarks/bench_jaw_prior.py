"""Does the markerless jaw prior help solve-mocap? (issue 17, item 8)

The shipped demo clip (made on the medium face, solved on the coarse one, 0.5 mm noise, planted
outliers and drop-outs) solved four ways: with all 81 markers and with the 19 chin and jaw
markers taken out (a capture with few markers on the chin), each without and with
``--jaw-prior``. The predictors are trained here on a markerless dataset of the coarse face that
recorded its markers (``facesim jaw markerless dataset --model meshes/face_coarse.npz --frames 400
-o D.npz``): one on all markers, one on the markers the reduced capture has.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_jaw_prior.py --data D.npz [--frames 0:71] [--sigma 1.0]

Prints one table: marker RMS, activation error, jaw opening error (deg), condyle slide error (mm),
incisor error (mm, the jaw's own pose error at the lower incisal point), Gauss-Newton steps and
seconds per frame.
"""

from __future__ import annotations

import argparse
import csv
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from facesim import se3
from facesim.demo import DEMO_CLIP, SOLVE_MODEL, load_truth, run_demo
from facesim.inverse.jaw_prior import JawPrior
from facesim.jaw.markerless import evaluate, train
from facesim.jaw.markerless_data import load_data
from facesim.jaw.markerless_features import bone_rest_points
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import load_model

#: the markers a capture "with few markers on the chin" lacks
CHIN = ("mentolabial_C", "mentolabial_L", "mentolabial_R", "chin_C", "chin_L", "chin_R", "chin_low_C", "under_chin_L",
        "under_chin_R", "depressor_L", "depressor_R", "jaw_front_L", "jaw_front_R", "jaw_mid_L", "jaw_mid_R",
        "jaw_angle_L", "jaw_angle_R", "jaw_ramus_L", "jaw_ramus_R")


def incisor_errors(model, out: Path, truth: dict) -> np.ndarray:
    """Per solved frame, mm: the lower incisal point under the solved jaw against the true jaw."""
    jm = SlidingCondyleJaw(model.jaw)
    rows = np.loadtxt(out / "jaw.csv", delimiter=",", skiprows=1, ndmin=2)
    solved = np.stack([jm.transform(row[1:4]) for row in rows])
    true = np.stack([jm.transform(truth["jaw"][int(row[0])]) for row in rows])
    return se3.vertex_errors(solved, true, np.asarray(model.jaw.incisor, dtype=np.float64)[None])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="markerless dataset of the coarse face with markers")
    ap.add_argument("--frames", default=None, help="FIRST:LAST frames of the clip (default: all)")
    ap.add_argument("--sigma", type=float, default=1.0, help="the prior's sigma, mm (default: 1.0)")
    ap.add_argument("--out", default=None, help="keep the solves here (default: a temporary folder)")
    args = ap.parse_args()

    model = load_model(SOLVE_MODEL)
    truth = load_truth(DEMO_CLIP)
    data = load_data(args.data)
    names = list(model.markers.names)
    few = [n for n in names if n not in CHIN]
    bone = bone_rest_points(model)
    predictors = {}
    for label, keep in (("all", None), ("few", few)):
        d = data.marker_features(keep)
        t = time.perf_counter()
        cut = int(0.75 * d.n_frames)
        held = evaluate(train(d.subset(np.arange(cut))), d.subset(np.arange(cut, d.n_frames)))
        pred = train(d)
        predictors[label] = JawPrior(pred, bone, tuple(names), sigma=args.sigma)
        print(f"predictor on {label} markers ({d.n_features}): {time.perf_counter() - t:.1f} s; held-out frames "
              f"{cut}-{d.n_frames - 1}: {held['predictor']['mean_mm']:.3f} mm mean "
              f"(Procrustes of the same markers {held['baseline']['mean_mm']:.3f})")
    root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="jaw_prior_"))
    rows = []
    for capture, drop, pkey in (("81 markers", (), "all"), ("no chin markers (62)", CHIN, "few")):
        for prior in (None, predictors[pkey]):
            out = root / f"{pkey}_{'prior' if prior else 'plain'}"
            t = time.perf_counter()
            r = run_demo(out, model, frames=args.frames, progress=False, say=None, jaw_prior=prior, drop=drop)
            seconds = time.perf_counter() - t
            s = r["score"]
            with open(out / "frames.csv", newline="") as f:
                steps = [int(row["gn_steps"]) for row in csv.DictReader(f)]
            n = len(s["frames"])
            e = incisor_errors(model, out, truth)
            rows.append((capture, "yes" if prior else "no", s["marker_rms"]["mean"], s["activation"]["mean"],
                         s["jaw"]["opening_deg_mean"], s["jaw"]["opening_deg_max"], s["jaw"]["slide_mm_mean"],
                         e.mean(), e.max(), float(np.mean(steps)), seconds / max(n, 1)))
    print(f"\n{platform.node() or 'machine'}, {platform.processor() or platform.machine()}; sigma {args.sigma} mm; "
          f"frames {args.frames or 'all'}")
    print("| capture | jaw prior | marker RMS mm | activation err | opening err deg mean / max | slide err mm | "
          "incisor err mm mean / max | GN steps/frame | s/frame |")
    print("|---|---|---|---|---|---|---|---|---|")
    for c, p, m, a, om, ox, sl, em, ex, gn, sec in rows:
        print(f"| {c} | {p} | {m:.3f} | {a:.3f} | {om:.2f} / {ox:.2f} | {sl:.2f} | {em:.2f} / {ex:.2f} | {gn:.2f} | "
              f"{sec:.2f} |")


if __name__ == "__main__":
    main()
