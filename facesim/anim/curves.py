"""Curves through keys: the interpolation of controls between keyframes, in a vector space
(activations, jaw parameters) and on SE(3) (rigid jaw and head poses).

Keys ``(t_i, p_i)``, ``i = 0..K-1``, at increasing times ``t_i`` (any unit: frame numbers for
keyframes, the source's frame numbers for a retime). A query at ``t`` in segment
``[t_i, t_{i+1}]`` has the local parameter ``s = (t - t_i) / (t_{i+1} - t_i)`` in [0, 1]
(queries outside ``[t_0, t_{K-1}]`` take the end keys). Methods:

* ``linear``: ``(1 - s) p_i + s p_{i+1}``;
* ``smoothstep``: the same with ``w = 3 s² - 2 s³`` for ``s`` (zero velocity at every key: an
  ease in and out of each key);
* ``catmull-rom``: the cubic Hermite segment with the non-uniform Catmull-Rom tangents
  ``m_i = (p_{i+1} - p_{i-1}) / (t_{i+1} - t_{i-1})`` (one-sided at the ends), so the curve is C1
  through the keys. It overshoots where the keys turn back (keys 0, 1, 1, 0 reach 1.125 between
  the two 1s): callers clamp (activations to [0, 1], jaw parameters to the jaw model's bounds).

Poses (4x4 rigid, mm) are interpolated in the tangent space of the segment's first key, through
the log and exp maps of :mod:`facesim.se3`: ``P(s) = P_i exp(x(s))`` with ``x`` the curve above
through the twists ``log(P_i^-1 P_j)`` of the neighbouring keys ``j`` (0 for ``j = i``). For
``linear`` that is the geodesic ``P_i exp(s log(P_i^-1 P_{i+1}))`` (a screw motion at constant
speed, :func:`facesim.se3.interpolate`); the result is rigid for every method.

At a key's own time every method returns the key itself, bit for bit (a retime keeps the values
at the times both frame rates share).
"""

from __future__ import annotations

import numpy as np

from facesim import se3
from facesim.errors import FacesimError

METHODS = ("linear", "smoothstep", "catmull-rom")


def check_method(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`, else a one-line :class:`FacesimError`."""
    if method not in METHODS:
        raise FacesimError(f"interpolation method: expected one of {', '.join(METHODS)}, got {method!r}")
    return method


def _locate(times: np.ndarray, query: np.ndarray):
    """Segment ``i (Q,)`` in [0, K-2] and local parameter ``s (Q,)`` in [0, 1] of each query."""
    i = np.clip(np.searchsorted(times, query, side="right") - 1, 0, len(times) - 2)
    s = np.clip((query - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    return i, s


def _hits(times: np.ndarray, query: np.ndarray):
    """``(mask (Q,), key (Q,))``: the queries at a key's own time, and that key."""
    k = np.clip(np.searchsorted(times, query), 0, len(times) - 1)
    return times[k] == query, k


def _hermite(s: np.ndarray):
    """The cubic Hermite basis ``h00, h10, h01, h11`` at ``s (Q,)``."""
    s2, s3 = s * s, s * s * s
    return 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, 3 * s2 - 2 * s3, s3 - s2


def _check(times, n: int, query) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(times, dtype=np.float64).ravel()
    q = np.atleast_1d(np.asarray(query, dtype=np.float64))
    if len(t) != n or not len(t):
        raise FacesimError(f"keys: expected one time per key ({n} keys), got {len(t)} times")
    if not (np.isfinite(t).all() and np.isfinite(q).all()) or np.any(np.diff(t) <= 0):
        raise FacesimError("keys: expected finite, strictly increasing key times")
    return t, q


def interpolate_values(times, values, query, method: str = "linear") -> np.ndarray:
    """Values ``(Q, d)`` at the times ``query (Q,)`` of the curve through ``values (K, d)`` at
    ``times (K,)`` (module doc; not clamped). Units: those of ``values``; times any unit."""
    check_method(method)
    P = np.asarray(values, dtype=np.float64)
    P = P.reshape(len(P), -1)
    t, q = _check(times, len(P), query)
    if len(t) == 1:
        return np.repeat(P, len(q), axis=0)
    i, s = _locate(t, q)
    if method == "catmull-rom":
        m = np.empty_like(P)
        m[1:-1] = (P[2:] - P[:-2]) / (t[2:] - t[:-2])[:, None]
        m[0] = (P[1] - P[0]) / (t[1] - t[0])
        m[-1] = (P[-1] - P[-2]) / (t[-1] - t[-2])
        h00, h10, h01, h11 = _hermite(s)
        dt = (t[i + 1] - t[i])[:, None]
        out = h00[:, None] * P[i] + h10[:, None] * dt * m[i] + h01[:, None] * P[i + 1] + h11[:, None] * dt * m[i + 1]
    else:
        w = s if method == "linear" else s * s * (3.0 - 2.0 * s)
        out = (1.0 - w)[:, None] * P[i] + w[:, None] * P[i + 1]
    hit, k = _hits(t, q)
    out[hit] = P[k[hit]]
    return out


def interpolate_poses(times, poses, query, method: str = "linear") -> np.ndarray:
    """Rigid poses ``(Q, 4, 4)`` at ``query (Q,)`` of the curve through the rigid ``poses (K, 4, 4)``
    (mm) at ``times (K,)``, in the tangent space of each segment's first key (module doc)."""
    check_method(method)
    T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    t, q = _check(times, len(T), query)
    if len(t) == 1:
        return np.repeat(T, len(q), axis=0)
    i, s = _locate(t, q)
    inv = se3.inverse(T)
    ahead = se3.log(inv[:-1] @ T[1:])          # (K-1, 6): key i+1 in the chart of key i
    if method == "catmull-rom":
        # in the chart of key i: key i at 0, key i+1 at ahead[i], keys i-1 and i+2 at their logs;
        # at the ends the missing neighbour is the key itself, which makes the tangent one-sided
        before, after = np.maximum(i - 1, 0), np.minimum(i + 2, len(t) - 1)
        x_before = se3.log(inv[i] @ T[before])
        x_after = se3.log(inv[i] @ T[after])
        m0 = (ahead[i] - x_before) / (t[i + 1] - t[before])[:, None]
        m1 = x_after / (t[after] - t[i])[:, None]
        _, h10, h01, h11 = _hermite(s)
        dt = (t[i + 1] - t[i])[:, None]
        x = h10[:, None] * dt * m0 + h01[:, None] * ahead[i] + h11[:, None] * dt * m1
    else:
        w = s if method == "linear" else s * s * (3.0 - 2.0 * s)
        x = w[:, None] * ahead[i]
    out = T[i] @ se3.exp(x)
    hit, k = _hits(t, q)
    out[hit] = T[k[hit]]
    return out


def blend_poses(A, B, t) -> np.ndarray:
    """Per frame the geodesic a fraction ``t (F,)`` of the way from ``A (F, 4, 4)`` to ``B (F, 4, 4)``
    (rigid, mm): ``A_k exp(t_k log(A_k^-1 B_k))``; exactly ``A_k`` at 0 and ``B_k`` at 1."""
    A, B = np.asarray(A, dtype=np.float64), np.asarray(B, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    out = A @ se3.exp(t[:, None] * se3.log(se3.inverse(A) @ B))
    out[t == 0.0] = A[t == 0.0]
    out[t == 1.0] = B[t == 1.0]
    return out


def scale_poses(T, factor: float) -> np.ndarray:
    """The poses ``T (F, 4, 4)`` with their motion from the identity scaled by ``factor``:
    ``exp(factor log T)`` (0: the identity; 1: ``T`` itself)."""
    T = np.asarray(T, dtype=np.float64)
    return T.copy() if factor == 1.0 else se3.exp(factor * se3.log(T))


__all__ = ["METHODS", "blend_poses", "check_method", "interpolate_poses", "interpolate_values", "scale_poses"]
