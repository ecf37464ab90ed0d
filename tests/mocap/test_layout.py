"""A capture with its own marker layout: registration, binding, head markers, the CLI path.

The captures are made here, independently of facesim.mocap.layout: skin points sampled on the
model's own skin (random front-facing triangles, random barycentric points), a 4-marker rigid
headband 15 mm off the forehead, a known random rigid transform, metres, 0.2 mm noise.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesim.errors import FacesimError
from facesim.mocap.io import read_markers, write_markers_csv
from facesim.mocap.layout import (bind_layout, propose_head_markers, read_marker_map, register_capture)
from facesim.model import MarkerSet, load_model

FACE = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"


def _normals(X, S):
    n = np.cross(X[S[:, 1]] - X[S[:, 0]], X[S[:, 2]] - X[S[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def face():
    if not FACE.is_file():
        pytest.skip("meshes/face_coarse.npz not present")
    return load_model(FACE)


def make_layout(model, seed=0, n_skin=40):
    """``(names, points (N, 3) model frame, head_names, skin_tri (n_skin,))``: skin points on
    random front-facing skin triangles (normal z > 0.6, in front of the ears) and a 4-marker headband
    15 mm out along the normals of the 4 front triangles highest on the forehead, spread in x."""
    rng = np.random.default_rng(seed)
    X, S = model.X, model.skin
    n, c = _normals(X, S), X[S].mean(axis=1)
    front = np.flatnonzero((n[:, 2] > 0.6) & (c[:, 2] > 30) & (np.abs(c[:, 1]) < 80))
    tri = rng.choice(front, n_skin, replace=False)
    b = rng.dirichlet([3, 3, 3], n_skin)
    skin = np.einsum("rk,rkj->rj", b, X[S[tri]])
    brow = np.flatnonzero((n[:, 2] > 0.5) & (c[:, 1] > 60))
    band = []
    for x0 in (-30.0, -10.0, 10.0, 30.0):   # the highest forehead triangle near each x
        near = brow[np.abs(c[brow, 0] - x0) < 6]
        t = near[np.argmax(c[near, 1])]
        band.append(c[t] + 15.0 * n[t])
    names = [f"cap{i:02d}" for i in range(n_skin)] + ["HB1", "HB2", "HB3", "HB4"]
    return names, np.r_[skin, np.array(band)], ["HB1", "HB2", "HB3", "HB4"], tri


def to_capture(points, seed=1, noise=0.2):
    """``points`` in a random capture frame: (capture positions, R, t) with model = R^T (p - t)."""
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(0.0, 500.0, 3)
    return points @ R.T + t + rng.normal(0.0, noise, points.shape), R, t


def test_register_recovers_a_random_rigid_transform_from_a_file_in_metres(face, tmp_path):
    names, pts, head, _ = make_layout(face)
    cap, R, t = to_capture(pts)
    write_markers_csv(tmp_path / "m.csv", [0], names, cap[None] / 1000.0)   # metres: the reader converts
    data = read_markers(tmp_path / "m.csv")
    assert data.units == "m"
    reg = register_capture(face, data.P[0], head=[names.index(h) for h in head])
    rotation_error = np.degrees(Rotation.from_matrix(reg.R @ R).magnitude())   # R_reg should be R^T
    assert rotation_error < 1.0, rotation_error
    # translation, measured where the markers are (the capture's origin is ~500 mm away)
    centre = cap.mean(axis=0)
    assert np.linalg.norm(reg.apply(centre) - R.T @ (centre - t)) < 1.0
    assert reg.rms < 0.5 and reg.max < 1.0 and reg.scale == 1.0
    assert np.nanmax(reg.distance[-4:]) > 5.0   # the headband is off the skin


def test_similarity_registration_recovers_a_scale(face):
    names, pts, head, _ = make_layout(face, seed=2)
    cap, R, t = to_capture(pts, seed=5)
    reg = register_capture(face, 1.04 * cap, head=[40, 41, 42, 43], similarity=True)
    assert abs(reg.scale * 1.04 - 1.0) < 0.01
    assert np.degrees(Rotation.from_matrix(reg.R @ R).magnitude()) < 1.0


def _bind(face, names, pts, head, noise):
    cap, R, t = to_capture(pts, seed=4, noise=noise)
    reg = register_capture(face, cap, head=[names.index(h) for h in head])
    markers, rows, rejected = bind_layout(face, names, reg.apply(cap), head)
    flat = MarkerSet(markers.names, markers.triangle, markers.bary, 0.0 * markers.offset, markers.head)
    on_skin = face.with_(markers=flat).marker_positions()   # the bound skin points, offsets left out
    error = np.linalg.norm(on_skin[~markers.head] - pts[:40], axis=1)
    return reg, cap, markers, rows, rejected, error


@pytest.mark.parametrize("noise", [0.0, 0.2])
def test_binding_puts_every_skin_marker_where_it_was_and_refuses_a_far_one(face, noise):
    names, pts, head, tri = make_layout(face, seed=3)
    names, pts = names + ["FAR"], np.r_[pts, pts[:40].mean(axis=0)[None] + [0.0, 0.0, 120.0]]
    reg, cap, markers, rows, rejected, error = _bind(face, names, pts, head, noise)
    assert list(rejected) == ["FAR"] and "mm from the skin" in rejected["FAR"]
    if noise == 0:
        assert error.max() < 0.05, error.max()
    else:   # 0.2 mm noise per coordinate: ~0.28 mm of it is along the skin, which binding keeps
        assert error.max() < 1.0 and np.median(error) < 0.5, (error.max(), np.median(error))
    assert markers.head.sum() == 4 and [r["role"] for r in rows].count("head") == 4
    # head markers: their bound rest positions reproduce the registered ones
    rest = face.with_(markers=markers).marker_positions()[markers.head]
    assert np.linalg.norm(rest - reg.apply(cap[40:44]), axis=1).max() < 1.0
    assert all(r["distance_mm"] < 1.0 for r, h in zip(rows, markers.head) if not h)


def test_propose_head_markers_finds_exactly_the_headband_on_a_deforming_face(face):
    names, pts, head, _ = make_layout(face, seed=6)
    rng = np.random.default_rng(7)
    frames = []
    for f in range(8):
        moved = pts.copy()
        moved[:40] += rng.normal(0.0, 2.0, (40, 3)) * np.sin(0.7 * f + rng.uniform(0, 6, (40, 1)))
        T = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix()
        frames.append(moved @ T.T + rng.normal(0, 3.0, 3) + rng.normal(0, 0.2, moved.shape))
    P = np.array(frames)
    P[2, 5] = np.nan   # a gap
    assert propose_head_markers(P, names, noise=0.2) == head
    assert propose_head_markers(P[:1], names) == []


def test_marker_map_file(tmp_path):
    (tmp_path / "map.csv").write_text("capture,model\nA,chin\nB,mouth_L\n")
    assert read_marker_map(tmp_path / "map.csv") == {"A": "chin", "B": "mouth_L"}
    (tmp_path / "bad.csv").write_text("from,to\nA,chin\n")
    with pytest.raises(FacesimError, match="capture,model"):
        read_marker_map(tmp_path / "bad.csv")


# ------------------------------------------------------------------ the CLI, end to end on the box
def box_capture(model, seed=0):
    """Skin points on the box's front (z = 20), left side (x = 30) and top (y = 25) faces, and 4
    head markers 10 mm behind the cranium-attached back face: names the model does not have."""
    rng = np.random.default_rng(seed)
    front = np.c_[rng.uniform(-25, 25, 8), rng.uniform(-20, 20, 8), np.full(8, 20.0)]
    side = np.c_[np.full(3, 30.0), rng.uniform(-20, 20, 3), rng.uniform(-15, 15, 3)]
    top = np.c_[rng.uniform(-25, 25, 3), np.full(3, 25.0), rng.uniform(-15, 15, 3)]
    head = np.array([[-20.0, 10, -30], [20, 10, -30], [-10, 20, -30], [15, 5, -30]])
    names = [f"S{i}" for i in range(14)] + ["H1", "H2", "H3", "H4"]
    return names, np.r_[front, side, top, head]


def test_solve_mocap_solves_a_capture_with_its_own_names(box_model, box_model_path, tmp_path, capsys):
    from facesim.cli import main

    names, pts = box_capture(box_model)
    rng = np.random.default_rng(1)
    # the box is symmetric under 180-degree turns, so only a translation (and metres) here
    P = np.array([pts + [100.0, -50.0, 30.0] + rng.normal(0, 0.05, pts.shape) for _ in range(3)])
    write_markers_csv(tmp_path / "m.csv", [0, 1, 2], names, P / 1000.0)
    out = tmp_path / "out"
    code = main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.csv"), "-o", str(out),
                 "--head-markers", "H1,H2,H3,H4", "--max-steps", "2", "--solver", "direct", "--noise", "0.05", "-q"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    assert "registration" in printed and "placed 18" in printed
    with open(out / "markers_placed.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows] == names
    assert [r["role"] for r in rows].count("head") == 4
    assert max(float(r["distance_mm"]) for r in rows if r["role"] == "skin") < 0.5
    assert (out / "markers_placed.png").stat().st_size > 1000
    with open(out / "frames.csv") as fh:
        log = list(csv.DictReader(fh))
    assert len(log) == 3 and all(r["converged"] in ("1", "True", "true") for r in log), log


def test_solve_mocap_refuses_a_head_marker_it_does_not_know(box_model, box_model_path, tmp_path, capsys):
    from facesim.cli import main

    names, pts = box_capture(box_model)
    write_markers_csv(tmp_path / "m.csv", [0, 1], names, np.array([pts, pts]))
    code = main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.csv"),
                 "-o", str(tmp_path / "out"), "--head-markers", "H1,NOPE,H3"])
    err = capsys.readouterr().err
    assert code == 2 and "NOPE" in err and len(err.strip().splitlines()) == 1, err
