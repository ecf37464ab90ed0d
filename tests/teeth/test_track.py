"""Tracking: a known pose recovered from a perturbed start; a hidden lower jaw flagged, held."""

import numpy as np

from facesim import se3
from facesim.teeth.capture import Capture
from facesim.teeth.track import Tracker

from .conftest import pose_error


def _perturbed(dentition, J, xi):
    """``J`` moved by the twist ``xi`` (rad, mm) about the lower incisal point."""
    C = np.eye(4)
    C[:3, 3] = dentition.incisor
    return C @ se3.exp(np.asarray(xi)) @ se3.inverse(C) @ J


def test_recovers_a_known_pose_from_a_perturbed_start(capture):
    folder, d, cams, truth = capture
    tracker = Tracker(d, cams)
    J0 = _perturbed(d, truth[1], [0.03, -0.02, 0.02, 1.0, -1.2, 0.8])    # 2.4 deg, 2.6 mm off
    start = pose_error(d, J0, truth[1])
    assert start[0] > 2.0 and start[1] > 2.0
    r = tracker.track_frame(Capture(folder, cams).labels(1), np.eye(4), J0)
    mm, deg = pose_error(d, r.fitted, truth[1])
    # 480x270 px (0.33 mm a pixel at the mouth), noise, blur, lips; the head tracked too
    assert mm < 0.8 and deg < 1.0, (mm, deg)
    assert not r.flagged and r.confidence > 0.1 and r.sigma_mm < 0.15
    assert np.allclose(r.jaw, r.fitted)


def test_given_masks_track_as_well(capture):
    folder, d, cams, truth = capture
    J0 = _perturbed(d, truth[2], [-0.02, 0.02, 0.01, -0.8, 1.0, 0.5])
    r = Tracker(d, cams).track_frame(Capture(folder / "masks", cams, masks=True).labels(2), np.eye(4), J0)
    mm, deg = pose_error(d, r.fitted, truth[2])
    assert mm < 0.8 and deg < 1.0, (mm, deg)


def test_hidden_lower_teeth_are_flagged_and_held(capture):
    folder, d, cams, truth = capture
    J0 = _perturbed(d, truth[3], [0.03, -0.02, 0.02, 1.0, -1.2, 0.8])
    r = Tracker(d, cams).track_frame(Capture(folder, cams).labels(3), np.eye(4), J0)
    assert r.flagged and r.confidence < 0.1
    assert np.array_equal(r.jaw, J0)          # the previous pose is kept, not the fit
