"""Shared fixtures: a small hand-built FaceModel, so tests never wait for the anatomy builder."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh

from facesim.model import FaceModel, JawGeometry, MarkerSet, MuscleSet, RigidSurface, Tissue

# tet faces with outward normals for a positively oriented tet (a, b, c, d)
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def box_tets(shape=(6, 5, 4), spacing=10.0):
    """Structured box centred at the origin, every cube split into 6 Kuhn tets.

    Returns ``X (n, 3)`` mm and positively oriented ``tets (m, 4)`` int32 with
    m = 6 * prod(shape); the Kuhn split uses the same diagonal in every cube, so the mesh
    is conforming.
    """
    nx, ny, nz = shape
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    X = g.reshape(-1, 3) * spacing - np.array(shape) * spacing / 2
    node = np.arange(len(X)).reshape(nx + 1, ny + 1, nz + 1)
    corner = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    tets = []
    for perm in itertools.permutations(range(3)):
        steps = [np.zeros(3, int)]
        for axis in perm:
            steps.append(steps[-1] + np.eye(3, dtype=int)[axis])
        tets.append(np.stack([node[tuple((corner + s).T)] for s in steps], 1))
    tets = np.concatenate(tets).astype(np.int32)
    e = X[tets[:, 1:]] - X[tets[:, :1]]
    negative = np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return X, tets


def boundary_triangles(tets):
    """(s, 3) outward oriented boundary faces of a positively oriented tet mesh."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1].astype(np.int32)


def _surface(name, bone, mesh):
    return RigidSurface(name, bone, np.asarray(mesh.vertices), np.asarray(mesh.faces))


def make_box_model(shape=(6, 5, 4), spacing=10.0) -> FaceModel:
    """A 60 x 50 x 40 mm flesh box (720 tets) with two muscles, 6 markers, bones and colliders.

    Nose along +z, up along +y, subject's left along +x. The back two node layers with y >= 0
    are attached to the cranium (tets there are not simulated), the back layer with y < 0 to
    the jaw. ``shape`` and ``spacing``: the same box meshed finer (every region is defined in mm),
    e.g. ``(12, 10, 8), 5.0``.
    """
    X, tets = box_tets(shape, spacing)
    centroid = X[tets].mean(axis=1)
    cranium = np.flatnonzero((X[:, 2] <= -10) & (X[:, 1] >= 0))
    jaw = np.flatnonzero((X[:, 2] <= -20) & (X[:, 1] < 0))
    simulated = ~np.isin(tets, cranium).all(axis=1)

    zyg = np.flatnonzero((centroid[:, 0] > 5) & (centroid[:, 2] > 0) & (np.abs(centroid[:, 1] - 2.5) < 12.5))
    orb = np.flatnonzero((np.abs(centroid[:, 0]) < 15) & (centroid[:, 1] < 0) & (centroid[:, 2] > 5))
    fib_zyg = np.array([-1.0, -1.0, 0.0]) / np.sqrt(2)
    muscles = MuscleSet(
        names=("zygomaticus_major_L", "orbicularis_oris"),
        sides=("L", "M"),
        sigma_max=np.array([0.3, 0.25]),
        muscle=np.r_[np.zeros(len(zyg)), np.ones(len(orb))],
        tet=np.r_[zyg, orb],
        fraction=np.r_[np.full(len(zyg), 0.55), np.full(len(orb), 0.4)],
        fibre=np.r_[np.tile(fib_zyg, (len(zyg), 1)), np.tile([1.0, 0.0, 0.0], (len(orb), 1))],
    )
    tissue = (muscles.total_fraction(len(tets)) > 0.5).astype(np.int32)

    skin = boundary_triangles(tets)
    skin_centroid = X[skin].mean(axis=1)

    def nearest(point):
        """Index of the skin triangle whose centroid is closest to ``point``."""
        return int(np.argmin(np.linalg.norm(skin_centroid - point, axis=1)))

    marker_tris = [nearest(p) for p in ((12, -12, 20), (-12, -12, 20), (0, -20, 20), (20, 5, 20),
                                        (15, 25, 0), (-15, 25, 0))]
    markers = MarkerSet(
        names=("mouth_L", "mouth_R", "chin", "cheek_L", "head_L", "head_R"),
        triangle=marker_tris,
        bary=np.full((6, 3), 1 / 3),
        offset=np.array([0.0, 0.0, 1.0, 0.0, 1.5, 1.5]),
        head=np.array([False, False, False, False, True, True]),
    )
    lip_upper = skin[[nearest((0, 3, 20))]]
    lip_lower = skin[[nearest((0, -3, 20))]]

    def box(extents, centre):
        return trimesh.creation.box(extents=extents).apply_translation(centre)

    bones = (_surface("cranium", "cranium", box((50, 40, 20), (0, 10, -35))),
             _surface("mandible", "jaw", box((40, 10, 15), (0, -22, -10))))
    colliders = (_surface("teeth_lower", "jaw", box((20, 5, 5), (0, -8, 12))),
                 _surface("eye_L", "cranium", trimesh.creation.icosphere(1, 6.0).apply_translation((15, 12, 8))))
    jaw_geometry = JawGeometry(
        condyle_right=np.array([-45.0, 0.0, -30.0]),
        condyle_left=np.array([45.0, 0.0, -30.0]),
        track_direction=np.array([0.0, -0.5, 1.0]) / np.sqrt(1.25),
        track_length=10.0,
        max_opening=0.5,
        incisor=np.array([0.0, -10.0, 20.0]),
    )
    return FaceModel(
        X=X, tets=tets, tissue=tissue,
        tissues=(Tissue("fat", 1e-3, 0.0, 0.1), Tissue("muscle", 2e-3, 0.0, 0.2)),
        simulated=simulated, muscles=muscles, cranium_nodes=cranium, jaw_nodes=jaw,
        skin=skin, lip_upper=lip_upper, lip_lower=lip_lower, bones=bones, colliders=colliders,
        markers=markers, jaw=jaw_geometry, meta={"resolution": "synthetic", "seed": 0},
    )


@pytest.fixture(scope="session")
def box_model() -> FaceModel:
    """The small synthetic model of :func:`make_box_model` (immutable, so shared)."""
    return make_box_model()


@pytest.fixture(scope="session")
def box_model_path(box_model, tmp_path_factory):
    """The synthetic model saved to a .npz (do not modify the file)."""
    return box_model.save(tmp_path_factory.mktemp("model") / "box.npz")


def one_numba_thread():
    """Generator for a module-scoped fixture: numba on one thread while the module runs, as in
    subprocesses started with NUMBA_NUM_THREADS=1 (the same sums, so results compare bit for bit)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(before)


def interrupt_frame_solves(monkeypatch, at: int = 3) -> None:
    """Make ``facesim.inverse.tracking._solve_frame`` raise KeyboardInterrupt on its ``at``-th call
    (an interrupted run); ``monkeypatch.undo()`` restores it."""
    from facesim.inverse import tracking

    solve = tracking._solve_frame
    calls = []

    def interrupted(*args):
        calls.append(args)
        if len(calls) == at:
            raise KeyboardInterrupt
        return solve(*args)

    monkeypatch.setattr(tracking, "_solve_frame", interrupted)


def node_order(H, system):
    """A matrix over ``system``'s dofs (rows in its own order, :class:`~facesim.fem.system.DofSystem`)
    as a dense ``(3n, 3n)`` matrix over the mesh's node dofs ``3 node + k``; zero where a node is
    not in the system."""
    H = H.toarray() if hasattr(H, "toarray") else np.asarray(H)
    dof = (3 * np.asarray(system.active)[:, None] + np.arange(3)).ravel()
    out = np.zeros((3 * system.n_nodes, 3 * system.n_nodes))
    out[np.ix_(dof, dof)] = H
    return out
