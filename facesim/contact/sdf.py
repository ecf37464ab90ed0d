"""Rigid colliders as signed distance functions (SDFs): mm, negative inside.

Shapes are defined in their own local frame: :class:`Sphere`, :class:`Plane`, :class:`Capsule`
(closed forms) and :class:`MeshSDF` (a precomputed grid of a closed triangle mesh, evaluated as a
cubic B-spline, or trilinearly). A :class:`Collider` places a shape with a rigid pose ``T (4, 4)`` (local ->
world), so it can follow a bone or be scripted in time; :class:`KinematicPath` is a collider
moved by one pose per frame.

Every shape and collider evaluates points ``p (k, 3)`` (mm) with ``distance(p) -> (k,)`` mm,
``gradient(p) -> (k, 3)`` (unit length wherever the distance is smooth), ``hessian(p) ->
(k, 3, 3)`` (1/mm) and ``evaluate(p, hessian=False) -> (d, G, H or None)`` in one pass.
Derivatives are those of the function actually evaluated (for the mesh, of the interpolant),
so finite differences agree with them.
"""

from __future__ import annotations

import time

import numpy as np

from facesim._csv import frame_numbers, numbers, read_table
from facesim._kernels import contact as K
from facesim.errors import FacesimError
from facesim.se3 import interpolate_rigid

_RIGID_TOL = 1e-6


def _vector(v, name: str) -> np.ndarray:
    v = np.array(v, dtype=np.float64)   # a copy: shapes never alias the caller's arrays
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise FacesimError(f"{name}: expected 3 finite numbers, got {v.tolist()!r}")
    return v


def _positive(v, name: str) -> float:
    v = float(v)
    if not (np.isfinite(v) and v > 0):
        raise FacesimError(f"{name}: expected a positive number (mm), got {v}")
    return v


def _points(p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 1 and p.shape == (3,):
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise FacesimError(f"points: expected shape (k, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise FacesimError("points: expected finite coordinates (mm), got NaN or inf")
    return np.ascontiguousarray(p)


def rigid_transform(T, name: str = "transform") -> np.ndarray:
    """A validated copy of ``T`` as a ``(4, 4) float64`` rigid transform (rotation + translation, mm)."""
    T = np.array(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise FacesimError(f"{name}: expected a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if (np.abs(R.T @ R - np.eye(3)).max() > _RIGID_TOL or np.linalg.det(R) < 0
            or np.abs(T[3] - [0, 0, 0, 1]).max() > _RIGID_TOL):
        raise FacesimError(f"{name}: expected a rigid transform (rotation, translation, last row 0 0 0 1); "
                           "a signed distance does not survive scaling or shear")
    return T


def translation(v) -> np.ndarray:
    """``(4, 4)`` transform translating by ``v (3,)`` mm."""
    T = np.eye(4)
    T[:3, 3] = _vector(v, "translation")
    return T


_IDENTITY = np.eye(4)


class _Evaluated:
    """``distance``, ``gradient`` and ``hessian`` from one ``evaluate(p, hessian)``."""

    def evaluate(self, p, hessian: bool = False):   # pragma: no cover - abstract
        raise NotImplementedError

    def distance(self, p) -> np.ndarray:
        """Signed distance ``(k,)`` mm of points ``p (k, 3)`` mm; negative inside."""
        return self.evaluate(p)[0]

    def gradient(self, p) -> np.ndarray:
        """``(k, 3)`` gradient of the signed distance (outward unit normal direction)."""
        return self.evaluate(p)[1]

    def hessian(self, p) -> np.ndarray:
        """``(k, 3, 3)`` Hessian of the signed distance, 1/mm."""
        return self.evaluate(p, True)[2]


class SDF(_Evaluated):
    """A signed distance in its local frame. Subclasses implement :meth:`_kernel`."""

    def _kernel(self, P, R, t, d, G, H, want_h) -> None:   # pragma: no cover - abstract
        raise NotImplementedError

    def _evaluate(self, p, T, want_h: bool):
        P = _points(p)
        k = len(P)
        d, G = np.empty(k), np.empty((k, 3))
        H = np.empty((k, 3, 3) if want_h else (0, 3, 3))
        R = np.ascontiguousarray(T[:3, :3])
        t = np.ascontiguousarray(T[:3, 3])
        self._kernel(P, R, t, d, G, H, bool(want_h))
        return d, G, (H if want_h else None)

    def evaluate(self, p, hessian: bool = False):
        """``(d (k,) mm, G (k, 3), H (k, 3, 3) 1/mm or None)`` at points ``p (k, 3)`` mm."""
        return self._evaluate(p, _IDENTITY, hessian)

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """A triangle mesh of the zero level set for drawing: ``(vertices (nv, 3) mm, faces (nf, 3))``
        in the local frame."""
        raise NotImplementedError   # pragma: no cover - abstract


class Sphere(SDF):
    """Ball of ``radius`` mm around ``centre (3,)`` mm: ``d = |p - c| - r``."""

    def __init__(self, centre, radius: float):
        self.centre = _vector(centre, "sphere centre")
        self.radius = _positive(radius, "sphere radius")

    def _kernel(self, P, R, t, d, G, H, want_h):
        K.sphere_sdf(P, R, t, self.centre, self.radius, d, G, H, want_h)

    def surface(self):
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=3, radius=self.radius)
        return np.asarray(m.vertices) + self.centre, np.asarray(m.faces)

    def __repr__(self):
        return f"Sphere(centre={self.centre.tolist()}, radius={self.radius})"


class Plane(SDF):
    """Half-space behind the plane through ``point (3,)`` mm; ``normal (3,)`` (normalised here)
    points to the outside: ``d = n . (p - point)``."""

    def __init__(self, point, normal):
        self.point = _vector(point, "plane point")
        n = _vector(normal, "plane normal")
        norm = np.linalg.norm(n)
        if norm == 0:
            raise FacesimError("plane normal: expected a non-zero vector")
        self.normal = n / norm

    def _kernel(self, P, R, t, d, G, H, want_h):
        K.plane_sdf(P, R, t, self.point, self.normal, d, G, H, want_h)

    def surface(self, half_size: float = 60.0):
        """A square of ``2 half_size`` mm around ``point`` (a plane has no end)."""
        n = self.normal
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
        V = np.array([self.point + half_size * (a * e1 + b * e2) for a, b in corners])
        return V, np.array([[0, 1, 2], [0, 2, 3]])

    def __repr__(self):
        return f"Plane(point={self.point.tolist()}, normal={self.normal.tolist()})"


class Capsule(SDF):
    """Points within ``radius`` mm of the segment ``a (3,)`` - ``b (3,)`` mm (a sphere if a == b)."""

    def __init__(self, a, b, radius: float):
        self.a = _vector(a, "capsule a")
        self.b = _vector(b, "capsule b")
        self.radius = _positive(radius, "capsule radius")

    def _kernel(self, P, R, t, d, G, H, want_h):
        K.capsule_sdf(P, R, t, self.a, self.b, self.radius, d, G, H, want_h)

    def surface(self):
        import trimesh

        axis = self.b - self.a
        length = float(np.linalg.norm(axis))
        m = trimesh.creation.capsule(height=length, radius=self.radius, count=[24, 24])   # along z, centred
        V = np.asarray(m.vertices, dtype=np.float64)
        if length > 0:
            R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / length)[:3, :3]
            V = V @ R.T
        return V + 0.5 * (self.a + self.b), np.asarray(m.faces)

    def __repr__(self):
        return f"Capsule(a={self.a.tolist()}, b={self.b.tolist()}, radius={self.radius})"


class MeshSDF(SDF):
    """Signed distance of a closed triangle mesh, sampled on a regular grid.

    ``origin (3,)`` mm is grid node (0, 0, 0), ``spacing`` mm the node spacing, ``values (nx, ny,
    nz)`` mm the signed distances at the nodes (every n >= 2). ``interpolation``:

    - ``"cubic"`` (default): the cubic B-spline with the values as its coefficients
      (:func:`facesim._kernels.contact.grid_sdf_cubic`). C2: value, gradient and Hessian are
      continuous, so a penalty on it is a smooth energy that Newton can solve to any tolerance.
      It approximates: a surface of radius r moves by about ``spacing^2 / (3 r)`` (0.02 mm on a
      15 mm sphere at 1 mm) and the kinks of the distance (its medial axis, e.g. mid-way inside a
      tooth) are rounded by a fraction of a cell; no overshoot.
    - ``"linear"``: trilinear interpolation, exact at the nodes but C0: the gradient jumps across
      every cell face. A contact node whose equilibrium lies on a face (its force flips with the
      side) has no point where the residual vanishes: on the shipped face, lip nodes pressed on
      the incisal edge of the teeth held Newton at 0.4-3 N (vs tolerances of ~1e-5 N) for 100-200
      iterations (examples/02_jaw_and_contact.py, frames 14-29).

    Value, gradient and Hessian are those of the function evaluated. Outside the grid box the
    distance is the value at the nearest box point plus the distance to the box.
    Build from a mesh with :meth:`from_mesh`.
    """

    INTERPOLATIONS = ("cubic", "linear")

    def __init__(self, origin, spacing: float, values, interpolation: str = "cubic"):
        if interpolation not in self.INTERPOLATIONS:
            raise FacesimError(f"grid interpolation: expected one of {', '.join(self.INTERPOLATIONS)}, "
                               f"got {interpolation!r}")
        self.interpolation = interpolation
        self.origin = _vector(origin, "grid origin")
        self.spacing = _positive(spacing, "grid spacing")
        v = np.ascontiguousarray(values, dtype=np.float64)
        if v.ndim != 3 or min(v.shape) < 2 or not np.all(np.isfinite(v)):
            raise FacesimError(f"grid values: expected finite (nx, ny, nz) with every n >= 2, got {v.shape}")
        self.values = v
        self.build_seconds = 0.0
        self.mesh = None   # (vertices, faces) of the source mesh, kept by from_mesh for drawing

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.values.shape

    @property
    def bounds(self) -> np.ndarray:
        """``(2, 3)`` lower and upper corners of the grid box, mm."""
        return np.stack([self.origin, self.origin + self.spacing * (np.array(self.shape) - 1)])

    @classmethod
    def from_mesh(cls, vertices, faces, spacing: float = 1.0, margin: float = 5.0, band: float | None = None,
                  name: str = "mesh", interpolation: str = "cubic") -> MeshSDF:
        """Sample the signed distance of the closed mesh ``vertices (nv, 3)`` mm, ``faces (nf, 3)``
        int on a grid of ``spacing`` mm covering its bounding box plus ``margin`` mm.

        Distances are exact at grid nodes within ``band`` mm (default two cells) of the surface;
        beyond, fast sweeping passes the nearest triangle on from node to node (after Bridson's
        makelevelset3), giving exact distances to candidate triangles (upper bounds, within
        0.06 mm of exact on spheres at 1 mm spacing). The sign
        comes from the parity of ray crossings, so the orientation of the faces does not
        matter but the mesh must be closed (every edge shared by two faces). ``interpolation``: see
        the class.
        """
        t0 = time.perf_counter()
        V = np.ascontiguousarray(vertices, dtype=np.float64)
        F = np.ascontiguousarray(faces, dtype=np.int64)
        spacing = _positive(spacing, f"{name}: spacing")
        margin = float(margin)
        if not (np.isfinite(margin) and margin >= 0):
            raise FacesimError(f"{name}: margin must be a number >= 0 (mm), got {margin}")
        if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4 or not np.all(np.isfinite(V)):
            raise FacesimError(f"{name}: vertices: expected finite (nv, 3) with nv >= 4, got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or len(F) < 4:
            raise FacesimError(f"{name}: faces: expected (nf, 3) with nf >= 4, got {F.shape}")
        if F.min() < 0 or F.max() >= len(V):
            raise FacesimError(f"{name}: faces: vertex indices must lie in [0, {len(V)})")
        edges = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        if np.any(counts != 2):
            raise FacesimError(f"{name}: not a closed surface ({int((counts != 2).sum())} edges not shared by "
                               "exactly two faces); a mesh SDF needs an inside")
        band = 2.0 * spacing if band is None else _positive(band, f"{name}: band")
        lo = V.min(axis=0) - margin
        shape = np.ceil((V.max(axis=0) + margin - lo) / spacing).astype(np.int64) + 1
        shape = np.maximum(shape, 2)
        if np.prod(shape) > 32e6:
            raise FacesimError(f"{name}: a {shape[0]}x{shape[1]}x{shape[2]} grid is too large; "
                               "use a coarser spacing or a smaller margin")
        dist2 = np.full(tuple(shape), np.inf)
        tri = np.full(tuple(shape), -1, np.int32)
        K.band_distances(V, F, lo, spacing, band, dist2, tri)
        uncertain = dist2 > band * band   # the true nearest triangle's box may not reach these nodes
        dist2[uncertain] = np.inf
        tri[uncertain] = -1
        K.sweep_distances(V, F, lo, spacing, dist2, tri)
        inside = np.zeros(tuple(shape), bool)
        # irrational fractions of a cell: vertical rays through mesh vertices or edges have measure zero
        eps = spacing * np.array([1e-6 * np.sqrt(2), 1e-6 * np.sqrt(3)])
        K.inside_by_parity(V, F, lo, spacing, shape, eps, inside)
        values = np.sqrt(dist2)
        values[inside] *= -1.0
        sdf = cls(lo, spacing, values, interpolation)
        sdf.build_seconds = time.perf_counter() - t0
        sdf.mesh = (V, F)
        return sdf

    def surface(self):
        """The source mesh, or the zero level set of the grid (marching cubes) without one."""
        if self.mesh is not None:
            return self.mesh
        import pyvista as pv

        grid = pv.ImageData(dimensions=self.shape, spacing=(self.spacing,) * 3, origin=self.origin)
        grid.point_data["d"] = self.values.ravel(order="F")
        iso = grid.contour([0.0], scalars="d").triangulate()
        return np.asarray(iso.points, dtype=np.float64), np.asarray(iso.faces).reshape(-1, 4)[:, 1:]

    def _kernel(self, P, R, t, d, G, H, want_h):
        kernel = K.grid_sdf_cubic if self.interpolation == "cubic" else K.grid_sdf
        kernel(P, R, t, self.origin, self.spacing, self.values, d, G, H, want_h)

    def __repr__(self):
        return (f"MeshSDF(origin={self.origin.tolist()}, spacing={self.spacing}, shape={self.shape}, "
                f"interpolation={self.interpolation!r})")


class Collider(_Evaluated):
    """A shape ``sdf`` placed in the world by the rigid transform ``transform (4, 4)`` (local ->
    world, mm): ``d(p) = sdf.d(R^T (p - t))``. Immutable; :meth:`at` and :meth:`moved_by`
    return moved copies."""

    def __init__(self, sdf: SDF, transform=None, name: str = ""):
        if not isinstance(sdf, SDF):
            raise FacesimError(f"collider {name!r}: expected a Sphere, Plane, Capsule or MeshSDF, got "
                               f"{type(sdf).__name__}")
        self.sdf = sdf
        self.transform = rigid_transform(np.eye(4) if transform is None else transform,
                                         f"collider {name!r} transform" if name else "collider transform")
        self.transform.setflags(write=False)
        self.name = name

    def at(self, T) -> Collider:
        """A copy whose pose is ``T (4, 4)`` (absolute: local -> world)."""
        return Collider(self.sdf, T, self.name)

    def moved_by(self, T) -> Collider:
        """A copy moved by ``T (4, 4)`` in the world: pose ``T @ transform`` (e.g. a bone's motion
        from its rest pose)."""
        return Collider(self.sdf, rigid_transform(T) @ self.transform, self.name)

    def evaluate(self, p, hessian: bool = False):
        """``(d (k,) mm, G (k, 3), H (k, 3, 3) 1/mm or None)`` at world points ``p (k, 3)`` mm (world
        gradient and Hessian)."""
        return self.sdf._evaluate(p, self.transform, hessian)

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (nv, 3), faces (nf, 3))`` of the shape's surface in the world (mm), for drawing."""
        V, F = self.sdf.surface()
        return V @ self.transform[:3, :3].T + self.transform[:3, 3], F

    def __repr__(self):
        return f"Collider({self.sdf!r}, t={self.transform[:3, 3].tolist()}{', ' + self.name if self.name else ''})"


def as_collider(c) -> Collider:
    """A :class:`Collider` from a collider or a bare shape (identity pose)."""
    if isinstance(c, Collider):
        return c
    if isinstance(c, SDF):
        return Collider(c)
    raise FacesimError(f"collider: expected a Collider or a shape (Sphere, Plane, Capsule, MeshSDF), "
                       f"got {type(c).__name__}")


class KinematicPath:
    """A collider scripted in time: pose ``transforms[i] (4, 4)`` at frame ``frames[i]``.

    Between listed frames the translation is interpolated linearly and the rotation by slerp;
    before the first and after the last listed frame the collider holds that pose.
    """

    def __init__(self, collider, frames, transforms):
        self.collider = as_collider(collider)
        self.frames = np.asarray(frames, dtype=np.int64).ravel()
        T = np.asarray(transforms, dtype=np.float64)
        if T.shape != (len(self.frames), 4, 4) or len(self.frames) == 0:
            raise FacesimError(f"kinematic path: expected one 4x4 transform per frame ({len(self.frames)}), "
                               f"got shape {T.shape}")
        if np.any(np.diff(self.frames) <= 0):
            raise FacesimError("kinematic path: frames must be strictly increasing")
        for i, Ti in enumerate(T):
            rigid_transform(Ti, f"kinematic path: transform of frame {self.frames[i]}")
        self.transforms = T

    @classmethod
    def from_centres(cls, collider, frames, centres) -> KinematicPath:
        """Path that moves the collider's local origin to ``centres (f, 3)`` mm at ``frames (f,)``,
        keeping its rotation."""
        collider = as_collider(collider)
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 3:
            raise FacesimError(f"kinematic path: expected centres of shape (f, 3), got {c.shape}")
        T = np.repeat(collider.transform[None], len(c), axis=0)
        T[:, :3, 3] = c
        return cls(collider, frames, T)

    @classmethod
    def from_csv(cls, path, collider) -> KinematicPath:
        """Path from a CSV file with columns ``frame,x,y,z`` (mm): the position of the collider's
        local origin (a sphere's centre when it is defined around 0) at each frame."""
        table = read_table(path, "collider path file", example="frame,x,y,z")
        missing = [c for c in ("x", "y", "z") if c not in table.header]
        if missing:
            raise FacesimError(f"{table.path}: line {table.header_line}: missing column(s) {', '.join(missing)}; "
                               "expected a header like 'frame,x,y,z'")
        unknown = [c for c in table.header[1:] if c not in ("x", "y", "z")]
        if unknown:   # a rotation or a second object the path cannot hold: refused, not ignored
            raise FacesimError(f"{table.path}: line {table.header_line}: unknown column {unknown[0]!r}; expected "
                               "exactly 'frame,x,y,z' (mm)")
        return cls.from_centres(collider, frame_numbers(table), numbers(table, ("x", "y", "z")))

    def transform_at(self, frame: float) -> np.ndarray:
        """``(4, 4)`` pose at ``frame`` (may be fractional)."""
        f = float(frame)
        i = int(np.searchsorted(self.frames, f, side="right")) - 1
        if i < 0:
            return self.transforms[0].copy()
        if i >= len(self.frames) - 1 or f == self.frames[i]:
            return self.transforms[i].copy()
        s = (f - self.frames[i]) / (self.frames[i + 1] - self.frames[i])
        return interpolate_rigid(self.transforms[i], self.transforms[i + 1], s)

    def at_frame(self, frame: float) -> Collider:
        """The collider posed at ``frame``."""
        return self.collider.at(self.transform_at(frame))

    def __len__(self):
        return len(self.frames)
