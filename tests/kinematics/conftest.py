"""Fixtures of the kinematics tests."""

import pytest


@pytest.fixture(scope="module")
def model():
    """The shipped coarse face (immutable; loaded once per process, facesim.jaw._shipped)."""
    from facesim.jaw._shipped import shipped_model

    return shipped_model()
