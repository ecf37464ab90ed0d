"""A wide jaw opening in one step on imported faces: Newton iterations, time, inverted tets and
the worst volume ratio, per flesh clamp and starting guess, one table.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_jaw_opening.py M1.npz [M2.npz ...] [--opening 0.3]
        [--clamps 0.1,0.01]

The models are imported faces (``facesim model import``; fTetWild's mesh differs run to run, so
pass several). Each row: the sliding-condyle jaw opened ``--opening`` rad from rest, rest muscles,
one equilibrium with no substep retry (``EquilibriumOptions(substeps=1)``, 200 Newton steps at
most), with the starting guess refined by as-rigid-as-possible steps where harmonic interpolation
crushes a tet (``arap``, the default) or harmonic interpolation alone (``harmonic``). Inverted:
simulated tets with ``det F <= 0``; min J: the smallest ratio of deformed to rest volume. Times
include nothing but the solve (a warm-up solve compiles the kernels first). Never asserted;
record the table in benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import facesim.fem.equilibrium as equilibrium_module
from facesim.controls import Controls
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.model import load_model


def solve(model, clamp: float, opening: float, guess: str) -> dict:
    equilibrium_module.PREDICT_MIN_J = 0.2 if guess == "arap" else -np.inf
    sim = FaceSimulator(model, EquilibriumOptions(NewtonOptions(max_iterations=200), clamp=clamp, substeps=1),
                        jaw_model="sliding-condyle")
    controls = Controls(np.zeros(model.n_muscles), np.array([opening, 0.0, 0.0]))
    start = sim.predict(controls)
    t0 = time.perf_counter()
    eq = sim.equilibrium(controls)
    seconds = time.perf_counter() - t0
    V0 = model.tet_volumes()[model.simulated]
    J = model.tet_volumes(eq.x)[model.simulated] / V0
    J_start = model.tet_volumes(start)[model.simulated] / V0
    return {"converged": eq.converged, "iterations": eq.report.iterations, "seconds": seconds,
            "inverted": int((J <= 0).sum()), "min_J": float(J.min()), "start_inverted": int((J_start <= 0).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--opening", type=float, default=0.3)
    ap.add_argument("--clamps", default="0.1,0.01")
    ap.add_argument("--guesses", default="harmonic,arap")
    args = ap.parse_args()
    clamps = [float(c) for c in args.clamps.split(",")]
    guesses = args.guesses.split(",")
    print(f"machine: {platform.machine()}, {platform.processor() or 'cpu'}; opening {args.opening} rad in one step")
    warm = load_model(args.models[0])
    solve(warm, clamps[0], 0.05, guesses[0])   # compiles the kernels
    print("| model | tets | clamp | guess | inverted in guess | converged | Newton | s | inverted | min J |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in args.models:
        model = load_model(path)
        for clamp in clamps:
            for guess in guesses:
                r = solve(model, clamp, args.opening, guess)
                print(f"| {path} | {model.n_tets:,} | {clamp:g} | {guess} | {r['start_inverted']} | {r['converged']} | "
                      f"{r['iterations']} | {r['seconds']:.1f} | {r['inverted']} | {r['min_J']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
