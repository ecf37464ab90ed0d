"""A Posselt rig as the jaw model of ``facesim solve-mocap``: every solved jaw pose stays in the
envelope (issue 6), and ``--jaw-model posselt`` finds a model's own rig.

The capture is synthetic: markers of the small box model (tests/conftest.py) simulated with its
own Posselt rig (fitted to motion generated for the box's TMJ) at slider values inside the unit
cube and, for two frames, beyond it (the rig continued smoothly outside), plus marker noise. The
frames beyond the cube are poses the jaw cannot reach: the best fit without bounds lies outside
the envelope, so the range penalty and its schedule must hold the sliders on the shield.
"""

import numpy as np
import pytest

import facesim.cli as facesim_cli
from facesim import se3
from facesim.jaw.model_rig import fit_model_rig, model_rig_path
from facesim.kinematics.rig_jaw import RigJaw
from facesim.mocap.io import write_markers_csv
from facesim.session import Simulation
from facesim.kinematics.jaw_models import make_jaw_model

TRUTH = np.array([            # sliders (s_x right -> left, s_y closed -> open, s_z retruded -> protruded)
    [0.5, 0.15, 0.3],         # inside
    [0.6, 0.25, 1.05],        # beyond the anterior face
    [-0.1, 0.2, 0.4],         # beyond the right face
])
ACTIVATIONS = np.array([0.2, 0.1])
TOLERANCE = 1e-4              # slider units past the bounds after the penalty schedule


@pytest.fixture(scope="module")
def capture(box_model, tmp_path_factory):
    """The box model and its own rig saved side by side, and a noisy marker file of TRUTH."""
    folder = tmp_path_factory.mktemp("rig_solver")
    model_path = box_model.save(folder / "box.npz")
    rig = fit_model_rig(box_model.jaw)
    rig_path = rig.save(model_rig_path(model_path))
    sim = Simulation(box_model, jaw_model=RigJaw(rig))
    P = []
    for q in TRUTH:
        frame = sim.step(ACTIVATIONS, jaw=q)
        assert frame.converged
        P.append(frame.markers)
    P = np.array(P) + np.random.default_rng(0).normal(scale=0.05, size=(len(TRUTH), box_model.n_markers, 3))
    markers = write_markers_csv(folder / "markers.csv", np.arange(len(TRUTH)), box_model.markers.names, P)
    return {"folder": folder, "model": model_path, "rig": rig_path, "markers": markers, "P": P}


def test_solve_mocap_keeps_every_jaw_pose_inside_the_envelope(box_model, capture):
    out = capture["folder"] / "solved"
    status = facesim_cli.main(["solve-mocap", "--model", str(capture["model"]), "--markers", str(capture["markers"]),
                               "-o", str(out), "--jaw-model", f"posselt:{capture['rig']}", "--head", "none",
                               "--noise", "0.05", "--solver", "direct", "-q"])
    assert status == 0
    table = np.genfromtxt(out / "jaw.csv", delimiter=",", names=True)
    assert table.dtype.names == ("frame", "sx", "sy", "sz")
    q = np.stack([table["sx"], table["sy"], table["sz"]], axis=1)
    assert q.shape == TRUTH.shape
    # every solved pose: sliders in the unit cube, its reference point on or inside the shield
    assert q.min() >= -TOLERANCE and q.max() <= 1 + TOLERANCE, q
    jaw = make_jaw_model(box_model, f"posselt:{capture['rig']}")
    rig = jaw.rig
    for s in q:
        p = rig.frame.to_local(se3.transform_points(jaw.transform(s), rig.reference_point)[0])
        assert rig.shield.sliders(p[None])[1][0] < 0.01                 # mm outside the envelope
    # the bounds were active where the truth lies beyond them (the solver reports the same
    # violation), and inside the fit finds the truth
    assert abs(q[1, 2] - 1) < TOLERANCE and abs(q[2, 0]) < TOLERANCE
    log = np.genfromtxt(out / "frames.csv", delimiter=",", names=True)
    assert log["worst_violation"][1:].min() > 0 and log["worst_violation"].max() <= TOLERANCE
    assert np.abs(q[0] - TRUTH[0]).max() < 0.02
    rms = np.genfromtxt(out / "residuals.csv", delimiter=",", names=True)["rms"]
    assert rms[0] < 0.15 and rms.max() < 1.0


def test_posselt_without_a_file_is_the_model_rig(box_model, capture):
    """``--jaw-model posselt``: the rig next to the model file, or a shipped rig of the same TMJ."""
    jaw = make_jaw_model(box_model, "posselt", model_path=capture["model"])
    assert jaw.kind == "posselt" and jaw.frame is None and jaw.rig.made_for(box_model.jaw)
    q = np.array([0.3, 0.4, 0.6])
    assert np.array_equal(jaw.transform(q), make_jaw_model(box_model, f"posselt:{capture['rig']}").transform(q))
    with pytest.raises(facesim_cli.FacesimError, match="facesim jaw fit-model --model"):
        make_jaw_model(box_model, "posselt")                 # no shipped rig records the box's TMJ
