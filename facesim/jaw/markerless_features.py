"""The feature points of the markerless jaw tracker (Zoss et al. 2019 section 5.1) on a face model.

Skin features are the skull-frame positions of ``P`` (~240) skin points found from the mandible:
a point of the mandible's surface inside a chin and jaw-line mask, then along the bone's outward
normal to the outer skin; each is stored as a skin triangle and barycentric weights, so it moves
with the skin mesh. Bone features are 5 points on the mandible itself (chin, left and right
body, left and right angle), whose rigid motion the regression predicts.

Correspondence across subjects
------------------------------
The paper assumes one mesh topology for every subject; facesim's models (procedural subjects of
other proportions, imported meshes) share none, so the points are defined on a chart of the
mandible's own shape, normalised by the subject's own dimensions, and feature ``p`` of every
subject is the same chart point ``(s_p, h_p)``:

1. **Frame.** The jaw frame of the model's TMJ (:meth:`facesim.jaw.frame.JawFrame.from_geometry`:
   origin at the lower incisal point, x along the intercondylar axis toward the subject's left,
   y up, z forward).
2. **Dimensions.** The extents of the lower mandible in the jaw frame: its lowest point
   ``y_min`` (the menton) sets the crest level ``y_cap = CREST_FRACTION * y_min`` (a quarter of
   the incisor-to-menton height below the incisal point, y = 0), and the mandible below that
   level (body, angles and the lower rami: no condyles, coronoids or crowns) its half-width
   ``W = (max x - min x) / 2``, its back ``O_z = min z`` and its depth ``D = max z - O_z`` (to the
   chin). The centre ``O`` lies on the midsagittal plane (x = 0: through the incisal point, normal
   to the intercondylar axis) at ``z = O_z``. Extremes along the frame's axes: they scale with
   the subject, and any mandible mesh (procedural, imported, with or without its teeth) has them.
3. **Around the arch: s.** In normalised coordinates ``x^ = (x - O_x) / W``, ``z^ = (z - O_z) / D``
   the arch is about a half circle of radius 1 whatever the subject's width and depth;
   ``s = atan2(x^, z^) / (pi / 2)`` runs from -1 at the right angle through 0 at the chin midline
   to +1 at the left angle. Chart column ``s`` is the vertical half-plane through O in the
   direction ``(W sin(s pi/2), 0, D cos(s pi/2))`` (jaw frame).
4. **Up the body: h.** In that half-plane the mandible's cross-section spans heights from its
   lowest point ``y_lo(s)`` (the lower border) to ``y_hi(s)``, its highest point but at most
   ``y_cap`` (the alveolar crest; a mandible meshed with its teeth has its crowns left out the
   same way, and the rami are cut at that level). ``h = (y - y_lo) / (y_hi - y_lo)``, 0 at the
   lower border, 1 at the crest.
5. **The point.** Chart point ``(s, h)`` is the outermost point of the cross-section at height
   ``y_lo + h (y_hi - y_lo)`` (the labial / buccal surface, farthest from O), an exact point of
   the mandible's surface. Its normal is the mandible's vertex normal smoothed over
   a few mm (a marching-cubes or coarse mesh has noisy facet normals).

The mask (chin and jaw line) and the grid are fixed in ``(s, h)``: columns ``s`` evenly spaced in
``[-S_MAX, S_MAX]`` (off the angles, which masseter and parotid cover), rows ``h`` evenly spaced
from ``H_MIN`` (just above the lower border) up to ``h_top(s)``: 0.70 under the chin (leaving out
the lower lip above the mentolabial sulcus, which expressions move most), rising smoothly to 0.90
along the body. Feature ``p = j * n_h + k`` is column ``j`` (right to left), row ``k`` (bottom to
top); feature ``mirror[p]`` is its mirror image (column ``n_s - 1 - j``). So an anisotropic
scaling of a head along the frame's axes maps every feature of the one onto the same feature of
the other exactly (the chart's coordinates are ratios of the subject's own extents), and on
subjects whose proportions differ otherwise (a longer jaw, thicker tissue) a feature lands on the
same anatomical place: the chin midline at ``s = 0``, the same fraction of the way up the body,
the mirror features mirrored across the symmetry plane.

The skin point of a bone point ``b`` with normal ``n`` is where the ray ``b + t n`` leaves the
flesh through the outer skin: the first crossing of ``model.skin`` outward (triangle normal along
``n``) that is not followed by a crossing back in within ``REENTRY_MM``. A procedural model's skin
is one closed surface including the mouth's lining (``facesim.anatomy.meshing.label_mesh``); a ray
through the lower lip's lining leaves the flesh into the vestibule and enters the lip again a
few mm on, so it is not the outer skin. An imported model's skin is the outer surface alone. A
ray leaving nowhere within ``MAX_DEPTH_MM`` (the neck below the angle, a skin open there) takes
the outer-skin point closest to its bone point instead; the layout counts those (``fallbacks``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facesim.errors import FacesimError
from facesim.jaw.frame import JawFrame

#: The layout's version, recorded in datasets and predictors: a predictor only reads features of
#: its own version.
LAYOUT_VERSION = 1
#: The skin mask in chart coordinates (module docstring).
S_MAX = 0.9
H_MIN = 0.1
H_TOP_CHIN, H_TOP_BODY = 0.70, 0.90
CHIN_HALF_WIDTH, BODY_FROM = 0.25, 0.55     # h_top rises between these |s|
#: The bone features: name and chart point (s, h); s > 0 is the subject's left.
BONE_FEATURES = (("chin", 0.0, 0.35), ("body_L", 0.5, 0.75), ("body_R", -0.5, 0.75),
                 ("angle_L", 0.9, 0.25), ("angle_R", -0.9, 0.25))
#: The crest is at most this fraction of the incisor-to-menton height below the incisal point.
CREST_FRACTION = 0.25
#: A crossing back into the flesh closer than this after leaving it (mm): the mouth's lining.
REENTRY_MM = 10.0
#: Soft tissue deeper than this along a bone normal (mm) is not the face's surface over the bone.
MAX_DEPTH_MM = 45.0
#: Normals are smoothed over vertices within this radius (mm, at least 1.5 mean edge lengths).
NORMAL_RADIUS_MM = 3.0


def h_top(s) -> np.ndarray:
    """The mask's upper edge ``h_top(s)`` (module docstring), C¹ in ``s``."""
    a = np.clip((np.abs(np.asarray(s, dtype=np.float64)) - CHIN_HALF_WIDTH) / (BODY_FROM - CHIN_HALF_WIDTH), 0, 1)
    return H_TOP_CHIN + (H_TOP_BODY - H_TOP_CHIN) * a * a * (3 - 2 * a)


def grid_shape(n_skin: int) -> tuple[int, int]:
    """``(n_s, n_h)`` columns and rows of the skin grid for about ``n_skin`` points (240: 30 x 8):
    columns about 4 times as many as rows (the mask is ~4 times longer around the arch than high
    in mm)."""
    if n_skin < 4:
        raise FacesimError(f"n_skin: expected at least 4 skin features, got {n_skin}")
    n_h = max(2, int(round(np.sqrt(n_skin / 3.75))))
    return max(2, int(round(n_skin / n_h))), n_h


def skin_grid(n_skin: int = 240) -> np.ndarray:
    """``(P, 2)`` chart coordinates ``(s, h)`` of the skin features, ``p = j * n_h + k``."""
    n_s, n_h = grid_shape(n_skin)
    s = np.linspace(-S_MAX, S_MAX, n_s)
    frac = np.linspace(0.0, 1.0, n_h)
    h = H_MIN + (h_top(s)[:, None] - H_MIN) * frac[None, :]
    return np.stack([np.repeat(s, n_h), h.ravel()], axis=1)


def mirror_index(n_skin: int = 240) -> np.ndarray:
    """``(P,)`` the index of each skin feature's mirror image (column ``n_s - 1 - j``)."""
    n_s, n_h = grid_shape(n_skin)
    j, k = np.divmod(np.arange(n_s * n_h), n_h)
    return (n_s - 1 - j) * n_h + k


# ------------------------------------------------------------------ the mandible chart
@dataclass(frozen=True)
class MandibleChart:
    """The chart ``(s, h)`` of one mandible (module docstring), in the skull frame (mm).

    frame : the jaw frame; centre : (2,) O's (x, z) in the jaw frame; width W, depth D : mm;
    crest_cap : the highest y (jaw frame) of a cross-section; landmarks : the extreme points that
    set them (lowest; left, right, back and front of the mandible below the crest; skull frame, mm).
    """

    frame: JawFrame
    centre: np.ndarray
    width: float
    depth: float
    crest_cap: float
    landmarks: dict
    vertices: np.ndarray = field(repr=False)   # (n, 3) jaw-frame coordinates of the mandible
    faces: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)    # (n, 3) jaw-frame vertex normals (trimesh's)

    @staticmethod
    def of(model) -> "MandibleChart":
        """The chart of ``model``'s mandible (its bone surfaces attached to the jaw) and TMJ."""
        surfaces = [s for s in model.bones if s.bone == "jaw"]
        if not surfaces:
            raise FacesimError("model.bones: no surface attached to the jaw (expected the mandible)")
        off = np.cumsum([0] + [len(s.vertices) for s in surfaces])
        V = np.concatenate([np.asarray(s.vertices, dtype=np.float64) for s in surfaces])
        F = np.concatenate([np.asarray(s.faces, dtype=np.int64) + o for s, o in zip(surfaces, off)])
        return MandibleChart.of_surface(V, F, model.jaw)

    @staticmethod
    def of_surface(V, F, geometry) -> "MandibleChart":
        """The chart of the mandible surface ``(V (n, 3) mm, F (m, 3))`` (skull frame) with the TMJ
        ``geometry`` (:class:`~facesim.model.JawGeometry`)."""
        import trimesh

        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        if len(V) < 4 or len(F) < 4:
            raise FacesimError(f"mandible: expected a closed surface, got {len(V)} vertices and {len(F)} triangles")
        frame = JawFrame.from_geometry(geometry)
        L = frame.to_local(V)
        y_min = float(L[:, 1].min())
        cap = CREST_FRACTION * y_min
        low = L[L[:, 1] <= cap]
        if not (y_min < -5.0 and len(low) >= 4):
            raise FacesimError(f"mandible: it reaches only {-y_min:.1f} mm below the lower incisal point; expected "
                               "a whole mandible below the incisor (is model.jaw the mandible's?)")
        lo, hi = low.min(axis=0), low.max(axis=0)
        centre = np.array([0.0, lo[2]])
        width, depth = 0.5 * (hi[0] - lo[0]), hi[2] - lo[2]
        if not (width > 5.0 and depth > 5.0):
            raise FacesimError(f"mandible: implausible proportions for the feature chart (half-width {width:.1f} mm, "
                               f"depth {depth:.1f} mm below the crest)")
        N = np.asarray(trimesh.Trimesh(L, F, process=False).vertex_normals, dtype=np.float64)
        extents = {"lowest": frame.to_world(L[np.argmin(L[:, 1])]),
                   "left": frame.to_world(low[np.argmax(low[:, 0])]), "right": frame.to_world(low[np.argmin(low[:, 0])]),
                   "back": frame.to_world(low[np.argmin(low[:, 2])]), "front": frame.to_world(low[np.argmax(low[:, 2])])}
        return MandibleChart(frame, centre, float(width), float(depth), float(cap), extents, L, F, N)

    # -------------------------------------------------------------- chart -> surface
    def direction(self, s) -> np.ndarray:
        """``(k, 3)`` unit horizontal directions (jaw frame) of the chart columns ``s (k,)``."""
        phi = 0.5 * np.pi * np.asarray(s, dtype=np.float64)
        d = np.stack([self.width * np.sin(phi), np.zeros_like(phi), self.depth * np.cos(phi)], axis=1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def section(self, s: float) -> np.ndarray:
        """``(k, 2, 2)`` the mandible's cross-section in chart column ``s``: segments in ``(r, y)``
        (r: distance from the vertical axis through O along the column's direction, mm)."""
        import trimesh

        d = self.direction([s])[0]
        o = np.array([self.centre[0], 0.0, self.centre[1]])
        normal = np.cross(d, [0.0, 1.0, 0.0])
        seg = trimesh.intersections.mesh_plane(trimesh.Trimesh(self.vertices, self.faces, process=False), normal, o)
        if not len(seg):
            return np.zeros((0, 2, 2))
        r = (seg - o) @ d
        y = seg[..., 1]
        keep = (r > 0).all(axis=1)
        return np.stack([r[keep], y[keep]], axis=-1)

    def points(self, params) -> tuple[np.ndarray, np.ndarray]:
        """Surface points ``(k, 3)`` and unit outward normals ``(k, 3)`` (skull frame, mm) of the
        chart points ``params (k, 2)`` = ``(s, h)``."""
        params = np.atleast_2d(np.asarray(params, dtype=np.float64))
        out = np.empty((len(params), 3))
        columns = {}
        for i, (s, h) in enumerate(params):
            if s not in columns:
                columns[s] = self.section(s)
            seg = columns[s]
            if not len(seg):
                raise FacesimError(f"mandible: chart column s = {s:.3f} misses the mandible (a partial mandible?)")
            lo = seg[..., 1].min()
            hi = min(seg[..., 1].max(), self.crest_cap)
            y = lo + h * (hi - lo)
            out[i] = self._outermost(seg, y, s)
        normals = self._normals(out)
        return self.frame.to_world(out), normals @ self.frame.axes

    def _outermost(self, seg, y, s) -> np.ndarray:
        """The jaw-frame point of the cross-section ``seg`` at height ``y`` farthest from O."""
        (r0, y0), (r1, y1) = seg[:, 0].T, seg[:, 1].T
        lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
        cross = (lo <= y) & (hi >= y) & (hi > lo)
        if not cross.any():   # at the very bottom or top: the extreme vertex
            P = seg.reshape(-1, 2)
            r = P[np.argmin(np.abs(P[:, 1] - y)), 0]
        else:
            t = (y - y0[cross]) / (y1[cross] - y0[cross])
            r = float((r0[cross] + t * (r1[cross] - r0[cross])).max())
        return np.array([self.centre[0], y, self.centre[1]]) + r * self.direction([s])[0]

    def _normals(self, P) -> np.ndarray:
        """Unit normals (jaw frame) at surface points ``P (k, 3)``: vertex normals within
        ``NORMAL_RADIUS_MM`` (or 1.5 mean edge lengths) averaged with Gaussian weights."""
        from scipy.spatial import cKDTree

        e = self.vertices[self.faces[:, [1, 2, 0]]] - self.vertices[self.faces]
        radius = max(NORMAL_RADIUS_MM, 1.5 * float(np.linalg.norm(e, axis=2).mean()))
        tree = cKDTree(self.vertices)
        out = np.empty_like(P)
        for i, p in enumerate(P):
            near = tree.query_ball_point(p, radius)
            if len(near) < 3:
                near = tree.query(p, k=3)[1]
            near = np.asarray(near)
            w = np.exp(-np.sum((self.vertices[near] - p) ** 2, axis=1) / (2 * (radius / 2) ** 2))
            n = (w[:, None] * self.normals[near]).sum(axis=0)
            out[i] = n / np.linalg.norm(n)
        return out

    def coordinates(self, P) -> np.ndarray:
        """``(k, 2)`` the chart column ``s`` and height ``y`` (jaw frame, mm) of skull-frame points
        ``P (k, 3)`` (the inverse of :meth:`points` in ``s``; for checks)."""
        L = self.frame.to_local(np.atleast_2d(P))
        xh = (L[:, 0] - self.centre[0]) / self.width
        zh = (L[:, 2] - self.centre[1]) / self.depth
        return np.stack([np.arctan2(xh, zh) / (0.5 * np.pi), L[:, 1]], axis=1)


# ------------------------------------------------------------------ the layout
@dataclass(frozen=True)
class FeatureLayout:
    """The feature points of one model (module docstring). Skull frame, mm.

    params : (P, 2) chart coordinates (s, h) of the skin features (the same for every model with
        the same ``n_skin``); triangle : (P,) int64 index into ``model.skin``; bary : (P, 3)
        barycentric weights in it; tri_nodes : (P, 3) the triangles' model node indices;
        tri_vertices : (P, 3) the same as vertex indices of the skin mesh ``simulate`` writes
        (the skin's nodes renumbered in increasing order); skin_rest : (P, 3) rest positions;
        bone_point, bone_normal : (P, 3) the mandible points the skin points were found from and
        their outward normals; depth : (P,) soft-tissue thickness along the normal, mm;
        fallback : (P,) bool, True where the ray found no outer skin (closest point taken);
        mirror : (P,) index of each feature's mirror image; bone_names : (B,) names;
        bone_params : (B, 2); bone_rest : (B, 3) bone feature points at rest; n_nodes,
        n_skin_vertices : the sizes of the arrays :func:`skin_features` reads; chart : the
        chart's dimensions (JSON); version : :data:`LAYOUT_VERSION`.
    """

    params: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    tri_nodes: np.ndarray
    tri_vertices: np.ndarray
    skin_rest: np.ndarray
    bone_point: np.ndarray
    bone_normal: np.ndarray
    depth: np.ndarray
    fallback: np.ndarray
    mirror: np.ndarray
    bone_names: tuple
    bone_params: np.ndarray
    bone_rest: np.ndarray
    n_nodes: int
    n_skin_vertices: int
    chart: dict
    version: int = LAYOUT_VERSION

    @property
    def n_features(self) -> int:
        return len(self.params)

    def meta(self) -> dict:
        """JSON description (for a dataset's ``meta``)."""
        return {"version": self.version, "n_skin": self.n_features, "grid": list(grid_shape(self.n_features)),
                "bone_names": list(self.bone_names), "bone_params": self.bone_params.tolist(),
                "fallbacks": int(self.fallback.sum()), "depth_mm": {
                    "min": round(float(self.depth.min()), 2), "median": round(float(np.median(self.depth)), 2),
                    "max": round(float(self.depth.max()), 2)},
                "mask": {"s_max": S_MAX, "h_min": H_MIN, "h_top_chin": H_TOP_CHIN, "h_top_body": H_TOP_BODY},
                "chart": self.chart}


def feature_layout(model, n_skin: int = 240) -> FeatureLayout:
    """The :class:`FeatureLayout` of ``model`` (a :class:`~facesim.model.FaceModel`): ``n_skin``
    (about; :func:`grid_shape`) skin features and the 5 bone features (module docstring)."""
    chart = MandibleChart.of(model)
    params = skin_grid(n_skin)
    bone_params = np.array([[s, h] for _, s, h in BONE_FEATURES])
    P, N = chart.points(params)
    B, _ = chart.points(bone_params)
    tri, bary, skin_pt, depth, fallback = _skin_points(model.X, model.skin, P, N)
    skin_nodes = np.unique(model.skin)
    tri_nodes = model.skin[tri].astype(np.int64)
    rank = np.searchsorted(skin_nodes, tri_nodes)
    desc = {"width_mm": round(chart.width, 3), "depth_mm": round(chart.depth, 3),
            "centre_mm": [round(float(v), 3) for v in chart.centre], "crest_cap_mm": round(chart.crest_cap, 3),
            "landmarks": {k: [round(float(c), 3) for c in v] for k, v in chart.landmarks.items()}}
    arrays = dict(params=params, triangle=tri, bary=bary, tri_nodes=tri_nodes, tri_vertices=rank, skin_rest=skin_pt,
                  bone_point=P, bone_normal=N, depth=depth, fallback=fallback, mirror=mirror_index(n_skin),
                  bone_params=bone_params, bone_rest=B)
    for a in arrays.values():
        a.setflags(write=False)
    return FeatureLayout(**arrays, bone_names=tuple(n for n, _, _ in BONE_FEATURES), n_nodes=int(model.n_nodes),
                         n_skin_vertices=int(len(skin_nodes)), chart=desc)


def bone_rest_points(model) -> np.ndarray:
    """``(B, 3)`` the bone feature points (:data:`BONE_FEATURES`) of ``model``'s mandible at rest,
    skull frame, mm: those of :func:`feature_layout`, without finding the skin features."""
    return MandibleChart.of(model).points(np.array([[s, h] for _, s, h in BONE_FEATURES]))[0]


def _skin_points(X, skin, P, N):
    """Where the rays ``P + t N`` (``(k, 3)`` each) leave the flesh through the outer skin (module
    docstring): triangle ``(k,)``, barycentric ``(k, 3)``, point ``(k, 3)``, depth ``(k,)`` mm and
    the fallback mask ``(k,)``."""
    import trimesh

    from facesim.mocap.binding import triangle_normals

    X = np.asarray(X, dtype=np.float64)
    skin = np.asarray(skin, dtype=np.int64)
    mesh = trimesh.Trimesh(X, skin, process=False)
    normals = triangle_normals(X, skin)
    loc, ray, tri = mesh.ray.intersects_location(P, N, multiple_hits=True)
    k = len(P)
    out_tri = np.full(k, -1, np.int64)
    out_pt = np.zeros((k, 3))
    for i in range(k):
        hits = np.flatnonzero(ray == i)
        if not len(hits):
            continue
        t = (loc[hits] - P[i]) @ N[i]
        order = np.argsort(t)
        hits, t = hits[order], t[order]
        leaving = normals[tri[hits]] @ N[i] > 0
        for j in range(len(hits)):
            if not leaving[j] or t[j] <= 0 or t[j] > MAX_DEPTH_MM:
                continue
            if j + 1 < len(hits) and t[j + 1] - t[j] < REENTRY_MM:
                continue
            out_tri[i], out_pt[i] = tri[hits[j]], loc[hits[j]]
            break
    fallback = out_tri < 0
    if fallback.any():
        outward = np.zeros(len(skin), bool)
        outward[np.unique(tri)] = True   # triangles some ray crossed: the face's surfaces, not the neck cut
        sub = np.flatnonzero(outward) if outward.any() else np.arange(len(skin))
        near = trimesh.Trimesh(X, skin[sub], process=False)
        q, _, t_idx = trimesh.proximity.closest_point(near, P[fallback])
        out_tri[fallback] = sub[t_idx]
        out_pt[fallback] = q
    corners = X[skin[out_tri]]
    bary = trimesh.triangles.points_to_barycentric(corners, out_pt)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    point = np.einsum("pk,pkj->pj", bary, corners)
    depth = np.linalg.norm(point - P, axis=1)
    return out_tri, bary, point, depth, fallback


# ------------------------------------------------------------------ evaluation
def points_on_surface(vertices, faces, triangle, bary) -> np.ndarray:
    """``(..., P, 3)`` the points ``bary (P, 3)`` of the triangles ``faces[triangle]`` of a mesh with
    ``vertices (..., n, 3)`` (one state or a batch)."""
    V = np.asarray(vertices, dtype=np.float64)
    corners = V[..., np.asarray(faces)[np.asarray(triangle)], :]          # (..., P, 3, 3)
    return np.einsum("pk,...pkj->...pj", np.asarray(bary, dtype=np.float64), corners)


def skin_features(layout: FeatureLayout, x, head=None) -> np.ndarray:
    """``(P, 3)`` (or ``(N, P, 3)``) skin feature points in the skull frame, mm, of a deformed state:
    ``x`` all node positions ``(n_nodes, 3)`` (or ``(N, n_nodes, 3)``), or the vertices of the
    skin mesh ``simulate`` writes ``(n_skin_vertices, 3)``; ``head`` the skull's transform
    ``(4, 4)`` (or ``(N, 4, 4)``) in the frame of ``x``, undone (None: the skull did not move)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim < 2 or x.shape[-1] != 3:
        raise FacesimError(f"skin features: expected positions (..., n, 3), got shape {x.shape}")
    rows = x.shape[-2]
    if rows == layout.n_nodes:
        idx = layout.tri_nodes
    elif rows == layout.n_skin_vertices:
        idx = layout.tri_vertices
    else:
        raise FacesimError(f"skin features: expected the model's {layout.n_nodes} node positions or its "
                           f"{layout.n_skin_vertices} skin vertices, got {rows}")
    corners = x[..., idx, :]
    p = np.einsum("pk,...pkj->...pj", layout.bary, corners)
    if head is not None:
        from facesim import se3

        H = np.asarray(head, dtype=np.float64)
        Hi = se3.inverse(H)
        p = np.einsum("...ij,...pj->...pi", Hi[..., :3, :3], p) + Hi[..., None, :3, 3]
    return p


__all__ = ["BONE_FEATURES", "LAYOUT_VERSION", "FeatureLayout", "MandibleChart", "bone_rest_points", "feature_layout",
           "h_top",
           "mirror_index", "points_on_surface", "skin_features", "skin_grid"]
