"""Equilibrium of the shipped coarse face: expressions move the face where anatomy says, the
solver converges and warm starts pay off, bones drive the attached flesh."""

from pathlib import Path

import numpy as np
import pytest

from facesim.controls import Controls, rotation_about
from facesim.kinematics.jaw_models import RigidJaw
from facesim.errors import FacesimError
from facesim.fem.equilibrium import FaceSimulator
from facesim.model import load_model

MODEL = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"


@pytest.fixture(scope="module")
def face():
    model = load_model(MODEL)
    return model, FaceSimulator(model)


def _activations(model, **values):
    a = np.zeros(model.n_muscles)
    for name, v in values.items():
        a[model.muscles.index(name)] = v
    return a


@pytest.fixture(scope="module")
def smile(face):
    model, sim = face
    return sim.equilibrium(Controls(_activations(model, zygomaticus_major_L=1.0, zygomaticus_major_R=1.0)))


def test_smile_converges_and_lifts_the_mouth_corners(face, smile):
    model, sim = face
    assert smile.converged and smile.report.relative_residual < 1e-6
    names = list(model.markers.names)
    d = model.marker_positions(smile.x) - model.marker_positions()
    left, right = d[names.index("mouth_corner_L")], d[names.index("mouth_corner_R")]
    # zygomaticus major pulls the corner up and out toward its origin on the cheekbone
    origin, corner = np.array([55.0, 4.0, 58.0]), model.marker_positions()[names.index("mouth_corner_L")]
    pull = (origin - corner) / np.linalg.norm(origin - corner)
    assert left @ pull > 1.5 and right @ (pull * [-1, 1, 1]) > 1.5
    assert left[1] > 0.4 and right[1] > 0.4
    assert left[0] > 0.3 and right[0] < -0.3
    # the two sides mirror each other only roughly: at ~9 mm tets the muscle's ~30 tets differ
    # from side to side (fTetWild meshes are not symmetric)
    assert abs(np.linalg.norm(left) - np.linalg.norm(right)) < 0.5 * max(np.linalg.norm(left), np.linalg.norm(right))
    # the forehead and the head markers stay put
    for name in ("head_forehead_C", "head_temple_L", "forehead_low_C"):
        assert np.linalg.norm(d[names.index(name)]) < 0.3, name
    # no inverted element
    assert (model.tet_volumes(smile.x)[sim.elems] > 0).all()


def test_warm_start_from_the_solution_needs_at_most_one_newton_step(face, smile):
    model, sim = face
    again = sim.equilibrium(smile.controls, x0=smile.x)
    assert again.converged and again.iterations <= 1
    # a 10 % change from a warm start converges in fewer steps than the cold solve
    less = sim.equilibrium(Controls(smile.controls.a * 0.9), x0=smile.x)
    assert less.converged and less.iterations < smile.iterations


def test_force_columns_match_the_muscle_force(face, smile):
    model, sim = face
    G = sim.force_columns(smile.x)
    a = smile.controls.a
    f_active = -(sim.muscle.gradient(smile.x, a) - sim.muscle.gradient(smile.x, np.zeros_like(a)))
    np.testing.assert_allclose(G @ a, f_active.ravel(), atol=1e-10)
    # at equilibrium the internal force vanishes on the free nodes
    f = sim.internal_force(smile.x, a)
    free = np.flatnonzero(~sim.fixed.all(axis=1))
    assert np.linalg.norm(f[free]) < 1e-5 * np.abs(G @ a).sum()


def test_head_motion_moves_the_face_rigidly(face):
    model, sim = face
    H = rotation_about([0.0, 0.3, 0.1], [0.0, 0.0, 40.0])
    H[:3, 3] += [5.0, -2.0, 3.0]
    eq = sim.equilibrium(Controls(np.zeros(model.n_muscles), head=H))
    assert eq.converged and eq.iterations <= 1
    np.testing.assert_allclose(eq.x, model.X @ H[:3, :3].T + H[:3, 3], atol=1e-6)


def test_jaw_opening_carries_the_lower_face(face):
    model, sim = face
    T = RigidJaw.from_rotation(model, 0.15, translation=3.0 * model.jaw.track_direction)
    eq = sim.equilibrium(Controls(np.zeros(model.n_muscles), jaw=T))
    assert eq.converged
    names = list(model.markers.names)
    d = model.marker_positions(eq.x) - model.marker_positions()
    assert d[names.index("chin_C"), 1] < -8.0                       # the chin drops with the mandible
    assert abs(d[names.index("nose_tip"), 1]) < 0.1 * abs(d[names.index("chin_C"), 1])   # the nose hardly
    assert d[names.index("lip_lower_C"), 1] < d[names.index("lip_upper_C"), 1] - 5.0   # the lips part
    assert (model.tet_volumes(eq.x)[sim.elems] > 0).all()


def test_bad_controls_are_refused(face):
    model, sim = face
    with pytest.raises(FacesimError, match="activations"):
        sim.equilibrium(Controls(np.zeros(3)))
    with pytest.raises(FacesimError, match="4x4"):
        Controls(np.zeros(model.n_muscles), head=np.eye(3))
    with pytest.raises(FacesimError, match="x0"):
        sim.equilibrium(Controls(np.zeros(model.n_muscles)), x0=np.zeros((3, 3)))


def test_rigid_fit_and_interpolation():
    from facesim.se3 import interpolate_rigid, rigid_fit

    rng = np.random.default_rng(0)
    T = rotation_about([0.2, -0.4, 0.1], [10.0, 0.0, 5.0])
    T[:3, 3] += [1.0, 2.0, -3.0]
    P = rng.normal(size=(30, 3)) * 20
    np.testing.assert_allclose(rigid_fit(P, P @ T[:3, :3].T + T[:3, 3]), T, atol=1e-12)
    c = P.mean(axis=0)
    np.testing.assert_allclose(interpolate_rigid(np.eye(4), T, 0.0, c), np.eye(4), atol=1e-14)
    np.testing.assert_allclose(interpolate_rigid(np.eye(4), T, 1.0, c), T, atol=1e-12)
    half = interpolate_rigid(np.eye(4), T, 0.5, c)
    assert np.allclose(half[:3, :3].T @ half[:3, :3], np.eye(3))
    np.testing.assert_allclose(half[:3, :3] @ c + half[:3, 3], 0.5 * (c + T[:3, :3] @ c + T[:3, 3]), atol=1e-12)


def test_a_failed_solve_is_retried_in_substeps(face):
    """With too few Newton steps allowed, a large jaw opening fails in one go and succeeds as a
    path of eight equilibria (in one go it takes 6 Newton steps from the refined starting guess)."""
    from facesim.fem.equilibrium import EquilibriumOptions
    from facesim.fem.newton import NewtonOptions

    model, _ = face
    T = RigidJaw.from_rotation(model, 0.25, translation=6.0 * model.jaw.track_direction)
    c = Controls(np.zeros(model.n_muscles), jaw=T)
    short = NewtonOptions(max_iterations=4, settle_iterations=0)   # stops at 4
    once = FaceSimulator(model, EquilibriumOptions(short, substeps=1)).equilibrium(c)
    stepped = FaceSimulator(model, EquilibriumOptions(short, substeps=8)).equilibrium(c)
    assert not once.converged
    assert stepped.converged and stepped.report.seconds["substeps"] == 8


def test_sphere_pressed_into_the_cheek_and_released(face):
    """Issue 4 scenario: a rigid sphere pushed 10 mm into the cheek through a ContactTerm passed
    as an extra term; no skin node deeper than 0.5 mm inside, no inverted tet, and the face
    returns to rest when the sphere leaves."""
    from facesim.contact import Collider, ContactTerm, Sphere, node_areas

    model, sim = face
    skin = np.unique(model.skin)
    weights = node_areas(model.X, model.skin)[skin]
    cheek = model.marker_positions()[list(model.markers.names).index("cheek_mid_L")]
    n = np.array([0.6, 0.0, 0.8])
    radius = 12.0
    rest = Controls(np.zeros(model.n_muscles))
    x = None
    for depth in (5.0, 10.0):
        term = ContactTerm(skin, [Collider(Sphere(cheek + (radius - depth) * n, radius))], stiffness=1.0,
                           weights=weights)
        eq = sim.equilibrium(rest, x0=x, extra_terms=[term])
        x = eq.x
        assert eq.converged
        assert term.signed_distances(x).min() > -0.5
        assert (model.tet_volumes(x)[sim.elems] > 0).all()
    pushed = np.linalg.norm(x - model.X, axis=1).max()
    assert pushed > 7.0   # the cheek gave way
    gone = ContactTerm(skin, [Collider(Sphere(cheek + 100.0 * n, radius))], stiffness=1.0, weights=weights)
    back = sim.equilibrium(rest, x0=x, extra_terms=[gone])
    assert back.converged
    assert np.linalg.norm(back.x - model.X, axis=1).max() < 1e-3 * pushed


def test_teeth_contact_keeps_the_puckered_lips_out_of_the_teeth(face):
    from facesim.fem.equilibrium import EquilibriumOptions

    model, plain = face
    a = np.array([1.0 if n.startswith("orbicularis_oris") else 0.0 for n in model.muscles.names])
    sim = FaceSimulator(model, EquilibriumOptions(teeth_contact=True))
    rest = sim.equilibrium(Controls(np.zeros(model.n_muscles)))
    assert rest.converged and np.abs(rest.x - model.X).max() < 1e-9   # the rest shape stays an equilibrium
    term = sim.teeth_term(Controls(a))
    with_contact = sim.equilibrium(Controls(a))
    without = plain.equilibrium(Controls(a))
    assert with_contact.converged and without.converged
    # per lip node, its distance to the teeth against where its penalty starts (term.margin, (k,) mm)
    assert (term.signed_distances(without.x) - term.margin).min() < -1.0     # the sphincter pushes lips into the teeth
    assert (term.signed_distances(with_contact.x) - term.margin).min() > -0.1   # ... unless they are kept out
