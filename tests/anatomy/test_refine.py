"""Uniform 1:8 refinement of a tet mesh (a finer model without fTetWild)."""

import numpy as np
import pytest

from facesim.anatomy.meshing import boundary_faces, refine_tets
from facesim.anatomy.quality import quality_summary
from facesim.cli import main
from facesim.model import signed_volumes
from tests.conftest import box_tets


def _area(X, faces):
    return 0.5 * np.linalg.norm(np.cross(X[faces[:, 1]] - X[faces[:, 0]], X[faces[:, 2]] - X[faces[:, 0]]), axis=1).sum()


def test_children_split_their_parent_and_keep_the_surface():
    X, T = box_tets((3, 3, 2), spacing=10.0)
    rng = np.random.default_rng(0)
    X = X + 1.5 * rng.normal(size=X.shape)   # irregular tets, still positive
    assert (signed_volumes(X, T) > 0).all()
    Xr, Tr = refine_tets(X, T)
    edges = {tuple(sorted(e)) for t in T for e in ((t[0], t[1]), (t[0], t[2]), (t[0], t[3]),
                                                    (t[1], t[2]), (t[1], t[3]), (t[2], t[3]))}
    assert len(Xr) == len(X) + len(edges) and len(Tr) == 8 * len(T)
    np.testing.assert_array_equal(Xr[:len(X)], X)
    V = signed_volumes(Xr, Tr).reshape(-1, 8)
    np.testing.assert_allclose(V, np.repeat(signed_volumes(X, T)[:, None] / 8, 8, axis=1), rtol=1e-12)
    # every child lies inside its parent: its centroid's barycentric coordinates are in [0, 1]
    c = Xr[Tr].mean(axis=1).reshape(-1, 8, 3)
    D = np.stack([X[T[:, j]] - X[T[:, 0]] for j in (1, 2, 3)], axis=2)
    lam = np.linalg.solve(D[:, None], (c - X[T[:, 0]][:, None])[..., None])[..., 0]
    assert lam.min() > 0 and lam.sum(axis=2).max() < 1
    faces, _ = boundary_faces(T)
    faces_r, _ = boundary_faces(Tr)
    assert len(faces_r) == 4 * len(faces)
    assert _area(Xr, faces_r) == pytest.approx(_area(X, faces), rel=1e-12)
    # the shortest octahedron diagonal keeps the shape bounded
    assert quality_summary(Xr, Tr)["min_dihedral_deg"] > 0.6 * quality_summary(X, T)["min_dihedral_deg"]
    # deterministic
    Xs, Ts = refine_tets(X, T)
    assert np.array_equal(Xs, Xr) and np.array_equal(Ts, Tr)


def test_refine_needs_a_mesh_to_refine(tmp_path, capsys):
    assert main(["model", "build", "--refine", "1", "-o", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert "--mesh-from" in err and len(err.strip().splitlines()) == 1
