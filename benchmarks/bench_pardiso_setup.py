"""What a PARDISO factorisation of the coarse face's tangent costs, with and without the MKL
library path kept between solvers (``PYPARDISO_MKL_RT``, set by facesim.fem.linear after the
first one): pypardiso otherwise searches the whole ``sys.prefix`` tree for ``libmkl_rt`` in every
solver it makes, and every Jacobian makes one.

    NUMBA_NUM_THREADS=2 python benchmarks/bench_pardiso_setup.py [meshes/face_coarse.npz] [repeats]

Prints a table: seconds per factorisation (median of ``repeats``), both ways, in one run.
"""

from __future__ import annotations

import os
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
    repeats = int(argv[1]) if len(argv) > 1 else 5
    model = load_model(path)
    sim = FaceSimulator(model)
    c = Controls(np.zeros(model.n_muscles))
    x = sim.attached_positions(c)
    K = Problem(sim.terms, sim.system, x, c.a).hessian(x, project=False)
    PardisoFactor(K)   # warm up: MKL loaded, the path kept
    kept = os.environ["PYPARDISO_MKL_RT"]
    rows = []
    for label, keep in (("path kept (facesim)", True), ("searched every time (pypardiso default)", False)):
        times = []
        for _ in range(repeats):
            if keep:
                os.environ["PYPARDISO_MKL_RT"] = kept
            else:
                os.environ.pop("PYPARDISO_MKL_RT", None)
            t = time.perf_counter()
            f = PardisoFactor(K)
            times.append(time.perf_counter() - t)
            del f
        rows.append((label, float(np.median(times))))
    os.environ["PYPARDISO_MKL_RT"] = kept
    print(f"model {path}: {sim.system.n_dofs:,} unknowns, {K.nnz:,} stored entries; median of {repeats}")
    print(f"{'MKL library':<42}{'s per factorisation':>22}")
    for label, t in rows:
        print(f"{label:<42}{t:>22.3f}")
    print(f"ratio {rows[1][1] / rows[0][1]:.2f}x")


if __name__ == "__main__":
    main()
