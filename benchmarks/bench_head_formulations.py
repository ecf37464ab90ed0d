"""Head formulations on the demo clip: Procrustes stabilisation against the head frame solved with
the other controls (12 affine coefficients under the rigidity penalty, Sifakis 2005 section 8),
with the clip's head markers as shipped, made noisier, and reduced to two (one table).

    NUMBA_NUM_THREADS=2 python benchmarks/bench_head_formulations.py [--frames 0:23] [--out DIR]
                                        [--head-noise 2.0] [--cases shipped noisy two]

The shipped clip (``meshes/demo_clip.c3d``: made on the medium face, head motion, 0.5 mm noise,
outliers and gaps) is solved on ``meshes/face_coarse.npz`` with
:func:`facesim.inverse.tracking.track` from the capture as captured (not stabilised beforehand),
neutral frames as :func:`facesim.demo.run_demo` takes them. Cases: ``shipped``; ``noisy``: the
head markers get ``--head-noise`` mm more Gaussian noise per axis (the same draw for both
formulations); ``two``: only two head markers are left (Procrustes needs three: solved with the
head frame only). Per run: Gauss-Newton steps, seconds (the frame logs' sums), marker RMS (mm,
mean over frames, in the capture's frame), the activation error of the visible muscles
(:func:`facesim.demo.score_solve`), and the head pose against the clip's truth: the RMS over the
model's rest markers of ``|T p - T_true p|`` (mm, mean and max over frames) and the rotation error
(degrees, mean). Procrustes' head pose is the inverse of its stabilisation transform. Timings are
never asserted; record the table in benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import csv
import platform
import tempfile
from pathlib import Path

import numpy as np

from facesim.controls_io import read_head_poses
from facesim.demo import DEMO_CLIP, HEAD_SMOOTHING, SOLVE_MODEL, load_truth, neutral_frames, score_solve
from facesim.fem.equilibrium import FaceSimulator
from facesim.inverse.gauss_newton import FitOptions
from facesim.inverse.tracking import TrackOptions, track
from facesim.kinematics.jaw_models import make_jaw_model
from facesim.mocap.binding import match_markers
from facesim.mocap.io import frame_mask, read_markers
from facesim.mocap.stabilise import stabilise
from facesim.model import load_model

CASES = ("shipped", "noisy", "two")


def _frame_log(path) -> dict:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("frame", "gn_steps", "seconds", "marker_rms")}


def head_errors(rest, poses: dict, truth) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of ``poses`` (frame -> 4x4, model head frame -> capture): RMS over ``rest (r, 3)``
    of the pose's error against the truth's head motion (mm), and its rotation error (degrees)."""
    row = {int(f): i for i, f in enumerate(truth["frames"])}
    mm, deg = [], []
    for f, T in sorted(poses.items()):
        H = truth["head"][row[f]]
        d = rest @ (T[:3, :3] - H[:3, :3]).T + (T[:3, 3] - H[:3, 3])
        mm.append(float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))))
        c = (np.trace(T[:3, :3] @ H[:3, :3].T) - 1.0) / 2.0
        deg.append(float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
    return np.array(mm), np.array(deg)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="0:23", help="FIRST:LAST frames of the clip, inclusive (default 0:23)")
    parser.add_argument("--head-noise", type=float, default=2.0, help="extra head-marker noise of 'noisy', mm")
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument("--out", default=None, help="results folder (default: a temporary one)")
    args = parser.parse_args(argv)

    model = load_model(SOLVE_MODEL)
    truth = load_truth(DEMO_CLIP)
    data = read_markers(DEMO_CLIP)
    index, _, _ = match_markers(model.markers.names, data.names)
    P_all = np.full((len(data.frames), model.n_markers, 3), np.nan)
    P_all[:, index >= 0] = data.P[:, index[index >= 0]]
    keep = frame_mask(args.frames, data.frames)
    head = np.flatnonzero(model.markers.head)
    rng = np.random.default_rng(1)
    noisy = P_all.copy()
    noisy[:, head] += rng.normal(0.0, args.head_noise, size=noisy[:, head].shape)
    two = P_all.copy()
    two[:, head[2:]] = np.nan
    captures = {"shipped": P_all, "noisy": noisy, "two": two}
    noise = float(truth["noise"])
    root = Path(args.out or tempfile.mkdtemp(prefix="bench_head_formulations_"))
    sim = FaceSimulator(model, jaw_model=make_jaw_model(model, "sliding-condyle"))
    print(f"{platform.processor() or platform.machine()}, numpy {np.__version__}; {model.n_tets:,} tets, "
          f"frames {args.frames} of {DEMO_CLIP.name} ({int(keep.sum())}), noise {noise:g} mm, {len(head)} head "
          f"markers, noisy: +{args.head_noise:g} mm on them; out {root}")
    rows = []
    for case in args.cases:
        P = captures[case]
        neutral = P[:neutral_frames(len(data.frames))]
        for mode in ("procrustes", "solve"):
            if mode == "procrustes" and case == "two":
                rows.append((case, mode) + (None,) * 7)
                continue
            out = root / f"{case}_{mode}"
            smoothing = HEAD_SMOOTHING if mode == "procrustes" else 0
            options = TrackOptions(fit=FitOptions(noise=noise), head=mode, head_smoothing=smoothing)
            track(sim, data.frames[keep], P[keep], out, options=options, progress=False, neutral=neutral,
                  overwrite=True)
            log = _frame_log(out / "frames.csv")
            score = score_solve(truth, out)
            if mode == "solve":
                poses = read_head_poses(out)
            else:   # the stabilisation's transforms (capture -> model), inverted; as track made them
                _, Ts = stabilise(model, P[keep], smoothing)
                poses = {int(f): np.linalg.inv(T) for f, T in zip(data.frames[keep], Ts)}
            mm, deg = head_errors(model.marker_positions(), poses, truth)
            rows.append((case, mode, int(log["gn_steps"].sum()), log["seconds"].sum(),
                         float(np.nanmean(log["marker_rms"])), score["activation"]["mean"], mm.mean(), mm.max(),
                         deg.mean()))
    cols = ("head markers", "head", "GN steps", "fit s", "marker RMS mm", "act err", "head err mm mean/max",
            "rotation err deg")
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        if r[2] is None:
            print(f"| {r[0]} | {r[1]} | - | - | - | - | needs >= 3 head markers | - |")
            continue
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.1f} | {r[4]:.3f} | {r[5]:.3f} | {r[6]:.3f} / {r[7]:.3f} | "
              f"{r[8]:.3f} |")


if __name__ == "__main__":
    main()
