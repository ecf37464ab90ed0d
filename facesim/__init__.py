"""facesim: an anatomical, quasistatic finite-element face simulator.

Units throughout: millimetre, newton, megapascal, second (tonne for mass).
"""

from facesim.errors import FacesimError
from facesim.model import FaceModel, load_model

__version__ = "0.1.0"
__all__ = ["FaceModel", "FacesimError", "Simulation", "load_model", "__version__"]


def __getattr__(name):   # the simulator pulls in numba kernels: import it when first asked for
    if name == "Simulation":
        from facesim.session import Simulation

        return Simulation
    raise AttributeError(f"module 'facesim' has no attribute {name!r}")
