"""A folder of multi-view images (or masks) to track, checked against the calibration.

Layout: ``DIR/<camera name>/<frame>.png`` for every camera of the calibration, the same frame
names in every camera folder (sorted by name), each image the size the calibration gives. Masks
(``--masks DIR``) have the same layout (see :mod:`facesim.teeth.segment` for their values).
Every mistake is a one-line :class:`~facesim.errors.FacesimError` naming the folder or file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesim.errors import FacesimError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _frames(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


class Capture:
    """The frames of a capture folder: ``names`` (the frame file names), ``cameras``, and the
    labels of a frame (:meth:`labels`: segmented images, or the masks)."""

    def __init__(self, folder, cameras, masks: bool = False):
        self.folder, self.cameras, self.masks = Path(folder), list(cameras), masks
        what = "masks" if masks else "images"
        if not self.folder.is_dir():
            raise FacesimError(f"{self.folder}: no such folder (expected the {what}: one folder per camera)")
        names = None
        for cam in self.cameras:
            sub = self.folder / cam.name
            if not sub.is_dir():
                raise FacesimError(f"{sub}: no such folder (the calibration has a camera {cam.name!r}; expected its "
                                   f"{what} there)")
            got = _frames(sub)
            if not got:
                raise FacesimError(f"{sub}: no images ({', '.join(IMAGE_SUFFIXES)})")
            if names is None:
                names, first = got, sub
            elif got != names:
                missing = sorted(set(names) - set(got))
                extra = sorted(set(got) - set(names))
                if missing:
                    raise FacesimError(f"{sub}: missing {len(missing)} frame(s) that {first} has (first: {missing[0]})")
                raise FacesimError(f"{sub}: {len(extra)} frame(s) that {first} does not have (first: {extra[0]})")
        self.names = names

    def __len__(self) -> int:
        return len(self.names)

    def image(self, camera, name) -> np.ndarray:
        """The RGB ``(h, w, 3) uint8`` (or grey mask ``(h, w)``) image of ``camera`` at frame ``name``."""
        import cv2

        path = self.folder / camera.name / name
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if self.masks else cv2.IMREAD_COLOR)
        if img is None:
            raise FacesimError(f"{path}: not a readable image")
        h, w = img.shape[:2]
        if (w, h) != (camera.width, camera.height):
            raise FacesimError(f"{path}: image is {w}x{h} px, the calibration of camera {camera.name!r} says "
                               f"{camera.width}x{camera.height}")
        return img if self.masks else img[..., ::-1]

    def labels(self, index: int) -> list[np.ndarray]:
        """The ``(h, w) uint8`` labels of frame ``index`` in every camera."""
        from facesim.teeth.segment import labels_from_mask, segment

        name = self.names[index]
        if self.masks:
            return [labels_from_mask(self.image(c, name)) for c in self.cameras]
        return [segment(self.image(c, name)) for c in self.cameras]


__all__ = ["Capture", "IMAGE_SUFFIXES"]
