"""Self-contact of two flesh surfaces (upper lip against lower lip) as a penalty energy term.

The term is symmetric: every node of surface A is kept out of B's triangles and every node of
B out of A's. Surfaces are ``(s, 3)`` triangle arrays into the global node array, oriented with
normals pointing out of the flesh (into the gap between them). For a node ``p`` of one surface:

- candidates are the other surface's triangles within ``radius`` of ``p`` (closest-point
  distance), found through a spatial hash rebuilt from the current positions at every
  evaluation (Teschner et al. 2003); triangles incident to ``p`` are skipped (the lips share
  the mouth-corner nodes);
- a candidate counts only if it faces the node, ``n_p . n_t <= max_cos`` with the *rest* normals
  (``n_p`` area-weighted in the node's own surface). This drops the lip's own teeth-facing side.
  Which triangles face which nodes is anatomy; deciding it on the current normals of a crushed
  Newton iterate made pairs appear and vanish between line-search trials;
- of those, the nearest (closest point ``c`` on face, edge or vertex, Ericson 5.1.5) gives the
  signed distance ``d``: ``n_t . (p - c)`` on the face region; from an edge or a vertex ``+|p - c|``
  in front of or beside the triangle, ``-|p - c|`` behind it (within 37 degrees of the inward
  normal) and a continuous ramp in between (:data:`BEHIND_CONES`). Ericson's ``sign(n_t . (p -
  c)) |p - c|`` jumps by ``2 |p - c|`` when a node beside a triangle crosses its plane; on the
  coarse face with orbicularis oris active such jumps (40 mJ, at nodes 3-5 mm beside the other
  lip's rim) stalled Newton's line search. ``d = +-|p - c|`` on both sides also keeps ``d``
  continuous when the nearest triangle changes (equally near triangles: the smaller ``d``).

Energy per node ``w_i k/2 max(0, m_i - d_i)^2`` with ``m_i = min(margin, d_rest_i - 0.05 mm)``:
where the rest surfaces already lie closer than ``margin`` or cross, the penalty starts 0.05 mm
below the rest distance, so the rest shape stays an equilibrium (as ``FaceSimulator.teeth_term``
does for the teeth). Pairs deeper than ``max_depth`` are ignored; its default is the search
radius, not a few mm: the first Newton step from rest moves the lips ~10 mm blindly (no contact
yet), and a pair dropped at a shallow cap is an energy *decrease* the line search accepts, so
the node would tunnel through for good.

Derivatives are exact (envelope theorem: the closest point's barycentrics are stationary, so
only the explicit dependence counts): ``grad_p d = nu``, ``grad_{x_j} d = -b_j nu`` with ``nu =
(p - c) / d`` (plus the plane-distance part in the ramp). The Hessian per pair (12 x 12: node and
triangle) is ``w k (grad d grad d^T - pen hess d)``. ``project=True`` keeps the Gauss-Newton part
``w k grad d grad d^T`` (PSD). The dropped curvature is ``O(pen / edge length)`` relative on the
face region; from edges and vertices it is ``O(pen / |d|)``: the distance to a line or a point
bends with ``1 / d``. ``project=False`` adds the exact ``hess d`` (implicit differentiation of the
closest point, :func:`facesim._kernels.selfcontact._distance_hessian`), which Newton's true-tangent
phase uses for quadratic convergence. The IPC-style per-pair PSD projection of the exact matrix
was tried in place of GN: 44 instead of 38 Newton iterations on that test, so GN stays.

What is left non-smooth: kinks (``pen = 0``; closest-point region and nearest-triangle changes,
e.g. the contact normal turning by the dihedral angle where a node slides across an edge of the
coarse lip mesh; the ramp's ends) and jumps only where the nearest triangle changes inside the
ramp (proportional to the depth there) or a node leaves ``radius``. Newton pays for the kinks
with iterations (see tests/contact/test_self_contact.py for numbers).

Units: ``k`` in N/mm^3 with area weights (``node_areas``, mm^2 of the node's own surface at
rest: a contact pressure per mm of penetration), N/mm with unit weights; energies mJ (N mm),
gradients N, Hessians N/mm. Immutable, no cached state. An evaluation on the coarse lips (224
nodes, 375 triangles) takes ~1 ms.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from facesim._kernels import selfcontact as K
from facesim.contact.penalty import DEFAULT_STIFFNESS, node_areas
from facesim.energy import NodeTerm
from facesim.errors import FacesimError

REST_CLEARANCE = 0.05
"""mm below a node's rest distance where its penalty starts when the rest surfaces are closer than
the margin (keeps the rest shape an equilibrium)."""

BEHIND_CONES = (0.3, 0.8)
"""Cosines ``(cone_out, cone_in)`` of the angle between ``p - c`` and a triangle's inward normal:
a node within ``acos(0.8) = 37`` degrees of it is behind (``d = -|p - c|``), beyond ``acos(0.3) =
73`` degrees in front or beside (``d = +|p - c|``), the sign ramps in between (see
:func:`facesim._kernels.selfcontact.nearest_triangles`)."""


def _triangles(tris, name: str, n_nodes: int) -> np.ndarray:
    t = np.asarray(tris)
    if t.ndim != 2 or t.shape[1] != 3 or not np.issubdtype(t.dtype, np.integer):
        raise FacesimError(f"{name}: expected an integer triangle array of shape (s, 3), got {t.dtype} {t.shape}")
    if len(t) == 0:
        raise FacesimError(f"{name}: expected at least one triangle")
    if t.min() < 0 or t.max() >= n_nodes:
        raise FacesimError(f"{name}: node ids must lie in [0, {n_nodes})")
    if np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])):
        raise FacesimError(f"{name}: a triangle repeats a node")
    return np.ascontiguousarray(t, dtype=np.int64)


def mean_edge_length(X, *surfaces) -> float:
    """Mean edge length (mm) over the triangles of ``surfaces`` (each ``(s, 3)``) at positions ``X``."""
    t = np.concatenate(surfaces)
    e = X[t[:, [1, 2, 0]]] - X[t]
    return float(np.linalg.norm(e, axis=2).mean())


class SurfaceContactTerm(NodeTerm):
    """Symmetric penalty self-contact between two surfaces of one mesh (energy term of the FEM).

    Parameters
    ----------
    surface_a, surface_b : (s_a, 3), (s_b, 3) int, triangles into the node array, normals pointing
        out of the flesh (towards the other surface). They may share nodes (mouth corners).
    X_rest : (n, 3) float, rest positions (mm): rest distances (the penalty's zero where the
        surfaces start closer than ``margin``), the default radius and the area weights.
    stiffness : ``k`` > 0, N/mm^3 with area weights (N/mm with unit weights).
    margin : mm, contact starts when a node comes within ``margin`` of the other surface.
    radius : mm, search radius (default 1.5 x the mean edge length); must exceed ``margin``.
    max_depth : mm, pairs with ``d < -max_depth`` are ignored (default and at most ``radius``).
    max_cos : a triangle faces a node when ``n_node . n_tri <= max_cos`` at rest (default -0.2:
        the lips face each other).
    weights : ``"area"`` (lumped area of the node in its own surface at rest, mm^2), ``None``
        (unit) or ``(k,)`` non-negative numbers in the order of :attr:`nodes`.

    Attributes: ``nodes (k,)`` node ids, A's (sorted) then B's (sorted; shared nodes appear in
    both); ``side (k,)`` 0 / 1; ``triangles (s_a + s_b, 3)``; ``weights (k,)``; ``rest_distances
    (k,)`` (+inf: no facing triangle in reach); ``margins (k,)`` the per-node ``m_i`` (mm).

    A :class:`~facesim.energy.NodeTerm`: ``x (n, 3)`` mm, ``a`` ignored; :meth:`add_hessian` adds
    nothing and :meth:`sparse_hessian` carries the whole Hessian (it couples nodes that share no
    element).
    """

    def __init__(self, surface_a, surface_b, X_rest, stiffness: float = DEFAULT_STIFFNESS, margin: float = 0.0,
                 radius: float | None = None, max_depth: float | None = None, max_cos: float = -0.2,
                 weights="area"):
        X = np.ascontiguousarray(X_rest, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != 3 or not np.all(np.isfinite(X)):
            raise FacesimError(f"X_rest: expected finite positions of shape (n, 3), got {X.shape}")
        A = _triangles(surface_a, "surface_a", len(X))
        B = _triangles(surface_b, "surface_b", len(X))
        self.n_nodes = len(X)
        self.stiffness = float(stiffness)
        if not (np.isfinite(self.stiffness) and self.stiffness > 0):
            raise FacesimError(f"self-contact stiffness: expected a positive number, got {stiffness}")
        self.margin = float(margin)
        if not np.isfinite(self.margin):
            raise FacesimError(f"self-contact margin: expected a finite number (mm), got {margin}")
        edge = mean_edge_length(X, A, B)
        self.radius = 1.5 * edge if radius is None else float(radius)
        if not (np.isfinite(self.radius) and self.radius > max(self.margin, 0.0)):
            raise FacesimError(f"self-contact radius: expected a number of mm > max(margin, 0) = "
                               f"{max(self.margin, 0.0)}, got {self.radius}")
        self.max_depth = self.radius if max_depth is None else float(max_depth)
        if not (0 < self.max_depth <= self.radius):
            raise FacesimError(f"self-contact max_depth: expected a number of mm in (0, radius = {self.radius:g}], "
                               f"got {max_depth}")
        self.max_cos = float(max_cos)
        if not -1.0 <= self.max_cos < 1.0:
            raise FacesimError(f"self-contact max_cos: expected a cosine in [-1, 1), got {max_cos}")
        # hash cell edge ~ radius, not below the edge length: a triangle's box inflated by radius
        # then spans at most ~4 cells per axis (any cell size finds the same candidates)
        self._cell = max(self.radius, edge)
        nodes_a, slot_a = np.unique(A, return_inverse=True)
        nodes_b, slot_b = np.unique(B, return_inverse=True)
        self.nodes = np.concatenate([nodes_a, nodes_b]).astype(np.int64)
        self.side = np.repeat(np.array([0, 1], np.int64), [len(nodes_a), len(nodes_b)])
        self.triangles = np.concatenate([A, B])
        self.tri_side = np.repeat(np.array([0, 1], np.int64), [len(A), len(B)])
        # slot of each triangle corner in the node list of its own surface (vertex normals)
        self._tri_slot = np.ascontiguousarray(np.concatenate([slot_a.reshape(-1, 3),
                                                              len(nodes_a) + slot_b.reshape(-1, 3)]), dtype=np.int64)
        if isinstance(weights, str):
            if weights != "area":
                raise FacesimError(f"self-contact weights: expected 'area', None or an array, got {weights!r}")
            w = np.concatenate([node_areas(X, A)[nodes_a], node_areas(X, B)[nodes_b]])
        elif weights is None:
            w = np.ones(len(self.nodes))
        else:
            w = np.asarray(weights, dtype=np.float64)
        if w.shape != self.nodes.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise FacesimError(f"self-contact weights: expected {len(self.nodes)} non-negative numbers, "
                               f"got shape {np.shape(w)}")
        self.weights = np.ascontiguousarray(w)
        # which triangles face which nodes is anatomy: decided once, on the rest normals
        self._tri_facing, self._node_facing = K.surface_normals(X, self.triangles, self._tri_slot, len(self.nodes))
        self.margins = np.zeros(len(self.nodes))   # placeholder while the rest distances are measured
        self.rest_distances = self.signed_distances(X)
        self.margins = np.minimum(self.margin, self.rest_distances - REST_CLEARANCE)

    # ------------------------------------------------------------------------------------------
    # geometry

    def _positions(self, x) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.shape != (self.n_nodes, 3):
            raise FacesimError(f"x: expected positions of shape ({self.n_nodes}, 3), got {x.shape}")
        return x

    def _search(self, x):
        """Current unit triangle normals ``(s, 3)`` and the candidate pairs ``(ptr, tri)`` at ``x``."""
        tri_normal, _ = K.surface_normals(x, self.triangles, self._tri_slot, len(self.nodes))
        ptr, cand = K.candidate_pairs(x, self.nodes, self.side, self.triangles, self.tri_side, tri_normal,
                                      self.radius, self._cell)
        return tri_normal, ptr, cand

    def candidates(self, x) -> tuple[np.ndarray, np.ndarray]:
        """All (node, triangle) pairs within ``radius`` (other surface, not degenerate, not incident):
        ``(i (p,), t (p,))`` indices into :attr:`nodes` and :attr:`triangles`, by node then triangle."""
        _, ptr, cand = self._search(self._positions(x))
        return np.repeat(np.arange(len(self.nodes)), np.diff(ptr)), cand

    def closest(self, x):
        """Nearest facing triangle per node at ``x (n, 3)``: ``(tri (k,) int (-1: none), d (k,) mm
        (+inf: none), coef, delta, U, B, region (k,), dist (k,) = |p - c| mm)``, the signed distance
        and its parts as returned by :func:`facesim._kernels.selfcontact.nearest_triangles`."""
        x = self._positions(x)
        tri_normal, ptr, cand = self._search(x)
        return K.nearest_triangles(x, self.nodes, self.triangles, tri_normal, self._node_facing, self._tri_facing, ptr,
                                   cand, self.max_depth, self.max_cos, *BEHIND_CONES)

    def signed_distances(self, x) -> np.ndarray:
        """``(k,)`` signed distance (mm) of each node of :attr:`nodes` to the other surface (negative
        behind it; +inf when no facing triangle is within reach)."""
        return self.closest(x)[1]

    def min_distance(self, x) -> float:
        """Smallest signed distance between the surfaces at ``x`` (mm; +inf if they are out of reach)."""
        d = self.signed_distances(x)
        return float(d.min()) if len(d) else float("inf")

    # ------------------------------------------------------------------------------------------
    # energy term

    def _energy(self, x, g) -> float:
        tri, d, coef, _, U, B, _, _ = self.closest(x)
        return float(K.penalty_gradient(self.nodes, self.triangles, tri, d, coef, U, B, self.weights, self.margins,
                                        self.stiffness, np.empty((0, 3)) if g is None else g, g is not None))

    def energy(self, x, a=None) -> float:
        """Penalty energy, mJ (N mm)."""
        return self._energy(x, None)

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        """``(E, g (n, 3))``: energy (mJ) and gradient (N; non-zero on penetrating nodes and the
        vertices of their closest triangles)."""
        g = np.zeros((self.n_nodes, 3))
        return self._energy(x, g), g

    def gradient(self, x, a=None) -> np.ndarray:
        return self.energy_and_gradient(x, a)[1]

    def _hessian(self, x, row_of, free_dof, project) -> sp.csr_matrix:
        """CSR Hessian (N/mm) over the dofs ``3 row_of[v] + k`` whose ``free_dof`` is True."""
        x = self._positions(x)
        tri, d, coef, delta, U, B, region, _ = self.closest(x)
        rows, cols, vals = K.penalty_hessian(x, self.nodes, self.triangles, tri, d, coef, delta, U, B, region,
                                             self.weights, self.margins, self.stiffness, row_of,
                                             np.ascontiguousarray(free_dof), not project)
        n = len(free_dof)
        return sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        """``(3n, 3n)`` CSR Hessian (N/mm). ``project``: Gauss-Newton (PSD); else exact."""
        return self._hessian(x, np.arange(self.n_nodes), np.ones(3 * self.n_nodes, bool), project)

    def add_hessian(self, x, a, system: "DofSystem", data: np.ndarray, project: bool = True) -> None:
        """Nothing: the whole Hessian, diagonal blocks included, comes from :meth:`sparse_hessian`
        (so no block is counted twice)."""

    def sparse_hessian(self, x, a, system: "DofSystem", project: bool = True) -> sp.csr_matrix:
        """``(system.n_dofs, system.n_dofs)`` CSR Hessian (N/mm) over ``system``'s dofs, zero in the
        rows and columns of prescribed components and of nodes outside the system. ``project``:
        Gauss-Newton (PSD); else exact."""
        if system.n_nodes != self.n_nodes:
            raise FacesimError(f"system: expected {self.n_nodes} nodes, got {system.n_nodes}")
        return self._hessian(x, system.row_of, system.free_dof, project)

    def __repr__(self):
        return (f"SurfaceContactTerm({int((self.side == 0).sum())} + {int((self.side == 1).sum())} nodes, "
                f"{len(self.triangles)} triangles, stiffness={self.stiffness}, margin={self.margin}, "
                f"radius={self.radius:.3g})")


#: Lip nodes closer than this to the other lip at rest (mm) are the corners of the mouth, where
#: the two lip surfaces meet: they carry no lip contact.
CORNER_GAP = 0.3


def lip_contact_term(model, stiffness: float = DEFAULT_STIFFNESS, margin: float = 0.0,
                     corner_gap: float = CORNER_GAP, **kwargs) -> SurfaceContactTerm:
    """Upper lip against lower lip of ``model`` (``model.lip_upper``, ``lip_lower``), area-weighted
    (``stiffness`` N/mm^3), rest distances from ``model.X``; ``kwargs`` go to
    :class:`SurfaceContactTerm` (``radius``, ``max_depth``, ``max_cos``).

    Nodes within ``corner_gap`` mm of the other lip at rest (touching it, or just behind its rim,
    at the corners of the mouth where the surfaces meet) get weight 0: there "the other lip" is
    the same flesh, and a penalty on such a node pulls it across the corner one way while the
    flesh holds it the other. On the shipped coarse face three such nodes took Newton to 199
    iterations (35 without them) with orbicularis oris fully active; the slit keeps its contact.
    """
    def term(weights):
        return SurfaceContactTerm(model.lip_upper, model.lip_lower, model.X, stiffness=stiffness, margin=margin,
                                  weights=weights, **kwargs)

    full = term("area")
    corner = full.rest_distances <= corner_gap
    if not corner.any():
        return full
    return term(np.where(corner, 0.0, full.weights))


__all__ = ["SurfaceContactTerm", "lip_contact_term", "mean_edge_length"]
