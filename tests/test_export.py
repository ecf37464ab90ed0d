"""Exporters: what meshio reads back from the VTU, PLY and OBJ files."""

import meshio
import numpy as np
import pytest

from facesim.errors import FacesimError
from facesim.export import export_skin, export_surfaces, export_volume

CELL_FIELDS = {"tissue", "simulated", "muscle", "muscle_fraction", "muscle_total_fraction", "fibre"}


def test_volume_vtu_round_trip(box_model, tmp_path):
    path = export_volume(box_model, tmp_path / "v.vtu")
    mesh = meshio.read(path)
    assert len(mesh.cells) == 1 and mesh.cells[0].type == "tetra"
    np.testing.assert_array_equal(mesh.cells[0].data, box_model.tets)
    np.testing.assert_allclose(mesh.points, box_model.X)
    assert set(mesh.cell_data) == CELL_FIELDS
    cd = {k: v[0] for k, v in mesh.cell_data.items()}
    assert all(len(v) == box_model.n_tets for v in cd.values())
    np.testing.assert_array_equal(cd["tissue"], box_model.tissue)
    np.testing.assert_array_equal(cd["simulated"], box_model.simulated)

    mus = box_model.muscles
    zyg, orb = (set(mus.tet[mus.entries(m)].tolist()) for m in range(2))
    both, neither = zyg & orb, set(range(box_model.n_tets)) - zyg - orb
    assert both and neither and orb - zyg
    both, neither, orb_only = sorted(both), sorted(neither), sorted(orb - zyg)
    assert (cd["muscle"][both] == 0).all()  # zygomaticus (0.55) beats orbicularis (0.4)
    assert (cd["muscle"][orb_only] == 1).all() and (cd["muscle"][neither] == -1).all()
    np.testing.assert_allclose(cd["muscle_fraction"][both], 0.55, rtol=1e-6)
    np.testing.assert_allclose(cd["muscle_total_fraction"][both], 0.95, rtol=1e-6)
    np.testing.assert_allclose(cd["muscle_total_fraction"][neither], 0.0)
    np.testing.assert_allclose(cd["fibre"][both], np.tile([-1, -1, 0], (len(both), 1)) / np.sqrt(2), atol=1e-6)
    np.testing.assert_allclose(cd["fibre"][orb_only], np.tile([1, 0, 0], (len(orb_only), 1)), atol=1e-6)
    np.testing.assert_array_equal(cd["fibre"][neither], 0.0)

    att = mesh.point_data["attachment"]
    assert (att == 1).sum() == len(box_model.cranium_nodes) and (att == 2).sum() == len(box_model.jaw_nodes)
    np.testing.assert_array_equal(np.flatnonzero(att == 1), box_model.cranium_nodes)
    assert (att == 0).sum() == box_model.n_nodes - len(box_model.cranium_nodes) - len(box_model.jaw_nodes)


def test_volume_with_deformed_positions(box_model, tmp_path):
    x = box_model.X * 2.0 + 1.0
    mesh = meshio.read(export_volume(box_model, tmp_path / "x.vtu", x=x))
    np.testing.assert_allclose(mesh.points, x)
    with pytest.raises(FacesimError, match="x: expected node positions"):
        export_volume(box_model, tmp_path / "bad.vtu", x=x[:-1])


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_skin_keeps_only_used_nodes_and_orientation(box_model, tmp_path, suffix):
    mesh = meshio.read(export_skin(box_model, tmp_path / f"skin{suffix}"))
    tri = mesh.cells_dict["triangle"]
    assert len(tri) == len(box_model.skin) == 296
    assert len(mesh.points) == len(np.unique(box_model.skin)) == 210 - 5 * 4 * 3  # box nodes minus interior
    # same triangles, same vertex order (so the same outward orientation)
    np.testing.assert_allclose(mesh.points[tri], box_model.X[box_model.skin], atol=1e-5)


def test_surfaces_one_ply_per_rigid_surface(box_model, tmp_path):
    paths = export_surfaces(box_model, tmp_path / "surf")
    assert [p.name for p in paths] == ["cranium.ply", "mandible.ply", "teeth_lower.ply", "eye_L.ply"]
    for p, s in zip(paths, box_model.bones + box_model.colliders):
        mesh = meshio.read(p)
        assert len(mesh.points) == len(s.vertices)
        np.testing.assert_allclose(mesh.points[mesh.cells_dict["triangle"]], s.vertices[s.faces], atol=1e-5)


@pytest.mark.parametrize("writer, name", [(export_volume, "v.ply"), (export_volume, "v"),
                                          (export_skin, "s.vtu"), (export_skin, "s.stl")])
def test_unknown_suffix_is_one_line_error(box_model, tmp_path, writer, name):
    with pytest.raises(FacesimError) as info:
        writer(box_model, tmp_path / name)
    assert name in str(info.value) and "expected" in str(info.value) and "\n" not in str(info.value)
    assert not (tmp_path / name).exists()


def test_surfaces_refuses_a_file_as_folder(box_model, tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(FacesimError, match="expected a folder"):
        export_surfaces(box_model, tmp_path / "f")
