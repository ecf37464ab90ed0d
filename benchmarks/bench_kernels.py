"""Milliseconds per call of the flesh kernels on a model: energy + gradient, and the element
Hessians (true and PSD-projected), at a random deformed state.

    python benchmarks/bench_kernels.py [--model meshes/face_coarse.npz] [--threads 1] [--repeat 10]

Unclamped tets take stress and true tangent from the invariants (no SVD); the projected
Hessian and clamped tets use the singular-value modes. ``--clamp-all`` sends every tet to the
SVD form (clamp 0.9: an estimate of the old cost, its clamped branch aside). Prints a table;
never asserted in tests.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _time(fn, repeat: int) -> float:
    fn()   # compile / warm
    t = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t) / repeat * 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(ROOT / "meshes" / "face_coarse.npz"))
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: numba's)")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--clamp-all", action="store_true", help="clamp 0.9: every tet through the SVD form")
    args = ap.parse_args(argv)
    import numba

    from facesim.fem.equilibrium import FaceSimulator
    from facesim.fem.terms import ElasticTerm
    from facesim.model import load_model

    if args.threads:
        numba.set_num_threads(args.threads)
    model = load_model(args.model)
    sim = FaceSimulator(model)
    term = next(t for t in sim.terms if isinstance(t, ElasticTerm))
    if args.clamp_all:
        term.clamp = 0.9
    x = model.X + 0.1 * np.random.default_rng(0).normal(size=model.X.shape)
    rows = [("energy + gradient", _time(lambda: term.energy_and_gradient(x), args.repeat)),
            ("element Hessians, true", _time(lambda: term.element_hessians(x, False), args.repeat)),
            ("element Hessians, projected", _time(lambda: term.element_hessians(x, True), args.repeat))]
    print(f"{Path(args.model).name}: {len(term.elems):,} simulated tets, numba threads {numba.get_num_threads()}, "
          f"load average {os.getloadavg()[0]:.2f}{', clamp 0.9 (SVD form everywhere)' if args.clamp_all else ''}")
    print(f"{'kernel':<30} {'ms/call':>8} {'us/tet':>7}")
    for name, ms in rows:
        print(f"{name:<30} {ms:>8.1f} {ms * 1e3 / len(term.elems):>7.2f}")


if __name__ == "__main__":
    main()
