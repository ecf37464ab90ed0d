"""From implicit head fields to a labelled flesh tet mesh.

Steps: marching cubes on the flesh field -> pytetwild (fTetWild) tetrahedralisation, finer in
the simulated face than in the attached back of the head -> positive orientation -> boundary
faces labelled by the part they lie on (skin, mouth lining, cranium, mandible, eye, joint) ->
bone attachments -> simulated region and tissue labels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytetwild
from scipy import ndimage
from skimage import measure

from facesim.anatomy import sdf
from facesim.anatomy.phantom import HeadFields
from facesim.errors import FacesimError
from facesim.model import positively_oriented, signed_volumes

#: Boundary-face labels.
SKIN, MOUTH, CRANIUM, JAW, EYE, JOINT, CUT = range(7)
LABEL_NAMES = ("skin", "mouth", "cranium", "jaw", "eye", "joint", "cut")


def isosurface(field: np.ndarray, grid: sdf.Grid, smooth_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Zero level set of ``field`` as ``(vertices (k, 3) float64 mm, faces (l, 3) int32)``, outward oriented."""
    f = ndimage.gaussian_filter(field, smooth_mm / grid.h) if smooth_mm > 0 else field
    if f.min() >= 0 or f.max() <= 0:
        raise FacesimError("isosurface: the field has no zero crossing on the grid")
    # pad with 'outside' so every surface closes
    f = np.pad(f, 1, constant_values=max(float(f.max()), 1.0))
    v, faces, _, _ = measure.marching_cubes(f, 0.0, spacing=(grid.h,) * 3, gradient_direction="ascent")
    v = v + np.asarray(grid.lo) - grid.h
    # marching cubes winds faces toward increasing values; flip so normals point outward
    return v.astype(np.float64), np.ascontiguousarray(faces[:, ::-1], dtype=np.int32)


def _sizing_mesh(lo, hi, step: float, size_fn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A structured background tet mesh over the box ``[lo, hi]`` with target edge lengths ``size_fn(points)``."""
    axes = [np.arange(a - step, b + 2 * step, step) for a, b in zip(lo, hi)]
    n = [len(a) for a in axes]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    idx = np.arange(P.shape[0]).reshape(n)
    c = [idx[i:n[0] - 1 + i, j:n[1] - 1 + j, k:n[2] - 1 + k].ravel() for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    # Kuhn split of every cube into six tets (consistent across neighbours)
    v000, v001, v010, v011, v100, v101, v110, v111 = c
    tets = np.concatenate([
        np.stack(t, 1) for t in (
            (v000, v100, v110, v111), (v000, v100, v101, v111), (v000, v001, v101, v111),
            (v000, v001, v011, v111), (v000, v010, v011, v111), (v000, v010, v110, v111))
    ]).astype(np.int32)
    return P, tets, np.asarray(size_fn(P), float)


def tetrahedralise(vertices, faces, edge_face: float, edge_back: float, simulated_fn, epsilon: float = 1.5e-3,
                   threads: int = 0):
    """fTetWild on a closed surface; target edge ``edge_face`` mm where ``simulated_fn(p)`` holds, else ``edge_back``.

    Returns ``(X (n, 3) float64, tets (m, 4) int32)`` with positive orientation and no unused nodes.
    fTetWild is not bit-reproducible between runs (wildmeshing/fTetWild#72); everything the
    builder derives from a given tet mesh is.
    """
    lo, hi = vertices.min(0), vertices.max(0)
    bgP, bgT, bgV = _sizing_mesh(lo, hi, 6.0, lambda p: np.where(simulated_fn(p), edge_face, edge_back))
    # fTetWild writes a scratch file (__tracked_surface.stl) into the working directory
    import os
    import tempfile

    cwd = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="facesim_tetwild_") as tmp:
        os.chdir(tmp)
        try:
            X, T = pytetwild.tetrahedralize(vertices, faces, edge_length_abs=edge_face, epsilon=epsilon,
                                            num_threads=threads, bg_vertices=bgP, bg_tets=bgT, bg_values=bgV)
        finally:
            os.chdir(cwd)
    X = np.asarray(X, np.float64)
    T = np.asarray(T, np.int32)
    used, inv = np.unique(T, return_inverse=True)
    X, T = X[used], inv.reshape(T.shape).astype(np.int32)
    return split_pinched_nodes(X, positively_oriented(X, T))


def check_tet_mesh(X, T) -> tuple[np.ndarray, np.ndarray]:
    """Validate a given tet mesh: ``X (n, 3)`` finite, ``T (m, 4)`` indices in range, positive volumes."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    T = np.ascontiguousarray(T, dtype=np.int32)
    if X.ndim != 2 or X.shape[1] != 3 or not np.isfinite(X).all():
        raise FacesimError(f"mesh: expected finite node positions of shape (n, 3), got {X.shape}")
    if T.ndim != 2 or T.shape[1] != 4 or len(T) == 0 or T.min() < 0 or T.max() >= len(X):
        raise FacesimError(f"mesh: expected tets of shape (m, 4) indexing {len(X)} nodes")
    if np.any(signed_volumes(X, T) <= 0):
        raise FacesimError("mesh: expected positively oriented tets with non-zero volume")
    return X, T


def refine_tets(X: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Uniform 1:8 ("red") refinement of the tet mesh ``X (n, 3)``, ``T (m, 4)``: a node at the
    midpoint of every edge, four corner tets per tet and the inner octahedron cut along its
    shortest diagonal into four more (the best-shaped of the three choices, so the quality stays
    bounded under repeated refinement). Every child has an eighth of its parent's volume and
    positive orientation; the boundary stays the same surface. Deterministic: a way to a finer
    model that does not run fTetWild again (``facesim model build --mesh-from M.npz --refine``).
    Returns ``(X (n + edges, 3), T (8 m, 4) int32)``; tet ``8 k + j`` is a child of tet ``k``."""
    X = np.asarray(X, dtype=np.float64)
    T = np.asarray(T, dtype=np.int64)
    pairs = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
    edges = np.sort(T[:, pairs].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mid = len(X) + inverse.reshape(-1, 6)                 # midpoint node of each tet's six edges
    Xr = np.concatenate([X, 0.5 * (X[unique[:, 0]] + X[unique[:, 1]])])
    v0, v1, v2, v3 = T.T
    m01, m02, m03, m12, m13, m23 = mid.T
    corners = [(v0, m01, m02, m03), (m01, v1, m12, m13), (m02, m12, v2, m23), (m03, m13, m23, v3)]
    # the octahedron's three diagonals, each with its equator as a cycle (opposite pairs apart)
    diagonals = [((m01, m23), (m02, m03, m13, m12)), ((m02, m13), (m01, m03, m23, m12)),
                 ((m03, m12), (m01, m02, m23, m13))]
    length = np.stack([np.linalg.norm(Xr[a] - Xr[b], axis=1) for (a, b), _ in diagonals], axis=1)
    pick = np.argmin(length, axis=1)
    inner = []
    for q in range(4):
        cols = []
        for slot in range(4):
            choice = [(a, b, ring[q], ring[(q + 1) % 4])[slot] for (a, b), ring in diagonals]
            cols.append(np.choose(pick, choice))
        inner.append(tuple(cols))
    Tr = np.stack([np.stack(t, axis=1) for t in corners + inner], axis=1).reshape(-1, 4)
    return Xr, positively_oriented(Xr, Tr.astype(np.int32))


def split_pinched_nodes(X: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Give every node one copy per face-connected fan of its tets.

    Where the envelope lets fTetWild close a thin gap (the lip slit at the mouth corners), two
    parts of the flesh can touch at a single node or edge: a non-manifold pinch that would glue
    the lips together. Tets around a node that share a face containing it stay on one copy;
    tets that only meet at the node (or an edge through it) get separate copies.
    Returns ``(X (n', 3), T (m, 4))`` with ``n' >= n``; unchanged when nothing is pinched.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(T)
    local = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    # incidence id of (tet t, local corner k) is 4 t + k
    faces = T[:, local].reshape(-1, 3)
    corners = (4 * np.arange(m)[:, None, None] + local[None]).reshape(-1, 3)
    key = np.sort(faces, axis=1)
    order = np.lexsort(key.T[::-1])
    ks = key[order]
    same = np.all(ks[1:] == ks[:-1], axis=1)
    f1, f2 = order[:-1][same], order[1:][same]
    # match the corners of the two copies of each interior face by node id
    rows, cols = [], []
    for a in range(3):
        node = faces[f1, a]
        for b in range(3):
            hit = faces[f2, b] == node
            rows.append(corners[f1, a][hit])
            cols.append(corners[f2, b][hit])
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(4 * m, 4 * m))
    n_comp, comp = connected_components(g, directed=False)
    node_of = T.ravel()
    if n_comp == len(np.unique(node_of)):
        return X, T
    # one new node per component, numbered in order of the original node (then component)
    first = np.full(n_comp, -1, np.int64)
    first[comp[::-1]] = node_of[::-1]
    order = np.lexsort((np.arange(n_comp), first))
    new_id = np.empty(n_comp, np.int64)
    new_id[order] = np.arange(n_comp)
    return X[first[order]].copy(), new_id[comp].reshape(T.shape).astype(np.int32)


def boundary_faces(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces used by exactly one tet, outward oriented for positive tets: ``(faces (b, 3), tet (b,))``."""
    # the face opposite vertex k, ordered so its normal points away from vertex k
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    F = T[:, local].reshape(-1, 3)
    owner = np.repeat(np.arange(len(T)), 4)
    key = np.sort(F, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    once = first[counts == 1]
    once.sort()
    return F[once].astype(np.int32), owner[once]


def face_components(faces: np.ndarray) -> np.ndarray:
    """Connected-component label per face (faces sharing an edge are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    fid = np.repeat(np.arange(len(faces)), 3)
    _, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    a, b = fid[order][:-1], fid[order][1:]
    same = inv[order][:-1] == inv[order][1:]
    g = coo_matrix((np.ones(same.sum()), (a[same], b[same])), shape=(len(faces), len(faces)))
    return connected_components(g, directed=False)[1]


def is_closed_manifold(faces: np.ndarray) -> bool:
    """Every edge shared by exactly two faces, with opposite orientations."""
    if len(faces) == 0:
        return False
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    und = np.sort(directed, axis=1)
    _, counts = np.unique(und, axis=0, return_counts=True)
    if not np.all(counts == 2):
        return False
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    return bool(np.all(dcounts == 1))


@dataclass(frozen=True)
class LabelledMesh:
    X: np.ndarray
    tets: np.ndarray
    faces: np.ndarray          # (b, 3) boundary faces
    face_label: np.ndarray     # (b,) one of SKIN..JOINT
    skin: np.ndarray           # (s, 3) the closed outer surface
    cranium_nodes: np.ndarray
    jaw_nodes: np.ndarray
    simulated: np.ndarray


def label_boundary(X, faces, fields: HeadFields) -> np.ndarray:
    """Which part every boundary face lies on: the part field closest to zero at its centroid."""
    c = X[faces].mean(axis=1)
    g = fields.grid
    dist = np.stack([
        np.abs(g.sample(fields.skin, c)),
        np.abs(g.sample(fields.mouth, c)),
        np.abs(g.sample(fields.cranium, c)),
        np.abs(g.sample(fields.jaw, c)),
        np.abs(g.sample(fields.eyes, c)),
        np.abs(g.sample(fields.joint, c)),
        np.abs(g.sample(fields.crop, c)) if fields.crop is not None else np.full(len(c), np.inf),
    ], axis=1)
    return np.argmin(dist, axis=1).astype(np.int8)


def label_mesh(X, T, fields: HeadFields, simulated_fn) -> LabelledMesh:
    faces, _ = boundary_faces(T)
    lab = label_boundary(X, faces, fields)
    comp = face_components(faces)
    # the skin: outer skin, the mouth lining it folds into and the flat neck cut that closes it,
    # in the component holding most skin
    counts = np.bincount(comp[lab == SKIN], minlength=comp.max() + 1)
    outer = int(np.argmax(counts))
    skin = faces[(comp == outer) & ((lab == SKIN) | (lab == MOUTH) | (lab == CUT))]
    simulated = simulated_fn(X[T].mean(axis=1))
    jaw_nodes = np.unique(faces[lab == JAW])
    # flesh on the mandible is always simulated: the attached region moves with the cranium only
    on_jaw = np.zeros(len(X), bool)
    on_jaw[jaw_nodes] = True
    simulated |= on_jaw[T].any(axis=1)
    cran = np.zeros(len(X), bool)
    cran[np.unique(faces[lab == CRANIUM])] = True
    cran[np.unique(T[~simulated])] = True
    cran[np.unique(faces[lab == CUT])] = True   # the neck cut is held by the cranium
    cran[jaw_nodes] = False
    return LabelledMesh(X=X, tets=T, faces=faces, face_label=lab, skin=skin,
                        cranium_nodes=np.flatnonzero(cran).astype(np.int32),
                        jaw_nodes=jaw_nodes.astype(np.int32), simulated=simulated)
