"""Binding a capture's markers to the skin at the neutral pose (facesim.mocap.binding)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from facesim.errors import FacesimError
from facesim.mocap.binding import match_markers, rebind_markers
from facesim.model import load_model

MESHES = Path(__file__).resolve().parents[2] / "meshes"


@pytest.fixture(scope="module")
def coarse():
    return load_model(MESHES / "face_coarse.npz")


def test_rebinding_to_the_models_own_markers_changes_nothing(coarse):
    bound, moved = rebind_markers(coarse, coarse.marker_positions())
    np.testing.assert_allclose(bound.marker_positions(), coarse.marker_positions(), atol=1e-6)
    assert moved.max() < 1e-6
    assert bound.markers.names == coarse.markers.names and (bound.markers.head == coarse.markers.head).all()


def test_markers_of_a_finer_mesh_are_carried_over():
    """The same landmarks bound separately on the medium and the coarse mesh sit up to ~9 mm
    apart (a skin fold projects differently); rebound on the coarse mesh at the medium markers
    they agree to a fraction of a mm, and they follow the coarse skin when it deforms."""
    coarse, medium = load_model(MESHES / "face_coarse.npz"), load_model(MESHES / "face_medium.npz")
    target = medium.marker_positions()
    before = np.linalg.norm(coarse.marker_positions() - target, axis=1)
    assert before.max() > 3.0
    bound, moved = rebind_markers(coarse, target)
    after = np.linalg.norm(bound.marker_positions() - target, axis=1)
    assert after.max() < 0.3, after.max()
    np.testing.assert_allclose(moved, before, atol=0.3)
    assert np.abs(bound.markers.offset).max() < 3.0           # on the skin, not floating
    # bound to the skin: a rigid motion of the mesh carries the markers rigidly
    c, s = np.cos(0.2), np.sin(0.2)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    np.testing.assert_allclose(bound.marker_positions(coarse.X @ R.T + 5.0), target @ R.T + 5.0, atol=0.3)


def test_noisy_neutral_frame_and_missing_markers(coarse):
    rng = np.random.default_rng(3)
    P = coarse.marker_positions() + rng.normal(0.0, 0.5, (coarse.n_markers, 3))
    P[4] = np.nan                                               # missing: keeps the model's binding
    bound, moved = rebind_markers(coarse, P)
    err = np.linalg.norm(bound.marker_positions() - P, axis=1)
    assert np.nanmax(err) < 0.5 and moved[4] == 0.0
    assert bound.markers.triangle[4] == coarse.markers.triangle[4]


def test_bad_neutral_frames_give_one_line_errors(coarse):
    P = coarse.marker_positions().copy()
    P[7] += [0.0, 0.0, 40.0]
    with pytest.raises(FacesimError, match=coarse.markers.names[7]):
        rebind_markers(coarse, P)
    with pytest.raises(FacesimError, match="expected"):
        rebind_markers(coarse, P[:-1])


def test_match_markers_reports_unmatched_names():
    index, extra, missing = match_markers(["chin", "Mouth_L", "nose"], ["CHIN", "mouth_l", "ear"])
    assert list(index) == [0, 1, -1] and extra == ["ear"] and missing == ["nose"]
