"""Markerless jaw tracking on simulated subjects: a Table-1-style report (Zoss et al. 2019, issue 17).

facesim can make what the paper could not: captures whose jaw motion is known exactly. Each
subject's database (``facesim jaw markerless dataset``) is a few hundred frames of TMJ motion
combined with random expressions, each a quasistatic equilibrium of the subject's face. Then:

1. **Single subject**: the predictor trained on the first part of the canonical subject's sequence,
   tested on the rest (the paper: 2000 frames train, 1539 test, consistently below 1 mm).
2. **Leave one subject out** over the training subjects: the multi-subject predictor of the others,
   retargeted to the held-out one from 5 calibration poses, against the Procrustes baseline of
   the same skin features (the paper's Table 1: 1.09-2.38 mm against 4.79-9.97 mm).
3. **A subject never used in training**: the predictor of all training subjects retargeted to it.

Prints the tables (mean / p95 / max mm over the bone feature points) and writes
``markerless_errors.png`` (mean error per held-out subject, predictor against baseline).

    python examples/05_markerless_jaw.py --data DB/ [--out OUT] [--build --frames 300]

``DB/`` holds ``<subject>.npz`` datasets of the subjects named by ``--subjects`` (default
``canonical,wide,long,bmi`` and ``--heldout heldout``); ``--build`` makes the missing ones
(phantom subjects of :data:`facesim.markerless_dataset.SUBJECTS`: minutes per subject, about a
second per frame on the coarse face; ``canonical`` is the shipped coarse face). ``--subjects
canonical --heldout ''`` runs only the single-subject part.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.jaw.markerless import calibration_frames, evaluate, retarget, train
from facesim.jaw.markerless_data import MarkerlessData, load_data

#: Zoss et al. 2019 Table 1 (leave one subject out, mm): learned predictor and Procrustes baseline
PAPER = {"predictor": (1.09, 2.38), "baseline": (4.79, 9.97)}


def dataset(folder: Path, name: str, build: bool, frames: int, seed: int) -> MarkerlessData:
    path = folder / f"{name}.npz"
    if not path.is_file():
        if not build:
            raise SystemExit(f"{path}: no such dataset (give --build to simulate it)")
        from facesim._files import MESHES
        from facesim.markerless_dataset import build_dataset, phantom_subject_model

        model = MESHES / "face_coarse.npz" if name == "canonical" else phantom_subject_model(name, progress=print)
        build_dataset(model, path, frames=frames, seed=seed, name=name)
    return load_data(path)


def row(label: str, r: dict, n_cal: int | None = None) -> str:
    p, b = r["predictor"], r["baseline"]
    ratio = p["mean_mm"] / max(b["mean_mm"], 1e-12)
    cal = "" if n_cal is None else f"{n_cal:>4}"
    return (f"| {label:<22} |{cal:>4} | {r['frames']:>6} | {p['mean_mm']:7.3f} | {p['p95_mm']:7.3f} | "
            f"{p['max_mm']:7.3f} | {b['mean_mm']:7.3f} | {b['p95_mm']:7.3f} | {b['max_mm']:7.3f} | {ratio:5.2f} |")


HEADER = ("| subject                | cal | frames | pred mean | p95 | max | baseline mean | p95 | max | ratio |\n"
          "|---|---|---|---|---|---|---|---|---|---|")


def held_out(train_sets, target: MarkerlessData, n_cal: int):
    """The predictor of ``train_sets`` retargeted to ``target`` from ``n_cal`` calibration frames,
    evaluated on the target's other frames (and, for comparison, without retargeting)."""
    pred = train(train_sets)
    cal = calibration_frames(target, n_cal)
    rest = np.setdiff1d(np.arange(target.n_frames), cal)
    test = target.subset(rest)
    plain = evaluate(pred, test)
    adapted = evaluate(retarget(pred, target.subset(cal)), test)
    return plain, adapted


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="folder of <subject>.npz datasets")
    ap.add_argument("--out", default="markerless", help="output folder")
    ap.add_argument("--subjects", default="canonical,wide,long,bmi", help="training subjects, comma-separated")
    ap.add_argument("--heldout", default="heldout", help="the subject never trained on ('' for none)")
    ap.add_argument("--build", action="store_true", help="simulate the missing datasets")
    ap.add_argument("--frames", type=int, default=300, help="frames of a dataset --build makes")
    ap.add_argument("--train-fraction", type=float, default=0.6, help="single subject: leading part trained on")
    ap.add_argument("--calibration", type=int, default=5, help="calibration poses of a retargeting")
    args = ap.parse_args(argv)
    folder, out = Path(args.data), Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    names = [n for n in args.subjects.split(",") if n]
    data = {n: dataset(folder, n, args.build, args.frames, seed=i) for i, n in enumerate(names)}
    if args.heldout:
        data[args.heldout] = dataset(folder, args.heldout, args.build, args.frames, seed=len(names))
    results = {}

    # 1. single subject: the first part of its sequence trains, the rest tests
    first = data[names[0]]
    k = int(round(args.train_fraction * first.n_frames))
    t0 = time.perf_counter()
    pred = train(first.subset(slice(0, k)))
    seconds = time.perf_counter() - t0
    results["single"] = evaluate(pred, first.subset(slice(k, None)))
    print(f"single subject {names[0]}: trained on frames 0-{k - 1} in {seconds:.1f} s "
          f"(C={pred.meta['hyper']['C']:g}, epsilon={pred.meta['hyper']['epsilon']:g}, "
          f"cross-validated {pred.meta['hyper']['cv_mm']:.3f} mm), tested on {first.n_frames - k} frames")
    print(HEADER)
    print(row(f"{names[0]} (single)", results["single"]))

    # 2. leave one subject out, retargeted from a few calibration poses
    if len(names) >= 2:
        print(f"\nleave one subject out: trained on the others, retargeted from {args.calibration} poses")
        print(HEADER)
        for n in names:
            others = [data[m] for m in names if m != n]
            plain, adapted = held_out(others, data[n], args.calibration)
            results[n] = {"plain": plain, "retargeted": adapted}
            print(row(f"{n} (not retargeted)", plain))
            print(row(f"{n} (retargeted)", adapted, args.calibration))
    # 3. the subject never trained on
    if args.heldout and len(names) >= 1:
        plain, adapted = held_out([data[m] for m in names], data[args.heldout], args.calibration)
        results[args.heldout] = {"plain": plain, "retargeted": adapted}
        print(f"\nnever trained on: {args.heldout}, predictor of {', '.join(names)}")
        print(HEADER)
        print(row(f"{args.heldout} (not retargeted)", plain))
        print(row(f"{args.heldout} (retargeted)", adapted, args.calibration))
    held = {n: r["retargeted"] for n, r in results.items() if n != "single"}
    if held:
        worst = max(r["predictor"]["mean_mm"] / r["baseline"]["mean_mm"] for r in held.values())
        print(f"\nretargeted predictor / baseline, worst held-out subject: {worst:.2f} (goal <= 0.33); "
              f"Zoss et al. 2019: {PAPER['predictor'][0]}-{PAPER['predictor'][1]} mm against "
              f"{PAPER['baseline'][0]}-{PAPER['baseline'][1]} mm")
        figure(held, results.get("single"), out / "markerless_errors.png")
    return results


def figure(held: dict, single, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(held)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(1.3 * len(names) + 3, 3.8))
    pred = [held[n]["predictor"]["mean_mm"] for n in names]
    base = [held[n]["baseline"]["mean_mm"] for n in names]
    ax.bar(x - 0.2, pred, 0.4, label="predictor, retargeted from 5 poses")
    ax.bar(x + 0.2, base, 0.4, label="Procrustes baseline")
    if single is not None:
        ax.axhline(single["predictor"]["mean_mm"], color="k", lw=0.8, ls="--", label="single subject")
    ax.set_xticks(x, names)
    ax.set_ylabel("mean jaw error over the bone points, mm")
    ax.set_title("markerless jaw tracking, held-out subjects")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
