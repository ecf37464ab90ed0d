"""Cameras: projection against OpenCV, the calibration file's checks."""

import json

import numpy as np
import pytest

from facesim.errors import FacesimError
from facesim.teeth.cameras import default_layout, look_at, projection_jacobian, read_cameras, write_cameras

cv2 = pytest.importorskip("cv2")


def _points(rng, k=50):
    return rng.uniform([-30, -70, 40], [30, -20, 90], size=(k, 3))


def test_projection_matches_opencv():
    rng = np.random.default_rng(0)
    X = _points(rng)
    K = np.array([[2100.0, 0.0, 630.0], [0.0, 2080.0, 355.0], [0.0, 0.0, 1.0]])   # projectPoints has no skew
    cam = look_at("a", eye=(120.0, -10.0, 330.0), target=(0.0, -45.0, 70.0), K=K, size=(1280, 720))
    rvec, _ = cv2.Rodrigues(cam.R)
    ref, _ = cv2.projectPoints(X, rvec, cam.t, K, np.zeros(5))
    assert np.abs(cam.project(X) - ref[:, 0, :]).max() < 1e-9
    # the default layout too, and the points land inside the image
    for cam in default_layout((0.0, -58.0, 75.0)):
        rvec, _ = cv2.Rodrigues(cam.R)
        ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, np.zeros(5))
        uv = cam.project(X)
        assert np.abs(uv - ref[:, 0, :]).max() < 1e-9
        assert (uv > 0).all() and (uv[:, 0] < 1280).all() and (uv[:, 1] < 720).all()


def test_default_layout_geometry():
    target = np.array([0.0, -58.0, 75.0])
    cams = default_layout(target)
    assert [c.name for c in cams] == ["centre", "left", "right"]
    for c in cams:
        assert abs(np.linalg.norm(c.centre - target) - 300.0) < 1e-9
        assert np.abs(c.project(target[None])[0] - [639.5, 359.5]).max() < 1e-9   # looks at the mouth
        assert np.abs(c.R @ c.R.T - np.eye(3)).max() < 1e-12 and np.linalg.det(c.R) > 0
    # up in the world is up in the image (smaller v); facing the subject, its left is on the image's right
    c = cams[0]
    up = c.project(np.array([target + [0, 10, 0]]))[0]
    left = c.project(np.array([target + [10, 0, 0]]))[0]
    assert up[1] < 359.5 and left[0] > 639.5
    yaw = np.degrees(np.arctan2(cams[1].centre[0] - target[0], cams[1].centre[2] - target[2]))
    assert abs(yaw - 30.0) < 1e-9


def test_projection_jacobian_against_differences():
    rng = np.random.default_rng(1)
    K = np.array([[900.0, 2.0, 300.0], [0.0, 880.0, 200.0], [0.0, 0.0, 1.0]])
    Y = rng.uniform([-20, -20, 200], [20, 20, 300], size=(5, 3))
    J = projection_jacobian(K, Y)
    h = 1e-5
    for a in range(3):
        d = np.zeros(3)
        d[a] = h
        num = ((Y + d) @ K.T)[:, :2] / ((Y + d) @ K.T)[:, 2:] - ((Y - d) @ K.T)[:, :2] / ((Y - d) @ K.T)[:, 2:]
        assert np.abs(num / (2 * h) - J[:, :, a]).max() < 1e-6
    assert np.abs(J).max() > 1.0


def test_scaled_camera_keeps_pixel_centres():
    cam = default_layout((0.0, -58.0, 75.0))[0]
    X = _points(np.random.default_rng(2))
    half = cam.scaled(0.5)
    assert half.size == (640, 360)
    assert np.abs(half.project(X) - (0.5 * (cam.project(X) + 0.5) - 0.5)).max() < 1e-9


def _write(tmp_path, cameras):
    p = tmp_path / "cams.json"
    p.write_text(json.dumps({"units": "mm", "cameras": cameras}))
    return p


def test_calibration_round_trip(tmp_path):
    cams = default_layout((0.0, -58.0, 75.0), size=(320, 180))
    back = read_cameras(write_cameras(tmp_path / "c.json", cams))
    assert [c.name for c in back] == ["centre", "left", "right"]
    for a, b in zip(cams, back):
        assert a.size == b.size and np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.t, b.t)


@pytest.mark.parametrize("change, words", [
    (lambda c: c.pop("K"), "field 'K' missing"),
    (lambda c: c.update(K=[[1, 0, 0], [0, 1, 0]]), "field 'K': expected a 3x3 matrix"),
    (lambda c: c.update(K=[[-5, 0, 10], [0, 5, 10], [0, 0, 1]]), "fx, fy > 0"),
    (lambda c: c.update(R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "field 'R': expected a rotation"),
    (lambda c: c.update(R=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "field 'R': expected a rotation"),
    (lambda c: c.update(t=[1, 2]), "field 't': expected a list of 3 numbers"),
    (lambda c: c.update(t=["a", 2, 3]), "field 't'"),
    (lambda c: c.update(size=[320.5, 180]), "field 'size'"),
    (lambda c: c.update(size=[320]), "field 'size'"),
    (lambda c: c.update(name="a/b"), "field 'name'"),
])
def test_calibration_errors_are_one_line(tmp_path, change, words):
    entry = default_layout((0.0, -58.0, 75.0), size=(320, 180))[0].to_json()
    change(entry)
    path = _write(tmp_path, [entry])
    with pytest.raises(FacesimError) as e:
        read_cameras(path)
    msg = str(e.value)
    assert words in msg and str(path) in msg and "\n" not in msg


def test_calibration_file_level_errors(tmp_path):
    entry = default_layout((0.0, -58.0, 75.0), size=(320, 180))[0].to_json()
    with pytest.raises(FacesimError, match="used twice"):
        read_cameras(_write(tmp_path, [entry, entry]))
    with pytest.raises(FacesimError, match="non-empty list"):
        read_cameras(_write(tmp_path, []))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(FacesimError, match="not a readable JSON"):
        read_cameras(bad)
    with pytest.raises(FacesimError, match="no such file"):
        read_cameras(tmp_path / "missing.json")
    other = tmp_path / "units.json"
    other.write_text(json.dumps({"units": "m", "cameras": [entry]}))
    with pytest.raises(FacesimError, match="units"):
        read_cameras(other)
