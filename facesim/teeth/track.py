"""Teeth tracking (Yang et al. 2018 section 4): per frame the head (upper teeth) then the jaw.

Each frame starts from the previous frame's poses (the paper's warm start) and minimises the
silhouette energy of :mod:`facesim.teeth.silhouette` in all cameras, first over the upper teeth's
world pose (the head; the lower teeth follow it at the previous jaw pose), then over the lower
teeth's world pose with the head fixed. The optimiser is Gauss-Newton on the point-to-line
residuals of the matched contour points (Levenberg-Marquardt damped, Huber-weighted), each step
accepted only if the true, re-rendered energy drops; otherwise a golden-section search along the
step (the paper's line search, here along the Gauss-Newton direction rather than the gradient)
finds the best fraction of it, and the body stops when none helps. Why Gauss-Newton: the paper's
gradient direction on a distance-transform energy needs many line searches per frame; the
point-to-line model is the energy's own quadratic model, so a few steps converge from several
millimetres off. The basin is widened coarse to fine: the images and cameras at 1/4, 1/2 and
full resolution, with match gates shrinking with the pixel size.

Trust (never silently kept): a body's *confidence* is the share of its visible model contour
points (at the final pose, in all cameras; visible: not near an occluder) that lie within
``match_px`` of the data's contour, scaled down by ``matched length / min_matched_mm`` when less
than ``min_matched_mm`` of contour matches (teeth mostly hidden); ``sigma_mm`` the standard
deviation of the incisal point
from the Gauss-Newton covariance ``s^2 (J^T W J)^-1``. A jaw with confidence below
``min_confidence``, ``sigma_mm`` above ``max_sigma_mm`` or an RMS residual above
``max_residual_px`` (a lost track), or leaving more than ``1 - min_explained`` of the data's contour
unexplained (teeth fitted off behind the lips) is *flagged*: the frame keeps the
previous trusted jaw pose (held), and so does a flagged head.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from facesim import se3
from facesim.teeth.silhouette import Model, View, energy_and_pairs, moved, normal_equations

GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)


@dataclass(frozen=True)
class TrackOptions:
    """Settings of the tracker (pixels are full-resolution pixels unless said).

    levels : image scales, coarse to fine; iterations : Gauss-Newton steps per body and level;
    gates : match gates per level, in that level's pixels; huber : px, Huber threshold of the
    residuals; occluder_px : margin around occluders; match_px : a contour point matches within
    it (confidence); min_confidence, max_sigma_mm : the flag thresholds; min_matched_mm : mm of
    matched contour (all cameras) below which the confidence shrinks; min_explained : the share
    of the data's contour pixels that the fitted model must explain (lie within ``match_px`` of
    its contour), else the frame is flagged (teeth fitted off into hiding); track_head : False keeps
    the upper teeth at the identity (a stabilised head); golden_steps : line-search evaluations;
    refine : passes over both bodies again at the finest level; restart_residual_px : a fit
    whose RMS residual exceeds it (or that is flagged) is re-fitted from the other start poses
    (:meth:`Tracker.track_frame`); restarts : how many of them, the best at the coarsest level,
    are fitted in full.
    """

    levels: tuple[float, ...] = (0.25, 0.5, 1.0)
    iterations: tuple[int, ...] = (8, 6, 5)
    gates_mm: tuple[float, ...] = (6.0, 2.0, 0.75)
    huber: float = 1.0
    occluder_mm: float = 0.4
    match_mm: float = 0.25
    min_confidence: float = 0.5
    min_matched_mm: float = 5.0
    min_explained: float = 0.6
    max_sigma_mm: float = 0.15
    max_residual_px: float = 1.5
    track_head: bool = True
    golden_steps: int = 6
    refine: int = 1
    restart_residual_px: float = 1.0
    restarts: int = 2


@dataclass(frozen=True)
class FrameResult:
    """One tracked frame: ``head (4, 4)`` world from skull, ``jaw (4, 4)`` mandible relative to
    skull (the held pose when flagged), ``fitted (4, 4)`` the jaw the fit found, ``residual`` px
    (RMS point-to-line distance of the jaw's final pairs), ``confidence`` in [0, 1], ``sigma_mm``,
    ``flagged`` (jaw not trusted), ``head_flagged``, ``seconds``, ``energy`` px^2 (the silhouette
    energy at the finest level), ``starts`` (the fits made: 1, or more after a restart)."""

    head: np.ndarray
    jaw: np.ndarray
    fitted: np.ndarray
    residual: float
    confidence: float
    sigma_mm: float
    flagged: bool
    head_flagged: bool
    seconds: float
    energy: float = float("nan")
    starts: int = 1


def _schedule(cameras, options: TrackOptions, mm_per_px: float) -> list[tuple[float, int, float]]:
    """``(scale, iterations, gate px)`` of the levels used: those whose images keep at least
    ``MIN_LEVEL_WIDTH`` px across (always the full resolution), the coarsest with the first
    iterations and gate of the options; ``mm_per_px`` at full resolution."""
    width = min(c.width for c in cameras)
    keep = [s for s in options.levels if s * width >= MIN_LEVEL_WIDTH or s == options.levels[-1]]
    return [(s, n, max(MIN_GATE_PX, g * s / mm_per_px)) for s, n, g in zip(keep, options.iterations, options.gates_mm)]


#: The coarsest image of the pyramid keeps at least this many pixels across; no gate is narrower
#: than MIN_GATE_PX.
MIN_LEVEL_WIDTH = 300
MIN_GATE_PX = 3.0


def _levels(cameras, labels, options: TrackOptions, scales, mm_per_px: float):
    """Per level the views of every camera: the label images resized to the level's scale."""
    import cv2

    from facesim.teeth.segment import OCCLUDER, TEETH

    out = []
    for s in scales:
        views = []
        for cam, lab in zip(cameras, labels):
            c = cam.scaled(s) if s != 1.0 else cam
            if s != 1.0:
                size = (c.width, c.height)
                teeth = cv2.resize((lab == TEETH).astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.5
                occ = cv2.resize((lab == OCCLUDER).astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.25
                lab = np.zeros(teeth.shape, np.uint8)
                lab[occ] = OCCLUDER
                lab[teeth] = TEETH
            views.append(View.of(c, lab, occluder_px=max(1.0, options.occluder_mm * s / mm_per_px)))
        out.append(views)
    return out


class Tracker:
    """Tracks a dentition (:class:`~facesim.teeth.dentition.Dentition`) in calibrated images."""

    def __init__(self, dentition, cameras, options: TrackOptions = TrackOptions()):
        self.dentition, self.cameras, self.options = dentition, list(cameras), options
        self.model = Model(dentition)
        # the pixel size at the teeth (mm), for the options' lengths: the finest camera's
        centre = np.concatenate([dentition.upper_V, dentition.lower_V]).mean(axis=0)
        self.mm_per_px = min(float(c.to_camera(centre[None])[0, 2] / c.K[0, 0]) for c in self.cameras)

    # ----------------------------------------------------------------- energy of poses
    def _evaluate(self, views, upper, lower, body, gate):
        total, pairs, stats = 0.0, [], []
        for v in views:
            c = self.model.contour(v, upper, lower)
            e, p, s = energy_and_pairs(v, c, body, gate)
            total += e
            pairs.append(p)
            stats.append(s)
        return total / len(views), pairs, stats

    def _fit_body(self, views, upper, lower, body, gate, iterations):
        """Gauss-Newton + golden section on one body's world pose; returns (upper, lower, info)."""
        o = self.options
        poses = [upper, lower]
        E, pairs, stats = self._evaluate(views, poses[0], poses[1], body, gate)
        lam = 1e-3
        info = None
        head_jaw = se3.inverse(upper) @ lower if body == 0 else None

        def at(delta, centre):
            p = list(poses)
            p[body] = moved(poses[body], delta, centre)
            if body == 0:   # the lower teeth follow the head at the jaw pose of the start
                p[1] = p[0] @ head_jaw
            return p

        for _ in range(iterations):
            A, b, H, wrr, wsum, npts = np.zeros((6, 6)), np.zeros(6), np.zeros((6, 6)), 0.0, 0.0, 0
            P = [p for p in pairs if p is not None and len(p.q)]
            if not P:
                break
            centre = np.concatenate([p.rest for p in P]).mean(axis=0)
            centre = poses[body][:3, :3] @ centre + poses[body][:3, 3]
            res = []
            for v, p in zip(views, pairs):
                if p is None or not len(p.q):
                    continue
                Ai, bi, Hi, wi, si, r = normal_equations(v, p, poses[body], centre, o.huber)
                A += Ai
                b += bi
                H += Hi
                wrr += wi
                wsum += si
                npts += len(r)
                res.append(r)
            if npts < 12:
                break
            scale = np.sqrt(np.trace(A) / 6.0) or 1.0
            D = np.diag(np.diag(A)) + 1e-9 * scale * scale * np.eye(6)
            delta = -np.linalg.solve(A + lam * D, b)
            info = (H, wrr / max(wsum, 1e-12), npts, centre, np.concatenate(res))
            if np.abs(delta[:3]).max() < 1e-4 and np.abs(delta[3:]).max() < 5e-3:
                break   # converged: the step moves no point by a hundredth of a millimetre
            new = at(delta, centre)
            E1, pairs1, stats1 = self._evaluate(views, new[0], new[1], body, gate)
            if E1 < E:
                poses, E, pairs, stats = new, E1, pairs1, stats1
                lam = max(lam * 0.3, 1e-6)
                continue
            # golden-section search for the best fraction of the step in [0, 1]
            a, c = 0.0, 1.0
            x1, x2 = c - GOLDEN * (c - a), a + GOLDEN * (c - a)
            f1 = self._evaluate(views, *at(x1 * delta, centre), body, gate)
            f2 = self._evaluate(views, *at(x2 * delta, centre), body, gate)
            for _ in range(o.golden_steps - 2):
                if f1[0] < f2[0]:
                    c, x2, f2 = x2, x1, f1
                    x1 = c - GOLDEN * (c - a)
                    f1 = self._evaluate(views, *at(x1 * delta, centre), body, gate)
                else:
                    a, x1, f1 = x1, x2, f2
                    x2 = a + GOLDEN * (c - a)
                    f2 = self._evaluate(views, *at(x2 * delta, centre), body, gate)
            x, best = (x1, f1) if f1[0] < f2[0] else (x2, f2)
            if best[0] < E:
                poses = at(x * delta, centre)
                E, pairs, stats = best
                lam *= 3.0
            else:
                break
        return poses[0], poses[1], info, stats

    def _trust(self, body, stats, info, point, px_mm: float = 0.0):
        """``(confidence, sigma_mm, residual px)`` of ``body`` from the final level's statistics;
        ``px_mm`` the size of that level's pixels at the teeth (mm)."""
        o = self.options
        visible = sum(int(s[0][body]) for s in stats)
        matched = sum(int(s[1][body]) for s in stats)
        confidence = matched / visible if visible else 0.0
        confidence *= min(1.0, matched * px_mm / o.min_matched_mm)   # too little contour seen: not trusted
        sigma, rms = np.inf, np.inf
        if info is not None:
            A, s2, npts, centre, r = info
            rms = float(np.sqrt(np.mean(r * r)))
            try:
                cov = s2 * np.linalg.inv(A) if npts > 6 else None
            except np.linalg.LinAlgError:
                cov = None
            if cov is not None:
                d = point - centre
                G = np.column_stack([-se3.hat(d), np.eye(3)])       # d point / d (omega, v)
                sigma = float(np.sqrt(max(np.trace(G @ cov @ G.T), 0.0)))
        return confidence, sigma, rms

    def _fit_pyramid(self, levels, schedule, upper, lower, first: int = 0):
        """Both bodies fitted level by level from ``first`` (head, then jaw), then ``refine`` passes
        at the finest level; returns ``(upper, lower, info_u, info_l)``."""
        o = self.options
        info_u = info_l = None
        for views, (_, n_iter, gate) in list(zip(levels, schedule))[first:]:
            if o.track_head:
                upper, lower, info_u, _ = self._fit_body(views, upper, lower, 0, gate, n_iter)
            upper, lower, info_l, _ = self._fit_body(views, upper, lower, 1, gate, n_iter)
        for _ in range(o.refine):   # again at the finest level: each body now meets the other where it is
            if o.track_head:
                upper, lower, info_u, _ = self._fit_body(levels[-1], upper, lower, 0, schedule[-1][2],
                                                         schedule[-1][1])
            upper, lower, info_l, _ = self._fit_body(levels[-1], upper, lower, 1, schedule[-1][2], schedule[-1][1])
        return upper, lower, info_u, info_l

    def _assess(self, levels, schedule, fit):
        """``(energy px^2, (conf, sigma, rms px), head (conf, sigma) or None)`` of a fitted
        ``(upper, lower, info_u, info_l)``: the energy at the finest level and gate (what the
        starts are compared by), the trust of each body (:meth:`_trust`)."""
        o = self.options
        upper, lower, info_u, info_l = fit
        s = schedule[-1][0]
        energy = self._evaluate(levels[-1], upper, lower, None, schedule[-1][2])[0]
        match_gate = 2.0 * max(1.0, o.match_mm * s / self.mm_per_px)   # stats count points within gate / 2
        _, _, stats = self._evaluate(levels[-1], upper, lower, None, match_gate)
        px_mm = self.mm_per_px / s
        conf, sigma, rms = self._trust(1, stats, info_l, se3.transform_points(lower, self.dentition.incisor[None])[0],
                                       px_mm)
        head = None
        if o.track_head:
            c_u, s_u, _ = self._trust(0, stats, info_u,
                                      se3.transform_points(upper, self.dentition.upper_incisor[None])[0], px_mm)
            head = (c_u, s_u)
        n_data = sum(int(st[3][0]) for st in stats)
        explained = sum(int(st[3][1]) for st in stats) / n_data if n_data else 1.0
        return energy, (conf, sigma, rms / s if np.isfinite(rms) else rms, explained), head

    def _lost(self, trust, head) -> bool:
        """Whether a fit's trust says it is not to be kept (the flag rules of the module docstring)."""
        o = self.options
        conf, sigma, rms, explained = trust
        head_bad = head is not None and (head[0] < o.min_confidence or not head[1] <= o.max_sigma_mm)
        return bool(conf < o.min_confidence or not sigma <= o.max_sigma_mm or head_bad
                    or not rms <= o.max_residual_px or explained < o.min_explained)

    def track_frame(self, labels, head0, jaw0, start=None, candidates=()) -> FrameResult:
        """Track one frame of label images ``labels`` (one ``(h, w) uint8`` per camera).

        head0 (4, 4), jaw0 (4, 4) : the last trusted poses (a flagged frame keeps them).
        start (4, 4) : the jaw pose the fit starts from (default ``jaw0``; e.g. a prediction).
        candidates : further jaw starts (4, 4) for a fit that looks lost (RMS residual above
            ``restart_residual_px`` or flagged): each is fitted at the coarsest level, the
            ``restarts`` best are fitted in full, and the lowest energy of all wins.
        """
        o = self.options
        t0 = time.perf_counter()
        schedule = _schedule(self.cameras, o, self.mm_per_px)
        levels = _levels(self.cameras, labels, o, [s for s, _, _ in schedule], self.mm_per_px)
        start = jaw0 if start is None else start
        best = self._fit_pyramid(levels, schedule, head0.copy(), head0 @ start)
        energy, trust, head = self._assess(levels, schedule, best)
        tried = 1
        if candidates and o.restarts > 0 and (self._lost(trust, head) or not trust[2] <= o.restart_residual_px):
            # multi-start: rank the candidates by their energy after a jaw fit at the coarsest level
            views, (_, n_iter, gate) = levels[0], schedule[0]
            ranked = []
            for J in candidates:
                u, lo, _, _ = self._fit_body(views, head0.copy(), head0 @ J, 1, gate, n_iter)
                ranked.append((self._evaluate(views, u, lo, None, gate)[0], len(ranked), u, lo))
            ranked.sort(key=lambda r: r[:2])
            for _, _, u, lo in ranked[:o.restarts]:
                fit = self._fit_pyramid(levels, schedule, u, lo)
                e, t, h = self._assess(levels, schedule, fit)
                tried += 1
                if e < energy:
                    best, energy, trust, head = fit, e, t, h
        upper, lower = best[0], best[1]
        conf, sigma, rms, _ = trust
        head_flagged = bool(head is not None and (head[0] < o.min_confidence or not head[1] <= o.max_sigma_mm))
        if head_flagged:
            upper = head0.copy()
        fitted = se3.inverse(upper) @ lower
        fitted = se3.from_rt(_orthonormal(fitted[:3, :3]), fitted[:3, 3])
        # a lost track fits worse than the segmentation's pixel noise: flagged too
        flagged = self._lost(trust, head)
        jaw = jaw0.copy() if flagged else fitted
        return FrameResult(upper, jaw, fitted, rms, conf, sigma, flagged, head_flagged,
                           time.perf_counter() - t0, energy, tried)


#: The frame log beside a poses file: one line per tracked frame (facesim.framelog).
_LOG_FIELDS = (["frame", "name"] + [f"jaw_{i}{j}" for i in range(4) for j in range(4)]
               + [f"head_{i}{j}" for i in range(4) for j in range(4)]
               + [f"fitted_{i}{j}" for i in range(4) for j in range(4)]
               + ["residual_px", "confidence", "sigma_mm", "flagged", "head_flagged", "seconds", "energy_px2",
                  "starts"])


def log_path(out) -> "Path":
    """The frame log of the poses file ``out``: ``<stem>.frames.csv`` beside it."""
    from pathlib import Path

    out = Path(out)
    return out.with_name(out.stem + ".frames.csv")


def _row(i: int, name: str, r: FrameResult) -> list:
    return [i, name, *np.round(r.jaw.reshape(-1), 12), *np.round(r.head.reshape(-1), 12),
            *np.round(r.fitted.reshape(-1), 12), f"{r.residual:.6g}", f"{r.confidence:.6g}", f"{r.sigma_mm:.6g}",
            int(r.flagged), int(r.head_flagged), f"{r.seconds:.4g}", f"{r.energy:.6g}", r.starts]


def _parse(line: str) -> FrameResult:
    import csv

    v = next(csv.reader([line]))
    f = [float(x) for x in v[2:]]
    return FrameResult(np.array(f[16:32]).reshape(4, 4), np.array(f[:16]).reshape(4, 4),
                       np.array(f[32:48]).reshape(4, 4), f[48], f[49], f[50], bool(f[51]), bool(f[52]), f[53], f[54],
                       int(f[55]))


#: Hinge steps (degrees) about the skull's left-right axis through the origin (facesim's frame
#: puts it between the condyles), applied to the last trusted jaw: starts for a frame that looks
#: lost in a fast opening or closing.
HINGE_STEPS_DEG = (-12.0, -6.0, 6.0, 12.0)


def _hinge(deg: float) -> np.ndarray:
    """``(4, 4)``: a rotation by ``deg`` about the x axis (positive: the incisors go down)."""
    return se3.exp(np.array([np.deg2rad(deg), 0.0, 0.0, 0.0, 0.0, 0.0]))


def jaw_starts(history, first=None) -> tuple[np.ndarray, list[np.ndarray]]:
    """``(start (4, 4), candidates)`` of the next frame's jaw from the frames tracked so far.

    history : list of :class:`FrameResult`, in order. first : (4, 4) the start of the first frame
    (default rest, the identity). The start is a constant-velocity prediction when the last two
    frames are trusted (``J2 J1^-1 J2``: the last frame's motion once more), else the last
    trusted jaw; the candidates (tried when the fit from the start looks lost) are the last
    trusted jaw, twice the last motion, the last fitted jaw of a flagged frame, rest and the
    :data:`HINGE_STEPS_DEG` openings and closings of the last trusted jaw.
    """
    rest = np.eye(4)
    prev = history[-1].jaw if history else (rest if first is None else np.asarray(first, dtype=np.float64))
    start, cands = prev, []
    if len(history) >= 2 and not history[-1].flagged and not history[-2].flagged:
        D = history[-1].jaw @ se3.inverse(history[-2].jaw)
        start = D @ prev
        cands += [prev, se3.exp(2.0 * se3.log(D)) @ prev]
    if history and history[-1].flagged:
        cands.append(history[-1].fitted)
    cands += [rest] + [_hinge(a) @ prev for a in HINGE_STEPS_DEG]
    return start, cands


def track_capture(capture, dentition, out, options: TrackOptions = TrackOptions(), resume: bool = False,
                  progress: bool = True, first=None) -> dict:
    """Track every frame of ``capture`` (:class:`~facesim.teeth.capture.Capture`) from the rest
    pose (head identity, jaw ``first (4, 4)`` or the identity at the first frame), each frame
    warm-started from the previous ones (:func:`jaw_starts`: a constant-velocity prediction,
    other starts when the fit looks lost); write the poses file ``out`` (``.npz``) at the end and every frame's line to its frame
    log (:func:`log_path`) as it is done. ``resume`` keeps the frames of an earlier log of the same
    capture and goes on after them. Returns a summary (frames, flagged, seconds per frame)."""
    from facesim.framelog import FrameLog, csv_line, read_lines

    header = csv_line(_LOG_FIELDS)
    lines = read_lines(log_path(out), header) if resume else {}
    done = {}
    for i in sorted(lines):   # resume only a run over the same frames, in order, without gaps
        if i != len(done) or i >= len(capture) or lines[i].split(",")[1] != capture.names[i]:
            break
        done[i] = lines[i]
    tracker = Tracker(dentition, capture.cameras, options)
    results = [_parse(done[i]) for i in range(len(done))]
    steps = range(len(done), len(capture))
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="track", unit="frame", initial=len(done), total=len(capture))
    with FrameLog(log_path(out), header, [done[i] for i in range(len(done))]) as log:
        for i in steps:
            head0 = results[-1].head if results else np.eye(4)
            start, candidates = jaw_starts(results, first)
            jaw0 = results[-1].jaw if results else start
            r = tracker.track_frame(capture.labels(i), head0, jaw0, start, candidates)
            results.append(r)
            log.add(csv_line(_row(i, capture.names[i], r)))
    write_poses(out, dentition, capture.names, results, options)
    seconds = [r.seconds for r in results[len(done):]]
    return {"frames": len(results), "resumed": len(done), "flagged": int(sum(r.flagged for r in results)),
            "head_flagged": int(sum(r.head_flagged for r in results)),
            "restarted": int(sum(r.starts > 1 for r in results)),
            "seconds_per_frame": float(np.mean(seconds)) if seconds else float("nan")}


def write_poses(out, dentition, names, results, options: TrackOptions):
    """The poses file of tracked ``results``: ``poses (N, 4, 4)`` (the jaw, held where flagged: a
    poses file ``facesim jaw fit`` reads), ``reference_point`` (the lower incisal point), ``mandible``
    (points of the lower teeth), ``head``, ``fitted``, ``residual_px``, ``confidence``, ``sigma_mm``,
    ``flagged``, ``head_flagged``, ``seconds``, ``energy_px2``, ``starts``, ``frame_names``, ``meta``
    (JSON: source of the teeth, options)."""
    import dataclasses
    import json

    from facesim._files import atomic_write

    arrays = dict(poses=np.stack([r.jaw for r in results]), head=np.stack([r.head for r in results]),
                  fitted=np.stack([r.fitted for r in results]), reference_point=dentition.incisor,
                  mandible=dentition.mandible_points(),
                  residual_px=np.array([r.residual for r in results]),
                  confidence=np.array([r.confidence for r in results]),
                  sigma_mm=np.array([r.sigma_mm for r in results]),
                  flagged=np.array([r.flagged for r in results]),
                  head_flagged=np.array([r.head_flagged for r in results]),
                  seconds=np.array([r.seconds for r in results]), energy_px2=np.array([r.energy for r in results]),
                  starts=np.array([r.starts for r in results]), frame_names=np.array(list(names)),
                  meta=np.array(json.dumps({"format": "facesim-teeth-poses", "teeth": dentition.source,
                                            "options": dataclasses.asdict(options)})))

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    return atomic_write(out, write)


def _orthonormal(R) -> np.ndarray:
    """The rotation nearest to ``R (3, 3)`` (products of many small steps drift by ~1e-15)."""
    U, _, Vt = np.linalg.svd(R)
    Q = U @ Vt
    if np.linalg.det(Q) < 0:
        U[:, -1] *= -1
        Q = U @ Vt
    return Q


__all__ = ["HINGE_STEPS_DEG", "FrameResult", "TrackOptions", "Tracker", "jaw_starts", "log_path", "track_capture",
           "write_poses"]
