"""Assembly helpers: element colouring and Dirichlet rows in a 3x3-block (BSR) matrix."""

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS

MAX_COLOURS = 128


@njit(**JIT_FLAGS)
def colour_elements(tets, elems, n_nodes):
    """Greedy colouring of the listed tets so that no two tets of a colour share a node.

    Returns ``colour (len(elems),) int32``, or -1 everywhere if more than 128 colours are
    needed (never seen on tet meshes: greedy needs about 20-40).
    """
    used = np.zeros((n_nodes, 2), dtype=np.uint64)
    colour = np.empty(elems.shape[0], dtype=np.int32)
    for i in range(elems.shape[0]):
        t = tets[elems[i]]
        m0 = used[t[0], 0] | used[t[1], 0] | used[t[2], 0] | used[t[3], 0]
        m1 = used[t[0], 1] | used[t[1], 1] | used[t[2], 1] | used[t[3], 1]
        c = -1
        for k in range(64):
            if not (m0 >> np.uint64(k)) & np.uint64(1):
                c = k
                break
        if c < 0:
            for k in range(64):
                if not (m1 >> np.uint64(k)) & np.uint64(1):
                    c = 64 + k
                    break
        if c < 0:
            colour[:] = -1
            return colour
        colour[i] = c
        word = c // 64
        bit = np.uint64(1) << np.uint64(c % 64)
        for a in range(4):
            used[t[a], word] |= bit
    return colour


@njit(**JIT_FLAGS)
def dirichlet_rows(indptr, indices, data, fixed, diag):
    """Zero the rows and columns of fixed components in BSR ``data (nb, 3, 3)`` and put ``diag``
    on their diagonal; ``fixed (N, 3)`` bool over the block rows."""
    for i in range(indptr.shape[0] - 1):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            for k in range(3):
                for m in range(3):
                    if fixed[i, k] or fixed[j, m]:
                        data[p, k, m] = diag if (i == j and k == m) else 0.0
