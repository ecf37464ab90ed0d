"""Constitutive models of the flesh, evaluated in batches (docs/physics.md section 1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim._kernels.mooney import mr_density_batch, mr_tangent_batch
from facesim.errors import FacesimError

VOLUMETRIC = {"log": 0, "quadratic": 1}

#: Singular values are clamped here before stress and stiffness are evaluated (Teran et al. 2005
#: used 0.1 for their face); below it the energy is continued to first order.
DEFAULT_CLAMP = 0.01


@dataclass(frozen=True)
class MooneyRivlin:
    """Compressible, invertible Mooney-Rivlin solid.

    ``psi = c10 (I1_bar - 3) + c01 (I2_bar - 3) + U(J)`` with ``U = (kappa/2)(ln J)^2``
    (``volumetric="log"``, default) or ``(kappa/2)(J - 1)^2`` (``"quadratic"``, as many FE codes
    use). Parameters in MPa; initial shear modulus ``mu = 2 (c10 + c01)``, bulk modulus ``kappa``.
    Singular values of F below ``clamp`` are clamped (energy continued linearly), so inverted
    elements have finite energy and push back.
    """

    c10: float
    c01: float
    kappa: float
    volumetric: str = "log"
    clamp: float = DEFAULT_CLAMP

    def __post_init__(self):
        for name in ("c10", "c01", "kappa"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise FacesimError(f"MooneyRivlin.{name}: expected a finite value >= 0 (MPa), got {v}")
        if self.c10 + self.c01 <= 0:
            raise FacesimError("MooneyRivlin: c10 + c01 must be > 0 (the shear modulus is 2 (c10 + c01))")
        if self.volumetric not in VOLUMETRIC:
            raise FacesimError(f"MooneyRivlin.volumetric: expected one of {tuple(VOLUMETRIC)}, got {self.volumetric!r}")
        if not 0 < self.clamp < 1:
            raise FacesimError(f"MooneyRivlin.clamp: expected a value in (0, 1), got {self.clamp}")

    @property
    def shear_modulus(self) -> float:
        return 2.0 * (self.c10 + self.c01)

    def _batch(self, F):
        F = np.asarray(F, dtype=np.float64)
        single = F.shape == (3, 3)
        if single:
            F = F[None]
        if F.ndim != 3 or F.shape[1:] != (3, 3):
            raise FacesimError(f"F: expected shape (k, 3, 3) or (3, 3), got {F.shape}")
        F = np.ascontiguousarray(F)
        k = len(F)
        par = (np.full(k, self.c10), np.full(k, self.c01), np.full(k, self.kappa))
        return F, par, single

    def energy_density(self, F) -> np.ndarray:
        """psi (k,) in MPa = mJ/mm^3 for ``F (k, 3, 3)`` (or a scalar for one ``(3, 3)``)."""
        F, par, single = self._batch(F)
        psi, P = np.empty(len(F)), np.empty_like(F)
        mr_density_batch(F, *par, VOLUMETRIC[self.volumetric], self.clamp, psi, P)
        return psi[0] if single else psi

    def first_piola(self, F) -> np.ndarray:
        """First Piola-Kirchhoff stress ``P = dpsi/dF`` (k, 3, 3), MPa."""
        F, par, single = self._batch(F)
        psi, P = np.empty(len(F)), np.empty_like(F)
        mr_density_batch(F, *par, VOLUMETRIC[self.volumetric], self.clamp, psi, P)
        return P[0] if single else P

    def tangent(self, F, project: bool = False) -> np.ndarray:
        """``dP/dF`` as (k, 9, 9) on row-major ``vec(F)``; ``project`` clamps its eigenvalues at 0."""
        F, par, single = self._batch(F)
        D = np.empty((len(F), 9, 9))
        mr_tangent_batch(F, *par, VOLUMETRIC[self.volumetric], self.clamp, bool(project), D)
        return D[0] if single else D

    def uniaxial_nominal_stress(self, stretch: float) -> tuple[float, float]:
        """Closed form for uniaxial tension along x with free lateral faces.

        Returns ``(P11, lateral_stretch)``: the lateral stretch solves ``P22 = 0`` (scalar
        Newton on the closed-form principal stresses), then P11 follows. For verification.
        """
        from facesim._kernels.mooney import PSI_ROWS, psi_derivatives

        vol = VOLUMETRIC[self.volumetric]
        g, H, T, work = np.empty(3), np.empty((3, 3)), np.empty((3, 3, 3)), np.empty((PSI_ROWS, 3))
        lat = 1.0
        for _ in range(100):
            psi_derivatives(np.array([stretch, lat, lat]), self.c10, self.c01, self.kappa, vol, False, g, H, T, work)
            step = g[1] / (H[1, 1] + H[1, 2])
            lat -= step
            if abs(step) < 1e-15:
                break
        psi_derivatives(np.array([stretch, lat, lat]), self.c10, self.c01, self.kappa, vol, False, g, H, T, work)
        return float(g[0]), float(lat)
