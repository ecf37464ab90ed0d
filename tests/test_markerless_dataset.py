"""The simulated capture database (facesim/markerless_dataset.py): poses, expressions, the
frames' equilibria on the shipped coarse face, and a build resumed after an interruption."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facesim.errors import FacesimError
from facesim import markerless_dataset as md
from facesim.jaw.markerless_data import load_data
from facesim.kinematics.jaw_models import RigidJaw
from tests.conftest import one_numba_thread

OPENINGS = (0.04, 0.08, 0.12)


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from one_numba_thread()


@pytest.fixture(scope="module")
def model():
    from facesim.jaw._shipped import shipped_model

    return shipped_model()


def _openings(model):
    """The rest pose twice, then pure openings about the intercondylar axis (rad)."""
    return np.stack([np.eye(4), np.eye(4)] + [RigidJaw.from_rotation(model, opening=t) for t in OPENINGS])


@pytest.fixture(scope="module")
def opening_data(model, tmp_path_factory):
    out = tmp_path_factory.mktemp("markerless") / "open.npz"
    return md.build_dataset(model, out, poses=_openings(model), expressions="none", progress=False), out


# ------------------------------------------------------------------ poses and expressions
def test_generated_poses_cover_the_motion_in_order(model):
    from facesim.jaw.model_rig import model_motion
    from facesim.se3 import check_poses

    session = model_motion(model.jaw, seed=0).poses
    P = md.jaw_poses(model.jaw, 50, seed=0)
    assert P.shape == (50, 4, 4)
    check_poses(P, "poses")
    assert np.array_equal(P[0], session[0]) and np.array_equal(P[-1], session[-1])
    # the range: the incisor drops by about the maximum opening somewhere in the sample
    drop = model.jaw.incisor[1] - (P[:, :3, :3] @ model.jaw.incisor + P[:, :3, 3])[:, 1]
    assert drop.max() > 35.0
    # more frames than one session: the next session's poses follow
    more = md.jaw_poses(model.jaw, len(session) + 10, seed=0)
    assert len(more) == len(session) + 10


def test_random_expressions_are_sparse_mirrored_and_smooth(model):
    A = md.random_expressions(model.muscles, 600, seed=3)
    assert A.shape == (600, model.n_muscles)
    assert A.min() >= 0.0 and A.max() <= md.MAX_LEVEL
    active = (A > 0).sum(axis=1)
    assert active.max() <= md.MAX_ACTIVE and (active == 0).any() and (active >= 3).any()
    names = model.muscles.names
    pairs = [(i, names.index(n[:-1] + "R")) for i, n in enumerate(names) if n.endswith("_L")]
    both = sum(np.any((A[:, i] > 0) & np.isclose(A[:, i], A[:, j])) for i, j in pairs)
    one = sum(np.any((A[:, i] > 0) & (A[:, j] == 0)) or np.any((A[:, j] > 0) & (A[:, i] == 0)) for i, j in pairs)
    assert both >= 3 and one >= 3
    assert np.abs(np.diff(A, axis=0)).max() < 0.3            # they rise and fall over frames
    assert np.array_equal(A, md.random_expressions(model.muscles, 600, seed=3))
    assert not np.array_equal(A, md.random_expressions(model.muscles, 600, seed=4))


def test_phantom_subjects_take_explicit_proportions(monkeypatch, tmp_path, box_model):
    from facesim.anatomy import build, phantom

    sub = md.phantom_subject("bmi")
    assert sub.tissue == 1.45 and sub.width == 1.03
    assert md.phantom_subject(0, tissue=1.3) == dataclasses.replace(phantom.Subject(), tissue=1.3)
    assert set(md.TRAINING_SUBJECTS) | {md.HELDOUT_SUBJECT} <= set(md.SUBJECTS) and len(md.TRAINING_SUBJECTS) >= 4
    with pytest.raises(FacesimError, match="unknown name"):
        md.phantom_subject("nobody")
    with pytest.raises(FacesimError, match="unknown proportion"):
        md.phantom_subject(0, chin=1.2)
    calls = []

    def fake_build_head(resolution="coarse", seed=0, progress=None, threads=0, mesh=None, subject=None):
        calls.append((resolution, subject))
        return box_model.with_(meta={"resolution": resolution, "subject": dataclasses.asdict(subject)})

    monkeypatch.setattr(build, "build_head", fake_build_head)
    path = md.phantom_subject_model("bmi", resolution="test", path=tmp_path / "bmi.npz")
    assert calls == [("test", sub)]
    assert md.phantom_subject_model("bmi", resolution="test", path=path) == path and len(calls) == 1   # cached
    md.phantom_subject_model("bmi", resolution="test", path=path, tissue=1.6)                        # another subject
    assert len(calls) == 2 and calls[1][1].tissue == 1.6


# ------------------------------------------------------------------ frames
def test_rest_frames_do_not_move_and_poses_are_the_simulated_jaw(model, opening_data):
    data, out = opening_data
    assert data.ok.all() and data.n_frames == 2 + len(OPENINGS) and data.n_features == 240
    assert np.array_equal(data.poses, _openings(model))
    assert data.meta["jaw_node_error_mm"] < 1e-9 and data.meta["jaw_model"] == "rigid"
    assert np.abs(data.skin_displacement[:2]).max() < 1e-6
    assert np.abs(data.activations).max() == 0.0
    again = load_data(out)
    assert np.array_equal(again.skin, data.skin) and again.meta["layout"]["version"] == data.meta["layout"]["version"]
    assert not md.parts_folder(out).exists()


def test_chin_features_follow_the_bone_when_the_mouth_opens(model, opening_data):
    from facesim.jaw.markerless_features import feature_layout

    data, _ = opening_data
    layout = feature_layout(model)
    chin = (np.abs(layout.params[:, 0]) < 0.2) & (layout.params[:, 1] < 0.45)
    assert chin.sum() >= 8
    previous = 0.0
    for k in range(2, data.n_frames):
        T = data.poses[k]
        bone = layout.bone_point @ T[:3, :3].T + T[:3, 3] - layout.bone_point
        skin = data.skin_displacement[k]
        b, s = bone[chin], skin[chin]
        ratio = np.linalg.norm(s, axis=1) / np.linalg.norm(b, axis=1)
        cos = np.einsum("ij,ij->i", s, b) / (np.linalg.norm(s, axis=1) * np.linalg.norm(b, axis=1))
        assert 0.9 < np.median(ratio) < 1.12 and cos.min() > 0.95
        assert np.linalg.norm(s, axis=1).mean() > previous   # further with a wider opening
        previous = np.linalg.norm(s, axis=1).mean()
    # the bone features are the dataset's: moved by the poses
    assert np.allclose(data.bone_points()[-1], data.bone_rest @ data.poses[-1][:3, :3].T + data.poses[-1][:3, 3])


def test_an_interrupted_build_resumes_to_the_same_dataset(model, tmp_path):
    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.fem.newton import NewtonOptions

    # direct linear solves on one thread: each frame a deterministic function of its warm start
    options = EquilibriumOptions(newton=NewtonOptions(linear_solver="direct"))
    poses = np.stack([RigidJaw.from_rotation(model, opening=t) for t in (0.0, 0.01, 0.02, 0.03, 0.04)])
    A = np.zeros((5, model.n_muscles))
    A[2:, model.muscles.index("mentalis_L")] = [0.2, 0.3, 0.2]
    whole = md.build_dataset(model, tmp_path / "whole.npz", poses=poses, expressions=A, options=options,
                             progress=False)

    class Stop(Exception):
        pass

    seen = []

    def stop_after_three(row):
        seen.append(row["i"])
        if len(seen) == 3:
            raise Stop

    out = tmp_path / "resumed.npz"
    with pytest.raises(Stop):
        md.build_dataset(model, out, poses=poses, expressions=A, options=options, progress=False,
                         on_frame=stop_after_three)
    parts = md.parts_folder(out)
    assert not out.exists() and len(list((parts / "frames").glob("frame_*.npz"))) == 3
    assert len(list((parts / "state").glob("warm_*.npz"))) == 1          # the last converged frame's
    # another run's inputs are refused, naming them
    with pytest.raises(FacesimError, match="activations"):
        md.build_dataset(model, out, poses=poses, expressions="none", options=options, progress=False)
    resumed_frames = []
    data = md.build_dataset(model, out, poses=poses, expressions=A, options=options, progress=False,
                            on_frame=lambda row: resumed_frames.append(row["i"]))
    assert resumed_frames == [3, 4]
    assert data.meta["reused_frames"] == 3 and not parts.exists()
    for name in ("skin", "skin_rest", "bone_rest", "poses", "ok", "feature_tri", "feature_bary", "activations"):
        assert np.array_equal(getattr(data, name), getattr(whole, name)), name
    # a finished dataset of the same inputs is read, not built again
    assert md.build_dataset(model, out, poses=poses, expressions=A, options=options, progress=False,
                            on_frame=lambda row: pytest.fail("solved again")).meta["inputs"] == data.meta["inputs"]
