"""A small rendered capture of the shipped teeth, made once for the teeth tests."""

import numpy as np
import pytest

#: Image size of the test captures (the benchmark runs at 1280x720).
SIZE = (480, 270)


def jaw_poses():
    """Four poses of a generated session 4 frames apart (30 fps): the jaw closing from its
    maximum opening along the posterior border, the incisal point 37-47 mm down."""
    from facesim.jaw.motion import JawMotion

    return JawMotion().session(seed=0).poses[[100, 104, 108, 112]]


@pytest.fixture(scope="session")
def capture(tmp_path_factory):
    """``(folder, dentition, cameras, truth poses)`` of a 4-frame capture, lips on, the lower
    teeth hidden by the lower lip in frame 3, with the true masks."""
    from facesim.teeth.cameras import default_layout
    from facesim.teeth.cli import mouth_target
    from facesim.teeth.dentition import shipped_dentition
    from facesim.teeth.render import CaptureOptions, render_capture

    out = tmp_path_factory.mktemp("teeth_capture")
    d = shipped_dentition()
    cams = default_layout(mouth_target(d), size=SIZE)
    poses = jaw_poses()
    render_capture(out, d, poses, cams, CaptureOptions(hide_lower=(3,), seed=3), write_masks=True)
    return out, d, cams, poses


def pose_error(dentition, A, B):
    """(mm at the lower incisal point, degrees) between jaw poses ``A`` and ``B`` (4, 4)."""
    p = A[:3, :3] @ dentition.incisor + A[:3, 3]
    q = B[:3, :3] @ dentition.incisor + B[:3, 3]
    R = A[:3, :3].T @ B[:3, :3]
    return float(np.linalg.norm(p - q)), float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
