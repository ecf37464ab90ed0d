"""Judging jaw rigs: mandible points, the front-weighted error map, and train/test comparisons.

The error of a rig on a pose is the weighted mean distance (mm) between the mandible points
placed by the captured pose and by the rig's pose (:func:`facesim.se3.vertex_errors`).
Following Zoss et al. 2018 Fig. 8 the weights favour the front of the mandible (chin and
incisors), where errors are visible: ``front_weights`` ramps them quadratically from ``floor``
at the back of the mandible to 1 at its front along the jaw frame's forward axis.

``compare_rigs`` fits every rig on one session and measures it on another session of the same
subject: mean, 95th percentile and maximum of the per-frame error.
"""

from __future__ import annotations

import functools
import itertools
import time
from dataclasses import dataclass

import numpy as np

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.frame import JawFrame


def farthest_points(X, count: int) -> np.ndarray:
    """Indices ``(min(count, n),)`` of a farthest-point sample of ``X (n, 3)``, starting nearest
    the centroid (deterministic)."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
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
    from facesim.jaw._shipped import shipped_model

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


@dataclass(frozen=True)
class ErrorStats:
    """Per-frame weighted mandible-point errors (mm) and their mean, 95th percentile and maximum."""

    per_frame: np.ndarray
    mean: float
    p95: float
    max: float

    @classmethod
    def of(cls, errors) -> ErrorStats:
        e = np.asarray(errors, dtype=np.float64)
        return cls(e, float(e.mean()), float(np.percentile(e, 95)), float(e.max()))

    def as_dict(self) -> dict[str, float]:
        return {"mean": self.mean, "p95": self.p95, "max": self.max}


def pose_errors(predicted, captured, points, weights=None) -> ErrorStats:
    """:class:`ErrorStats` of ``predicted`` against ``captured`` poses ``(N, 4, 4)`` on the
    mandible ``points (P, 3)`` mm with ``weights (P,)``."""
    return ErrorStats.of(se3.vertex_errors(predicted, captured, points, weights))


@dataclass(frozen=True)
class RigReport:
    """One rig in :func:`compare_rigs`: ``fit_seconds`` and the errors on the training and the
    test session."""

    name: str
    fit_seconds: float
    train: ErrorStats
    test: ErrorStats
    rig: object


RIGS = ("1dof", "3dof", "5dof", "6dof", "posselt", "nlpca")


def compare_rigs(train, test, points, weights=None, rigs=RIGS, frame: JawFrame | None = None,
                 posselt_options: dict | None = None, nlpca_options: dict | None = None) -> dict[str, RigReport]:
    """Fit each rig of ``rigs`` on the session ``train`` and measure it on ``test``.

    train, test : :class:`facesim.jaw.motion.Session` of the same subject.
    points : (P, 3) mm mandible at rest (skull frame); weights : (P,) (default uniform).
    frame : the jaw frame for the rigs (default ``JawFrame.from_poses`` of the training poses).
    The classic rigs are measured with their per-frame best parameters (their pivot is what
    they learn); the Posselt rig is driven by the captured reference point alone; the NLPCA rig
    by its inverse kinematics (best parameters on ``points``). ``posselt_options`` and
    ``nlpca_options`` go to ``fit_posselt`` and ``fit_nlpca``.
    """
    from facesim.jaw.classic import DOF, fit_classic
    from facesim.jaw.nlpca import fit_nlpca
    from facesim.jaw.posselt import fit_posselt

    if frame is None:
        frame = JawFrame.from_poses(train.poses, train.reference_point)
    reports = {}
    for name in rigs:
        start = time.perf_counter()
        if name in DOF:
            rig = fit_classic(train.poses, name, frame, points, weights).rig
        elif name == "posselt":
            rig = fit_posselt(train, frame=frame, **(posselt_options or {}))
        elif name == "nlpca":
            rig = fit_nlpca(train.poses, frame, points=points, weights=weights, **(nlpca_options or {}))
        else:
            raise FacesimError(f"compare_rigs: unknown rig {name!r} (expected one of {', '.join(RIGS)})")
        seconds = time.perf_counter() - start
        reports[name] = RigReport(
            name, seconds,
            pose_errors(rig.reproduce(train.poses, points, weights), train.poses, points, weights),
            pose_errors(rig.reproduce(test.poses, points, weights), test.poses, points, weights),
            rig)
    return reports


def format_table(reports: dict[str, RigReport]) -> str:
    """A plain-text table: rig, fit time (s), train mean, test mean / p95 / max (mm)."""
    lines = [f"{'rig':<9}{'fit s':>8}{'train mean':>12}{'test mean':>11}{'test p95':>10}{'test max':>10}"]
    for r in reports.values():
        lines.append(f"{r.name:<9}{r.fit_seconds:>8.2f}{r.train.mean:>12.3f}{r.test.mean:>11.3f}"
                     f"{r.test.p95:>10.3f}{r.test.max:>10.3f}")
    return "\n".join(lines)


__all__ = [
    "RIGS",
    "ErrorStats",
    "RigReport",
    "compare_rigs",
    "farthest_points",
    "format_table",
    "front_weights",
    "mandible_points",
    "pose_errors",
    "synthetic_mandible",
]
