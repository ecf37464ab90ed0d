"""Volume cells (tetrahedra, hexahedra, wedges, pyramids) split into conforming, positive tets.

Two cells sharing a quadrilateral face must cut it along the same diagonal, or the tet mesh has
a crack. Every quad face of the mesh therefore gets one diagonal, first the one through its
smallest global node index (the rule of Dompierre et al. 1999, *How to subdivide pyramids,
prisms and hexahedra into tetrahedra*: with it every cell has a split without added nodes), and
every cell is split by the best (largest smallest tet) of the triangulations of its reference
shape that use its faces' diagonals: the 74 triangulations of the cube for a hexahedron (5 or 6
tets), the 6 of the prism for a wedge (3), the 2 of the pyramid (2). A warped cell (non-planar
faces, a corner pushed in) can have no positive split with the diagonals of that rule; then the
diagonals of its faces are changed, one cell at a time, to a combination for which it and its
neighbours all have one. Real meshes need this: the ArtiSynth Badin face has 50 such hexahedra.

Hexahedra collapsed by repeated nodes (a face shrunk to an edge: a wedge; a face shrunk to a
point: a pyramid) are split as the cells they collapse to, so no zero-volume tet is made.

Node order: VTK's, which meshio uses for every format (faces checked against vtkHexahedron,
vtkWedge, vtkPyramid ``GetFace``).
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from facesim.errors import FacesimError

#: Outward faces of each linear cell for positive orientation: (triangles, quads), local nodes.
CELL_FACES = {
    "tetra": ([(1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)], []),
    "hexahedron": ([], [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]),
    "wedge": ([(0, 2, 1), (3, 4, 5)], [(0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)]),
    "pyramid": ([(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)], [(0, 3, 2, 1)]),
}
#: Positively oriented reference shapes, VTK node order.
REFERENCE = {
    "tetra": [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)],
    "hexahedron": [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
    "wedge": [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 1)],
    "pyramid": [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.5, 1)],
}
#: Node orders turning a cell round (its mirror image).
MIRROR = {"tetra": [0, 2, 1, 3], "hexahedron": [0, 3, 2, 1, 4, 7, 6, 5], "wedge": [0, 2, 1, 3, 5, 4],
          "pyramid": [0, 3, 2, 1, 4]}
#: Quadratic cells and the linear cell of their corner nodes (VTK lists the corners first).
QUADRATIC = {"tetra10": "tetra", "hexahedron20": "hexahedron", "hexahedron24": "hexahedron",
             "hexahedron27": "hexahedron", "wedge12": "wedge", "wedge15": "wedge", "wedge18": "wedge",
             "pyramid13": "pyramid", "pyramid14": "pyramid"}
CORNERS = {"tetra": 4, "hexahedron": 8, "wedge": 6, "pyramid": 5}
#: A tet whose volume is at most this share of its cell's mean edge length cubed counts as flat.
FLAT_VOLUME = 1e-7
#: Sweeps of the diagonal repair over the cells still without a positive split, and the most
#: branches one local search of the repair may try.
REPAIR_SWEEPS = 20
SEARCH_BUDGET = 20_000


def tet_volumes(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(t,) signed volumes of ``T (t, 4)`` at ``X (n, 3)``: positive when node 3 lies on the
    side of the right-hand normal of (0, 1, 2)."""
    e = X[T[:, 1:]] - X[T[:, :1]]
    return np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


# ------------------------------------------------------------------ reference triangulations
@functools.cache
def triangulations(kind: str) -> tuple[tuple[np.ndarray, int], ...]:
    """Every triangulation of the reference ``kind`` by its own corners: ``(tets (k, 4) local,
    positively oriented; code)``, bit q of the code set when quad q of ``CELL_FACES[kind]`` is
    cut along its local nodes 1-3 instead of 0-2. The cube has 74 (De Loera, Rambau, Santos,
    *Triangulations*, 2010), the prism 6, the pyramid 2, the tet 1.

    Found by an exact cover, with corner tets, of random points of the shape (each tet covers
    the points inside it, each point covered once), every cover kept only if it is
    face-to-face and fills the shape's volume.
    """
    C = np.asarray(REFERENCE[kind], dtype=float)
    tris, quads = CELL_FACES[kind]
    planes = []
    for f in [*tris, *quads]:
        n = np.cross(C[f[1]] - C[f[0]], C[f[2]] - C[f[0]])
        planes.append((n / np.linalg.norm(n), float(n @ C[f[0]] / np.linalg.norm(n))))
    volume = sum(np.linalg.det(C[list(t[1:])] - C[t[0]]) for t in _cone(len(C), tris, quads)) / 6.0
    cands = []
    for q in itertools.combinations(range(len(C)), 4):
        v = np.linalg.det(C[list(q[1:])] - C[q[0]])
        if abs(v) > 1e-9:
            cands.append(q if v > 0 else (q[0], q[2], q[1], q[3]))
    S = np.random.default_rng(1).random((3000, 3))
    S = S[np.all([S @ n <= d for n, d in planes], axis=0)]
    masks = []
    for t in cands:
        P = C[list(t)]
        b = (S - P[0]) @ np.linalg.inv((P[1:] - P[0]).T).T
        inside = (b > 0).all(axis=1) & (b.sum(axis=1) < 1)
        masks.append(sum(1 << int(i) for i in np.flatnonzero(inside)))
    full = (1 << len(S)) - 1
    by_point = [[k for k, m in enumerate(masks) if m >> i & 1] for i in range(len(S))]
    found = []

    def cover(covered: int, chosen: tuple[int, ...]):
        if covered == full:
            found.append(chosen)
            return
        free = ~covered & full
        i = (free & -free).bit_length() - 1
        for k in by_point[i]:
            if not masks[k] & covered:
                cover(covered | masks[k], chosen + (k,))

    cover(0, ())
    out = []
    for sol in found:
        T = np.array([cands[k] for k in sol], dtype=np.int64)
        if abs(sum(np.linalg.det(C[t[1:]] - C[t[0]]) for t in T) / 6.0 - volume) > 1e-9:
            continue
        key = np.sort(T[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
        u, n = np.unique(key, axis=0, return_counts=True)
        on_face = np.array([any(np.allclose(C[f] @ pn, pd) for pn, pd in planes) for f in u])
        if (n > 2).any() or not on_face[n == 1].all():
            continue
        edges = {tuple(sorted(e)) for t in T for e in itertools.combinations(t, 2)}
        code = sum(1 << j for j, q in enumerate(quads) if tuple(sorted((q[1], q[3]))) in edges)
        out.append((T, code))
    return tuple(out)


def _cone(n: int, tris, quads) -> list[tuple[int, ...]]:
    """Tets of the reference cell coned from node 0 (for its volume only)."""
    faces = list(tris) + [q[:3] for q in quads] + [(q[0], q[2], q[3]) for q in quads]
    return [(0, *f) for f in faces if 0 not in f]


# --------------------------------------------------------------------- collapsed hexahedra
@functools.cache
def _cube_rotations() -> np.ndarray:
    """(24, 8) the node permutations of the VTK hexahedron under the cube's rotations."""
    C = np.asarray(REFERENCE["hexahedron"], dtype=float) - 0.5
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            R = np.zeros((3, 3))
            R[range(3), perm] = signs
            if np.linalg.det(R) < 0:
                continue
            image = C @ R.T
            out.append([int(np.argmin(np.abs(C - p).sum(axis=1))) for p in image])
    return np.array(out)


def collapse(cells: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    """Hexahedra ``cells (c, 8)`` with repeated nodes as the cells they collapse to.

    A face shrunk to an edge (its two opposite edges collapsed) makes a wedge, a face shrunk to
    a point a pyramid. Returns ``(cells by kind, index into cells by kind, unmatched (u,) indices
    of collapsed hexahedra of any other pattern)``; hexahedra without repeated nodes stay
    hexahedra."""
    cells = np.asarray(cells, dtype=np.int64)
    s = np.sort(cells, axis=1)
    repeated = (s[:, 1:] == s[:, :-1]).any(axis=1)
    out = {"hexahedron": cells[~repeated]}
    index = {"hexahedron": np.flatnonzero(~repeated)}
    todo = np.flatnonzero(repeated)
    distinct = lambda a: (np.sort(a, axis=1)[:, 1:] != np.sort(a, axis=1)[:, :-1]).all(axis=1)  # noqa: E731
    wedges, wi, pyramids, pi = [], [], [], []
    for r in _cube_rotations():
        if not len(todo):
            break
        H = cells[todo][:, r]
        w = (H[:, 2] == H[:, 3]) & (H[:, 6] == H[:, 7]) & distinct(H[:, [0, 1, 2, 4, 5, 6]])
        p = (H[:, 4] == H[:, 5]) & (H[:, 5] == H[:, 6]) & (H[:, 6] == H[:, 7]) & distinct(H[:, :5])
        wedges.append(H[w][:, [0, 1, 2, 4, 5, 6]])
        wi.append(todo[w])
        pyramids.append(H[p][:, :5])
        pi.append(todo[p])
        todo = todo[~(w | p)]
    if wedges and sum(len(w) for w in wedges):
        out["wedge"], index["wedge"] = np.concatenate(wedges), np.concatenate(wi)
    if pyramids and sum(len(p) for p in pyramids):
        out["pyramid"], index["pyramid"] = np.concatenate(pyramids), np.concatenate(pi)
    return out, index, todo


# ----------------------------------------------------------------------------- the split
def _quad_keys(cells: np.ndarray, kind: str) -> np.ndarray:
    """(c, q, 4) node ids of each cell's quads, local order."""
    quads = CELL_FACES[kind][1]
    return cells[:, quads] if quads else np.zeros((len(cells), 0, 4), np.int64)


def _values(X: np.ndarray, cells: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """For every cell and every diagonal code: the largest smallest tet volume of the kind's
    triangulations with that code (-inf if none) and which triangulation gives it:
    ``(value (c, 2^q), which (c, 2^q) int)``."""
    tri = triangulations(kind)
    nq = len(CELL_FACES[kind][1])
    value = np.full((len(cells), 1 << nq), -np.inf)
    which = np.zeros((len(cells), 1 << nq), np.int64)
    for k, (T, code) in enumerate(tri):
        vmin = tet_volumes(X, cells[:, T].reshape(-1, 4)).reshape(len(cells), -1).min(axis=1)
        better = vmin > value[:, code]
        value[better, code] = vmin[better]
        which[better, code] = k
    return value, which


def cell_volumes(X: np.ndarray, cells: np.ndarray, kind: str) -> np.ndarray:
    """(c,) signed volumes of the cells ``cells (c, k)`` of ``kind``: cones from the mean of their
    nodes over their outward faces, each quad taken as the mean of its two triangle pairs (so no
    diagonal is preferred; exact for planar faces)."""
    tris, quads = CELL_FACES[kind]
    P = X[cells]
    c = P.mean(axis=1)

    def cone(a, b, d):
        return np.einsum("ij,ij->i", P[:, a] - c, np.cross(P[:, b] - c, P[:, d] - c)) / 6.0

    v = sum((cone(*t) for t in tris), np.zeros(len(cells)))
    for q0, q1, q2, q3 in quads:
        v += 0.5 * (cone(q0, q1, q2) + cone(q0, q2, q3) + cone(q1, q2, q3) + cone(q1, q3, q0))
    return v


def _size(X: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(c,) a length per cell: the mean distance of its nodes from their centre, times 2."""
    P = X[cells]
    return 2.0 * np.linalg.norm(P - P.mean(axis=1, keepdims=True), axis=2).mean(axis=1)


def tetrahedralise(X: np.ndarray, blocks, path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Conforming, positively oriented tets of the volume cells ``blocks`` (list of ``(kind,
    cells (c, k) int)``, VTK order) on nodes ``X (n, 3)``; see the module docstring.

    A cell type whose cells are *all* negatively oriented is turned round (a file written in the
    mirror-image node order) and said in the notes. Refused with one line naming ``path``, how
    many cells and the first (cells numbered over the blocks in order): inverted cells
    (negative volume), cells of no volume, hexahedra collapsed other than to a wedge or a
    pyramid, faces shared by more than two cells, and cells with no positive conforming split.

    Returns ``(tets (t, 4) int64, cell (t,) int64 the cell of each tet, notes)``.
    """
    X = np.asarray(X, dtype=np.float64)
    notes = []
    n_cells = sum(len(d) for _, d in blocks)
    groups = []                                        # (kind, cells, original index)
    offset = 0
    for kind, data in blocks:
        data = np.asarray(data, dtype=np.int64)
        index = offset + np.arange(len(data))
        offset += len(data)
        if kind == "hexahedron":
            by_kind, idx, odd = collapse(data)
            if len(odd):
                raise FacesimError(f"{path}: {len(odd):,} hexahedra have repeated nodes that collapse them to no "
                                   f"wedge or pyramid (first: cell {int(index[odd[0]])})")
            n_w = len(by_kind.get("wedge", ())) + len(by_kind.get("pyramid", ()))
            if n_w:
                notes.append(f"{n_w:,} hexahedra with repeated nodes split as the wedges or pyramids they collapse to")
            parts = [(k, by_kind[k], index[idx[k]]) for k in by_kind]
        else:
            s = np.sort(data, axis=1)
            odd = np.flatnonzero((s[:, 1:] == s[:, :-1]).any(axis=1))
            if len(odd):
                raise FacesimError(f"{path}: {len(odd):,} {kind} cells have repeated nodes (first: cell {int(index[odd[0]])})")
            parts = [(kind, data, index)]
        # orientation: the cell volumes; a type all negative is turned round
        vols = [cell_volumes(X, c, k) for k, c, _ in parts]
        if len(data) and all((v < 0).all() for v in vols):
            notes.append(f"all {len(data):,} {kind} cells are negatively oriented (mirror-image node order): turned round")
            parts = [(k, c[:, MIRROR[k]], i) for k, c, i in parts]
            vols = [-v for v in vols]
        for (k, c, i), v in zip(parts, vols):
            flat = np.abs(v) <= FLAT_VOLUME * _size(X, c) ** 3
            for bad, what in ((~flat & (v < 0), "are inverted (negative volume"), (flat, "have no volume (")):
                if bad.any():
                    first = int(np.min(i[bad]))
                    raise FacesimError(f"{path}: {int(bad.sum()):,} of {n_cells:,} volume cells {what}; first: cell "
                                       f"{first}, {_kind_of(blocks, first)})")
            groups.append((k, c, i))
    T, cell, n_changed, n_cells_changed = _split_conforming(X, groups, path)
    counts = ", ".join(f"{len(d):,} {k}" for k, d in blocks)
    notes.append(f"split {counts} cells into {len(T):,} tets (conforming: each quad face cut along one diagonal)")
    if n_changed:
        notes.append(f"{n_cells_changed:,} warped cells needed other face diagonals than the smallest-node rule's "
                     f"({n_changed:,} faces changed) to split into positive tets")
    return T, cell, notes


def _kind_of(blocks, index: int) -> str:
    for kind, data in blocks:
        if index < len(data):
            return f"a {kind}"
        index -= len(data)
    return "?"


def _split_conforming(X, groups, path):
    """The tets of ``groups`` (list of ``(kind, cells, original index)``, positive cells) with
    one diagonal per quad face; see the module docstring."""
    # every quad face of the mesh, its cells and its smallest-node diagonal
    keys, owner, local = [], [], []
    for g, (kind, cells, _) in enumerate(groups):
        Q = _quad_keys(cells, kind)
        keys.append(np.sort(Q, axis=2).reshape(-1, 4))
        owner.append(np.c_[np.full(Q.shape[0] * Q.shape[1], g), np.repeat(np.arange(len(cells)), Q.shape[1])])
        local.append(np.tile(np.arange(Q.shape[1]), len(cells)))
    keys = np.concatenate(keys) if keys else np.zeros((0, 4), np.int64)
    owner = np.concatenate(owner) if owner else np.zeros((0, 2), np.int64)
    local = np.concatenate(local) if local else np.zeros(0, np.int64)
    if len(keys):
        _, face, count = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        face = face.ravel()
        if (count > 2).any():
            f = int(np.argmax(count > 2))
            raise FacesimError(f"{path}: {int((count > 2).sum()):,} faces are shared by more than two cells "
                               f"(first: the face of nodes {', '.join(map(str, keys[np.argmax(face == f)]))})")
    else:
        face, count = np.zeros(0, np.int64), np.zeros(0, np.int64)
    flip = np.zeros(len(count), bool)                      # False: the diagonal through the smallest node
    # per group: face ids (c, q), the smallest-node local bit (c, q), values, tolerances
    state = []
    pos = 0
    for kind, cells, _ in groups:
        Q = _quad_keys(cells, kind)
        nq = Q.shape[1]
        fid = face[pos:pos + Q.size // 4].reshape(len(cells), nq)
        pos += Q.size // 4
        mbit = (np.argmin(Q, axis=2) % 2).astype(np.int64) if nq else np.zeros((len(cells), 0), np.int64)
        value, which = _values(X, cells, kind)
        tiny = FLAT_VOLUME * _size(X, cells) ** 3
        state.append((fid, mbit, value, which, tiny))

    def codes(g, rows):
        fid, mbit, *_ = state[g]
        bits = mbit[rows] ^ flip[fid[rows]]
        return (bits << np.arange(bits.shape[1])).sum(axis=1) if bits.shape[1] else np.zeros(len(rows), np.int64)

    def ok(g, rows):
        _, _, value, _, tiny = state[g]
        return value[rows, codes(g, rows)] > tiny[rows]

    # the (group, row) of the up to two cells of each face, -1 where there is none
    face_cells = np.full((len(count), 2, 2), -1, np.int64)
    o = np.argsort(face, kind="stable")
    fs = face[o]
    first = np.r_[True, fs[1:] != fs[:-1]] if len(fs) else np.zeros(0, bool)
    face_cells[fs[first], 0] = owner[o[first]]
    face_cells[fs[~first], 1] = owner[o[~first]]
    def faces_of(g, r):
        return [int(f) for f in state[g][0][r]]

    def neighbours(g, r):
        return {(int(a), int(b)) for f in faces_of(g, r) for a, b in face_cells[f] if a >= 0 and (a, b) != (g, r)}

    def solve(free):
        """Diagonals for the faces ``free`` (a few dozen at most) after which every cell on them has
        a positive split, as the list of faces to change (few, not always the fewest); None if
        there are none. A depth-first search over the faces, keeping each one's diagonal first,
        that drops a branch as soon as some cell on the faces set so far has no positive split
        whatever its other free faces get."""
        free = sorted(free)
        at = {f: i for i, f in enumerate(free)}
        constraints = []                                # (free slots, table of allowed bit patterns)
        for g, r in {(int(a), int(b)) for f in free for a, b in face_cells[f] if a >= 0}:
            fid, mbit, value, _, tiny = state[g]
            nq = fid.shape[1]
            base = (mbit[r] ^ flip[fid[r]]).astype(np.int64)
            slots = [q for q in range(nq) if int(fid[r, q]) in at]
            pats = ((np.arange(1 << len(slots))[:, None] >> np.arange(len(slots))) & 1).astype(np.int64)
            B = np.broadcast_to(base, (len(pats), nq)).copy()
            B[:, slots] ^= pats
            allowed = value[r, (B << np.arange(nq)).sum(axis=1)] > tiny[r]
            constraints.append(([at[int(fid[r, q])] for q in slots], pats[allowed]))
        if any(len(t) == 0 for _, t in constraints):
            return None
        choice = np.full(len(free), -1, np.int64)
        by_var = [[k for k, (v, _) in enumerate(constraints) if i in v] for i in range(len(free))]

        def consistent(i):
            for k in by_var[i]:
                v, table = constraints[k]
                sel = choice[v]
                known = sel >= 0
                if not (table[:, known] == sel[known]).all(axis=1).any():
                    return False
            return True

        budget = [SEARCH_BUDGET]

        def search(i):
            if i == len(free):
                return True
            budget[0] -= 1
            if budget[0] < 0:
                return False
            for bit in (0, 1):
                choice[i] = bit
                if consistent(i) and search(i + 1):
                    return True
            choice[i] = -1
            return False

        if not search(0):
            return None
        return [f for i, f in enumerate(free) if choice[i]]

    changed_faces, changed_cells = set(), set()
    for _ in range(REPAIR_SWEEPS):
        bad = [(g, int(r)) for g in range(len(groups)) for r in np.flatnonzero(~ok(g, np.arange(len(groups[g][1]))))]
        if not bad:
            break
        progress = False
        for g, r in bad:                               # the few warped cells, not every cell
            if ok(g, np.array([r]))[0]:
                continue
            # the cell's own faces first, then those of the cells up to one and two faces away
            ring, tries = {(g, r)}, []
            for _ in range(3):
                tries.append({f for c in ring for f in faces_of(*c)})
                ring = ring | {n for c in ring for n in neighbours(*c)}
            for free in tries:
                change = solve(free)
                if change is not None:
                    flip[change] ^= True
                    changed_faces.symmetric_difference_update(change)
                    changed_cells.add((g, r))
                    progress = True
                    break
        if not progress:
            break
    tets, cell = [], []
    for g, (kind, cells, index) in enumerate(groups):
        rows = np.arange(len(cells))
        good = ok(g, rows)
        if not good.all():
            first = int(np.min(index[~good]))
            raise FacesimError(f"{path}: {int((~good).sum()):,} volume cells are too distorted to split into positive tets "
                               f"that conform with their neighbours (first: cell {first})")
        _, _, _, which, _ = state[g]
        k = which[rows, codes(g, rows)]
        for j, (T, _) in enumerate(triangulations(kind)):
            hit = np.flatnonzero(k == j)
            if len(hit):
                tets.append(cells[hit][:, T].reshape(-1, 4))
                cell.append(np.repeat(index[hit], len(T)))
    T = np.concatenate(tets).astype(np.int64)
    cell = np.concatenate(cell).astype(np.int64)
    order = np.argsort(cell, kind="stable")
    return T[order], cell[order], len(changed_faces), len(changed_cells)
