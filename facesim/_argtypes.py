"""argparse types for the command groups (``facesim``, ``facesim jaw``, ``facesim teeth``, ...): one
parser per kind of number, so every command words a bad number the same way -- "expected an
integer from 1 to 1000, got 'x'" -- and rejects NaN and infinities."""

from __future__ import annotations

import argparse
import math


def _parser(kind, ok, expected: str):
    def parse(text: str):
        try:
            v = kind(text)
        except (ValueError, OverflowError):
            v = None
        if v is None or not math.isfinite(v) or not ok(v):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v
    return parse


def number(what: str = "a number"):
    """Any finite number."""
    return _parser(float, lambda v: True, what)


def whole(what: str = "a whole number"):
    """Any integer."""
    return _parser(int, lambda v: True, what)


def positive(maximum: float, what: str = "a number"):
    """A finite number > 0 and <= ``maximum``."""
    return _parser(float, lambda v: 0.0 < v <= maximum, f"{what} > 0 and <= {maximum:g}")


def in_range(minimum: float, maximum: float, what: str = "a number"):
    """A finite number from ``minimum`` to ``maximum`` (both included)."""
    return _parser(float, lambda v: minimum <= v <= maximum, f"{what} from {minimum:g} to {maximum:g}")


def integer(minimum: int, maximum: int):
    """An integer from ``minimum`` to ``maximum`` (both included)."""
    return _parser(int, lambda v: minimum <= v <= maximum, f"an integer from {minimum} to {maximum}")


def at_least(minimum, kind=float, maximum=None):
    """A finite ``kind`` (float or int) >= ``minimum`` (and <= ``maximum``)."""
    what = "an integer" if kind is int else "a number"
    upper = "" if maximum is None else f" and <= {maximum:g}"
    return _parser(kind, lambda v: v >= minimum and (maximum is None or v <= maximum),
                   f"{what} >= {minimum:g}{upper}")


__all__ = ["at_least", "in_range", "integer", "number", "positive", "whole"]
