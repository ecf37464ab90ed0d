"""Tracking on the shipped coarse face (issue 5): from a neutral start a frame converges in at
most 5 Gauss-Newton steps, and along a capture-rate sequence most frames need one."""

from pathlib import Path

import numpy as np
import pytest

from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.inverse import ControlSpace, FitOptions, fit_frame
from facesim.inverse.tracking import TrackOptions, fit_markers
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.demo import VISIBLE_MM, muscle_sensitivity
from facesim.model import load_model
from facesim.session import activation_vector

NOISE = 0.5   # mm per coordinate, as the recovery test


@pytest.fixture(scope="module")
def capture():
    """A smile with eye squint and lower-lip depressor building up while the jaw opens, at a
    capture rate (activations change by at most 0.06 and the jaw by 0.01 rad, 0.6 deg, per frame:
    a 60 Hz capture of a smile that builds in a quarter of a second), sampled at the markers with
    0.5 mm noise; one marker per tracked frame is an outlier moved 8 mm."""
    model = load_model(Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz")
    jaw = SlidingCondyleJaw(model.jaw)
    sim = FaceSimulator(model, jaw_model=jaw)
    rng = np.random.default_rng(4)
    truths, targets, planted, x = [], [], [], None
    for k in range(7):
        a = activation_vector(model, {"zygomaticus_major": 0.4 + 0.06 * k, "orbicularis_oculi": 0.3 - 0.03 * k,
                                      "depressor_labii_inferioris": 0.2 + 0.03 * k})
        truth = Controls(a, jaw=jaw.natural_parameters(0.05 + 0.01 * k))
        eq = sim.equilibrium(truth, x0=x)
        assert eq.converged
        x = eq.x
        T = model.marker_positions(x) + NOISE * rng.normal(size=(model.n_markers, 3))
        face = np.flatnonzero(~model.markers.head)
        j = int(rng.choice(face)) if k else -1
        if k:
            d = rng.normal(size=3)
            T[j] += 8.0 * d / np.linalg.norm(d)
        truths.append(truth)
        targets.append(T)
        planted.append(j)
    return sim, truths, targets, planted, muscle_sensitivity(sim) >= VISIBLE_MM


def test_cold_frame_then_most_tracked_frames_take_one_step(capture):
    sim, truths, targets, planted, visible = capture
    model = sim.model
    space = ControlSpace.of(sim)
    options = TrackOptions(fit=FitOptions(noise=NOISE), head="none")
    neutral = Controls(np.zeros(model.n_muscles), jaw=np.zeros(space.n_jaw))
    fit = fit_frame(sim, targets[0], neutral, None, space, options.fit)
    assert fit.report.gn_steps <= 5                       # from a neutral start
    assert fit.report.marker_rms < 1.2 * NOISE * np.sqrt(3)
    steps, fits_per_frame = [], []
    for k in range(1, len(targets)):
        fit, outliers, fits = fit_markers(sim, targets[k], fit.controls, fit.x, space, options, fit.jacobian)
        steps.append(sum(f.report.gn_steps for f in fits))
        fits_per_frame.append(len(fits))
        assert outliers == [planted[k]]                   # the 8 mm outlier, and nothing else
        assert fit.report.marker_rms < 1.2 * NOISE * np.sqrt(3)   # the noise alone: 0.87 mm RMS
        # muscles the markers see (one unit moves a marker >= 5 mm, as the demo scores) are recovered
        # (the largest errors: muscles that share their markers with another, e.g. risorius and
        # zygomaticus); those the markers barely see scatter with the noise
        err = np.abs(fit.controls.a - truths[k].a)[visible]
        assert err.max() < 0.4 and np.mean(err) < 0.05, (k, err.max(), np.mean(err))
        assert fit.report.worst_violation < 1e-4
    # the outlier was screened on the first step's linear prediction: frames are fitted once (the
    # screen may also flag a good marker whose prediction was off, which costs a refit)
    assert sum(n == 1 for n in fits_per_frame) >= len(fits_per_frame) - 1, fits_per_frame
    assert sum(s == 1 for s in steps) > len(steps) / 2, steps
    assert max(steps) <= 3, steps
