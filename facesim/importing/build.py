"""A simulation-ready face from a user's own meshes (``facesim model import``), as Sifakis 2005 built
its face: the subject's flesh and bones, the template's muscles, fibres and markers morphed onto them.

Two routes to the flesh volume:

* **surfaces** -- a skin surface (closed, or repaired closed) and the bone surfaces: the flesh is
  the skin's inside minus the bones, tetrahedralised by fTetWild's CSG (``pytetwild``) at the
  ``resolution``'s edge length;
* **volume** -- a volume mesh of the soft tissue (tets, hexahedra, wedges, pyramids in any meshio
  format; :func:`facesim.importing.meshes.read_volume` splits cells into positive tets).

Then, whatever the route (:func:`import_model`):

1. units from the anatomy's size (or given), the head's frame from the anatomy
   (:func:`facesim.importing.frame.anatomical_frame`: symmetry plane, mandible, teeth) or a
   ``--frame`` spec; every input moved into facesim's frame (mm; x left, y up, z forward, origin
   between the condyles); the transform is kept in ``meta["input_frame"]``;
2. bones checked against the skin (:func:`~facesim.importing.meshes.check_anatomy`), the flesh's
   boundary split into the outer skin and the inner surface (:func:`~facesim.importing.meshes.split_skin`);
3. attachments (:func:`attachments`): flesh nodes on or inside a bone move with it (nearest bone wins, so
   the sets are disjoint); inner-surface nodes that face the teeth (the lips' and cheeks' lining)
   stay free; with ``fix_boundary="cut"`` the rest of the inner surface -- where a face mask ends
   or lies on bone the input does not have (a mask's forehead, the cut behind the cheeks) -- is
   fixed to the cranium, unless it lies nearer the mandible than any cranium part;
4. landmarks (:mod:`facesim.importing.landmarks`) on the bones and skin, the user's
   ``--landmarks`` file overriding any; the TMJ from them;
5. the template's muscles and markers carried over by a thin-plate warp through the landmarks
   (:mod:`facesim.importing.template`), re-embedded; its tissue labels (lips, nose cartilage) the
   same way;
6. teeth as colliders (closed by repair), lip contact surfaces where the mouth has an opening.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from facesim.errors import FacesimError

#: target tet edge (mm) of the surfaces route by name; a number is taken as the edge itself
RESOLUTIONS = {"coarse": 8.0, "medium": 5.0}
FIX_BOUNDARY = ("cut", "none")
REMESH = ("auto", "yes", "no")
#: fTetWild's envelope (mm): how far the meshed flesh's surface may stray from the input surfaces
ENVELOPE_MM = 0.25   # 0.5 mm closes the lips' slit of the Badin face
#: with ``remesh="auto"``, a given volume mesh is re-meshed when its worst tet is below either figure:
#: slivers invert under the first large motion (Badin's split hexes reach 0.12 degrees)
REMESH_MIN_DIHEDRAL_DEG = 5.0
REMESH_MIN_VOLUME_RATIO = 0.05
#: a flesh node within this distance (mm) of a bone is attached to it (at least; see ATTACH_EDGE)
ATTACH_MM = 2.5
#: ... or within this fraction of the mesh's median edge, on coarse meshes
ATTACH_EDGE = 0.4
#: a flesh surface node this close (mm) to a tooth rests on it and moves with its bone
TOUCH_MM = 1.0
#: inner-surface nodes this close (mm) to a bone (nearer than to anything else) lie on it, with a gap
ON_BONE_GAP_MM = 6.0
#: inner-surface nodes nearest the teeth within this distance (mm) are the lips' and cheeks' lining: free
LINING_MM = 12.0
#: the template's landmark warp is smoothed by this much (mm^2 units of the spline's regulariser):
#: landmark finders are ~1-3 mm noisy, and nearby landmarks (incisors, lips) fold an exact fit
WARP_SMOOTHING = 1.0
#: the landmark warp is refined this many times by surface correspondences (skin to skin, bone to bone)
REFINE_ITERATIONS = 3
#: spacing (mm) of the subject's surface points paired with the template's, and the farthest pair kept
REFINE_SPACING_MM = 10.0
REFINE_MAX_MM = 15.0
#: smoothing of the refined warp (the pairs are approximate: nearest points, not true correspondences)
REFINE_SMOOTHING = 500.0


def _say(progress, text: str) -> None:
    if progress is not None:
        progress(text)


def import_model(*, skin=None, flesh=None, cranium=(), mandible=None, teeth_upper=None, teeth_lower=None,
                 units: str = "auto", frame: str | None = None, resolution="coarse", landmarks=None,
                 fix_boundary: str = "cut", remesh: str = "auto", template=None, progress=None):
    """Build a :class:`~facesim.model.FaceModel` from a user's meshes (module doc).

    skin : a skin surface file (surfaces route) -- or flesh : a volume mesh file (volume route);
    cranium : bone surface files rigid with the skull (braincase, maxilla, ...); mandible : the
    mandible's surface file (required); teeth_upper, teeth_lower : optional dentition surfaces;
    units : ``"auto"``, ``"m"``, ``"cm"`` or ``"mm"``; frame : None (found from the anatomy) or a
    spec such as ``"x=backward,y=right,z=up"`` (:func:`facesim.importing.frame.parse_frame_spec`);
    resolution : ``"coarse"``, ``"medium"`` or an edge length in mm (surfaces route);
    landmarks : a landmarks JSON overriding found ones (:func:`facesim.importing.landmarks.load_landmarks`);
    fix_boundary : ``"cut"`` or ``"none"`` (module doc, step 3); remesh : the volume route's mesh
    re-meshed from its boundary by fTetWild at ``resolution`` -- ``"yes"``, ``"no"``, or ``"auto"``
    when its quality is below :data:`REMESH_MIN_DIHEDRAL_DEG` / :data:`REMESH_MIN_VOLUME_RATIO`
    (said in the report); template : the template model
    (a FaceModel or a path; default the shipped coarse face); progress : a callable taking one
    line per stage.

    Returns ``(model, report)``: ``report`` is JSON-serialisable (units, frame, repairs, route,
    attachments, landmarks, flagged muscles, dropped markers, timings) and is also the model's
    ``meta["import"]``.
    """
    from facesim.importing import landmarks as lm
    from facesim.importing.frame import anatomical_frame
    from facesim.importing.meshes import (check_anatomy, clean_surface, infer_units, orient_outward, read_surface,
                                          read_volume, split_skin, volume_boundary)

    t0 = time.perf_counter()
    timings = {}
    if (skin is None) == (flesh is None):
        raise FacesimError("model import: give either --skin (a skin surface) or --flesh (a volume mesh), not "
                           f"{'both' if skin is not None else 'neither'}")
    if mandible is None:
        raise FacesimError("model import: --mandible is required (the jaw's bone surface)")
    if fix_boundary not in FIX_BOUNDARY:
        raise FacesimError(f"--fix-boundary: expected one of {', '.join(FIX_BOUNDARY)}, got {fix_boundary!r}")
    if remesh not in REMESH:
        raise FacesimError(f"--remesh: expected one of {', '.join(REMESH)}, got {remesh!r}")
    cranium = [cranium] if isinstance(cranium, (str, os.PathLike)) else list(cranium)
    edge = _edge(resolution)
    overrides = lm.load_landmarks(landmarks) if landmarks is not None else None   # a bad file fails first
    # ---- read
    mand = read_surface(mandible, "mandible")
    crania = [read_surface(p, "cranium") for p in cranium]
    teeth = {role: read_surface(p, role) for role, p in (("teeth_upper", teeth_upper), ("teeth_lower", teeth_lower))
             if p is not None}
    if skin is not None:
        skin_in = read_surface(skin, "skin")
        points = skin_in.vertices
        volume = None
    else:
        volume = read_volume(flesh)
        points = volume.X
        skin_in = clean_surface(volume.X, volume_boundary(volume.X, volume.tets), str(flesh), "skin")
    scale, unit_name, unit_reason = infer_units(np.concatenate([points, mand.vertices]), units,
                                                source=Path(skin or flesh).name)
    _say(progress, f"units: {unit_reason}")
    span = float(np.ptp(scale * mand.vertices, axis=0).max())
    if not 40.0 <= span <= 250.0:   # an adult mandible spans ~90-130 mm
        raise FacesimError(f"{mand.path}: the mandible spans {span:.3g} mm in {unit_name}; expected 40 to 250 mm: "
                           f"are the units right (--units auto|m|cm|mm)?")
    timings["read"] = time.perf_counter() - t0
    # ---- frame
    t = time.perf_counter()
    fit = anatomical_frame(mand, crania, skin_in, teeth.get("teeth_upper"), teeth.get("teeth_lower"),
                           scale_to_mm=scale, units=unit_name, spec=frame)
    _say(progress, f"frame ({fit.how}): " + "; ".join(fit.cues))
    mand_mm = mand.transformed(fit.T, scale)
    crania_mm = [c.transformed(fit.T, scale) for c in crania]
    teeth_mm = {k: v.transformed(fit.T, scale) for k, v in teeth.items()}
    bones_mm = [mand_mm, *crania_mm]
    timings["frame"] = time.perf_counter() - t
    # ---- the flesh volume
    t = time.perf_counter()
    repairs = {s.name: list(s.repairs) for s in (mand, *crania, *teeth.values(), skin_in) if s.repairs}
    if volume is not None:
        from facesim.anatomy.quality import quality_summary

        X = fit.to_facesim(volume.X)
        T = np.asarray(volume.tets, dtype=np.int64)
        route = {"route": "volume", "file": str(flesh), "notes": list(volume.notes)}
        q = quality_summary(X, T.astype(np.int32))
        poor = q["min_dihedral_deg"] < REMESH_MIN_DIHEDRAL_DEG or q["worst_volume_ratio"] < REMESH_MIN_VOLUME_RATIO
        if remesh == "yes" or (remesh == "auto" and poor):
            why = (f"its tets reach {q['min_dihedral_deg']:.2f} deg dihedral, volume ratio {q['worst_volume_ratio']:.4f}"
                   if poor else "asked")
            _say(progress, f"re-meshing the flesh from its boundary ({why}; --remesh no keeps the given mesh)")
            from facesim.importing.meshes import Surface

            boundary = Surface(X, volume_boundary(X, T), str(flesh), "skin", closed=True)
            X, T, notes = _mesh_surfaces(boundary, [], edge, progress)
            route.update(remeshed=why, edge_mm=edge, given_quality=q)
            route["notes"] += notes
    else:
        skin_mm = orient_outward(skin_in.transformed(fit.T, scale),
                                 np.concatenate([b.vertices for b in bones_mm]))
        X, T, notes = _mesh_surfaces(skin_mm, bones_mm, edge, progress)
        route = {"route": "surfaces", "file": str(skin), "edge_mm": edge, "notes": notes}
    from facesim.anatomy.meshing import split_pinched_nodes
    from facesim.model import positively_oriented

    X, T = split_pinched_nodes(X, positively_oriented(X, T))
    timings["mesh"] = time.perf_counter() - t
    _say(progress, f"flesh ({route['route']}): {len(X):,} nodes, {len(T):,} tets")
    # ---- skin and checks
    t = time.perf_counter()
    F = volume_boundary(X, T)
    split = split_skin(X, F, bones_mm)
    _say(progress, split.summary(X))
    from facesim.importing.meshes import Surface

    outer = Surface(X, split.outer, str(skin or flesh), "skin", closed=False)
    checks = check_anatomy(outer, bones_mm)
    # ---- attachments
    cranium_nodes, jaw_nodes, attach = attachments(X, T, split, mand_mm, crania_mm, list(teeth_mm.values()),
                                                   fix_boundary)
    _say(progress, "attachments: " + ", ".join(f"{k} {v:,}" for k, v in attach["counts"].items()))
    T, cranium_nodes, bridged = drop_bridging_tets(X, T, cranium_nodes, jaw_nodes, split.outer)
    attach["bridging_tets_removed"] = bridged
    if bridged["tets"]:
        _say(progress, f"joint space: {bridged['tets']:,} tets ({bridged['volume_mm3']:.0f} mm^3) joined a cranium node "
                       "to a jaw node (flesh any jaw motion tears or crushes, between maxilla and ramus or the "
                       "closed gums): removed")
    timings["attach"] = time.perf_counter() - t
    # ---- landmarks and the TMJ
    t = time.perf_counter()
    mesh = lm.Mesh
    found, how = lm.detect(mesh(mand_mm.vertices, mand_mm.faces),
                           mesh.join([mesh(c.vertices, c.faces) for c in crania_mm]) if crania_mm else None,
                           mesh(X, split.outer),
                           *(mesh(teeth_mm[k].vertices, teeth_mm[k].faces) if k in teeth_mm else None
                             for k in ("teeth_upper", "teeth_lower")), x_mid=fit.x_mid)
    if overrides is not None:
        for name, p in overrides.in_facesim(fit).items():
            found[name], how[name] = p, f"given in {overrides.path}"
    jaw = lm.jaw_geometry_from_landmarks(found)
    timings["landmarks"] = time.perf_counter() - t
    # ---- the template's muscles, markers and tissues
    t = time.perf_counter()
    template = _template(template)
    muscles, markers, tissue, carried = carry_template(template, X, T, split.outer, found, mand_mm, crania_mm)
    _say(progress, f"muscles: {muscles.n_muscles} carried over ({len(carried['muscles']['flagged'])} flagged); "
                   f"markers: {markers.n_markers} of {template.n_markers} placed")
    timings["template"] = time.perf_counter() - t
    # ---- surfaces of the model
    from facesim.model import FaceModel, RigidSurface

    bones = (RigidSurface("cranium", "cranium", *_merged(crania_mm)) if crania_mm else None,
             RigidSurface("mandible", "jaw", mand_mm.vertices, mand_mm.faces))
    colliders, collider_notes = _colliders(teeth_mm)
    lip_upper, lip_lower, lip_note = lip_surfaces(X, F, split, found)
    from facesim.anatomy.quality import quality_summary

    report = {
        "builder": "import", "route": route, "units": {"name": unit_name, "scale_to_mm": scale, "how": unit_reason},
        "input_frame": fit.meta(), "inputs": {"skin": None if skin is None else str(skin),
                                               "flesh": None if flesh is None else str(flesh),
                                               "cranium": [str(c) for c in cranium], "mandible": str(mandible),
                                               "teeth_upper": None if teeth_upper is None else str(teeth_upper),
                                               "teeth_lower": None if teeth_lower is None else str(teeth_lower)},
        "repairs": repairs, "checks": checks, "skin_split": split.summary(X), "attachments": attach,
        "landmarks": {k: [round(float(v), 4) for v in p] for k, p in found.items()}, "landmark_how": how,
        "template": carried, "colliders": collider_notes, "lips": lip_note,
        "fix_boundary": fix_boundary, "quality": quality_summary(X, T.astype(np.int32)),
        "timings": {k: round(v, 2) for k, v in timings.items()},
    }
    model = FaceModel(X=X, tets=T.astype(np.int32), tissue=tissue, tissues=template.tissues,
                      simulated=np.ones(len(T), bool), muscles=muscles, cranium_nodes=cranium_nodes,
                      jaw_nodes=jaw_nodes, skin=split.outer.astype(np.int32), lip_upper=lip_upper, lip_lower=lip_lower,
                      bones=tuple(b for b in bones if b is not None), colliders=colliders, markers=markers, jaw=jaw,
                      meta={"builder": "import", "units": "mm", "quality": report["quality"], "import": report,
                            "input_frame": {"T_facesim_from_input_mm": fit.meta()["T_facesim_from_input_mm"],
                                            "scale_to_mm": scale, "units": unit_name}})
    # ---- head markers where the jaw does not move the skin (facesim.importing.head_markers)
    t = time.perf_counter()
    import dataclasses

    from facesim.importing.head_markers import choose_head_markers

    head, heads = choose_head_markers(model)
    model = model.with_(markers=dataclasses.replace(model.markers, head=head))
    report["head_markers"] = heads
    moved = "; ".join(f"{n} dropped (the jaw moves it {v['jaw_mm']:.2f} mm)" for n, v in heads["dropped"].items())
    added = ", ".join(f"{n} ({v['jaw_mm']:.2f} mm under the jaw, {v['muscles_mm']:.2f} under a muscle)"
                      for n, v in heads["added"].items())
    _say(progress, f"head markers: {', '.join(np.asarray(model.markers.names)[head])}"
                   + (f"; {moved}" if moved else "") + (f"; added {added}" if added else ""))
    timings["head_markers"] = time.perf_counter() - t
    report["timings"] = {k: round(v, 2) for k, v in timings.items()}
    report["timings"]["total"] = round(time.perf_counter() - t0, 2)
    return model, report


def _edge(resolution) -> float:
    if isinstance(resolution, str) and resolution in RESOLUTIONS:
        return RESOLUTIONS[resolution]
    try:
        edge = float(resolution)
    except (TypeError, ValueError):
        edge = float("nan")
    if not (0.5 <= edge <= 50.0):
        raise FacesimError(f"--resolution: expected {', '.join(RESOLUTIONS)} or a tet edge length in mm "
                           f"(0.5 to 50), got {resolution!r}")
    return edge


def _template(template):
    from facesim.model import FaceModel, load_model

    if isinstance(template, FaceModel):
        return template
    if template is None:
        from facesim._files import MESHES

        template = MESHES / "face_coarse.npz"
    return load_model(template)


def _merged(surfaces) -> tuple[np.ndarray, np.ndarray]:
    V, F, n = [], [], 0
    for s in surfaces:
        V.append(s.vertices)
        F.append(s.faces + n)
        n += len(s.vertices)
    return np.concatenate(V), np.concatenate(F)


def _mesh_surfaces(skin, bones, edge: float, progress) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Tets of the skin's inside minus the bones' (mm; fTetWild CSG). The skin must be closed
    (repaired if it is not); bones that stay open after repair are not subtracted (their flesh
    nodes still attach)."""
    import pytetwild
    import trimesh

    from facesim.importing.meshes import repair_surface

    notes = []
    if not skin.closed:
        skin = repair_surface(skin)
        notes += [f"skin: {r}" for r in skin.repairs[-3:]]
        if not skin.closed:
            raise FacesimError(f"{skin.path}: the skin is open and could not be closed by repair "
                               f"({skin.repairs[-1] if skin.repairs else 'holes remain'}); give a closed skin, or "
                               "the flesh as a volume mesh (--flesh)")
    closed = []
    for b in bones:
        r = repair_surface(b)
        if r.closed:
            closed.append(r)
        else:
            notes.append(f"{b.name}: open after repair, not subtracted from the flesh")
    V = skin.vertices
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    _say(progress, f"tetrahedralising the flesh (fTetWild, edge {edge:g} mm): this takes a minute or more")
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="facesim_import_") as tmp:
        names = []
        for k, s in enumerate([skin, *closed]):
            path = Path(tmp) / f"s{k}.obj"
            trimesh.Trimesh(s.vertices, s.faces, process=False).export(path)
            names.append(str(path))
        tree = names[0] if len(names) == 1 else {"operation": "difference", "left": names[0],
                                                  "right": _union(names[1:])}
        import json

        (Path(tmp) / "tree.json").write_text(json.dumps(tree))
        os.chdir(tmp)   # fTetWild writes scratch files into the working directory
        try:
            if len(names) == 1:   # nothing to subtract: the surface's inside
                Xo, To = pytetwild.tetrahedralize(skin.vertices, skin.faces.astype(np.int32), edge_length_abs=edge,
                                                  epsilon=ENVELOPE_MM / diag, num_threads=0, quiet=True, loglevel=6)
                grid = None
            else:
                grid = pytetwild.tetrahedralize_csg(str(Path(tmp) / "tree.json"), edge_length_r=edge / diag,
                                                    epsilon=ENVELOPE_MM / diag, num_threads=0, loglevel=6)
        except Exception as exc:  # noqa: BLE001 - fTetWild's errors are RuntimeErrors of any text
            raise FacesimError(f"{skin.path}: fTetWild could not tetrahedralise the flesh "
                               f"({' '.join(str(exc).split())[:200]})") from None
        finally:
            os.chdir(cwd)
    import pyvista as pv

    if grid is None:
        points, T = np.asarray(Xo, dtype=np.float64), np.asarray(To, dtype=np.int64)
    else:
        points = np.asarray(grid.points, dtype=np.float64)
        T = np.asarray(grid.cells_dict.get(pv.CellType.TETRA, np.zeros((0, 4))), dtype=np.int64)
    if not len(T):
        raise FacesimError(f"{skin.path}: fTetWild made no tets: do the bones fill the skin's inside?")
    used, inv = np.unique(T, return_inverse=True)
    X = points[used]
    return X, inv.reshape(T.shape), notes


def _union(names):
    if len(names) == 1:
        return names[0]
    return {"operation": "union", "left": names[0], "right": _union(names[1:])}


def _nearest(points, surfaces) -> np.ndarray:
    """(k,) distance (mm) of ``points`` to the union of ``surfaces`` (sampled every 0.5 mm; inf
    without any)."""
    from facesim.importing.meshes import sample_surface

    if not surfaces:
        return np.full(len(points), np.inf)
    S = np.concatenate([sample_surface(s, spacing=0.5)[0] for s in surfaces])
    return cKDTree(S).query(points)[0]


def _inside(points, surfaces) -> np.ndarray:
    """(k,) bool: ``points (k, 3)`` mm inside any of the closed ``surfaces`` (open ones have no inside)."""
    import trimesh

    inside = np.zeros(len(points), bool)
    for s in surfaces:
        if s.closed:
            inside |= trimesh.Trimesh(s.vertices, s.faces, process=False).contains(points)
    return inside


def attachments(X, T, split, mandible, crania, teeth, fix_boundary: str = "cut"):
    """``(cranium_nodes, jaw_nodes, report)`` of the flesh ``X (n, 3)`` mm, ``T (m, 4)``.

    Every node inside a closed bone, or within ``max(ATTACH_MM, ATTACH_EDGE x median edge)`` of a bone moves with it (the
    nearer bone when both are that close); inside the flesh the teeth count with their bone (the
    flesh round them is gum), while on its surface a node nearer the teeth than the bone is the
    lining of the lips and cheeks against them, and stays free unless it touches a tooth (within
    ``TOUCH_MM``: it rests on it and moves with it). Inner-surface nodes (``split.inner``) nearer a bone
    than anything else and within ``ON_BONE_GAP_MM`` lie on it across a modelling gap: attached
    too. Inner-surface nodes nearest the teeth (within ``LINING_MM``) are the lips' and cheeks'
    lining: free. With ``fix_boundary="cut"``, the remaining inner surface (lying on bone the
    input lacks, or the cut where a face mask ends) is fixed to the cranium unless its nearest
    structure is the mandible (then free: it moves with the jaw's flesh)."""
    e = np.sort(T[:, [0, 1, 0, 2, 0, 3, 1, 2, 1, 3, 2, 3]].reshape(-1, 2), axis=1)
    edge = float(np.median(np.linalg.norm(X[e[:, 0]] - X[e[:, 1]], axis=1)))
    tol = max(ATTACH_MM, ATTACH_EDGE * edge)
    # a node inside a closed bone (a volume mesh that overlaps it: Badin's flesh reaches 5 mm into
    # the mandible) is on it, however deep: the bone is rigid and carries what lies in it
    in_j, in_c = _inside(X, [mandible]), _inside(X, crania)
    d_j = np.where(in_j, 0.0, _nearest(X, [mandible]))
    d_c = np.where(in_c, 0.0, _nearest(X, crania))
    d_tu = _nearest(X, [t for t in teeth if t.role == "teeth_upper"])
    d_tl = _nearest(X, [t for t in teeth if t.role == "teeth_lower"])
    d_t = np.minimum(d_tu, d_tl)
    surface = np.zeros(len(X), bool)
    surface[np.unique(np.concatenate([split.outer, split.inner]))] = True
    # inside the flesh, the teeth count with their bone (flesh round them is gum); on its surface a
    # node nearer the teeth than the bone is the lips' and cheeks' lining against them: free
    # -- unless it touches them (within TOUCH_MM): lining resting on the teeth moves with them
    lining_free = surface & (d_t > TOUCH_MM)
    dJ = np.where(lining_free, d_j, np.minimum(d_j, d_tl))
    dC = np.where(lining_free, d_c, np.minimum(d_c, d_tu))
    jaw = (dJ <= tol) & (dJ <= dC) & (~lining_free | (d_j <= d_t))
    cra = (dC <= tol) & ~jaw & (~lining_free | (d_c <= d_t))
    inner = np.zeros(len(X), bool)
    inner[np.unique(split.inner)] = True
    outer = np.zeros(len(X), bool)
    outer[np.unique(split.outer)] = True
    inner &= ~outer   # nodes on the rim between skin and inner surface belong to the skin
    free_inner = inner & ~jaw & ~cra
    near = np.minimum(d_j, d_c)
    lining = free_inner & (d_t < near) & (d_t <= LINING_MM)
    gap_j = free_inner & ~lining & (d_j <= ON_BONE_GAP_MM) & (d_j <= d_c) & (d_j < d_t)
    gap_c = free_inner & ~lining & (d_c <= ON_BONE_GAP_MM) & (d_c < d_j) & (d_c < d_t)
    jaw |= gap_j
    cra |= gap_c
    rest = free_inner & ~lining & ~gap_j & ~gap_c
    cut = np.zeros(len(X), bool)
    if fix_boundary == "cut":
        cut = rest & ~(d_j < d_c)
        cra |= cut
    counts = {"cranium": int(cra.sum()), "jaw": int(jaw.sum()), "on a bone": int(((d_j <= tol) | (d_c <= tol)).sum()),
              "inside a bone": int((in_j | in_c).sum()),
              "across a gap": int((gap_j | gap_c).sum()), "lining (free)": int(lining.sum()),
              "cut (fixed)": int(cut.sum()), "free inner": int((rest & ~cut).sum())}
    if not cra.any():
        raise FacesimError("model import: no flesh node lies on a cranium bone (and --fix-boundary fixed none): "
                           "give the cranium bones (--cranium), or --fix-boundary cut")
    if not jaw.any():
        raise FacesimError("model import: no flesh node lies on the mandible: is --mandible the jaw of this face, "
                           "in the same frame and units as the flesh?")
    report = {"tolerance_mm": round(tol, 3), "median_edge_mm": round(edge, 3), "counts": counts}
    return np.flatnonzero(cra).astype(np.int32), np.flatnonzero(jaw).astype(np.int32), report


def drop_bridging_tets(X, T, cranium_nodes, jaw_nodes, outer):
    """Remove the tets that have a node attached to the cranium and one attached to the mandible:
    the flesh of a narrow gap between the two bones (maxillary tuberosity and ramus, the gums of a
    closed mouth) that any jaw motion must tear or crush -- on the Badin face 99 tets whose
    inversion under a 0.3 rad opening no material can prevent; anatomically it is joint space and
    loose areolar tissue. Tets with a face on the outer skin ``outer (s, 3)`` are kept (the skin
    stays closed over them). Nodes left without a tet that are free are fixed to the cranium (they
    carry no element). Returns ``(T, cranium_nodes, report)`` with the report's ``tets`` and
    ``volume_mm3``."""
    from facesim.model import signed_volumes

    cr = np.zeros(len(X), bool)
    cr[cranium_nodes] = True
    jw = np.zeros(len(X), bool)
    jw[jaw_nodes] = True
    bridge = cr[T].any(axis=1) & jw[T].any(axis=1)
    if bridge.any() and len(outer):
        n = np.int64(len(X))
        key = lambda f: (f[..., 0] * n + f[..., 1]) * n + f[..., 2]  # noqa: E731 (a sorted face as one integer)
        idx = np.flatnonzero(bridge)
        faces = np.sort(T[idx][:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].astype(np.int64), axis=2)
        on_skin = np.isin(key(faces), key(np.sort(np.asarray(outer, dtype=np.int64), axis=1))).any(axis=1)
        bridge[idx[on_skin]] = False
    volume = float(signed_volumes(X, T[bridge]).sum()) if bridge.any() else 0.0
    T = T[~bridge]
    used = np.zeros(len(X), bool)
    used[T.ravel()] = True
    orphans = np.flatnonzero(~used & ~cr & ~jw)
    if len(orphans):
        cranium_nodes = np.union1d(cranium_nodes, orphans).astype(np.asarray(cranium_nodes).dtype)
    return T, cranium_nodes, {"tets": int(bridge.sum()), "volume_mm3": round(volume, 1), "orphans_fixed": int(len(orphans))}


def _template_meshes(template):
    from facesim.importing import landmarks as lm

    bone = {b.bone: b for b in template.bones}
    col = {c.name: c for c in template.colliders}
    mesh = lm.Mesh

    def of(s):
        return None if s is None else mesh(s.vertices, s.faces)

    return (of(bone.get("jaw")), of(bone.get("cranium")), mesh(template.X, template.skin),
            of(col.get("upper_teeth")), of(col.get("lower_teeth")))


def template_landmarks(template) -> dict:
    """The template's landmarks, found by the same rules as the subject's (so the definitions match)."""
    from facesim.importing import landmarks as lm

    found, _ = lm.detect(*_template_meshes(template), x_mid=0.0)
    return found


def surface_pairs(template_surface, subject_surface, warp, spacing=REFINE_SPACING_MM, max_mm=REFINE_MAX_MM):
    """Correspondences ``(template points (k, 3), subject points (k, 3))`` between two surfaces
    ``(V, F)`` mm, for refining ``warp``: the template's vertices thinned to one per ``spacing``
    mm cube of the template's own frame (so the same points whatever the subject's pose), each
    warped and paired with the nearest subject vertex when that is within ``max_mm``, its normal
    agrees (cosine > 0.5) and it is not on an open edge of the subject's surface (a face mask's
    rim: what lies beyond it, the subject lacks); a subject vertex pairs once (its nearest)."""
    from facesim.importing.meshes import boundary_loops, vertex_normals

    (Vt, Ft), (Vs, Fs) = template_surface, subject_surface
    used = np.unique(Ft)
    _, first = np.unique(np.floor(Vt[used] / spacing).astype(np.int64), axis=0, return_index=True)
    pick = used[np.sort(first)]
    W = warp(Vt[pick])
    nw = vertex_normals(warp(Vt), Ft)[pick]
    ns = vertex_normals(Vs, Fs)
    rim = np.zeros(len(Vs), bool)
    for loop in boundary_loops(np.asarray(Fs, dtype=np.int64)):
        rim[loop] = True
    d, j = cKDTree(Vs).query(W)
    ok = (d <= max_mm) & (np.einsum("ij,ij->i", nw, ns[j]) > 0.5) & ~rim[j]
    P, j, d = Vt[pick][ok], j[ok], d[ok]
    order = np.lexsort((np.arange(len(d)), d))
    _, keep = np.unique(j[order], return_index=True)
    keep = np.sort(order[keep])
    return P[keep], Vs[j[keep]]


def refined_warp(template, landmarks, X, skin, mandible=None, crania=(), iterations=REFINE_ITERATIONS):
    """The warp template -> subject through the ``landmarks`` (both sides found by the same rules),
    refined ``iterations`` times by surface correspondences (:func:`surface_pairs`: the skin onto
    the subject's outer skin ``skin`` over ``X``, the mandible onto ``mandible`` and the cranium
    onto the ``crania`` surfaces), each refit smoothed (:data:`REFINE_SMOOTHING`). Landmarks alone
    leave the warp free between them (a muscle layer warped a few mm off lands outside a thin face
    mask); the surfaces tie skin to skin and bone to bone. Returns ``(warp, report)``."""
    from facesim.importing.template import landmark_warp

    src = template_landmarks(template)
    warp = landmark_warp(src, landmarks, smoothing=WARP_SMOOTHING)
    bone = {b.bone: b for b in template.bones}
    pairs = [((template.X, template.skin), (X, skin))]
    if mandible is not None and "jaw" in bone:
        pairs.append(((bone["jaw"].vertices, bone["jaw"].faces), (mandible.vertices, mandible.faces)))
    if crania and "cranium" in bone:
        pairs.append(((bone["cranium"].vertices, bone["cranium"].faces), _merged(crania)))
    report = {"landmarks_used": sorted(set(src) & set(landmarks)),
              "landmark_rms_mm": round(float(np.sqrt(np.mean(warp.landmark_error() ** 2))), 3), "iterations": []}
    # where the warp must not fold: the template's muscles and its skin (what is carried over)
    domain = template.X[np.unique(np.r_[template.tets[template.muscles.tet].ravel(), template.skin.ravel()])]
    for _ in range(iterations):
        s, d = dict(src), dict(landmarks)
        counts, gaps = [], []
        for k, (tmpl, subj) in enumerate(pairs):
            P, Q = surface_pairs(tmpl, subj, warp)
            counts.append(len(P))
            gaps.append(float(np.sqrt(np.mean(np.sum((warp(P) - Q) ** 2, axis=1)))) if len(P) else 0.0)
            for i in range(len(P)):
                s[f"_s{k}_{i}"], d[f"_s{k}_{i}"] = P[i], Q[i]
        try:
            warp = landmark_warp(s, d, smoothing=REFINE_SMOOTHING, domain=domain)
        except FacesimError as exc:   # a refit that folds: keep the last good warp, and say so
            report["stopped"] = " ".join(str(exc).split())
            break
        report["iterations"].append({"pairs": counts, "gap_rms_mm": [round(g, 3) for g in gaps]})
    return warp, report


def carry_template(template, X, T, skin, landmarks, mandible=None, crania=()):
    """The template's muscles, markers and tissue labels carried onto the flesh ``X``, ``T`` with
    outer skin ``skin`` through the warp between the template's and the subject's ``landmarks``,
    refined by the skin and bone surfaces (:func:`refined_warp`). Returns ``(MuscleSet,
    MarkerSet, tissue (m,) int32, report)``."""
    from facesim.fem.meshes import TetLocator
    from facesim.importing.template import transfer_markers, transfer_muscles

    warp, refine = refined_warp(template, landmarks, X, skin, mandible, crania)
    muscles, mrep = transfer_muscles(template, warp, X, T)
    markers, krep = transfer_markers(template, warp, X, skin)
    # tissue labels: the template's at each tet's centroid pulled back (flesh where it falls outside)
    C = X[T].mean(axis=1)
    P = warp.inverse(C)
    tet, _ = TetLocator(template.X, template.tets, 1.0).locate(P)
    flesh = 0
    tissue = np.where(tet >= 0, template.tissue[np.maximum(tet, 0)], flesh).astype(np.int32)
    report = {"landmarks_used": refine.pop("landmarks_used"), "refinement": refine,
              "muscles": {"flagged": mrep.get("flagged", {}), "per_muscle": mrep.get("muscles", {})},
              "markers": {"dropped": krep.get("dropped", {})},
              "tissues": {t.name: int((tissue == i).sum()) for i, t in enumerate(template.tissues)}}
    return muscles, markers, tissue, report


def _colliders(teeth) -> tuple[tuple, list[str]]:
    """Teeth as colliders (closed by repair; a surface that stays open is left out, said)."""
    from facesim.importing.meshes import repair_surface
    from facesim.model import RigidSurface

    out, notes = [], []
    for role, name, bone in (("teeth_upper", "upper_teeth", "cranium"), ("teeth_lower", "lower_teeth", "jaw")):
        if role not in teeth:
            continue
        s = repair_surface(teeth[role])
        if s.closed:
            out.append(RigidSurface(name, bone, s.vertices, s.faces))
            notes.append(f"{name}: collider ({len(s.faces):,} faces{'; repaired' if s.repairs else ''})")
        else:
            notes.append(f"{name}: still open after repair, no collider (no teeth contact)")
    return tuple(out), notes


def lip_surfaces(X, F, split, landmarks) -> tuple[np.ndarray, np.ndarray, str]:
    """The lips' contact surfaces: flesh boundary faces around the mouth slit that face across it
    or back toward the teeth, upper above the stomion and lower below. Empty with a note when the
    skin has no opening there (closed lips)."""
    need = ("stomion", "cheilion_left", "cheilion_right")
    if any(n not in landmarks for n in need):
        return np.zeros((0, 3), np.int32), np.zeros((0, 3), np.int32), \
            f"no lip contact surfaces: landmarks {', '.join(n for n in need if n not in landmarks)} not found"
    st = landmarks["stomion"]
    half = 0.5 * abs(landmarks["cheilion_left"][0] - landmarks["cheilion_right"][0]) + 4.0
    c = X[F].mean(axis=1)
    n = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    region = (np.abs(c[:, 0] - st[0]) <= half) & (np.abs(c[:, 1] - st[1]) <= 14.0) & (c[:, 2] >= st[2] - 25.0)
    upper = region & (c[:, 1] > st[1]) & ((n[:, 1] < -0.5) | (n[:, 2] < -0.5))
    lower = region & (c[:, 1] < st[1]) & ((n[:, 1] > 0.5) | (n[:, 2] < -0.5))
    across_u = (upper & (n[:, 1] < -0.5)).sum()
    across_l = (lower & (n[:, 1] > 0.5)).sum()
    if across_u < 3 or across_l < 3:
        return np.zeros((0, 3), np.int32), np.zeros((0, 3), np.int32), \
            "closed lips: the skin has no opening between the lips, so no lip contact surfaces; the jaw opens by " \
            "stretching the lips rather than parting them"
    return F[upper].astype(np.int32), F[lower].astype(np.int32), \
        f"lip contact surfaces: upper {int(upper.sum())} faces, lower {int(lower.sum())} faces"


__all__ = ["FIX_BOUNDARY", "RESOLUTIONS", "attachments", "carry_template", "import_model", "lip_surfaces",
           "template_landmarks"]
