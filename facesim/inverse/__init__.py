"""The inverse problem: muscle activations and jaw (and head) pose from marker positions.

``jacobian``: implicit derivatives of the equilibrium and of the markers with respect to the
controls (Sifakis 2005 eqs. 5-6); ``gauss_newton``: one frame (Gauss-Newton with the progressive
penalty schedule and golden-section search).
"""

from facesim.inverse.gauss_newton import Fit, FitOptions, FitReport, fit_frame
from facesim.inverse.jacobian import ControlSpace, EquilibriumJacobian, equilibrium_jacobian, marker_jacobian

__all__ = ["ControlSpace", "EquilibriumJacobian", "equilibrium_jacobian", "marker_jacobian", "Fit", "FitOptions",
           "FitReport", "fit_frame"]
