"""PARDISO's Cholesky (``mtype`` 2) against its symmetric indefinite LDL^T (``mtype`` -2) on a
face's tangent, in one run: what ``PardisoFactor`` gains by trying Cholesky first.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_pardiso_kinds.py [model.npz] [repeats] [activation]

The tangent is the true one at the equilibrium of the model's muscles all at ``activation``
(default 0: the rest shape, no solve needed; above 0 an equilibrium is solved first). Prints a
table: seconds per factorisation (ordering, symbolic and numerical phases; median of
``repeats``), per single-right-hand-side solve and per 35-column solve (a Jacobian's), the
factor's nonzeros, and the solution's relative residual after ``solve``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.fem.linear import PardisoFactor
from facesim.fem.newton import Problem
from facesim.model import load_model


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    path = argv[0] if argv else "meshes/face_coarse.npz"
    repeats = int(argv[1]) if len(argv) > 1 else 3
    level = float(argv[2]) if len(argv) > 2 else 0.0
    model = load_model(path)
    sim = FaceSimulator(model)
    c = Controls(np.full(model.n_muscles, level))
    x = sim.attached_positions(c) if level == 0 else sim.equilibrium(c).x
    K = Problem(sim.terms, sim.system, x, c.a).hessian(x, project=False).tocsr()
    n = K.shape[0]
    rng = np.random.default_rng(0)
    b = rng.normal(size=n)
    B = rng.normal(size=(n, 35))
    PardisoFactor(K)   # warm up: MKL loaded
    rows = []
    for label, spd in (("Cholesky (mtype 2, facesim)", True), ("LDL^T (mtype -2)", False)):
        factor_t, solve_t, many_t = [], [], []
        for _ in range(repeats):
            t = time.perf_counter()
            f = PardisoFactor(K, spd=spd)
            factor_t.append(time.perf_counter() - t)
            t = time.perf_counter()
            f.precondition(b)
            solve_t.append(time.perf_counter() - t)
            t = time.perf_counter()
            f.precondition(B)
            many_t.append(time.perf_counter() - t)
        x = f.solve(b)
        res = float(np.linalg.norm(K @ x - b) / np.linalg.norm(b))
        rows.append((label, np.median(factor_t), np.median(solve_t), np.median(many_t), f.factor_nonzeros, res))
        del f
    print(f"model {path}: {n:,} unknowns, {K.nnz:,} stored entries, activation {level}; median of {repeats}")
    print(f"{'factorisation':<30}{'factor s':>10}{'solve s':>10}{'35 RHS s':>10}{'nnz(L)':>14}{'residual':>10}")
    for label, tf, ts, tm, nz, res in rows:
        print(f"{label:<30}{tf:>10.3f}{ts:>10.4f}{tm:>10.3f}{nz:>14,}{res:>10.1e}")
    print(f"LDL^T / Cholesky: factor {rows[1][1] / rows[0][1]:.2f}x, solve {rows[1][2] / rows[0][2]:.2f}x, "
          f"35 RHS {rows[1][3] / rows[0][3]:.2f}x")


if __name__ == "__main__":
    main()
