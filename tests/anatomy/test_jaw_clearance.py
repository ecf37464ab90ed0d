"""Room for the mandible: the rigid core stays clear of it in every pose of the jaw's range, and
no flesh of the shipped head is clamped between the two bones.

Opening to 0.5 rad used to invert ~120 tets of flesh caught between the moving mandible and the
rigid deep core (floor of the mouth, medial to the ramus and the angle).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from facesim.anatomy import phantom, sdf
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import load_model

SHIPPED = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"


@pytest.fixture(scope="module")
def head():
    return load_model(SHIPPED)


def _rotation_x(angle):
    T = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T


def test_swept_occupancy_matches_an_inverse_sampling_oracle():
    """Forward splatting of the occupied voxels against the obvious definition: a voxel is swept
    if some pose maps a point of the body onto it (its centre pulled back lands in the body)."""
    g = sdf.Grid((-20.0, -20.0, -20.0), 1.0, (41, 41, 41))
    x, y, z = g.axes()
    inside = np.broadcast_to((np.abs(x) < 3) & (np.abs(y + 9) < 4) & (np.abs(z) < 5), g.shape)
    poses = np.array([_rotation_x(a) for a in np.linspace(0.0, 1.2, 25)])
    for stride in (1, 2):
        got = phantom.swept_occupancy(g, inside, poses, stride=stride)
        assert got[inside].all()
        centres = g.to_world(np.argwhere(np.ones(g.shape, bool)))
        want = np.zeros(g.shape, bool).ravel()
        for T in poses:
            back = (centres - T[:3, 3]) @ T[:3, :3]
            want |= g.sample(inside.astype(np.float32), back) > 0.5
        want = want.reshape(g.shape)
        assert got.sum() > 2 * inside.sum()                   # it did sweep
        # the two agree up to the rounding of a block: every voxel of one lies near the other
        for a, b in ((got, want), (want, got)):
            far = sdf.exact_sdf(b, g.h)[a & ~b]
            assert far.size == 0 or far.max() <= 1.5 * stride * np.sqrt(3), (stride, far.max())


def test_jaw_geometry_is_the_shipped_models(head):
    sub = phantom.subject_from_seed(head.meta["seed"])
    geometry = phantom.jaw_geometry(sub, phantom.dental_arches(sub))
    for name in ("condyle_right", "condyle_left", "track_direction", "incisor"):
        np.testing.assert_allclose(getattr(geometry, name), getattr(head.jaw, name))
    assert geometry.max_opening == head.jaw.max_opening and geometry.track_length == head.jaw.track_length
    poses = phantom.jaw_range_poses(geometry, 3, 2)
    jaw = SlidingCondyleJaw(geometry)
    assert len(poses) == 12
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(poses[-1], jaw.transform([geometry.max_opening, geometry.track_length,
                                                         geometry.track_length]))


def test_rigid_core_keeps_clear_of_the_mandible_in_every_pose():
    """The deep core the builder grows onto the cranium keeps its clearance from the mandible and
    the floor of the mouth it carries, in every pose of the sliding-condyle range."""
    sub = phantom.Subject()
    f = phantom.build_fields(sub, h=3.0)
    arches = phantom.dental_arches(sub)
    core = (f.cranium < 0) & ~(f.cranium_skull < 0)
    assert core.sum() * 27.0 > 1e5                           # mm^3: there is a core
    carried = (f.jaw < 0) | (phantom.floor_of_mouth_field(f.grid, sub, arches) < 0)
    poses = phantom.jaw_range_poses(phantom.jaw_geometry(sub, arches))
    clearance = sdf.exact_sdf(phantom.swept_occupancy(f.grid, carried, poses), f.grid.h)[core]
    # the core's field is smoothed by a voxel or so and the sweep is sampled: a few mm of slack
    assert clearance.min() > phantom.CORE_CLEARANCE["jaw"] - 3 * f.grid.h, clearance.min()


def test_no_flesh_is_clamped_between_the_bones(head):
    """No tet holds nodes of both bones, and along the natural opening path to the maximum the
    nodes on the mandible stay clear of those on the cranium: the flesh between can move."""
    on_cranium = np.zeros(head.n_nodes, bool)
    on_cranium[head.cranium_nodes] = True
    on_jaw = np.zeros(head.n_nodes, bool)
    on_jaw[head.jaw_nodes] = True
    assert not (on_cranium & on_jaw).any()
    assert not (on_cranium[head.tets].any(axis=1) & on_jaw[head.tets].any(axis=1)).any()
    jaw = SlidingCondyleJaw(head.jaw)
    tree = cKDTree(head.X[head.cranium_nodes])
    gaps = []
    for opening in np.linspace(0.0, head.jaw.max_opening, 9):
        T = jaw.transform(jaw.natural_parameters(opening))
        gaps.append(tree.query(head.X[head.jaw_nodes] @ T[:3, :3].T + T[:3, 3])[0].min())
    assert min(gaps) > MIN_GAP_MM, np.round(gaps, 1)


#: Smallest distance (mm) between a jaw node and a cranium node along the natural opening path:
#: the condylar neck passes ~10 mm under the root of the zygomatic arch; the chin stays ~30 mm
#: above the neck cut (held by the cranium) at full opening.
MIN_GAP_MM = 7.0
