"""Jaw formulations on the demo clip: the sliding-condyle jaw's 3 natural parameters against the
affine-condyle jaw's 12 frame coefficients with penalties (Sifakis 2005 section 8), one table.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_jaw_formulations.py [--frames 0:7] [--out DIR]
                                        [--models sliding-condyle affine-condyle]

The first frames of the shipped clip (``meshes/demo_clip.c3d``, made on the medium face) are
loaded, stabilised and bound to the skin as :func:`facesim.demo.run_demo` does, and solved on
``meshes/face_coarse.npz`` with :func:`facesim.inverse.tracking.track` (``overwrite=True``) once
per jaw formulation. Per formulation: Gauss-Newton steps, equilibria, seconds (the frame logs'
sums), marker RMS (mm, mean over frames), the activation error of the visible muscles
(:func:`facesim.demo.score_solve`), and the jaw against the clip's truth (``demo_clip_truth.npz``:
sliding-condyle parameters, turned into poses on the solve model's TMJ): opening angle error
(degrees; the fitted pose's opening ``atan2(-w.Mv, |(u.Mv, v.Mv)|)``), incisor position error (mm),
mean and max over frames, and how far the fitted poses are from valid ones: ``sqrt`` of the
affine-condyle penalty (mm, 0 for the sliding-condyle jaw whose poses are valid by construction).
Timings are never asserted; record the table in benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import csv
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from facesim.demo import DEMO_CLIP, HEAD_SMOOTHING, SOLVE_MODEL, load_truth, neutral_frames, score_solve
from facesim.fem.equilibrium import FaceSimulator
from facesim.framelog import read_log
from facesim.inverse.gauss_newton import FitOptions
from facesim.inverse.tracking import TrackOptions, track
from facesim.kinematics.affine_jaw import AffineCondyleJaw
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.kinematics.frames import matrix_to_frame
from facesim.kinematics.jaw_models import make_jaw_model
from facesim.mocap.binding import match_markers
from facesim.mocap.io import frame_mask, read_markers
from facesim.mocap.stabilise import stabilise
from facesim.model import load_model


def load_clip(model, clip=DEMO_CLIP, frames="0:7"):
    """The clip's markers in the model's order, stabilised over the whole clip as
    :func:`facesim.demo.run_demo` does: ``(frame numbers (F,), P (F, r, 3) mm, neutral (k, r, 3))``."""
    data = read_markers(clip)
    index, _, _ = match_markers(model.markers.names, data.names)
    P = np.full((len(data.frames), model.n_markers, 3), np.nan)
    P[:, index >= 0] = data.P[:, index[index >= 0]]
    P_all, _ = stabilise(model, P, HEAD_SMOOTHING)
    keep = frame_mask(frames, data.frames)
    return data.frames[keep], P_all[keep], P_all[:neutral_frames(len(data.frames))]


def _frame_log(path) -> dict:
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("frame", "gn_steps", "equilibria", "seconds", "marker_rms")}


def jaw_errors(model, truth, out, jaw_model) -> dict:
    """Opening error (deg) and incisor error (mm) of the solve in ``out`` against the truth, and the
    validity of the fitted poses (sqrt of the affine-condyle penalty, mm), per frame."""
    sc, affine = SlidingCondyleJaw(model.jaw), AffineCondyleJaw(model.jaw)
    _, J = read_log(Path(out) / "jaw.csv")
    row = {int(f): i for i, f in enumerate(truth["frames"])}
    incisor = model.jaw.incisor
    opening, inc, invalid = [], [], []
    for line in J:
        T = jaw_model.transform(line[1:])
        T_true = sc.transform(truth["jaw"][row[int(line[0])]])
        Mv = T[:3, :3] @ sc.v
        theta = np.arctan2(-(sc.w @ Mv), np.hypot(sc.u @ Mv, sc.v @ Mv))
        opening.append(np.degrees(abs(theta - truth["jaw"][row[int(line[0])]][0])))
        inc.append(np.linalg.norm((T - T_true)[:3, :3] @ incisor + (T - T_true)[:3, 3]))
        invalid.append(np.sqrt(affine.penalty(matrix_to_frame(T))[0]))
    return {"opening": np.array(opening), "incisor": np.array(inc), "invalid": np.array(invalid)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="0:7", help="FIRST:LAST frames of the clip, inclusive (default 0:7)")
    parser.add_argument("--models", nargs="+", default=["sliding-condyle", "affine-condyle"])
    parser.add_argument("--out", default=None, help="results folder (default: a temporary one)")
    args = parser.parse_args(argv)

    model = load_model(SOLVE_MODEL)
    truth = load_truth(DEMO_CLIP)
    frames, P, neutral = load_clip(model, DEMO_CLIP, args.frames)
    options = TrackOptions(fit=FitOptions(noise=float(truth["noise"])), head="none")
    root = Path(args.out or tempfile.mkdtemp(prefix="bench_jaw_formulations_"))
    print(f"{platform.processor() or platform.machine()}, numpy {np.__version__}; {model.n_tets:,} tets, "
          f"frames {args.frames} of {DEMO_CLIP.name} ({len(frames)}), noise {float(truth['noise']):g} mm; out {root}")
    rows = []
    for name in args.models:
        sim = FaceSimulator(model, jaw_model=make_jaw_model(model, name))
        out = root / name
        t0 = time.perf_counter()
        track(sim, frames, P, out, options=options, progress=False, neutral=neutral, overwrite=True)
        wall = time.perf_counter() - t0
        log = _frame_log(out / "frames.csv")
        score = score_solve(truth, out)
        jaw = jaw_errors(model, truth, out, sim.jaw_model)
        rows.append((name, sim.jaw_model.n_params, int(log["gn_steps"].sum()), int(log["equilibria"].sum()),
                     log["seconds"].sum(), wall, float(np.nanmean(log["marker_rms"])), score["activation"]["mean"],
                     jaw["opening"].mean(), jaw["opening"].max(), jaw["incisor"].mean(), jaw["incisor"].max(),
                     jaw["invalid"].max()))
    head = ("jaw model", "q", "GN steps", "equilibria", "fit s", "wall s", "marker RMS mm", "act err",
            "opening err deg mean/max", "incisor err mm mean/max", "invalid mm max")
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.1f} | {r[5]:.1f} | {r[6]:.3f} | {r[7]:.3f} | "
              f"{r[8]:.3f} / {r[9]:.3f} | {r[10]:.3f} / {r[11]:.3f} | {r[12]:.2e} |")


if __name__ == "__main__":
    main()
