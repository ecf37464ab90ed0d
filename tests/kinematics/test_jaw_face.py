"""Opening the jaw to 0.5 rad with the sliding-condyle model on the shipped coarse face.

psi1..psi3 ~ 0 and psi4..psi6 in range; the condyles translate along their tracks beyond the
pure-rotation range; the flesh follows with no inverted elements: one equilibrium from the rest
shape (about 30 s on two cores; the solver substeps by itself if a direct solve fails).
"""

from __future__ import annotations

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.kinematics.frames import matrix_to_frame
from facesim.model import signed_volumes
from tests.kinematics.test_condyle import apply, jaw  # noqa: F401  (its jaw fixture; the model is conftest's)

OPENING = 0.5   # rad, ~29 degrees: past the pure hinge (~0.16 rad), short of the maximum 0.62


@pytest.fixture(scope="module")
def opened(model, jaw):  # noqa: F811
    sim = FaceSimulator(model, jaw_model=jaw)
    return sim.equilibrium(Controls(np.zeros(model.n_muscles), jaw=jaw.natural_parameters(OPENING)))


def test_pose_satisfies_the_sliding_condyle_constraints(jaw):  # noqa: F811
    psi = jaw.psi(matrix_to_frame(jaw.transform(jaw.natural_parameters(OPENING))))
    assert np.allclose(psi[:3], 0.0, atol=1e-9)
    assert np.all(psi[3:] >= jaw.psi_lower[3:] - 1e-9) and np.all(psi[3:] <= jaw.psi_upper[3:] + 1e-9)
    assert psi[5] == pytest.approx(-np.sin(OPENING))


def test_condyles_translate_along_the_tracks_beyond_pure_rotation(model, jaw):  # noqa: F811
    g = model.jaw
    hinge = jaw.natural_parameters(0.1)        # incisor drop ~10 mm: still the pure hinge
    assert np.all(hinge[1:] == 0.0)
    p = jaw.natural_parameters(OPENING)
    assert np.all(p[1:] > 0.5 * g.track_length)
    condyles = np.stack([g.condyle_right, g.condyle_left])
    moved = apply(jaw.transform(p), condyles) - condyles
    along = moved @ g.track_direction
    np.testing.assert_allclose(along, p[1:], atol=1e-9)        # the slide, mm, along v
    assert np.all(along > 5.0) and np.all(along <= g.track_length + 1e-9)
    np.testing.assert_allclose(moved - along[:, None] * g.track_direction, 0.0, atol=1e-9)
    # under pure rotation the condyles stay put
    np.testing.assert_allclose(apply(jaw.transform(hinge), condyles), condyles, atol=1e-9)


def test_flesh_follows_the_open_jaw_without_inverted_elements(model, jaw, opened):  # noqa: F811
    assert opened.converged, opened.report.relative_residual
    volume = signed_volumes(opened.x, model.tets)[model.simulated]
    assert np.all(volume > 0), f"{int(np.sum(volume <= 0))} inverted simulated tets"
    # the lower lip and the chin go down with the mandible (tens of mm, most of the way a point
    # fixed to the bone would go)
    T = jaw.transform(jaw.natural_parameters(OPENING))
    rest = model.marker_positions()
    moved = model.marker_positions(opened.x) - rest
    bone = apply(T, rest) - rest      # where a point carried rigidly by the mandible would go
    names = list(model.markers.names)
    for name in ("lip_lower_C", "chin_C", "chin_low_C", "mentolabial_C"):
        i = names.index(name)
        assert moved[i, 1] < -15.0, (name, moved[i])
        assert 0.6 < moved[i, 1] / bone[i, 1] < 1.2, (name, moved[i], bone[i])
    # the upper lip is stretched open a little (a few mm), the nose and forehead stay
    upper, lower = moved[names.index("lip_upper_C")], moved[names.index("lip_lower_C")]
    assert upper[1] > 0.25 * lower[1], (upper, lower)
    assert np.linalg.norm(moved[names.index("nose_tip")]) < 8.0, moved[names.index("nose_tip")]
    assert np.linalg.norm(moved[names.index("head_forehead_C")]) < 0.5
