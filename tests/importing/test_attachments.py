"""The importer's attachment rules on a synthetic flesh block (no anatomy needed): flesh that a
closed bone surface overlaps moves with the bone however deep it lies (a volume mesh of the soft
tissue may reach into the bones: Badin's flesh reaches 5 mm into the mandible)."""

import numpy as np
import trimesh
from scipy.spatial import Delaunay

from facesim.importing.build import attachments
from facesim.importing.meshes import SkinSplit, Surface, volume_boundary
from facesim.model import positively_oriented


def _bone(mesh, role):
    return Surface(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64), f"{role}.obj", role,
                   closed=bool(mesh.is_watertight))


def test_flesh_inside_a_closed_bone_moves_with_it():
    g = np.linspace(-30.0, 30.0, 13)                                   # a 60 mm block, 5 mm grid
    X = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    T = positively_oriented(X, Delaunay(X).simplices.astype(np.int64))
    split = SkinSplit(volume_boundary(X, T), np.zeros((0, 3), np.int64))
    mandible = _bone(trimesh.creation.icosphere(4, 14.0), "mandible")                 # inside the block
    cranium = _bone(trimesh.creation.box((10.0, 10.0, 10.0)).apply_translation((30.0, 30.0, 30.0)), "cranium")
    cra, jaw, report = attachments(X, T, split, mandible, [cranium], [])
    r = np.linalg.norm(X, axis=1)
    deep = r < 14.0 - report["tolerance_mm"] - 0.5                       # farther inside than the tolerance
    assert deep.sum() >= 20
    assert np.isin(np.flatnonzero(deep), jaw).all()
    assert report["counts"]["inside a bone"] >= deep.sum()
    # outside the sphere only nodes within the tolerance of it are the jaw's
    far = r > 14.0 + report["tolerance_mm"] + 0.5
    assert not np.isin(np.flatnonzero(far), jaw).any()
    assert not np.isin(jaw, cra).any()
