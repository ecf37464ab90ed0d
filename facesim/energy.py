"""The energy-term protocol: what the solvers minimise is a sum of :class:`EnergyTerm` objects.

Every term has the same four calls, ``energy``, ``gradient``, ``energy_and_gradient`` and
``hessian`` (plus ``max_step``, a step-size veto), over its own variable ``x``:

- :class:`NodeTerm` (flesh, muscles, contact, self-contact): ``x (n, 3)`` node positions, mm;
  ``a (n_muscles,)`` activations in [0, 1] (ignored by the terms that do not depend on them).
  Energies mJ (N mm), gradients ``(n, 3)`` N, ``hessian`` a scipy.sparse ``(3n, 3n)`` matrix,
  N/mm, dof ``3 i + k`` = coordinate k of node i. For the Newton solver they also assemble into a
  ``DofSystem`` (:mod:`facesim.fem.system`): ``add_hessian`` adds 3x3 blocks on the mesh pattern,
  ``sparse_hessian`` returns what falls outside it (None for most terms).
- :class:`ParameterTerm` (jaw kinematic and rigidity penalties): ``x = q (k,)``, a small parameter
  vector (e.g. the 12 affine coefficients of a bone frame); ``a`` ignored; ``hessian`` dense
  ``(k, k)``. Units: energy in the term's units, derivatives per unit of q.

``project=True`` asks for a positive semi-definite Hessian (what Newton with CG needs; terms
whose exact Hessian is already PSD return it unchanged), ``project=False`` for the exact one.
Terms are immutable: evaluations never change them. Every term's derivatives are checked by
one parametrised central-difference test (``tests/test_energy_terms.py``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np


class EnergyTerm(ABC):
    """One energy of the total: value, gradient and Hessian at ``x`` (and activations ``a``)."""

    def energy(self, x, a=None) -> float:
        """The energy at ``x``."""
        return self.energy_and_gradient(x, a)[0]

    def gradient(self, x, a=None) -> np.ndarray:
        """Its gradient, shaped like ``x``."""
        return self.energy_and_gradient(x, a)[1]

    @abstractmethod
    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        """``(energy, gradient)`` in one evaluation."""

    @abstractmethod
    def hessian(self, x, a=None, project: bool = True):
        """Hessian in ``x`` (flattened row-major); PSD if ``project``."""

    def max_step(self, x, dx) -> float:
        """Largest fraction of the step ``dx`` (shaped like ``x``) the term allows from ``x``;
        ``inf`` when it sets no limit (the default)."""
        return math.inf


class NodeTerm(EnergyTerm):
    """A term on node positions ``x (n, 3)`` mm: mJ, N, and N/mm Hessians ``(3n, 3n)`` sparse."""

    @abstractmethod
    def add_hessian(self, x, a, system: "DofSystem", data: np.ndarray, project: bool = True) -> None:
        """Add the Hessian's 3x3 blocks on ``system``'s pattern into ``data (system.n_blocks, 3, 3)``."""

    def sparse_hessian(self, x, a, system: "DofSystem", project: bool = True):
        """The rest of the Hessian, coupling nodes that share no element of ``system``: a scipy.sparse
        ``(system.n_dofs, system.n_dofs)`` matrix, zero in prescribed rows and columns, or None
        (the default: the term lies on the mesh pattern)."""
        return None


class ParameterTerm(EnergyTerm):
    """A term on a parameter vector ``q (k,)`` whose value, gradient ``(k,)`` and dense Hessian
    ``(k, k)`` come from one evaluation, :meth:`evaluate`."""

    @abstractmethod
    def evaluate(self, q, project: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
        """``(value, gradient (k,), Hessian (k, k))`` at ``q``; Hessian PSD if ``project``."""

    def energy_and_gradient(self, x, a=None) -> tuple[float, np.ndarray]:
        value, grad, _ = self.evaluate(x, False)
        return float(value), grad

    def hessian(self, x, a=None, project: bool = True) -> np.ndarray:
        return self.evaluate(x, project)[2]


__all__ = ["EnergyTerm", "NodeTerm", "ParameterTerm"]
