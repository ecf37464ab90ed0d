"""The shipped procedural head (meshes/face_coarse.npz) and the builder's deterministic parts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from facesim.anatomy import meshing, phantom
from facesim.anatomy.markers import bind_markers, marker_table
from facesim.anatomy.muscles import CATALOGUE, embed_muscles, muscle_names
from facesim.anatomy.quality import quality_summary
from facesim.model import load_model

SHIPPED = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"


@pytest.fixture(scope="module")
def head():
    if not SHIPPED.exists():
        pytest.fail(f"shipped model missing: {SHIPPED}")
    return load_model(SHIPPED)


def test_counts_and_names(head):
    assert head.n_muscles == 32
    assert list(head.muscles.names) == muscle_names()
    assert head.n_markers >= 80
    assert head.markers.head.sum() >= 4
    assert 10_000 <= head.n_simulated <= head.n_tets


def test_no_inverted_or_degenerate_tets(head):
    q = quality_summary(head.X, head.tets)
    assert q["n_inverted"] == 0
    assert q["n_degenerate"] == 0
    assert q["min_dihedral_deg"] > 5.0
    assert np.all(head.tet_volumes() > 0)


def test_every_muscle_is_embedded_with_unit_fibres(head):
    vol = head.muscles.volume_per_muscle(head.tet_volumes())
    count = head.muscles.tets_per_muscle()
    assert np.all(count >= 10), dict(zip(head.muscles.names, count))   # the corrugator is ~15 mm long
    assert np.all(vol >= 150.0), dict(zip(head.muscles.names, vol.round()))
    assert np.allclose(np.linalg.norm(head.muscles.fibre, axis=1), 1.0)
    # left and right twins are near mirror images
    for i in range(0, 32, 2):
        assert 0.6 < vol[i] / vol[i + 1] < 1.6


def test_muscles_sit_where_anatomy_puts_them(head):
    c = head.X[head.tets].mean(axis=1)
    for name, (lo, hi) in {
        "frontalis_L": ((5, 50, 40), (60, 110, 100)),
        "zygomaticus_major_L": ((25, -48, 50), (70, 12, 100)),
        "mentalis_R": ((-20, -95, 70), (5, -50, 110)),
        "orbicularis_oris_upper_L": ((-5, -48, 70), (40, -20, 115)),
    }.items():
        m = head.muscles.index(name)
        e = head.muscles.entries(m)
        centre = np.average(c[head.muscles.tet[e]], axis=0, weights=head.muscles.fraction[e])
        assert np.all(centre > lo) and np.all(centre < hi), (name, centre)


def test_ring_muscle_fibres_are_circumferential(head):
    c = head.X[head.tets].mean(axis=1)
    # the lip ring is flat: across its middle third the fibres run around the mouth, not up-down
    for name in ("orbicularis_oris_upper_L", "orbicularis_oris_lower_R"):
        e = head.muscles.entries(head.muscles.index(name))
        mid = np.abs(c[head.muscles.tet[e], 0]) < 12
        assert mid.sum() > 5
        assert np.median(np.abs(head.muscles.fibre[e][mid, 1])) < 0.5, name
    for name, centre in (("orbicularis_oculi_L", (32, 27, 0)), ("orbicularis_oculi_R", (-32, 27, 0))):
        e = head.muscles.entries(head.muscles.index(name))
        radial = c[head.muscles.tet[e]] - centre
        radial[:, 2] = 0
        radial /= np.linalg.norm(radial, axis=1, keepdims=True)
        along = np.abs(np.einsum("ij,ij->i", radial, head.muscles.fibre[e]))
        assert np.median(along) < 0.35, (name, np.median(along))


def test_attachments_disjoint_and_on_bone(head):
    cran, jaw = head.cranium_nodes, head.jaw_nodes
    assert len(cran) > 100 and len(jaw) > 50
    assert np.intersect1d(cran, jaw).size == 0
    mandible = head.surface("mandible")
    m = trimesh.Trimesh(mandible.vertices, mandible.faces, process=False)
    _, dist, _ = trimesh.proximity.closest_point(m, head.X[jaw])
    assert np.percentile(dist, 95) < 2.0
    # lips over the teeth are free to slide
    lips = np.unique(np.r_[head.lip_upper.ravel(), head.lip_lower.ravel()])
    assert len(lips) > 30
    assert np.intersect1d(lips, np.r_[cran, jaw]).size == 0


def test_bones_and_colliders_are_closed_manifolds(head):
    for s in head.bones + head.colliders:
        assert meshing.is_closed_manifold(s.faces), s.name
        assert trimesh.Trimesh(s.vertices, s.faces, process=False).volume > 0, s.name


def test_skin_is_closed_and_manifold(head):
    """Skin, mouth lining and the flat neck cut bound the head: one closed, outward surface."""
    assert meshing.is_closed_manifold(head.skin)
    assert len(np.unique(meshing.face_components(head.skin))) == 1
    mesh = trimesh.Trimesh(head.X, head.skin, process=False)
    assert mesh.volume > 1e6   # mm^3: a head, oriented outward
    # the bones sit inside it
    for s in head.bones:
        assert mesh.contains(s.vertices[::50]).mean() > 0.95, s.name


def test_only_the_face_is_simulated_and_the_rest_is_attached(head):
    c = head.X[head.tets].mean(axis=1)
    sim = head.simulated
    assert 0.3 < sim.mean() < 0.9
    # the face region in front of the ears is simulated, the back of the head is not
    face = (c[:, 2] > 40) & (np.abs(c[:, 1]) < 90)
    assert sim[face].mean() > 0.99
    # behind the region (and the tets straddling its edge, up to one ~9 mm element) nothing is
    assert not sim[c[:, 2] < phantom.FACE_REGION["z_min"] - 5.0].any()
    assert sim[c[:, 2] < phantom.FACE_REGION["z_min"] - 5.0].size > 1000
    attached = np.zeros(head.n_nodes, bool)
    attached[head.cranium_nodes] = True
    attached[head.jaw_nodes] = True
    assert attached[head.tets[~sim]].all()


def test_markers_lie_on_the_skin(head):
    pos = head.marker_positions()
    skin = trimesh.Trimesh(head.X, head.skin, process=False)
    _, dist, _ = trimesh.proximity.closest_point(skin, pos)
    assert dist.max() < 1e-6
    # and each one near its design position (bound to the closest outer-skin triangle)
    design = np.array([p for _, p, _ in marker_table()])
    assert np.median(np.linalg.norm(pos - design, axis=1)) < 6.0


def test_soft_tissue_depths_in_published_ranges(head):
    """The anatomy puts every landmark depth inside its docs/physics.md range; the meshed skin follows
    it to within the fTetWild envelope (about 1 mm at coarse resolution)."""
    depths = head.meta["soft_tissue_depths"]
    assert set(depths) == {name for name, *_ in phantom.DEPTH_LANDMARKS}
    bad = {k: round(v["anatomy_depth_mm"], 2) for k, v in depths.items()
           if not v["range_mm"][0] <= v["anatomy_depth_mm"] <= v["range_mm"][1]}
    assert not bad, bad
    tol = head.meta["envelope_mm"]
    assert 0 < tol < 1.5
    bad = {k: round(v["depth_mm"], 2) for k, v in depths.items()
           if not v["range_mm"][0] - tol <= v["depth_mm"] <= v["range_mm"][1] + tol}
    assert not bad, bad


def test_fields_are_deterministic_for_a_seed():
    a = phantom.build_fields(phantom.subject_from_seed(3), h=4.0)
    b = phantom.build_fields(phantom.subject_from_seed(3), h=4.0)
    c = phantom.build_fields(phantom.subject_from_seed(4), h=4.0)
    for name in ("cranium", "jaw", "teeth_upper", "teeth_lower", "mouth", "skin"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(a.skin, c.skin)


def test_embedding_and_binding_are_deterministic(head):
    g = phantom.build_fields(phantom.Subject(), h=3.0)
    m1, _ = embed_muscles(head.X, head.tets, g.skin, g.grid)
    m2, _ = embed_muscles(head.X, head.tets, g.skin, g.grid)
    assert np.array_equal(m1.tet, m2.tet) and np.array_equal(m1.fraction, m2.fraction)
    outer = np.ones(len(head.skin), bool)
    k1 = bind_markers(head.X, head.skin, outer)
    k2 = bind_markers(head.X, head.skin, outer)
    assert np.array_equal(k1.triangle, k2.triangle) and np.array_equal(k1.bary, k2.bary)
    assert len(CATALOGUE) == 16


@pytest.mark.slow
def test_rebuild_from_the_shipped_mesh_reproduces_the_model(head, tmp_path):
    """``model build --mesh-from``: everything but fTetWild is deterministic (about 3 minutes)."""
    from facesim.anatomy import build_head

    built = build_head(head.meta["resolution"], seed=head.meta["seed"], mesh=(head.X, head.tets))
    m = load_model(built.save(tmp_path / "again.npz"))   # compare as stored (some fields are float32)
    for name in ("X", "tets", "tissue", "simulated", "cranium_nodes", "jaw_nodes", "skin", "lip_upper", "lip_lower"):
        assert np.array_equal(getattr(m, name), getattr(head, name)), name
    assert np.array_equal(m.muscles.fraction, head.muscles.fraction)
    assert np.array_equal(m.muscles.fibre, head.muscles.fibre)
    assert np.array_equal(m.markers.bary, head.markers.bary)
