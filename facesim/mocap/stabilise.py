"""Head stabilisation of a capture: every frame moved into the model's head frame.

:func:`stabilise` fits, per frame, the rigid transform carrying the capture's head markers onto the
model's rest head markers (Kabsch, :func:`facesim.se3.rigid_fit`) and applies it to all markers;
:func:`smooth_transforms` optionally smooths those transforms over time (Savitzky-Golay on rotation
vectors and translations), since the few head markers carry the capture's noise into every frame.
"""

from __future__ import annotations

import numpy as np

from facesim.errors import FacesimError
from facesim.se3 import rigid_fit


def stabilise(model, P: np.ndarray, window: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Capture ``P (F, r, 3)`` (model marker order) moved per frame into the model's head frame by
    the rigid fit of its head markers onto the model's rest head markers. Returns the moved
    positions and the per-frame 4x4 transforms (capture -> model). Needs >= 3 head markers.

    ``window`` (odd, >= 3; 0: off): smooth the transforms over time with a Savitzky-Golay filter
    (quadratic, ``window`` frames) of their rotation vectors and translations. A few head markers
    on the upper face carry the noise of the capture into every frame's fit, and the lever arm to
    the chin multiplies it (the demo clip: up to 2.7 mm RMS over the face in one frame at 0.5 mm
    noise); the head moves smoothly, its noise does not. Frames with too few head markers then
    take the transform interpolated from their neighbours."""
    head = np.flatnonzero(model.markers.head)
    rest = model.marker_positions()[head]
    Ts = np.full((len(P), 4, 4), np.nan)
    for f, frame in enumerate(P):
        ok = np.isfinite(frame[head]).all(axis=1)
        if ok.sum() >= 3:
            Ts[f] = rigid_fit(frame[head][ok], rest[ok])
    if window:
        Ts = smooth_transforms(Ts, window)
    out = np.einsum("fij,frj->fri", Ts[:, :3, :3], P) + Ts[:, None, :3, 3]
    return out, Ts


def check_window(window: int) -> None:
    """One-line :class:`FacesimError` unless ``window`` is a smoothing window: odd, >= 3 frames."""
    if window < 3 or window % 2 == 0:
        raise FacesimError(f"head smoothing: expected 0 (off) or an odd window of >= 3 frames, got {window}")


def smooth_transforms(Ts: np.ndarray, window: int) -> np.ndarray:
    """Rigid transforms ``Ts (F, 4, 4)`` (NaN: unknown) smoothed over time: rotation vectors
    (relative to their mean rotation, so none is near pi) and translations filtered by a
    quadratic Savitzky-Golay filter of ``window`` frames (odd, >= 3); unknown frames are first
    interpolated from the known ones. All NaN, or one frame: returned unchanged."""
    from scipy.signal import savgol_filter
    from scipy.spatial.transform import Rotation

    check_window(window)
    known = np.isfinite(Ts).all(axis=(1, 2))
    if known.sum() < 2:
        return Ts
    t = np.arange(len(Ts))
    mean = Rotation.from_matrix(Ts[known, :3, :3]).mean()
    rv = np.full((len(Ts), 3), np.nan)
    rv[known] = (mean.inv() * Rotation.from_matrix(Ts[known, :3, :3])).as_rotvec()
    tr = Ts[:, :3, 3].copy()
    for arr in (rv, tr):
        for k in range(3):
            arr[:, k] = np.interp(t, t[known], arr[known, k])
    w = min(window, len(Ts) if len(Ts) % 2 else len(Ts) - 1)
    if w >= 3:
        rv, tr = (savgol_filter(a, w, 2, axis=0, mode="interp") for a in (rv, tr))
    out = np.tile(np.eye(4), (len(Ts), 1, 1))
    out[:, :3, :3] = (mean * Rotation.from_rotvec(rv)).as_matrix()
    out[:, :3, 3] = tr
    return out


__all__ = ["check_window", "smooth_transforms", "stabilise"]
