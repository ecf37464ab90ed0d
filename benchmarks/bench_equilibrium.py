"""Equilibrium solver figures on face models; prints a table (never asserted in tests).

    python benchmarks/bench_equilibrium.py meshes/face_coarse.npz [more models ...] [--solver amg|direct]

Per model: tets (simulated), unknowns, assembly time (Hessian of flesh + muscles), AMG setup,
PCG iterations and time per Newton iteration, Newton iterations and total time from rest to a
smile (zygomaticus major L/R = 1) and to all muscles at 0.5, peak memory (ru_maxrss).
"""

from __future__ import annotations

import argparse
import platform
import resource
import time

import numpy as np

from facesim.controls import Controls
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.model import load_model


def bench(path: str, solver: str) -> dict:
    model = load_model(path)
    t = time.perf_counter()
    sim = FaceSimulator(model, EquilibriumOptions(NewtonOptions(linear_solver=solver)))
    setup = time.perf_counter() - t
    x = model.X.copy()
    a = np.full(model.n_muscles, 0.5)
    sim.elastic.gradient(x)                      # compile outside the timings
    prob = sim.problem(Controls(a))
    prob.hessian(x)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        A = prob.hessian(x)
        times.append(time.perf_counter() - t)
    row = {"model": path, "tets": model.n_tets, "simulated": model.n_simulated, "dofs": sim.system.n_dofs,
           "setup_s": setup, "assembly_s": min(times)}
    if solver == "amg":
        t = time.perf_counter()
        sim.linear.setup(A, sim.system.rigid_modes(x))
        row["amg_setup_s"] = time.perf_counter() - t
        sim.linear.ml = None
    for label, act in (("smile", {"zygomaticus_major_L": 1.0, "zygomaticus_major_R": 1.0}), ("all_0.5", None)):
        a = np.full(model.n_muscles, 0.5) if act is None else np.zeros(model.n_muscles)
        for name, v in (act or {}).items():
            a[model.muscles.index(name)] = v
        sim.linear = type(sim.linear)()          # cold: no hierarchy carried over
        eq = sim.equilibrium(Controls(a))
        r = eq.report
        its = max(r.iterations, 1)
        row[label] = {"converged": r.converged, "newton": r.iterations, "total_s": r.seconds["total"],
                      "per_newton_s": r.seconds["total"] / its, "pcg_its_per_newton": sum(r.linear_iterations) / its,
                      "linear_s": r.seconds["linear"], "assembly_s": r.seconds["assembly"],
                      "rel_residual": r.relative_residual}
        # warm start: the same controls again from the solution, then a 10 % change
        eq2 = sim.equilibrium(Controls(a * 0.9), x0=eq.x)
        row[label]["warm_newton"] = eq2.report.iterations
        row[label]["warm_s"] = eq2.report.seconds["total"]
    row["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+")
    ap.add_argument("--solver", default="amg", choices=("amg", "direct"))
    args = ap.parse_args()
    rows = [bench(p, args.solver) for p in args.models]
    print("\ntime split of the cold solves (s): assembly / linear (AMG setup + PCG) / rest (gradients, line search)")
    for r in rows:
        for case in ("smile", "all_0.5"):
            c = r[case]
            print(f"  {r['model'][-28:]:>28} {case:>8}: {c['assembly_s']:.2f} / {c['linear_s']:.2f} / "
                  f"{c['total_s'] - c['assembly_s'] - c['linear_s']:.2f}")
    print(f"\nmachine: {platform.machine()}, python {platform.python_version()}, solver {args.solver}")
    print(f"{'model':>28} {'tets':>8} {'sim':>8} {'dofs':>8} {'assem s':>8} {'amg s':>6} | {'case':>8} {'conv':>5} "
          f"{'newton':>6} {'pcg/it':>6} {'s/it':>6} {'total s':>8} {'warm it':>7} {'warm s':>7} {'peak GB':>7}")
    for r in rows:
        for case in ("smile", "all_0.5"):
            c = r[case]
            print(f"{r['model'][-28:]:>28} {r['tets']:>8} {r['simulated']:>8} {r['dofs']:>8} {r['assembly_s']:>8.3f} "
                  f"{r.get('amg_setup_s', float('nan')):>6.2f} | {case:>8} {str(c['converged']):>5} {c['newton']:>6} "
                  f"{c['pcg_its_per_newton']:>6.1f} {c['per_newton_s']:>6.2f} {c['total_s']:>8.1f} {c['warm_newton']:>7} "
                  f"{c['warm_s']:>7.2f} {r['peak_gb']:>7.2f}")


if __name__ == "__main__":
    main()
