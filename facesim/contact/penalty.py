"""Penalty contact of flesh nodes against rigid colliders, as an energy term of the FEM.

For each node ``i`` of the term and each collider ``c`` with signed distance ``d_c``:

    E = sum_c sum_i  w_i (k / 2) max(0, margin - d_c(x_i))^2

(quadratic in the penetration ``pen = margin - d``). Gradient ``-w k pen grad d``; Hessian per
node ``w k (grad d grad d^T - pen hess d)``, exact (the colliders supply ``hess d``). The
curvature part ``-pen hess d`` is negative semidefinite for convex colliders, so with
``project=True`` each node's 3x3 block is clamped to its PSD part (for a sphere, plane or
capsule this is exactly the Gauss-Newton block ``w k grad d grad d^T``).

Units: ``k`` in N/mm with unit weights (a spring per node); with ``weights`` = lumped surface
areas in mm^2 (:func:`node_areas`) ``k`` is a contact pressure per mm of penetration, N/mm^3,
and the result no longer depends on the mesh resolution. At equilibrium a node penetrates by
its contact force over ``w k``.
"""

from __future__ import annotations

import weakref

import numpy as np
import scipy.sparse as sp

from facesim._kernels import contact as K
from facesim.contact.sdf import as_collider
from facesim.energy import NodeTerm
from facesim.errors import FacesimError

DEFAULT_STIFFNESS = 1.0
"""Default ``k``: 1 N/mm per node (unit weights) or 1 N/mm^3 (area weights). Soft tissue
(shear modulus ~5-20 kPa) pressed by a few mm carries contact pressures of ~1e-3 MPa, which
this stiffness resists with ~1e-3 mm of penetration over area-weighted nodes."""


def node_areas(x, triangles, n_nodes: int | None = None) -> np.ndarray:
    """Lumped area per node ``(n,)`` mm^2: a third of each incident triangle's area.

    ``x (n, 3)`` mm, ``triangles (s, 3)`` int (e.g. the skin surface)."""
    x = np.asarray(x, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise FacesimError(f"triangles: expected shape (s, 3), got {tri.shape}")
    n = len(x) if n_nodes is None else int(n_nodes)
    a = 0.5 * np.linalg.norm(np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]), axis=1)
    return np.bincount(tri.ravel(), np.repeat(a / 3.0, 3), minlength=n)


class ContactTerm(NodeTerm):
    """Penalty contact of ``nodes`` against rigid ``colliders`` (energy term of the FEM).

    Parameters
    ----------
    nodes : (k,) int, distinct node ids (e.g. skin or lip surface nodes).
    colliders : sequence of :class:`~facesim.contact.Collider` or bare shapes (identity pose).
    stiffness : ``k`` > 0, N/mm per node (unit weights) or N/mm^3 (area ``weights``).
    margin : contact starts when a node is within ``margin`` mm of a collider's surface (0:
        only penetrating nodes are pushed); a number, or ``(k,)`` per node (e.g. each node's own
        rest clearance where the rest shape already touches a collider).
    weights : optional (k,) non-negative weights, typically :func:`node_areas` (mm^2).

    A :class:`~facesim.energy.NodeTerm`: ``x (n, 3)`` mm, ``a`` ignored, energies in mJ (N mm),
    gradients in N, Hessian (one 3x3 block per node) in N/mm.
    Immutable; :meth:`with_colliders` returns a copy with moved colliders (scripted frames).
    """

    def __init__(self, nodes, colliders, stiffness: float = DEFAULT_STIFFNESS, margin: float = 0.0, weights=None):
        self.nodes = np.ascontiguousarray(np.asarray(nodes).ravel(), dtype=np.int64)
        if len(self.nodes) and self.nodes.min() < 0:
            raise FacesimError("contact nodes: expected non-negative node ids")
        if len(np.unique(self.nodes)) != len(self.nodes):
            raise FacesimError("contact nodes: expected distinct node ids")
        self.colliders = tuple(as_collider(c) for c in colliders)
        self.stiffness = float(stiffness)
        if not (np.isfinite(self.stiffness) and self.stiffness > 0):
            raise FacesimError(f"contact stiffness: expected a positive number, got {stiffness}")
        m = np.asarray(margin, dtype=np.float64)
        if m.ndim > 1 or (m.ndim == 1 and m.shape != self.nodes.shape) or not np.all(np.isfinite(m)):
            raise FacesimError(f"contact margin: expected a finite number or {len(self.nodes)} of them (mm), got "
                               f"shape {m.shape}")
        self.margin = np.ascontiguousarray(np.broadcast_to(m, self.nodes.shape))
        w = np.ones(len(self.nodes)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != self.nodes.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise FacesimError(f"contact weights: expected {len(self.nodes)} non-negative numbers, got shape {w.shape}")
        self.weights = np.ascontiguousarray(w)
        self._blocks = (None, None)   # (weakref to the DofSystem, diagonal block per node)

    def with_colliders(self, colliders) -> ContactTerm:
        """A copy with other colliders (same nodes, stiffness, margin, weights)."""
        other = object.__new__(ContactTerm)
        other.__dict__.update(self.__dict__)
        other.colliders = tuple(as_collider(c) for c in colliders)
        return other

    def _positions(self, x) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise FacesimError(f"x: expected positions of shape (n, 3), got {x.shape}")
        if len(self.nodes) and self.nodes.max() >= len(x):
            raise FacesimError(f"contact nodes: node id {int(self.nodes.max())} out of range for {len(x)} nodes")
        return x

    def signed_distances(self, x) -> np.ndarray:
        """``(k,)`` smallest signed distance of each node to any collider, mm (+inf without colliders)."""
        x = self._positions(x)
        d = np.full(len(self.nodes), np.inf)
        for c in self.colliders:
            d = np.minimum(d, c.distance(x[self.nodes]))
        return d

    def penetration(self, x) -> np.ndarray:
        """``(k,)`` depth of each node inside the nearest collider surface, mm (0 outside)."""
        return np.maximum(0.0, -self.signed_distances(x))

    def _energy(self, x, g) -> float:
        x = self._positions(x)
        p = x[self.nodes]
        E = 0.0
        for c in self.colliders:
            d, G, _ = c.evaluate(p)
            E += K.penalty_gradient(self.nodes, d, G, self.weights, self.stiffness, self.margin,
                                    np.empty((0, 3)) if g is None else g, g is not None)
        return float(E)

    def energy(self, x, a=None) -> float:
        """Penalty energy, mJ (N mm)."""
        return self._energy(x, None)

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        """``(E, g (n, 3))``: energy (N mm) and its gradient (N; non-zero only on penetrating nodes)."""
        g = np.zeros(np.shape(x))
        return self._energy(x, g), g

    def gradient(self, x, a=None) -> np.ndarray:
        return self.energy_and_gradient(x, a)[1]

    def diagonal_blocks(self, system: "DofSystem") -> np.ndarray:
        """``(k,)`` index of each node's diagonal 3x3 block in ``system``'s BSR data (-1 for nodes
        outside the system). Computed once per system (its pattern never changes)."""
        ref, blocks = self._blocks
        if ref is not None and ref() is system:
            return blocks
        if len(self.nodes) and self.nodes.max() >= system.n_nodes:
            raise FacesimError(f"contact nodes: node id {int(self.nodes.max())} out of range for "
                               f"{system.n_nodes} nodes")
        blocks = K.diagonal_blocks(system.indptr, system.indices, system.row_of[self.nodes])
        self._blocks = (weakref.ref(system), blocks)
        return blocks

    def _add_blocks(self, x, blocks, data, project) -> None:
        """Add node i's 3x3 Hessian block (N/mm) into ``data[blocks[i]]`` (-1: skip the node)."""
        x = self._positions(x)
        p = x[self.nodes]
        for c in self.colliders:
            d, G, H = c.evaluate(p, hessian=True)
            K.penalty_hessian(blocks, d, G, H, self.weights, self.stiffness, self.margin, bool(project), data)

    def add_hessian(self, x, a, system: "DofSystem", data: np.ndarray, project: bool = True) -> None:
        """Add the Hessian (N/mm) into ``data (n_blocks, 3, 3)``; ``project`` keeps each node's PSD part."""
        self._add_blocks(x, self.diagonal_blocks(system), data, project)

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        """``(3n, 3n)`` block-diagonal Hessian (N/mm); ``project`` keeps each node's PSD part."""
        n = len(self._positions(x))
        k = len(self.nodes)
        blocks = np.zeros((k, 3, 3))
        self._add_blocks(x, np.arange(k), blocks, project)
        dof = 3 * self.nodes[:, None] + np.arange(3)                 # (k, 3)
        rows = np.broadcast_to(dof[:, :, None], (k, 3, 3))
        cols = np.broadcast_to(dof[:, None, :], (k, 3, 3))
        return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))

    def __repr__(self):
        return (f"ContactTerm({len(self.nodes)} nodes, {len(self.colliders)} colliders, stiffness={self.stiffness}, "
                f"margin={float(self.margin.min(initial=0.0)):.3g}..{float(self.margin.max(initial=0.0)):.3g})")
