"""A Mooney-Rivlin block in uniaxial tension: facesim's FE solution against the closed form.

A 10 mm cube on symmetry rollers (x=0, y=0, z=0 faces) is pulled along x; the lateral faces are
free. For each stretch and both volumetric terms, prints the nominal stress from the reaction
force (N / mm^2 = MPa) next to the closed form, and the lateral stretch.

    python examples/00_uniaxial_block.py [--cells 4]
"""

from __future__ import annotations

import argparse

import numpy as np

from facesim.fem import ElasticTerm, MooneyRivlin, NewtonOptions, RestShape, box_mesh, solve_static

L = 10.0


def uniaxial(mat: MooneyRivlin, stretch: float, cells: int = 4):
    """Returns (FE nominal stress MPa, closed-form stress MPa, FE lateral stretch, Newton iterations)."""
    X, T = box_mesh((L, L, L), (cells, cells, cells))
    fixed = np.zeros((len(X), 3), bool)
    for k in range(3):
        fixed[X[:, k] < 1e-9, k] = True
    right = X[:, 0] > L - 1e-9
    fixed[right, 0] = True
    target = X.copy()
    target[right, 0] = stretch * L
    x, report = solve_static(X, T, mat, fixed, target, options=NewtonOptions(rtol=1e-12))
    reaction = ElasticTerm(RestShape(X, T), mat.c10, mat.c01, mat.kappa, volumetric=mat.volumetric).gradient(x)
    P_fe = reaction[right, 0].sum() / L ** 2
    P_exact, _ = mat.uniaxial_nominal_stress(stretch)
    return P_fe, P_exact, x[:, 1].max() / L, report.iterations


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", type=int, default=4, help="cells per edge")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'volumetric':>10} {'stretch':>7} {'P FE (kPa)':>11} {'P exact (kPa)':>13} {'rel err':>8} "
          f"{'lateral':>8} {'Newton':>6}")
    for vol in ("log", "quadratic"):
        mat = MooneyRivlin(c10=6e-3, c01=2e-3, kappa=0.4, volumetric=vol)
        for stretch in (0.7, 0.9, 1.1, 1.5, 2.0):
            P_fe, P_exact, lateral, its = uniaxial(mat, stretch, args.cells)
            rows.append((vol, stretch, P_fe, P_exact))
            print(f"{vol:>10} {stretch:>7.2f} {1e3 * P_fe:>11.4f} {1e3 * P_exact:>13.4f} "
                  f"{abs(P_fe - P_exact) / abs(P_exact):>8.1e} {lateral:>8.4f} {its:>6}")
    return rows


if __name__ == "__main__":
    main()
