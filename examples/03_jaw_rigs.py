"""Empirical jaw rigs on motion generated for the shipped face's own TMJ.

Two capture-like sessions (border movements, chewing, speech, free moves; 0.03 mm capture
noise) are generated for the temporomandibular joints of the shipped model
(:func:`facesim.jaw.motion.subject_for`: its condyles, tracks and maximum opening). Every rig is
fitted on the first session and judged on the second by the per-frame error: the mean distance
between the mandible surface placed by the captured pose and by the rig's pose, weighted toward
the chin and incisors (Zoss et al. 2018 Fig. 8).

1. ``rigs.png`` -- the per-frame error of the traditional 1-, 3- and 5-DOF rigs (best
   parameters per frame, pivot optimised), the Posselt-envelope rig (driven by the incisal point
   alone) and the 3-parameter NLPCA rig (Yang et al. 2018; inverse kinematics), their mean /
   95th percentile / max, and the weight map on the mandible.
2. ``envelope.png`` -- Posselt's envelope (the shield) of the Posselt rig with the test session's
   incisal points, in 3D and in the sagittal and frontal views, and dashed the border curves
   found in the same poses without movement labels.
3. ``retarget.png`` -- the Posselt rig moved to a second subject (another joint and incisal
   range on the same skull) from five extremal poses: unadapted, reduced adaptation (envelope
   only) and full adaptation (envelope and pose map), against a rig fitted on that subject's own
   session; per-frame errors and the sagittal view of the envelopes.

The tables printed are the numbers behind the figures, and linear PCA against NLPCA with 1 to 3
parameters (reconstruction of the test session, next to Yang et al.'s 1.73 mm mean).

    python examples/03_jaw_rigs.py --out jaw_rigs/ [--target 1] [--points 400] [--nlpca-iterations 1000]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim import load_model, se3
from facesim.jaw.evaluate import compare_rigs, pose_errors
from facesim.jaw.figures import envelope_figure
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Subject, subject_for
from facesim.jaw.nlpca import compare_reconstruction
from facesim.jaw.points import front_weights, mandible_points
from facesim.jaw.posselt import Shield, fit_posselt
from facesim.jaw.retarget import EXTREMES, retarget_posselt

RIGS = ("1dof", "3dof", "5dof", "posselt", "nlpca")
LABELS = {"1dof": "1-DOF", "3dof": "3-DOF", "5dof": "5-DOF", "posselt": "Posselt", "nlpca": "NLPCA (3 params)",
          "none": "source rig, unadapted", "reduced": "reduced adaptation", "full": "full adaptation",
          "fitted": "fitted on the subject's session"}
COLOURS = {"1dof": "tab:gray", "3dof": "tab:brown", "5dof": "tab:purple", "posselt": "tab:blue", "nlpca": "tab:green",
           "none": "tab:gray", "reduced": "tab:orange", "full": "tab:blue", "fitted": "k"}
YANG_MEAN = 1.73      # mm, Yang et al. 2018: mean reconstruction error of their 3-parameter model
LATENT = {"rest": (0.0, 0.0, 0.0), "open": (1.0, 0.0, 0.0), "protrusion": (0.0, 1.0, 0.0), "left": (0.0, 0.0, 1.0),
          "right": (0.0, 0.0, -1.0)}     # generator controls (opening, protrusion, laterality) of the extremes


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def rigs_figure(path, times, reports, points, weights, frame):
    """Zoss Fig. 8: per-frame error per rig (log scale), summary bars, and the weight map."""
    plt = _plt()
    fig = plt.figure(figsize=(13, 8))
    grid = fig.add_gridspec(2, 2, height_ratios=(1.3, 1.0))
    ax = fig.add_subplot(grid[0, :])
    for name, r in reports.items():
        ax.plot(times, np.maximum(r.test.per_frame, 1e-3), color=COLOURS[name], linewidth=0.8,
                label=f"{LABELS[name]}: mean {r.test.mean:.2f} mm")
    ax.set_yscale("log")
    ax.set_xlabel("time (s), test session")
    ax.set_ylabel("weighted mandible error (mm)")
    ax.legend(loc="upper right", fontsize=8, ncol=3)
    ax.grid(alpha=0.3, which="both")
    bars = fig.add_subplot(grid[1, 0])
    names = list(reports)
    x = np.arange(len(names))
    for k, (stat, alpha) in enumerate((("mean", 1.0), ("p95", 0.6), ("max", 0.3))):
        values = [getattr(reports[n].test, stat) for n in names]
        bars.bar(x + (k - 1) * 0.27, values, width=0.27, color=[COLOURS[n] for n in names], alpha=alpha,
                 label=stat if stat != "p95" else "95th percentile")
    bars.set_xticks(x, [LABELS[n].split(" ")[0] for n in names])
    bars.set_yscale("log")
    bars.set_ylabel("error (mm)")
    bars.legend(fontsize=8)
    bars.grid(alpha=0.3, axis="y", which="both")
    side = fig.add_subplot(grid[1, 1])
    local = frame.to_local(points)
    shown = side.scatter(local[:, 2], local[:, 1], c=weights, cmap="viridis", s=8)
    fig.colorbar(shown, ax=side, label="weight")
    side.set_aspect("equal", adjustable="datalim")
    side.set_xlabel("z, forward (mm)")
    side.set_ylabel("y, up (mm)")
    side.set_title("mandible points and their front weights (side view)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def retarget_figure(path, times, errors, rigs, extremes_local):
    """Per-frame errors of the retargeted rigs and the sagittal view of their envelopes."""
    plt = _plt()
    fig, (ax, view) = plt.subplots(1, 2, figsize=(14, 5.2), gridspec_kw={"width_ratios": (1.6, 1.0)})
    for mode, e in errors.items():
        ax.plot(times, np.maximum(e.per_frame, 1e-3), color=COLOURS[mode], linewidth=0.8,
                label=f"{LABELS[mode]}: mean {e.mean:.2f} mm")
    ax.set_yscale("log")
    ax.set_xlabel("time (s), the new subject's test session")
    ax.set_ylabel("weighted mandible error (mm)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    for mode, rig in rigs.items():
        for k, curve in enumerate(rig.shield.curves[:2]):           # posterior and anterior borders
            view.plot(curve[:, 2], curve[:, 1], color=COLOURS[mode], linestyle="-" if k else "--", linewidth=1.2,
                      label=LABELS[mode] if k else None)
    view.scatter(extremes_local[:, 2], extremes_local[:, 1], color="tab:red", zorder=3, label="the five extremal poses")
    view.set_aspect("equal", adjustable="datalim")
    view.set_xlabel("z, forward (mm)")
    view.set_ylabel("y, up (mm)")
    view.set_title("posterior (dashed) and anterior borders, sagittal view\n(reduced and full adaptation share "
                   "the adapted envelope)", fontsize=10)
    view.legend(fontsize=7, loc="upper left")
    view.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="jaw_rigs", help="output folder")
    ap.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "meshes" / "face_coarse.npz"),
                    help="the face model whose TMJ and mandible are used")
    ap.add_argument("--target", type=int, default=1, help="seed of the second subject (Subject.random) to retarget to")
    ap.add_argument("--noise", type=float, default=0.03, help="capture noise, mm (rotation: noise/100 rad)")
    ap.add_argument("--points", type=int, default=400, help="mandible surface points the errors are measured on")
    ap.add_argument("--nlpca-iterations", type=int, default=1000, help="L-BFGS iterations of the NLPCA autoencoder")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    model = load_model(args.model)
    motion = JawMotion(model.jaw, subject_for(model.jaw))
    train = motion.session(seed=1, noise=args.noise)
    test = motion.session(seed=2, noise=args.noise)
    points = mandible_points(model, args.points)
    frame = JawFrame.from_poses(train.poses, train.reference_point)
    weights = front_weights(points, frame)
    print(f"{args.model}: TMJ subject with a maximum opening of {motion.subject.max_opening:.1f} mm "
          f"({np.degrees(model.jaw.max_opening):.1f} degrees); {len(train.poses)} training and {len(test.poses)} "
          f"test frames; errors on {len(points)} front-weighted mandible points")

    # 1. the rigs of Zoss Fig. 8
    reports = compare_rigs(train, test, points, weights, rigs=RIGS, frame=frame,
                           nlpca_options={"iterations": args.nlpca_iterations})
    print(f"\n{'rig':<18}{'fit s':>7}{'train mean':>12}{'test mean':>11}{'p95':>8}{'max':>8}   (mm)")
    for name, r in reports.items():
        print(f"{LABELS[name]:<18}{r.fit_seconds:>7.2f}{r.train.mean:>12.3f}{r.test.mean:>11.3f}{r.test.p95:>8.3f}"
              f"{r.test.max:>8.3f}")
    rigs_figure(out / "rigs.png", test.times, reports, points, weights, frame)
    nl = compare_reconstruction(train.poses, test.poses, frame, points, weights, iterations=args.nlpca_iterations)
    print(f"\n{'parameters':<12}{'PCA mean':>10}{'PCA max':>9}{'NLPCA mean':>12}{'NLPCA max':>11}   "
          f"(reconstruction of the test session, mm; Yang et al. 2018: {YANG_MEAN} mm mean)")
    for k in sorted(nl.pca):
        print(f"{k:<12}{nl.pca[k][0]:>10.3f}{nl.pca[k][1]:>9.3f}{nl.nlpca[k][0]:>12.3f}{nl.nlpca[k][1]:>11.3f}")

    # 2. the envelope, from the labelled border movements and found in the unlabelled poses
    posselt = reports["posselt"].rig
    found = Shield.from_cloud(posselt.frame.pose_to_local(train.poses)[:, :3, 3])
    from scipy.spatial import cKDTree

    labelled = posselt.shield
    gap = np.concatenate([cKDTree(b.point(b.face_samples(120))).query(a.point(a.face_samples(40)))[0]
                          for a, b in ((found, labelled), (labelled, found))])
    print(f"\nenvelope found in the unlabelled poses vs from the labelled border movements: surface distance mean "
          f"{gap.mean():.3f} mm, max {gap.max():.3f} mm; bijectivity (eq. 15) {labelled.bijectivity():.4f} labelled, "
          f"{found.bijectivity():.4f} found")
    envelope_figure(posselt, out / "envelope.png", test.poses, compare=found.curves,
                    compare_label="found without labels",
                    title="Posselt's envelope of the incisal point (jaw frame): shield of the labelled border "
                          "movements, test-session incisal points")

    # 3. retargeting to a second subject from five extremal poses
    target = JawMotion(model.jaw, Subject.random(args.target))
    rng = np.random.default_rng(0)
    names = list(EXTREMES)
    extremes = target.poses(np.array([LATENT[n] for n in names])) @ se3.exp(
        np.c_[rng.normal(scale=args.noise / 100, size=(len(names), 3)), rng.normal(scale=args.noise, size=(len(names), 3))])
    t_train, t_test = target.session(seed=1, noise=args.noise), target.session(seed=2, noise=args.noise)
    retargeted, errors = {}, {}
    print(f"\nretargeting to subject {args.target} (maximum opening {target.subject.max_opening:.1f} mm, protrusion "
          f"{target.subject.protrusion:.1f} mm, eminence {np.degrees(target.inclination):.0f} degrees) from "
          f"{len(names)} extremal poses ({', '.join(names)})")
    print(f"{'rig':<32}{'s':>6}{'test mean':>11}{'p95':>8}{'max':>8}   (mm)")
    for mode in ("none", "reduced", "full", "fitted"):
        t0 = time.perf_counter()
        rig = fit_posselt(t_train) if mode == "fitted" else \
            retarget_posselt(posselt, extremes, t_train.reference_point, names=names, mode=mode)
        seconds = time.perf_counter() - t0
        e = pose_errors(rig.reproduce(t_test.poses), t_test.poses, points, front_weights(points, rig.frame))
        retargeted[mode], errors[mode] = rig, e
        print(f"{LABELS[mode]:<32}{seconds:>6.2f}{e.mean:>11.3f}{e.p95:>8.3f}{e.max:>8.3f}")
    extremes_local = retargeted["full"].frame.pose_to_local(extremes)[:, :3, 3]
    retarget_figure(out / "retarget.png", t_test.times, errors, retargeted, extremes_local)
    files = [out / "rigs.png", out / "envelope.png", out / "retarget.png"]
    print(f"\nwrote {', '.join(map(str, files))} in {time.perf_counter() - start:.0f} s")
    return {"rigs": {n: r.test for n, r in reports.items()}, "reconstruction": nl, "envelope_gap": gap,
            "retarget": errors, "files": files}


if __name__ == "__main__":
    main()
