"""Jaw rigs on generated motion: fit time and held-out error per rig (never asserted in tests).

    python benchmarks/bench_jaw_rigs.py [--subjects 0 1 2] [--noise 0.03] [--points 400]
                                        [--pairs 3:4 1:2 5:6 7:8 9:10]

For each subject (``default`` is ``Subject()``, ``model`` the shipped model's own subject
``subject_for(model.jaw)``, an integer n is ``Subject.random(n)``) on the shipped model's TMJ: a capture-like session (seed 1: border movements, chewing, speech, free
moves) trains every rig, a second session (seed 2) of the same subject tests it. The error of a
frame is the front-weighted mean distance (mm) of the mandible surface points between the
captured pose and the rig's pose (Zoss et al. 2018 Fig. 8); the table gives its mean, 95th
percentile and maximum over the test frames, and the mean over the training frames.

Three more tables: the envelope found in the unlabelled training poses (``detect_border``)
against the one from the labelled border movements (surface distance both ways, and the test
error of the Posselt rig with either); linear PCA against hierarchical NLPCA with 1-3 parameters (Yang et al. 2018;
reconstruction of the test session by projection / encoder-decoder, next to Yang's 1.73 mm
mean), and retargeting (Zoss section 5) for each source:target pair of subjects: the source
rig fitted on its session, adapted from five noisy extremal poses of the target (rest, maximum
opening, protrusion, left, right), measured on the target's test session, next to the rig
fitted on the target's full training session.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from facesim import se3
from facesim.jaw.evaluate import RIGS, compare_rigs, pose_errors
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Subject, subject_for
from facesim.jaw.nlpca import compare_reconstruction
from facesim.jaw.points import front_weights, mandible_points
from facesim.jaw.posselt import fit_posselt
from facesim.jaw.retarget import retarget_posselt


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", nargs="+", default=["model", "default", "0", "1"])
    parser.add_argument("--noise", type=float, default=0.03, help="capture noise, mm (default 0.03)")
    parser.add_argument("--points", type=int, default=400, help="mandible surface points (default 400)")
    parser.add_argument("--pairs", nargs="*", default=["3:4", "1:2", "5:6", "7:8", "9:10"],
                        help="retargeting source:target subject seeds")
    args = parser.parse_args(argv)

    points = mandible_points(count=args.points)
    print(f"# {platform.processor() or platform.machine()}, numpy {np.__version__}; noise {args.noise} mm, "
          f"{len(points)} mandible points, front-weighted (floor 0.1)")
    print(f"{'subject':<9}{'rig':<9}{'frames':>8}{'fit s':>8}{'train mean':>12}{'test mean':>11}"
          f"{'test p95':>10}{'test max':>10}")
    summary = {name: [] for name in RIGS}
    for name in args.subjects:
        train, test, frame = _sessions(name, args.noise)
        reports = compare_rigs(train, test, points, front_weights(points, frame), frame=frame)
        for r in reports.values():
            summary[r.name].append(r.test.mean)
            print(f"{name:<9}{r.name:<9}{len(train.poses):>8}{r.fit_seconds:>8.2f}{r.train.mean:>12.3f}"
                  f"{r.test.mean:>11.3f}{r.test.p95:>10.3f}{r.test.max:>10.3f}")
    print("# mean test error over subjects (mm): "
          + ", ".join(f"{k} {np.mean(v):.3f}" for k, v in summary.items() if v))
    detection_table(args, points)
    nlpca_table(args, points)
    retarget_table(args, points)


def _subject(name: str) -> Subject:
    if name == "default":
        return Subject()
    if name == "model":
        return subject_for()
    return Subject.random(int(name))


def _sessions(name, noise):
    """Training session (seed 1), test session (seed 2) and the jaw frame of the training poses."""
    motion = JawMotion(subject=_subject(name))
    train = motion.session(seed=1, noise=noise)
    return train, motion.session(seed=2, noise=noise), JawFrame.from_poses(train.poses, train.reference_point)


def detection_table(args, points):
    from scipy.spatial import cKDTree

    print(f"\n{'subject':<9}{'found s':>8}{'gap mean':>10}{'gap max':>9}{'labelled mean':>15}{'found mean':>12}"
          f"{'found max':>11}   (envelope found in unlabelled poses vs labelled, mm)")
    for name in args.subjects:
        train, test, frame = _sessions(name, args.noise)
        labelled = fit_posselt(train, frame=frame)
        start = time.perf_counter()
        found = fit_posselt(train, frame=frame, border="detect")
        seconds = time.perf_counter() - start
        a, b = found.shield, labelled.shield
        gap = np.concatenate([cKDTree(y.point(y.face_samples(120))).query(x.point(x.face_samples(40)))[0]
                              for x, y in ((a, b), (b, a))])
        w = front_weights(points, frame)
        e_l = pose_errors(labelled.reproduce(test.poses), test.poses, points, w)
        e_f = pose_errors(found.reproduce(test.poses), test.poses, points, w)
        print(f"{name:<9}{seconds:>8.2f}{gap.mean():>10.3f}{gap.max():>9.3f}{e_l.mean:>15.3f}{e_f.mean:>12.3f}"
              f"{e_f.max:>11.3f}")


def nlpca_table(args, points):
    print(f"\n{'subject':<9}{'params':>7}{'PCA mean':>10}{'PCA max':>9}{'NLPCA mean':>12}{'NLPCA max':>11}"
          f"{'train s':>9}   (Yang et al. 2018: 1.73 mm mean)")
    for name in args.subjects:
        train, test, frame = _sessions(name, args.noise)
        report = compare_reconstruction(train.poses, test.poses, frame, points, front_weights(points, frame))
        for k in (1, 2, 3):
            print(f"{name:<9}{k:>7}{report.pca[k][0]:>10.3f}{report.pca[k][1]:>9.3f}{report.nlpca[k][0]:>12.3f}"
                  f"{report.nlpca[k][1]:>11.3f}{report.seconds:>9.2f}")


def retarget_table(args, points):
    print(f"\n{'source':<8}{'target':<8}{'rig':<9}{'s':>6}{'test mean':>11}{'test p95':>10}{'test max':>10}")
    latent = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1.0]])
    for pair in args.pairs:
        a, b = (int(v) for v in pair.split(":"))
        source = fit_posselt(JawMotion(subject=Subject.random(a)).session(seed=1, noise=args.noise))
        target = JawMotion(subject=Subject.random(b))
        rng = np.random.default_rng(0)
        extremes = target.poses(latent) @ se3.exp(np.c_[rng.normal(scale=args.noise / 100, size=(5, 3)),
                                                        rng.normal(scale=args.noise, size=(5, 3))])
        train, test = target.session(seed=1, noise=args.noise), target.session(seed=2, noise=args.noise)
        for mode in ("none", "reduced", "full", "fitted"):
            start = time.perf_counter()
            rig = fit_posselt(train) if mode == "fitted" else \
                retarget_posselt(source, extremes, train.reference_point, mode=mode)
            seconds = time.perf_counter() - start
            w = front_weights(points, rig.frame)
            e = pose_errors(rig.reproduce(test.poses), test.poses, points, w)
            print(f"{a:<8}{b:<8}{mode:<9}{seconds:>6.2f}{e.mean:>11.3f}{e.p95:>10.3f}{e.max:>10.3f}")


if __name__ == "__main__":
    main()
