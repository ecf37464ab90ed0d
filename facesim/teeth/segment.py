"""Teeth masks from images: colour and brightness, then morphology (OpenCV).

Teeth are bright and nearly grey; lips and skin are saturated red; the mouth behind the teeth is
dark. :func:`segment` labels every pixel (a ``(h, w) uint8`` label image): :data:`TEETH` where
the smoothed image's saturation ``(max - min) / max`` is below ``max_saturation`` and its
value above ``min_value`` and, next to a dark pixel (within 2 px, below ``min_value``), above
the middle of the local 5x5 range (a blurred edge cut half way, where the tooth ends);
:data:`OCCLUDER` where it is not teeth, bright enough and red
(``(R - G) / R`` above ``min_redness``: lips, skin); :data:`BACKGROUND` elsewhere. The teeth
mask is opened (specks of noise go) and closed (pits fill) with a 3x3 ellipse and components
smaller than ``min_area`` pixels are dropped; the occluder mask is closed with a 5x5 ellipse.

Masks segmented elsewhere (``--masks DIR``) are grey PNGs: 255 (any value > 191) teeth, 128
(64-191) an occluder (lips, tongue, a hand), 0 (< 64) the rest. Binary 0/255 masks are fine:
without occluder labels the tracker cannot tell a hidden tooth from a missing one and relies on
its matching test alone.
"""

from __future__ import annotations

import numpy as np

BACKGROUND, TEETH, OCCLUDER = 0, 1, 2


def segment(rgb, max_saturation: float = 0.3, min_value: float = 80.0, min_redness: float = 0.2,
            min_area: int = 30) -> np.ndarray:
    """``(h, w) uint8`` labels (BACKGROUND, TEETH, OCCLUDER) of an RGB image ``(h, w, 3) uint8``."""
    import cv2

    img = cv2.GaussianBlur(np.asarray(rgb, dtype=np.float32), (0, 0), 1.0)
    hi, lo = img.max(axis=2), img.min(axis=2)
    sat = (hi - lo) / np.maximum(hi, 1.0)
    teeth = (sat < max_saturation) & (hi > min_value)
    # where a tooth meets the dark mouth, cut at half the local contrast, not at min_value: the
    # blurred step crosses min_value about a pixel outside the tooth (a mask a pixel too big)
    k5 = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))
    top, bottom = cv2.dilate(hi, k5), cv2.erode(hi, k5)
    teeth &= ~((bottom <= min_value) & (hi < 0.5 * (top + bottom)))
    teeth = teeth.astype(np.uint8)
    k3 = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    teeth = cv2.morphologyEx(teeth, cv2.MORPH_OPEN, k3)
    teeth = cv2.morphologyEx(teeth, cv2.MORPH_CLOSE, k3)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(teeth, connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    teeth = keep[comp]
    red = (img[..., 0] - img[..., 1]) / np.maximum(img[..., 0], 1.0)
    occ = ((red > min_redness) & (img[..., 0] > min_value) & ~teeth).astype(np.uint8)
    occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))) > 0
    labels = np.full(teeth.shape, BACKGROUND, np.uint8)
    labels[occ & ~teeth] = OCCLUDER
    labels[teeth] = TEETH
    return labels


def labels_from_mask(mask) -> np.ndarray:
    """``(h, w) uint8`` labels of a grey mask image (see the module docstring)."""
    m = np.asarray(mask)
    if m.ndim == 3:
        m = m.max(axis=2)
    labels = np.full(m.shape, BACKGROUND, np.uint8)
    labels[(m >= 64) & (m <= 191)] = OCCLUDER
    labels[m > 191] = TEETH
    return labels


__all__ = ["BACKGROUND", "OCCLUDER", "TEETH", "labels_from_mask", "segment"]
