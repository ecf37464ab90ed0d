"""Simple tet meshes for verification, examples and benchmarks, and point location in a tet mesh."""

from __future__ import annotations

import numpy as np

from facesim._kernels import locate as _locate
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


class TetLocator:
    """Point location in one tet mesh (``X (n, 3)`` mm, ``tets (m, 4)``): the inverse edge
    matrices and a uniform grid over the tets' boxes grown by ``snap`` mm, built once (the
    template transfer, :mod:`facesim.importing.template`; the coarse start's prolongation,
    :mod:`facesim.inverse.coarse`)."""

    def __init__(self, X: np.ndarray, tets: np.ndarray, snap: float):
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.tets = np.ascontiguousarray(tets, dtype=np.int32)
        self.snap = float(snap)
        E = np.transpose(self.X[self.tets[:, 1:]] - self.X[self.tets[:, :1]], (0, 2, 1))   # columns: edges
        self.Tinv = np.ascontiguousarray(np.linalg.inv(E))
        box = np.ptp(self.X[self.tets], axis=1).max(axis=1)
        lo = self.X.min(axis=0) - self.snap - 1e-6
        hi = self.X.max(axis=0) + self.snap + 1e-6
        h = max(float(np.median(box)), float(np.prod(hi - lo) / 4e6) ** (1 / 3))   # at most ~4M cells
        self.origin, self.h = lo, h
        self.shape = np.maximum(np.ceil((hi - lo) / h).astype(np.int64), 1)
        self.ptr, self.idx = _locate.tet_grid(self.X, self.tets, self.snap, self.origin, self.h, self.shape)

    def locate(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(tet (k,) int32, -1 outside; bary (k, 4))`` of the points ``P (k, 3)`` mm."""
        P = np.ascontiguousarray(np.asarray(P, dtype=np.float64).reshape(-1, 3))
        tet = np.empty(len(P), dtype=np.int32)
        bary = np.zeros((len(P), 4))
        _locate.locate_points(P, self.X, self.tets, self.Tinv, self.origin, self.h, self.shape, self.ptr,
                              self.idx, self.snap, tet, bary)
        return tet, bary
