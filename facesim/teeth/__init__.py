"""Teeth tracking from calibrated multi-view images (Yang et al. 2018, section 4).

One module per concept: :mod:`~facesim.teeth.cameras` (calibration file, projection, the default
layout), :mod:`~facesim.teeth.dentition` (teeth meshes in mm in facesim's frame, incisal points),
:mod:`~facesim.teeth.raster` (the z-buffer front end of :mod:`facesim._kernels.raster`),
:mod:`~facesim.teeth.lips` (a procedural lip occluder), :mod:`~facesim.teeth.render` (synthetic
captures), :mod:`~facesim.teeth.segment` (teeth masks from images),
:mod:`~facesim.teeth.capture` (an image folder checked against the calibration),
:mod:`~facesim.teeth.silhouette` (the silhouette energy and its Gauss-Newton model),
:mod:`~facesim.teeth.track` (per-frame head and jaw fits, sequences, the poses file) and
:mod:`~facesim.teeth.cli` (``facesim teeth render|track``).
"""
