"""The progressive penalty schedule of a Gauss-Newton step with box bounds on the controls.

:func:`facesim.inverse.gauss_newton.schedule_penalty` in one compiled loop, for the common case
where every bound is a box on a control (activations in [0, 1], a sliding-condyle jaw's or a
Posselt rig's parameter ranges): a hundred or so nested steps, each a small dense solve, cost
~17 ms a step in Python (the coarse face's demo clip: 4.5 s over its 266 steps) and well under
one compiled (benchmarks/RESULTS.md, session 33). The Python function stays the reference and
the path of every other penalty (an NLPCA rig's curved ranges, a solved head frame's rigidity).
"""

import math

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS


@njit(**JIT_FLAGS)
def _box(c, lower, upper, weight, g, hd):
    """``sum_i weight_i e_i^2`` with ``e`` the distance of ``c`` outside ``[lower, upper]``; its
    gradient into ``g`` and its (diagonal) Hessian into ``hd``."""
    v = 0.0
    for i in range(c.shape[0]):
        e = max(c[i] - upper[i], 0.0) + min(c[i] - lower[i], 0.0)
        v += weight[i] * e * e
        g[i] = 2.0 * weight[i] * e
        hd[i] = 2.0 * weight[i] if e != 0.0 else 0.0
    return v


@njit(**JIT_FLAGS)
def _max_abs(v):
    out = 0.0
    for i in range(v.shape[0]):
        out = max(out, abs(v[i]))
    return out


@njit(**JIT_FLAGS)
def box_schedule(A, b, r, J, w, c, lower, upper, weight, mu, growth, final_ratio):
    """Minimise ``1/2 dc^T A dc + b^T dc + mu B(c + dc)`` along the schedule of ``mu`` (see
    ``schedule_penalty``: the same steps, tests and jumps), ``B`` the box penalty of
    ``(lower, upper, weight)``. ``A (n, n)``, ``b (n,)`` the weighted normal equations of the linear
    model ``r (m,) + J (m, n) dc`` with weights ``w (m,)``. Returns ``(dc, mu, nested steps)``."""
    n = c.shape[0]
    dc = np.zeros(n)
    g = np.empty(n)
    hd = np.empty(n)
    piece = np.zeros(n, dtype=np.bool_)
    have_piece = False
    nested = 0
    streak = 0
    v = _box(c, lower, upper, weight, g, hd)
    grad = np.empty(n)
    M = np.empty((n, n))
    at = np.empty(n)
    while True:
        Adc = A @ dc
        for i in range(n):
            grad[i] = Adc[i] + b[i] + mu * g[i]
        inner = 0
        for inner in range(50):   # Newton on the piecewise-quadratic model
            for i in range(n):
                for j in range(n):
                    M[i, j] = A[i, j]
                M[i, i] += mu * hd[i]
            step = np.linalg.solve(M, -grad)
            for i in range(n):
                dc[i] += step[i]
                at[i] = c[i] + dc[i]
            v = _box(at, lower, upper, weight, g, hd)
            Adc = A @ dc
            for i in range(n):
                grad[i] = Adc[i] + b[i] + mu * g[i]
            if _max_abs(grad) <= 1e-12 * max(_max_abs(b), _max_abs(Adc), 1e-300) or \
                    _max_abs(step) <= 1e-12 * (1.0 + _max_abs(dc)):
                break
        model = r + J @ dc
        data = 0.0
        for i in range(model.shape[0]):
            data += model[i] * w[i] * model[i]
        data *= 0.5
        target = final_ratio * max(data, 1e-12)
        free = v == 0.0 and _max_abs(g) == 0.0
        if free:   # no bound active: the rest of the schedule leaves dc unchanged
            nested += 1
            while mu < target:
                mu *= growth
                nested += 1
        if mu >= target:
            return dc, mu, nested + (0 if free else 1)
        same = have_piece
        for i in range(n):
            active = hd[i] != 0.0
            if active != piece[i]:
                same = False
            piece[i] = active
        have_piece = True
        streak = streak + 1 if inner == 0 and same else 0
        k = 2 ** min(streak, 6)
        jump = growth ** k
        if mu * jump >= target and k > 1:   # land on the target, not far beyond it
            k = max(1, math.ceil(math.log(target / mu) / math.log(growth)))
            jump = growth ** k
        nested += k
        mu *= jump
