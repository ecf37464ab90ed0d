"""Feature points of the markerless jaw tracker (facesim/jaw/markerless_features.py): on the outer
skin and the mandible, and corresponding across subjects of other proportions."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from facesim.jaw.markerless_features import (LAYOUT_VERSION, MandibleChart, feature_layout, grid_shape, mirror_index,
                                             points_on_surface, skin_features, skin_grid)
from facesim.model import JawGeometry, RigidSurface


@pytest.fixture(scope="module")
def shipped():
    from facesim.jaw._shipped import shipped_model

    return shipped_model()


@pytest.fixture(scope="module")
def layout(shipped):
    return feature_layout(shipped)


def _surfaces_subject(sub, h: float = 2.0):
    """A phantom subject's outer skin, mandible and TMJ, without meshing the flesh: the skin and
    mandible isosurfaces of its fields on an ``h`` mm grid (~6 s), shaped like a model for
    :func:`feature_layout`."""
    from facesim.anatomy import meshing, phantom

    fields = phantom.build_fields(sub, h=h)
    sv, sf = meshing.isosurface(fields.skin, fields.grid, smooth_mm=0.5)
    jv, jf = meshing.isosurface(fields.jaw, fields.grid, smooth_mm=0.5)
    return SimpleNamespace(X=sv, skin=sf, bones=(RigidSurface("mandible", "jaw", jv, jf),),
                           jaw=phantom.jaw_geometry(sub, phantom.dental_arches(sub)), n_nodes=len(sv), subject=sub)


@pytest.fixture(scope="module")
def subjects():
    from facesim.anatomy import phantom

    a = _surfaces_subject(phantom.Subject())
    b = _surfaces_subject(phantom.Subject(width=1.08, height=0.94, depth=1.05, jaw_length=1.1, tissue=1.4))
    return a, b, feature_layout(a), feature_layout(b)


def _normalised(layout, P, geometry):
    """Points ``P (k, 3)`` in the subject's own proportions: x / W, (y - incisor) / (incisor -
    lowest point), (z - O) / D (the chart's dimensions)."""
    c = layout.chart
    inc = geometry.incisor
    height = inc[1] - c["landmarks"]["lowest"][1]
    return np.stack([P[:, 0] / c["width_mm"], (P[:, 1] - inc[1]) / height,
                     (P[:, 2] - inc[2] - c["centre_mm"][1]) / c["depth_mm"]], axis=1)


# ------------------------------------------------------------------ the grid
def test_grid_is_the_mask_in_chart_coordinates():
    assert grid_shape(240) == (30, 8)
    g = skin_grid(240)
    assert g.shape == (240, 2)
    assert np.all(np.abs(g[:, 0]) <= 0.9 + 1e-12) and g[:, 1].min() >= 0.1 - 1e-12 and g[:, 1].max() <= 0.9 + 1e-12
    # under the chin the mask stops lower (the lower lip), along the body higher
    top = g.reshape(30, 8, 2)[:, -1, 1]
    assert top[14] < 0.72 and top[0] > 0.89
    m = mirror_index(240)
    assert np.array_equal(m[m], np.arange(240))
    assert np.allclose(g[m, 0], -g[:, 0]) and np.allclose(g[m, 1], g[:, 1])


# ------------------------------------------------------------------ on the shipped model
def test_skin_features_lie_on_the_outer_skin_outward_of_their_bone_points(shipped, layout):
    assert layout.n_features == 240 and layout.version == LAYOUT_VERSION
    assert not layout.fallback.any()
    mesh = trimesh.Trimesh(shipped.X, shipped.skin, process=False)
    _, dist, _ = trimesh.proximity.closest_point(mesh, layout.skin_rest)
    assert dist.max() < 1e-6
    # each skin point is on its bone point's normal ray, outward, a plausible tissue depth away
    d = layout.skin_rest - layout.bone_point
    along = np.einsum("ij,ij->i", d, layout.bone_normal)
    off = np.linalg.norm(d - along[:, None] * layout.bone_normal, axis=1)
    assert off.max() < 1e-6
    assert along.min() > 5.0 and along.max() < 30.0
    assert np.allclose(along, layout.depth)
    # on the outside of the face: the triangle faces along the ray, and is no lip contact surface
    from facesim.mocap.binding import triangle_normals

    nrm = triangle_normals(shipped.X, shipped.skin[layout.triangle])
    assert np.all(np.einsum("ij,ij->i", nrm, layout.bone_normal) > 0.0)
    lining = {tuple(t) for t in np.concatenate([shipped.lip_upper, shipped.lip_lower]).tolist()}
    assert not any(tuple(t) in lining for t in shipped.skin[layout.triangle].tolist())
    # a ray on from the skin point leaves the head: no skin within 10 mm beyond it
    loc, ray, _ = mesh.ray.intersects_location(layout.skin_rest + 0.01 * layout.bone_normal, layout.bone_normal,
                                               multiple_hits=True)
    if len(loc):
        t = np.einsum("ij,ij->i", loc - layout.skin_rest[ray], layout.bone_normal[ray])
        assert t.min() > 10.0


def test_bone_points_lie_on_the_mandible(shipped, layout):
    mand = [s for s in shipped.bones if s.bone == "jaw"][0]
    mesh = trimesh.Trimesh(mand.vertices, mand.faces, process=False)
    for P in (layout.bone_rest, layout.bone_point):
        _, dist, _ = trimesh.proximity.closest_point(mesh, P)
        assert dist.max() < 1e-6
    # outward normals: away from the arch's inside, along the chart column's direction
    chart = MandibleChart.of(shipped)
    column = chart.direction(layout.params[:, 0]) @ chart.frame.axes
    assert np.einsum("ij,ij->i", layout.bone_normal, column).min() > 0.3
    assert layout.bone_names == ("chin", "body_L", "body_R", "angle_L", "angle_R")
    chin, body_l, body_r, angle_l, angle_r = layout.bone_rest
    assert abs(chin[0]) < 1e-9 and chin[2] > body_l[2] > angle_l[2]          # front to back
    assert body_l[0] > 20 and body_r[0] < -20 and angle_l[0] > body_l[0]
    assert np.allclose(body_l * [-1, 1, 1], body_r, atol=1.0) and np.allclose(angle_l * [-1, 1, 1], angle_r, atol=1.0)


def test_features_move_with_the_skin_mesh(shipped, layout):
    assert np.allclose(skin_features(layout, shipped.X), layout.skin_rest, atol=1e-12)
    rng = np.random.default_rng(0)
    x = shipped.X + rng.normal(size=shipped.X.shape)
    p = skin_features(layout, x)
    # the skin mesh simulate writes: the skin's nodes renumbered in increasing order
    nodes = np.unique(shipped.skin)
    faces = np.searchsorted(nodes, shipped.skin)
    assert np.allclose(skin_features(layout, x[nodes]), p, atol=1e-12)
    assert np.allclose(points_on_surface(x[nodes], faces, layout.triangle, layout.bary), p, atol=1e-12)
    # a moved head is undone; batches keep their leading axis
    from facesim.controls import rotation_about

    H = rotation_about([0.1, -0.2, 0.05], [0, 0, 0])
    H[:3, 3] = [5.0, -3.0, 12.0]
    moved = x @ H[:3, :3].T + H[:3, 3]
    assert np.allclose(skin_features(layout, moved, head=H), p, atol=1e-9)
    both = skin_features(layout, np.stack([x, moved]), head=np.stack([np.eye(4), H]))
    assert both.shape == (2, 240, 3) and np.allclose(both[1], p, atol=1e-9)
    from facesim.errors import FacesimError

    with pytest.raises(FacesimError, match="node positions"):
        skin_features(layout, x[:100])


def test_the_medium_model_has_the_same_layout(layout):
    from facesim._files import MESHES
    from facesim.model import load_model

    medium = feature_layout(load_model(MESHES / "face_medium.npz"))
    assert not medium.fallback.any()
    assert np.array_equal(medium.params, layout.params)
    # the same head meshed finer: the same points within the meshes' difference (~1 mm)
    assert np.abs(medium.bone_rest - layout.bone_rest).max() < 1.0
    assert np.median(np.linalg.norm(medium.skin_rest - layout.skin_rest, axis=1)) < 1.0


# ------------------------------------------------------------------ correspondence
def _scaled(model, S):
    """``model`` stretched by the axis scales ``S (3,)`` (a subject of other proportions)."""
    S = np.asarray(S, float)
    jaw = model.jaw
    v = jaw.track_direction * S
    return model.with_(X=model.X * S,
                       bones=tuple(dataclasses.replace(b, vertices=b.vertices * S) for b in model.bones),
                       colliders=tuple(dataclasses.replace(c, vertices=c.vertices * S) for c in model.colliders),
                       jaw=JawGeometry(jaw.condyle_right * S, jaw.condyle_left * S, v / np.linalg.norm(v),
                                       jaw.track_length, jaw.max_opening, jaw.incisor * S))


def test_a_stretched_head_has_the_stretched_features(shipped, layout):
    S = np.array([1.1, 0.93, 1.06])
    other = feature_layout(_scaled(shipped, S))
    assert np.array_equal(other.params, layout.params)
    assert other.chart["width_mm"] == pytest.approx(1.1 * layout.chart["width_mm"], rel=0.01)
    assert other.chart["depth_mm"] == pytest.approx(1.06 * layout.chart["depth_mm"], rel=0.01)
    # every bone point of the one is the same point of the other, stretched (the chart's
    # coordinates are ratios of the mandible's own extents along the frame's axes)
    assert np.abs(other.bone_rest - layout.bone_rest * S).max() < 1e-9
    assert np.abs(other.bone_point - layout.bone_point * S).max() < 1e-9
    # the skin points too, but for the normals, which a stretch turns
    assert np.median(np.linalg.norm(other.skin_rest - layout.skin_rest * S, axis=1)) < 1.0


def test_features_correspond_across_phantom_subjects(subjects):
    a, b, la, lb = subjects
    assert np.array_equal(la.params, lb.params) and np.array_equal(la.mirror, lb.mirror)
    assert not la.fallback.any() and not lb.fallback.any()
    # the chart coordinates of the points found are the grid's, on both subjects
    for model, lay in ((a, la), (b, lb)):
        chart = MandibleChart.of(model)
        assert np.allclose(chart.coordinates(lay.bone_point)[:, 0], lay.params[:, 0], atol=1e-9)
    # the subjects differ: wider, longer jaw, 40 % thicker tissue
    assert lb.chart["width_mm"] > 1.05 * la.chart["width_mm"] and lb.chart["depth_mm"] > 1.1 * la.chart["depth_mm"]
    assert np.median(lb.depth / la.depth) == pytest.approx(1.4, abs=0.1)
    # in each subject's own proportions the points coincide
    na, nb = _normalised(la, la.bone_rest, a.jaw), _normalised(lb, lb.bone_rest, b.jaw)
    assert np.abs(na - nb).max() < 0.02
    na, nb = _normalised(la, la.bone_point, a.jaw), _normalised(lb, lb.bone_point, b.jaw)
    assert np.abs(na - nb).mean(axis=0).max() < 0.01 and np.abs(na - nb).max() < 0.05
    for model, lay in ((a, la), (b, lb)):
        # the chin feature on the chin midline, left and right features mirror images
        assert abs(lay.bone_rest[0, 0]) < 1e-9
        mid = lay.params[:, 0] == 0.0
        assert not mid.any() or np.abs(lay.bone_point[mid, 0]).max() < 1e-9
        centre = lay.mirror[lay.mirror] == np.arange(lay.n_features)
        assert centre.all()
        flip = np.array([-1.0, 1.0, 1.0])
        assert np.linalg.norm(lay.bone_point - lay.bone_point[lay.mirror] * flip, axis=1).max() < 1.0
        # (the test surfaces are isosurfaces of fields sampled on a grid not centred on x = 0:
        # mirror images within ~1 mm, a ray grazing the skin under the angle within a few mm)
        err = np.linalg.norm(lay.skin_rest - lay.skin_rest[lay.mirror] * flip, axis=1)
        assert np.median(err) < 1.0 and np.percentile(err, 95) < 2.5 and err.max() < 8.0
        # the innermost columns straddle the midline
        n_s, n_h = grid_shape(lay.n_features)
        c = lay.skin_rest.reshape(n_s, n_h, 3)
        assert np.abs(0.5 * (c[n_s // 2 - 1, :, 0] + c[n_s // 2, :, 0])).max() < 1.0
