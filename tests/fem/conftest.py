import numpy as np
import pytest

from facesim.fem import RestShape, box_mesh


@pytest.fixture
def small_block():
    """A 3 x 2 x 2-cell box (72 tets) with rest shape."""
    X, T = box_mesh((10.0, 8.0, 6.0), (3, 2, 2))
    return X, T, RestShape(X, T)


def random_unit(rng, k):
    v = rng.normal(size=(k, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def inverted_count(rest, x):
    T = rest.tets
    D = np.stack([x[T[:, j]] - x[T[:, 0]] for j in (1, 2, 3)], axis=-1)
    return int((np.linalg.det(D) <= 0).sum())
