"""Building face models: the procedural anatomical head (phantom), muscles, markers, meshing."""

from facesim.anatomy.build import RESOLUTIONS, build_head

__all__ = ["RESOLUTIONS", "build_head"]
