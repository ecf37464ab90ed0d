"""Energy terms of the flesh: invertible Mooney-Rivlin elasticity and muscle fibres.

Both are :class:`~facesim.energy.NodeTerm` s: ``x (n, 3)`` positions in mm, ``a (n_muscles,)``
activations; energies in mJ (N mm), gradients ``(n, 3)`` in N, Hessians in N/mm, assembled into a
:class:`~facesim.fem.system.DofSystem`'s block data by ``add_hessian``.
"""

from __future__ import annotations

import weakref

import numpy as np
import scipy.sparse as sp

from facesim._arrays import unique_ints
from facesim._kernels import elements as K
from facesim.energy import NodeTerm
from facesim.errors import FacesimError
from facesim.fem.material import DEFAULT_CLAMP, VOLUMETRIC
from facesim.fem.system import DofSystem, RestShape, element_chunks


INVERSION_SAMPLES = 16
"""Points per step at which :meth:`ElasticTerm.max_step` samples each tet's volume (then bisects)."""


def _positions(x, n) -> np.ndarray:
    x = np.ascontiguousarray(x, dtype=np.float64)
    if x.shape != (n, 3):
        raise FacesimError(f"x: expected positions of shape ({n}, 3), got {x.shape}")
    return x


def _own_hessian(term, x, a, project: bool, elems) -> sp.csr_matrix:
    """``(3n, 3n)`` Hessian of ``term`` (``add_hessian``) over the tets ``elems``, every node free."""
    n = len(term.rest.X)
    if len(elems) == 0:
        return sp.csr_matrix((3 * n, 3 * n))
    system = DofSystem(term.rest.tets, n, np.zeros((n, 3), bool), elems)
    data = system.new_data()
    term.add_hessian(x, a, system, data, project)
    H = sp.bsr_matrix((data, system.indices, system.indptr), shape=(system.n_dofs, system.n_dofs)).tocoo()
    dof = (3 * system.active[:, None] + np.arange(3)).ravel()
    return sp.csr_matrix((H.data, (dof[H.row], dof[H.col])), shape=(3 * n, 3 * n))


class _ChunkCopies:
    """An :class:`ElasticTerm`'s tet arrays in chunk orders: ``by_system`` (DofSystem -> arrays in
    its order, for assembly) and ``gradient`` (``(arrays, colour_ptr, chunk_ptr)``)."""

    def __init__(self):
        self.by_system = weakref.WeakKeyDictionary()
        self.gradient = None


class ElasticTerm(NodeTerm):
    """Mooney-Rivlin flesh on the tets ``elems`` with per-tet parameters (MPa).

    ``c10, c01, kappa``: (m,) arrays over all tets of the mesh (only ``elems`` are used).
    """

    def __init__(self, rest: RestShape, c10, c01, kappa, elems=None, volumetric: str = "log",
                 clamp: float = DEFAULT_CLAMP):
        m = len(rest.tets)
        self.rest = rest
        self.c10, self.c01, self.kappa = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), (m,)))
                                          for v in (c10, c01, kappa))
        if volumetric not in VOLUMETRIC:
            raise FacesimError(f"volumetric: expected one of {tuple(VOLUMETRIC)}, got {volumetric!r}")
        self.vol = VOLUMETRIC[volumetric]
        self.clamp = float(clamp)
        self.elems = np.ascontiguousarray(np.arange(m) if elems is None else elems, dtype=np.int64)
        self._copies = _ChunkCopies()   # the tet arrays in chunk orders (shared by with_clamp)

    def _args(self):
        r = self.rest
        return r.tets, r.Bm, r.V0, self.c10, self.c01, self.kappa, self.vol, self.clamp

    def energy(self, x, a=None) -> float:
        return K.elastic_energy(_positions(x, len(self.rest.X)), *self._args(), self.elems)

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        x = _positions(x, len(self.rest.X))
        g = np.zeros_like(x)
        arrays, colour_ptr, chunk_ptr = self._gradient_chunks()
        e = K.elastic_gradient(x, *arrays, self.vol, self.clamp, colour_ptr, chunk_ptr, g)
        return e, g

    def _gradient_chunks(self) -> tuple:
        """``(arrays, colour_ptr, chunk_ptr)``: the tets' arrays of :meth:`_args` in a chunk order,
        made once: the gradient adds into the nodes chunk by chunk in parallel, neighbouring tets
        one after the other (the paper-size face's gradient 0.15 against 0.22 s on two threads,
        benchmarks/RESULTS.md, session 32). The order of a system this term assembles into over
        the same tets when there is one (no second copy), else its own
        (:func:`~facesim.fem.system.element_chunks`)."""
        copies = self._copies
        if copies.gradient is None:
            for system, arrays in list(copies.by_system.items()):
                if np.array_equal(system.elems, self.elems):
                    copies.gradient = (arrays, system.colour_ptr, system.chunk_ptr)
                    break
            else:
                colour_ptr, chunk_ptr, order = element_chunks(self.rest.tets, self.elems, len(self.rest.X))
                copies.gradient = (self._arrays_in(self.elems[order]), colour_ptr, chunk_ptr)
        return copies.gradient

    def _arrays_in(self, elems) -> tuple:
        """The per-tet arrays of :meth:`_args` (tets, Bm, V0, c10, c01, kappa) in the order ``elems``."""
        return tuple(np.ascontiguousarray(v[elems]) for v in self._args()[:6])

    def gradient(self, x, a=None) -> np.ndarray:
        return self.energy_and_gradient(x, a)[1]

    def with_clamp(self, clamp: float) -> "ElasticTerm":
        """This term with another clamp, sharing its arrays and their chunk-ordered copies (which do
        not depend on the clamp)."""
        other = object.__new__(type(self))
        other.__dict__.update(self.__dict__)
        other.clamp = float(clamp)
        return other

    def restricted(self, elems) -> "ElasticTerm":
        """This term on the tets ``elems`` only (a subset of its own), with copies of its own."""
        other = object.__new__(type(self))
        other.__dict__.update(self.__dict__)
        other.elems = np.ascontiguousarray(elems, dtype=np.int64)
        other._copies = _ChunkCopies()
        return other

    def touching(self, nodes) -> np.ndarray:
        """The tets of ``elems`` with a node among ``nodes``."""
        near = np.zeros(len(self.rest.X), bool)
        near[np.asarray(nodes, dtype=np.int64)] = True
        return self.elems[near[self.rest.tets[self.elems]].any(axis=1)]

    def __getstate__(self):   # pickled (to a worker) without the chunk-ordered copies
        state = dict(self.__dict__)
        state["_copies"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._copies = _ChunkCopies()

    def _chunked(self, system: DofSystem) -> tuple:
        """The tets' arrays of :meth:`_args` in ``system``'s chunk order (``system.chunk_elems``), made
        once per system: assembly then reads them in order rather than scattered over the mesh
        (the medium face's true tangent 0.89 against 1.11 us a tet on two threads,
        benchmarks/RESULTS.md, session 31)."""
        chunked = self._copies.by_system.get(system)
        if chunked is None:
            chunked = self._copies.by_system[system] = self._arrays_in(system.chunk_elems)
        return chunked

    def add_hessian(self, x, a, system: DofSystem, data: np.ndarray, project: bool = True) -> None:
        K.elastic_assemble(_positions(x, len(self.rest.X)), *self._chunked(system), self.vol, self.clamp,
                           bool(project), system.colour_ptr, system.chunk_ptr, system.chunk_e2b, data)

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        return _own_hessian(self, x, a, project, self.elems)

    def max_step(self, x, dx) -> float:
        """Largest fraction in (0, 1] of ``dx (n, 3)`` mm before a tet of positive volume at ``x``
        reaches zero volume (1 when none does); already inverted tets set no limit."""
        dx = np.ascontiguousarray(dx, dtype=np.float64)
        return float(K.max_inversion_free_step(_positions(x, len(self.rest.X)), dx, self.rest.tets, self.elems,
                                               INVERSION_SAMPLES))

    def element_hessians(self, x, project: bool = False) -> np.ndarray:
        """(len(elems), 12, 12) element Hessians (node-major dofs), for tests and inspection."""
        Ke = np.empty((len(self.elems), 12, 12))
        K.elastic_element_hessians(_positions(x, len(self.rest.X)), *self._args(), bool(project), self.elems, Ke)
        return Ke


class MuscleTerm(NodeTerm):
    """Fibre term of all muscles: passive plus activation-scaled active force-length stress.

    Entries ``(tet, muscle, fraction, fibre)`` as in :class:`~facesim.model.MuscleSet`;
    ``sigma_max (M,)`` MPa; ``gain (M,)`` scales each muscle's active curve (exaggeration, 1 by
    default). Energy ``sum V0 sigma rho [F_P(lam) + a g F_L(lam)]``.
    """

    def __init__(self, rest: RestShape, tet, muscle, fraction, fibre, sigma_max, gain=None, elems=None):
        self.rest = rest
        order = np.lexsort((np.asarray(muscle), np.asarray(tet)))   # group entries by tet
        self.tet = np.ascontiguousarray(np.asarray(tet, np.int64)[order])
        self.muscle = np.ascontiguousarray(np.asarray(muscle, np.int64)[order])
        self.fraction = np.ascontiguousarray(np.asarray(fraction, np.float64)[order])
        self.fibre = np.ascontiguousarray(np.asarray(fibre, np.float64)[order])
        self.sigma = np.ascontiguousarray(sigma_max, dtype=np.float64)
        self.n_muscles = len(self.sigma)
        self.gain = np.ascontiguousarray(np.ones(self.n_muscles) if gain is None else gain, dtype=np.float64)
        if self.gain.shape != (self.n_muscles,):
            raise FacesimError(f"gain: expected shape ({self.n_muscles},), got {self.gain.shape}")
        if elems is not None:   # keep only entries on assembled tets
            keep = np.zeros(len(rest.tets), bool)
            keep[elems] = True
            k = keep[self.tet]
            self.tet, self.muscle, self.fraction, self.fibre = (np.ascontiguousarray(v[k]) for v in
                                                                (self.tet, self.muscle, self.fraction, self.fibre))
        self.ent_ptr = np.searchsorted(self.tet, np.arange(len(rest.tets) + 1)).astype(np.int64)

    def with_gain(self, gain) -> "MuscleTerm":
        """A copy with another per-muscle gain (exaggeration)."""
        other = object.__new__(MuscleTerm)
        other.__dict__.update(self.__dict__)
        other.gain = np.ascontiguousarray(gain, dtype=np.float64)
        if other.gain.shape != (self.n_muscles,):
            raise FacesimError(f"gain: expected shape ({self.n_muscles},), got {other.gain.shape}")
        return other

    def _a(self, a) -> np.ndarray:
        a = np.zeros(self.n_muscles) if a is None else np.ascontiguousarray(a, dtype=np.float64)
        if a.shape != (self.n_muscles,):
            raise FacesimError(f"activations: expected shape ({self.n_muscles},), got {a.shape}")
        return a

    def _entry_gradients(self, x, a, active_only):
        r = self.rest
        ge = np.empty((len(self.tet), 4, 3))
        e = K.fibre_element_gradients(_positions(x, len(r.X)), r.tets, r.Bm, r.V0, self.tet, self.muscle,
                                      self.fraction, self.fibre, self.sigma, self.gain, self._a(a), active_only, ge)
        return e, ge

    def energy(self, x, a=None) -> float:
        return self._entry_gradients(x, a, False)[0]

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        e, ge = self._entry_gradients(x, a, False)
        g = np.zeros((len(self.rest.X), 3))
        K.scatter_gradient(self.rest.tets, self.tet, ge, g)
        return e, g

    def gradient(self, x, a=None) -> np.ndarray:
        return self.energy_and_gradient(x, a)[1]

    def add_hessian(self, x, a, system: DofSystem, data: np.ndarray, project: bool = True) -> None:
        r = self.rest
        K.fibre_assemble(_positions(x, len(r.X)), r.tets, r.Bm, r.V0, self.ent_ptr, self.fibre, self.muscle,
                         self.fraction, self.sigma, self.gain, self._a(a), bool(project), system.colour_ptr,
                         system.chunk_ptr, system.chunk_elems, system.chunk_e2b, data)

    def hessian(self, x, a=None, project: bool = True) -> sp.csr_matrix:
        return _own_hessian(self, x, a, project, unique_ints(self.tet))

    def force_columns(self, x) -> sp.csc_matrix:
        """``G (3n, n_muscles)``: column m is the internal force of muscle m at activation 1 with the
        passive part removed, ``g_m = -d/dx [sigma rho g F_L]``; the total internal force is
        ``f(x, a) = f_0(x) + G(x) a`` (Sifakis 2005 eq. 1). Newtons."""
        _, ge = self._entry_gradients(x, None, True)
        n = len(self.rest.X)
        nodes = self.rest.tets[self.tet]                          # (k, 4)
        rows = (3 * nodes[:, :, None] + np.arange(3)).reshape(len(self.tet), 12)
        cols = np.repeat(self.muscle[:, None], 12, axis=1)
        return sp.csc_matrix((-ge.reshape(len(self.tet), 12).ravel(), (rows.ravel(), cols.ravel())),
                             shape=(3 * n, self.n_muscles))
