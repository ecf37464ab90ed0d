"""The points jaw rigs are fitted and judged on: mandible samples and their weights.

- ``farthest_points`` -- a deterministic farthest-point sample (of points or of any coordinates).
- ``mandible_points`` -- an even sample of a model's mandible (default the shipped model's);
  ``synthetic_mandible`` -- a U-shaped stand-in for a jaw geometry without a model.
- ``front_weights`` -- the front-weighted error map of Zoss et al. 2018 Fig. 8: weights ramping
  quadratically from ``floor`` at the back of the mandible to 1 at its front (chin and incisors),
  where errors are visible, along the jaw frame's forward axis.
- ``second_moment_factor`` -- the factor that turns a weighted point cost into 12 residuals.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from facesim.errors import FacesimError
from facesim.jaw._shipped import shipped_model
from facesim.jaw.frame import JawFrame


def farthest_points(X, count: int) -> np.ndarray:
    """Indices ``(min(count, n),)`` of a farthest-point sample of the rows of ``X (n, d)`` (points,
    d = 3, or any coordinates), in the order chosen, starting nearest the centroid (deterministic)."""
    X = np.atleast_2d(np.asarray(X, dtype=np.float64))
    count = min(int(count), len(X))
    if count <= 0:
        return np.zeros(0, dtype=int)
    chosen = np.empty(count, dtype=int)
    chosen[0] = int(np.argmin(np.linalg.norm(X - X.mean(axis=0), axis=1)))
    d = np.linalg.norm(X - X[chosen[0]], axis=1)
    for i in range(1, count):
        chosen[i] = int(np.argmax(d))
        d = np.minimum(d, np.linalg.norm(X - X[chosen[i]], axis=1))
    return chosen


def mandible_points(model=None, count: int = 400) -> np.ndarray:
    """``(count, 3)`` mm: an even sample of the mandible surface (the bone attached to the jaw)
    of ``model`` (default the shipped model, whose samples are computed once per count), skull
    frame at rest."""
    if model is None:
        return _shipped_mandible(int(count)).copy()
    return _mandible_sample(model, count)


@functools.lru_cache(maxsize=4)
def _shipped_mandible(count: int) -> np.ndarray:
    return _mandible_sample(shipped_model(), count)


def _mandible_sample(model, count: int) -> np.ndarray:
    surfaces = [s for s in model.bones if s.bone == "jaw"]
    if not surfaces:
        raise FacesimError("model.bones: no surface attached to the jaw (expected the mandible)")
    V = np.concatenate([np.asarray(s.vertices, dtype=np.float64) for s in surfaces])
    return V[farthest_points(V, count)]


def synthetic_mandible(geometry, count: int = 400, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """``(count, 3)`` mm: a U-shaped stand-in mandible for a :class:`~facesim.model.JawGeometry`
    without a model: condyles down the rami to the gonial angles, then the body forward to the
    incisor (a tube of 6 mm radius around that polyline)."""
    frame = JawFrame.from_geometry(geometry, up)
    c_r, c_l = frame.to_local(geometry.condyle_right), frame.to_local(geometry.condyle_left)
    drop = c_r[1] + 20.0                             # condyle down to the gonion, ~20 mm below the incisor
    g_r = c_r + np.array([3.0, -drop, -5.0])
    g_l = c_l + np.array([-3.0, -drop, -5.0])
    chin = np.array([0.0, -35.0, -8.0])
    poly = [c_r, g_r, chin, np.zeros(3), chin, g_l, c_l]
    seg = np.array([np.linalg.norm(b - a) for a, b in itertools.pairwise(poly)])
    s = np.linspace(0.0, seg.sum(), 4 * count)
    k = np.minimum(np.searchsorted(np.cumsum(seg), s, side="right"), len(seg) - 1)
    start = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    a, b = np.array(poly[:-1])[k], np.array(poly[1:])[k]
    centre = a + ((s - start[k]) / seg[k])[:, None] * (b - a)
    rng = np.random.default_rng(0)
    offsets = rng.normal(size=centre.shape)
    offsets *= 6.0 / np.linalg.norm(offsets, axis=1, keepdims=True)
    P = centre + offsets
    return frame.to_world(P[farthest_points(P, count)])


def front_weights(points, frame: JawFrame, floor: float = 0.1) -> np.ndarray:
    """``(P,)`` weights in [floor, 1] of ``points (P, 3)`` mm (skull frame): ``floor`` at the
    back of the point set, 1 at its front, quadratic in between along the frame's z axis."""
    z = frame.to_local(points)[:, 2]
    t = (z - z.min()) / max(z.max() - z.min(), 1e-12)
    return floor + (1.0 - floor) * t * t


def second_moment_factor(points, weights) -> np.ndarray:
    """``L (4, 4)`` with L Lᵀ = Σ w x̃ x̃ᵀ / Σ w for ``points (k, 3)`` mm and ``weights (k,)`` >= 0
    (None: uniform), x̃ = (x, 1): then Σ w |D x̃|² / Σ w = |D L|²_F for any 3x4 D, so the weighted
    mean squared distance between the points moved by two poses is twelve residuals whatever k
    (the point cost of the classic and NLPCA rigs' fits)."""
    X = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    w = np.ones(len(X)) if weights is None else np.asarray(weights, dtype=np.float64)
    if len(X) < 3 or w.shape != (len(X),) or not (w >= 0).all() or not w.sum() > 0:
        raise FacesimError(f"points/weights: expected >= 3 points (k, 3) and k non-negative weights "
                           f"with a positive sum, got {X.shape} and {w.shape}")
    Xh = np.c_[X, np.ones(len(X))]
    S = (Xh * (w / w.sum())[:, None]).T @ Xh
    lam, V = np.linalg.eigh(S)           # S is PSD; eigh keeps it exact even for flat point sets
    return V * np.sqrt(np.maximum(lam, 0.0))


__all__ = ["farthest_points", "front_weights", "mandible_points", "second_moment_factor", "synthetic_mandible"]
