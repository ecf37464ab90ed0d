"""External colliders of a simulation: what they are, how they move, and the ``--collider`` syntax.

A :class:`SceneCollider` is a shape with its motion: fixed in the world, scripted in time (a
:class:`~facesim.contact.KinematicPath`), or carried by a bone (its pose is then relative to the
cranium or the mandible and moves with it, e.g. a bite block held between the teeth).

Command-line specification (``facesim simulate --collider SPEC``, repeatable)::

    KIND:key=value,key=value,...

    sphere:radius=12,centre=55:-30:70            a ball fixed in the world (centre or path is required)
    sphere:radius=12,path=ball.csv               a ball whose centre follows frame,x,y,z rows
    capsule:radius=4,a=0:-40:90,b=0:-40:130      a rod (segment a-b, radius)
    plane:point=0:-70:0,normal=0:1:0             a half-space (normal points out of it)
    mesh:file=cup.stl,spacing=1,path=cup.csv     a closed triangle mesh (any format trimesh reads)

Vectors are ``x:y:z`` in mm (model frame); ``path`` is a CSV with ``frame,x,y,z`` moving the
shape's local origin; ``bone=world|cranium|jaw`` (default world) carries the collider with a
bone; ``name=`` labels it in reports. Relative file names are resolved against ``base``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facesim.contact.sdf import SDF, Capsule, Collider, KinematicPath, MeshSDF, Plane, Sphere, as_collider
from facesim.errors import FacesimError

BONES = ("world", "cranium", "jaw")
_KEYS = {
    "sphere": ({"radius"}, {"centre", "path", "bone", "name"}),
    "capsule": ({"radius", "a", "b"}, {"path", "bone", "name"}),
    "plane": ({"point", "normal"}, {"bone", "name"}),
    "mesh": ({"file"}, {"spacing", "path", "bone", "name", "scale"}),
}
_VECTORS = {"centre", "a", "b", "point", "normal"}
_NUMBERS = {"radius", "spacing", "scale"}
#: Positions and lengths beyond this (mm; 1 km) are refused as absurd: a collider is near the face.
MAX_MM = 1e6


@dataclass(frozen=True)
class SceneCollider:
    """A collider with its motion. ``shape``: a :class:`Collider` (its pose is fixed, or relative
    to ``bone``) or a :class:`KinematicPath` (posed per frame); ``bone``: ``"world"``,
    ``"cranium"`` or ``"jaw"``; ``name`` for reports."""

    shape: object
    bone: str = "world"
    name: str = ""

    def __post_init__(self):
        if self.bone not in BONES:
            raise FacesimError(f"collider {self.name!r}: bone must be one of {', '.join(BONES)}, got {self.bone!r}")
        if not isinstance(self.shape, KinematicPath):
            object.__setattr__(self, "shape", as_collider(self.shape))

    def at(self, frame: float, cranium=None, jaw=None) -> Collider:
        """The collider posed at ``frame`` with the bones at ``cranium``, ``jaw`` (4x4 world transforms)."""
        c = self.shape.at_frame(frame) if isinstance(self.shape, KinematicPath) else self.shape
        carrier = {"world": None, "cranium": cranium, "jaw": jaw}[self.bone]
        return c if carrier is None else c.moved_by(carrier)


def as_scene_collider(c, index: int = 0) -> SceneCollider:
    """A :class:`SceneCollider` from a scene collider, a collider, a bare shape or a kinematic path."""
    if isinstance(c, SceneCollider):
        return c
    if isinstance(c, (Collider, SDF, KinematicPath)):
        name = c.collider.name if isinstance(c, KinematicPath) else getattr(c, "name", "")
        return SceneCollider(c, "world", name or f"collider{index}")
    raise FacesimError(f"collider {index}: expected a Collider, a shape, a KinematicPath or a SceneCollider, got "
                       f"{type(c).__name__}")


def _vector(spec: str, key: str, value: str) -> np.ndarray:
    parts = value.split(":")
    try:
        v = np.array([float(p) for p in parts])
    except ValueError:
        v = None
    if v is None or v.shape != (3,) or not np.isfinite(v).all():
        raise FacesimError(f"collider {spec!r}: {key}={value!r}: expected three numbers x:y:z (mm)")
    if np.abs(v).max() > MAX_MM:
        raise FacesimError(f"collider {spec!r}: {key}={value!r}: expected coordinates within {MAX_MM:g} mm of the "
                           "origin (mm, model frame)")
    return v


def _number(spec: str, key: str, value: str) -> float:
    try:
        v = float(value)
    except ValueError:
        v = float("nan")
    if not (np.isfinite(v) and v > 0):
        raise FacesimError(f"collider {spec!r}: {key}={value!r}: expected a positive number")
    if key != "scale" and v > MAX_MM:
        raise FacesimError(f"collider {spec!r}: {key}={value!r}: expected at most {MAX_MM:g} mm")
    return v


def _file(spec: str, key: str, value: str, base) -> Path:
    p = Path(value)
    if not p.is_absolute() and base is not None:
        p = Path(base) / p
    if not p.is_file():
        raise FacesimError(f"collider {spec!r}: {key}={value!r}: no such file {p}")
    return p


def _check_mesh_size(spec: str, path: Path, V: np.ndarray, spacing: float) -> None:
    """Refuse a (scaled) mesh with coordinates that are not finite or beyond :data:`MAX_MM`, and a
    grid spacing coarser than the mesh (its distance field would be two cells wide)."""
    if not len(V) or not np.isfinite(V).all() or np.abs(V).max() > MAX_MM:
        raise FacesimError(f"collider {spec!r}: {path}: expected finite vertices within {MAX_MM:g} mm of the origin "
                           "(after scale), mm")
    size = float((V.max(axis=0) - V.min(axis=0)).max())
    if not spacing < size:
        raise FacesimError(f"collider {spec!r}: spacing={spacing:g}: expected a grid spacing below the mesh's size "
                           f"({size:.3g} mm)")


def parse_collider_spec(spec: str, base=None, index: int = 0) -> SceneCollider:
    """A :class:`SceneCollider` from ``KIND:key=value,...`` (see the module doc)."""
    kind, sep, rest = spec.partition(":")
    kind = kind.strip().lower()
    if kind not in _KEYS or not sep:
        raise FacesimError(f"collider {spec!r}: expected KIND:key=value,... with KIND one of "
                           f"{', '.join(_KEYS)} (e.g. sphere:radius=12,path=ball.csv)")
    required, optional = _KEYS[kind]
    raw = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip().lower()
        if not eq or key not in required | optional:
            raise FacesimError(f"collider {spec!r}: unknown or malformed entry {item!r}; {kind} takes "
                               f"{', '.join(sorted(required))} and optionally {', '.join(sorted(optional))}")
        if key in raw:
            raise FacesimError(f"collider {spec!r}: {key} given twice")
        raw[key] = value.strip()
    missing = sorted(required - set(raw))
    if missing:
        raise FacesimError(f"collider {spec!r}: missing {', '.join(missing)}")
    v = {k: (_vector(spec, k, s) if k in _VECTORS else _number(spec, k, s) if k in _NUMBERS else s)
         for k, s in raw.items()}
    if kind == "sphere" and "centre" in v and "path" in v:
        raise FacesimError(f"collider {spec!r}: give either centre or path, not both")
    if kind == "sphere":
        shape = Sphere(v.get("centre", np.zeros(3)) if "path" not in v else np.zeros(3), v["radius"])
    elif kind == "capsule":
        shape = Capsule(v["a"], v["b"], v["radius"])
    elif kind == "plane":
        shape = Plane(v["point"], v["normal"])
    else:
        import trimesh

        path = _file(spec, "file", v["file"], base)
        try:
            # the file's own connectivity first: merging coincident vertices would pinch a closed surface
            # whose sheets touch at a point (the model's teeth and cranium, written by model export --surfaces)
            mesh = trimesh.load(path, force="mesh", process=False)
            if not mesh.is_watertight:   # a triangle soup (STL): weld its corners
                mesh.merge_vertices()
        except Exception as exc:   # trimesh raises many types for unreadable files
            raise FacesimError(f"collider {spec!r}: {path}: cannot read a triangle mesh ({exc})") from None
        V = np.asarray(mesh.vertices, dtype=np.float64) * v.get("scale", 1.0)
        _check_mesh_size(spec, path, V, v.get("spacing", 1.0))
        shape = MeshSDF.from_mesh(V, np.asarray(mesh.faces), spacing=v.get("spacing", 1.0), name=str(path))
    name = v.get("name", f"{kind}{index}")
    collider = Collider(shape, name=name)
    if "path" in v:
        collider = KinematicPath.from_csv(_file(spec, "path", v["path"], base), collider)
    scene = SceneCollider(collider, v.get("bone", "world"), name)   # checks the bone first
    if kind == "sphere" and "centre" not in v and "path" not in v:
        # without a position the ball would sit at the origin, between the condyles inside the head
        raise FacesimError(f"collider {spec!r}: a sphere needs a position: centre=x:y:z (mm, model frame) or "
                           "path=FILE.csv (frame,x,y,z)")
    return scene


__all__ = ["SceneCollider", "as_scene_collider", "parse_collider_spec", "BONES"]
