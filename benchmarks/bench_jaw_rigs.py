"""Jaw rigs on generated motion: fit time and held-out error per rig (never asserted in tests).

    python benchmarks/bench_jaw_rigs.py [--subjects 0 1 2] [--noise 0.03] [--points 400]

For each subject (``default`` is ``Subject()``, an integer n is ``Subject.random(n)``) on the
shipped model's TMJ: a capture-like session (seed 1: border movements, chewing, speech, free
moves) trains every rig, a second session (seed 2) of the same subject tests it. The error of a
frame is the front-weighted mean distance (mm) of the mandible surface points between the
captured pose and the rig's pose (Zoss et al. 2018 Fig. 8); the table gives its mean, 95th
percentile and maximum over the test frames, and the mean over the training frames.
"""

from __future__ import annotations

import argparse
import platform

import numpy as np

from facesim.jaw.evaluate import RIGS, compare_rigs, front_weights, mandible_points
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Subject


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subjects", nargs="+", default=["default", "0", "1"])
    parser.add_argument("--noise", type=float, default=0.03, help="capture noise, mm (default 0.03)")
    parser.add_argument("--points", type=int, default=400, help="mandible surface points (default 400)")
    args = parser.parse_args(argv)

    points = mandible_points(count=args.points)
    print(f"# {platform.processor() or platform.machine()}, numpy {np.__version__}; noise {args.noise} mm, "
          f"{len(points)} mandible points, front-weighted (floor 0.1)")
    print(f"{'subject':<9}{'rig':<9}{'frames':>8}{'fit s':>8}{'train mean':>12}{'test mean':>11}"
          f"{'test p95':>10}{'test max':>10}")
    summary = {name: [] for name in RIGS}
    for name in args.subjects:
        subject = Subject() if name == "default" else Subject.random(int(name))
        motion = JawMotion(subject=subject)
        train = motion.session(seed=1, noise=args.noise)
        test = motion.session(seed=2, noise=args.noise)
        frame = JawFrame.from_poses(train.poses, train.reference_point)
        reports = compare_rigs(train, test, points, front_weights(points, frame), frame=frame)
        for r in reports.values():
            summary[r.name].append(r.test.mean)
            print(f"{name:<9}{r.name:<9}{len(train.poses):>8}{r.fit_seconds:>8.2f}{r.train.mean:>12.3f}"
                  f"{r.test.mean:>11.3f}{r.test.p95:>10.3f}{r.test.max:>10.3f}")
    print("# mean test error over subjects (mm): "
          + ", ".join(f"{k} {np.mean(v):.3f}" for k, v in summary.items() if v))


if __name__ == "__main__":
    main()
