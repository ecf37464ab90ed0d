"""Lip self-contact term: derivatives, the spatial hash against brute force, the closest-point
kernel against trimesh, the rest shape of the shipped face, and the lips under orbicularis oris."""

import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from facesim._kernels import selfcontact as K
from facesim.contact import SurfaceContactTerm, lip_contact_term
from facesim.contact.self_contact import CORNER_GAP
from facesim.errors import FacesimError
from facesim.fem import DofSystem
from tests.conftest import node_order
from tests.fem.test_terms import _fd_gradient, _fd_hessian

MODEL = Path(__file__).resolve().parents[2] / "meshes" / "face_coarse.npz"


def grid_sheet(nx, nz, y, spacing=1.0, shift=(0.0, 0.0), normal=-1):
    """``(X (nx nz, 3), tris)``: a grid in the plane ``y`` with normals along ``normal * e_y``."""
    i, k = np.meshgrid(np.arange(nx), np.arange(nz), indexing="ij")
    X = np.stack([i.ravel() * spacing + shift[0], np.full(i.size, y), k.ravel() * spacing + shift[1]], 1)
    v = np.arange(nx * nz).reshape(nx, nz)
    a, b, c, d = v[:-1, :-1].ravel(), v[1:, :-1].ravel(), v[1:, 1:].ravel(), v[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])   # normal -y
    return X, (tris if normal < 0 else tris[:, [0, 2, 1]])


def two_sheets(gap=1.0, shift=(-0.63, 0.21)):
    """Upper sheet (normals -y) above a lower sheet (normals +y), ``gap`` mm apart. The lower one
    has a V-shaped valley along x = 2 and a pit at one vertex (nodes behind them are closest to
    the crease edges or the pit's vertex); the upper one is shifted so its nodes fall on faces,
    edges and off the lower sheet's rim. The lower sheet's corner node 0 is also a node of the
    upper sheet (a shared mouth corner)."""
    Xb, Tb = grid_sheet(6, 6, -gap / 2, normal=+1)
    Xb[:, 1] -= 0.35 * np.maximum(0.0, 1.0 - np.abs(Xb[:, 0] - 2.0))
    Xb[1 * 6 + 2, 1] -= 0.9   # a pit at (1, 2): nodes behind it are closest to the vertex
    Xa, Ta = grid_sheet(5, 5, gap / 2, shift=shift)
    X = np.concatenate([Xb, Xa])
    Ta = Ta + len(Xb)
    Ta[Ta == len(Xb)] = 0   # share the corner (the upper sheet's node 0 becomes node 0)
    return X, Ta, Tb


def pressed(X, Ta, depth, noise, seed):
    """The upper sheet pushed ``depth`` mm through the gap with a bump, plus random noise."""
    rng = np.random.default_rng(seed)
    x = X + noise * rng.normal(size=X.shape)
    up = np.unique(Ta)
    up = up[up != 0]
    centre = X[up][:, [0, 2]].mean(axis=0)
    bump = np.exp(-((X[up][:, [0, 2]] - centre) ** 2).sum(axis=1) / 4.0)
    x[up, 1] -= depth * bump
    return x


def _state(depth=2.0, noise=0.12, seed=12, **kw):
    X, Ta, Tb = two_sheets()
    term = SurfaceContactTerm(Ta, Tb, X, stiffness=2.0, margin=0.1, radius=2.0, weights=None, **kw)
    return X, term, pressed(X, Ta, depth, noise, seed)


def flat_sheets(gap=1.0):
    """A 4 x 4-node upper sheet 1 mm above the middle of a 6 x 6-node lower sheet (spacing 1 mm)."""
    Xb, Tb = grid_sheet(6, 6, -gap / 2, normal=+1)
    Xa, Ta = grid_sheet(4, 4, gap / 2, shift=(0.5, 0.5))
    return np.concatenate([Xb, Xa]), Ta + len(Xb), Tb


def _system(n, fixed=None):
    """A DofSystem over ``n`` nodes (a chain of dummy tets puts every node in it)."""
    tets = np.arange(n - 3)[:, None] + np.arange(4)
    return DofSystem(tets, n, np.zeros((n, 3), bool) if fixed is None else fixed, np.arange(n - 3))


def _active_regions(term, x):
    tri, d, *_, region, _ = term.closest(x)
    on = (tri >= 0) & (d < term.margins)
    return region[on]


SEEDS = [12, 13, 15]   # edges and a ramp at a vertex; an edge and a ramp at an edge; a vertex and edges


# ---------------------------------------------------------------------------------------------
# derivatives


def test_states_cover_every_closest_point_region():
    reg = np.concatenate([_active_regions(term, x) for _, term, x in (_state(seed=s) for s in SEEDS)])
    plain = reg[reg < K.RAMP]
    assert (reg == K.FACE).sum() >= 20
    assert np.isin(plain, [1, 2, 4]).any() and np.isin(plain, [3, 5, 6]).any()   # vertex, edge
    assert (reg & K.RAMP).any()


@pytest.mark.parametrize("seed", SEEDS)
def test_gradient_against_central_differences(seed):
    _, term, x = _state(seed=seed)
    reg = _active_regions(term, x)
    # several pairs in contact, on faces and on edges, vertices or in the sign ramp
    assert len(reg) >= 8 and (reg == K.FACE).sum() >= 3 and (reg != K.FACE).sum() >= 1
    E, g = term.energy_and_gradient(x)
    assert E > 0.05 and np.linalg.norm(g) > 0.5
    assert term.energy(x) == pytest.approx(E, rel=1e-14)
    g_fd = _fd_gradient(term, x, None)
    assert np.linalg.norm(g_fd - g) < 1e-6 * np.linalg.norm(g)
    # the contact forces of each pair balance (action and reaction)
    np.testing.assert_allclose(g.sum(axis=0), 0.0, atol=1e-12 * np.abs(g).max() * len(g))


@pytest.mark.parametrize("seed", SEEDS)
def test_exact_hessian_against_central_differences(seed):
    _, term, x = _state(seed=seed)
    sysm = _system(len(x))
    H = node_order(term.sparse_hessian(x, None, sysm, project=False), sysm)
    H_fd = _fd_hessian(term, x, None)
    assert np.linalg.norm(H_fd) > 1.0
    assert np.linalg.norm(H - H_fd) < 1e-6 * np.linalg.norm(H_fd)
    np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())
    # the curvature part is real: Gauss-Newton differs
    H_gn = node_order(term.sparse_hessian(x, None, sysm, project=True), sysm)
    assert np.linalg.norm(H_gn - H_fd) > 1e-3 * np.linalg.norm(H_fd)


@pytest.mark.parametrize("seed", SEEDS)
def test_gauss_newton_hessian_is_symmetric_psd(seed):
    _, term, x = _state(seed=seed)
    H = term.sparse_hessian(x, None, _system(len(x)), project=True)
    assert isinstance(H, sp.csr_matrix) and H.nnz > 0
    H = H.toarray()
    np.testing.assert_allclose(H, H.T, atol=1e-12 * np.abs(H).max())
    lam = np.linalg.eigvalsh(H)
    assert lam.max() > 1.0 and lam.min() > -1e-10 * lam.max()


def test_gauss_newton_is_exact_for_a_node_against_a_face_and_first_order_in_depth():
    X, Ta, Tb = flat_sheets()
    term = SurfaceContactTerm(Ta, Tb, X, stiffness=3.0, weights=None)
    sysm = _system(len(X))
    # one upper node through a face of the lower sheet, everything else fixed: exact
    p = Ta[7, 1]
    x = X.copy()
    x[p] += [0.13, -1.4, -0.21]
    _, d, *_, region, _ = term.closest(x)
    i = int(np.flatnonzero(term.nodes == p)[0])
    assert region[i] == K.FACE and d[i] == pytest.approx(-0.4)
    H = node_order(term.sparse_hessian(x, None, sysm, project=True), sysm)[3 * p:3 * p + 3, 3 * p:3 * p + 3]
    H_fd = np.empty((3, 3))
    for k in range(3):
        xp, xm = x.copy(), x.copy()
        xp[p, k] += 1e-6
        xm[p, k] -= 1e-6
        H_fd[:, k] = (term.gradient(xp)[p] - term.gradient(xm)[p]) / 2e-6
    np.testing.assert_allclose(H, np.diag([0.0, 3.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(H, H_fd, atol=1e-6 * 3.0)

    # the whole upper sheet pressed ``depth`` through the lower one, both meshes distorted in
    # their planes: every pair is on a face region (16 upper nodes, 9 lower ones), and the
    # Gauss-Newton matrix misses only the curvature term, O(depth / edge length)
    def error(depth):
        xs = X + np.random.default_rng(4).uniform(-0.15, 0.15, size=X.shape) * [1.0, 0.0, 1.0]
        xs[np.unique(Ta), 1] -= 1.0 + depth
        reg = _active_regions(term, xs)
        assert len(reg) == 25 and np.all(reg == K.FACE)
        H_fd = _fd_hessian(term, xs, None)
        H_gn = node_order(term.sparse_hessian(xs, None, sysm, project=True), sysm)
        return np.linalg.norm(H_gn - H_fd) / np.linalg.norm(H_fd)

    shallow, deep = error(1e-3), error(0.1)
    assert shallow < 1e-2
    assert deep > 20 * shallow   # first order in the depth


def test_energy_of_two_parallel_sheets_in_closed_form():
    """Flat sheets 1 mm apart, the upper one lowered by 0.7 mm: every node over the other sheet
    is 0.3 mm from it, 0.2 mm inside a 0.5 mm margin (16 upper nodes, 9 lower nodes under it)."""
    X, Ta, Tb = flat_sheets()
    term = SurfaceContactTerm(Ta, Tb, X, stiffness=3.0, margin=0.5, weights=None)
    assert term.energy(X) == 0.0 and not term.gradient(X).any()
    x = X.copy()
    x[np.unique(Ta), 1] -= 0.7
    d = term.signed_distances(x)
    np.testing.assert_allclose(np.sort(d)[:25], 0.3, atol=1e-12)
    assert np.sort(d)[25] > 0.5
    assert term.energy(x) == pytest.approx(25 * 0.5 * 3.0 * 0.2 ** 2, rel=1e-12)
    g = term.gradient(x)
    # each lower node under the sheet is pushed down by k pen, the upper sheet up by the same total
    assert g[np.unique(Tb), 1].sum() == pytest.approx(25 * 3.0 * 0.2, rel=1e-12)
    assert g[np.unique(Ta), 1].sum() == pytest.approx(-25 * 3.0 * 0.2, rel=1e-12)
    # rest surfaces closer than the margin: the penalty starts 0.05 mm below the rest distance
    close = SurfaceContactTerm(Ta, Tb, X, stiffness=3.0, margin=1.5, weights=None)
    assert close.energy(X) == 0.0
    np.testing.assert_allclose(np.sort(close.margins)[:25], 0.95, atol=1e-12)
    pen = np.maximum(close.margins - close.signed_distances(x), 0.0)
    assert np.sort(pen)[::-1][24] == pytest.approx(0.65)
    assert close.energy(x) == pytest.approx(0.5 * 3.0 * (pen ** 2).sum(), rel=1e-12)
    # the upper sheet moved away sideways, out of reach: no pair at all
    far = X.copy()
    far[np.unique(Ta), 0] += 20.0
    assert np.isinf(term.signed_distances(far)).all() and term.min_distance(far) == np.inf


def test_sparse_hessian_over_a_system_with_prescribed_dofs():
    _, term, x = _state(seed=13)
    whole = _system(len(x))
    full = node_order(term.sparse_hessian(x, None, whole, project=False), whole)
    fixed = np.zeros((len(x), 3), bool)
    pen = term.margins - term.signed_distances(x)
    touching = term.nodes[pen > 0]
    out, partial = touching[0], touching[1]
    fixed[out] = True          # leaves the system
    fixed[partial, 1] = True   # one prescribed component
    sysm = _system(len(x), fixed)
    H = term.sparse_hessian(x, None, sysm, project=False)
    assert H.shape == (sysm.n_dofs, sysm.n_dofs)
    dofs = (3 * sysm.active[:, None] + np.arange(3)).ravel()
    expected = full[np.ix_(dofs, dofs)]
    expected[~sysm.free_dof] = 0.0
    expected[:, ~sysm.free_dof] = 0.0
    assert np.abs(expected).max() > 1.0
    np.testing.assert_allclose(H.toarray(), expected, atol=1e-12)
    assert out not in sysm.active and partial in sysm.active


def test_collapsed_triangles_are_skipped():
    """A lower triangle squeezed to a segment under the pressed sheet: no side to be behind, so it
    is never a candidate (Ericson's weights would divide by zero); the rest still works."""
    X, Ta, Tb = flat_sheets()
    term = SurfaceContactTerm(Ta, Tb, X, weights=None)
    x = X.copy()
    x[np.unique(Ta), 1] -= 1.2
    t = 12
    x[Tb[t, 2]] = 0.5 * (x[Tb[t, 0]] + x[Tb[t, 1]])   # its third vertex onto the opposite edge
    i, tri = term.candidates(x)
    assert len(i) > 0 and len(Ta) + t not in tri.tolist() and len(Ta) + t + 1 in tri.tolist()
    E, g = term.energy_and_gradient(x)
    H = term.sparse_hessian(x, None, _system(len(x)), project=False)
    assert E > 0 and np.isfinite(g).all() and np.isfinite(H.data).all()


def test_add_hessian_adds_nothing():
    _, term, x = _state()
    sysm = _system(len(x))
    data = sysm.new_data()
    term.add_hessian(x, None, sysm, data, True)
    assert not data.any()


# ---------------------------------------------------------------------------------------------
# kernels against numpy / trimesh


def _random_surfaces(seed):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 10.0, size=(90, 3))
    A = np.stack([rng.choice(55, 3, replace=False) for _ in range(60)])
    B = np.stack([rng.choice(np.arange(35, 90), 3, replace=False) for _ in range(60)])   # 20 shared nodes
    return X, A, B


def brute_force_candidates(x, term):
    """All (node, triangle) pairs of the exact candidate test, one trimesh closest point each."""
    i, t = np.meshgrid(np.arange(len(term.nodes)), np.arange(len(term.triangles)), indexing="ij")
    i, t = i.ravel(), t.ravel()
    keep = (term.side[i] != term.tri_side[t]) & ~(term.triangles[t] == term.nodes[i][:, None]).any(axis=1)
    i, t = i[keep], t[keep]
    c = trimesh.triangles.closest_point(x[term.triangles[t]], x[term.nodes[i]])
    near = np.linalg.norm(x[term.nodes[i]] - c, axis=1) <= term.radius
    return set(zip(i[near].tolist(), t[near].tolist()))


@pytest.mark.parametrize("seed", [0, 1])
def test_spatial_hash_finds_exactly_the_brute_force_candidates(seed):
    X, A, B = _random_surfaces(seed)
    term = SurfaceContactTerm(A, B, X, radius=2.5, weights=None)
    x = X + 0.5 * np.random.default_rng(seed + 10).normal(size=X.shape)
    expected = brute_force_candidates(x, term)
    assert 200 < len(expected) < 0.5 * len(term.nodes) * len(term.triangles) / 2   # a real filter
    i, t = term.candidates(x)
    assert set(zip(i.tolist(), t.tolist())) == expected and len(i) == len(expected)   # no duplicates
    # any cell size finds the same pairs
    for h in (0.3, 1.0, 7.0):
        normal, _ = K.surface_normals(x, term.triangles, np.zeros_like(term.triangles), 1)
        ptr, tri = K.candidate_pairs(x, term.nodes, term.side, term.triangles, term.tri_side, normal, term.radius, h)
        got = set(zip(np.repeat(np.arange(len(term.nodes)), np.diff(ptr)).tolist(), tri.tolist()))
        assert got == expected


def test_closest_point_kernel_against_trimesh():
    rng = np.random.default_rng(5)
    m = 2000
    x = rng.normal(size=(4 * m, 3)) * [3.0, 3.0, 1.0]
    out = np.array([K.closest_point(x, 4 * j, 4 * j + 1, 4 * j + 2, 4 * j + 3) for j in range(m)])
    b, region = out[:, :3], out[:, 3].astype(int)
    c = np.einsum("mj,mjk->mk", b, x.reshape(m, 4, 3)[:, 1:])
    expected = trimesh.triangles.closest_point(x.reshape(m, 4, 3)[:, 1:], x[::4])
    np.testing.assert_allclose(c, expected, atol=1e-9)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-12)
    assert b.min() >= 0.0
    # every region occurs, and the region names the vertices with non-zero weight
    assert set(region.tolist()) == {1, 2, 3, 4, 5, 6, 7}
    for r in range(1, 8):
        used = (r >> np.arange(3)) & 1
        assert np.all(b[region == r][:, used == 0] == 0.0)


# ---------------------------------------------------------------------------------------------
# input checks


def test_bad_input():
    X, Ta, Tb = flat_sheets()
    with pytest.raises(FacesimError, match="stiffness"):
        SurfaceContactTerm(Ta, Tb, X, stiffness=-1.0)
    with pytest.raises(FacesimError, match="surface_a"):
        SurfaceContactTerm(Ta[:, :2], Tb, X)
    with pytest.raises(FacesimError, match="surface_b"):
        SurfaceContactTerm(Ta, Tb + 1000, X)
    with pytest.raises(FacesimError, match="X_rest"):
        SurfaceContactTerm(Ta, Tb, X[:, :2])
    with pytest.raises(FacesimError, match="radius"):
        SurfaceContactTerm(Ta, Tb, X, margin=2.0, radius=1.0)
    with pytest.raises(FacesimError, match="max_depth"):
        SurfaceContactTerm(Ta, Tb, X, radius=1.0, max_depth=3.0)
    with pytest.raises(FacesimError, match="weights"):
        SurfaceContactTerm(Ta, Tb, X, weights=np.ones(3))
    with pytest.raises(FacesimError, match="weights"):
        SurfaceContactTerm(Ta, Tb, X, weights="volume")
    term = SurfaceContactTerm(Ta, Tb, X)
    with pytest.raises(FacesimError, match="x: expected"):
        term.energy(X[:-1])
    with pytest.raises(FacesimError, match="system"):
        term.sparse_hessian(X, None, _system(len(X) + 1))


# ---------------------------------------------------------------------------------------------
# the shipped face


@pytest.fixture(scope="module")
def face():
    from facesim.model import FaceModel

    return FaceModel.load(MODEL)


def test_lip_contact_term_of_the_face_rests_at_zero(face):
    from facesim.contact import node_areas

    term = lip_contact_term(face)
    up, lo = np.unique(face.lip_upper), np.unique(face.lip_lower)
    assert term.nodes.tolist() == up.tolist() + lo.tolist()
    areas = np.r_[node_areas(face.X, face.lip_upper)[up], node_areas(face.X, face.lip_lower)[lo]]
    corner = term.rest_distances <= CORNER_GAP       # where the lips meet: no contact there
    assert 0 < corner.sum() <= 6
    assert np.all(np.abs(face.X[term.nodes[corner], 0]) > 15.0)     # at the corners, not mid-slit
    np.testing.assert_allclose(term.weights, np.where(corner, 0.0, areas))
    np.testing.assert_allclose(lip_contact_term(face, corner_gap=-np.inf).weights, areas)
    edges = face.X[np.r_[face.lip_upper, face.lip_lower][:, [1, 2, 0]]] - face.X[np.r_[face.lip_upper, face.lip_lower]]
    assert term.radius == pytest.approx(1.5 * np.linalg.norm(edges, axis=2).mean())
    # the lips face each other across the slit: most nodes of the slit see the other lip, a
    # millimetre or two away; only at the corners of the mouth, where the two surfaces meet, may
    # a node touch or sit just behind the other lip
    d = term.rest_distances
    d = d[np.isfinite(d)]
    assert d.size >= 50 and 0.5 < np.percentile(d, 10) < 2.4 and np.median(d) < 5.0, np.percentile(d, [10, 50])
    assert np.mean(d > 0.5) > 0.9 and d.min() > -2.0, np.sort(d)[:5]
    for margin in (0.0, 1.5):   # with a margin wider than the rest gap the margins adapt
        t = lip_contact_term(face, margin=margin)
        E, g = t.energy_and_gradient(face.X)
        assert E == 0.0 and not g.any()
        assert not t.sparse_hessian(face.X, None, _system(face.n_nodes), project=False).nnz
    assert (lip_contact_term(face, margin=1.5).margins < 1.5).any()


def _orbicularis_oris(model):
    names = model.muscles.names
    a = np.array([1.0 if n.startswith("orbicularis_oris") else 0.0 for n in names])
    assert a.sum() == 4   # upper and lower, left and right
    return a


def test_orbicularis_oris_presses_the_lips_and_the_term_keeps_them_apart(face):
    """Orbicularis oris fully active closes the mouth slit (lip gap 2.4 mm at rest). Without the
    term the lips cross by several mm; with it (default stiffness 1 N/mm^3) they touch within
    0.1 mm. The teeth colliders are on in both solves, so the lips cannot escape into the teeth.

    Measured on 2 cores (coarse model): without 30 Newton iterations, min distance -8.1 mm;
    with 35 iterations, min distance -0.009 mm."""
    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator

    sim = FaceSimulator(face, EquilibriumOptions(teeth_contact=True))
    term = lip_contact_term(face)
    controls = Controls(_orbicularis_oris(face))
    t0 = time.perf_counter()
    free = sim.equilibrium(controls)
    t1 = time.perf_counter()
    held = sim.equilibrium(controls, extra_terms=(term,))
    t2 = time.perf_counter()
    d_free, d_held = term.min_distance(free.x), term.min_distance(held.x)
    print(f"\nlips under orbicularis oris: min distance {d_free:.3f} mm without the term "
          f"({free.iterations} Newton iterations, {t1 - t0:.1f} s), {d_held:.3f} mm with it "
          f"({held.iterations} iterations, {t2 - t1:.1f} s)")
    assert free.converged and held.converged
    assert d_free < -1.0          # without the term the lips interpenetrate
    assert d_held >= -0.1         # the requirement
    assert d_held < 0.05          # and they do touch: the muscle closes the slit
    # the contact carries load: at equilibrium the contact force balances the flesh on the lips
    f = term.gradient(held.x)
    assert np.linalg.norm(f) > 0.1
    assert (face.tet_volumes(held.x)[sim.elems] > 0).all()
