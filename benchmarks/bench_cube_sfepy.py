"""A plain Mooney-Rivlin cube stretched 1.2: facesim's ``solve_static`` against SfePy on the same
meshes in one run, printed as a table with the ratio of their times and the displacements' agreement.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_cube_sfepy.py [--cells 20,29] [--venv DIR]
        [--facesim amg,pardiso] [--sfepy amg-rbm,amg]

The cube (10 mm, ``cells`` Kuhn-split cubes per side: 20 -> 48,000 tets, 29 -> 146,334 tets) has
its bottom face clamped and its top face moved up 2 mm with its x and y held (both faces fully
prescribed). Material: ``psi = c10 (I1_bar - 3) + c01 (I2_bar - 3) + K/2 (J - 1)^2`` with
c10 0.5, c01 0.1, K 10 MPa -- facesim's ``MooneyRivlin(volumetric="quadratic")``, SfePy's
total-Lagrangian ``dw_tl_he_neohook`` (mu = 2 c10) + ``dw_tl_he_mooney_rivlin`` (kappa = 2 c01) +
``dw_tl_bulk_penalty`` (K), one-point quadrature (linear tets).

SfePy is installed into its own virtualenv (``--venv``, made on first use with
``pip install sfepy pyamg``); it is never a dependency of facesim. It runs Newton in 8 load steps
(with 4, its Newton steps invert tets and its line search crawls at 1e-3 of a step: 2.7x the
time on a 10K-tet cube), with one of these linear solvers: ``amg-rbm`` (pyamg smoothed
aggregation with CG as accelerator and the six rigid-body modes as near-null space, as
facesim's AMG has; rebuilt every Newton step, as SfePy does for a changed matrix), ``amg`` (the
same with pyamg's default near-null space) or ``direct`` (SfePy's default direct solver, SuperLU
here: 263 s on the 48K cube). facesim runs ``solve_static`` in one load step with its
inversion-safe line search and the linear solver named (``amg``, ``pardiso``, ``direct``).

Each run is its own process. Times are the solve alone (mesh and problem set-up excluded, numba
compiled by a warm-up solve); memory is the process's peak RSS. Both solve to a force residual
of 1e-8 of the first one (SfePy: of each load step's first one), so the displacements agree to
round-off (column "max abs du / max abs u", against the first SfePy run). Never asserted; record the table in benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SIZE = 10.0           # mm
STRETCH = 1.2
C10, C01, K = 0.5, 0.1, 10.0   # MPa
LOAD_STEPS = 8       # SfePy's: with 4 its Newton steps invert tets ("warp violation") and crawl at
                     # 1e-3 of a step (83 iterations on the 10K-tet cube, 32 with 8 steps, 2.7x the time)
TOLERANCE = 1e-8      # force residual relative to the first one
SFEPY_NEWTON_LIMIT = 50   # Newton iterations per SfePy load step


def cube(cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``X (n, 3)``, ``tets (m, 4)`` (from facesim's ``box_mesh``, computed in the parent only) and
    the bottom and top node ids."""
    from facesim.fem.meshes import box_mesh

    X, tets = box_mesh((SIZE, SIZE, SIZE), (cells, cells, cells))
    return X, tets, np.flatnonzero(X[:, 2] < 1e-9), np.flatnonzero(X[:, 2] > SIZE - 1e-9)


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_facesim(mesh: Path, out: Path, solver: str) -> dict:
    from facesim.fem.material import MooneyRivlin
    from facesim.fem.newton import NewtonOptions
    from facesim.fem.static import solve_static

    d = np.load(mesh)
    X, tets, bottom, top = d["X"], d["tets"], d["bottom"], d["top"]
    material = MooneyRivlin(C10, C01, K, volumetric="quadratic")
    fixed = np.concatenate([bottom, top])
    target = X[fixed].copy()
    target[len(bottom):, 2] *= STRETCH
    warm = MooneyRivlin(C10, C01, K, volumetric="quadratic")
    solve_static(X, tets, warm, fixed, X[fixed] * 1.01, options=NewtonOptions(max_iterations=1, linear_solver=solver))
    t0 = time.perf_counter()
    x, rep = solve_static(X, tets, material, fixed, target,
                          options=NewtonOptions(rtol=TOLERANCE, linear_solver=solver, max_iterations=100))
    seconds = time.perf_counter() - t0
    np.save(out, x - X)
    return {"seconds": seconds, "newton": rep.iterations, "converged": rep.converged,
            "linear": int(sum(rep.linear_iterations)), "peak_mb": peak_rss_mb(),
            "parts": {k: round(v, 2) for k, v in rep.seconds.items()}}


def rigid_modes(X: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``(3 n_free, 6)`` rigid-body modes of the free nodes, in SfePy's dof order (EBC dofs removed,
    node-major): SfePy's system holds only the nodes with no prescribed component here."""
    free = np.setdiff1d(np.arange(len(X)), fixed)
    p = X[free] - X[free].mean(axis=0)
    B = np.zeros((len(free), 3, 6))
    for k in range(3):
        B[:, k, k] = 1.0
    B[:, 1, 3], B[:, 2, 3] = -p[:, 2], p[:, 1]
    B[:, 0, 4], B[:, 2, 4] = p[:, 2], -p[:, 0]
    B[:, 0, 5], B[:, 1, 5] = -p[:, 1], p[:, 0]
    return B.reshape(-1, 6)


def run_sfepy(mesh: Path, out: Path, solver: str) -> dict:
    from sfepy.base.base import IndexedStruct, output
    from sfepy.discrete import Equation, Equations, FieldVariable, Function, Integral, Material, Problem
    from sfepy.discrete.conditions import Conditions, EssentialBC
    from sfepy.discrete.fem import FEDomain, Field, Mesh
    from sfepy.solvers.ls import PyAMGSolver, ScipyDirect
    from sfepy.solvers.nls import Newton
    from sfepy.solvers.ts_solvers import SimpleTimeSteppingSolver
    from sfepy.terms import Term

    output.set_output(quiet=True)
    d = np.load(mesh)
    X, tets = d["X"], d["tets"].astype(np.int32)
    m = Mesh.from_data("cube", X, None, [tets], [np.zeros(len(tets), np.int32)], ["3_4"])
    domain = FEDomain("domain", m)
    omega = domain.create_region("Omega", "all")
    bottom = domain.create_region("Bottom", f"vertices in (z < {1e-6})", "facet")
    top = domain.create_region("Top", f"vertices in (z > {SIZE - 1e-6})", "facet")
    field = Field.from_args("displacement", np.float64, "vector", omega, approx_order=1)
    u = FieldVariable("u", "unknown", field)
    v = FieldVariable("v", "test", field, primary_var_name="u")
    mat = Material("m", mu=2 * C10, kappa=2 * C01, K=K)
    integral = Integral("i", order=1)
    terms = [Term.new(f"{name}(m.{p}, v, u)", integral, omega, m=mat, v=v, u=u)
             for name, p in (("dw_tl_he_neohook", "mu"), ("dw_tl_he_mooney_rivlin", "kappa"),
                             ("dw_tl_bulk_penalty", "K"))]
    equations = Equations([Equation("balance", terms[0] + terms[1] + terms[2])])

    def lift(ts, coors, **kwargs):
        return np.full(len(coors), ts.time * (STRETCH - 1.0) * SIZE)

    ebcs = Conditions([EssentialBC("bottom", bottom, {"u.all": 0.0}),
                       EssentialBC("top_xy", top, {"u.[0,1]": 0.0}),
                       EssentialBC("top_z", top, {"u.2": Function("lift", lift)})])
    if solver == "direct":
        ls = ScipyDirect({})
    else:
        conf = {"accel": "cg", "eps_r": 1e-8, "i_max": 1000}
        if solver == "amg-rbm":   # the six rigid-body modes as near-null space, as facesim's AMG has
            conf["method:B"] = rigid_modes(X, np.unique(np.concatenate([d["bottom"], d["top"]])))
        ls = PyAMGSolver(conf)
    status = IndexedStruct()
    nls = Newton({"i_max": SFEPY_NEWTON_LIMIT, "eps_a": 1e-30, "eps_r": TOLERANCE, "eps_mode": "or", "lin_red": None}, lin_solver=ls, status=status)
    pb = Problem("cube", equations=equations)
    pb.set_bcs(ebcs=ebcs)
    pb.set_ics(ics=Conditions([]))
    tss = SimpleTimeSteppingSolver({"t0": 0.0, "t1": 1.0, "n_step": LOAD_STEPS + 1}, nls=nls, context=pb)
    pb.set_solver(tss)
    iterations = []

    failed = []

    def count(problem, ts, variables):   # after each load step
        iterations.append(int(status.get("n_iter", 0)))
        failed.append(int(status.get("condition", 0)) != 0 or iterations[-1] >= SFEPY_NEWTON_LIMIT)

    t0 = time.perf_counter()
    variables = pb.solve(save_results=False, step_hook=count)
    seconds = time.perf_counter() - t0
    disp = variables["u"].get_state_in_region(omega)
    np.save(out, disp)
    # a load step that ran into Newton's limit did not converge (before session 24 this was
    # reported converged regardless: the 146K-tet run of session 23 was not)
    return {"seconds": seconds, "newton": int(sum(iterations)), "converged": not any(failed), "linear": None,
            "peak_mb": peak_rss_mb(), "parts": {"per_step": iterations}}


def ensure_venv(venv: Path) -> Path:
    python = venv / "bin" / "python"
    if not python.exists():
        print(f"making SfePy's virtualenv in {venv} (pip install sfepy pyamg; a few minutes, once)", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", "sfepy", "pyamg"], check=True)
    return python


def child(python: str, tool: str, solver: str, mesh: Path, out: Path, load_steps: int) -> dict:
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", "2")
    proc = subprocess.run([python, __file__, "--child", tool, solver, str(mesh), str(out), str(load_steps)],
                          capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
        return {"error": " | ".join(tail)}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", default="20,29", help="cubes per side, comma-separated (20: 48K tets, 29: 146K)")
    ap.add_argument("--venv", default=str(Path.home() / ".cache" / "facesim-bench" / "sfepy-venv"))
    ap.add_argument("--facesim", default="amg,pardiso", help="facesim linear solvers to run")
    ap.add_argument("--sfepy", default="amg-rbm,amg", help="SfePy linear solvers to run ('' for none)")
    ap.add_argument("--load-steps", type=int, default=LOAD_STEPS, help="SfePy's load steps")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        tool, solver, mesh, out, steps = args.child
        globals()["LOAD_STEPS"] = int(steps)
        result = (run_facesim if tool == "facesim" else run_sfepy)(Path(mesh), Path(out), solver)
        print(json.dumps(result))
        return
    sfepy_solvers = [s for s in args.sfepy.split(",") if s]
    python = str(ensure_venv(Path(args.venv))) if sfepy_solvers else None
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, NUMBA_NUM_THREADS="
          f"{os.environ.get('NUMBA_NUM_THREADS', 'default')}; cube {SIZE:g} mm, stretch {STRETCH}, "
          f"c10 {C10} c01 {C01} K {K} MPa; SfePy in {args.load_steps} load steps, facesim in one")
    print("| tets | dofs | tool | linear solver | Newton | s | peak MB | first SfePy s / this s | max abs du / max abs u |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for cells in (int(c) for c in args.cells.split(",")):
            X, tets, bottom, top = cube(cells)
            mesh = Path(tmp) / f"cube{cells}.npz"
            np.savez(mesh, X=X, tets=tets, bottom=bottom, top=top)
            dofs = 3 * (len(X) - len(bottom) - len(top))
            runs = [("sfepy", s, python) for s in sfepy_solvers] + \
                   [("facesim", s, sys.executable) for s in args.facesim.split(",") if s]
            reference, reference_s = None, None
            for tool, solver, exe in runs:
                out = Path(tmp) / f"{tool}_{solver}_{cells}.npy"
                r = child(exe, tool, solver, mesh, out, args.load_steps)
                if "error" in r:
                    print(f"| {len(tets)} | {dofs} | {tool} | {solver} | failed: {r['error']} |||||")
                    continue
                u = np.load(out)
                if reference is None:
                    reference = u
                if tool == "sfepy" and reference_s is None:
                    reference_s = r["seconds"]
                agree = np.abs(u - reference).max() / np.abs(reference).max()
                ratio = f"{reference_s / r['seconds']:.1f}" if reference_s else "-"
                print(f"| {len(tets)} | {dofs} | {tool} | {solver} | {r['newton']}{'' if r['converged'] else ' (not converged)'}"
                      f" | {r['seconds']:.2f} | {r['peak_mb']:.0f} | {ratio} | {agree:.1e} |", flush=True)
                print(f"    {tool} {solver}: {r['parts']}", file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
