"""``solve_static``: quasistatic equilibrium of a Mooney-Rivlin body on any tet mesh."""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError
from facesim.fem.material import MooneyRivlin
from facesim.fem.newton import NewtonOptions, Problem, SolveReport, newton
from facesim.fem.system import DofSystem, RestShape
from facesim.fem.terms import ElasticTerm


def fixed_mask(fixed, n: int) -> np.ndarray:
    """``(n, 3) bool`` from an index array (all components) or a boolean mask ``(n, 3)`` / ``(n,)``."""
    f = np.asarray(fixed)
    if f.dtype == bool:
        if f.shape == (n,):
            f = np.repeat(f[:, None], 3, axis=1)
        if f.shape != (n, 3):
            raise FacesimError(f"fixed: expected a boolean mask of shape ({n}, 3) or ({n},), got {f.shape}")
        return f.copy()
    f = f.astype(np.int64).ravel()
    if f.size and (f.min() < 0 or f.max() >= n):
        raise FacesimError(f"fixed: node indices must lie in [0, {n})")
    mask = np.zeros((n, 3), bool)
    mask[f] = True
    return mask


def _prescribed(X, fixed, fixed_positions, mask) -> np.ndarray:
    """Full (n, 3) array of prescribed positions (free components hold the rest positions)."""
    n = len(X)
    xf = X.copy()
    p = np.asarray(fixed_positions, dtype=np.float64)
    f = np.asarray(fixed)
    if f.dtype != bool:
        idx = f.astype(np.int64).ravel()
        if p.shape == (len(idx), 3):
            xf[idx] = p
            return xf
    if p.shape != (n, 3):
        raise FacesimError(f"fixed_positions: expected shape ({len(np.ravel(f)) if f.dtype != bool else n}, 3) "
                           f"or ({n}, 3), got {p.shape}")
    xf[mask] = p[mask]
    return xf


def solve_static(X, tets, material: MooneyRivlin, fixed, fixed_positions, x0=None,
                 options: NewtonOptions | None = None) -> tuple[np.ndarray, SolveReport]:
    """Equilibrium positions of a hyperelastic body with prescribed displacements.

    Parameters
    ----------
    X : (n, 3) float, rest positions (mm).
    tets : (m, 4) int, positively oriented linear tets.
    material : :class:`~facesim.fem.MooneyRivlin` (MPa).
    fixed : node indices (all three components prescribed) or an ``(n, 3)`` boolean mask
        (per component: rollers, symmetry planes).
    fixed_positions : prescribed positions, ``(len(fixed), 3)`` for an index array or ``(n, 3)``
        (only the masked components are read).
    x0 : optional (n, 3) starting guess for the free components (warm start).
    options : :class:`~facesim.fem.NewtonOptions`.

    Returns ``(x (n, 3), report)``; ``report.converged`` says whether the force residual reached
    ``options.rtol`` relative to the residual of the undeformed body under the prescribed
    positions.
    """
    options = options or NewtonOptions()
    rest = RestShape(X, tets)
    n = len(rest.X)
    mask = fixed_mask(fixed, n)
    x_fixed = _prescribed(rest.X, fixed, fixed_positions, mask)
    term = ElasticTerm(rest, material.c10, material.c01, material.kappa, volumetric=material.volumetric,
                       clamp=material.clamp)
    system = DofSystem(rest.tets, n, mask, np.arange(len(rest.tets)))
    cold = Problem([term], system, x_fixed)
    force_scale = float(np.linalg.norm(cold.energy_and_gradient(x_fixed)[1]))
    start = x_fixed
    if x0 is not None:
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (n, 3):
            raise FacesimError(f"x0: expected shape ({n}, 3), got {x0.shape}")
        start = np.where(mask, x_fixed, x0)
    return newton(Problem([term], system, start), options, force_scale)
