"""Transversely isotropic muscle fibres, force affine in activation (docs/physics.md section 2).

Along-fibre stretch lam = |F d|, s = lam - 1. Nominal fibre stress (MPa)

    T(lam, a) = sigma_max rho [ f_P(lam) + a g f_L(lam) ]

with the C1 piecewise-quadratic active force-length curve f_L, Blemker's exponential passive
curve f_P (linear beyond lam* = 1.4), the muscle's volume fraction rho in the tet and a
per-muscle gain g (exaggeration scales the curve, Sifakis 2005 Fig. 8). Energy density
psi = integral_1^lam T, first Piola P = (T / lam) (F d) (x) d.
"""

import math

from numba import njit

from facesim._kernels import JIT_FLAGS

P1 = 0.05
P2 = 6.6
LAM_STAR = 1.4


@njit(**JIT_FLAGS)
def active_curve(s):
    """f_L, f_L' and F_L = integral_0^s f_L at fibre strain ``s = lam - 1``."""
    a = abs(s)
    sign = 1.0 if s >= 0.0 else -1.0
    if a < 0.4:
        return 1.0 - 25.0 / 6.0 * s * s, -25.0 / 3.0 * s, s - 25.0 / 18.0 * s * s * s
    F04 = 0.4 - 25.0 / 18.0 * 0.064
    if a < 0.6:
        return (25.0 / 3.0 * (a - 0.6) ** 2, sign * 50.0 / 3.0 * (a - 0.6),
                sign * (F04 + 25.0 / 9.0 * ((a - 0.6) ** 3 + 0.008)))
    return 0.0, 0.0, sign * (F04 + 25.0 / 9.0 * 0.008)


@njit(**JIT_FLAGS)
def passive_curve(s):
    """f_P, f_P' and F_P = integral_0^s f_P at fibre strain ``s = lam - 1``."""
    if s <= 0.0:
        return 0.0, 0.0, 0.0
    ss = LAM_STAR - 1.0
    if s <= ss:
        e = math.exp(P2 * s)
        return P1 * (e - P2 * s - 1.0), P1 * P2 * (e - 1.0), P1 * ((e - 1.0) / P2 - 0.5 * P2 * s * s - s)
    e = math.exp(P2 * ss)
    f0 = P1 * (e - P2 * ss - 1.0)
    k = P1 * P2 * (e - 1.0)
    F0 = P1 * ((e - 1.0) / P2 - 0.5 * P2 * ss * ss - ss)
    t = s - ss
    return f0 + k * t, k, F0 + f0 * t + 0.5 * k * t * t


@njit(**JIT_FLAGS)
def fibre_stress(lam, scale_passive, scale_active):
    """Fibre energy density, stress T and dT/dlam for ``T = scale_passive f_P + scale_active f_L``."""
    fl, dfl, Fl = active_curve(lam - 1.0)
    fp, dfp, Fp = passive_curve(lam - 1.0)
    return (scale_passive * Fp + scale_active * Fl, scale_passive * fp + scale_active * fl,
            scale_passive * dfp + scale_active * dfl)
