"""Editing performances in activation space (Sifakis, Neverov, Fedkiw 2005, section 9).

Every in-between of two captured expressions is physically attainable, because the face simulated
at interpolated controls is an equilibrium like any other: the edits below act on the controls
(:class:`~facesim.anim.sequence.ControlsSequence`) and leave the physics to the simulator.

* :func:`blend` -- ``(1 - t) a + t b`` frame by frame (``t`` scalar or per frame);
* :func:`keyframes` -- a sequence through expressions at given frames, ``linear``, ``smoothstep``
  or ``catmull-rom`` (:mod:`facesim.anim.curves`);
* :func:`scale` -- exaggerate or de-emphasise: activations times a factor, clamped to [0, 1];
* :func:`gain` -- beyond what activation 1 can do: the per-muscle scale of the active
  force-length curve (Fig. 8 of the paper: unscaled, doubled, quadrupled);
* :func:`splice`, :func:`concatenate` -- segments of solved sequences one after the other, with an
  optional crossfade;
* :func:`retime` -- resample to another frame rate;
* :func:`mirror` (:mod:`facesim.anim.symmetry`) -- left for right.

Controls of each kind are interpolated where they live: activations in [0, 1] (clamped, since
Catmull-Rom overshoots), jaw parameters in the jaw model's own parameters (clamped to its
bounds), rigid jaw poses and head poses on SE(3) (:mod:`facesim.se3`'s log and exp maps).

Sequences combined must be alike: the same model (muscles), the same jaw model, the same frame
rate, the same gains (apply :func:`gain` after combining), head poses in both or in neither, and
the same recorded contact set-up (a source without one, a CSV file, takes the other's). Each
operation returns a new sequence; every mistake is a one-line :class:`FacesimError`.
"""

from __future__ import annotations

import json
import math

import numpy as np

from facesim.anim.curves import blend_poses, check_method, interpolate_poses, interpolate_values, scale_poses
from facesim.anim.sequence import ControlsSequence, muscle_indices
from facesim.errors import FacesimError

#: the largest scale and gain factor: beyond, every activation is 1 and every face torn (a typo)
MAX_FACTOR = 100.0


# ------------------------------------------------------------------ checks
def _contact(setup: str):
    """The contact part of a recorded set-up (teeth, lips, stiffness N/mm^3, colliders), None unknown."""
    if not setup:
        return None
    d = json.loads(setup)
    return (bool(d.get("teeth_contact")), bool(d.get("lip_contact")), d.get("contact_stiffness"),
            len(d.get("colliders") or []))


def _describe_contact(c) -> str:
    teeth, lips, stiffness, colliders = c
    on = [name for name, flag in (("teeth", teeth), ("lips", lips)) if flag]
    return f"contact {'+'.join(on) or 'off'}, stiffness {stiffness}, {colliders} collider(s)"


def compatible(seqs, what: str, labels=None) -> dict:
    """Check that ``seqs`` can be combined (module doc); returns the merged record fields
    (``setup``, ``rebound``) of the result. ``what`` starts the messages, ``labels`` name the
    sequences in them (default "sequence 1", ...)."""
    seqs = list(seqs)
    labels = labels or [f"sequence {j + 1}" for j in range(len(seqs))]
    first, a = seqs[0], labels[0]
    for s, b in zip(seqs[1:], labels[1:]):
        if s.muscles != first.muscles or s.model_parts != first.model_parts:
            raise FacesimError(f"{what}: {b} is for another model than {a}; expected controls of one model")
        if s.jaw_model != first.jaw_model:
            other = "another" if s.jaw_model.name == first.jaw_model.name else "the"
            raise FacesimError(f"{what}: {b} is for {other} {s.jaw_model.name!r} jaw model, {a} for the "
                               f"{first.jaw_model.name!r} one; expected the same jaw model (the controls of one mean "
                               "nothing in another)")
        if s.fps != first.fps:
            raise FacesimError(f"{what}: {b} is at {s.fps:g} Hz, {a} at {first.fps:g} Hz; expected the same frame "
                               "rate (retime one first)")
        if not np.array_equal(s.gain, first.gain):
            j = int(np.flatnonzero(s.gain != first.gain)[0])
            raise FacesimError(f"{what}: {b} has gain {s.gain[j]:g} on {s.muscles[j]}, {a} {first.gain[j]:g}; "
                               "expected the same gains (apply the gain after combining)")
        if (s.head is None) != (first.head is None):
            has, hasnt = (a, b) if s.head is None else (b, a)
            raise FacesimError(f"{what}: {has} has head poses (head.csv: a solve-mocap --head solve run) and {hasnt} "
                               "none; expected both or neither (they are in different frames)")
    known = [c for c in (_contact(s.setup) for s in seqs) if c is not None]
    for c in known[1:]:
        if c != known[0]:
            raise FacesimError(f"{what}: the sources were solved with different contact set-ups "
                               f"({_describe_contact(known[0])} and {_describe_contact(c)}); expected one set-up to "
                               "simulate the result with")
    setup = next((s.setup for s in seqs if s.setup), "")
    return {"setup": setup, "rebound": any(s.rebound for s in seqs)}


def _weights(t, n: int, what: str) -> np.ndarray:
    """``t`` as ``(n,)`` weights in [0, 1]: a scalar for every frame, or one per frame."""
    w = np.asarray(t, dtype=np.float64)
    if w.ndim == 0:
        w = np.full(n, float(w))
    if w.shape != (n,):
        raise FacesimError(f"{what}: {w.size} values for {n} frames; expected one number, or one per frame")
    bad = np.flatnonzero(~((w >= 0.0) & (w <= 1.0)))   # NaN fails too
    if len(bad):
        raise FacesimError(f"{what} = {w[bad[0]]:g} outside [0, 1]" + (f" (frame row {bad[0]})" if n > 1 else ""))
    return w


def _factor(factor, what: str, zero: bool) -> float:
    try:
        f = float(factor)
    except (TypeError, ValueError):
        raise FacesimError(f"{what}: expected a number, got {factor!r}") from None
    low_ok = f >= 0.0 if zero else f > 0.0
    if not (low_ok and f <= MAX_FACTOR):   # NaN fails too
        low = "0 <=" if zero else "0 <"
        raise FacesimError(f"{what}: expected {low} factor <= {MAX_FACTOR:g}, got {factor}")
    return f


def _frame_count(value, what: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not float(value).is_integer() or int(value) < minimum:
        raise FacesimError(f"{what}: expected a whole number of frames >= {minimum}, got {value}")
    return int(value)


def _clip_jaw(seq: ControlsSequence, q) -> np.ndarray:
    lo, hi = seq.jaw_model.bounds.T
    return np.clip(q, lo, hi)


def _poses(seq: ControlsSequence) -> np.ndarray:
    """The rigid jaw poses of ``seq``, the identity for a jaw at rest (None)."""
    return np.broadcast_to(np.eye(4), (seq.n_frames, 4, 4)) if seq.jaw is None else seq.jaw


# ------------------------------------------------------------------ blend and keyframes
def blend(a: ControlsSequence, b: ControlsSequence, t) -> ControlsSequence:
    """``(1 - t) a + t b``, frame by frame: activations (clamped to [0, 1]), jaw parameters
    (clamped to the bounds), rigid jaw and head poses along the SE(3) geodesic. ``t`` in [0, 1]:
    one number, or one per frame ``(F,)``. ``a`` and ``b`` have the same number of frames, or one
    of them a single frame (an expression, blended into every frame of the other); the frame
    numbers are those of ``a`` (of ``b`` when ``a`` is the single frame). Two single frames with
    ``t (n,)``: the ``n`` in-betweens of the two expressions, numbered from ``a``'s frame on.
    ``t = 0`` gives ``a``'s controls and ``t = 1`` ``b``'s, bit for bit."""
    merged = compatible([a, b], "blend", ["a", "b"])
    if a.n_frames == b.n_frames == 1 and np.ndim(t) == 1:   # two expressions: one frame per weight
        n = len(t)
        frames, ia, ib = a.frames[0] + np.arange(n), np.zeros(n, int), np.zeros(n, int)
    elif a.n_frames == b.n_frames:
        frames, ia, ib = a.frames, np.arange(a.n_frames), np.arange(b.n_frames)
    elif b.n_frames == 1:
        frames, ia, ib = a.frames, np.arange(a.n_frames), np.zeros(a.n_frames, int)
    elif a.n_frames == 1:
        frames, ia, ib = b.frames, np.zeros(b.n_frames, int), np.arange(b.n_frames)
    else:
        raise FacesimError(f"blend: a has {a.n_frames} frames, b {b.n_frames}; expected the same number, or a single "
                           "frame in one of them (retime or cut a segment first)")
    w = _weights(t, len(frames), "blend: t")
    A = np.clip((1.0 - w)[:, None] * a.A[ia] + w[:, None] * b.A[ib], 0.0, 1.0)
    if a.jaw_model.posed:
        jaw = None if a.jaw is None and b.jaw is None else blend_poses(_poses(a)[ia], _poses(b)[ib], w)
    else:
        jaw = _clip_jaw(a, (1.0 - w)[:, None] * a.jaw[ia] + w[:, None] * b.jaw[ib])
    head = None if a.head is None else blend_poses(a.head[ia], b.head[ib], w)
    return a.replace(frames=frames, A=A, jaw=jaw, head=head, **merged)


def _sample(seq: ControlsSequence, times, A, jaw, head, query, method: str):
    """Activations, jaw and head at ``query`` of the curves through the keys ``(times, A, jaw,
    head)`` of ``seq``'s kinds, clamped."""
    A = np.clip(interpolate_values(times, A, query, method), 0.0, 1.0)
    if seq.jaw_model.posed:
        jaw = None if jaw is None else interpolate_poses(times, jaw, query, method)
    else:
        jaw = _clip_jaw(seq, interpolate_values(times, jaw, query, method))
    head = None if head is None else interpolate_poses(times, head, query, method)
    return A, jaw, head


def keyframes(keys, times, method: str = "linear") -> ControlsSequence:
    """A sequence through the expressions ``keys`` (single-frame sequences, e.g. ``seq.at(k)`` of
    solved ones) at the frame numbers ``times`` (increasing integers >= 0), one frame per frame
    number from ``times[0]`` to ``times[-1]``; ``method`` ``linear``, ``smoothstep`` or
    ``catmull-rom`` (:mod:`facesim.anim.curves`). Each key's controls are reached exactly at its
    frame."""
    keys = list(keys)
    check_method(method)
    if not keys:
        raise FacesimError("keyframes: expected at least one key")
    for j, k in enumerate(keys):
        if k.n_frames != 1:
            raise FacesimError(f"keyframes: key {j + 1} has {k.n_frames} frames; expected one expression per key "
                               "(pick one frame of a sequence)")
    t = np.asarray(times)
    if t.shape != (len(keys),):
        raise FacesimError(f"keyframes: {t.size} frame numbers for {len(keys)} keys; expected one per key")
    if t.dtype.kind not in "iuf" or not np.all(t == np.round(t)) or t.min() < 0 or np.any(np.diff(t) <= 0):
        raise FacesimError(f"keyframes: frame numbers {', '.join(map(str, t.tolist()))}; expected increasing "
                           "integers >= 0")
    merged = compatible(keys, "keyframes", [f"key {j + 1}" for j in range(len(keys))])
    first = keys[0]
    query = np.arange(int(t[0]), int(t[-1]) + 1)
    jaw = None
    if not first.jaw_model.posed:
        jaw = np.concatenate([k.jaw for k in keys])
    elif any(k.jaw is not None for k in keys):
        jaw = np.concatenate([_poses(k) for k in keys])
    head = None if first.head is None else np.concatenate([k.head for k in keys])
    A, jaw, head = _sample(first, t.astype(np.float64), np.concatenate([k.A for k in keys]), jaw, head, query, method)
    return first.replace(frames=query, A=A, jaw=jaw, head=head, **merged)


# ------------------------------------------------------------------ scale and gain
def scale(seq: ControlsSequence, factor: float, muscles=None, jaw: bool = False) -> ControlsSequence:
    """Exaggerate (factor > 1) or de-emphasise (< 1) the activations of ``muscles`` (names, or base
    names for both sides; default all): ``factor * a``, clamped to [0, 1]. ``jaw``: also scale the
    jaw's motion from rest (parameters ``rest + factor (q - rest)`` clamped to the bounds; rigid
    poses ``exp(factor log T)``). ``factor`` in [0, 100]; 1 returns the controls bit for bit, 0
    the rest activations (and, with ``jaw``, the jaw at rest: the rest face)."""
    f = _factor(factor, "scale", zero=True)
    idx = muscle_indices(seq, muscles)
    A = np.array(seq.A)
    A[:, idx] = np.clip(f * A[:, idx], 0.0, 1.0)
    q = seq.jaw
    if jaw and f != 1.0 and q is not None:
        if seq.jaw_model.posed:
            q = scale_poses(q, f)
        else:
            rest = seq.jaw_model.rest
            q = _clip_jaw(seq, rest + f * (q - rest))
    return seq.replace(A=A, jaw=q)


def gain(seq: ControlsSequence, factor: float, muscles=None) -> ControlsSequence:
    """Set the gain of ``muscles`` (names or base names; default all) to ``factor`` in (0, 100]: the
    scale of each one's active force-length curve, so activation 1 pulls ``factor`` times as hard
    (Sifakis 2005 Fig. 8: 2 doubled, 4 quadrupled) -- beyond what any activation reaches. The
    simulator applies it (``facesim.simulate.simulate(gain=...)``); the activations stay."""
    f = _factor(factor, "gain", zero=False)
    g = np.array(seq.gain)
    g[muscle_indices(seq, muscles)] = f
    return seq.replace(gain=g)


# ------------------------------------------------------------------ splice, concatenate, retime
def _join(pieces) -> dict:
    """The fields of the pieces' frames one after the other (frames already numbered)."""
    first = pieces[0]
    if first.jaw_model.posed:
        jaw = None if all(p.jaw is None for p in pieces) else np.concatenate([_poses(p) for p in pieces])
    else:
        jaw = np.concatenate([p.jaw for p in pieces])
    return {"frames": np.concatenate([p.frames for p in pieces]), "A": np.concatenate([p.A for p in pieces]),
            "jaw": jaw, "head": None if first.head is None else np.concatenate([p.head for p in pieces])}


def splice(a: ControlsSequence, b: ControlsSequence, at: int, crossfade: int = 0) -> ControlsSequence:
    """``a`` until frame ``at``, then ``b``: the frames of ``a`` numbered below ``at``, then every
    frame of ``b`` renumbered to start at ``at`` (its spacing kept). With ``crossfade = k`` frames,
    the first ``k`` frames of ``b`` are blended with the ``k`` frames of ``a`` from ``at`` on, the
    weight of ``b`` ramping ``1/(k+1), ..., k/(k+1)``, so neither end jumps; ``a`` must have them."""
    merged = compatible([a, b], "splice", ["a", "b"])
    k = _frame_count(crossfade, "splice: crossfade")
    at = _frame_count(at, "splice: at")
    keep = np.flatnonzero(a.frames < at)
    if not len(keep):
        raise FacesimError(f"splice: no frame of a before frame {at} (a starts at frame {a.frames[0]}); expected a "
                           "frame after a's first")
    after = np.flatnonzero(a.frames >= at)
    if len(after) < k:
        raise FacesimError(f"splice: a crossfade of {k} frames from frame {at} needs {k} frames of a from there; a "
                           f"has {len(after)} (it ends at frame {a.frames[-1]})")
    if b.n_frames < k:
        raise FacesimError(f"splice: a crossfade of {k} frames needs {k} frames of b; b has {b.n_frames}")
    b = b.replace(frames=at + (b.frames - b.frames[0]))
    pieces = [a.rows(keep)]
    if k:
        ramp = np.arange(1, k + 1) / (k + 1.0)
        faded = blend(a.rows(after[:k]), b.rows(slice(0, k)), ramp)
        pieces.append(faded.replace(frames=b.frames[:k]))
    if b.n_frames > k:
        pieces.append(b.rows(slice(k, None)))
    return a.replace(**_join(pieces), **merged)


def concatenate(seqs, crossfade: int = 0) -> ControlsSequence:
    """The sequences one after the other: each starts the frame after the previous one ends, or,
    with ``crossfade = k``, overlaps its last ``k`` frames (blended as in :func:`splice`)."""
    seqs = list(seqs)
    if not seqs:
        raise FacesimError("concatenate: expected at least one sequence")
    k = _frame_count(crossfade, "concatenate: crossfade")
    compatible(seqs, "concatenate")
    out = seqs[0]
    for j, s in enumerate(seqs[1:], 2):
        if k and out.n_frames <= k:
            raise FacesimError(f"concatenate: a crossfade of {k} frames needs more than {k} frames before sequence "
                               f"{j}; there are {out.n_frames}")
        if k and s.n_frames < k:
            raise FacesimError(f"concatenate: a crossfade of {k} frames needs {k} frames of sequence {j}; it has "
                               f"{s.n_frames}")
        out = splice(out, s, int(out.frames[-k]) if k else int(out.frames[-1]) + 1, k)
    return out


def retime(seq: ControlsSequence, fps: float, method: str = "linear") -> ControlsSequence:
    """``seq`` resampled at ``fps`` Hz (frame ``f`` at time ``f / fps`` s, as in the source): one
    frame per new frame number from the one at or before the source's first time to the one at or
    after its last, each the interpolation (``method``, as :func:`keyframes`) of the source's
    frames at its time, clamped to the source's time span -- so the first and last frames are the
    source's first and last controls, and at the times both rates share the values are the
    source's, bit for bit. Gaps in the source's frame numbers are interpolated across."""
    check_method(method)
    try:
        rate = float(fps)
    except (TypeError, ValueError):
        rate = math.nan
    if not (math.isfinite(rate) and rate > 0):
        raise FacesimError(f"retime: expected a frame rate > 0 Hz, got {fps}")
    src = seq.frames.astype(np.float64)
    # in the source's frame units, exact where both rates share a time (integer products and quotients)
    first = math.floor(src[0] * rate / seq.fps + 1e-9)
    last = math.ceil(src[-1] * rate / seq.fps - 1e-9)
    frames = np.arange(first, last + 1)
    query = np.clip(frames * seq.fps / rate, src[0], src[-1])
    A, jaw, head = _sample(seq, src, seq.A, seq.jaw, seq.head, query, method)
    return seq.replace(frames=frames, fps=rate, A=A, jaw=jaw, head=head)


__all__ = ["MAX_FACTOR", "blend", "compatible", "concatenate", "gain", "keyframes", "retime", "scale", "splice"]
