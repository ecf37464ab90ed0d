"""Sequences: fit every frame of a marker capture, warm-started from the previous one.

``track(sim, data, out_dir)`` maps the capture's markers onto the model's by name, stabilises the
head (rigid Procrustes of the head markers onto the model's rest head markers) or leaves it to
the solver, then fits frame after frame with :func:`~facesim.inverse.gauss_newton.fit_frame`,
each warm-started from the previous frame's controls and equilibrium. Missing markers (NaN) are
dropped per frame; after a fit, markers whose residual is far above the frame's robust spread
(``outlier_factor`` x 1.4826 MAD, at least ``outlier_floor`` mm) are reported as outliers and,
with ``robust``, the frame is refitted without them.

Files in ``out_dir`` (append-only logs, one complete line per frame, flushed; ``resume`` keeps
the frames already written and continues after them):

* ``activations.csv`` ``frame,<muscle>,...``; ``jaw.csv`` ``frame,<jaw parameter>,...``;
* ``residuals.csv`` ``frame,rms,<marker>,...`` (mm, NaN for missing markers);
* ``frames.csv`` the solver log per frame; ``report.json`` the summary (rewritten per frame).
"""

from __future__ import annotations

import csv
import io
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.inverse.gauss_newton import FitOptions, fit_frame
from facesim.inverse.jacobian import ControlSpace
from facesim.kinematics.frames import rigid_fit

LOG_COLUMNS = ("frame", "gn_steps", "equilibria", "newton_iterations", "linear_solves", "marker_rms",
               "worst_violation", "markers_used", "outliers", "seconds")


@dataclass(frozen=True)
class TrackOptions:
    """fit : per-frame :class:`FitOptions`; head : ``"procrustes"`` (stabilise with the head
    markers) or ``"none"`` (the capture is already in the model's head frame); outlier_factor,
    outlier_floor : outlier test; robust : refit frames without their outliers."""

    fit: FitOptions = FitOptions()
    head: str = "procrustes"
    outlier_factor: float = 5.0
    outlier_floor: float = 2.0
    robust: bool = True

    def __post_init__(self):
        if self.head not in ("procrustes", "none"):
            raise FacesimError(f"head: expected 'procrustes' or 'none', got {self.head!r}")


def match_markers(model_names, data_names) -> tuple[np.ndarray, list[str], list[str]]:
    """Index of each model marker in the capture (-1 if absent), the capture's names the model
    does not have and the model's names the capture does not have. Names match exactly, then
    case-insensitively."""
    data_names = list(data_names)
    exact = {n: i for i, n in enumerate(data_names)}
    folded = {n.lower(): i for i, n in enumerate(data_names)}
    index = np.array([exact.get(n, folded.get(n.lower(), -1)) for n in model_names], dtype=np.int64)
    used = set(index[index >= 0].tolist())
    unmatched_data = [n for i, n in enumerate(data_names) if i not in used]
    missing_model = [n for n, i in zip(model_names, index) if i < 0]
    return index, unmatched_data, missing_model


def stabilise(model, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Capture ``P (F, r, 3)`` (model marker order) moved per frame into the model's head frame by
    the rigid fit of its head markers onto the model's rest head markers. Returns the moved
    positions and the per-frame 4x4 transforms (capture -> model). Needs >= 3 head markers."""
    head = np.flatnonzero(model.markers.head)
    rest = model.marker_positions()[head]
    out = np.full_like(P, np.nan)
    Ts = np.full((len(P), 4, 4), np.nan)
    for f, frame in enumerate(P):
        ok = np.isfinite(frame[head]).all(axis=1)
        if ok.sum() < 3:
            continue
        T = rigid_fit(frame[head][ok], rest[ok])
        out[f] = frame @ T[:3, :3].T + T[:3, 3]
        Ts[f] = T
    return out, Ts


def _line(values) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(values)
    return buf.getvalue()


class _Log:
    def __init__(self, path: Path, header: list[str], resume: bool):
        self.path = path
        self.header = _line(header)
        kept = []
        if resume and path.is_file():
            lines = path.read_text().splitlines(keepends=True)
            if lines and lines[0] == self.header:
                kept = [ln for ln in lines[1:] if ln.endswith("\n") and len(next(csv.reader([ln]))) == len(header)]
        text = self.header + "".join(kept)
        atomic_write(path, lambda tmp: tmp.write_text(text))
        self.rows = {int(next(csv.reader([ln]))[0]): ln for ln in kept}
        self.file = open(path, "a", encoding="utf-8")  # noqa: SIM115

    def add(self, values) -> None:
        import os

        self.file.write(_line(values))
        self.file.flush()
        os.fsync(self.file.fileno())

    def close(self):
        self.file.close()


def _fmt(v) -> str:
    return "nan" if not np.isfinite(v) else f"{v:.6g}"


def track(sim, frames, P, out_dir, *, names=None, options: TrackOptions | None = None, start: Controls | None = None,
          resume: bool = False, progress: bool = True) -> dict:
    """Fit every frame of ``P (F, r, 3)`` (mm, the model's marker order, NaN missing; frame numbers
    ``frames (F,)``) and write the results into ``out_dir`` (see the module doc). ``start``:
    controls of the first frame's starting guess (default rest). Returns the summary."""
    from tqdm import tqdm

    options = options or TrackOptions()
    model = sim.model
    P = np.asarray(P, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    if P.shape[1:] != (model.n_markers, 3) or len(frames) != len(P):
        raise FacesimError(f"markers: expected ({len(frames)}, {model.n_markers}, 3) positions, got {P.shape}")
    if options.head == "procrustes":
        P, _ = stabilise(model, P)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    space = ControlSpace.of(sim, jaw=bool(getattr(sim.jaw_model, "n_params", 0)))
    jaw_names = list(getattr(sim.jaw_model, "param_names", [f"q{k}" for k in range(space.n_jaw)]))
    if getattr(sim.jaw_model, "name", "") == "sliding-condyle":
        jaw_names = ["opening", "right_slide", "left_slide"]
    logs = {
        "activations": _Log(out / "activations.csv", ["frame", *model.muscles.names], resume),
        "jaw": _Log(out / "jaw.csv", ["frame", *jaw_names], resume),
        "residuals": _Log(out / "residuals.csv", ["frame", "rms", *model.markers.names], resume),
        "frames": _Log(out / "frames.csv", list(LOG_COLUMNS), resume),
    }
    done = set.intersection(*(set(log.rows) for log in logs.values()))
    n_done = 0
    while n_done < len(frames) and int(frames[n_done]) in done:
        n_done += 1
    controls = start or Controls(np.zeros(model.n_muscles), jaw=_rest_jaw(space))
    x = None
    if n_done:   # warm start from the last written frame's controls
        last = int(frames[n_done - 1])
        a = np.array([float(v) for v in next(csv.reader([logs["activations"].rows[last]]))[1:]])
        q = np.array([float(v) for v in next(csv.reader([logs["jaw"].rows[last]]))[1:]])
        controls = Controls(a, jaw=q if len(q) else None)
    summary = {"frames": len(frames), "reused_frames": n_done, "outliers": {}, "status": "running"}
    t_start = time.perf_counter()
    rows = []
    try:
        with tqdm(total=len(frames), initial=n_done, desc="solve-mocap", unit="frame", disable=not progress) as bar:
            for i in range(n_done, len(frames)):
                k = int(frames[i])
                target = P[i]
                fit = fit_frame(sim, target, controls, x, space, options.fit)
                outliers = _outliers(fit.markers, target, options)
                if outliers and options.robust:
                    cleaned = target.copy()
                    cleaned[outliers] = np.nan
                    fit = fit_frame(sim, cleaned, fit.controls, fit.x, space, options.fit)
                controls, x = fit.controls, fit.x
                r = np.linalg.norm(fit.markers - target, axis=1)
                rep = fit.report
                logs["activations"].add([k, *map(_fmt, controls.a)])
                logs["jaw"].add([k, *map(_fmt, np.atleast_1d(controls.jaw) if space.n_jaw else [])])
                logs["residuals"].add([k, _fmt(rep.marker_rms), *map(_fmt, r)])
                used = int(np.isfinite(target).all(axis=1).sum()) - (len(outliers) if options.robust else 0)
                logs["frames"].add([k, rep.gn_steps, rep.equilibria, rep.newton_iterations, rep.linear_solves,
                                    _fmt(rep.marker_rms), _fmt(rep.worst_violation), used, len(outliers),
                                    f"{rep.seconds:.3f}"])
                if outliers:
                    summary["outliers"][str(k)] = [model.markers.names[j] for j in outliers]
                rows.append(rep)
                bar.set_postfix(rms=f"{rep.marker_rms:.2f}", steps=rep.gn_steps, refresh=False)
                bar.update(1)
        summary["status"] = "complete"
    except BaseException as exc:
        summary["status"] = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"failed: {type(exc).__name__}"
        raise
    finally:
        for log in logs.values():
            log.close()
        summary.update({
            "solved_frames": len(rows), "seconds": round(time.perf_counter() - t_start, 3),
            "gn_steps": [r.gn_steps for r in rows], "marker_rms": [round(r.marker_rms, 4) for r in rows],
        })
        atomic_write(out / "report.json", lambda tmp: tmp.write_text(json.dumps(summary, indent=2) + "\n"))
    return summary


def _rest_jaw(space: ControlSpace):
    if not space.n_jaw:
        return None
    return np.zeros(space.n_jaw) if space.jaw_rest is None else np.array(space.jaw_rest)


def _outliers(P, target, options: TrackOptions) -> list[int]:
    r = np.linalg.norm(P - target, axis=1)
    ok = np.isfinite(r)
    if ok.sum() < 5:
        return []
    med = np.median(r[ok])
    spread = 1.4826 * np.median(np.abs(r[ok] - med))
    limit = max(med + options.outlier_factor * spread, options.outlier_floor)
    return [int(j) for j in np.flatnonzero(ok & (r > limit))]


__all__ = ["TrackOptions", "match_markers", "stabilise", "track"]
