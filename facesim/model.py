"""The face model: an immutable volumetric description of one subject's face.

A :class:`FaceModel` holds everything the simulator and the solvers need and never changes
after construction: variants are made with :meth:`FaceModel.with_` (a validated copy).

Units: millimetre (positions), megapascal (stiffness, muscle stress), radian (angles).
Coordinates: x toward the subject's left, y up, z toward the nose; origin between the
condyles (see ``docs/physics.md`` section 6).

File format: one compressed ``.npz`` whose ``meta`` entry is a JSON string carrying
``format`` (``"facesim-model"``) and ``version`` (:data:`FORMAT_VERSION`); every array field
is stored under a fixed key. Unknown versions and missing fields are refused with a one-line
:class:`~facesim.errors.ModelFileError`, and so is bad content (:func:`load_model`).

Content. Every :class:`FaceModel`, built in memory or read from a file, passes one content
check at construction (``_check_content``): finite numbers, at least one node, tet, skin
triangle and simulated tet, positive rest tet volumes, materials in their physical ranges
(c10 > 0, c01 >= 0, kappa > 0 MPa; sigma_max >= 0 MPa), unit fibres, non-empty cranium and
jaw attachments. The parts check their structure (shapes, counts, index ranges) themselves;
:class:`JawGeometry`, which the jaw rigs use on their own, also its content. A model whose
tets are all inverted is refused like any other: it is not silently re-oriented (the message
says every tet is inverted, i.e. the file stores the other orientation).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facesim._files import NpzFormat, read_npz, write_npz
from facesim.errors import FacesimError, ModelFileError

FORMAT_NAME = "facesim-model"
FORMAT_VERSION = 1
MODEL_FORMAT = NpzFormat(FORMAT_NAME, FORMAT_VERSION, what="a facesim model .npz", name="a facesim model file",
                         label="model format")

#: The rigid bodies flesh can be attached to, and what a rigid surface can move with.
BONES = ("cranium", "jaw")
SIDES = ("L", "R", "M")
#: Bounds of a model in mm: coordinates (a head is ~300 mm across, its origin between the condyles),
#: the bounding-box diagonal (from a small test block to a whole body), marker heights off the skin.
MAX_COORDINATE_MM = 1e4
EXTENT_MM = (1.0, 1e4)
MAX_MARKER_HEIGHT_MM = 100.0


class _FieldError(FacesimError):
    """Bad content of one model field. ``field`` names it as the model does (``"X"``,
    ``"muscles.fibre"``, ``"tissues[1].kappa"``); ``expected`` says what was expected and what
    was found. :func:`load_model` reports it under the field's key in the file."""

    def __init__(self, field: str, expected: str):
        self.field, self.expected = field, expected
        super().__init__(f"{field}: {expected}")


def _some(bad: np.ndarray, noun: str, plural: str | None = None, index: np.ndarray | None = None) -> str:
    """``"3 of 5,123 nodes (first: node 17)"`` for the True entries of ``bad (k,)`` bool; ``index (k,)``
    numbers the entries (default 0 .. k-1)."""
    first = int(np.argmax(bad)) if index is None else int(index[np.argmax(bad)])
    return f"{int(bad.sum()):,} of {bad.size:,} {plural or noun + 's'} (first: {noun} {first})"


def _num(v) -> str:
    """A value for a message: numbers as ``%.6g`` (``-0.1``, ``nan``), anything else as its repr."""
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return repr(v)


def _as(a, dtype, shape_tail: tuple[int, ...], name: str) -> np.ndarray:
    """Read-only contiguous copy of ``a`` as ``dtype`` with trailing shape ``shape_tail``.

    Always a copy, so freezing it never makes the caller's array read-only. Only numbers and
    bools convert (strings, objects and complex numbers are refused, not cast); an integer
    ``dtype`` takes integral values that fit it, so indices are never truncated or wrapped.
    """
    src = np.asarray(a)
    if src.dtype.kind not in "biuf":
        raise _FieldError(name, f"expected numbers, got dtype {src.dtype}")
    if np.dtype(dtype).kind in "iu" and src.size and src.dtype.kind in "iuf":
        info = np.iinfo(dtype)
        flat = src.ravel()
        bad = ~(np.isfinite(flat) & (flat >= info.min) & (flat <= info.max))
        if src.dtype.kind == "f":
            bad |= ~(np.floor(flat) == flat)
        if bad.any():
            raise _FieldError(name, f"expected integers in [{info.min}, {info.max}], got "
                                    f"{_num(flat[np.argmax(bad)])} in {_some(bad, 'entry', 'entries')}")
    arr = np.array(src, dtype=dtype, order="C", copy=True)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(k" + "".join(f", {s}" for s in shape_tail) + ")"
        raise FacesimError(f"{name}: expected shape {want}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


def signed_volumes(X: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) float64 signed volumes of ``tets (m, 4)`` at node positions ``X (n, 3)``: positive when
    ``(x1 - x0) . ((x2 - x0) x (x3 - x0)) > 0``."""
    e = X[tets[:, 1:]] - X[tets[:, :1]]
    return np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) / 6.0


def positively_oriented(X: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """``tets`` with every negatively oriented tet's second and third node swapped (a copy)."""
    T = np.array(tets, copy=True)
    flip = signed_volumes(X, T) < 0
    T[flip] = T[flip][:, [0, 2, 1, 3]]
    return T


def _check_index(arr: np.ndarray, upper: int, name: str) -> None:
    if arr.size and (arr.min() < 0 or arr.max() >= upper):
        raise _FieldError(name, f"indices must lie in [0, {upper}), got [{arr.min()}, {arr.max()}]")


@dataclass(frozen=True)
class Tissue:
    """Mooney-Rivlin parameters of one tissue (MPa): psi = c10 (I1b-3) + c01 (I2b-3) + kappa/2 (ln J)^2."""

    name: str
    c10: float
    c01: float
    kappa: float

    @property
    def shear_modulus(self) -> float:
        """Small-strain shear modulus mu = 2 (c10 + c01), MPa."""
        return 2.0 * (self.c10 + self.c01)


@dataclass(frozen=True)
class MuscleSet:
    """Muscles embedded in the flesh mesh, stored sparsely as (muscle, tet) entries.

    Attributes
    ----------
    names : tuple[str, ...], ``n_muscles`` unique names, e.g. ``"zygomaticus_major_L"``.
    sides : tuple[str, ...], ``"L"``, ``"R"`` or ``"M"`` (midline) per muscle.
    sigma_max : (n_muscles,) float64, peak isometric stress, MPa.
    muscle : (k,) int32, muscle index of each entry (entries sorted by muscle, then tet).
    tet : (k,) int32, tet index of each entry.
    fraction : (k,) float64, volume fraction of the tet occupied by the muscle, in (0, 1].
    fibre : (k, 3) float64, unit rest fibre direction of the muscle in that tet.

    Shapes, counts, order and muscle indices are checked here; the values (peak stresses,
    fractions, fibres) by the model's content check.
    """

    names: tuple[str, ...]
    sides: tuple[str, ...]
    sigma_max: np.ndarray
    muscle: np.ndarray
    tet: np.ndarray
    fraction: np.ndarray
    fibre: np.ndarray

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        sides = tuple(str(s) for s in self.sides)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "sides", sides)
        if len(set(names)) != len(names):
            raise FacesimError("muscles.names: expected unique names")
        if len(sides) != len(names) or any(s not in SIDES for s in sides):
            raise FacesimError(f"muscles.sides: expected one of {SIDES} per muscle")
        object.__setattr__(self, "sigma_max", _as(self.sigma_max, np.float64, (), "muscles.sigma_max"))
        if self.sigma_max.shape != (len(names),):
            raise FacesimError(f"muscles.sigma_max: expected shape ({len(names)},), got {self.sigma_max.shape}")
        object.__setattr__(self, "muscle", _as(self.muscle, np.int32, (), "muscles.muscle"))
        k = len(self.muscle)
        object.__setattr__(self, "tet", _as(self.tet, np.int32, (), "muscles.tet"))
        object.__setattr__(self, "fraction", _as(self.fraction, np.float64, (), "muscles.fraction"))
        object.__setattr__(self, "fibre", _as(self.fibre, np.float64, (3,), "muscles.fibre"))
        for name in ("tet", "fraction", "fibre"):
            if len(getattr(self, name)) != k:
                raise FacesimError(f"muscles.{name}: expected {k} entries like muscles.muscle")
        _check_index(self.muscle, len(names), "muscles.muscle")
        if k > 1:
            key = self.muscle.astype(np.int64) * (int(self.tet.max()) + 1) + self.tet
            if np.any(np.diff(key) <= 0):
                raise FacesimError("muscles: entries must be sorted by (muscle, tet) without duplicates")

    @property
    def n_muscles(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of muscle ``name``; a :class:`FacesimError` lists the known names otherwise."""
        try:
            return self.names.index(name)
        except ValueError:
            raise FacesimError(f"unknown muscle {name!r}; known: {', '.join(self.names)}") from None

    def entries(self, m: int) -> slice:
        """Slice of the entries of muscle ``m`` (entries are sorted by muscle)."""
        lo, hi = np.searchsorted(self.muscle, [m, m + 1])
        return slice(int(lo), int(hi))

    def tets_per_muscle(self) -> np.ndarray:
        """(n_muscles,) int, number of tets each muscle touches."""
        return np.bincount(self.muscle, minlength=self.n_muscles)

    def volume_per_muscle(self, tet_volume: np.ndarray) -> np.ndarray:
        """(n_muscles,) float64 embedded muscle volume, mm^3, from rest tet volumes ``(n_tets,)``."""
        return np.bincount(self.muscle, weights=self.fraction * tet_volume[self.tet], minlength=self.n_muscles)

    def total_fraction(self, n_tets: int) -> np.ndarray:
        """(n_tets,) float64, summed muscle volume fraction per tet."""
        return np.bincount(self.tet, weights=self.fraction, minlength=n_tets)

    def dominant(self, n_tets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per tet: index of the muscle with the largest fraction (-1 if none), that fraction and its fibre.

        Returns ``(muscle (n_tets,) int32, fraction (n_tets,) float64, fibre (n_tets, 3) float64)``.
        """
        best = np.full(n_tets, -1, dtype=np.int32)
        frac = np.zeros(n_tets)
        fib = np.zeros((n_tets, 3))
        if len(self.tet):
            # sort by (tet, fraction) and keep the last entry of every tet: its largest fraction
            order = np.lexsort((self.fraction, self.tet))
            last = np.r_[self.tet[order][1:] != self.tet[order][:-1], True]
            keep = order[last]
            best[self.tet[keep]] = self.muscle[keep]
            frac[self.tet[keep]] = self.fraction[keep]
            fib[self.tet[keep]] = self.fibre[keep]
        return best, frac, fib


@dataclass(frozen=True)
class MarkerSet:
    """Named skin markers bound to skin triangles.

    Attributes
    ----------
    names : tuple[str, ...], unique marker names.
    triangle : (r,) int32, index into ``FaceModel.skin``.
    bary : (r, 3) float64, barycentric coordinates in that triangle (sum 1, non-negative).
    offset : (r,) float64, distance along the triangle's outward normal, mm (marker height).
    head : (r,) bool, True for head (stabilisation) markers on rigid-looking regions.
    """

    names: tuple[str, ...]
    triangle: np.ndarray
    bary: np.ndarray
    offset: np.ndarray
    head: np.ndarray

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        object.__setattr__(self, "names", names)
        if len(set(names)) != len(names):
            raise FacesimError("markers.names: expected unique names")
        r = len(names)
        object.__setattr__(self, "triangle", _as(self.triangle, np.int32, (), "markers.triangle"))
        object.__setattr__(self, "bary", _as(self.bary, np.float64, (3,), "markers.bary"))
        object.__setattr__(self, "offset", _as(self.offset, np.float64, (), "markers.offset"))
        object.__setattr__(self, "head", _as(self.head, bool, (), "markers.head"))
        for name in ("triangle", "bary", "offset", "head"):
            if len(getattr(self, name)) != r:
                raise FacesimError(f"markers.{name}: expected {r} entries, one per marker name")

    @property
    def n_markers(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class RigidSurface:
    """A closed triangle surface that moves rigidly with a bone (teeth, gums, eyeball, bone).

    ``vertices (k, 3) float64`` in rest position, mm; ``faces (l, 3) int32`` outward oriented;
    ``bone`` is ``"cranium"`` or ``"jaw"``.
    """

    name: str
    bone: str
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        if self.bone not in BONES:
            raise FacesimError(f"surface {self.name!r}: bone must be one of {BONES}, got {self.bone!r}")
        object.__setattr__(self, "vertices", _as(self.vertices, np.float64, (3,), f"{self.name}.vertices"))
        object.__setattr__(self, "faces", _as(self.faces, np.int32, (3,), f"{self.name}.faces"))
        _check_index(self.faces, len(self.vertices), f"{self.name}.faces")


@dataclass(frozen=True)
class JawGeometry:
    """Temporomandibular joint geometry in the cranium frame at rest (Sifakis 2005 section 8).

    condyle_right, condyle_left : (3,) rest condyle centres, mm.
    track_direction : (3,) unit vector v along the sliding tracks, back to front (inclined down).
    track_length : d, mm, how far each condyle may slide along its track.
    max_opening : rad, largest opening rotation about the intercondylar axis.
    incisor : (3,) lower incisal reference point (moves with the jaw), mm.
    """

    condyle_right: np.ndarray
    condyle_left: np.ndarray
    track_direction: np.ndarray
    track_length: float
    max_opening: float
    incisor: np.ndarray

    def __post_init__(self):
        # content checked here, not by the model's check: the jaw rigs use a geometry on its own
        for name in ("condyle_right", "condyle_left", "track_direction", "incisor"):
            v = _as(getattr(self, name), np.float64, (), f"jaw.{name}")
            if v.shape != (3,):
                raise FacesimError(f"jaw.{name}: expected shape (3,), got {v.shape}")
            if not np.isfinite(v).all():
                raise _FieldError(f"jaw.{name}", f"expected 3 finite numbers, got {v.tolist()}")
            if np.abs(v).max() > MAX_COORDINATE_MM:
                raise _FieldError(f"jaw.{name}", f"expected a point within +-{MAX_COORDINATE_MM:g} mm of the origin, "
                                                 f"got {', '.join(f'{c:.3g}' for c in v)}")
            object.__setattr__(self, name, v)
        if not abs(np.linalg.norm(self.track_direction) - 1.0) <= 1e-9:
            raise _FieldError("jaw.track_direction", "expected a unit vector")
        if not self.intercondylar_distance > 0:
            raise _FieldError("jaw.condyle_left", "expected two distinct condyles, got condyle_left = condyle_right")
        for name in ("track_length", "max_opening"):
            try:
                object.__setattr__(self, name, float(getattr(self, name)))
            except (TypeError, ValueError):
                raise _FieldError(f"jaw.{name}", f"expected a number, got {getattr(self, name)!r}") from None
        if not self.track_length > 0 or not np.isfinite(self.track_length):
            raise _FieldError("jaw.track_length", f"expected a finite length > 0 mm, got {_num(self.track_length)}")
        if not 0 < self.max_opening < np.pi / 2:
            raise _FieldError("jaw.max_opening", f"expected an angle in (0, pi/2) rad, got {_num(self.max_opening)}")

    @property
    def u(self) -> np.ndarray:
        """(3,) unit intercondylar axis, right condyle to left condyle."""
        d = self.condyle_left - self.condyle_right
        return d / np.linalg.norm(d)

    @property
    def v(self) -> np.ndarray:
        """(3,) unit sliding-track direction (alias of ``track_direction``)."""
        return self.track_direction

    @property
    def w(self) -> np.ndarray:
        """(3,) unit normal of the track plane, w = v x u (Sifakis 2005 section 8)."""
        w = np.cross(self.v, self.u)
        return w / np.linalg.norm(w)

    @property
    def midpoint(self) -> np.ndarray:
        """(3,) rest midpoint m of the condyles, mm."""
        return 0.5 * (self.condyle_left + self.condyle_right)

    @property
    def intercondylar_distance(self) -> float:
        """l, mm."""
        return float(np.linalg.norm(self.condyle_left - self.condyle_right))


@dataclass(frozen=True)
class FaceModel:
    """Volumetric face: flesh tets, tissues, muscles, bone attachments, surfaces, markers, TMJ.

    Attributes
    ----------
    X : (n, 3) float64, rest node positions, mm.
    tets : (m, 4) int32, flesh tetrahedra, positively oriented.
    tissue : (m,) int32, index into ``tissues`` per tet.
    tissues : tuple[Tissue, ...], material of each tissue label.
    simulated : (m,) bool, True for tets of the simulated face region; the others move with the
        cranium (their nodes are all in ``cranium_nodes``).
    muscles : MuscleSet.
    cranium_nodes, jaw_nodes : (p,), (q,) int32, sorted, disjoint node sets attached to the
        cranium and to the mandible.
    skin : (s, 3) int32, outer skin triangles (closed, outward oriented), node indices.
    lip_upper, lip_lower : (a, 3), (b, 3) int32, flesh boundary triangles of the upper and
        lower lip contact surfaces (the faces across the mouth slit and facing the teeth).
    bones : tuple[RigidSurface, ...], the cranium and mandible surfaces (rendering, contact).
    colliders : tuple[RigidSurface, ...], teeth, gums and eyeballs the flesh must not enter.
    markers : MarkerSet, bound to ``skin`` triangles.
    jaw : JawGeometry.
    meta : dict, JSON-serialisable build information (resolution, seed, mesh quality, ...).
    """

    X: np.ndarray
    tets: np.ndarray
    tissue: np.ndarray
    tissues: tuple[Tissue, ...]
    simulated: np.ndarray
    muscles: MuscleSet
    cranium_nodes: np.ndarray
    jaw_nodes: np.ndarray
    skin: np.ndarray
    lip_upper: np.ndarray
    lip_lower: np.ndarray
    bones: tuple[RigidSurface, ...]
    colliders: tuple[RigidSurface, ...]
    markers: MarkerSet
    jaw: JawGeometry
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "X", _as(self.X, np.float64, (3,), "X"))
        object.__setattr__(self, "tets", _as(self.tets, np.int32, (4,), "tets"))
        n, m = len(self.X), len(self.tets)
        _check_index(self.tets, n, "tets")
        for name, dtype, tail in (("tissue", np.int32, ()), ("simulated", bool, ())):
            arr = _as(getattr(self, name), dtype, tail, name)
            if len(arr) != m:
                raise FacesimError(f"{name}: expected one entry per tet ({m}), got {len(arr)}")
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "tissues", tuple(self.tissues))
        _check_index(self.tissue, len(self.tissues), "tissue")
        for name in ("cranium_nodes", "jaw_nodes"):
            arr = _as(getattr(self, name), np.int32, (), name)
            _check_index(arr, n, name)
            object.__setattr__(self, name, arr)
        if np.intersect1d(self.cranium_nodes, self.jaw_nodes).size:
            raise FacesimError("cranium_nodes and jaw_nodes: expected disjoint sets")
        for name in ("skin", "lip_upper", "lip_lower"):
            arr = _as(getattr(self, name), np.int32, (3,), name)
            _check_index(arr, n, name)
            object.__setattr__(self, name, arr)
        _check_index(self.muscles.tet, m, "muscles.tet")
        _check_index(self.markers.triangle, len(self.skin), "markers.triangle")
        object.__setattr__(self, "bones", tuple(self.bones))
        object.__setattr__(self, "colliders", tuple(self.colliders))
        object.__setattr__(self, "meta", dict(self.meta))
        _check_content(self)

    # ------------------------------------------------------------------ sizes
    @property
    def n_nodes(self) -> int:
        return len(self.X)

    @property
    def n_tets(self) -> int:
        return len(self.tets)

    @property
    def n_simulated(self) -> int:
        return int(self.simulated.sum())

    @property
    def n_muscles(self) -> int:
        return self.muscles.n_muscles

    @property
    def n_markers(self) -> int:
        return self.markers.n_markers

    # ------------------------------------------------------------ geometry
    def tet_volumes(self, x: np.ndarray | None = None) -> np.ndarray:
        """(m,) float64 signed tet volumes, mm^3, at positions ``x (n, 3)`` (rest if None)."""
        return signed_volumes(self.X if x is None else np.asarray(x, dtype=np.float64), self.tets)

    def marker_positions(self, x: np.ndarray | None = None) -> np.ndarray:
        """(r, 3) float64 marker positions, mm, for node positions ``x (n, 3)`` (rest if None).

        Each marker sits at its barycentric point of its skin triangle, moved ``offset`` mm
        along the triangle's unit normal (markers are linear in ``x`` when offsets are zero).
        """
        x = self.X if x is None else np.asarray(x, dtype=np.float64)
        tri = x[self.skin[self.markers.triangle]]  # (r, 3, 3)
        p = np.einsum("rk,rkj->rj", self.markers.bary, tri)
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        return p + self.markers.offset[:, None] * nrm

    def surface(self, name: str) -> RigidSurface:
        """The bone or collider surface called ``name``."""
        for s in self.bones + self.colliders:
            if s.name == name:
                return s
        known = ", ".join(s.name for s in self.bones + self.colliders)
        raise FacesimError(f"unknown surface {name!r}; known: {known}")

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """((3,), (3,)) lower and upper corners of the rest nodes, mm."""
        return self.X.min(axis=0), self.X.max(axis=0)

    # ------------------------------------------------------------- variants
    def with_(self, **changes) -> "FaceModel":
        """A validated copy with the given fields replaced (the model itself never changes)."""
        return dataclasses.replace(self, **changes)

    def with_tissues(self, tissues) -> "FaceModel":
        """Copy with a new tissue table (same labels), e.g. stiffer flesh."""
        return self.with_(tissues=tuple(tissues))

    def with_muscle_strength(self, sigma_max) -> "FaceModel":
        """Copy with new per-muscle peak stresses ``(n_muscles,)``, MPa."""
        return self.with_(muscles=dataclasses.replace(self.muscles, sigma_max=np.asarray(sigma_max, float)))

    # ------------------------------------------------------------------- I/O
    def save(self, path) -> Path:
        """Write the model to one compressed ``.npz`` (atomically) and return its path."""
        arrays, meta = _to_arrays(self)
        return write_npz(path, MODEL_FORMAT, arrays, meta)

    @staticmethod
    def load(path) -> "FaceModel":
        """Read a model written by :meth:`save`; see :func:`load_model`."""
        return load_model(path)


# -------------------------------------------------------------------- content
#: physical ranges of the material parameters, MPa: (name, lower bound, lower bound included)
#: and an upper bound far above any soft tissue (bone's moduli are ~1e4 MPa, a near-incompressible
#: kappa ~1e3 times the shear modulus); the largest peak muscle stress, MPa (muscle: ~0.3 MPa)
_TISSUE_RANGES = (("c10", 0.0, False), ("c01", 0.0, True), ("kappa", 0.0, False))
MAX_MODULUS_MPA = {"c10": 1e4, "c01": 1e4, "kappa": 1e7}
MAX_SIGMA_MPA = 100.0


def _check_content(model: FaceModel) -> None:
    """The content check of every model (module docstring): one-line :class:`_FieldError` naming
    the field, what was expected and what was found. The structure (shapes, counts, index
    ranges) is checked before, so the indices here are safe to use."""
    X, tets = model.X, model.tets
    if not len(X):
        raise _FieldError("X", "expected at least one node, got none")
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise _FieldError("X", f"expected finite node coordinates (mm), {_some(bad, 'node')} are NaN or inf")
    far = np.abs(X).max(axis=1) > MAX_COORDINATE_MM
    if far.any():
        raise _FieldError("X", f"expected node coordinates within +-{MAX_COORDINATE_MM:g} mm of the origin, "
                               f"{_some(far, 'node')} are further (up to {np.abs(X).max():.3g} mm)")
    extent = float(np.linalg.norm(np.ptp(X, axis=0)))
    if not EXTENT_MM[0] <= extent <= EXTENT_MM[1]:
        raise _FieldError("X", f"the model spans {extent:.3g} mm (bounding-box diagonal); expected a face in mm, "
                               f"{EXTENT_MM[0]:g} to {EXTENT_MM[1]:g} mm (a model stored in m or cm?)")
    if not len(tets):
        raise _FieldError("tets", "expected at least one tet, got none")
    volume = signed_volumes(X, tets)
    bad = ~(volume > 0)
    if (volume < 0).all():
        raise _FieldError("tets", f"expected positively oriented tets (rest volume > 0), every one of the "
                                  f"{len(tets):,} tets is inverted (stored in the other orientation: swap two "
                                  f"columns, e.g. facesim.model.positively_oriented)")
    if bad.any():
        raise _FieldError("tets", f"expected positive rest volumes, {_some(bad, 'tet')} are inverted or flat "
                                  f"(volume {volume[np.argmax(bad)]:.3g} mm^3)")
    if not len(model.skin):
        raise _FieldError("skin", "expected at least one skin triangle, got none")
    if not model.simulated.any():
        raise _FieldError("simulated", f"expected at least one simulated tet, got none of {len(tets):,}")
    if not len(model.cranium_nodes):
        raise _FieldError("cranium_nodes", "expected at least one node attached to the cranium (the flesh "
                                           "needs a fixed boundary), got none")
    if not len(model.jaw_nodes):
        raise _FieldError("jaw_nodes", "expected at least one node attached to the mandible (else the jaw "
                                       "controls move nothing), got none")
    still = np.flatnonzero(~model.simulated)
    loose = ~np.isin(tets[still], model.cranium_nodes).all(axis=1)
    if loose.any():
        raise _FieldError("simulated", f"expected the nodes of every non-simulated tet in cranium_nodes (those tets "
                                       f"move with the cranium), {_some(loose, 'tet', 'non-simulated tets', still)} "
                                       f"have free nodes")
    for i, t in enumerate(model.tissues):
        for name, low, closed in _TISSUE_RANGES:
            v = getattr(t, name)
            ok = isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and np.isfinite(v) and \
                (v >= low if closed else v > low) and v <= MAX_MODULUS_MPA[name]
            if not ok:
                raise _FieldError(f"tissues[{i}].{name}", f"expected {name} {'>=' if closed else '>'} {low:g} MPa, "
                                                          f"<= {MAX_MODULUS_MPA[name]:g} MPa and finite for tissue "
                                                          f"{t.name!r}, got {_num(v)}")
    mus = model.muscles
    bad = ~(np.isfinite(mus.sigma_max) & (mus.sigma_max >= 0) & (mus.sigma_max <= MAX_SIGMA_MPA))
    if bad.any():
        j = int(np.argmax(bad))
        raise _FieldError("muscles.sigma_max", f"expected finite peak stresses 0 <= sigma_max <= {MAX_SIGMA_MPA:g} "
                                               f"MPa, {_some(bad, 'muscle')} are not ({mus.names[j]!r}: "
                                               f"{_num(mus.sigma_max[j])})")
    bad = ~((mus.fraction > 0) & (mus.fraction <= 1 + 1e-9))
    if bad.any():
        raise _FieldError("muscles.fraction", f"expected volume fractions in (0, 1], {_some(bad, 'entry', 'entries')} "
                                              f"are not ({_num(mus.fraction[np.argmax(bad)])})")
    norm = np.linalg.norm(mus.fibre, axis=1)
    bad = ~(np.abs(norm - 1.0) <= 1e-6)
    if bad.any():
        raise _FieldError("muscles.fibre", f"expected unit fibre directions, {_some(bad, 'entry', 'entries')} are "
                                           f"zero, not finite or not of length 1 (length {_num(norm[np.argmax(bad)])})")
    mk = model.markers
    bad = ~((mk.bary >= -1e-9).all(axis=1) & (np.abs(mk.bary.sum(axis=1) - 1.0) <= 1e-9))
    if bad.any():
        raise _FieldError("markers.bary", f"expected finite non-negative barycentric coordinates summing to 1, "
                                          f"{_some(bad, 'marker')} are not")
    bad = ~np.isfinite(mk.offset)
    if bad.any():
        raise _FieldError("markers.offset", f"expected finite marker heights (mm), {_some(bad, 'marker')} are "
                                            f"NaN or inf")
    far = np.abs(mk.offset) > MAX_MARKER_HEIGHT_MM
    if far.any():
        raise _FieldError("markers.offset", f"expected marker heights within +-{MAX_MARKER_HEIGHT_MM:g} mm of the "
                                            f"skin, {_some(far, 'marker')} are further")
    for s in model.bones + model.colliders:
        bad = ~np.isfinite(s.vertices).all(axis=1)
        if bad.any():
            raise _FieldError(f"{s.name}.vertices", f"expected finite vertex coordinates (mm), "
                                                    f"{_some(bad, 'vertex', 'vertices')} are NaN or inf")
        if len(s.faces) < 4:   # a closed surface has at least a tetrahedron's four triangles
            raise _FieldError(f"{s.name}.faces", f"expected a closed surface of at least 4 triangles, got "
                                                 f"{len(s.faces)}")
        far = np.abs(s.vertices).max(axis=1, initial=0.0) > MAX_COORDINATE_MM
        if far.any():
            raise _FieldError(f"{s.name}.vertices", f"expected vertex coordinates within +-{MAX_COORDINATE_MM:g} mm "
                                                    f"of the origin, {_some(far, 'vertex', 'vertices')} are further")


# --------------------------------------------------------------------- format
def _surfaces_to_arrays(prefix: str, surfaces) -> tuple[dict, list]:
    arrays, meta = {}, []
    for i, s in enumerate(surfaces):
        arrays[f"{prefix}{i}_vertices"] = s.vertices
        arrays[f"{prefix}{i}_faces"] = s.faces
        meta.append({"name": s.name, "bone": s.bone})
    return arrays, meta


def _to_arrays(model: FaceModel) -> tuple[dict[str, np.ndarray], dict]:
    arrays = {
        "X": model.X,
        "tets": model.tets,
        "tissue": model.tissue.astype(np.int8 if len(model.tissues) < 128 else np.int32),
        "simulated": model.simulated,
        "cranium_nodes": model.cranium_nodes,
        "jaw_nodes": model.jaw_nodes,
        "skin": model.skin,
        "lip_upper": model.lip_upper,
        "lip_lower": model.lip_lower,
        "muscle_sigma_max": model.muscles.sigma_max,
        "muscle_entry_muscle": model.muscles.muscle.astype(np.int16),
        "muscle_entry_tet": model.muscles.tet,
        "muscle_entry_fraction": model.muscles.fraction.astype(np.float32),
        "muscle_entry_fibre": model.muscles.fibre.astype(np.float32),
        "marker_triangle": model.markers.triangle,
        "marker_bary": model.markers.bary,
        "marker_offset": model.markers.offset,
        "marker_head": model.markers.head,
        "jaw_condyle_right": model.jaw.condyle_right,
        "jaw_condyle_left": model.jaw.condyle_left,
        "jaw_track_direction": model.jaw.track_direction,
        "jaw_incisor": model.jaw.incisor,
    }
    bone_arrays, bone_meta = _surfaces_to_arrays("bone", model.bones)
    coll_arrays, coll_meta = _surfaces_to_arrays("collider", model.colliders)
    arrays.update(bone_arrays)
    arrays.update(coll_arrays)
    meta = {
        "tissues": [dataclasses.asdict(t) for t in model.tissues],
        "muscle_names": list(model.muscles.names),
        "muscle_sides": list(model.muscles.sides),
        "marker_names": list(model.markers.names),
        "bones": bone_meta,
        "colliders": coll_meta,
        "jaw_track_length": model.jaw.track_length,
        "jaw_max_opening": model.jaw.max_opening,
        "build": model.meta,
    }
    return arrays, meta


#: stored index arrays (and ``bone{i}_faces``, ``collider{i}_faces``): integers in the file
_INDEX_KEYS = frozenset(("tets", "tissue", "cranium_nodes", "jaw_nodes", "skin", "lip_upper", "lip_lower",
                         "muscle_entry_muscle", "muscle_entry_tet", "marker_triangle"))
_MASK_KEYS = frozenset(("simulated", "marker_head"))
#: model field (as a :class:`_FieldError` names it) -> its key in the file, where they differ
_FILE_KEYS = {"muscles.sigma_max": "muscle_sigma_max", "muscles.muscle": "muscle_entry_muscle",
              "muscles.tet": "muscle_entry_tet", "muscles.fraction": "muscle_entry_fraction",
              "muscles.fibre": "muscle_entry_fibre", "markers.triangle": "marker_triangle",
              "markers.bary": "marker_bary", "markers.offset": "marker_offset", "markers.head": "marker_head",
              "jaw.track_length": "meta.jaw_track_length", "jaw.max_opening": "meta.jaw_max_opening"}


def _stored(path, key: str, a: np.ndarray) -> np.ndarray:
    """``a`` if the file stores field ``key`` with the right kind of dtype, checked before any cast
    can hide it (a float index array would be truncated): integers for indices, bools for masks,
    real numbers for the rest."""
    if key in _INDEX_KEYS or key.endswith("_faces"):
        kinds, what = "iu", "integer indices"
    elif key in _MASK_KEYS:
        kinds, what = "b", "a bool mask"
    else:
        kinds, what = "fiu", "real numbers"
    if a.dtype.kind not in kinds:
        raise ModelFileError(path, f"field {key!r}: expected {what}, stored as dtype {a.dtype}")
    return a


def load_model(path) -> FaceModel:
    """Read a :class:`FaceModel` from a ``.npz`` written by :meth:`FaceModel.save`.

    Raises :class:`~facesim.errors.ModelFileError` (one line: file, field, expectation) when the
    file is missing, not an npz, not a facesim model, of an unknown version, lacks a field, stores
    a field with the wrong kind of dtype (e.g. float tets), or fails the content check of every
    model (module docstring), e.g. ``M.npz: field 'X': expected finite node coordinates (mm),
    3 of 5,123 nodes (first: node 17) are NaN or inf``; also for the few unreadable files the
    npz reader lets through (a .npy renamed .npz, corrupt compressed data).
    """
    import zipfile
    import zlib

    try:
        return _load_model(path)
    except FacesimError:
        raise
    except (TypeError, AttributeError, ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ModelFileError(path, f"not a readable facesim model ({type(exc).__name__}: {exc})") from None


def _load_model(path) -> FaceModel:
    """:func:`load_model` without the catch-all for unreadable files."""
    with read_npz(path, MODEL_FORMAT) as archive:
        m = archive.field

        def arr(key: str) -> np.ndarray:
            return _stored(archive.path, key, archive.array(key))

        def surfaces(prefix: str, key: str) -> tuple[RigidSurface, ...]:
            return tuple(RigidSurface(s["name"], s["bone"], arr(f"{prefix}{i}_vertices"), arr(f"{prefix}{i}_faces"))
                         for i, s in enumerate(m(key)))

        try:
            return FaceModel(
                X=arr("X"),
                tets=arr("tets"),
                tissue=arr("tissue"),
                tissues=tuple(Tissue(**t) for t in m("tissues")),
                simulated=arr("simulated"),
                muscles=MuscleSet(
                    names=tuple(m("muscle_names")),
                    sides=tuple(m("muscle_sides")),
                    sigma_max=arr("muscle_sigma_max"),
                    muscle=arr("muscle_entry_muscle"),
                    tet=arr("muscle_entry_tet"),
                    fraction=arr("muscle_entry_fraction"),
                    fibre=_renormalise(arr("muscle_entry_fibre")),
                ),
                cranium_nodes=arr("cranium_nodes"),
                jaw_nodes=arr("jaw_nodes"),
                skin=arr("skin"),
                lip_upper=arr("lip_upper"),
                lip_lower=arr("lip_lower"),
                bones=surfaces("bone", "bones"),
                colliders=surfaces("collider", "colliders"),
                markers=MarkerSet(
                    names=tuple(m("marker_names")),
                    triangle=arr("marker_triangle"),
                    bary=arr("marker_bary"),
                    offset=arr("marker_offset"),
                    head=arr("marker_head"),
                ),
                jaw=JawGeometry(
                    condyle_right=arr("jaw_condyle_right"),
                    condyle_left=arr("jaw_condyle_left"),
                    track_direction=arr("jaw_track_direction"),
                    track_length=m("jaw_track_length"),
                    max_opening=m("jaw_max_opening"),
                    incisor=arr("jaw_incisor"),
                ),
                meta=m("build"),
            )
        except ModelFileError:
            raise
        except _FieldError as exc:
            key = _file_key(exc.field, archive.meta)
            raise ModelFileError(archive.path, f"field {key!r}: {exc.expected}") from None
        except (FacesimError, KeyError, TypeError, ValueError) as exc:
            raise ModelFileError(archive.path, f"inconsistent model data: {exc}") from None


def _file_key(field: str, meta: dict) -> str:
    """The key in the file of the model field ``field`` (as a :class:`_FieldError` names it)."""
    if field in _FILE_KEYS:
        return _FILE_KEYS[field]
    if field.startswith("jaw."):
        return "jaw_" + field[len("jaw."):]
    if field.startswith("tissues["):
        return "meta." + field
    name, _, part = field.rpartition(".")
    for prefix, key in (("bone", "bones"), ("collider", "colliders")):
        for i, s in enumerate(meta.get(key, ())):
            if isinstance(s, dict) and s.get("name") == name:
                return f"{prefix}{i}_{part}"
    return field


def _renormalise(v: np.ndarray) -> np.ndarray:
    """Fibres are stored as float32; restore exact unit length in float64. Only the float32
    rounding is undone: a zero, non-finite or otherwise non-unit stored fibre is kept as stored,
    for the content check to refuse (dividing would turn a zero fibre into NaN)."""
    v = np.array(v, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        return v.reshape(0, 3) if not v.size else v
    n = np.linalg.norm(v, axis=1)
    rounding = np.abs(n - 1.0) <= 1e-6
    v[rounding] /= n[rounding, None]
    return v
