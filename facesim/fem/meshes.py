"""Simple tet meshes for verification, examples and benchmarks."""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError
from facesim.model import positively_oriented


def box_mesh(size=(1.0, 1.0, 1.0), cells=(4, 4, 4), origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Structured tet mesh of a box: ``cells`` cubes per axis, each split into six tets (Kuhn).

    Returns ``X ((nx+1)(ny+1)(nz+1), 3) float64`` and ``tets (6 nx ny nz, 4) int32``, positively
    oriented. Node ``(i, j, k)`` has index ``(i (ny+1) + j)(nz+1) + k``.
    """
    nx, ny, nz = (int(c) for c in cells)
    if min(nx, ny, nz) < 1:
        raise FacesimError(f"cells: expected at least one cell per axis, got {cells}")
    axes = [o + np.linspace(0.0, s, c + 1) for o, s, c in zip(origin, size, (nx, ny, nz))]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(len(X)).reshape(nx + 1, ny + 1, nz + 1)
    c = {(i, j, k): idx[i:nx + i, j:ny + j, k:nz + k].ravel() for i in (0, 1) for j in (0, 1) for k in (0, 1)}
    o, d = c[0, 0, 0], c[1, 1, 1]
    paths = []
    for a, b in (((1, 0, 0), (1, 1, 0)), ((1, 0, 0), (1, 0, 1)), ((0, 1, 0), (1, 1, 0)),
                 ((0, 1, 0), (0, 1, 1)), ((0, 0, 1), (1, 0, 1)), ((0, 0, 1), (0, 1, 1))):
        paths.append(np.stack([o, c[a], c[b], d], 1))
    return X, positively_oriented(X, np.concatenate(paths).astype(np.int32))
