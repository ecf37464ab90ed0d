"""Judging jaw rigs: per-frame errors and train/test comparisons.

The error of a rig on a pose is the weighted mean distance (mm) between the mandible points
placed by the captured pose and by the rig's pose (:func:`facesim.se3.vertex_errors`), on the
points and front weights of :mod:`facesim.jaw.points` (Zoss et al. 2018 Fig. 8).

``compare_rigs`` fits every rig on one session and measures it on another session of the same
subject: mean, 95th percentile and maximum of the per-frame error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.classic import DOF, fit_classic
from facesim.jaw.frame import JawFrame
from facesim.jaw.nlpca import fit_nlpca
from facesim.jaw.posselt import fit_posselt


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
    "format_table",
    "pose_errors",
]
