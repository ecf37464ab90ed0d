"""One frame of the inverse problem on the shipped coarse face: markers of a known expression
(smile, eye squint, lower-lip depressor, jaw 0.1 rad on the natural sliding-condyle path) with
0.5 mm Gaussian noise per coordinate, fitted from the neutral face.

    python benchmarks/bench_fit_frame.py [--model meshes/face_coarse.npz] [--threads N] [--paper]

Prints GN steps, equilibria, Newton (and chord) iterations, Jacobian evaluations, marker RMS,
worst bound violation, seconds split into equilibria / Jacobian / algebra / line search, the
objective and step length per step, and the activation / jaw errors. ``--paper`` fits with the
paper's scheme instead (a new Jacobian and a golden-section search at every step, Newton
equilibria). (Markers from the same mesh: the finer-mesh recovery of issue 5 is tested elsewhere.)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.inverse import FitOptions, fit_frame
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import load_model
from facesim.session import activation_vector

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(ROOT / "meshes" / "face_coarse.npz"))
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: numba's)")
    ap.add_argument("--paper", action="store_true", help="golden section and a new Jacobian at every step")
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    m = load_model(args.model)
    jaw = SlidingCondyleJaw(m.jaw)
    sim = FaceSimulator(m, jaw_model=jaw)
    a = activation_vector(m, {"zygomaticus_major": 0.6, "orbicularis_oculi": 0.3, "depressor_labii_inferioris": 0.3})
    truth = Controls(a, jaw=jaw.natural_parameters(0.1))
    t = time.perf_counter()
    eq = sim.equilibrium(truth)
    print(f"truth equilibrium: {eq.iterations} Newton iterations, {time.perf_counter() - t:.1f} s", flush=True)
    rng = np.random.default_rng(0)
    T = m.marker_positions(eq.x) + 0.5 * rng.normal(size=(m.n_markers, 3))
    options = FitOptions(noise=0.5, line_search="golden", jacobian_max_age=0, chord=False) if args.paper else \
        FitOptions(noise=0.5)
    t = time.perf_counter()
    fit = fit_frame(sim, T, Controls(np.zeros(m.n_muscles), jaw=np.zeros(3)), options=options)
    r = fit.report
    print(f"fit: {r.gn_steps} GN steps, {r.equilibria} equilibria, {r.newton_iterations} Newton iterations "
          f"({r.chord_iterations} on the Jacobian's tangent), {r.jacobians} Jacobians, RMS {r.marker_rms:.3f} mm, "
          f"worst violation {r.worst_violation:.1e}, {time.perf_counter() - t:.1f} s")
    print("seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in r.timing.items()))
    print("objective", [round(o, 2) for o in r.objective], "alpha", [round(s, 2) for s in r.step_lengths])
    err = np.abs(fit.controls.a - a)
    print(f"activation error max {err.max():.3f} mean {err.mean():.3f}; jaw {np.round(fit.controls.jaw, 3)} "
          f"truth {np.round(truth.jaw, 3)}")


if __name__ == "__main__":
    main()
