"""User meshes in: surfaces and volumes read, cleaned, repaired, split into tets, scaled and checked.

* :func:`read_surface` -- any surface trimesh or meshio reads (OBJ, PLY, STL, OFF, GLB, VTK/VTU
  surfaces, ...) as a :class:`Surface`: duplicate vertices merged, degenerate and duplicate
  faces dropped, winding made consistent and closed surfaces turned outward (trimesh), holes
  and non-manifold edges reported. :func:`repair_surface` closes holes (trimesh, then MeshFix).
* :func:`read_volume` -- a volume mesh of tetrahedra, hexahedra, wedges and pyramids (any format
  meshio reads) as a :class:`Volume` of positively oriented, conforming tets.
  :func:`volume_boundary` is its outward boundary.
* :func:`infer_units` -- metres, centimetres or millimetres from the size of the anatomy.
* :func:`split_skin` -- a flesh volume's boundary cut into the outer skin and the inner surface
  lying on the bones.
* :func:`check_anatomy` -- bones that cut through the skin, a skin that does not enclose them.

Units: a :class:`Surface` or :class:`Volume` keeps the file's units; :func:`infer_units` gives
the factor to millimetres. :func:`split_skin` and :func:`check_anatomy` work in mm.

Every failure is a one-line :class:`~facesim.errors.FacesimError` naming the file and what was
wrong with it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np
from scipy.spatial import cKDTree

from facesim.anatomy.meshing import boundary_faces, face_components, is_closed_manifold
from facesim.importing.cells import CELL_FACES, CORNERS, QUADRATIC, tet_volumes, tetrahedralise
from facesim.errors import FacesimError

#: Relative tolerance (of the bounding-box diagonal) under which two vertices are one.
MERGE_TOLERANCE = 1e-8
#: A triangle with less area than this share of the bounding-box diagonal squared is degenerate.
DEGENERATE_AREA = 1e-14
#: Fewest faces a surface may keep after cleaning.
MIN_FACES = 4


# ===================================================================================== surfaces
@dataclass(frozen=True)
class Surface:
    """A triangle surface read from a user's file.

    vertices : (n, 3) float64, in the file's units (see :func:`infer_units`).
    faces : (m, 3) int64, indices into ``vertices``; consistently wound, outward if closed.
    path : str, the file it came from (for messages).
    role : str, what it is in the face: ``"skin"``, ``"mandible"``, ``"cranium"``,
        ``"teeth_upper"``, ``"teeth_lower"``, ...
    closed : bool, every edge shared by exactly two faces with opposite orientations.
    repairs : tuple[str, ...], one human-readable line per repair made or problem found.
    """

    vertices: np.ndarray
    faces: np.ndarray
    path: str
    role: str
    closed: bool
    repairs: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        """The file name, for messages."""
        return Path(self.path).name

    def transformed(self, T: np.ndarray, scale: float = 1.0) -> "Surface":
        """A copy with vertices ``scale * v`` moved by the rigid 4x4 ``T`` (e.g. input units to
        mm in facesim's frame)."""
        V = (scale * self.vertices) @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]
        return dataclasses.replace(self, vertices=V)

    def face_normals(self) -> np.ndarray:
        """(m, 3) unit face normals (right-hand rule of the winding); zero for degenerate faces."""
        return _unit(_cross_faces(self.vertices, self.faces))

    def area(self) -> float:
        """Total area, file units squared."""
        return float(0.5 * np.linalg.norm(_cross_faces(self.vertices, self.faces), axis=1).sum())


def _cross_faces(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    T = V[F]
    return np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, 3) unit vertex normals of the surface ``(V, F)``: the area-weighted mean of the faces'
    normals (zero at unused vertices)."""
    vn = np.zeros_like(np.asarray(V, dtype=np.float64))
    np.add.at(vn, np.asarray(F).ravel(), np.repeat(_cross_faces(V, F), 3, axis=0))
    return _unit(vn)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:160]}" if text else type(exc).__name__


def _load_trimesh(path: Path):
    """(vertices, faces) through trimesh, or raise."""
    import trimesh

    mesh = trimesh.load(str(path), force="mesh", process=False, skip_materials=True)
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"trimesh read a {type(mesh).__name__}, not a triangle mesh")
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def _load_meshio(path: Path, role: str):
    """(vertices, faces) through meshio (triangles, and quads split in two), or raise."""
    import meshio

    m = meshio.read(str(path))
    tris = [np.asarray(c.data, dtype=np.int64) for c in m.cells if c.type == "triangle"]
    quads = [np.asarray(c.data, dtype=np.int64) for c in m.cells if c.type == "quad"]
    tris += [q[:, [0, 1, 2]] for q in quads] + [q[:, [0, 2, 3]] for q in quads]
    if not tris:
        kinds = sorted({c.type for c in m.cells})
        volume = set(kinds) & {"tetra", "hexahedron", "wedge", "pyramid"}
        hint = " (a volume mesh: give it as the flesh volume)" if volume else ""
        raise FacesimError(f"{path}: no triangles for the {role} surface; found cells {', '.join(kinds) or 'none'}{hint}")
    return np.asarray(m.points, dtype=np.float64)[:, :3], np.concatenate(tris)


#: Suffixes trimesh reads itself; anything else goes to meshio first.
_TRIMESH_SUFFIXES = {".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".3mf", ".dae", ".xaml"}


def _read_any(path: Path, role: str) -> tuple[np.ndarray, np.ndarray]:
    readers = [_load_trimesh, lambda p: _load_meshio(p, role)]
    if path.suffix.lower() not in _TRIMESH_SUFFIXES:
        readers.reverse()
    errors = []
    for reader in readers:
        try:
            V, F = reader(path)
        except FacesimError:
            raise
        except (Exception, SystemExit) as exc:  # noqa: BLE001 (parsers raise anything; meshio's PLY reader exits)
            errors.append(_first_line(exc))
            continue
        if len(F):
            return V, F
        errors.append("no triangles")
    raise FacesimError(f"{path}: cannot read the {role} surface as a mesh ({'; '.join(errors)})")


def read_surface(path, role: str) -> Surface:
    """Read the surface mesh at ``path`` (its ``role`` in the face names it in messages).

    Reads any format trimesh or meshio reads. Then, each step listed in ``Surface.repairs``:
    vertices closer than ``MERGE_TOLERANCE`` x the bounding-box diagonal merged, faces with a
    repeated vertex or no area and repeated faces dropped, unused vertices dropped, winding
    made consistent (trimesh), a closed surface turned outward (positive enclosed volume per
    closed component). Holes (boundary loops) and non-manifold edges are reported there too.
    Refused (one-line :class:`FacesimError` naming the file): a missing or unreadable file, no
    triangles, non-finite coordinates, indices out of range, fewer than ``MIN_FACES`` faces.
    """
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such file (expected the {role} surface mesh)")
    V, F = _read_any(path, role)
    if F.ndim != 2 or F.shape[1] != 3:
        raise FacesimError(f"{path}: expected triangles, got faces of shape {F.shape}")
    if F.min() < 0 or F.max() >= len(V):
        raise FacesimError(f"{path}: face indices must lie in [0, {len(V)}), got [{F.min()}, {F.max()}]")
    return clean_surface(V, F, path, role)


def clean_surface(V, F, path, role: str, repairs: Sequence[str] = ()) -> Surface:
    """The cleaning of :func:`read_surface` on arrays ``V (n, 3)``, ``F (m, 3)`` (e.g. a skin cut
    from a volume's boundary); ``path`` names their source in messages."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    repairs = list(repairs)
    used, F = np.unique(F, return_inverse=True)
    F = F.reshape(-1, 3)
    if len(used) < len(V):
        repairs.append(f"dropped {len(V) - len(used):,} unused vertices")
    bad = ~np.isfinite(V[used]).all(axis=1)
    if bad.any():
        raise FacesimError(f"{path}: {int(bad.sum()):,} of {len(V):,} vertices have non-finite coordinates "
                           f"(first: vertex {int(used[np.argmax(bad)])})")
    V = V[used]
    # merge coincident vertices (texture seams of OBJ, the triangle soup of STL)
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    q = max(diag * MERGE_TOLERANCE, np.finfo(float).tiny)
    _, first, inverse = np.unique(np.round(V / q), axis=0, return_index=True, return_inverse=True)
    if len(first) < len(V):
        repairs.append(f"merged {len(V) - len(first):,} duplicate vertices")
    F = inverse.ravel()[F]
    V = V[first]
    # drop faces with a repeated vertex, no area, or seen before
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    flat = ~rep & (np.linalg.norm(_cross_faces(V, F), axis=1) <= DEGENERATE_AREA * diag * diag)
    if rep.any() or flat.any():
        repairs.append(f"dropped {int(rep.sum() + flat.sum()):,} degenerate faces")
    F = F[~rep & ~flat]
    _, keep = np.unique(np.sort(F, axis=1), axis=0, return_index=True)
    if len(keep) < len(F):
        repairs.append(f"dropped {len(F) - len(keep):,} duplicate faces")
    F = F[np.sort(keep)]
    if len(F) < MIN_FACES:
        raise FacesimError(f"{path}: the {role} surface has {len(F)} usable faces, expected at least {MIN_FACES}")
    used, F = np.unique(F, return_inverse=True)
    F = F.reshape(-1, 3).astype(np.int64)
    V = V[used]
    F, notes = _orient(V, F)
    repairs += notes
    return Surface(vertices=V, faces=F, path=str(path), role=role, closed=is_closed_manifold(F),
                   repairs=tuple(repairs))


def edge_use(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(edges (e, 2) sorted vertex pairs, count (e,) faces using each)`` of the triangles ``F``."""
    e = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def boundary_loops(F: np.ndarray) -> list[np.ndarray]:
    """The holes of the surface ``F (m, 3)``: one array of vertex indices per connected set of
    boundary edges (edges used by one face), largest first."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges, count = edge_use(F)
    b = edges[count == 1]
    if not len(b):
        return []
    nodes, inv = np.unique(b, return_inverse=True)
    inv = inv.reshape(-1, 2)
    g = coo_matrix((np.ones(len(b)), (inv[:, 0], inv[:, 1])), shape=(len(nodes), len(nodes)))
    _, label = connected_components(g, directed=False)
    order = np.argsort(-np.bincount(label), kind="stable")
    return [nodes[label == k] for k in order]


def _orient(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Consistent winding per connected component (trimesh), closed components outward;
    returns ``(faces, report lines)``, holes and non-manifold edges among the lines."""
    import trimesh

    notes = []
    edges, count = edge_use(F)
    nonmanifold = int((count > 2).sum())
    mesh = trimesh.Trimesh(V, F.copy(), process=False, validate=False)
    before = np.sort(F, axis=1)
    try:
        trimesh.repair.fix_winding(mesh)
        if mesh.is_watertight:
            trimesh.repair.fix_normals(mesh, multibody=True)
    except Exception as exc:  # noqa: BLE001 (a library failure leaves the winding as read, reported)
        notes.append(f"could not make the winding consistent ({_first_line(exc)})")
    G = np.asarray(mesh.faces, dtype=np.int64)
    if G.shape == F.shape and np.array_equal(np.sort(G, axis=1), before):
        flipped = int((_cyclic_key(G) != _cyclic_key(F)).any(axis=1).sum())
        if flipped:
            notes.append(f"reversed {flipped:,} faces (consistent winding{', outward' if mesh.is_watertight else ''})")
        F = G
    if not mesh.is_winding_consistent and not nonmanifold:
        notes.append("winding cannot be made consistent (a one-sided surface such as a Moebius strip?)")
    loops = boundary_loops(F)
    if loops:
        sizes = ", ".join(str(len(l)) for l in loops[:6]) + (", ..." if len(loops) > 6 else "")
        notes.append(f"open: {len(loops)} hole{'s' if len(loops) > 1 else ''} (boundary loops of {sizes} edges)")
    if nonmanifold:
        notes.append(f"non-manifold: {nonmanifold:,} edges shared by more than two faces")
    n_comp = int(face_components(F).max()) + 1
    if n_comp > 1:
        notes.append(f"{n_comp} separate pieces")
    return F, notes


def _cyclic_key(F: np.ndarray) -> np.ndarray:
    """Each face rotated to start at its smallest index (same winding, comparable)."""
    k = np.argmin(F, axis=1)
    idx = (k[:, None] + np.arange(3)) % 3
    return np.take_along_axis(F, idx, axis=1)


def repair_surface(surface: Surface, close: bool = True) -> Surface:
    """A copy of ``surface`` with its holes closed where a well-kept library can do it.

    First trimesh's ``fill_holes`` (triangulates each boundary loop); if holes remain, MeshFix
    (``pymeshfix``) on each piece that is still open, all of its pieces kept. The lines of
    ``repairs`` say what was done and what could not be; a surface that stays open is returned
    open (``closed`` False), for the caller to refuse or accept. ``close=False`` returns the
    surface unchanged.
    """
    if not close or surface.closed:
        return surface
    import trimesh

    repairs = list(surface.repairs)
    n_holes = len(boundary_loops(surface.faces))
    mesh = trimesh.Trimesh(surface.vertices.copy(), surface.faces.copy(), process=False, validate=False)
    try:
        trimesh.repair.fill_holes(mesh)
    except Exception as exc:  # noqa: BLE001
        repairs.append(f"trimesh could not fill the holes ({_first_line(exc)})")
    V, F = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    left = len(boundary_loops(F))
    if left < n_holes:
        repairs.append(f"closed {n_holes - left} of {n_holes} holes (trimesh fill_holes)")
    if left:
        Vm, Fm, note = _meshfix(V, F)
        if not is_closed_manifold(Fm):
            # trimesh's fans can leave edges shared by three faces, which MeshFix cannot mend: MeshFix
            # on the surface as read, without debris pieces of fewer than MIN_FACES faces (Badin's
            # upper teeth: 7 stray triangles; closed this way, 28,140 faces)
            Vr, Fr, dropped = _without_debris(surface.vertices, surface.faces)
            Vr, Fr, note_r = _meshfix(Vr, Fr)
            if is_closed_manifold(Fr):
                Vm, Fm = Vr, Fr
                note = note_r + " on the surface as read" + (f", {dropped} stray faces left out" if dropped else "")
                repairs = [r for r in repairs if "trimesh fill_holes" not in r]
        V, F = Vm, Fm
        repairs.append(note)
    F, notes = _orient(V, F)
    repairs += [n for n in notes if not n.startswith("reversed")]
    closed = is_closed_manifold(F)
    if not closed:
        repairs.append(f"still open after repair: {len(boundary_loops(F))} holes")
    return dataclasses.replace(surface, vertices=V, faces=F, closed=closed, repairs=tuple(repairs))


def _without_debris(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """``(V, F, dropped)``: the surface without its connected pieces of fewer than ``MIN_FACES``
    faces (stray triangles of a scan), unused vertices removed."""
    comp = face_components(F)
    sizes = np.bincount(comp)
    keep = sizes[comp] >= MIN_FACES
    used, Fk = np.unique(F[keep], return_inverse=True)
    return V[used], Fk.reshape(-1, 3), int((~keep).sum())


def _meshfix(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """MeshFix on every open piece of ``(V, F)``; the closed pieces as they are."""
    try:
        import pymeshfix
    except ImportError:
        return V, F, "pymeshfix is not installed: the remaining holes stay open"
    comp = face_components(F)
    pieces, fixed, failed = [], 0, 0
    for k in range(int(comp.max()) + 1):            # per piece (a handful), not per element
        Fk = F[comp == k]
        used, Fk = np.unique(Fk, return_inverse=True)
        Vk, Fk = V[used], Fk.reshape(-1, 3)
        if not is_closed_manifold(Fk):
            try:
                mf = pymeshfix.MeshFix(Vk, Fk.astype(np.int32))
                mf.repair(joincomp=False, remove_smallest_components=False)
                Vn, Fn = np.asarray(mf.points, float), np.asarray(mf.faces, np.int64).reshape(-1, 3)
                if len(Fn) >= MIN_FACES and is_closed_manifold(Fn):
                    Vk, Fk = Vn, Fn
                    fixed += 1
                else:
                    failed += 1
            except Exception:  # noqa: BLE001 (MeshFix raises RuntimeError and others on hopeless input)
                failed += 1
        pieces.append((Vk, Fk))
    offsets = np.cumsum([0] + [len(p[0]) for p in pieces])
    V = np.concatenate([p[0] for p in pieces])
    F = np.concatenate([p[1] + o for p, o in zip(pieces, offsets)])
    note = f"closed {fixed} open piece{'s' if fixed != 1 else ''} with MeshFix"
    if failed:
        note += f"; MeshFix could not close {failed}"
    return V, F, note


# ====================================================================================== volumes
@dataclass(frozen=True)
class Volume:
    """A flesh volume read from a user's file, as tets.

    X : (n, 3) float64 node positions in the file's units; only nodes used by a tet.
    tets : (t, 4) int64, positively oriented, conforming (every interior triangle shared by
        exactly two tets).
    path : str, the file it came from.
    notes : tuple[str, ...], one line per conversion made (cells split, nodes dropped, ...).
    cell : (t,) int64, the index of the file's volume cell each tet came from (cells counted
        over the file's volume cell blocks in order).
    """

    X: np.ndarray
    tets: np.ndarray
    path: str
    notes: tuple[str, ...] = ()
    cell: np.ndarray | None = None

    def volume(self) -> float:
        """Total volume, file units cubed."""
        return float(tet_volumes(self.X, self.tets).sum())


def read_volume(path) -> Volume:
    """Read the flesh volume at ``path`` (any format meshio reads) as conforming tets.

    Cells: ``tetra``, ``hexahedron``, ``wedge``, ``pyramid``; their quadratic variants
    (``tetra10``, ``hexahedron20/27``, ``wedge15/18``, ``pyramid13/14``) are reduced to their
    corner nodes (linear cells; the mid-edge nodes dropped), and surface or line cells in the
    file are ignored, each said in ``notes``. Cells are split into conforming positive tets by
    :func:`facesim.importing.cells.tetrahedralise` (hexahedra collapsed by repeated nodes as the
    wedges or pyramids they are; warped cells with other face diagonals). A cell type whose
    cells are *all* negatively oriented is taken as written in the mirror-image node order and
    turned round (said in ``notes``); otherwise inverted cells are refused: one line naming the
    file, how many cells and the first one.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such file (expected the flesh volume mesh)")
    try:
        m = meshio.read(str(path))
    except (Exception, SystemExit) as exc:  # noqa: BLE001 (meshio raises ReadError, ValueError, ...; some readers exit)
        raise FacesimError(f"{path}: cannot read the flesh volume mesh ({_first_line(exc)})") from None
    X = np.asarray(m.points, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] < 3 or not len(X):
        raise FacesimError(f"{path}: expected 3-D node positions, got points of shape {X.shape}")
    X = X[:, :3]
    notes, blocks, other = [], [], {}
    for c in m.cells:
        kind, data = c.type, np.asarray(c.data, dtype=np.int64)
        if kind in QUADRATIC:
            base = QUADRATIC[kind]
            notes.append(f"read {len(data):,} quadratic {kind} cells as linear {base} cells (corner nodes only)")
            kind, data = base, data[:, :CORNERS[base]]
        if kind in CELL_FACES:
            blocks.append((kind, data))
        else:
            other[kind] = other.get(kind, 0) + len(data)
    if other:
        notes.append("ignored " + ", ".join(f"{n:,} {k} cells" for k, n in sorted(other.items())))
    if not blocks:
        raise FacesimError(f"{path}: no volume cells (tetra, hexahedron, wedge, pyramid); found "
                           f"{', '.join(sorted(other)) or 'no cells'}")
    for kind, data in blocks:
        if len(data) and (data.min() < 0 or data.max() >= len(X)):
            raise FacesimError(f"{path}: {kind} cells index nodes outside [0, {len(X)}): got [{data.min()}, {data.max()}]")
    used = np.zeros(len(X), bool)
    for _, data in blocks:
        used[data.ravel()] = True
    bad = used & ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise FacesimError(f"{path}: {int(bad.sum()):,} of {len(X):,} nodes have non-finite coordinates "
                           f"(first: node {int(np.argmax(bad))})")
    T, cell, split_notes = tetrahedralise(X, blocks, path)
    notes += split_notes
    keep, T = np.unique(T, return_inverse=True)
    T = T.reshape(-1, 4).astype(np.int64)
    if len(keep) < len(X):
        notes.append(f"dropped {len(X) - len(keep):,} nodes used by no volume cell")
    return Volume(X=X[keep], tets=T, path=str(path), notes=tuple(notes), cell=cell)


def volume_boundary(X: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(k, 3) int64 boundary triangles (used by one tet) of the positively oriented ``tets (t, 4)``,
    outward oriented. ``X`` is not needed for the topology; it is checked for shape only."""
    if np.asarray(X).ndim != 2:
        raise FacesimError(f"volume_boundary: expected X of shape (n, 3), got {np.asarray(X).shape}")
    faces, _ = boundary_faces(np.asarray(tets, dtype=np.int64))
    return faces.astype(np.int64)


def conformity(tets: np.ndarray) -> tuple[int, int, int]:
    """``(interior, boundary, overshared)`` triangle counts of the tet mesh: triangles shared by
    two tets, by one, by more than two. A conforming mesh made from cells whose outer faces
    are known has no overshared triangle and exactly those outer faces' triangles as boundary."""
    local = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    key = np.sort(np.asarray(tets)[:, local].reshape(-1, 3), axis=1)
    _, count = np.unique(key, axis=0, return_counts=True)
    return int((count == 2).sum()), int((count == 1).sum()), int((count > 2).sum())


# ======================================================================================= units
#: The span of a face region, mm: a mandible is ~100 mm wide, a face mask ~200 mm tall, a head
#: with a neck ~300 mm. Sizes between the windows of two units are ambiguous.
HEAD_SPAN_MM = (60.0, 400.0)
UNITS = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
_UNIT_NAMES = {"mm": "mm", "millimetre": "mm", "millimetres": "mm", "millimeter": "mm", "millimeters": "mm",
               "cm": "cm", "centimetre": "cm", "centimetres": "cm", "centimeter": "cm", "centimeters": "cm",
               "m": "m", "metre": "m", "metres": "m", "meter": "m", "meters": "m"}
_UNIT_WORDS = {"mm": "millimetres", "cm": "centimetres", "m": "metres"}


def infer_units(points, units: str = "auto", source: str = "the meshes") -> tuple[float, str, str]:
    """``(scale_to_mm, name, reason)`` for coordinates ``points (k, 3)`` (all meshes of one face).

    ``units`` ``"m"``, ``"cm"`` or ``"mm"`` (or their spelled-out names) is taken as given;
    ``"auto"`` picks the one unit that makes the largest extent of the points a face region's
    span, :data:`HEAD_SPAN_MM` (60-400 mm). Sizes that fit no unit are refused with a one-line
    error asking for ``--units``. ``reason`` is a line for the output, e.g. ``"auto: extent
    0.187 -> metres (187 mm)"``; ``source`` names the files in messages.
    """
    key = str(units).strip().lower()
    if key in _UNIT_NAMES:
        name = _UNIT_NAMES[key]
        return UNITS[name], name, f"given: {_UNIT_WORDS[name]}"
    if key != "auto":
        raise FacesimError(f"units: expected auto, m, cm or mm, got {units!r}")
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    P = P[np.isfinite(P).all(axis=1)]
    if not len(P):
        raise FacesimError(f"{source}: no finite coordinates to tell the units from")
    extent = float((P.max(axis=0) - P.min(axis=0)).max())
    lo, hi = HEAD_SPAN_MM
    fits = [n for n, s in UNITS.items() if lo <= extent * s <= hi]
    if len(fits) != 1:
        spans = ", ".join(f"{extent * s:.4g} mm in {n}" for n, s in UNITS.items())
        raise FacesimError(f"{source}: cannot tell the units from the size (extent {extent:.4g}, i.e. {spans}; "
                           f"a face spans {lo:g}-{hi:g} mm): give --units m, cm or mm")
    name = fits[0]
    return UNITS[name], name, f"auto: extent {extent:.4g} -> {_UNIT_WORDS[name]} ({extent * UNITS[name]:.0f} mm)"


# ================================================================================= skin split
class SkinSplit(NamedTuple):
    """The outer skin and the inner (on-bone) part of a flesh volume's boundary, as triangles of
    the volume's nodes: ``outer (a, 3)``, ``inner (b, 3)`` int64, outward oriented."""

    outer: np.ndarray
    inner: np.ndarray

    def summary(self, X: np.ndarray) -> str:
        """One line with the sizes, e.g. ``"outer skin 9,120 faces (61,000 mm^2); inner 4,200 faces
        (22,000 mm^2) on the bones"`` (``X`` in mm)."""
        a = [0.5 * np.linalg.norm(_cross_faces(X, f), axis=1).sum() if len(f) else 0.0 for f in self]
        return (f"outer skin {len(self.outer):,} faces ({a[0]:,.0f} mm^2); inner {len(self.inner):,} faces "
                f"({a[1]:,.0f} mm^2) on the bones")


#: A boundary face whose centre lies within this distance (mm) of a bone, with the bone in front
#: of its outward normal, lies on the bone: a seed of the inner surface.
ON_BONE_MM = 2.0
#: A face farther than this (mm) from every bone, with the bones behind it, is a seed of the skin.
OFF_BONE_MM = 6.0
#: How sharply the split avoids cutting across smooth surface: the weight of the edge between
#: two faces is exp(-CREASE_STIFFNESS (1 - cos angle between their normals)).
CREASE_STIFFNESS = 10.0


def split_skin(X: np.ndarray, faces: np.ndarray, bones: Sequence[Surface], on_bone_mm: float = ON_BONE_MM,
               off_bone_mm: float = OFF_BONE_MM) -> SkinSplit:
    """Separate a flesh boundary ``faces (k, 3)`` (outward, nodes ``X (n, 3)`` mm) into the outer
    skin and the inner surface lying on the bones ``bones`` (surfaces in mm, same frame; open or
    closed, any orientation).

    Seeds: a face within ``on_bone_mm`` of a bone (bones sampled every ~1 mm) with the bone in
    front of its outward normal lies on the bone; a face farther than ``off_bone_mm`` from every
    bone, with the nearest bone behind it and facing away from the bones' centre (cos > 0.5), is
    skin; one that far facing the bones' centre is inner surface. Every other face goes with the seeds it is best
    connected to: a random walk over the faces (Grady 2006, *Random walks for image
    segmentation*) whose steps across edges are likely between faces of similar normals and
    unlikely across creases (weight exp(-CREASE_STIFFNESS (1 - cos angle))). The rim of a face
    mask, where the skin folds round to the inner surface, is such a crease, so inner surface
    far from any given bone (on a cranium that was not given) still goes with the inner side.
    A piece of the boundary with no seed is skin.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    X = np.asarray(X, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if not bones:
        raise FacesimError("split_skin: no bone surfaces given to tell the inner surface from the skin")
    P = np.concatenate([sample_surface(b, spacing=1.0)[0] for b in bones])
    c = X[faces].mean(axis=1)
    n = _unit(_cross_faces(X, faces))
    d, j = cKDTree(P).query(c)
    ahead = np.einsum("ij,ij->i", P[j] - c, n)
    # far from the bones: facing away from their centre is skin, facing it is inner surface
    # (the inside of a mask's forehead, say, where no cranium was given)
    away = np.einsum("ij,ij->i", n, _unit(c - P.mean(axis=0)))
    inner_seed = ((d <= on_bone_mm) & ((ahead > 0) | (d < 0.25))) | ((d > off_bone_mm) & (away < -0.5))
    outer_seed = (d > off_bone_mm) & (ahead < -0.5 * d) & (away > 0.5)
    # face adjacency across manifold edges, weighted by the normals' agreement
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    fid = np.repeat(np.arange(len(faces)), 3)
    _, inv, count = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    a, b = fid[order][:-1], fid[order][1:]
    pair = (inv[order][:-1] == inv[order][1:]) & (count[inv[order][:-1]] == 2)
    a, b = a[pair], b[pair]
    w = np.exp(-CREASE_STIFFNESS * (1.0 - np.einsum("ij,ij->i", n[a], n[b])))
    m = len(faces)
    W = coo_matrix((np.r_[w, w], (np.r_[a, b], np.r_[b, a])), shape=(m, m)).tocsr()
    L = (coo_matrix((np.asarray(W.sum(axis=1)).ravel(), (np.arange(m), np.arange(m))), shape=(m, m)) - W).tocsr()
    seed = inner_seed | outer_seed
    value = np.where(outer_seed, 1.0, 0.0)
    free = np.flatnonzero(~seed)
    reach = _reaches_seed(W, seed)
    solve = free[reach[free]]
    outer = outer_seed.copy()
    if len(solve):
        A = L[solve][:, solve]
        rhs = -L[solve][:, np.flatnonzero(seed)] @ value[seed]
        x = spsolve(A.tocsc(), rhs)
        outer[solve] = x >= 0.5
    outer[free[~reach[free]]] = True
    return SkinSplit(outer=faces[outer], inner=faces[~outer])


def _reaches_seed(W, seed: np.ndarray) -> np.ndarray:
    """(m,) bool: the face's connected component (graph ``W``) holds a seed."""
    from scipy.sparse.csgraph import connected_components

    _, label = connected_components(W, directed=False)
    has = np.zeros(label.max() + 1, bool)
    has[label[seed]] = True
    return has[label]


def sample_surface(surface: Surface, spacing: float, scale: float = 1.0, seed: int = 0,
                   max_points: int = 400_000) -> tuple[np.ndarray, np.ndarray]:
    """``(points (k, 3), normals (k, 3))``: the vertices of ``surface`` plus points spread over its
    faces about every ``spacing`` (in the units after ``scale``), each with its face's unit
    normal (vertex normals: area-weighted). Deterministic for a given mesh and ``seed``: the
    same faces and barycentric coordinates whatever the mesh's position."""
    V = scale * surface.vertices
    F = surface.faces
    cross = _cross_faces(V, F)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    nf = _unit(cross)
    vn = vertex_normals(V, F)
    k = int(min(max_points, np.ceil(area.sum() / (spacing * spacing))))
    rng = np.random.default_rng(seed)
    if k > 0 and area.sum() > 0:
        f = rng.choice(len(F), size=k, p=area / area.sum())
        r = rng.random((k, 2))
        flip = r.sum(axis=1) > 1
        r[flip] = 1 - r[flip]
        T = V[F[f]]
        S = T[:, 0] + r[:, :1] * (T[:, 1] - T[:, 0]) + r[:, 1:] * (T[:, 2] - T[:, 0])
        return np.concatenate([V, S]), np.concatenate([vn, nf[f]])
    return V, vn


# ===================================================================================== checks
#: Bone points farther than this (mm) outside the skin make a bone cut through the skin; points
#: outside by more than OUTSIDE_NOTE_MM but within it are reported (real meshes touch: the teeth
#: of a cast reach into the lips' gap).
OUTSIDE_TOL_MM = 2.0
OUTSIDE_NOTE_MM = 0.5


def orient_outward(surface: Surface, inside: np.ndarray) -> Surface:
    """``surface`` (mm) with its faces reversed if most of its area faces the points ``inside
    (k, 3)`` (mm; e.g. the bones under a face mask): an open skin's outward is away from the
    bones. Closed surfaces are returned as they are (already outward)."""
    if surface.closed:
        return surface
    tree = cKDTree(np.asarray(inside, float))
    c = surface.vertices[surface.faces].mean(axis=1)
    cross = _cross_faces(surface.vertices, surface.faces)
    _, j = tree.query(c)
    toward = np.einsum("ij,ij->i", cross, np.asarray(inside, float)[j] - c)
    if toward.sum() <= 0:                 # area-weighted: cross has length 2 x area
        return surface
    return dataclasses.replace(surface, faces=surface.faces[:, [0, 2, 1]],
                               repairs=surface.repairs + ("reversed all faces (outward: away from the bones)",))


def outside_skin(skin: Surface, points: np.ndarray, tol: float = OUTSIDE_TOL_MM) -> np.ndarray:
    """(k,) float64 how far (mm) each of ``points (k, 3)`` lies outside the outward skin (0 inside).

    The nearest point of the skin (sampled every ~1 mm) with its normal: a point is outside when
    it lies in front of the skin along that normal by more than ``tol`` and nearly straight in
    front of it (so points beyond an open skin's edge, behind a face mask, count as inside)."""
    S, N = sample_surface(skin, spacing=1.0)
    P = np.asarray(points, dtype=np.float64)
    d, j = cKDTree(S).query(P)
    ahead = np.einsum("ij,ij->i", P - S[j], N[j])
    out = (ahead > tol) & (ahead >= 0.9 * d)
    if skin.closed:
        out = ahead > tol
    return np.where(out, ahead, 0.0)


def check_anatomy(skin: Surface, bones: Sequence[Surface], tol: float = OUTSIDE_TOL_MM) -> list[str]:
    """Check that the skin (mm, outward; an open mask oriented by :func:`orient_outward`) covers
    the bones (mm, same frame). Returns report lines, one per bone (vertices sticking out by
    less than ``tol`` are counted there); raises a one-line :class:`FacesimError` naming the
    files when a bone's vertices lie more than ``tol`` mm outside the skin (a bone cutting
    through the skin: how many vertices, how far), or when the whole bone lies outside it (the
    files in different frames or units)."""
    lines = []
    for bone in bones:
        far = outside_skin(skin, bone.vertices, OUTSIDE_NOTE_MM)
        n_out, n_cut = int((far > 0).sum()), int((far > tol).sum())
        if n_out == len(bone.vertices):
            raise FacesimError(f"{bone.path}: the {bone.role} lies wholly outside the skin {skin.path} "
                               f"(all files must share one frame and one unit)")
        if n_cut:
            raise FacesimError(f"{bone.path}: {n_cut:,} of {len(bone.vertices):,} vertices of the {bone.role} lie more than "
                               f"{tol:g} mm outside the skin {skin.path} (up to {far.max():.1f} mm): the bone cuts "
                               f"through the skin")
        if n_out:
            lines.append(f"{bone.name}: {n_out:,} of {len(bone.vertices):,} vertices stick out of the skin by up to "
                         f"{far.max():.1f} mm (under the {tol:g} mm tolerance)")
        else:
            lines.append(f"{bone.name}: under the skin")
    return lines
