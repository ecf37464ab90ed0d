"""Batched Levenberg-Marquardt: many small, independent least-squares problems (one per frame of
a capture) solved at once, each row with its own damping, rows dropping out as they converge.

Used by the classic rigs' per-frame fits (Zoss et al. 2018 eq. 6, analytic Jacobians) and by the
NLPCA rig's inverse kinematics (central-difference Jacobians).
"""

from __future__ import annotations

import numpy as np


def levenberg_marquardt(evaluate, x0, iterations: int, mu: float = 1e-4, floor: float = 1e-12,
                        accept_ties: bool = False, stall: float = 1e-12):
    """Minimise |r_n(x_n)|² for every row n of ``x0 (N, k)`` at once.

    evaluate : ``evaluate(x (n, k), rows (n,))`` -> ``(r (n, m), J (n, m, k), *extra)``, the
        residuals, their Jacobians and any further per-row arrays ``(n, ...)`` of the rows
        ``rows`` of the batch at ``x``.
    Each step solves (H + mu_n D) step = −g with H = JᵀJ, g = Jᵀr and Marquardt's scaling
    D = diag(H) + ``floor``; mu_n starts at ``mu``, is divided by 3 (down to 1e-12) when the cost
    falls and multiplied by 4 when it does not (``accept_ties``: an equal cost counts as a fall).
    A row drops out once its step is below 1e-10 in every component, its cost no longer falls
    by more than ``stall`` (relative, the round-off floor), or mu_n exceeds 1e8.

    Returns ``(x (N, k), r, J, *extra)`` at each row's last accepted point.
    """
    x = np.array(x0, dtype=np.float64)
    out = list(evaluate(x, np.arange(len(x))))
    cost = np.einsum("ij,ij->i", out[0], out[0])
    mu = np.full(len(x), float(mu))
    eye = np.eye(x.shape[1])
    active = np.arange(len(x))
    for _ in range(iterations):
        r, J = out[0][active], out[1][active]
        g = np.einsum("nij,ni->nj", J, r)
        H = np.einsum("nij,nil->njl", J, J)
        damp = mu[active, None, None] * (eye * (np.diagonal(H, axis1=1, axis2=2)[:, None, :] + floor))
        step = -np.linalg.solve(H + damp, g[..., None])[..., 0]
        trial = x[active] + step
        new = evaluate(trial, active)
        cost_new = np.einsum("ij,ij->i", new[0], new[0])
        better = cost_new <= cost[active] if accept_ties else cost_new < cost[active]
        idx = active[better]
        x[idx] = trial[better]
        for kept, value in zip(out, new):
            kept[idx] = value[better]
        cost[idx] = cost_new[better]
        mu[active] = np.where(better, np.maximum(mu[active] / 3, 1e-12), mu[active] * 4)
        stalled = ~better & (cost_new - cost[active] <= stall * (cost[active] + 1e-12))
        done = (np.abs(step).max(axis=1) < 1e-10) | stalled | (mu[active] > 1e8)
        active = active[~done]
        if len(active) == 0:
            break
    return (x, *out)


__all__ = ["levenberg_marquardt"]
