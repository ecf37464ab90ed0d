"""Seconds per inverse frame (issue 5): a cold frame from the neutral face and tracked frames,
each warm-started from the previous fit, its equilibrium and its Jacobian.

    python benchmarks/bench_inverse.py [--model meshes/face_coarse.npz --model meshes/face_medium.npz]
        [--frames 6] [--threads 2] [--compare] [--verbose] [--coarse COARSE.npz]

Synthetic capture: a smile with eye squint and lower-lip depressor whose activations change by
0.06 / 0.03 per frame and a jaw opening by 0.01 rad per frame on the natural sliding-condyle
path, sampled at the model's markers with 0.5 mm Gaussian noise per coordinate. All activations
and the three jaw parameters are solved for. ``--model`` takes any model file, e.g. a paper
model from ``facesim model build --resolution paper``. ``--coarse COARSE.npz`` fits the cold frame
coarse-to-fine (:class:`facesim.inverse.coarse.CoarseStart`: on that coarser model of the same
face first, e.g. the one a paper model was refined from; repeated: a chain, coarsest first fitted);
its row is ``cold c2f`` and its set-up
(loading the coarse model, binding the markers, locating the nodes) is printed apart.

Prints per model and frame kind (cold, tracked): tets (simulated), unknowns, seconds per frame
split into equilibria (start + each step's first trial), Jacobian (evaluations + secant
updates), GN algebra (penalty schedule, objective) and line search (trials beyond the first),
then GN steps, equilibria, Newton/chord iterations and Jacobian evaluations per frame, the marker
RMS, the largest activation error against the truth, and the peak resident memory of that
model's fits (the synthetic capture's own peak is printed with it, and what stays of it counts;
before session 24 the column included the capture). ``--compare`` also fits each tracked frame with the paper's scheme (a new Jacobian and
a golden-section search at every step, Newton equilibria) from the same start. ``--threads``
sets numba's threads; the load average is printed, since on a shared machine it decides the
numbers.
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("equilibria", "jacobian", "algebra", "line_search")


def _reset_peak_memory() -> None:
    try:   # Linux: "5" resets the peak resident set size of this process
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_memory_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _truth(model, jaw, k: int, step: float):
    from facesim.controls import Controls
    from facesim.session import activation_vector

    s = step * k
    a = activation_vector(model, {"zygomaticus_major": 0.4 + 0.06 * s, "orbicularis_oculi": 0.3 - 0.03 * s,
                                  "depressor_labii_inferioris": 0.2 + 0.03 * s})
    return Controls(a, jaw=jaw.natural_parameters(0.05 + 0.01 * s))


def run_model(path: str, frames: int, step: float, compare: bool, verbose: bool, coarse: list[str] | None = None,
              **fit_options) -> list[dict]:
    from facesim.controls import Controls
    from facesim.fem.equilibrium import FaceSimulator
    from facesim.inverse import ControlSpace, FitOptions, fit_frame
    from facesim.inverse.jacobian import default_jacobian_solver
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.model import load_model

    _reset_peak_memory()
    model = load_model(path)
    jaw = SlidingCondyleJaw(model.jaw)
    sim = FaceSimulator(model, jaw_model=jaw)
    space = ControlSpace.of(sim)
    rng = np.random.default_rng(0)
    t = time.perf_counter()
    truths, targets, x = [], [], None
    for k in range(frames + 1):
        truth = _truth(model, jaw, k, step)
        eq = sim.equilibrium(truth, x0=x)
        if not eq.converged:
            raise SystemExit(f"{path}: the synthetic frame {k} has no converged equilibrium")
        x = eq.x
        truths.append(truth)
        targets.append(model.marker_positions(x) + 0.5 * rng.normal(size=(model.n_markers, 3)))
    print(f"{Path(path).name}: {model.n_tets:,} tets ({model.n_simulated:,} simulated), "
          f"{sim.system.n_dofs:,} unknowns, {model.n_muscles} muscles, {model.n_markers} markers; "
          f"synthetic capture {time.perf_counter() - t:.1f} s (peak {_peak_memory_mb():,.0f} MB); Jacobian solver "
          f"{fit_options.get('linear_solver') or default_jacobian_solver(sim.system.n_dofs)}", flush=True)
    _reset_peak_memory()   # the table's peak is the fits' (what stays of the capture, e.g. its AMG hierarchy, counts)
    options = FitOptions(noise=0.5, **fit_options)
    paper = FitOptions(noise=0.5, line_search="golden", jacobian_max_age=0, chord=False)
    neutral = Controls(np.zeros(model.n_muscles), jaw=np.zeros(space.n_jaw))
    rows = []

    def record(kind, k, fit, seconds):
        r = fit.report
        row = {"model": Path(path).name, "kind": kind, "frame": k, "tets": model.n_tets, "simulated": model.n_simulated,
               "unknowns": sim.system.n_dofs, "seconds": seconds, **{key: r.timing[key] for key in KEYS},
               "gn_steps": r.gn_steps, "equilibria_n": r.equilibria, "newton": r.newton_iterations,
               "chord": r.chord_iterations, "jacobians": r.jacobians, "rms": r.marker_rms,
               "act_err": float(np.abs(fit.controls.a - truths[k].a).max()), "peak_mb": _peak_memory_mb()}
        rows.append(row)
        if verbose:
            print(f"  {kind:>8} frame {k}: {seconds:6.2f} s  " + "  ".join(f"{key} {r.timing[key]:.2f}" for key in KEYS)
                  + (f"  coarse {r.timing['coarse']:.2f}" if "coarse" in r.timing else "")
                  + f"  steps {r.gn_steps} eq {r.equilibria} newton {r.newton_iterations} chord {r.chord_iterations}"
                  f" jac {r.jacobians} alpha {np.round(r.step_lengths, 2).tolist()}"
                  f" ratio {np.round(r.ratios, 2).tolist()}"
                  f" objective {np.round(r.objective, 3).tolist()} rms {r.marker_rms:.3f}", flush=True)

    if coarse:   # the cold frame coarse-to-fine (facesim.inverse.coarse); set-up timed on its own
        from facesim.inverse.coarse import CoarseStart

        t = time.perf_counter()
        c2f = CoarseStart.chain(sim, [load_model(p) for p in coarse], coarse)
        levels = ", ".join(f"{Path(c.name).name} ({c.sim.system.n_dofs:,} unknowns)" for c in c2f.levels)
        print(f"  coarse start from {levels}: set-up {time.perf_counter() - t:.1f} s", flush=True)
        t = time.perf_counter()
        fit = c2f.fit_frame(targets[0], neutral, space, options)
        record("cold c2f", 0, fit, time.perf_counter() - t)
        del c2f
    else:
        t = time.perf_counter()
        fit = fit_frame(sim, targets[0], neutral, None, space, options)
        record("cold", 0, fit, time.perf_counter() - t)
    for k in range(1, frames + 1):
        start = fit
        t = time.perf_counter()
        fit = fit_frame(sim, targets[k], start.controls, start.x, space, options, jacobian=start.jacobian)
        record("tracked", k, fit, time.perf_counter() - t)
        if compare:
            t = time.perf_counter()
            ref = fit_frame(sim, targets[k], start.controls, start.x, space, paper)
            record("paper", k, ref, time.perf_counter() - t)
    return rows


def _mean(rows: list[dict], key: str) -> float:
    return float(np.mean([r[key] for r in rows]))


def summarise(rows: list[dict]) -> None:
    head = (f"{'model':<18} {'kind':<9} {'frames':>6} {'tets (sim)':>17} {'unknowns':>9} {'s/frame':>8} "
            f"{'equil s':>8} {'jacob s':>8} {'algebra s':>9} {'search s':>9} {'GN steps':>8} {'1-step':>6} "
            f"{'equil':>6} {'newton':>6} {'chord':>6} {'jacob':>6} {'RMS mm':>7} {'act err':>7} {'peak MB':>8}")
    print(head)
    groups = {}
    for r in rows:
        groups.setdefault((r["model"], r["kind"]), []).append(r)
    for (name, kind), g in groups.items():
        mean = functools.partial(_mean, g)
        print(f"{name:<18} {kind:<9} {len(g):>6} {g[0]['tets']:>8,} ({g[0]['simulated']:>6,}) {g[0]['unknowns']:>9,} "
              f"{mean('seconds'):>8.2f} {mean('equilibria'):>8.2f} {mean('jacobian'):>8.2f} {mean('algebra'):>9.2f} "
              f"{mean('line_search'):>9.2f} {mean('gn_steps'):>8.2f} "
              f"{sum(r['gn_steps'] <= 1 for r in g):>3}/{len(g):<2} "
              f"{mean('equilibria_n'):>6.1f} {mean('newton'):>6.1f} {mean('chord'):>6.1f} {mean('jacobians'):>6.2f} "
              f"{mean('rms'):>7.3f} {max(r['act_err'] for r in g):>7.3f} {max(r['peak_mb'] for r in g):>8.0f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", action="append", help="model file (repeat for several; default the shipped coarse)")
    ap.add_argument("--frames", type=int, default=6, help="tracked frames after the cold one")
    ap.add_argument("--step", type=float, default=1.0, help="scale of the change between frames")
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: numba's)")
    ap.add_argument("--compare", action="store_true", help="also fit tracked frames with the paper's scheme")
    ap.add_argument("--verbose", action="store_true", help="print every frame")
    ap.add_argument("--jacobian-max-age", type=int, default=None, help="FitOptions.jacobian_max_age")
    ap.add_argument("--jacobian-drift", type=float, default=None, help="FitOptions.jacobian_drift")
    ap.add_argument("--resolution", type=float, default=None, help="FitOptions.resolution")
    ap.add_argument("--coarse", action="append", default=None, metavar="MODEL",
                    help="fit the cold frame on this coarser model of the same face first (facesim.inverse.coarse); "
                         "repeat for a chain of them")
    ap.add_argument("--linear-solver", choices=("direct", "pardiso", "amg"), default=None,
                    help="the Jacobian's linear solver (default: PARDISO if installed, else SuperLU / AMG by size)")
    args = ap.parse_args(argv)
    fit_options = {k: v for k, v in (("jacobian_max_age", args.jacobian_max_age),
                                     ("jacobian_drift", args.jacobian_drift),
                                     ("resolution", args.resolution),
                                     ("linear_solver", args.linear_solver)) if v is not None}
    import numba

    if args.threads:
        numba.set_num_threads(args.threads)
    load0 = os.getloadavg()[0]
    print(f"numba threads {numba.get_num_threads()}, cores {os.cpu_count()}, load average {load0:.2f}", flush=True)
    rows = []
    for path in args.model or [str(ROOT / "meshes" / "face_coarse.npz")]:
        rows += run_model(path, args.frames, args.step, args.compare, args.verbose, coarse=args.coarse, **fit_options)
    print(f"load average at the end {os.getloadavg()[0]:.2f} (1 min)")
    summarise(rows)


if __name__ == "__main__":
    main()
