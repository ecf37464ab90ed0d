"""The sparse system of one mesh: which nodes are unknown, the 3x3-block pattern, the scatter
map from element blocks to matrix blocks, and the element colouring. Built once per mesh and
set of fixed nodes; every Newton step assembles into the same arrays."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facesim._arrays import unique_ints
from facesim._kernels.assembly import colour_chunks, dirichlet_rows
from facesim._kernels.elements import rest_shape
from facesim.errors import FacesimError


class RestShape:
    """Rest-state geometry of a tet mesh: ``Bm (m, 3, 3) = Dm^-1`` and volumes ``V0 (m,)`` (mm^3)."""

    def __init__(self, X: np.ndarray, tets: np.ndarray):
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.tets = np.ascontiguousarray(tets, dtype=np.int32)
        if self.X.ndim != 2 or self.X.shape[1] != 3:
            raise FacesimError(f"X: expected shape (n, 3), got {self.X.shape}")
        if self.tets.ndim != 2 or self.tets.shape[1] != 4:
            raise FacesimError(f"tets: expected shape (m, 4), got {self.tets.shape}")
        if len(self.tets) and (self.tets.min() < 0 or self.tets.max() >= len(self.X)):
            raise FacesimError(f"tets: indices must lie in [0, {len(self.X)})")
        self.Bm = np.empty((len(self.tets), 3, 3))
        self.V0 = np.empty(len(self.tets))
        rest_shape(self.X, self.tets, self.Bm, self.V0)
        if np.any(self.V0 <= 0):
            bad = int(np.argmin(self.V0))
            raise FacesimError(f"tets: rest volumes must be positive (tet {bad} has {self.V0[bad]:.3g} mm^3); "
                               "orient every tet so that (x1-x0).((x2-x0)x(x3-x0)) > 0")


#: chunks the elements of a :class:`DofSystem` are cut into for parallel assembly (at most; at least
#: ``MIN_CHUNK`` tets each): a constant, so the colouring does not depend on the thread count
CHUNKS = 64
MIN_CHUNK = 32


def _block_pairs(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 16 (row, column) pairs of each element's ``rows (k, 4)`` (-1: no row), a-major, as
    ``(rr, cc, ok)`` of shape ``(k, 16)``; ``ok`` where both are rows."""
    rr = np.repeat(rows, 4, axis=1)
    cc = np.tile(rows, (1, 4))
    return rr, cc, (rr >= 0) & (cc >= 0)


def _bandwidth_order(rows: np.ndarray, n: int) -> np.ndarray:
    """Reverse Cuthill-McKee order of the ``n`` rows coupled by the elements' ``rows (k, 4)`` (-1:
    no row): ``order[i]`` is the old row that becomes row ``i``."""
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    if n == 0:
        return np.zeros(0, np.int64)
    rr, cc, ok = _block_pairs(rows)
    graph = sp.csr_matrix((np.ones(int(ok.sum()), np.int8), (rr[ok], cc[ok])), shape=(n, n))
    return np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True), dtype=np.int64)


def _coloured_chunks(tets, elems, rows, n_nodes):
    """``(colour_ptr, chunk_ptr, order)`` of :class:`DofSystem`: ``elems`` (their rows ``rows (k,
    4)``, -1: none) sorted by their least and greatest row, cut into up to ``CHUNKS`` chunks of
    equal size, the chunks coloured greedily and grouped by colour; ``order`` the positions in
    ``elems`` in that order. Where that needs too many colours (a mesh that a bandwidth order does
    not narrow), chunks of one tet each, as the tets' own colouring."""
    if len(elems) == 0:
        return np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64)
    r_low = np.where(rows >= 0, rows, np.iinfo(np.int64).max).min(axis=1)
    order = np.lexsort((rows.max(axis=1), r_low))
    elems = np.ascontiguousarray(elems[order], dtype=np.int64)
    n_chunks = int(min(CHUNKS, max(1, len(elems) // MIN_CHUNK)))
    for chunk_ptr in (np.linspace(0, len(elems), n_chunks + 1).astype(np.int64),
                      np.arange(len(elems) + 1, dtype=np.int64)):
        colour = colour_chunks(tets, elems, chunk_ptr, n_nodes)
        if colour[0] >= 0:
            break
    else:
        raise FacesimError("assembly: element colouring needs more than 128 colours (is the mesh valid?)")
    by_colour = np.argsort(colour, kind="stable")
    sizes = np.diff(chunk_ptr)[by_colour]
    # chunk order within a colour and tet order within a chunk kept
    order = order[np.argsort(np.repeat(colour, np.diff(chunk_ptr)), kind="stable")]
    new_ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    colour_ptr = np.searchsorted(colour[by_colour], np.arange(int(colour.max()) + 2)).astype(np.int64)
    return colour_ptr, new_ptr, order


def element_chunks(tets, elems, n_nodes: int):
    """``(colour_ptr, chunk_ptr, order)`` as :class:`DofSystem` makes them, over the nodes rather
    than a system's rows: ``elems`` sorted by their nodes' reverse Cuthill-McKee rank, cut into
    chunks and coloured so that no two chunks of a colour share a node; ``order`` the positions in
    ``elems`` in that order (for a term's gradient, which has no system)."""
    T = np.asarray(tets)[np.asarray(elems, dtype=np.int64)].astype(np.int64)
    rank = np.empty(n_nodes, np.int64)
    rank[_bandwidth_order(T, n_nodes)] = np.arange(n_nodes)
    return _coloured_chunks(tets, np.asarray(elems, dtype=np.int64), rank[T], n_nodes)


class DofSystem:
    """Unknowns and matrix pattern for the elements ``elems`` of a mesh with ``fixed`` components.

    ``fixed (n, 3) bool``: prescribed components. Nodes with all three components prescribed
    are left out of the system; prescribed components of the remaining ("active") nodes keep
    their rows with a unit diagonal, so the matrix stays 3x3-blocked (what AMG wants).

    Attributes: ``tets``; ``active (N,)`` node ids of the system rows, in reverse Cuthill-McKee
    order of the mesh graph (not sorted); ``row_of (n,)`` node -> block row or -1;
    ``fixed_active (N, 3)``; ``indptr, indices`` (BSR pattern); ``chunk_elems`` the elements
    sorted by their first row and cut into chunks ``chunk_elems[chunk_ptr[k]:chunk_ptr[k + 1]]``,
    ``chunk_e2b (k, 4, 4)`` the block index of each one's node pairs or -1, grouped by colour (chunks
    ``colour_ptr[c]:colour_ptr[c + 1]``): no two chunks of a colour share a node, so each colour
    assembles in parallel, and the tets of a chunk, neighbours in the mesh, add into nearby rows.

    Assembly in that order against the tets coloured one by one (each colour a pass over the
    whole matrix, consecutive tets apart): the medium face's true tangent on one thread 1.3 against
    3.0 us a tet (benchmarks/RESULTS.md, session 31).
    """

    def __init__(self, tets: np.ndarray, n_nodes: int, fixed: np.ndarray, elems: np.ndarray):
        tets = np.ascontiguousarray(tets, dtype=np.int32)
        self.tets = tets
        fixed = np.asarray(fixed, dtype=bool)
        if fixed.shape != (n_nodes, 3):
            raise FacesimError(f"fixed: expected a boolean mask of shape ({n_nodes}, 3), got {fixed.shape}")
        self.n_nodes = int(n_nodes)
        self.elems = np.ascontiguousarray(elems, dtype=np.int64)
        used = np.zeros(n_nodes, bool)
        used[tets[self.elems].ravel()] = True
        self.active = np.flatnonzero(used & ~fixed.all(axis=1)).astype(np.int64)
        self.row_of = np.full(n_nodes, -1, np.int64)
        self.row_of[self.active] = np.arange(len(self.active))
        # rows in reverse Cuthill-McKee order: a tet's rows, and its neighbours', close together
        r = self.row_of[tets[self.elems]]
        self.active = self.active[_bandwidth_order(r, len(self.active))]
        self.row_of[self.active] = np.arange(len(self.active))
        self.fixed_active = np.ascontiguousarray(fixed[self.active])
        self.free_dof = ~self.fixed_active.ravel()
        N = len(self.active)
        # pattern: all (row, col) block pairs of active nodes sharing an element
        r = self.row_of[tets[self.elems]]                      # (k, 4)
        rr, cc, ok = _block_pairs(r)                            # (k, 16)
        key = rr.astype(np.int64) * max(N, 1) + cc
        uniq = unique_ints(key[ok])
        rows, cols = uniq // max(N, 1), uniq % max(N, 1)
        self.indptr = np.searchsorted(rows, np.arange(N + 1)).astype(np.int32)
        self.indices = cols.astype(np.int32)
        e2b = np.full(key.shape, -1, np.int32)
        e2b[ok] = np.searchsorted(uniq, key[ok])
        self.colour_ptr, self.chunk_ptr, order = _coloured_chunks(tets, self.elems, r, n_nodes)
        self.chunk_elems = self.elems[order]
        self.chunk_e2b = np.ascontiguousarray(e2b[order].reshape(-1, 4, 4))
        self.n_blocks = len(self.indices)

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.active)

    def new_data(self) -> np.ndarray:
        return np.zeros((self.n_blocks, 3, 3))

    def matrix(self, data: np.ndarray, diag: float = 1.0) -> sp.bsr_matrix:
        """BSR matrix over the active dofs from assembled ``data``, prescribed rows set to ``diag``."""
        dirichlet_rows(self.indptr, self.indices, data, self.fixed_active, float(diag))
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=(self.n_dofs, self.n_dofs))

    def gather(self, g_full: np.ndarray) -> np.ndarray:
        """(n, 3) nodal vector -> (3N,) system vector with prescribed components zeroed."""
        v = g_full[self.active].ravel().copy()
        v[~self.free_dof] = 0.0
        return v

    def scatter(self, x_full: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Positions with the active nodes' free components taken from ``u (3N,)``."""
        x = x_full.copy()
        xa = x[self.active]
        flat = xa.ravel()
        flat[self.free_dof] = u[self.free_dof]
        x[self.active] = flat.reshape(-1, 3)
        return x

    def rigid_modes(self, x: np.ndarray) -> np.ndarray:
        """(3N, 6) rigid-body modes at positions ``x (n, 3)`` (3 translations, 3 rotations), prescribed
        components zeroed: the near-null space AMG needs for elasticity."""
        p = x[self.active] - x[self.active].mean(axis=0)
        N = len(p)
        B = np.zeros((N, 3, 6))
        for k in range(3):
            B[:, k, k] = 1.0
        B[:, 1, 3], B[:, 2, 3] = -p[:, 2], p[:, 1]
        B[:, 0, 4], B[:, 2, 4] = p[:, 2], -p[:, 0]
        B[:, 0, 5], B[:, 1, 5] = -p[:, 1], p[:, 0]
        B = B.reshape(3 * N, 6)
        B[~self.free_dof] = 0.0
        return B
