"""A capture with its own marker layout: registered to the model's skin, its markers bound to it.

A studio's capture has its own marker names, a headband or a few rigid markers, and its own world
frame (z up, metres already converted to mm by :func:`facesim.mocap.io.read_markers`). Nothing
pairs its markers with the model's, so:

1. :func:`register_capture` finds the rigid (optionally similarity) transform from the capture's
   frame into the model's (x toward the subject's left, y up, z toward the nose, mm) without
   correspondences: the neutral marker cloud's principal axes are put onto the skin's principal
   axes in each of the 24 proper axis-aligned ways, from 7 translations each, and every start is
   refined by trimmed point-to-plane ICP against the skin (the worst ``1 - keep`` of the markers
   are left out of each step, so headband markers off the skin do not pull the face off it). The
   start with the lowest trimmed RMS distance to the skin wins, then a few steps against the exact
   skin surface finish it.
2. :func:`bind_layout` binds each marker to the closest skin point (triangle, barycentric
   coordinates, offset along the triangle's normal: Sifakis et al. 2005's binding), head markers
   too (their rest positions then reproduce the registered ones), and refuses by name the markers
   the model cannot use (too far from the skin, behind the head, inside the skin).
3. :func:`propose_head_markers` finds the markers that stay rigid relative to each other over the
   capture: the largest group of >= 3 whose pairwise distances hardly vary.
4. :func:`read_marker_map` reads a ``capture,model`` name map.
"""

from __future__ import annotations

import csv
import itertools
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from facesim.errors import FacesimError
from facesim.mocap.binding import bind_point, triangle_normals
from facesim.model import FaceModel, MarkerSet
from facesim.se3 import so3_exp

#: Fraction of the markers each ICP step fits (the rest, farthest from the skin, are trimmed).
KEEP = 0.8
#: A skin marker farther than this from the skin is refused (mm).
MAX_SKIN_DISTANCE = 25.0
#: ... a head marker (headband) farther than this (mm).
MAX_HEAD_DISTANCE = 40.0
#: A marker deeper than this under the skin (negative offset) is refused (mm).
MAX_DEPTH = 5.0
#: A marker whose closest skin triangle's normal has z below this faces away from the face (back
#: of the head), where no facial marker is glued.
MIN_FRONT = -0.5
#: Candidates whose trimmed RMS is within this of the best (mm, or 5 %) are ties (a symmetric
#: shape); the one nearest the capture's own orientation (smallest rotation) is kept.
TIE_MM = 0.05
#: Distances are capped here in the tie-break score of all the markers (mm), so a headband counts
#: no more than a marker that is a little off.
CAP_MM = 10.0


@dataclass(frozen=True)
class Registration:
    """A transform ``p_model = scale * R @ p_capture + t`` and its residual.

    R : (3, 3) float64 rotation; t : (3,) float64, mm; scale : 1.0 unless fitted (similarity);
    rms : RMS distance to the skin of the kept markers, mm; max : their largest distance, mm;
    distance : (N,) float64 distance of every marker to the skin after registration, mm (NaN:
    missing); kept : (N,) bool, the markers in the trimmed fit; starts : number of starts tried.
    """

    R: np.ndarray
    t: np.ndarray
    scale: float
    rms: float
    max: float
    distance: np.ndarray
    kept: np.ndarray
    starts: int = 0

    def apply(self, P) -> np.ndarray:
        """``P (..., 3)`` capture-frame positions (NaN kept) in the model's frame, mm."""
        P = np.asarray(P, dtype=np.float64)
        return self.scale * P @ self.R.T + self.t

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous transform capture -> model."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.scale * self.R, self.t
        return T

    def summary(self) -> dict:
        angle = np.degrees(np.arccos(np.clip((np.trace(self.R) - 1) / 2, -1, 1)))
        return {"rms_mm": round(self.rms, 3), "max_mm": round(self.max, 3), "kept": int(self.kept.sum()),
                "markers": int(np.isfinite(self.distance).sum()), "rotation_deg": round(float(angle), 2),
                "translation_mm": [round(float(v), 2) for v in self.t], "scale": round(self.scale, 5)}


# ------------------------------------------------------------------ skin as a query surface
@dataclass
class _Skin:
    """The model's rest skin: a dense sample with normals (k-d tree, for the many ICP starts) and
    the exact surface (trimesh, for the finish and the binding)."""

    X: np.ndarray
    tris: np.ndarray
    normals: np.ndarray
    mesh: trimesh.Trimesh
    points: np.ndarray
    point_tri: np.ndarray
    tree: cKDTree = field(repr=False)
    coarse: cKDTree = field(repr=False)

    @staticmethod
    def of(model: FaceModel, spacing: float = 2.5, most: int = 50_000) -> "_Skin":
        X, tris = model.X, model.skin
        mesh = trimesh.Trimesh(X, tris, process=False)
        normals = triangle_normals(X, tris)
        count = int(np.clip(mesh.area / spacing ** 2, 2 * len(tris), most))
        points, tri = trimesh.sample.sample_surface(mesh, count, seed=0)
        points = np.r_[points, X[tris].mean(axis=1)]
        tri = np.r_[tri, np.arange(len(tris))]
        every = max(1, len(points) // 4000)   # for the many short starts: queries far off the skin are slow
        return _Skin(X, tris, normals, mesh, points, tri, cKDTree(points), cKDTree(points[::every]))

    def near(self, p) -> tuple[np.ndarray, np.ndarray]:
        """Approximate closest skin points of ``p (k, 3)`` and their triangles' normals."""
        _, j = self.tree.query(p)
        return self.points[j], self.normals[self.point_tri[j]]

    def rough(self, p) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`near`, on a sparse sample (~4,000 points)."""
        _, j = self.coarse.query(p)
        every = max(1, len(self.points) // 4000)
        j = j * every
        return self.points[j], self.normals[self.point_tri[j]]

    def closest(self, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact closest skin points of ``p (k, 3)``, distances (k,) and triangles (k,)."""
        q, d, t = trimesh.proximity.closest_point(self.mesh, p)
        return np.asarray(q), np.asarray(d), np.asarray(t, dtype=np.int64)


def _skin(model) -> _Skin:
    cached = _SKINS.get(id(model))
    if cached is None or cached[0] is not model:
        cached = _SKINS[id(model)] = (model, _Skin.of(model))
        while len(_SKINS) > 4:
            _SKINS.pop(next(iter(_SKINS)))
    return cached[1]


_SKINS: dict = {}


# ------------------------------------------------------------------ registration
def _principal(P) -> tuple[np.ndarray, np.ndarray]:
    c = P.mean(axis=0)
    w, U = np.linalg.eigh(np.cov((P - c).T))
    return c, U[:, ::-1]


def _axis_rotations() -> np.ndarray:
    """The 24 signed permutation matrices with determinant +1."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            S = np.zeros((3, 3))
            S[range(3), perm] = signs
            if np.linalg.det(S) > 0:
                out.append(S)
    return np.array(out)


def _rotation_starts(Us, Uq, tilt_deg: float = 20.0) -> np.ndarray:
    """Starting rotations: the capture's principal axes ``Uq`` put onto the model's frame axes (x,
    y, z: a face's marker cloud spreads most across and along the face and least in depth) in the
    24 proper axis-aligned ways, each also tilted by +-``tilt_deg`` about each axis (a cloud's axes
    are often ~20 degrees off the face's: ICP from a right translation converges from 20+ degrees),
    and onto the skin's own principal axes ``Us`` (for shapes that are not faces); and first the
    identity (a capture already oriented as the model)."""
    tilts = [np.eye(3)] + [so3_exp(sign * np.radians(tilt_deg) * np.eye(3)[a]) for a in range(3) for sign in (1, -1)]
    out = [np.eye(3)]   # the capture's own orientation first: it wins the ties of a symmetric shape
    for S in _axis_rotations():
        for frame, dR in [(np.eye(3), d) for d in tilts] + [(Us, np.eye(3))]:
            R0 = frame @ S @ Uq.T
            if np.linalg.det(R0) < 0:   # Uq (or Us) improper: flip its last axis
                R0 = frame @ S @ np.diag([1.0, 1.0, -1.0]) @ Uq.T
            out.append(dR @ R0)
    return np.array(out)


def _icp(P, R, t, s, closest, keep: float, steps: int, tol: float = 1e-4):
    """Trimmed point-to-plane ICP of ``P (k, 3)`` from ``s R p + t`` (``s`` held); ``closest(y) ->
    (q, n)``. Each step linearises the rotation about the current pose and solves the
    least squares of the plane distances of the kept markers, with a small point-to-point term so
    a flat or symmetric cloud's sliding directions stay determined. Returns R, t, s, trimmed RMS."""
    k = max(3, int(round(keep * len(P))))
    rms = np.inf
    for _ in range(steps):
        Y = s * P @ R.T + t
        q, n = closest(Y)
        d = np.einsum("ij,ij->i", Y - q, n)
        e = np.linalg.norm(Y - q, axis=1)
        use = np.argsort(np.abs(d) + 0.1 * e)[:k]
        rms = float(np.sqrt(np.mean(d[use] ** 2)))
        Yk, qk, nk = Y[use], q[use], n[use]
        c = Yk.mean(axis=0)
        rel = Yk - c
        # the pose update dy_i = w x rel_i + dt, i.e. J_i [w, dt]:
        m = 6
        J = np.zeros((len(use), 3, m))
        J[:, 0, 1], J[:, 0, 2] = rel[:, 2], -rel[:, 1]      # w x r = -[r]x w
        J[:, 1, 0], J[:, 1, 2] = -rel[:, 2], rel[:, 0]
        J[:, 2, 0], J[:, 2, 1] = rel[:, 1], -rel[:, 0]
        J[:, :, 3:6] = np.eye(3)
        r = Yk - qk
        # plane distances n.(r + J x), plus 0.1 x the point distances so a flat or symmetric cloud's
        # sliding directions stay determined
        Jn = np.einsum("ij,ijk->ik", nk, J)
        lam2 = 0.01
        H = Jn.T @ Jn + lam2 * np.einsum("ijk,ijl->kl", J, J) + 1e-9 * np.eye(m)
        g = Jn.T @ np.einsum("ij,ij->i", r, nk) + lam2 * np.einsum("ijk,ij->k", J, r)
        x = np.linalg.solve(H, -g)
        dR = so3_exp(x[:3])
        # y' = c + dR (y - c) + dt
        R = dR @ R
        t = c + dR @ (t - c) + x[3:6]
        if np.linalg.norm(x[:3]) < tol and np.linalg.norm(x[3:6]) < tol * 10:
            break
    return R, t, s, rms


def _reorder(fit):
    R, t, s, rms = fit
    return rms, R, t, s


def _capped(P, R, t, s, skin: _Skin) -> float:
    """RMS of the (approximate) skin distances of all of ``P`` capped at :data:`CAP_MM`, mm: breaks
    the ties of the trimmed RMS (a symmetric shape, or a part of the cloud that fits elsewhere).
    Markers on skin facing backward (the back of the head, where :func:`bind_layout` refuses them)
    count as capped."""
    Y = s * P @ R.T + t
    q, n = skin.near(Y)
    d = np.minimum(np.linalg.norm(Y - q, axis=1), CAP_MM)
    d[n[:, 2] < MIN_FRONT] = CAP_MM   # a facial marker on skin facing backward: as bad as a far one
    return float(np.sqrt(np.mean(d ** 2)))


def _trimmed_distance(P, R, t, s, skin: _Skin, keep: float):
    Y = s * P @ R.T + t
    _, d, _ = skin.closest(Y)
    k = max(3, int(round(keep * len(P))))
    order = np.argsort(d)
    return float(np.sqrt(np.mean(d[order[:k]] ** 2))), d, order[:k]


def register_capture(model: FaceModel, neutral, head=None, similarity: bool = False,
                     keep: float = KEEP) -> Registration:
    """The transform of the capture's frame into the model's, found from the shapes alone.

    Parameters
    ----------
    model : FaceModel, whose rest skin ``model.skin`` at ``model.X`` the markers are fitted to.
    neutral : (N, 3) float64, the capture's neutral marker positions in its own frame, mm (NaN:
        missing; at least 6 present).
    head : optional (N,) bool or indices of head markers (off the skin, e.g. a headband): they are
        left out of the fit (they would be trimmed anyway) but their distance is reported.
    similarity : also fit a uniform scale (a capture of another person's face).
    keep : fraction of the (skin) markers each step fits.

    Returns a :class:`Registration` whose ``rms``/``max`` are the exact distances to the skin of
    the kept markers.
    """
    P = np.asarray(neutral, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise FacesimError(f"neutral markers: expected (N, 3) positions, got {P.shape}")
    ok = np.isfinite(P).all(axis=1)
    if head is not None:
        mask = np.zeros(len(P), bool)
        mask[np.asarray(head)] = True
        ok &= ~mask
    if ok.sum() < 6:
        raise FacesimError(f"registration: expected >= 6 skin markers seen in the neutral frames, got {int(ok.sum())}")
    Q = P[ok]
    skin = _skin(model)
    cq, Uq = _principal(Q)
    cs, Us = _principal(skin.points)
    # translations: the cloud centred on the skin's centre, or pushed along each principal axis of
    # the skin until its extreme marker touches the skin's extreme point (a face's markers sit on
    # one side of the head: the nose, the brow or the chin leads)
    along = skin.points @ Us   # (k, 3) skin in its principal frame
    scored = []
    for R0 in _rotation_starts(Us, Uq):
        Y = (Q - cq) @ R0.T
        starts = [cs]
        for a in range(3):
            d = Us[:, a]
            for sign in (1.0, -1.0):
                lead = (along[:, a] * sign).max() - (Y @ d * sign).max()
                starts.append(cs + d * (sign * lead - cs @ d))
        for centre in starts:
            t0 = centre - R0 @ cq
            R, t, s, rms = _icp(Q, R0, t0, 1.0, skin.rough, keep, steps=6)
            scored.append((rms, R, t, s))
    scored.sort(key=lambda c: c[0])   # a few steps sort the starts; the promising ones go on
    scored = sorted((_reorder(_icp(Q, R, t, s, skin.near, keep, steps=40)) for _, R, t, s in scored[:48]),
                    key=lambda c: c[0] + 0.1 * _capped(Q, c[1], c[2], c[3], skin))
    if similarity:   # the scale of the best pose: shrinking a cloud onto the skin always lowers the
        # plane distances, so the scale is not an ICP unknown but searched in [0.8, 1.25] (units are
        # converted before), each scale refitted rigidly
        from scipy.optimize import minimize_scalar

        rms0, R1, t1, _ = scored[0]
        c1 = R1 @ cq + t1

        def at(log_s):
            s1 = float(np.exp(log_s))
            return _icp(Q, R1, c1 - s1 * R1 @ cq, s1, skin.near, keep, steps=15)

        best_log = minimize_scalar(lambda v: at(v)[3], bounds=(np.log(0.8), np.log(1.25)), method="bounded",
                                   options={"xatol": 1e-4}).x
        R1, t1, s1, rms1 = at(best_log)
        scored = [(rms1, R1, t1, s1)]

    # finish the best few against the exact surface
    def exact(y):
        q, _, tri = skin.closest(y)
        return q, skin.normals[tri]

    finals = []
    for rms0, R, t, s in _distinct(scored, 8):
        R, t, s, _ = _icp(Q, R, t, s, exact, keep, steps=8, tol=1e-6)
        rms, d, _ = _trimmed_distance(Q, R, t, s, skin, keep)
        finals.append((rms, R, t, s, _capped(Q, R, t, s, skin)))
    best = min(r[0] for r in finals)
    ties = [f for f in finals if f[0] <= best + max(TIE_MM, 0.05 * best)]
    # among ties (a symmetric shape, or trimming that lets a part of the cloud fit elsewhere): the
    # pose where all the markers, trimmed ones included, sit closest (capped), then the smallest turn
    low = min(f[4] for f in ties)
    ties = [f for f in ties if f[4] <= low + max(TIE_MM, 0.05 * low)]
    rms, R, t, s, _ = max(ties, key=lambda f: np.trace(f[1]))   # largest trace: smallest rotation angle
    _, d, kept_q = _trimmed_distance(Q, R, t, s, skin, keep)
    distance = np.full(len(P), np.nan)
    seen = np.isfinite(P).all(axis=1)
    distance[seen] = skin.closest(s * P[seen] @ R.T + t)[1]
    kept = np.zeros(len(P), bool)
    kept[np.flatnonzero(ok)[kept_q]] = True
    return Registration(R=R, t=t, scale=float(s), rms=rms, max=float(d[kept_q].max()), distance=distance,
                        kept=kept, starts=len(scored))


def _distinct(scored, n, angle_deg: float = 5.0, shift_mm: float = 5.0):
    """The ``n`` best-scored poses that differ from each other (rotation or translation)."""
    out = []
    for c in scored:
        if all(np.degrees(np.arccos(np.clip((np.trace(c[1] @ o[1].T) - 1) / 2, -1, 1))) > angle_deg
               or np.linalg.norm(c[2] - o[2]) > shift_mm for o in out):
            out.append(c)
        if len(out) == n:
            break
    return out


# ------------------------------------------------------------------ binding
PLACED_HEADER = ("name", "triangle", "b0", "b1", "b2", "offset_mm", "distance_mm", "role")


def bind_layout(model: FaceModel, names, registered, head_names=()) -> tuple[MarkerSet, list[dict], dict[str, str]]:
    """Bind the capture's markers to the model's rest skin.

    Parameters
    ----------
    names : (N,) the capture's marker names.
    registered : (N, 3) float64, their neutral positions in the model's frame, mm (NaN: never seen).
    head_names : names of the head markers (bound the same way, with ``head=True``).

    Returns the :class:`~facesim.model.MarkerSet` of the usable markers (capture order), one
    placement row per bound marker (keys :data:`PLACED_HEADER`) and ``{name: reason}`` of the
    refused ones: not seen, farther than :data:`MAX_SKIN_DISTANCE` (head markers:
    :data:`MAX_HEAD_DISTANCE`) mm from the skin, deeper than :data:`MAX_DEPTH` mm under it, or
    closest to a skin triangle facing backward (the back of the head).
    """
    names = [str(n) for n in names]
    P = np.asarray(registered, dtype=np.float64)
    if P.shape != (len(names), 3):
        raise FacesimError(f"registered markers: expected ({len(names)}, 3) positions, got {P.shape}")
    head_names = set(head_names)
    unknown = head_names - set(names)
    if unknown:
        raise FacesimError(f"head markers: {', '.join(sorted(unknown))} not in the capture")
    skin = _skin(model)
    seen = np.isfinite(P).all(axis=1)
    rejected = {n: "not seen in the neutral frames" for n, s in zip(names, seen) if not s}
    q = np.full((len(P), 3), np.nan)
    d = np.full(len(P), np.nan)
    tri = np.full(len(P), -1)
    if seen.any():
        q[seen], d[seen], tri[seen] = skin.closest(P[seen])
    keep, rows = [], []
    tris, barys, offsets, heads = [], [], [], []
    for i in np.flatnonzero(seen):
        name, is_head, t = names[i], names[i] in head_names, int(tri[i])
        n = skin.normals[t]
        b, offset = bind_point(skin.X[skin.tris[t]], q[i], P[i], n)
        limit = MAX_HEAD_DISTANCE if is_head else MAX_SKIN_DISTANCE
        if d[i] > limit:
            rejected[name] = f"{d[i]:.1f} mm from the skin (limit {limit:g} mm for a {'head' if is_head else 'skin'} marker)"
            continue
        if offset < -MAX_DEPTH:
            rejected[name] = f"{-offset:.1f} mm under the skin (limit {MAX_DEPTH:g} mm): inside the mouth or a bad label?"
            continue
        if n[2] < MIN_FRONT and not is_head:
            rejected[name] = "on the back of the head (its skin faces away from the face)"
            continue
        keep.append(i)
        tris.append(t), barys.append(b), offsets.append(offset), heads.append(is_head)
        rows.append({"name": name, "triangle": t, "b0": b[0], "b1": b[1], "b2": b[2], "offset_mm": offset,
                     "distance_mm": float(d[i]), "role": "head" if is_head else "skin"})
    if len(keep) < 3:
        raise FacesimError(f"marker binding: only {len(keep)} of {len(names)} markers can be bound to the skin "
                           f"({'; '.join(f'{k}: {v}' for k, v in list(rejected.items())[:5])})")
    markers = MarkerSet(names=tuple(names[i] for i in keep), triangle=np.array(tris), bary=np.array(barys),
                        offset=np.array(offsets), head=np.array(heads, bool))
    return markers, rows, rejected


def write_placement(path, rows) -> Path:
    """OUT/markers_placed.csv: one row per bound marker (:data:`PLACED_HEADER`); return its path."""
    from facesim._files import atomic_write

    def fmt(v):   # 12 digits: the barycentric coordinates read back sum to 1 within 1e-9 (MarkerSet's check)
        return f"{v:.12g}" if isinstance(v, float) else str(v)

    text = ",".join(PLACED_HEADER) + "\n" + "".join(",".join(fmt(r[k]) for k in PLACED_HEADER) + "\n" for r in rows)
    return atomic_write(Path(path), lambda tmp: tmp.write_text(text))


# ------------------------------------------------------------------ head markers
def propose_head_markers(P, names=None, noise: float = 0.0, min_size: int = 3) -> list:
    """The markers that move rigidly together over the capture ``P (F, N, 3)`` (mm, NaN missing):
    the largest group of >= ``min_size`` markers whose pairwise distances vary (standard deviation
    over the frames where both are seen) by less than ``max(0.5 mm, 3 noise)``. Ties: the group
    with the smallest total spread. Returns their indices (or names, if ``names`` is given), or []
    when no such group exists (fewer than 2 frames, or the whole face rigid: then every marker is
    rigid and nothing tells the head apart, so [] too)."""
    import networkx as nx

    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3:
        raise FacesimError(f"markers: expected (F, N, 3) positions, got {P.shape}")
    F, N, _ = P.shape
    if F < 2 or N < min_size:
        return []
    D = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1)   # (F, N, N)
    with np.errstate(invalid="ignore"):
        both = np.isfinite(D).sum(axis=0)
        mean = np.nanmean(np.where(np.isfinite(D), D, np.nan), axis=0)
        spread = np.sqrt(np.nanmean((D - mean) ** 2, axis=0))
    tol = max(0.5, 3.0 * noise)
    rigid = (spread < tol) & (both >= 2)
    np.fill_diagonal(rigid, False)
    graph = nx.Graph()
    graph.add_nodes_from(range(N))
    graph.add_edges_from(zip(*np.nonzero(np.triu(rigid))))
    groups = [sorted(c) for c in nx.find_cliques(graph) if len(c) >= min_size]
    if not groups:
        return []
    best = max(groups, key=lambda g: (len(g), -np.nansum(spread[np.ix_(g, g)])))
    if len(best) == N:
        return []
    return [names[i] for i in best] if names is not None else best


# ------------------------------------------------------------------ marker maps
def read_marker_map(path) -> dict[str, str]:
    """``{capture name: model name}`` from a CSV with header ``capture,model``."""
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such marker map")
    with open(path, newline="") as fh:
        rows = [r for r in csv.reader(fh) if r and any(c.strip() for c in r)]
    if not rows or [c.strip().lower() for c in rows[0][:2]] != ["capture", "model"]:
        raise FacesimError(f"{path}: line 1: expected the header 'capture,model'")
    out = {}
    for k, row in enumerate(rows[1:], start=2):
        if len(row) < 2 or not row[0].strip() or not row[1].strip():
            raise FacesimError(f"{path}: line {k}: expected 'capture name,model name'")
        cap, mod = row[0].strip(), row[1].strip()
        if cap in out:
            raise FacesimError(f"{path}: line {k}: capture marker {cap!r} mapped twice")
        out[cap] = mod
    if len(set(out.values())) != len(out):
        raise FacesimError(f"{path}: a model marker is mapped from two capture markers")
    return out


# ------------------------------------------------------------------ the whole path
#: Neutral frames when none are named: the capture's first frames.
DEFAULT_BIND_FRAMES = 10


@dataclass(frozen=True)
class Layout:
    """A capture's own markers on the model: ``markers`` (MarkerSet, the usable markers in capture
    order), ``index (r,)`` their columns in the capture, ``registration``, ``rows`` (placement,
    :data:`PLACED_HEADER`), ``rejected {name: reason}``, ``head`` (head marker names) and how they
    were chosen (``head_source``: ``given``, ``map`` or ``proposed``), ``mapped {capture: model}``."""

    markers: MarkerSet
    index: np.ndarray
    registration: Registration
    rows: list
    rejected: dict
    head: tuple
    head_source: str
    mapped: dict

    def to_model(self, P) -> np.ndarray:
        """The capture ``P (F, N, 3)`` (all its markers, own frame, mm) as the model's ``(F, r, 3)``."""
        return self.registration.apply(np.asarray(P, dtype=np.float64)[:, self.index])


def fit_layout(model: FaceModel, names, P, neutral_frames, head_names=None, marker_map=None,
               similarity: bool = False, noise: float = 0.5, min_head: int = 3) -> Layout:
    """Register and bind a capture of its own layout (see the module doc).

    names : (N,) the capture's marker names; P : (F, N, 3) float64 the capture, mm, its own frame
    (NaN missing); neutral_frames : (F,) bool, the frames of the neutral face; head_names : the
    head markers (None: from the map's model head markers, else :func:`propose_head_markers`);
    marker_map : ``{capture name: model name}``: those markers take the model's own binding, and
    with >= 3 of them seen the registration is their rigid fit onto the model's rest markers.
    min_head : the fewest head markers the layout needs: 3 to stabilise the head by them
    (Procrustes); 0 when the head frame is solved with the other controls (``--head solve``),
    then fewer (or none) are taken and the neutral frames are aligned by all their markers.
    """
    from facesim.se3 import rigid_fit

    names = [str(n) for n in names]
    P = np.asarray(P, dtype=np.float64)
    marker_map = dict(marker_map or {})
    model_index = {n: i for i, n in enumerate(model.markers.names)}
    for cap, mod in marker_map.items():
        if cap not in names:
            raise FacesimError(f"marker map: capture marker {cap!r} is not in the capture")
        if mod not in model_index:
            raise FacesimError(f"marker map: {mod!r} is not one of the model's markers ('facesim model info' lists them)")
    if head_names is not None:
        unknown = [h for h in head_names if h not in names]
        if unknown:
            raise FacesimError(f"--head-markers: {', '.join(unknown)} not in the capture "
                               f"(it has {', '.join(names[:6])}{', ...' if len(names) > 6 else ''})")
        if len(set(head_names)) < min_head:
            raise FacesimError(f"--head-markers: expected >= {min_head} head markers (or --head solve, which needs "
                               f"none), got {len(set(head_names))}")
        head, source = tuple(head_names), "given"
    else:
        from_map = tuple(c for c, m in marker_map.items() if model.markers.head[model_index[m]])
        if len(from_map) >= 3:
            head, source = from_map, "map"
        else:
            head, source = tuple(propose_head_markers(P, names, noise=noise)), "proposed"
            if len(head) < min_head:
                raise FacesimError("head markers: no group of >= 3 markers moves rigidly over the capture; "
                                   "name them with --head-markers NAME,NAME,..., or solve the head (--head solve)")
    hidx = [names.index(h) for h in head]
    N = P[np.asarray(neutral_frames, bool)]
    if not len(N):
        raise FacesimError("neutral frames: none selected")
    # the head may move during the neutral frames: each onto the first by its head markers (by all
    # its markers when there are fewer than 3: the neutral face does not change)
    align = hidx if len(hidx) >= 3 else list(range(len(names)))
    ref = N[0][align]
    aligned = []
    for frame in N:
        ok = np.isfinite(frame[align]).all(axis=1) & np.isfinite(ref).all(axis=1)
        if ok.sum() >= 3:
            T = rigid_fit(frame[align][ok], ref[ok])
            frame = frame @ T[:3, :3].T + T[:3, 3]
        aligned.append(frame)
    with warnings.catch_warnings():   # a marker missing in every neutral frame stays NaN (refused)
        warnings.simplefilter("ignore", RuntimeWarning)
        neutral = np.nanmedian(np.array(aligned), axis=0)
    mapped_idx = [names.index(c) for c in marker_map]
    rest = model.marker_positions()
    seen_map = [i for i in mapped_idx if np.isfinite(neutral[i]).all()]
    if len(seen_map) >= 3:   # correspondences: their rigid fit, the residual measured on the skin
        T = rigid_fit(neutral[seen_map], rest[[model_index[marker_map[names[i]]] for i in seen_map]])
        skin = _skin(model)
        Y = neutral @ T[:3, :3].T + T[:3, 3]
        d = np.full(len(names), np.nan)
        seen = np.isfinite(Y).all(axis=1)
        d[seen] = skin.closest(Y[seen])[1]
        kept = seen.copy()
        kept[hidx] = False
        reg = Registration(R=T[:3, :3], t=T[:3, 3], scale=1.0, rms=float(np.sqrt(np.nanmean(d[kept] ** 2))),
                           max=float(np.nanmax(d[kept])), distance=d, kept=kept, starts=0)
    else:
        reg = register_capture(model, neutral, head=hidx, similarity=similarity)
    markers, rows, rejected = bind_layout(model, names, reg.apply(neutral), head)
    if marker_map:   # mapped markers take the model's own binding
        tri, bary, offset, is_head = (markers.triangle.copy(), markers.bary.copy(), markers.offset.copy(),
                                      markers.head.copy())
        for k, n in enumerate(markers.names):
            if n in marker_map:
                j = model_index[marker_map[n]]
                tri[k], bary[k], offset[k] = model.markers.triangle[j], model.markers.bary[j], model.markers.offset[j]
                is_head[k] = is_head[k] or model.markers.head[j]
                rows[k].update(triangle=int(tri[k]), b0=bary[k, 0], b1=bary[k, 1], b2=bary[k, 2],
                               offset_mm=float(offset[k]), role="head" if is_head[k] else "skin")
        markers = MarkerSet(markers.names, tri, bary, offset, is_head)
    if markers.head.sum() < min(3, max(min_head, len(head))) and min_head:
        raise FacesimError(f"head markers: only {int(markers.head.sum())} of {', '.join(head)} could be bound "
                           f"({'; '.join(f'{k}: {v}' for k, v in rejected.items() if k in head)})")
    index = np.array([names.index(n) for n in markers.names], dtype=np.int64)
    return Layout(markers, index, reg, rows, rejected, head, source, marker_map)


__all__ = ["DEFAULT_BIND_FRAMES", "KEEP", "Layout", "fit_layout", "MAX_DEPTH", "MAX_HEAD_DISTANCE", "MAX_SKIN_DISTANCE", "PLACED_HEADER", "Registration",
           "bind_layout", "propose_head_markers", "read_marker_map", "register_capture", "write_placement"]
