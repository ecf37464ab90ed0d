"""Penalty contact term: derivatives, assembly, projection, and a small FEM indentation."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from facesim.contact import (
    Capsule,
    Collider,
    ContactTerm,
    MeshSDF,
    Plane,
    Sphere,
    node_areas,
    translation,
)
from facesim.errors import FacesimError
from facesim.fem import DofSystem, ElasticTerm, NewtonOptions, RestShape, box_mesh
from facesim.fem.newton import Problem, newton
from tests.conftest import node_order
from tests.fem.test_terms import _fd_gradient, _fd_hessian


def block_mesh():
    """A 2 x 2 x 1-cell box of 10 x 10 x 5 mm (18 nodes) at the origin."""
    X, T = box_mesh((10.0, 10.0, 5.0), (2, 2, 1))
    return X, T


def colliders(which):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    T[:3, 3] = [5.0, 5.0, 2.5]
    return {
        "sphere": [Sphere([5.0, 5.0, 2.5], 5.0)],
        "plane": [Plane([0.0, 0.0, 2.0], [0.2, 0.1, -1.0])],
        "capsule": [Collider(Capsule([-4.0, 0.0, 0.0], [4.0, 0.0, 0.0], 3.5), T)],
        "two": [Sphere([5.0, 5.0, 2.5], 5.0), Plane([0.0, 0.0, 2.0], [0.2, 0.1, -1.0])],
        "mesh": [Collider(MeshSDF.from_mesh(*_icosphere(5.5), spacing=0.7, margin=2.0), T)],
    }[which]


def _icosphere(r):
    m = trimesh.creation.icosphere(3, r)
    return m.vertices, m.faces


def assembled(term, x, T, project, fixed=None):
    sysm = DofSystem(T, len(x), np.zeros((len(x), 3), bool) if fixed is None else fixed, np.arange(len(T)))
    data = sysm.new_data()
    term.add_hessian(x, None, sysm, data, project)
    return sysm, node_order(sysm.matrix(data, diag=0.0), sysm)


def contact_state(which, seed=0):
    X, T = block_mesh()
    x = X + 0.3 * np.random.default_rng(seed).normal(size=X.shape)
    w = np.random.default_rng(seed + 1).uniform(0.5, 2.0, len(X))
    term = ContactTerm(np.arange(len(X)), colliders(which), stiffness=3.0, margin=0.4, weights=w)
    return X, T, x, term


@pytest.mark.parametrize("which", ["sphere", "plane", "capsule", "two", "mesh"])
def test_gradient_and_hessian_against_central_differences(which):
    _, T, x, term = contact_state(which)
    pen = term.margin - term.signed_distances(x)
    assert (pen > 0).sum() >= 3 and (pen <= 0).sum() >= 1   # some nodes in contact, some not
    E, g = term.energy_and_gradient(x)
    assert E > 0 and np.linalg.norm(g) > 1e-2
    assert term.energy(x) == pytest.approx(E, rel=1e-14)
    np.testing.assert_allclose(_fd_gradient(term, x, None), g, atol=1e-6 * max(1.0, np.abs(g).max()))
    # exact Hessian (project=False) includes the collider curvature -w k pen hess d
    _, H = assembled(term, x, T, project=False)
    H_fd = _fd_hessian(term, x, None)
    assert np.linalg.norm(H_fd) > 1e-2
    np.testing.assert_allclose(H, H_fd, atol=1e-5 * np.abs(H_fd).max())
    # nodes outside every collider's margin contribute nothing
    free = np.flatnonzero(pen <= 0)   # pen of the nearest collider
    assert np.all(g[free] == 0) and np.all(H.reshape(len(x), 3, len(x), 3)[free][:, :, free] == 0)


@pytest.mark.parametrize("which", ["sphere", "capsule", "mesh"])
def test_projected_blocks_are_psd_gauss_newton(which):
    _, T, x, term = contact_state(which, seed=2)
    _, H = assembled(term, x, T, project=True)
    _, H_true = assembled(term, x, T, project=False)
    assert np.linalg.eigvalsh(H).min() > -1e-10
    assert np.linalg.eigvalsh(H_true).min() < -1e-3   # the curvature part is really indefinite
    if which != "mesh":
        # convex closed forms: projection leaves exactly the Gauss-Newton part w k G G^T
        c = term.colliders[0]
        d, G, _ = c.evaluate(x)
        pen = np.maximum(term.margin - d, 0.0)
        gn = np.zeros_like(H)
        for i in np.flatnonzero(pen > 0):
            gn[3 * i:3 * i + 3, 3 * i:3 * i + 3] = term.stiffness * term.weights[i] * np.outer(G[i], G[i])
        np.testing.assert_allclose(H, gn, atol=1e-10)


def test_kernel_energy_against_numpy_oracle():
    _, _, x, term = contact_state("two", seed=3)
    E = 0.0
    for c in term.colliders:
        pen = np.maximum(term.margin - c.distance(x), 0.0)
        E += 0.5 * term.stiffness * (term.weights * pen ** 2).sum()
    assert E > 0
    assert term.energy(x) == pytest.approx(E, rel=1e-13)


def test_zero_outside_and_margin():
    X, T = block_mesh()
    far = Sphere([5.0, 5.0, 20.0], 3.0)   # 12 mm above the block
    term = ContactTerm(np.arange(len(X)), [far], stiffness=10.0)
    E, g = term.energy_and_gradient(X)
    assert E == 0.0 and not g.any()
    _, H = assembled(term, X, T, project=True)
    assert not H.any()
    assert np.all(term.penetration(X) == 0)
    # within the margin but outside the surface: pushed away already
    near = ContactTerm([0], [Plane([0, 0, -0.1], [0, 0, 1.0])], stiffness=10.0, margin=0.5)
    assert near.energy(X) == pytest.approx(0.5 * 10.0 * 0.4 ** 2)
    assert near.gradient(X)[0, 2] == pytest.approx(-10.0 * 0.4)   # energy falls as the node moves up


def test_fixed_nodes_skip_the_hessian_and_with_colliders_copies():
    X, T, x, term = contact_state("sphere")
    fixed = np.zeros((len(X), 3), bool)
    fixed[:3] = True   # nodes 0-2 are out of the system
    sysm, _ = assembled(term, x, T, project=True, fixed=fixed)
    blocks = term.diagonal_blocks(sysm)
    assert np.all(blocks[:3] == -1) and np.all(blocks[3:] >= 0)
    assert sysm.indices[blocks[3:]].tolist() == sysm.row_of[term.nodes[3:]].tolist()
    assert term.diagonal_blocks(sysm) is blocks   # looked up once per system
    moved = term.with_colliders([Sphere([5.0, 5.0, 40.0], 5.0)])
    assert moved.energy(x) == 0.0 and term.energy(x) > 0.0


def test_bad_arguments():
    with pytest.raises(FacesimError, match="stiffness"):
        ContactTerm([0, 1], [Sphere(np.zeros(3), 1.0)], stiffness=0.0)
    with pytest.raises(FacesimError, match="distinct"):
        ContactTerm([0, 0], [Sphere(np.zeros(3), 1.0)])
    with pytest.raises(FacesimError, match="weights"):
        ContactTerm([0, 1], [Sphere(np.zeros(3), 1.0)], weights=[1.0])
    with pytest.raises(FacesimError, match="collider"):
        ContactTerm([0], ["sphere"])
    with pytest.raises(FacesimError, match="out of range"):
        ContactTerm([5], [Sphere(np.zeros(3), 1.0)]).energy(np.zeros((3, 3)))


def test_node_areas_sum_to_surface_area():
    m = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    a = node_areas(m.vertices, m.faces)
    assert a.shape == (len(m.vertices),) and a.min() > 0
    assert a.sum() == pytest.approx(m.area)


def test_sphere_pressed_into_a_box():
    """A rigid ball (radius 6 mm) pushed 2 mm into the top of a 20 x 20 x 10 mm block with a fixed
    bottom. Flesh-like material: mu = 16 kPa, kappa = 0.4 MPa.

    Penetration bound: at equilibrium each contact node's penetration is its contact force over
    k (checked below to round-off). The force is bounded by the confined-compression stress
    sigma <= (kappa + 4 mu / 3) * strain ~ 0.42 MPa * (2 / 10) ~ 0.08 MPa (the stiffest
    response the layer can give) times the node's tributary area (2.5 mm)^2, i.e. ~0.5 N, so
    k = 50 N/mm keeps every node within ~0.01 mm of the surface: we assert 0.05 mm.
    """
    X, T = box_mesh((20.0, 20.0, 10.0), (8, 8, 4), origin=(-10.0, -10.0, 0.0))
    rest = RestShape(X, T)
    n = len(X)
    elastic = ElasticTerm(rest, 6e-3, 2e-3, 0.4)
    fixed = np.zeros((n, 3), bool)
    fixed[X[:, 2] == 0.0] = True
    top = np.flatnonzero(np.isclose(X[:, 2], 10.0))
    k, radius, depth = 50.0, 6.0, 2.0
    ball = Collider(Sphere(np.zeros(3), radius)).at(translation([0.0, 0.0, 10.0 + radius - depth]))
    contact = ContactTerm(top, [ball], stiffness=k)
    assert contact.penetration(X).max() == pytest.approx(depth)
    system = DofSystem(rest.tets, n, fixed, np.arange(len(T)))
    x, report = newton(Problem([elastic, contact], system, X), NewtonOptions(linear_solver="direct"), force_scale=1.0)
    assert report.converged
    pen = contact.penetration(x)
    assert 0.0 < pen.max() < 0.05
    # force balance at every contact node: k pen = |elastic force|
    f_elastic = np.linalg.norm(elastic.gradient(x)[top], axis=1)
    np.testing.assert_allclose(k * pen, f_elastic, atol=1e-6)
    # the block deforms: the node under the ball goes down by the indentation (less its penetration)
    centre = top[np.argmin(np.linalg.norm(X[top, :2], axis=1))]
    assert X[centre, 2] - x[centre, 2] > depth - 0.05
    corners = top[np.abs(X[top, :2]).min(axis=1) == 10.0]
    assert np.abs(x[corners] - X[corners]).max() < 0.5 * depth
    e = x[T[:, 1:]] - x[T[:, :1]]
    assert np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])).min() > 0
    # the ball leaves: the block springs back to rest
    away = contact.with_colliders([ball.at(translation([0.0, 0.0, 30.0]))])
    back, report = newton(Problem([elastic, away], system, x), NewtonOptions(linear_solver="direct"),
                          force_scale=1.0)
    assert report.converged
    np.testing.assert_allclose(back, X, atol=1e-6)
