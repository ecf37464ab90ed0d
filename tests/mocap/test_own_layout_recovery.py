"""solve-mocap recovers known activations from a capture with its own layout (issue 15, part 1).

The capture is made here, not by facesim.mocap.layout: a short performance simulated on the coarse
face (smile and lower-lip depressor building up, the jaw opening a little), 30 skin points on
random forward-facing skin triangles carried through the deformed skin, a 4-marker headband 15 mm
off the forehead and temples, a known head motion, 0.1 mm noise, a gap; names the model does not
have; turned into a z-up capture frame and written in metres. Solved on the same coarse face (the
full-size check on another mesh is benchmarks/bench_own_layout.py).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from facesim.mocap.io import write_markers_csv
from facesim.model import load_model

FACE = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"
DRIVEN = {"zygomaticus_major": 0.5, "depressor_labii_inferioris": 0.4}
#: activation error allowed on the driven muscles (both sides), and jaw opening error, rad
TOL_ACTIVATION, TOL_JAW = 0.1, 0.01
HEADBAND_AT = np.array([[-22.0, 90.0, 80.0], [22.0, 90.0, 80.0], [-62.0, 62.0, 45.0], [62.0, 62.0, 45.0]])
#: model (x left, y up, z forward) -> capture (x forward, y left, z up), turned 30 deg about z
TO_CAPTURE = Rotation.from_euler("z", 30, degrees=True).as_matrix() @ np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])


def _layout(model, rng, n_skin=30):
    X, S = model.X, model.skin
    n = np.cross(X[S[:, 1]] - X[S[:, 0]], X[S[:, 2]] - X[S[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = X[S].mean(axis=1)
    front = np.flatnonzero((n[:, 2] > 0.6) & (c[:, 2] > 40) & (np.abs(c[:, 0]) < 55) & (c[:, 1] > -80)
                           & (c[:, 1] < 70))
    tri = rng.choice(front, n_skin, replace=False)
    band = np.array([c[k] + 15.0 * n[k] for k in (int(np.argmin(np.linalg.norm(c - p, axis=1))) for p in HEADBAND_AT)])
    return tri, rng.dirichlet([3, 3, 3], n_skin), band


@pytest.fixture(scope="module")
def face():
    if not FACE.is_file():
        pytest.skip("meshes/face_coarse.npz not present")
    return load_model(FACE)


@pytest.mark.parametrize("head, n_band", [("procrustes", 4), ("solve", 2)])
def test_capture_of_its_own_layout_recovers_the_activations(face, tmp_path, capsys, head, n_band):
    """With a 4-marker headband stabilised by Procrustes, and with only 2 headband markers (too
    few to stabilise by) and the head solved with the other controls (--head solve)."""
    from facesim.cli import main
    from facesim.framelog import read_log
    from facesim.session import Simulation, activation_vector

    rng = np.random.default_rng(3)
    sim = Simulation(face, jaw_model="sliding-condyle")
    ramp = np.array([0.0, 0.0, 0.5, 1.0])                 # two neutral frames, then the expression builds
    A = np.array([s * activation_vector(face, DRIVEN) for s in ramp])
    opening = 0.06 * ramp
    X = []
    for a, q in zip(A, opening):
        f = sim.step(a, jaw=sim.jaw_model.natural_parameters(q))
        assert f.converged, f.error
        X.append(f.x)
    tri, bary, band = _layout(face, rng)
    skin = np.array([np.einsum("rk,rkj->rj", bary, x[face.skin[tri]]) for x in X])
    P = np.concatenate([skin, np.broadcast_to(band[:n_band], (len(X), n_band, 3))], axis=1)
    centre = face.X[face.cranium_nodes].mean(axis=0)
    for k in range(len(P)):   # a known head motion: up to ~1.7 deg and 3 mm
        R = Rotation.from_rotvec([0.03 * np.sin(k), -0.02 * k / 3, 0.01]).as_matrix()
        P[k] = (P[k] - centre) @ R.T + centre + [1.0 * k, -0.5, 3.0 * np.sin(k)]
    P = P @ TO_CAPTURE.T + [900.0, -300.0, 1600.0] + rng.normal(0.0, 0.1, P.shape)
    P[3, 7] = np.nan   # a gap
    bands = ["band_a", "band_b", "band_c", "band_d"][:n_band]
    names = [f"m{i:02d}" for i in range(len(tri))] + bands
    assert not set(names) & set(face.markers.names)
    write_markers_csv(tmp_path / "cap.csv", np.arange(len(P)), names, P / 1000.0)   # metres
    out = tmp_path / "out"
    code = main(["solve-mocap", "--model", str(FACE), "--markers", str(tmp_path / "cap.csv"), "-o", str(out),
                 "--layout", "capture", "--head-markers", ",".join(bands), "--bind-frames", "0:1",
                 "--no-contact", "--noise", "0.1", "--head", head, "-q"])
    printed = capsys.readouterr().out
    assert code == 0, printed
    with open(out / "markers_placed.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows] == names                      # every marker placed, none refused
    assert [r["role"] for r in rows] == ["skin"] * len(tri) + ["head"] * n_band
    assert (out / "head.csv").is_file() == (head == "solve")
    assert max(float(r["distance_mm"]) for r in rows if r["role"] == "skin") < 1.0
    with open(out / "frames.csv") as fh:
        log = list(csv.DictReader(fh))
    assert len(log) == 4 and all(r["converged"] in ("1", "True", "true") for r in log), log
    header, got = read_log(out / "activations.csv")
    driven = [i for i, m in enumerate(face.muscles.names) if any(m.startswith(d) for d in DRIVEN)]
    assert len(driven) == 4 and A[-1, driven].min() > 0.3   # both sides of both muscles, truly driven
    error = np.abs(got[:, 1:] - A)
    # two markers fewer, and the head's pose taken from markers that also carry the expression
    tol = TOL_ACTIVATION if head == "procrustes" else 1.5 * TOL_ACTIVATION
    assert error[:, driven].max() < tol, error[:, driven]
    _, jaw = read_log(out / "jaw.csv")
    assert np.abs(jaw[:, 1] - opening).max() < TOL_JAW, jaw[:, 1]
    _, res = read_log(out / "residuals.csv")
    assert res[:, 1].max() < 0.5, res[:, 1]   # mm: the noise is 0.17 mm in 3-D
