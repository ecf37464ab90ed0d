"""Time the implicit Jacobian (all activations + the 3 sliding-condyle parameters) at an equilibrium.

    python benchmarks/bench_jacobian.py [--model meshes/face_coarse.npz] [--solvers direct amg] [--threads N]

Prints, per linear solver: simulated tets, unknowns, columns, seconds for assembly of the true
tangent, the bone right-hand sides, the solve of all columns, total, CG iterations per column,
and the peak memory of the process. The direct solver is SuperLU in symmetric mode (minimum
degree on A^T + A); the bone columns differentiate the forces of the tets next to the jaw only.
"""

from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from facesim.controls import Controls
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.inverse import ControlSpace, equilibrium_jacobian
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import load_model

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(ROOT / "meshes" / "face_coarse.npz"))
    ap.add_argument("--solvers", nargs="+", default=["direct", "amg"], choices=["direct", "amg"])
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: numba's)")
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    model = load_model(args.model)
    jaw = SlidingCondyleJaw(model.jaw)
    a = np.zeros(model.n_muscles)
    a[[i for i, n in enumerate(model.muscles.names) if n.startswith("zygomaticus_major")]] = 0.5
    controls = Controls(a, jaw=jaw.natural_parameters(0.1))
    sim = FaceSimulator(model, EquilibriumOptions(newton=NewtonOptions(rtol=1e-8)), jaw_model=jaw)
    t = time.perf_counter()
    eq = sim.equilibrium(controls)
    print(f"model {args.model}: {model.n_simulated:,} simulated tets, {sim.system.n_dofs:,} unknowns; "
          f"equilibrium {eq.iterations} Newton iterations, {time.perf_counter() - t:.1f} s")
    space = ControlSpace.of(sim)
    equilibrium_jacobian(sim, controls, eq.x, space, linear_solver="direct")   # JIT warm-up
    print(f"{'solver':>8} {'columns':>8} {'assembly s':>11} {'rhs s':>7} {'solve s':>8} {'total s':>8} "
          f"{'CG it/col':>10} {'peak MB':>8}")
    for solver in args.solvers:
        J = equilibrium_jacobian(sim, controls, eq.x, space, linear_solver=solver, rtol=1e-8)
        s = J.seconds
        it = np.mean(J.linear_iterations) if J.linear_iterations else float("nan")
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"{solver:>8} {space.size:>8} {s['assembly']:>11.2f} {s['rhs']:>7.2f} {s['solve']:>8.2f} "
              f"{s['total']:>8.2f} {it:>10.1f} {peak:>8.0f}")


if __name__ == "__main__":
    main()
