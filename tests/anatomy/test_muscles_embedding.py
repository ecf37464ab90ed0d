"""Muscle embedding: ribbons end where their paths end, rings run round their openings.

The shipped mesh is re-embedded with fields built on a coarse grid (h = 3 mm, a few seconds),
so these tests check the current ``muscles.py`` rather than the muscles stored in the file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from facesim.anatomy import phantom, sdf
from facesim.anatomy.muscles import CATALOGUE, MuscleSpec, embed_muscles
from facesim.model import load_model

SHIPPED = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"

#: (muscle, centre (x, y) mm, semi-axes (x, y) mm) of the rings, docs/physics.md section 6
RINGS = [(f"orbicularis_oris_{half}_{side}", (0.0, -40.0), (26.0, 12.0)) for half in ("upper", "lower") for side in "LR"]
RINGS += [("orbicularis_oculi_L", (32.0, 27.0), (24.0, 20.0)), ("orbicularis_oculi_R", (-32.0, 27.0), (24.0, 20.0))]


@pytest.fixture(scope="module")
def embedded():
    if not SHIPPED.exists():
        pytest.fail(f"shipped model missing: {SHIPPED}")
    head = load_model(SHIPPED)
    sub = phantom.Subject()
    fields = phantom.build_fields(sub, h=3.0)
    muscles, paths = embed_muscles(head.X, head.tets, fields.skin, fields.grid, scale=sub.scaled)
    return dict(head=head, fields=fields, muscles=muscles, paths=paths,
                centroid=head.X[head.tets].mean(axis=1), volume=head.tet_volumes())


def _muscle(embedded, name):
    """Centroids (e, 3) mm, unit fibres (e, 3) and muscle volumes (e,) mm^3 of one muscle's tets."""
    m = embedded["muscles"]
    e = m.entries(m.index(name))
    t = m.tet[e]
    return embedded["centroid"][t], m.fibre[e], embedded["volume"][t] * m.fraction[e]


def _across_ring(c, centre, axes):
    """|fibre . n| where n (e, 2) is the in-plane normal of the ellipse through each centroid,
    concentric and similar to the ring's (the gradient of (x/a)^2 + (y/b)^2). A fibre along
    the ring gives 0, one across it 1. For a 26 x 12 ellipse the normal is not the direction
    from the centre, which is why that direction is not used."""
    n = (c[:, :2] - np.asarray(centre)) / np.asarray(axes) ** 2
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _distance_to_polyline(p, pts, closed):
    """Distance (q,) from points ``p (q, 3)`` to the polyline ``pts (k, 3)``, mm."""
    a, b = (pts, np.roll(pts, -1, axis=0)) if closed else (pts[:-1], pts[1:])
    ab = b - a
    t = np.clip(np.einsum("qsj,sj->qs", p[:, None] - a, ab) / np.einsum("sj,sj->s", ab, ab), 0.0, 1.0)
    return np.linalg.norm(p[:, None] - a - t[..., None] * ab, axis=2).min(axis=1)


@pytest.mark.parametrize("name, centre, axes", RINGS)
def test_ring_fibres_run_around_the_opening(embedded, name, centre, axes):
    c, fibre, vol = _muscle(embedded, name)
    assert vol.sum() > 150.0
    across = np.abs(np.einsum("ij,ij->i", _across_ring(c, centre, axes), fibre[:, :2]))
    assert vol[across < 0.35].sum() / vol.sum() > 0.9, (name, np.median(across))
    if name.startswith("orbicularis_oris"):
        # where the two halves meet: the old lower ring ran up-down here
        mid = np.abs(c[:, 0]) < 8.0
        assert mid.sum() >= 5, name
        assert vol[mid & (across < 0.35)].sum() / vol[mid].sum() > 0.9, (name, np.median(across[mid]))
        assert np.median(np.abs(fibre[mid, 1])) < 0.2, name


@pytest.mark.parametrize("name", [r[0] for r in RINGS if r[0].startswith("orbicularis_oris")])
def test_lip_ring_keeps_its_front_view_ellipse(embedded, name):
    # laid under the skin, the ring must still reach the mouth corners (a push along the skin
    # normal had slid them from x = 26 to x = 18 mm) and sit at its depth below the skin
    pts, _ = embedded["paths"][name]
    f = embedded["fields"]
    on_ellipse = (pts[:, 0] / 26.0) ** 2 + ((pts[:, 1] + 40.0) / 12.0) ** 2
    assert np.allclose(on_ellipse, 1.0, atol=0.02), on_ellipse.round(3)
    assert np.abs(pts[:, 0]).max() > 25.5
    assert np.allclose(-f.grid.sample(f.skin, pts), 4.5, atol=0.5)


def test_procerus_is_a_strip_over_the_nasal_root(embedded):
    both = []
    for side in "LR":
        c, _, vol = _muscle(embedded, f"procerus_{side}")
        assert len(c) >= 10
        assert 100.0 < vol.sum() < 800.0, (side, vol.sum())
        assert np.all(np.abs(c[:, 0]) < 12.0) and np.all((c[:, 1] > 20.0) & (c[:, 1] < 55.0)), side
        both.append(c)
    both = np.concatenate(both)
    assert np.ptp(both[:, 0]) < 18.0            # ~15 mm across, not the whole nose
    assert np.ptp(both[:, 1]) > 12.0            # but running from the nasal bones to the glabella


def test_every_muscle_stays_within_its_ribbon(embedded):
    m, paths = embedded["muscles"], embedded["paths"]
    for spec in CATALOGUE:
        for side in "LR":
            name = f"{spec.name}_{side}"
            c, _, vol = _muscle(embedded, name)
            assert len(c) >= 10 and vol.sum() >= 150.0, (name, len(c), vol.sum())
            d = _distance_to_polyline(c, paths[name][0], spec.closed)
            # centroids of tets with a share of ribbon lie within its half width plus a tet
            assert d.max() < max(max(spec.width), max(spec.thickness)) + 3.0, (name, d.max())
    assert len(m.names) == 32


def test_ribbon_ends_at_its_caps_and_grows_no_tangent_rays():
    # flat skin at z = 100 mm; an L-shaped muscle 3 mm under it, probed by tiny tets
    grid = sdf.Grid.around((-10, -40, 80), (70, 40, 110), 1.0)
    skin = np.broadcast_to(grid.axes()[2] - np.float32(100.0), grid.shape).copy()
    spec = MuscleSpec("bent", ((20, -20, 100), (20, 0, 100), (40, 0, 100)), (3.0, 3.0), (3.0, 3.0), (1.5, 1.5))

    def embed(points):
        corner = 0.05 * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
        X = (points[:, None] + corner - corner.mean(0)).reshape(-1, 3)
        tets = np.arange(len(X), dtype=np.int32).reshape(-1, 4)
        ms, paths = embed_muscles(X, tets, skin, grid, catalogue=(spec,))
        e = ms.entries(ms.index("bent_L"))
        hit = np.zeros(len(points), bool)
        hit[ms.tet[e]] = True
        fibre = np.zeros((len(points), 3))
        fibre[ms.tet[e]] = ms.fibre[e]
        return hit, fibre, paths["bent_L"]

    _, _, (pts, tang) = embed(np.zeros((1, 3)))
    assert np.allclose(pts[:, 2], 97.0, atol=0.05)
    mids = 0.5 * (pts[1:] + pts[:-1])
    rays = pts[1:-1] + 10.0 * tang[1:-1]                  # along each interior vertex's tangent
    rays = rays[_distance_to_polyline(rays, pts, False) > 5.0]
    ends = np.array([pts[0] - 5.0 * tang[0], pts[-1] + 5.0 * tang[-1]])   # past the 1.5 mm caps
    assert len(rays) >= 3
    hit, fibre, _ = embed(np.concatenate([mids, rays, ends]))
    n = len(mids)
    assert hit[:n].all()
    seg = np.diff(pts, axis=0)
    assert np.all(np.einsum("ij,ij->i", fibre[:n], seg / np.linalg.norm(seg, axis=1, keepdims=True)) > 0.9)
    assert not hit[n:].any(), np.flatnonzero(hit[n:])
