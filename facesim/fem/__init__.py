"""Quasistatic finite elements: invertible Mooney-Rivlin flesh, muscle fibres, Newton + AMG.

Public entry points: :class:`MooneyRivlin`, :func:`solve_static` (any tet mesh),
:class:`NewtonOptions`, the energy terms and :func:`box_mesh` for verification.
"""

from facesim.fem.material import MooneyRivlin
from facesim.fem.meshes import box_mesh
from facesim.fem.newton import NewtonOptions, SolveReport
from facesim.fem.static import solve_static
from facesim.fem.system import DofSystem, RestShape
from facesim.fem.terms import ElasticTerm, MuscleTerm

__all__ = ["MooneyRivlin", "NewtonOptions", "SolveReport", "solve_static", "box_mesh", "DofSystem", "RestShape",
           "ElasticTerm", "MuscleTerm"]
