"""Synthetic multi-view captures of the teeth: the test data teeth tracking needs.

Every frame the upper teeth move with the head (``head (4, 4)``, world from skull), the lower
teeth with the head and the jaw (``head @ jaw``), the procedural lips
(:class:`~facesim.teeth.lips.LipOccluder`) with the head, their lower edge with the jaw. Each
camera sees them through our z-buffer (:mod:`facesim.teeth.raster`), flat shaded with a light
at the camera (``AMBIENT + (1 - AMBIENT) |n . view|``): ivory teeth, red lips, a dark mouth
behind. Then the image is blurred (Gaussian, ``blur`` px) and Gaussian noise added (``noise``
grey levels) before rounding to 8 bits.

A capture folder::

    cameras.json                  calibration (facesim.teeth.cameras)
    truth.npz                     poses (N, 4, 4) mandible relative to skull (a poses file
                                  facesim jaw fit reads), head (N, 4, 4) world from skull,
                                  reference_point (3,), mandible (P, 3), frames (N,) source
                                  frame numbers, hidden (N,) frames whose lower teeth the lips hide
    teeth_upper.obj, teeth_lower.obj   the teeth drawn (mm, facesim's frame)
    <camera>/frame_00000.png ...  the images (RGB)
    masks/<camera>/frame_00000.png     with write_masks: the true labels (255 teeth seen,
                                  128 lips, 0 the rest), the format track --masks reads
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim import se3
from facesim.teeth.raster import render_ids

#: Colours (RGB, 0-255) and the share of light that does not depend on the surface's tilt.
TEETH_RGB = np.array([236.0, 231.0, 214.0])
LIPS_RGB = np.array([196.0, 104.0, 98.0])
MOUTH_RGB = np.array([46.0, 20.0, 24.0])
AMBIENT = 0.55
#: Label values of a mask image.
LABEL_TEETH, LABEL_OCCLUDER = 255, 128
FRAME_NAME = "frame_{:05d}.png"


@dataclass(frozen=True)
class CaptureOptions:
    """How a capture is degraded.

    noise : std of the image noise, grey levels (0-255). blur : Gaussian blur sigma, px.
    lips : draw the lip occluder. cover_upper, cover_lower : the lips' cover (mm, see
    :mod:`facesim.teeth.lips`); lip_jitter : mm, amplitude of their slow random variation.
    hide_lower : frame indices (of the capture) where the lower lip rises over the lower teeth.
    seed : of the noise and the lips' variation.
    """

    noise: float = 4.0
    blur: float = 0.8
    lips: bool = True
    cover_upper: float = 6.0
    cover_lower: float = 5.0
    lip_jitter: float = 1.0
    hide_lower: tuple[int, ...] = ()
    seed: int = 0


def head_motion(n: int, amplitude: float, seed: int = 0) -> np.ndarray:
    """``(n, 4, 4)`` smooth random head poses (world from skull): translations up to about
    ``amplitude`` mm and rotations up to about ``amplitude`` degrees about the teeth, sums of
    slow sines (identity for ``amplitude`` 0)."""
    rng = np.random.default_rng(seed)
    f = np.arange(n)[:, None]
    xi = np.zeros((n, 6))
    for k in range(6):
        periods, phases = rng.uniform(20.0, 60.0, 2), rng.uniform(0.0, 2.0 * np.pi, 2)
        xi[:, k] = 0.5 * (np.sin(2.0 * np.pi * f[:, 0] / periods[0] + phases[0])
                          + np.sin(2.0 * np.pi * f[:, 0] / periods[1] + phases[1]))
    xi[:, :3] *= np.deg2rad(amplitude)
    xi[:, 3:] *= amplitude
    return se3.exp(xi)


def _flat_shade(camera, V, F, colours) -> np.ndarray:
    """``(m, 3)`` RGB of each triangle of ``F`` over world ``V`` with base colours ``colours (m, 3)``."""
    Y = camera.to_camera(V)
    T = Y[F]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    view = T.mean(axis=1)
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
    lam = AMBIENT + (1.0 - AMBIENT) * np.abs(np.einsum("ij,ij->i", n, view))
    return colours * lam[:, None]


class Scene:
    """The meshes of one capture: dentition, optional lips, their materials."""

    def __init__(self, dentition, lips=None):
        self.dentition, self.lips = dentition, lips
        V, F, self.n_upper = dentition.merged()
        self.n_teeth_V, self.n_teeth_F = len(V), len(F)
        self.n_upper_V = len(dentition.upper_V)
        lip_F = lips.faces() if lips is not None else np.zeros((0, 3), np.int32)
        self.F = np.concatenate([F, lip_F + len(V)]).astype(np.int32)
        self.colours = np.concatenate([np.repeat(TEETH_RGB[None], len(F), 0), np.repeat(LIPS_RGB[None], len(lip_F), 0)])

    def vertices(self, jaw, head, cover_upper, cover_lower, hide_lower=False) -> np.ndarray:
        """``(n, 3)`` world vertices of the scene at the jaw and head poses (4, 4)."""
        d = self.dentition
        parts = [se3.transform_points(head, d.upper_V), se3.transform_points(head @ jaw, d.lower_V)]
        if self.lips is not None:
            parts.append(self.lips.vertices(jaw, head, cover_upper, cover_lower, hide_lower))
        return np.concatenate(parts)

    def draw(self, camera, V) -> tuple[np.ndarray, np.ndarray]:
        """``(rgb (h, w, 3) float64, labels (h, w) uint8)`` of the scene vertices ``V`` in ``camera``."""
        _, ids = render_ids(camera, V, self.F)
        shade = _flat_shade(camera, V, self.F, self.colours)
        rgb = np.where((ids >= 0)[..., None], shade[np.maximum(ids, 0)], MOUTH_RGB)
        labels = np.zeros(ids.shape, np.uint8)
        labels[(ids >= 0) & (ids < self.n_teeth_F)] = LABEL_TEETH
        labels[ids >= self.n_teeth_F] = LABEL_OCCLUDER
        return rgb, labels


def degrade(rgb, options: CaptureOptions, rng) -> np.ndarray:
    """``(h, w, 3) uint8``: ``rgb`` blurred and noised as ``options`` says."""
    import cv2

    img = rgb.astype(np.float32)
    if options.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), options.blur)
    if options.noise > 0:
        img = img + rng.normal(0.0, options.noise, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def write_png(path, rgb) -> Path:
    """Write an RGB ``(h, w, 3) uint8`` (or a grey ``(h, w)``) image as PNG, atomically."""
    import cv2

    from facesim._files import atomic_write
    from facesim.errors import FacesimError

    img = rgb[..., ::-1] if rgb.ndim == 3 else rgb

    def write(tmp):
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(img)):
            raise FacesimError(f"{path}: cannot write the image")

    return atomic_write(path, write)


def lip_covers(n: int, options: CaptureOptions) -> tuple[np.ndarray, np.ndarray]:
    """``(cover_upper (n,), cover_lower (n,))`` mm per frame: the options' covers with a slow random
    variation."""
    rng = np.random.default_rng(options.seed + 7)
    f = np.arange(n)
    up = options.cover_upper + options.lip_jitter * np.sin(2 * np.pi * f / rng.uniform(9, 15) + rng.uniform(0, 6.3))
    lo = options.cover_lower + options.lip_jitter * np.sin(2 * np.pi * f / rng.uniform(9, 15) + rng.uniform(0, 6.3))
    return up, lo


def render_capture(out, dentition, jaw, cameras, options: CaptureOptions = CaptureOptions(), head=None,
                   frames=None, write_masks: bool = False, progress: bool = False) -> dict:
    """Render the capture of the jaw poses ``jaw (N, 4, 4)`` (mandible relative to skull, mm) and
    head poses ``head (N, 4, 4)`` (default still) from ``cameras`` into the folder ``out`` (see
    the module docstring). ``frames (N,)``: the source frame numbers kept in ``truth.npz``.
    Returns a summary dict (frames, cameras, files)."""
    from facesim._files import atomic_write
    from facesim.teeth.cameras import write_cameras
    from facesim.teeth.lips import LipOccluder

    out = Path(out)
    jaw = np.asarray(jaw, dtype=np.float64)
    n = len(jaw)
    head = np.repeat(np.eye(4)[None], n, 0) if head is None else np.asarray(head, dtype=np.float64)
    lips = LipOccluder.of(dentition) if options.lips else None
    scene = Scene(dentition, lips)
    up, lo = lip_covers(n, options)
    rng = np.random.default_rng(options.seed)
    write_cameras(out / "cameras.json", cameras)
    dentition.save_obj(out)
    hidden = np.zeros(n, bool)
    if options.lips:
        hidden[[i for i in options.hide_lower if 0 <= i < n]] = True
    truth = dict(poses=jaw, head=head, reference_point=dentition.incisor, mandible=dentition.mandible_points(),
                 frames=np.arange(n) if frames is None else np.asarray(frames), hidden=hidden)

    def write_truth(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **truth)

    atomic_write(out / "truth.npz", write_truth)
    steps = range(n)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="render", unit="frame")
    for f in steps:
        V = scene.vertices(jaw[f], head[f], up[f], lo[f], hidden[f])
        for cam in cameras:
            rgb, labels = scene.draw(cam, V)
            write_png(out / cam.name / FRAME_NAME.format(f), degrade(rgb, options, rng))
            if write_masks:
                write_png(out / "masks" / cam.name / FRAME_NAME.format(f), labels)
    return {"frames": n, "cameras": [c.name for c in cameras], "folder": str(out)}


__all__ = ["CaptureOptions", "FRAME_NAME", "LABEL_OCCLUDER", "LABEL_TEETH", "Scene", "degrade", "head_motion",
           "lip_covers", "render_capture", "write_png"]
