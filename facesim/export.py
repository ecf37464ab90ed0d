"""Write a :class:`~facesim.model.FaceModel` to standard mesh files for other tools.

* :func:`export_volume` -- the flesh tets as VTU (ParaView) with per-tet labels, muscles and
  fibres and per-node bone attachment;
* :func:`export_skin` -- the skin surface as PLY or OBJ;
* :func:`export_surfaces` -- every bone and collider surface as PLY.

Positions are written in mm in facesim's frame, or, given an
:class:`~facesim.output_frame.OutputFrame` ``frame`` (``--output-frame input``), in the user's
input frame and units of an imported model (directions such as fibres rotated with it; the
winding, and so the outward normals, kept: the map is a rotation, a translation and a positive
scale). Every writer accepts deformed node positions ``x (n, 3)`` (mm, facesim's frame) in place
of the rest positions, and writes through a temporary file renamed into place, so a failed
export never leaves a truncated file behind.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np

from facesim._files import atomic_write, require_suffix
from facesim.errors import FacesimError
from facesim.model import FaceModel

#: Point-data values of the ``attachment`` field written by :func:`export_volume`.
ATTACHMENT_FREE, ATTACHMENT_CRANIUM, ATTACHMENT_JAW = 0, 1, 2

VOLUME_SUFFIXES = (".vtu",)
SURFACE_SUFFIXES = (".ply", ".obj")
_FORMATS = {".vtu": "vtu", ".ply": "ply", ".obj": "obj"}  # meshio format per suffix


def _positions(model: FaceModel, x) -> np.ndarray:
    if x is None:
        return model.X
    x = np.asarray(x, dtype=np.float64)
    if x.shape != model.X.shape:
        raise FacesimError(f"x: expected node positions of shape {model.X.shape}, got {x.shape}")
    return x


def _out(frame, P) -> np.ndarray:
    """``P (k, 3)`` mm in facesim's frame in the output ``frame`` (None: facesim's)."""
    return P if frame is None else frame.points(P)


def _write(path: Path, mesh: meshio.Mesh) -> Path:
    return atomic_write(path, lambda tmp: meshio.write(tmp, mesh, file_format=_FORMATS[path.suffix.lower()]))


def attachment_labels(model: FaceModel) -> np.ndarray:
    """(n,) int8 per node: 0 free, 1 attached to the cranium, 2 attached to the jaw."""
    label = np.full(model.n_nodes, ATTACHMENT_FREE, dtype=np.int8)
    label[model.cranium_nodes] = ATTACHMENT_CRANIUM
    label[model.jaw_nodes] = ATTACHMENT_JAW
    return label


def export_volume(model: FaceModel, path, x=None, frame=None) -> Path:
    """Write the flesh mesh to a ``.vtu`` file and return its path.

    Cell data (one value per tet): ``tissue`` (int32 label into ``model.tissues``),
    ``simulated`` (uint8 0/1), ``muscle`` (int32 index of the dominant muscle into
    ``model.muscles.names``, -1 for none), ``muscle_fraction`` (its volume fraction),
    ``muscle_total_fraction`` (sum over all muscles), ``fibre`` (3 comps, unit rest fibre
    direction of the dominant muscle, zero where there is none). Point data: ``attachment``
    (int8: 0 free, 1 cranium, 2 jaw). ``x (n, 3)`` mm replaces the rest positions if given;
    ``frame``: the :class:`~facesim.output_frame.OutputFrame` of the points and fibres (None: facesim's).

    ``muscle_total_fraction`` is not a volume fraction and may exceed 1: each muscle's fraction
    is the share of the tet inside that muscle's own ribbon (11 sample points,
    :func:`facesim.anatomy.muscles.embed_muscles`), and ribbons overlap where muscles interlace
    -- at the modiolus (zygomaticus major, levator anguli oris, risorius into orbicularis oris),
    the orbicularis oris halves at the midline, the levators and corrugator into orbicularis
    oculi. Each muscle then acts on its own fraction (:class:`facesim.fem.terms.MuscleTerm`:
    fibre stress ``sigma_max rho [f_P + a f_L]`` per muscle, summed), so such a tet carries the
    fibres of every muscle passing through it. On the shipped coarse face 111 of its 1,277
    muscle tets sum above 1 (at most 2.91, three muscles).
    """
    path = require_suffix(path, VOLUME_SUFFIXES, "a volume mesh file name")
    points = _out(frame, _positions(model, x))
    dominant, fraction, fibre = model.muscles.dominant(model.n_tets)
    if frame is not None:
        fibre = frame.directions(fibre)
    cell_data = {
        "tissue": [model.tissue.astype(np.int32)],
        "simulated": [model.simulated.astype(np.uint8)],
        "muscle": [dominant.astype(np.int32)],
        "muscle_fraction": [fraction],
        "muscle_total_fraction": [model.muscles.total_fraction(model.n_tets)],
        "fibre": [fibre],
    }
    mesh = meshio.Mesh(points, [("tetra", model.tets)], cell_data=cell_data,
                       point_data={"attachment": attachment_labels(model)})
    return _write(path, mesh)


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep only the vertices ``faces`` uses, reindexed in increasing order of old index."""
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(faces.shape).astype(np.int32)


def _write_surface(path: Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    mesh = meshio.Mesh(vertices, [("triangle", faces)])
    return _write(path, mesh)


def export_skin(model: FaceModel, path, x=None, frame=None) -> Path:
    """Write the skin triangles (outward oriented) to ``.ply`` or ``.obj``, by suffix.

    Only the nodes the skin uses are written, renumbered in increasing order of their model
    node index. ``x (n, 3)`` mm replaces the rest positions if given; ``frame``: the
    :class:`~facesim.output_frame.OutputFrame` of the vertices (None: facesim's). Returns the path.
    """
    path = require_suffix(path, SURFACE_SUFFIXES, "a surface file name")
    vertices, faces = _compact(_positions(model, x), model.skin)
    return _write_surface(path, _out(frame, vertices), faces)


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "surface"


def export_surfaces(model: FaceModel, folder, frame=None) -> list[Path]:
    """Write every bone and collider surface to ``folder/<name>.ply`` (rest positions, mm; in the
    :class:`~facesim.output_frame.OutputFrame` ``frame`` if given).

    Returns the written paths, bones first, in model order.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise FacesimError(f"{folder}: expected a folder for the surfaces, found a file")
    paths = []
    for surface in model.bones + model.colliders:
        vertices, faces = _compact(surface.vertices, surface.faces)
        paths.append(_write_surface(folder / f"{_safe_name(surface.name)}.ply", _out(frame, vertices), faces))
    return paths
