"""Markerless jaw tracking (issue 17): the simulated database's cost and the predictor's.

For the datasets in ``--data`` (``<subject>.npz`` as ``facesim jaw markerless dataset`` writes;
``examples/05_markerless_jaw.py --build`` makes them) prints per subject its frames, seconds and
Newton iterations per frame and failed frames, then the time to train the multi-subject
predictor on the training subjects, to retarget it (5 calibration poses) and to predict a frame,
and the file size. With ``--ship PATH`` it also writes the shipped predictor: the training
subjects every ``--stride``-th frame, single precision (``meshes/markerless_jaw.npz``), and
reports its errors on the never-trained-on subject.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_markerless.py --data DB/ [--ship meshes/markerless_jaw.npz]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from facesim.jaw.markerless import (calibration_frames, evaluate, predict_poses, retarget, save_predictor,
                                    train)
from facesim.jaw.markerless_data import load_data


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--subjects", default="canonical,wide,long,bmi")
    ap.add_argument("--heldout", default="heldout")
    ap.add_argument("--ship", default=None, help="write the shipped predictor here")
    ap.add_argument("--stride", type=int, default=2, help="every k-th frame of each subject in the shipped predictor")
    args = ap.parse_args(argv)
    folder = Path(args.data)
    names = [n for n in args.subjects.split(",") if n]
    data = {n: load_data(folder / f"{n}.npz") for n in names + ([args.heldout] if args.heldout else [])}
    print("| subject | frames | failed | s/frame | Newton/frame | nodes | tets |")
    print("|---|---|---|---|---|---|---|")
    for n, d in data.items():
        m = d.meta
        print(f"| {n} | {d.n_frames} | {int((~d.ok).sum())} | {m.get('seconds_per_frame', float('nan')):.2f} | "
              f"{m.get('iterations_per_frame', float('nan')):.1f} | {m['model']['nodes']:,} | {m['model']['tets']:,} |")
    sets = [data[n] for n in names]
    t = time.perf_counter()
    pred = train(sets)
    t_train = time.perf_counter() - t
    target = data[args.heldout] if args.heldout else sets[-1]
    cal = calibration_frames(target, 5)
    t = time.perf_counter()
    adapted = retarget(pred, target.subset(cal))
    t_retarget = time.perf_counter() - t
    t = time.perf_counter()
    predict_poses(adapted, target)
    t_predict = (time.perf_counter() - t) / target.n_frames
    with tempfile.TemporaryDirectory() as tmp:
        size64 = os.path.getsize(save_predictor(pred, Path(tmp) / "p.npz"))
        size32 = os.path.getsize(save_predictor(pred, Path(tmp) / "q.npz", single=True))
    print()
    print("| predictor | training frames | support vectors | train s | retarget s | predict ms/frame | file MB (f64 / f32) |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {len(names)} subjects | {sum(int(d.ok.sum()) for d in sets)} | {len(pred.support)} | {t_train:.1f} | "
          f"{t_retarget:.2f} | {1e3 * t_predict:.2f} | {size64 / 1e6:.1f} / {size32 / 1e6:.1f} |")
    if args.ship:
        thin = [d.subset(np.arange(0, d.n_frames, args.stride)) for d in sets]
        ship = train(thin)
        ship = dataclasses.replace(ship, meta={**ship.meta, "shipped": {
            "subjects": names, "stride": args.stride, "made_by": "benchmarks/bench_markerless.py --ship"}})
        path = save_predictor(ship, args.ship, single=True)
        rest = np.setdiff1d(np.arange(target.n_frames), cal)
        r = evaluate(retarget(ship, target.subset(cal)), target.subset(rest))
        plain = evaluate(ship, target.subset(rest))
        print(f"\nshipped predictor -> {path} ({os.path.getsize(path) / 1e6:.1f} MB, "
              f"{sum(d.n_frames for d in thin)} frames): on {args.heldout}, not retargeted "
              f"{plain['predictor']['mean_mm']:.3f} mm, retargeted from 5 poses {r['predictor']['mean_mm']:.3f} mm "
              f"(p95 {r['predictor']['p95_mm']:.3f}, max {r['predictor']['max_mm']:.3f}); baseline "
              f"{r['baseline']['mean_mm']:.3f} mm")


if __name__ == "__main__":
    main()
