"""Mesh quality kernel against a plain-numpy oracle and closed forms."""

import numpy as np
import pytest

from facesim.anatomy.quality import DEGENERATE_RATIO, quality_summary, tet_quality
from facesim.errors import FacesimError

REGULAR = np.array([[1.0, 1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, -1.0], [-1.0, -1.0, 1.0]])  # positive
REGULAR_DIHEDRAL = np.degrees(np.arccos(1.0 / 3.0))  # 70.5288 deg


def naive_quality(X, tets):
    """Slow, obvious oracle: det for the volume, per-edge projected vectors for dihedrals."""
    out = {k: [] for k in ("volume", "min_dihedral_deg", "max_dihedral_deg", "volume_ratio")}
    for tet in tets:
        p = X[tet]
        vol = np.linalg.det(np.array([p[1] - p[0], p[2] - p[0], p[3] - p[0]])) / 6.0
        angles, sq = [], []
        for i, j in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]:
            k, m = (v for v in range(4) if v not in (i, j))
            e = (p[j] - p[i]) / np.linalg.norm(p[j] - p[i])
            u = p[k] - p[i] - np.dot(p[k] - p[i], e) * e  # in-face directions away from the edge
            w = p[m] - p[i] - np.dot(p[m] - p[i], e) * e
            angles.append(np.degrees(np.arccos(np.clip(u @ w / np.linalg.norm(u) / np.linalg.norm(w), -1, 1))))
            sq.append(np.sum((p[j] - p[i]) ** 2))
        l_rms = np.sqrt(np.mean(sq))
        out["volume"].append(vol)
        out["min_dihedral_deg"].append(min(angles))
        out["max_dihedral_deg"].append(max(angles))
        out["volume_ratio"].append(vol / (l_rms ** 3 / (6 * np.sqrt(2))))
    return {k: np.array(v) for k, v in out.items()}


def test_kernel_matches_numpy_oracle_on_random_tets():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(60, 3)) * 10.0
    tets = np.array([rng.choice(60, 4, replace=False) for _ in range(400)])
    got, want = tet_quality(X, tets), naive_quality(X, tets)
    assert (want["volume"] < 0).any() and (want["volume"] > 0).any()  # both orientations exercised
    np.testing.assert_allclose(got["volume"], want["volume"], rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(got["volume_ratio"], want["volume_ratio"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got["min_dihedral_deg"], want["min_dihedral_deg"], atol=1e-6)
    np.testing.assert_allclose(got["max_dihedral_deg"], want["max_dihedral_deg"], atol=1e-6)


def test_regular_tet_is_scale_and_translation_invariant():
    for scale, shift in ((1.0, 0.0), (0.01, 5.0), (250.0, -40.0)):
        q = tet_quality(REGULAR * scale + shift, [[0, 1, 2, 3]])
        np.testing.assert_allclose(q["min_dihedral_deg"], REGULAR_DIHEDRAL, atol=1e-9)
        np.testing.assert_allclose(q["max_dihedral_deg"], REGULAR_DIHEDRAL, atol=1e-9)
        np.testing.assert_allclose(q["volume_ratio"], 1.0, rtol=1e-12)
        np.testing.assert_allclose(q["volume"], 8.0 / 3.0 * scale ** 3, rtol=1e-12)


def test_right_corner_tet_closed_form():
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    q = tet_quality(X, [[0, 1, 2, 3]])
    # three right angles at the axis edges, arccos(1/sqrt 3) at the edges of the oblique face
    np.testing.assert_allclose(q["max_dihedral_deg"], 90.0, atol=1e-9)
    np.testing.assert_allclose(q["min_dihedral_deg"], np.degrees(np.arccos(1 / np.sqrt(3))), atol=1e-9)
    # V = 1/6, edges 1,1,1,sqrt2,sqrt2,sqrt2 -> l_rms^2 = 3/2 -> ratio = sqrt(2) / 1.5^1.5
    np.testing.assert_allclose(q["volume_ratio"], np.sqrt(2) / 1.5 ** 1.5, rtol=1e-12)


def test_flattened_sliver_has_ratio_near_zero_and_extreme_angles():
    eps = 1e-5
    X = np.array([[1, 0, eps], [-1, 0, eps], [0, 1, -eps], [0, -1, -eps]], dtype=float)
    q = tet_quality(X, [[0, 1, 2, 3]])
    np.testing.assert_allclose(abs(q["volume"][0]), 4 * eps / 3, rtol=1e-9)
    assert abs(q["volume_ratio"][0]) < 1e-4
    assert q["min_dihedral_deg"][0] < 0.01 and q["max_dihedral_deg"][0] > 179.99


def test_inverted_tet_has_negative_volume_and_ratio_same_angles():
    q = tet_quality(REGULAR, [[0, 1, 2, 3], [1, 0, 2, 3]])
    np.testing.assert_allclose(q["volume"], [8 / 3, -8 / 3], rtol=1e-12)
    np.testing.assert_allclose(q["volume_ratio"], [1.0, -1.0], rtol=1e-12)
    np.testing.assert_allclose(q["min_dihedral_deg"], REGULAR_DIHEDRAL, atol=1e-9)


def test_collapsed_tet_is_finite_and_degenerate():
    X = np.zeros((4, 3))
    q = tet_quality(X, [[0, 1, 2, 3]])
    assert all(np.isfinite(v).all() for v in q.values())
    assert q["volume_ratio"][0] == 0.0 and q["min_dihedral_deg"][0] == 0.0


def test_summary_counts_inverted_and_degenerate(box_model):
    X = np.vstack([box_model.X, REGULAR + 100.0, [[200, 0, 0], [201, 0, 0], [200, 1, 0], [201, 1, 1e-6]]])
    n = box_model.n_nodes
    tets = np.vstack([box_model.tets, [n + 1, n, n + 2, n + 3], [n + 4, n + 5, n + 6, n + 7]])
    s = quality_summary(X, tets)
    q = tet_quality(X, tets)
    assert s["n_tets"] == box_model.n_tets + 2
    assert q["volume"][-2] < 0 < q["volume"][-1]  # the swapped regular tet is inverted, the sliver is not
    assert s["n_inverted"] == 1
    # degenerate: volume ratio below 1e-3, which counts inverted tets too
    assert q["volume_ratio"][-1] < DEGENERATE_RATIO and s["n_degenerate"] == 2
    assert s["worst_volume_ratio"] == pytest.approx(q["volume_ratio"].min())
    assert s["min_volume_mm3"] == pytest.approx(q["volume"].min())
    assert s["max_dihedral_deg"] > 179.0 and s["min_dihedral_deg"] < 1.0


def test_box_mesh_summary_matches_kuhn_tets(box_model):
    s = quality_summary(box_model.X, box_model.tets)
    # every Kuhn tet of a cube: V = h^3/6, edges h, h, h, h sqrt2, h sqrt2, h sqrt3
    assert s["n_inverted"] == 0 and s["n_degenerate"] == 0
    assert s["min_dihedral_deg"] == pytest.approx(45.0) and s["max_dihedral_deg"] == pytest.approx(90.0)
    assert s["worst_volume_ratio"] == pytest.approx(np.sqrt(2) / (10 / 6) ** 1.5)
    assert s["min_volume_mm3"] == pytest.approx(1000.0 / 6)


@pytest.mark.parametrize("X, tets, words", [
    (np.zeros((4, 2)), [[0, 1, 2, 3]], "X: expected shape (n, 3)"),
    (np.zeros((4, 3)), [[0, 1, 2]], "tets: expected shape (m, 4)"),
    (np.zeros((4, 3)), [[0, 1, 2, 4]], "tets: indices must lie in [0, 4)"),
    (np.zeros((4, 3)), [[0, 1, 2, 3.5]], "tets: expected integer"),
    (np.zeros((4, 3)), np.zeros((0, 4), int), "at least one tet"),
])
def test_bad_input_gives_one_line_error(X, tets, words):
    with pytest.raises(FacesimError) as info:
        quality_summary(X, tets)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_boundary_faces_point_outward():
    from facesim.anatomy.meshing import boundary_faces
    from facesim.fem.meshes import box_mesh

    X, T = box_mesh((2.0, 3.0, 4.0), (2, 2, 3))
    faces, owner = boundary_faces(T)
    assert len(faces) == 2 * 2 * (2 * 2 + 2 * 3 + 2 * 3)
    n = np.cross(X[faces[:, 1]] - X[faces[:, 0]], X[faces[:, 2]] - X[faces[:, 0]])
    c = X[faces].mean(axis=1) - X.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", n, c) > 0)
