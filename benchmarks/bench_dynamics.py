"""Dynamic vs quasistatic frames on the coarse face; prints a table (never asserted in tests).

    python benchmarks/bench_dynamics.py [--model meshes/face_coarse.npz] [--start 6] [--frames 6]
                                        [--substeps 2,4] [--solver amg|direct] [--shake DEG,HZ]

The controls are the demo clip's truth (``meshes/demo_clip_truth.npz``: activations, sliding-condyle
jaw and head pose per frame at its 24 fps), frames ``start`` .. ``start + frames``. Per case: the
quasistatic sequence (:meth:`FaceSimulator.equilibrium` per frame, warm-started from the previous
frame) and the dynamic ones (:class:`~facesim.fem.dynamics.DynamicSimulator`, BDF2, each of
``substeps`` time steps per frame, default damping), all from the quasistatic equilibrium of the
first frame, at rest.
Columns: seconds and Newton iterations per frame (the first frame, the shared start, left out), time
steps per frame, and the largest marker difference dynamic - quasistatic over the frames (mm): all
markers and the nose markers (``nose_*``). Cases: the face as built, nose cartilage softened to
0.2 x (Sifakis 2005's ballistic example), and with ``--shake`` both again with a head shake (yaw
of DEG degrees times sin^3 of HZ Hz about the condyle midpoint: from rest, no kick) on top of the
clip's head motion. Contact as in a solve of the clip: lips against teeth and against each other.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from facesim.controls import Controls, rotation_about
from facesim.fem.dynamics import DynamicsOptions, DynamicSimulator, DynamicState
from facesim.fem.equilibrium import EquilibriumOptions
from facesim.fem.newton import NewtonOptions
from facesim.model import load_model

ROOT = Path(__file__).resolve().parents[1]


def clip_controls(model, first: int, n: int, shake=None):
    """``(controls per frame, fps)`` of frames ``first .. first + n`` of the demo clip's truth, the
    activations reordered by muscle name; ``shake = (deg, hz)`` adds a yaw about the condyle midpoint."""
    with np.load(ROOT / "meshes" / "demo_clip_truth.npz") as z:
        names = [str(s) for s in z["muscle_names"]]
        A, Q, H, fps = z["activations"], z["jaw"], z["head"], float(z["fps"])
    order = [names.index(m) for m in model.muscles.names]
    out = []
    centre = 0.5 * (model.jaw.condyle_left + model.jaw.condyle_right)
    for k in range(first, first + n + 1):
        head = H[k]
        if shake is not None:
            t = (k - first) / fps
            yaw = np.radians(shake[0]) * np.sin(2 * np.pi * shake[1] * t) ** 3   # starts at rest: no kick
            head = head @ rotation_about([0.0, yaw, 0.0], centre)
        out.append(Controls(A[k][order], jaw=Q[k], head=head))
    return out, fps


def run_case(model, controls, fps, substeps, solver, soften=()):
    """The quasistatic run over ``controls`` and a dynamic one per entry of ``substeps``: rows of
    per-frame figures and marker differences."""
    opts = EquilibriumOptions(newton=NewtonOptions(linear_solver=solver), teeth_contact=True, lip_contact=True)
    dyn = DynamicSimulator(model, opts, jaw_model="sliding-condyle", dynamics=DynamicsOptions(soften=soften))
    sim, m = dyn.sim, dyn.model
    eq0 = sim.equilibrium(controls[0])
    nose = np.array(["nose" in n and not n.startswith("head") for n in m.markers.names])
    qs_t, qs_it, qs_markers, x = [], [], [], eq0.x
    for c in controls[1:]:
        t = time.perf_counter()
        eq = sim.equilibrium(c, x0=x)
        qs_t.append(time.perf_counter() - t)
        qs_it.append(eq.iterations)
        x = eq.x
        qs_markers.append(m.marker_positions(x))
    rows = []
    for k in substeps:
        state = DynamicState.at_rest(eq0.x, eq0.controls)
        dyn_t, dyn_it, ok, ke, dyn_markers = [], [], True, [], []
        for c in controls[1:]:
            t = time.perf_counter()
            state, r = dyn.advance(state, c, 1.0 / fps, substeps=k)
            dyn_t.append(time.perf_counter() - t)
            dyn_it.append(r.iterations)
            ok &= r.converged
            ke.append(r.kinetic_energy)
            dyn_markers.append(m.marker_positions(state.x))
        d = np.linalg.norm(np.array(dyn_markers) - np.array(qs_markers), axis=2)   # (frames, markers) mm
        rows.append({"qs_s": np.mean(qs_t), "qs_newton": np.mean(qs_it), "dyn_s": np.mean(dyn_t),
                     "dyn_newton": np.mean(dyn_it), "substeps": k, "converged": ok, "max_mm": d.max(),
                     "nose_mm": d[:, nose].max(), "worst": m.markers.names[int(np.argmax(d.max(axis=0)))],
                     "max_ke_mJ": max(ke)})
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(ROOT / "meshes" / "face_coarse.npz"))
    ap.add_argument("--start", type=int, default=6)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--substeps", default="2,4", help="time steps per frame, one dynamic run each (default: 2,4)")
    ap.add_argument("--solver", default="amg", choices=("amg", "direct", "pardiso"))
    ap.add_argument("--shake", default=None, metavar="DEG,HZ", help="also with a head shake (e.g. 10,3)")
    args = ap.parse_args()
    model = load_model(args.model)
    shakes = [None] + ([tuple(float(v) for v in args.shake.split(","))] if args.shake else [])
    rows = []
    for shake in shakes:
        controls, fps = clip_controls(model, args.start, args.frames, shake)
        for soften in ((), ("nose:0.2",)):
            t = time.perf_counter()
            case = ("nose 0.2x" if soften else "as built") + (f", shake {shake[0]:g} deg {shake[1]:g} Hz"
                                                              if shake else "")
            for r in run_case(model, controls, fps, [int(k) for k in args.substeps.split(",")], args.solver, soften):
                rows.append({**r, "case": case})
            print(f"  done: {case} ({time.perf_counter() - t:.0f} s)", flush=True)
    print(f"\nmachine: {platform.machine()}, python {platform.python_version()}, solver {args.solver}; "
          f"{Path(args.model).name}, demo clip frames {args.start}..{args.start + args.frames} at {fps:g} fps")
    head = (f"{'case':>32} | {'qs s/frame':>10} {'qs newton':>9} | {'dyn s/frame':>11} {'dyn newton':>10} "
            f"{'steps':>5} {'conv':>4} | {'ratio':>5} | {'max diff mm':>11} {'nose mm':>7} {'worst marker':>20} "
            f"{'max KE mJ':>9}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['case']:>32} | {r['qs_s']:>10.2f} {r['qs_newton']:>9.1f} | {r['dyn_s']:>11.2f} "
              f"{r['dyn_newton']:>10.1f} {r['substeps']:>5d} {str(r['converged']):>4} | "
              f"{r['dyn_s'] / r['qs_s']:>5.2f} | "
              f"{r['max_mm']:>11.4f} {r['nose_mm']:>7.4f} {r['worst']:>20} {r['max_ke_mJ']:>9.3g}")


if __name__ == "__main__":
    main()
