"""Calibrated pinhole cameras: the calibration file, projection, and the default mouth layout.

Conventions (OpenCV's): a world point ``X`` (mm) is at ``x_cam = R X + t`` in a camera, whose
+z looks forward, +x to the image's right and +y down the image; its pixel is ``K x_cam / z``,
with pixel centres at integer coordinates (column ``u``, row ``v``). No lens distortion: undistort
real footage first. The world is the frame of the teeth meshes at rest (facesim's frame: x the
subject's left, y up, z forward, mm), so a head that does not move has the identity pose.

Calibration file (JSON)::

    {"units": "mm",
     "cameras": [{"name": "centre", "K": [[fx, s, cx], [0, fy, cy], [0, 0, 1]],
                  "size": [width, height], "R": [[...], [...], [...]], "t": [tx, ty, tz]}, ...]}

``K`` 3x3 (fx, fy > 0, bottom row 0 0 1), ``size`` [w, h] pixels, ``R`` a proper rotation
(world to camera), ``t`` (3,) mm. Every mistake is a one-line :class:`ModelFileError` naming the
file, the camera and the field.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.errors import FacesimError, ModelFileError

#: The default layout (:func:`default_layout`): image size (px), focal length (px), the distance
#: of every camera to the mouth (mm) and the side cameras' yaw (degrees).
DEFAULT_SIZE = (1280, 720)
DEFAULT_FOCAL_PX = 2400.0
DEFAULT_DISTANCE_MM = 300.0
DEFAULT_YAW_DEG = 30.0
#: Names are folder names: letters, digits, '-' and '_'.
_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class Camera:
    """A calibrated pinhole camera.

    name : str, also the folder of its images.
    K : (3, 3) float64 intrinsics (px). size : (width, height) px.
    R : (3, 3) float64 world-to-camera rotation. t : (3,) float64 mm, so ``x_cam = R X + t``.
    """

    name: str
    K: np.ndarray
    size: tuple[int, int]
    R: np.ndarray
    t: np.ndarray

    @property
    def width(self) -> int:
        return int(self.size[0])

    @property
    def height(self) -> int:
        return int(self.size[1])

    @property
    def centre(self) -> np.ndarray:
        """(3,) mm, the camera's optical centre in the world."""
        return -self.R.T @ self.t

    def to_camera(self, X) -> np.ndarray:
        """Camera coordinates ``(k, 3)`` mm of world points ``X (k, 3)`` mm."""
        return np.asarray(X, dtype=np.float64) @ self.R.T + self.t

    def project(self, X) -> np.ndarray:
        """Pixels ``(k, 2)`` (u column, v row) of world points ``X (k, 3)`` mm (in front of the camera)."""
        return pixels(self.K, self.to_camera(X))

    def rays(self, uv) -> np.ndarray:
        """Directions ``(k, 3)`` in camera coordinates (z = 1) through the pixels ``uv (k, 2)``."""
        uv = np.asarray(uv, dtype=np.float64)
        h = np.column_stack([uv, np.ones(len(uv))])
        return np.linalg.solve(self.K, h.T).T

    def scaled(self, s: float) -> Camera:
        """The same camera with images resized by ``s`` (e.g. 0.5: half width and height),
        pixel centres kept at integer coordinates (``u' = s (u + 0.5) - 0.5``)."""
        S = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0.0, 0.0, 1.0]])
        w, h = max(1, int(round(self.width * s))), max(1, int(round(self.height * s)))
        return Camera(self.name, S @ self.K, (w, h), self.R, self.t)

    def to_json(self) -> dict:
        return {"name": self.name, "K": self.K.tolist(), "size": [self.width, self.height], "R": self.R.tolist(),
                "t": self.t.tolist()}


def pixels(K, Y) -> np.ndarray:
    """Pixels ``(k, 2)`` of camera-frame points ``Y (k, 3)`` mm under intrinsics ``K (3, 3)``."""
    Y = np.asarray(Y, dtype=np.float64)
    h = Y @ np.asarray(K).T
    return h[:, :2] / h[:, 2:3]


def projection_jacobian(K, Y) -> np.ndarray:
    """``(k, 2, 3)`` derivatives of the pixels of camera-frame points ``Y (k, 3)`` mm with respect
    to those points (px / mm)."""
    Y = np.asarray(Y, dtype=np.float64)
    h = Y @ np.asarray(K).T                       # (k, 3) = (a, b, z)
    z = h[:, 2]
    J = np.zeros((len(Y), 2, 3))
    for r in range(2):   # d(h_r / z) = (K_r z - h_r K_2) / z^2, two rows
        J[:, r, :] = (K[r][None, :] * z[:, None] - h[:, r:r + 1] * K[2][None, :]) / (z * z)[:, None]
    return J


def look_at(name: str, eye, target, K, size, up=(0.0, 1.0, 0.0)) -> Camera:
    """A camera at ``eye (3,)`` mm looking at ``target (3,)`` mm, with the world's ``up`` pointing
    up the image (image y is down)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up, z)             # image right = down x forward (x, y, z right-handed, y down)
    if np.linalg.norm(x) < 1e-9:
        raise FacesimError(f"camera {name}: the viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return Camera(name, np.asarray(K, dtype=np.float64), (int(size[0]), int(size[1])), R, -R @ eye)


def default_layout(target, size=DEFAULT_SIZE, focal_px: float = DEFAULT_FOCAL_PX,
                   distance: float = DEFAULT_DISTANCE_MM, yaw_deg: float = DEFAULT_YAW_DEG) -> list[Camera]:
    """Three cameras looking at ``target (3,)`` mm (the mouth) from in front of the face (+z):
    ``centre`` straight on, ``left`` and ``right`` turned ``yaw_deg`` about the world's up axis
    toward the subject's left (+x) and right, all ``distance`` mm away, focal ``focal_px`` at
    ``size`` (width, height) px; the focal scales with the width, so a smaller image sees the
    same field (at 1280x720, 2400 px and 300 mm: 160 x 90 mm at the mouth, 0.125 mm a pixel)."""
    w, h = int(size[0]), int(size[1])
    f = focal_px * w / DEFAULT_SIZE[0]
    K = np.array([[f, 0.0, 0.5 * (w - 1)], [0.0, f, 0.5 * (h - 1)], [0.0, 0.0, 1.0]])
    target = np.asarray(target, dtype=np.float64)
    cams = []
    for name, yaw in (("centre", 0.0), ("left", yaw_deg), ("right", -yaw_deg)):
        a = np.deg2rad(yaw)
        eye = target + distance * np.array([np.sin(a), 0.0, np.cos(a)])
        cams.append(look_at(name, eye, target, K, (w, h)))
    return cams


# ------------------------------------------------------------------ the calibration file
def _matrix(path, where: str, key: str, value, shape) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != shape:
        raise ModelFileError(path, f"{where} field {key!r}: expected {_shape_words(shape)}, got {_short(value)}")
    if not np.isfinite(a).all():
        raise ModelFileError(path, f"{where} field {key!r}: expected finite numbers, got {_short(value)}")
    return a


def _shape_words(shape) -> str:
    return "a 3x3 matrix (list of 3 rows of 3 numbers)" if shape == (3, 3) else f"a list of {shape[0]} numbers"


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def camera_from_json(path, index: int, entry) -> Camera:
    """The camera of entry ``index`` of the file ``path`` (see the module docstring)."""
    where = f"camera {index}"
    if not isinstance(entry, dict):
        raise ModelFileError(path, f"{where}: expected an object with name, K, size, R, t; got {_short(entry)}")
    name = entry.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        raise ModelFileError(path, f"{where} field 'name': expected a folder name of letters, digits, '-' or '_', "
                                   f"got {_short(name)}")
    where = f"camera {index} ({name})"
    for key in ("K", "size", "R", "t"):
        if key not in entry:
            raise ModelFileError(path, f"{where} field {key!r} missing (expected K 3x3, size [w, h], R 3x3, t [3] mm)")
    K = _matrix(path, where, "K", entry["K"], (3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0) or np.abs(K[1, 0]) > 0 or np.abs(K[2] - [0.0, 0.0, 1.0]).max() > 1e-9:
        raise ModelFileError(path, f"{where} field 'K': expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                                   f"got {_short(entry['K'])}")
    size = entry["size"]
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
                                                              and 16 <= v <= 16384 for v in size)):
        raise ModelFileError(path, f"{where} field 'size': expected [width, height] in pixels (integers 16-16384), "
                                   f"got {_short(size)}")
    R = _matrix(path, where, "R", entry["R"], (3, 3))
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise ModelFileError(path, f"{where} field 'R': expected a rotation matrix (orthonormal, det +1), got "
                                   f"{_short(entry['R'])}")
    t = _matrix(path, where, "t", entry["t"], (3,))
    return Camera(name, K, (size[0], size[1]), R, t)


def read_cameras(path) -> list[Camera]:
    """The cameras of the calibration file ``path``; one-line errors name the file, camera and field."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(path, "no such file (expected a camera calibration .json)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(path, f"not a readable JSON file ({type(exc).__name__})") from None
    if not isinstance(data, dict) or "cameras" not in data:
        raise ModelFileError(path, "field 'cameras' missing (expected {\"units\": \"mm\", \"cameras\": [...]})")
    units = data.get("units", "mm")
    if units != "mm":
        raise ModelFileError(path, f"field 'units': expected \"mm\", got {_short(units)}")
    entries = data["cameras"]
    if not isinstance(entries, list) or not entries:
        raise ModelFileError(path, "field 'cameras': expected a non-empty list of cameras")
    cams = [camera_from_json(path, i, e) for i, e in enumerate(entries)]
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise ModelFileError(path, f"field 'cameras': the name {dup!r} is used twice (names are image folders)")
    return cams


def write_cameras(path, cameras) -> Path:
    """Write the calibration file of ``cameras`` at ``path`` (atomically)."""
    text = json.dumps({"units": "mm", "convention": "OpenCV: x_cam = R X + t, pixel = K x_cam / z, +z forward, "
                                                    "y down the image, pixel centres at integers",
                       "cameras": [c.to_json() for c in cameras]}, indent=1)
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text + "\n", encoding="utf-8"))


__all__ = ["Camera", "default_layout", "look_at", "pixels", "projection_jacobian", "read_cameras", "write_cameras"]
