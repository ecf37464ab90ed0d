"""Head markers of an imported model chosen by how little the face moves them.

Head markers stabilise a capture (``solve-mocap`` fits the head's rigid motion to them), so they
must sit where the skin does not move with the expression or the jaw. On the template they do
(the forehead, the nose bridge, the temples over the skull); carried onto a subject's anatomy they
may not: a face mask has no forehead, and skin over a temple that the subject's bones leave free
moves with the jaw. Measured on the ArtiSynth Badin face: its carried temple markers move 1.0 mm
when the jaw opens 0.12 rad, and a head stabilised on them leaves 1 mm RMS that no control
explains (the solve then recovers the wrong muscles).

So the importer measures it: the implicit Jacobian of the marker positions at rest with respect to
every control (:func:`facesim.inverse.jacobian.equilibrium_jacobian`, one factorisation), each
column scaled by its control's range (activation 0..1, the jaw's parameter bounds), gives each
marker's largest linearised motion under the jaw and under any one muscle. The jaw is what
disqualifies: it moves in every capture, while a head marker's motion under the few muscles that
reach it (the frontalis lifts the template's own forehead markers by up to 3 mm) is what the
solver already expects of head markers. A carried head marker is kept when the jaw moves it at
most :data:`HEAD_MOTION_MM` over its whole range; when fewer than three are, the markers (off the
lips and chin) the jaw moves that little and the muscles least are added, spread out (the largest
triangle), so the model always has three head markers, and the report says which and how far
each moves.
"""

from __future__ import annotations

import numpy as np

#: a head marker may move this much under any single control at its full range, mm
HEAD_MOTION_MM = 0.25
#: markers whose name says they are on the lips or the mouth corners never become head markers
_MOBILE = ("lip", "mouth", "chin", "jaw")
#: head markers are added from this many of the stillest candidates, the most spread out of them
POOL = 6


def marker_motion(model) -> tuple[np.ndarray, np.ndarray]:
    """``(n_markers,)`` mm twice: each marker's largest linearised displacement at rest under one
    jaw control moved over its whole range (the sliding-condyle jaw's opening and slides over their
    bounds), and under one muscle from activation 0 to 1."""
    from facesim.controls import Controls
    from facesim.fem.equilibrium import FaceSimulator
    from facesim.inverse.jacobian import ControlSpace, equilibrium_jacobian

    sim = FaceSimulator(model, jaw_model="sliding-condyle")
    jm = sim.jaw_model
    space = ControlSpace.of(sim, jaw=True)
    rest = Controls(np.zeros(model.n_muscles), jaw=np.asarray(jm.rest, dtype=np.float64))
    J = equilibrium_jacobian(sim, rest, model.X, space=space)
    lo, hi = np.asarray(jm.bounds, dtype=np.float64).T
    ranges = np.concatenate([np.ones(model.n_muscles), np.maximum(hi - jm.rest, jm.rest - lo)])
    D = np.linalg.norm(J.dP.reshape(model.n_markers, 3, -1) * ranges[None, None, :], axis=1)
    return D[:, model.n_muscles:].max(axis=1), D[:, :model.n_muscles].max(axis=1)


def _spread(points: np.ndarray, pool: list[int], fixed: list[int], count: int) -> list[int]:
    """Greedily add ``count - len(fixed)`` of ``pool`` to ``fixed`` maximising the spread (first the
    farthest from the chosen ones, then the largest triangle)."""
    chosen = list(fixed)
    while len(chosen) < count and pool:
        rest = [i for i in pool if i not in chosen]
        if not rest:
            break
        if len(chosen) < 2:
            ref = points[chosen] if chosen else points[rest].mean(axis=0, keepdims=True)
            score = [np.linalg.norm(points[i] - ref, axis=1).min() for i in rest]
        else:
            a, b = points[chosen[0]], points[chosen[1]]
            score = [np.linalg.norm(np.cross(b - a, points[i] - a)) for i in rest]
        chosen.append(rest[int(np.argmax(score))])
    return chosen


def choose_head_markers(model, limit_mm: float = HEAD_MOTION_MM) -> tuple[np.ndarray, dict]:
    """The head flags ``(n_markers,) bool`` for ``model`` (module docstring) and a report:
    ``{"kept": {name: {"jaw_mm", "muscles_mm"}}, "dropped": {...}, "added": {...}, "limit_mm": ..}``."""
    jaw, muscles = marker_motion(model)
    names = list(model.markers.names)
    old = np.asarray(model.markers.head, dtype=bool)
    still = jaw <= limit_mm
    kept = [i for i in np.flatnonzero(old & still)]
    order = np.lexsort((muscles, ~still))          # still under the jaw first, then by the muscles' motion
    candidates = [i for i in order if not old[i] and not any(w in names[i].lower() for w in _MOBILE)]
    head = list(kept)
    if len(head) < 3:
        # the most spread out of the POOL candidates the jaw leaves still and the muscles move least
        pool = candidates[:POOL]
        pos = model.marker_positions()
        head = _spread(pos, pool, head, 3)
    flags = np.zeros(len(names), dtype=bool)
    flags[head] = True
    r = lambda i: {"jaw_mm": round(float(jaw[i]), 3), "muscles_mm": round(float(muscles[i]), 3)}  # noqa: E731
    report = {"limit_mm": limit_mm,
              "kept": {names[i]: r(i) for i in kept},
              "dropped": {names[i]: r(i) for i in np.flatnonzero(old & ~flags)},
              "added": {names[i]: r(i) for i in head if i not in kept}}
    return flags, report
