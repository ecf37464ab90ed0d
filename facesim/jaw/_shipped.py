"""The shipped face model, loaded once, for default jaw geometry and mandible points."""

from __future__ import annotations

from functools import lru_cache

from facesim._files import MESHES


@lru_cache(maxsize=1)
def shipped_model():
    """The immutable ``meshes/face_coarse.npz`` model of the repository holding ``facesim``."""
    from facesim.model import FaceModel

    return FaceModel.load(MESHES / "face_coarse.npz")
