"""The frame-by-frame scripting API: facesim.Simulation."""

import numpy as np
import pytest

import facesim
from facesim.contact import Collider, KinematicPath, Sphere
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.newton import NewtonOptions
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.session import Simulation, activation_vector
from facesim.kinematics.jaw_models import make_jaw_model

DIRECT = NewtonOptions(linear_solver="direct")


def test_activation_vector_by_name_base_name_or_array(box_model):
    a = activation_vector(box_model, {"zygomaticus_major": 0.5, "orbicularis_oris": 1.0})
    np.testing.assert_array_equal(a, [0.5, 1.0])
    np.testing.assert_array_equal(activation_vector(box_model, {"zygomaticus_major_L": 0.2}), [0.2, 0.0])
    np.testing.assert_array_equal(activation_vector(box_model, None), [0.0, 0.0])
    with pytest.raises(FacesimError, match="unknown muscle 'zygomaticus'.*closest: zygomaticus_major_L"):
        activation_vector(box_model, {"zygomaticus": 1.0})
    with pytest.raises(FacesimError, match=r"in \[0, 1\]"):
        activation_vector(box_model, [0.0, 1.5])
    with pytest.raises(FacesimError, match="expected 2 values"):
        activation_vector(box_model, [0.0])


def test_jaw_models_by_name(box_model):
    assert make_jaw_model(box_model, "rigid").name == "rigid"
    assert isinstance(make_jaw_model(box_model, "sliding-condyle"), SlidingCondyleJaw)
    with pytest.raises(FacesimError, match="expected one of rigid, sliding-condyle"):
        make_jaw_model(box_model, "hinge")
    with pytest.raises(FacesimError, match="transform"):
        make_jaw_model(box_model, 3)


def test_steps_warm_start_from_the_last_converged_frame(box_model):
    sim = facesim.Simulation(box_model, newton=DIRECT)
    first = sim.step({"zygomaticus_major": 1.0})
    assert first.converged and first.iterations > 1 and first.index == 0
    again = sim.step({"zygomaticus_major": 1.0})   # same controls, warm: nothing to do
    assert again.converged and again.iterations == 0 and again.index == 1
    np.testing.assert_allclose(again.x, first.x)
    np.testing.assert_allclose(again.markers, box_model.marker_positions(first.x))
    sim.reset()
    assert sim.last is None and sim.step(Controls(np.zeros(2))).iterations == 0


def test_sliding_condyle_jaw_places_the_jaw_nodes(box_model):
    sim = Simulation(box_model, jaw_model="sliding-condyle", newton=DIRECT)
    p = np.array([0.2, 3.0, 3.0])
    f = sim.step(None, jaw=p)
    assert f.converged
    T = SlidingCondyleJaw(box_model.jaw).transform(p)
    X = box_model.X[box_model.jaw_nodes]
    np.testing.assert_allclose(f.x[box_model.jaw_nodes], X @ T[:3, :3].T + T[:3, 3], atol=1e-12)


def test_scripted_sphere_presses_in_and_leaves(box_model):
    """A ball (radius 8 mm) driven 4 mm into the front face of the box and out again: the skin
    stays within 0.1 mm of its surface (contact stiffness 1 N/mm^3 on lumped areas), the node
    under it gives way, and the box returns to rest once the ball has gone."""
    radius, depth = 8.0, 4.0
    front = box_model.X[:, 2].max()
    # on the line of a skin node (x = 0, y = 5): node-based contact lets a ball sink between nodes
    centres = [[0.0, 5.0, front + radius + 5.0], [0.0, 5.0, front + radius - depth], [0.0, 5.0, front + 40.0]]
    ball = KinematicPath.from_centres(Collider(Sphere((0, 0, 0), radius), name="ball"), [0, 4, 8], centres)
    sim = Simulation(box_model, colliders=[ball], newton=DIRECT)
    frames = [sim.step(None, frame=k) for k in range(9)]
    assert all(f.converged for f in frames)
    pressed = frames[4]
    assert 0.0 < pressed.penetration < 0.1
    centre = np.argmin(np.linalg.norm(box_model.X - [0.0, 5.0, front], axis=1))
    assert box_model.X[centre, 2] - pressed.x[centre, 2] > 0.5 * depth   # pushed in (and aside: 10 mm elements)
    assert frames[-1].penetration == 0.0
    np.testing.assert_allclose(frames[-1].x, box_model.X, atol=1e-6)
    assert [len(f.colliders) for f in frames] == [1] * 9
