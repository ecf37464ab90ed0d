"""Wall-clock budgets: every solve is bounded in time as well as in iterations.

A budget is a deadline carried in a context variable, so the solvers far down a call chain (a
Newton solve inside a line-search trial inside a Gauss-Newton step inside a tracked frame) see
the deadline of the frame without it being passed through every signature::

    with time_budget(120.0):          # this frame may take two minutes
        fit = fit_frame(...)          # Newton and Gauss-Newton stop with stop_reason "time_limit"

Budgets nest: an inner budget never extends an outer one (the earlier deadline wins), so a
per-solve limit inside a per-frame limit bounds both. ``time_budget(None)`` adds no limit.
Solvers call :func:`expired` between iterations; an iteration itself is never interrupted, so a
frame overruns its budget by at most one iteration (one linear solve).
"""

from __future__ import annotations

import contextvars
import math
import time
from contextlib import contextmanager
from typing import Iterator

from facesim.errors import FacesimError

_DEADLINE: contextvars.ContextVar[float | None] = contextvars.ContextVar("facesim_deadline", default=None)

#: The stop reason of a solve that ran out of its wall-clock budget.
TIME_LIMIT = "time_limit"
#: The default budget of a frame: FRAME_SECONDS plus SECONDS_PER_UNKNOWN per unknown of the mesh
#: (the coarse face 330 s, the paper-size face 1,100 s): a guard against a frame that would never
#: end, several times what the hardest frames take on a busy 2-core machine (a coarse frame with
#: contact, 6 Gauss-Newton steps and 400 Newton iterations: 135 s), not a speed target.
FRAME_SECONDS = 300.0
SECONDS_PER_UNKNOWN = 2e-3


def check_seconds(seconds, what: str = "max seconds per frame") -> float | None:
    """``seconds`` as a float if it is a positive finite number of seconds (None: no limit), else a
    one-line :class:`FacesimError` naming ``what``."""
    if seconds is None:
        return None
    try:
        value = float(seconds)
    except (TypeError, ValueError):
        raise FacesimError(f"{what}: expected a number of seconds > 0, got {seconds!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise FacesimError(f"{what}: expected a number of seconds > 0, got {seconds!r}")
    return value


def default_frame_seconds(model) -> float:
    """The default wall-clock budget of one frame of ``model`` (a FaceModel), s: see
    :data:`FRAME_SECONDS`."""
    free = model.n_nodes - len(model.cranium_nodes) - len(model.jaw_nodes)
    return FRAME_SECONDS + SECONDS_PER_UNKNOWN * 3 * free


@contextmanager
def time_budget(seconds: float | None) -> Iterator[None]:
    """Within the block, :func:`expired` turns true ``seconds`` from now (or at the enclosing
    budget's deadline, if that is earlier). ``None``: only the enclosing budget, if any."""
    seconds = check_seconds(seconds, "time budget")
    outer = _DEADLINE.get()
    deadline = outer if seconds is None else time.monotonic() + seconds
    if outer is not None:
        deadline = min(deadline, outer)
    token = _DEADLINE.set(deadline)
    try:
        yield
    finally:
        _DEADLINE.reset(token)


def expired() -> bool:
    """True when the current budget's deadline has passed (False without a budget)."""
    deadline = _DEADLINE.get()
    return deadline is not None and time.monotonic() >= deadline


def remaining() -> float:
    """Seconds left in the current budget (``inf`` without one; 0 once it has expired)."""
    deadline = _DEADLINE.get()
    return math.inf if deadline is None else max(0.0, deadline - time.monotonic())


__all__ = ["FRAME_SECONDS", "SECONDS_PER_UNKNOWN", "TIME_LIMIT", "check_seconds", "default_frame_seconds", "expired",
           "remaining", "time_budget"]
