"""Assembly helpers: colouring of element chunks and Dirichlet rows in a 3x3-block (BSR) matrix."""

import numpy as np
from numba import njit

from facesim._kernels import JIT_FLAGS

MAX_COLOURS = 128


@njit(**JIT_FLAGS)
def colour_chunks(tets, elems, chunk_ptr, n_nodes):
    """Greedy colouring of chunks of the listed tets -- chunk ``k`` is
    ``elems[chunk_ptr[k]:chunk_ptr[k + 1]]`` -- so that no two chunks of a colour share a node
    (chunks of one tet each: the tets' own colouring).

    Returns ``colour (n_chunks,) int32``, or -1 everywhere if more than ``MAX_COLOURS`` colours
    are needed (tets one by one: about 20-40; chunks of a bandwidth-ordered mesh: a handful).
    """
    used = np.zeros((n_nodes, 2), dtype=np.uint64)
    n_chunks = chunk_ptr.shape[0] - 1
    colour = np.empty(n_chunks, dtype=np.int32)
    for k in range(n_chunks):
        m0 = np.uint64(0)
        m1 = np.uint64(0)
        for i in range(chunk_ptr[k], chunk_ptr[k + 1]):
            t = tets[elems[i]]
            for a in range(4):
                m0 |= used[t[a], 0]
                m1 |= used[t[a], 1]
        c = -1
        for j in range(64):
            if not (m0 >> np.uint64(j)) & np.uint64(1):
                c = j
                break
        if c < 0:
            for j in range(64):
                if not (m1 >> np.uint64(j)) & np.uint64(1):
                    c = 64 + j
                    break
        if c < 0:
            colour[:] = -1
            return colour
        colour[k] = c
        word = c // 64
        bit = np.uint64(1) << np.uint64(c % 64)
        for i in range(chunk_ptr[k], chunk_ptr[k + 1]):
            t = tets[elems[i]]
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
