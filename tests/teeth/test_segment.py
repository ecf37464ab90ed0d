"""Segmentation against the true labels of a rendered capture: no systematic offset of the contour."""

import cv2
import numpy as np

from facesim.teeth.capture import Capture
from facesim.teeth.segment import TEETH, labels_from_mask, segment


def _offsets(seg, truth):
    """Signed px distance of each contour pixel of ``seg`` from the contour of ``truth`` (+ outside)."""
    from facesim.teeth.silhouette import _inner_boundary

    out = cv2.distanceTransform((~truth).astype(np.uint8), cv2.DIST_L2, 5)
    inside = cv2.distanceTransform(truth.astype(np.uint8), cv2.DIST_L2, 5)
    return np.where(truth, 1.0 - inside, out)[_inner_boundary(seg)]


def test_teeth_mask_is_not_a_pixel_too_big(capture):
    folder, d, cams, truth = capture
    img = Capture(folder, cams).image(cams[0], "frame_00001.png")
    true = labels_from_mask(Capture(folder / "masks", cams, masks=True).image(cams[0], "frame_00001.png")) == TEETH
    seg = segment(img) == TEETH
    off = _offsets(seg, true)
    assert len(off) > 200 and true.sum() > 1000
    # the blurred edge is cut half way: the contour sits on the true one (a low threshold: +0.5 px or more)
    assert abs(off.mean()) < 0.2, off.mean()
    assert (seg ^ true).sum() < 0.05 * true.sum()
