"""Array helpers numpy has but too slowly for facesim's sizes."""

from __future__ import annotations

import numpy as np


def unique_ints(values) -> np.ndarray:
    """The sorted distinct values of the 1-D integer array ``values`` (as ``np.unique(values)``).

    A sort and a mask: numpy 2.4's ``np.unique`` took 18.7 s on the 13M element-block keys of the
    paper-size face's sparsity pattern, this 0.24 s (benchmarks/RESULTS.md, session 27)."""
    s = np.sort(np.asarray(values).ravel())
    if len(s) == 0:
        return s
    keep = np.empty(len(s), dtype=bool)
    keep[0] = True
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]


__all__ = ["unique_ints"]
