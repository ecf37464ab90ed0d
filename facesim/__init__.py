"""facesim: an anatomical, quasistatic finite-element face simulator.

Units throughout: millimetre, newton, megapascal, second (tonne for mass).
"""

from facesim.errors import FacesimError
from facesim.model import FaceModel, load_model

__version__ = "0.1.0"
__all__ = ["FaceModel", "FacesimError", "load_model", "__version__"]
