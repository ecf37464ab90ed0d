"""facesim.importing.meshes and .cells: reading, cleaning and repairing surfaces, splitting volume
cells into conforming positive tets, units, the skin split and the anatomy checks; on small
meshes made here and on the ArtiSynth Badin face (skipped when shared/anatomy is absent)."""

from __future__ import annotations

import os
from pathlib import Path

import meshio
import numpy as np
import pytest
import trimesh

import facesim
from facesim.errors import FacesimError
from facesim.importing import cells
from facesim.importing.meshes import (check_anatomy, clean_surface, conformity, infer_units, orient_outward,
                                      read_surface, read_volume, repair_surface, split_skin, volume_boundary)

ANATOMY = Path(os.environ.get("FACESIM_ANATOMY", Path(facesim.__file__).resolve().parents[2] / "shared" / "anatomy"))
BADIN = ANATOMY / "badin"
needs_badin = pytest.mark.skipif(not (BADIN / "flesh.vtu").is_file(), reason=f"no Badin data at {BADIN}")


def _volume(V, F) -> float:
    T = V[F]
    return float(np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6.0)


# ===================================================================================== surfaces
@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off", ".vtu"])
def test_read_surface_formats_round_trip(tmp_path, suffix):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    path = tmp_path / f"bone{suffix}"
    if suffix == ".vtu":
        meshio.write(path, meshio.Mesh(sphere.vertices, [("triangle", sphere.faces)]))
    else:
        sphere.export(path)
    s = read_surface(path, "mandible")
    assert s.vertices.shape == (len(sphere.vertices), 3) and s.faces.shape == (len(sphere.faces), 3)
    assert s.faces.dtype == np.int64 and s.closed and s.role == "mandible" and s.path == str(path)
    assert _volume(s.vertices, s.faces) == pytest.approx(sphere.volume, rel=1e-5)   # outward
    if suffix == ".stl":                                   # a triangle soup: the vertices merged back
        assert any("merged" in r for r in s.repairs)


def test_cleaning_repairs_duplicates_degenerates_and_winding(tmp_path):
    box = trimesh.creation.box(extents=(40.0, 30.0, 20.0))
    V, F = box.vertices.copy(), box.faces.copy()
    F_bad = np.concatenate([F[:, ::-1],                     # inside out
                            F[:2],                          # duplicate faces (reversed twins)
                            [[0, 0, 1]]])                   # a repeated vertex
    V_bad = np.concatenate([V, V[:3]])                      # duplicate vertices, unused
    F_bad[3] = F_bad[3] + np.where(F_bad[3] < 3, len(V), 0)  # one face uses the duplicates
    s = clean_surface(V_bad, F_bad, "box.obj", "cranium")
    assert s.closed and len(s.faces) == 12 and len(s.vertices) == 8
    text = " | ".join(s.repairs)
    n_dup = int((F_bad[3] >= len(V)).sum())
    assert f"merged {n_dup} duplicate vertices" in text and f"dropped {3 - n_dup} unused vertices" in text
    assert "dropped 1 degenerate faces" in text and "dropped 2 duplicate faces" in text and "reversed 12 faces" in text
    assert _volume(s.vertices, s.faces) == pytest.approx(24000.0)          # turned outward


def test_holes_are_reported_and_closed(tmp_path):
    box = trimesh.creation.box(extents=(40.0, 30.0, 20.0))
    s = clean_surface(box.vertices, box.faces[2:], "open.obj", "mandible")   # one quad missing
    assert not s.closed and any(r.startswith("open: 1 hole") for r in s.repairs)
    fixed = repair_surface(s)
    assert fixed.closed and any("closed 1 of 1 holes" in r for r in fixed.repairs)
    assert _volume(fixed.vertices, fixed.faces) == pytest.approx(24000.0)
    assert repair_surface(s, close=False) is s


def test_large_hole_closed_by_meshfix():
    pytest.importorskip("pymeshfix")
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    keep = sphere.triangles_center[:, 2] < 20.0                # a cap of ~60 faces cut off
    s = clean_surface(sphere.vertices, sphere.faces[keep], "cap.obj", "mandible")
    assert not s.closed
    fixed = repair_surface(s)
    assert fixed.closed
    cap = np.pi * 10.0 ** 2 * (3 * 30.0 - 10.0) / 3                 # the cut-off cap, filled about flat
    assert abs(_volume(fixed.vertices, fixed.faces)) == pytest.approx(sphere.volume - cap, rel=0.03)


def test_bad_surface_files_are_one_line_errors(tmp_path):
    with pytest.raises(FacesimError, match="no such file") as e:
        read_surface(tmp_path / "missing.obj", "skin")
    assert "missing.obj" in str(e.value) and "\n" not in str(e.value)
    junk = tmp_path / "junk.ply"
    junk.write_text("this is not a mesh\n" * 20)
    with pytest.raises(FacesimError, match="junk.ply") as e:
        read_surface(junk, "skin")
    assert "\n" not in str(e.value)
    obj = tmp_path / "junk.obj"
    obj.write_text("hello world\n")
    with pytest.raises(FacesimError, match="junk.obj"):
        read_surface(obj, "skin")
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    with pytest.raises(FacesimError, match=r"nan.obj: 1 of 4 vertices have non-finite coordinates \(first: vertex 2\)"):
        read_surface(nan, "mandible")
    few = tmp_path / "few.obj"
    few.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n")
    with pytest.raises(FacesimError, match="few.obj: the mandible surface has 2 usable faces"):
        read_surface(few, "mandible")
    vol = tmp_path / "vol.vtu"
    meshio.write(vol, meshio.Mesh(np.eye(4, 3), [("tetra", np.array([[0, 1, 2, 3]]))]))
    with pytest.raises(FacesimError, match="no triangles.*volume"):
        read_surface(vol, "skin")


# ====================================================================================== volumes
def _hex_grid(n=(4, 3, 3), h=10.0, seed=0):
    """A structured hexahedral block with randomly numbered nodes: ``(X, hexes (c, 8) VTK order)``."""
    nx, ny, nz = n
    g = np.stack(np.meshgrid(*(np.arange(k + 1) for k in n), indexing="ij"), -1).reshape(-1, 3) * h
    perm = np.random.default_rng(seed).permutation(len(g))
    X = np.empty_like(g, dtype=float)
    X[perm] = g
    node = perm.reshape(nx + 1, ny + 1, nz + 1)
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(m) for m in n), indexing="ij"))
    H = np.stack([node[i, j, k], node[i + 1, j, k], node[i + 1, j + 1, k], node[i, j + 1, k],
                  node[i, j, k + 1], node[i + 1, j, k + 1], node[i + 1, j + 1, k + 1], node[i, j + 1, k + 1]], 1)
    return X, H


def _boundary_quads(H):
    Q = H[:, cells.CELL_FACES["hexahedron"][1]].reshape(-1, 4)
    _, inv, cnt = np.unique(np.sort(Q, axis=1), axis=0, return_inverse=True, return_counts=True)
    return Q[cnt[inv.ravel()] == 1]


def _assert_conforming(T, n_boundary_triangles):
    interior, boundary, over = conformity(T)
    assert over == 0 and boundary == n_boundary_triangles, (interior, boundary, over)


def test_triangulation_tables():
    counts = {k: len(cells.triangulations(k)) for k in ("tetra", "hexahedron", "wedge", "pyramid")}
    assert counts == {"tetra": 1, "hexahedron": 74, "wedge": 6, "pyramid": 2}
    for kind in counts:                                    # each fills its reference cell, positively
        C = np.asarray(cells.REFERENCE[kind], float)
        ref = cells.cell_volumes(C, np.arange(len(C))[None], kind)[0]
        for T, _ in cells.triangulations(kind):
            v = cells.tet_volumes(C, T)
            assert (v > 0).all() and v.sum() == pytest.approx(ref)


def test_hexahedra_split_conforming_and_positive(tmp_path):
    X, H = _hex_grid()
    rng = np.random.default_rng(1)
    X = X + rng.uniform(-1.5, 1.5, X.shape)               # warped, not inverted
    path = tmp_path / "block.vtu"
    meshio.write(path, meshio.Mesh(X, [("hexahedron", H)]))
    v = read_volume(path)
    assert v.tets.dtype == np.int64 and (cells.tet_volumes(v.X, v.tets) > 0).all()
    _assert_conforming(v.tets, 2 * len(_boundary_quads(H)))
    assert v.volume() == pytest.approx(cells.cell_volumes(X, H, "hexahedron").sum(), rel=3e-3)
    assert len(volume_boundary(v.X, v.tets)) == 2 * len(_boundary_quads(H))
    assert np.array_equal(np.unique(v.cell), np.arange(len(H)))


def test_collapsed_hexahedra_wedges_pyramids_and_quadratic_tets(tmp_path):
    X, H = _hex_grid(n=(3, 2, 2))
    H = H.copy()
    H[0, 3], H[0, 7] = H[0, 2], H[0, 6]                    # face (2,3,7,6) shrunk to an edge: a wedge
    top = H[-1, [4, 5, 6, 7]]
    X2 = np.concatenate([X, [X[top].mean(axis=0) + [0.0, 0.0, 10.0]]])
    pyramid = np.r_[top, len(X)]                           # a pyramid on the block's top
    path = tmp_path / "mixed.vtu"
    meshio.write(path, meshio.Mesh(X2, [("hexahedron", H), ("pyramid", pyramid[None])]))
    v = read_volume(path)
    vol = cells.tet_volumes(v.X, v.tets)
    assert (vol > 1e-6).all()                              # no zero-volume tet from the collapsed one
    assert any("collapse" in n for n in v.notes)
    expected = cells.cell_volumes(X2, H[1:], "hexahedron").sum() + 1000.0 / 2 + 1000.0 / 3
    assert v.volume() == pytest.approx(expected, rel=1e-6)
    assert conformity(v.tets)[2] == 0
    # a quadratic tet is read by its corners
    P = np.concatenate([np.eye(3) * 10, [[0, 0, 0]], np.random.default_rng(0).random((6, 3))])
    q = tmp_path / "tet10.vtu"
    meshio.write(q, meshio.Mesh(P, [("tetra10", np.array([[3, 0, 1, 2, 4, 5, 6, 7, 8, 9]]))]))
    v = read_volume(q)
    assert len(v.tets) == 1 and len(v.X) == 4 and v.volume() == pytest.approx(1000.0 / 6)
    assert any("tetra10" in n for n in v.notes) and any("dropped 6" in n for n in v.notes)


def test_inverted_and_bad_volumes_are_one_line_errors(tmp_path):
    X = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [10, 10, 10]], float)
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [0, 2, 1, 3]])     # the third inverted
    path = tmp_path / "inverted.vtu"
    meshio.write(path, meshio.Mesh(X, [("tetra", tets)]))
    with pytest.raises(FacesimError) as e:
        read_volume(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and "1 of 3 volume cells are inverted" in msg and "first: cell 2" in msg
    assert "\n" not in msg
    # all inverted: a mirror-image node order, turned round
    meshio.write(path, meshio.Mesh(X, [("tetra", tets[[2]])]))
    v = read_volume(path)
    assert (cells.tet_volumes(v.X, v.tets) > 0).all() and any("turned round" in n for n in v.notes)
    with pytest.raises(FacesimError, match="no such file"):
        read_volume(tmp_path / "nothing.vtu")
    junk = tmp_path / "junk.vtu"
    junk.write_text("<VTKFile> garbage")
    with pytest.raises(FacesimError, match="junk.vtu: cannot read the flesh volume mesh"):
        read_volume(junk)
    nan = tmp_path / "nan.vtu"
    meshio.write(nan, meshio.Mesh(np.where(np.arange(15).reshape(5, 3) == 4, np.nan, X), [("tetra", tets[:1])]))
    with pytest.raises(FacesimError, match="nan.vtu: 1 of 5 nodes have non-finite coordinates"):
        read_volume(nan)
    surf = tmp_path / "surf.vtu"
    meshio.write(surf, meshio.Mesh(X, [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(FacesimError, match="no volume cells"):
        read_volume(surf)


# ======================================================================================== units
def test_infer_units():
    head = np.random.default_rng(0).random((100, 3)) * np.array([150.0, 220.0, 180.0])
    assert infer_units(head)[:2] == (1.0, "mm")
    assert infer_units(head / 10)[:2] == (10.0, "cm")
    scale, name, reason = infer_units(head / 1000)
    assert (scale, name) == (1000.0, "m") and reason.startswith("auto: extent 0.21") and "metres" in reason
    assert infer_units(head, "metres")[:2] == (1000.0, "m")
    with pytest.raises(FacesimError, match="--units"):
        infer_units(head * 2.5)                            # 550 mm, 55 cm, 0.55 m: none a face
    with pytest.raises(FacesimError, match="units: expected auto, m, cm or mm"):
        infer_units(head, "inch")


# ================================================================================== skin, checks
def _slab_on_plate():
    """A hexahedral slab 10 mm thick lying on a bone plate: ``(X, tets, bone Surface, top z)``."""
    X, H = _hex_grid(n=(6, 6, 2), h=5.0)
    X = X.astype(float)
    T, _, _ = cells.tetrahedralise(X, [("hexahedron", H)], "slab")
    plate = trimesh.creation.box(extents=(40.0, 40.0, 4.0))
    bone = clean_surface(plate.vertices + np.array([15.0, 15.0, -2.0]), plate.faces, "plate.obj", "cranium")
    return X, T, bone


def test_split_skin_separates_the_surface_on_the_bone():
    X, T, bone = _slab_on_plate()
    F = volume_boundary(X, T)
    split = split_skin(X, F, [bone])
    c_out, c_in = X[split.outer].mean(axis=1), X[split.inner].mean(axis=1)
    assert len(split.outer) + len(split.inner) == len(F)
    assert (c_in[:, 2] < 9.0).all()                        # no top face is inner (the sides: either)
    assert (np.isclose(c_out[:, 2], 0.0)).sum() == 0       # the bottom, on the plate, is all inner
    assert (np.isclose(c_in[:, 2], 0.0)).sum() == 72
    assert (np.isclose(c_out[:, 2], 10.0)).sum() == 72     # the top (6 x 6 quads) is all skin
    assert "outer skin" in split.summary(X)


def test_check_anatomy_finds_bones_through_the_skin():
    skin = clean_surface(trimesh.creation.icosphere(3, radius=80.0).vertices,
                         trimesh.creation.icosphere(3, radius=80.0).faces, "skin.stl", "skin")
    ball = trimesh.creation.icosphere(2, radius=30.0)
    inside = clean_surface(ball.vertices, ball.faces, "mandible.obj", "mandible")
    assert check_anatomy(skin, [inside]) == ["mandible.obj: under the skin"]
    poking = clean_surface(ball.vertices + [60.0, 0.0, 0.0], ball.faces, "mandible.obj", "mandible")
    with pytest.raises(FacesimError, match=r"mandible.obj: \d+ of \d+ vertices of the mandible lie more than 2 mm "
                                           r"outside the skin skin.stl \(up to 1\d\.\d mm\)") as e:
        check_anatomy(skin, [poking])
    assert "\n" not in str(e.value)
    away = clean_surface(ball.vertices * 1000, ball.faces, "mandible.obj", "mandible")
    with pytest.raises(FacesimError, match="wholly outside the skin"):
        check_anatomy(skin, [away])
    # an open mask (the front half, inside out): oriented away from the bones, then in front = out
    mask = trimesh.creation.icosphere(3, radius=80.0)
    keep = mask.triangles_center[:, 2] > 0
    front = orient_outward(clean_surface(mask.vertices, mask.faces[keep][:, ::-1], "mask.obj", "skin"), ball.vertices)
    assert any("reversed all faces" in r for r in front.repairs)
    assert check_anatomy(front, [inside])[0].endswith("under the skin")
    ahead = clean_surface(ball.vertices + [0.0, 0.0, 75.0], ball.faces, "chin.obj", "mandible")
    with pytest.raises(FacesimError, match="chin.obj"):
        check_anatomy(front, [ahead])


# ======================================================================================== Badin
@pytest.fixture(scope="module")
def badin_volume():
    return read_volume(BADIN / "flesh.vtu")


@needs_badin
def test_badin_volume(badin_volume):
    v = badin_volume
    vol = cells.tet_volumes(v.X, v.tets)
    assert (vol > 0).all()
    assert v.volume() * 1e6 == pytest.approx(698.0, abs=3.0)          # cm^3
    H = meshio.read(BADIN / "flesh.vtu").cells_dict["hexahedron"]
    # the cells' faces by their distinct nodes (a collapsed quad is a triangle, or an edge)
    Q = np.sort(H[:, cells.CELL_FACES["hexahedron"][1]].reshape(-1, 4), axis=1)
    Q = np.where(np.c_[np.zeros(len(Q), bool), Q[:, 1:] == Q[:, :-1]], -1, Q)
    Q = np.sort(Q, axis=1)
    n_nodes = (Q >= 0).sum(axis=1)
    u, count = np.unique(Q[n_nodes >= 3], axis=0, return_counts=True)
    outer = u[count == 1]
    expected = int(2 * ((outer >= 0).sum(axis=1) == 4).sum() + ((outer >= 0).sum(axis=1) == 3).sum())
    _assert_conforming(v.tets, expected)
    # and the tets' boundary triangles lie on those outer faces
    B = np.sort(volume_boundary(v.X, v.tets), axis=1)
    on = {tuple(f[f >= 0]) for f in outer}
    assert all(any(set(t) <= set(f) for f in on if len(set(t) & set(f)) == 3) for t in map(tuple, B[:200]))
    assert any("collapse" in n for n in v.notes) and any("warped" in n for n in v.notes)
    assert infer_units(v.X)[:2] == (1000.0, "m")


@needs_badin
def test_badin_skin_split_and_anatomy(badin_volume):
    v = badin_volume
    X = v.X * 1000.0
    bones = [read_surface(BADIN / f"{n}.obj", n).transformed(np.eye(4), 1000.0)
             for n in ("mandible", "maxilla", "teeth_lower", "teeth_upper")]
    F = volume_boundary(X, v.tets)
    split = split_skin(X, F, bones)
    area = [0.5 * np.linalg.norm(np.cross(X[f[:, 1]] - X[f[:, 0]], X[f[:, 2]] - X[f[:, 0]]), axis=1).sum()
            for f in split]
    assert 50_000 < area[0] < 75_000 and 35_000 < area[1] < 60_000          # mm^2, outer and inner
    nose = np.argmin(X[:, 0])                                                # x backward: the nose tip
    assert nose in split.outer and nose not in split.inner
    skin = clean_surface(X, split.outer, "flesh.vtu", "skin")
    skin = orient_outward(skin, np.concatenate([b.vertices for b in bones]))
    lines = check_anatomy(skin, bones)
    assert len(lines) == 4 and lines[0] == "mandible.obj: under the skin"


@needs_badin
def test_badin_upper_teeth_close_as_read():
    """trimesh's hole fans leave Badin's upper dentition with edges of three faces that MeshFix
    cannot mend; MeshFix on the scan as read (its stray triangles left out) closes it, so the
    upper teeth become a collider."""
    s = read_surface(BADIN / "teeth_upper.obj", "teeth_upper")
    assert not s.closed
    fixed = repair_surface(s)
    assert fixed.closed, fixed.repairs
    assert any("as read" in r and "stray faces left out" in r for r in fixed.repairs), fixed.repairs
    assert not any("trimesh fill_holes" in r for r in fixed.repairs)
    assert len(fixed.faces) > 0.99 * len(s.faces)   # the scan, not a hull
    # the closed surface lies on the scan: every repaired vertex within 0.5 mm of the original
    d = trimesh.proximity.closest_point(trimesh.Trimesh(s.vertices, s.faces, process=False),
                                        fixed.vertices[:: max(1, len(fixed.vertices) // 2000)])[1]
    assert d.max() * 1000.0 < 0.5


def test_stray_pieces_are_left_out():
    from facesim.importing.meshes import _without_debris

    box = trimesh.creation.box(extents=(1, 1, 1))
    V = np.r_[np.asarray(box.vertices), [[5, 5, 5], [6, 5, 5], [5, 6, 5]]]
    F = np.r_[np.asarray(box.faces), [[8, 9, 10]]]
    V2, F2, dropped = _without_debris(V, F)
    assert dropped == 1 and len(F2) == 12 and len(V2) == 8
