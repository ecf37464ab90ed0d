"""The frame results are written in: facesim's own, or the user's input frame of an imported model.

facesim computes in its frame (mm; x the subject's left, y up, z forward; origin between the
condyles). ``facesim model import`` converts the user's anatomy into it and stores the transform
in the model (:meth:`facesim.importing.frame.FrameFit.meta`, under ``meta["import"]["input_frame"]``
and ``meta["input_frame"]``)::

    p_facesim = T[:3, :3] @ (scale_to_mm * p_input) + T[:3, 3]        (T_facesim_from_input_mm)

:func:`output_frame` gives the writers of meshes and markers (``--output-frame`` of ``simulate``,
``model export``, ``export-cache``, ``solve-mocap --write-meshes``) the map back: in the
``"input"`` frame a point is ``p_input = T^-1 p_facesim / scale_to_mm``, in the user's units and
axes, the exact inverse of the import. The import transform is a rotation, a translation and a
positive scale (checked here), so triangle winding and outward normals survive it. The solver's
own files (state/frame_KKKKK.npz: the resume state) stay in facesim's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim.errors import FacesimError
from facesim.mocap.io import UNITS_MM

#: The names of ``--output-frame``.
OUTPUT_FRAMES = ("facesim", "input")
#: Tolerance on the stored rotation's orthonormality (it is stored to 9 decimals).
ROTATION_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class OutputFrame:
    """Where written positions are expressed.

    name : ``"facesim"`` or ``"input"``.
    units : ``"mm"``, ``"cm"`` or ``"m"``: the unit of :meth:`points` (TRC / C3D unit fields).
    matrix : (4, 4) float64 similarity, facesim mm -> output coordinates (homogeneous, column
        vectors): ``points(P) = P @ matrix[:3, :3].T + matrix[:3, 3]``.
    how : how the input frame was found (the importer's ``how``; empty for facesim's frame).
    """

    name: str = "facesim"
    units: str = "mm"
    matrix: np.ndarray = None
    how: str = ""

    def __post_init__(self):
        M = np.eye(4) if self.matrix is None else np.array(self.matrix, dtype=np.float64)
        M.setflags(write=False)
        object.__setattr__(self, "matrix", M)

    # ------------------------------------------------------------------ derived
    @property
    def is_identity(self) -> bool:
        return self.name == "facesim"

    @property
    def mm_per_unit(self) -> float:
        """mm in one output unit (1, 10 or 1000)."""
        return UNITS_MM[self.units]

    @property
    def meters_per_unit(self) -> float:
        """Metres in one output unit (USD's ``metersPerUnit``)."""
        return self.mm_per_unit / 1000.0

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) the rotation part, facesim axes -> output axes."""
        return self.matrix[:3, :3] * self.mm_per_unit

    # ------------------------------------------------------------------ maps
    def points(self, P) -> np.ndarray:
        """``P (..., 3)`` mm in facesim's frame -> ``(..., 3)`` in this frame's axes, origin and
        units (NaN stays NaN)."""
        P = np.asarray(P, dtype=np.float64)
        if self.is_identity:
            return P.copy()
        return P @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def points_mm(self, P) -> np.ndarray:
        """``P (..., 3)`` mm in facesim's frame -> ``(..., 3)`` in this frame's axes and origin but
        in mm: what writers that take mm and a file unit (TRC, C3D, marker CSV) want."""
        Q = self.points(P)
        return Q if self.units == "mm" else Q * self.mm_per_unit

    def to_facesim(self, Q) -> np.ndarray:
        """The inverse of :meth:`points`: ``Q (..., 3)`` in this frame (its units) -> mm in facesim's
        frame (for the input frame: the import transform itself)."""
        Q = np.asarray(Q, dtype=np.float64)
        if self.is_identity:
            return Q.copy()
        Mi = np.linalg.inv(self.matrix)
        return Q @ Mi[:3, :3].T + Mi[:3, 3]

    def vectors(self, V) -> np.ndarray:
        """``V (..., 3)`` displacements, mm in facesim's axes -> this frame's axes and units."""
        V = np.asarray(V, dtype=np.float64)
        return V.copy() if self.is_identity else V @ self.matrix[:3, :3].T

    def directions(self, D) -> np.ndarray:
        """``D (..., 3)`` directions (e.g. unit fibre directions) -> this frame's axes, rotated only
        (lengths kept; zero vectors stay zero)."""
        D = np.asarray(D, dtype=np.float64)
        return D.copy() if self.is_identity else D @ self.rotation.T

    def transform(self, T) -> np.ndarray:
        """A 4x4 rigid motion ``T`` of facesim's frame (mm) as the same motion of this frame:
        ``matrix @ T @ matrix^-1`` (still rigid: the frames differ by a similarity)."""
        T = np.asarray(T, dtype=np.float64)
        return T.copy() if self.is_identity else self.matrix @ T @ np.linalg.inv(self.matrix)

    def up_axis(self) -> str:
        """``"Y"`` or ``"Z"``: the axis of this frame closest to facesim's up (USD's ``upAxis``
        takes no other)."""
        up = self.directions([0.0, 1.0, 0.0])
        return "Z" if abs(up[2]) > abs(up[1]) else "Y"

    def describe(self) -> dict:
        """JSON for a run's ``report.json`` and the caches: name, units and, for the input frame,
        ``matrix_from_facesim_mm`` (the 4x4 of :attr:`matrix`) and how the frame was found."""
        out = {"name": self.name, "units": self.units}
        if not self.is_identity:
            out["matrix_from_facesim_mm"] = np.round(self.matrix, 12).tolist()
            out["how"] = self.how
        return out

    def said(self) -> str:
        """A few words for the command's output, e.g. ``"the input frame (m)"``."""
        return "facesim's frame (mm)" if self.is_identity else f"the input frame ({self.units})"


FACESIM = OutputFrame()


def output_frame(model, name: str = "facesim", source=None) -> OutputFrame:
    """The :class:`OutputFrame` ``name`` (``"facesim"`` or ``"input"``) of ``model``.

    ``"input"`` needs a model made by ``facesim model import`` (its ``meta["import"]["input_frame"]``,
    or ``meta["input_frame"]``); any other model gives a one-line :class:`FacesimError` naming
    ``source`` (the model file) where given. A stored transform that is not a proper rotation,
    a translation and a positive scale of a known unit is refused the same way.
    """
    if isinstance(name, OutputFrame):
        return name
    if name not in OUTPUT_FRAMES:
        raise FacesimError(f"--output-frame: expected one of {', '.join(OUTPUT_FRAMES)}, got {name!r}")
    if name == "facesim":
        return FACESIM
    what = str(source) if source is not None else "the model"
    meta = model.meta if isinstance(model.meta, dict) else {}
    imported = meta.get("import") if isinstance(meta.get("import"), dict) else {}
    stored = imported.get("input_frame") or meta.get("input_frame")
    if not isinstance(stored, dict):
        raise FacesimError(f"--output-frame input: {what} was built by facesim model build, not imported; it has no "
                           "input frame")
    field = "meta.import.input_frame" if imported.get("input_frame") else "meta.input_frame"
    try:
        T = np.array(stored["T_facesim_from_input_mm"], dtype=np.float64)
        scale = float(stored["scale_to_mm"])
        units = str(stored["units"])
    except (KeyError, TypeError, ValueError):
        raise FacesimError(f"--output-frame input: {what}: {field}: expected T_facesim_from_input_mm (4x4), "
                           "scale_to_mm and units") from None
    R = T[:3, :3] if T.shape == (4, 4) else None
    if R is None or not np.isfinite(T).all() or not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]) or \
            not np.allclose(R.T @ R, np.eye(3), atol=ROTATION_TOL) or np.linalg.det(R) <= 0:
        raise FacesimError(f"--output-frame input: {what}: {field}.T_facesim_from_input_mm is not a 4x4 proper "
                           "rigid transform (rotation and translation)")
    if units not in UNITS_MM or not np.isclose(scale, UNITS_MM[units], rtol=1e-12):
        raise FacesimError(f"--output-frame input: {what}: {field}: units {units!r} with scale_to_mm {scale:g}; "
                           f"expected one of {', '.join(f'{u} ({s:g})' for u, s in UNITS_MM.items())}")
    # p_input = T^-1 p_facesim / scale: the exact inverse of the import (the stored T, not R^T)
    M = np.diag([1.0 / scale, 1.0 / scale, 1.0 / scale, 1.0]) @ np.linalg.inv(T)
    return OutputFrame("input", units, M, str(stored.get("how", "")))


def run_output_frame(model, report: dict | None) -> OutputFrame:
    """The output frame a run recorded in its ``report.json`` (``output_frame.name``; facesim's
    frame for a run without one)."""
    recorded = report.get("output_frame") if isinstance(report, dict) else None
    return output_frame(model, recorded.get("name", "facesim") if isinstance(recorded, dict) else "facesim")


__all__ = ["FACESIM", "OUTPUT_FRAMES", "OutputFrame", "output_frame", "run_output_frame"]
