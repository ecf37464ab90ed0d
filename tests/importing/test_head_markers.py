"""Head markers of an imported model chosen by how little the jaw moves them
(facesim.importing.head_markers), on the shipped coarse face whose head markers are known good."""

import dataclasses

import numpy as np
import pytest

from facesim.importing.head_markers import HEAD_MOTION_MM, choose_head_markers, marker_motion
from facesim.jaw._shipped import shipped_model


@pytest.fixture(scope="module")
def coarse():
    return shipped_model()


def test_the_shipped_head_markers_are_kept(coarse):
    """The built face's six head markers (forehead, nose bridge, temples over the skull) are still
    under the jaw; the chin and the lower lip are not (mm over the jaw's whole range)."""
    jaw, muscles = marker_motion(coarse)
    names = list(coarse.markers.names)
    head = np.asarray(coarse.markers.head)
    assert jaw[head].max() < HEAD_MOTION_MM
    assert jaw[names.index("chin_C")] > 10.0 and jaw[names.index("lip_lower_C")] > 10.0
    assert muscles[names.index("mouth_corner_L")] > 2.0          # a muscle moves the corner mm
    flags, report = choose_head_markers(coarse)
    assert (flags == head).all() and not report["dropped"] and not report["added"]


def test_head_markers_that_move_with_the_jaw_are_replaced(coarse):
    """A layout whose head markers ride on the jaw (as the temple markers of a face mask do): they
    are dropped, and the three added ones are jaw-still, off the mouth, and not collinear."""
    names = list(coarse.markers.names)
    bad = np.zeros(len(names), bool)
    bad[[names.index(n) for n in ("chin_C", "jaw_angle_L", "head_nose_bridge")]] = True
    model = coarse.with_(markers=dataclasses.replace(coarse.markers, head=bad))
    flags, report = choose_head_markers(model)
    jaw, _ = marker_motion(model)
    assert set(report["dropped"]) == {"chin_C", "jaw_angle_L"}
    assert "head_nose_bridge" in report["kept"] and flags.sum() == 3
    assert jaw[flags].max() <= HEAD_MOTION_MM
    assert not any(w in n for n in np.asarray(names)[flags] for w in ("lip", "mouth", "chin"))
    P = model.marker_positions()[flags]
    area = 0.5 * np.linalg.norm(np.cross(P[1] - P[0], P[2] - P[0]))
    assert area > 100.0                                           # mm^2: a triangle, not a line
