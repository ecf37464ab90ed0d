"""The muscle catalogue and its embedding in the flesh mesh.

Each muscle is a ribbon swept along a path laid under the skin: a polyline from origin to
insertion (or a closed/partial ring for the sphincters), pushed to a prescribed depth below the
skin, with a half width across and a half thickness through the ribbon. Embedding samples
points in every tet and records, per (muscle, tet), the fraction of samples inside the ribbon
and the path tangent there (the fibre direction; circumferential for the rings).

Positions follow ``docs/physics.md`` section 6 (left side; the right side is mirrored).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim._kernels.embed import ribbon_inside
from facesim.anatomy import sdf
from facesim.model import MuscleSet


@dataclass(frozen=True)
class MuscleSpec:
    """One left-side muscle. ``path (k, 3)`` canonical mm, depth below the skin at both ends (mm),
    half width and half thickness at both ends (mm), peak stress ``sigma_max`` (MPa)."""

    name: str
    path: tuple
    depth: tuple[float, float]
    width: tuple[float, float]
    thickness: tuple[float, float]
    sigma_max: float = 0.25
    closed: bool = False
    midline: bool = False   # a single midline-crossing muscle per side is still mirrored
    ring: bool = False      # a sphincter drawn in the front view: laid along z, see ``lay_path``


def _arc(centre, a, b, t0, t1, z_drop=0.0, n=9):
    """Points of the ellipse arc ``centre + (a cos t, b sin t, -z_drop (1 - sin^2 ...))`` from t0 to t1 (deg)."""
    t = np.deg2rad(np.linspace(t0, t1, n))
    c = np.asarray(centre, float)
    x = c[0] + a * np.cos(t)
    y = c[1] + b * np.sin(t)
    z = c[2] - z_drop * np.cos(t) ** 2
    return tuple(map(tuple, np.stack([x, y, z], 1)))


#: 16 left muscles; each is mirrored to the right, giving 32.
CATALOGUE: tuple[MuscleSpec, ...] = (
    MuscleSpec("frontalis", ((30, 100, 40), (30, 80, 70), (28, 55, 84)), (3.5, 3.0), (14, 12), (1.8, 1.8), 0.20),
    MuscleSpec("corrugator_supercilii", ((10, 42, 82), (20, 46, 84), (30, 48, 82)), (6.0, 4.0), (3.5, 3.0), (2.0, 2.0), 0.22),
    # a slip from the nasal bones to the glabella skin, 6-7 mm wide; with its twin a strip ~15 mm wide
    MuscleSpec("procerus", ((4, 25, 92), (4, 35, 90), (4, 45, 88)), (3.0, 3.5), (3.0, 3.5), (1.5, 1.5), 0.20),
    MuscleSpec("orbicularis_oculi", _arc((32, 27, 70), 24, 20, 0, 360, z_drop=8, n=25), (2.5, 2.5), (6.0, 6.0),
               (1.6, 1.6), 0.20, closed=True, ring=True),
    MuscleSpec("levator_labii_superioris_alaeque_nasi", ((14, 30, 84), (15, 10, 94), (16, -14, 100)), (4.0, 3.5),
               (3.0, 3.5), (2.0, 2.0), 0.25),
    MuscleSpec("levator_labii_superioris", ((28, 10, 80), (22, -8, 90), (15, -28, 96)), (5.0, 4.0), (5.0, 4.0),
               (2.2, 2.2), 0.25),
    MuscleSpec("zygomaticus_minor", ((40, 4, 78), (30, -12, 88), (19, -29, 95)), (5.0, 4.0), (3.0, 3.0), (2.0, 2.0), 0.25),
    MuscleSpec("zygomaticus_major", ((55, 4, 58), (46, -18, 72), (33, -38, 84)), (6.0, 4.5), (4.0, 3.5), (2.5, 2.5), 0.30),
    MuscleSpec("levator_anguli_oris", ((20, -8, 84), (26, -22, 86), (31, -37, 86)), (8.0, 5.0), (4.0, 3.5), (2.5, 2.5), 0.25),
    MuscleSpec("risorius", ((60, -36, 38), (48, -38, 64), (33, -40, 84)), (4.0, 3.5), (4.5, 3.0), (1.8, 1.8), 0.22),
    MuscleSpec("buccinator", ((40, -36, 38), (37, -38, 60), (30, -40, 80)), (10.0, 7.0), (8.0, 5.0), (2.5, 2.5), 0.25),
    MuscleSpec("depressor_anguli_oris", ((38, -78, 60), (36, -60, 74), (32, -44, 84)), (4.0, 4.0), (6.0, 3.5),
               (2.2, 2.2), 0.25),
    MuscleSpec("depressor_labii_inferioris", ((18, -74, 76), (15, -60, 86), (11, -48, 94)), (5.0, 4.5), (5.5, 4.5),
               (2.2, 2.2), 0.25),
    MuscleSpec("mentalis", ((6, -58, 82), (6, -70, 88), (6, -80, 90)), (6.0, 4.0), (4.5, 4.5), (2.5, 2.5), 0.22),
    MuscleSpec("orbicularis_oris_upper", _arc((0, -40, 96), 26, 12, 0, 90, z_drop=8), (4.5, 4.5), (3.5, 4.0), (3.0, 3.0),
               0.30, ring=True),
    MuscleSpec("orbicularis_oris_lower", _arc((0, -40, 96), 26, 12, 0, -90, z_drop=8), (4.5, 4.5), (3.5, 4.0), (3.0, 3.0),
               0.30, ring=True),
)


def muscle_names() -> list[str]:
    """The 32 muscle names in model order: every left muscle followed by its right twin."""
    return [f"{m.name}_{s}" for m in CATALOGUE for s in ("L", "R")]


def lay_path(path: np.ndarray, depth: tuple[float, float], skin: np.ndarray, grid: sdf.Grid,
             n: int = 24, closed: bool = False, along_z: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample ``path (k, 3)`` to ``n`` points and push each to its depth below the skin.

    By default each point moves along the skin normal. With ``along_z`` only its z changes: it
    goes to the first point at that depth seen from the front, so the path keeps its (x, y)
    front-view shape. Rings need this: the face curves back at the mouth corners and the outer
    canthi, and a push along the normal there slides the ends medially (the lip ring's corners
    from x = 26 to x = 18 mm), which bends the fibres of the flattened ring off circumferential.
    Returns ``(points (n, 3), tangents (n, 3), skin normals (n, 3))`` in mm.
    """
    path = np.asarray(path, float)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.r_[0, np.cumsum(seg)]
    u = np.linspace(0, s[-1], n, endpoint=not closed) if not closed else np.linspace(0, s[-1], n + 1)[:-1]
    p = np.stack([np.interp(u, s, path[:, i]) for i in range(3)], 1)
    d = np.interp(u / max(s[-1], 1e-9), [0, 1], depth)
    if along_z:
        p = _sink_along_z(p, d, skin, grid)
    else:
        for _ in range(6):
            val = grid.sample(skin, p)
            g = grid.gradient_at(skin, p)
            nrm = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
            p = p - (val + d)[:, None] * nrm
    g = grid.gradient_at(skin, p)
    nrm = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
    if closed:
        tang = np.roll(p, -1, 0) - np.roll(p, 1, 0)
    else:
        tang = np.gradient(p, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    return p, tang, nrm


def _inside_ribbon(P: np.ndarray, pts: np.ndarray, tang: np.ndarray, nrm: np.ndarray, W: np.ndarray,
                   H: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Which of the points ``P (q, 3)`` lie in the ribbon laid along ``pts (k, 3)``, and its fibre there.

    Returns ``(inside (q,) bool, fibre (q, 3) unit tangents of the closest segment, zero outside)``.
    """
    inside = np.zeros(len(P), dtype=np.bool_)
    fibre = np.zeros((len(P), 3))
    ribbon_inside(np.ascontiguousarray(P), np.ascontiguousarray(pts), np.ascontiguousarray(tang),
                  np.ascontiguousarray(nrm), np.ascontiguousarray(W, dtype=np.float64),
                  np.ascontiguousarray(H, dtype=np.float64), bool(closed), inside, fibre)
    fibre[~inside] = 0.0
    return inside, fibre


def _sink_along_z(p: np.ndarray, d: np.ndarray, skin: np.ndarray, grid: sdf.Grid, reach: float = 40.0,
                  step: float = 0.25) -> np.ndarray:
    """Move each of ``p (n, 3)`` along z to the first point from the front where the skin distance
    is ``-d (n,)``: march back from ``reach`` mm in front of it, then interpolate the crossing."""
    z = p[:, 2:3] + reach - step * np.arange(int(2 * reach / step) + 1)       # (n, m), front to back
    ray = np.stack(np.broadcast_arrays(p[:, :1], p[:, 1:2], z), axis=-1)        # (n, m, 3)
    f = grid.sample(skin, ray.reshape(-1, 3)).reshape(z.shape) + d[:, None]    # < 0 deeper than d
    j = np.argmax(f <= 0, axis=1)
    if np.any(f[np.arange(len(p)), j] > 0) or np.any(j == 0):
        raise ValueError("a ring point has no depth crossing within reach of its seed along z")
    f0, f1 = f[np.arange(len(p)), j - 1], f[np.arange(len(p)), j]
    out = p.copy()
    out[:, 2] = z[np.arange(len(p)), j - 1] - step * f0 / (f0 - f1)
    return out


#: Barycentric sample points per tet (centroid, 4 near the vertices, 6 near the edge midpoints).
_SAMPLES = np.array(
    [[0.25, 0.25, 0.25, 0.25]]
    + [[0.55 if i == j else 0.15 for j in range(4)] for i in range(4)]
    + [[0.4 if k in (i, j) else 0.1 for k in range(4)] for i in range(4) for j in range(i + 1, 4)]
)


def embed_muscles(X: np.ndarray, tets: np.ndarray, skin: np.ndarray, grid: sdf.Grid, scale=None,
                  catalogue=CATALOGUE, min_fraction: float = 0.05) -> tuple[MuscleSet, dict]:
    """Embed every catalogue muscle (left and mirrored right) in the mesh ``(X, tets)``.

    ``skin`` is the skin signed distance on ``grid`` (mm) used to lay the paths; ``scale`` maps
    canonical mm to the subject (callable on ``(k, 3)``). Returns the :class:`MuscleSet` and the
    laid paths ``{name: (points, tangents)}`` for inspection.
    """
    scale = scale or (lambda p: p)
    q = len(_SAMPLES)
    P = np.einsum("sk,mkj->msj", _SAMPLES, X[tets]).reshape(-1, 3)
    centroid = X[tets].mean(axis=1)
    names, sides, sig, e_m, e_t, e_f, e_d = [], [], [], [], [], [], []
    paths = {}
    mirror = np.array([-1.0, 1.0, 1.0])
    for spec in catalogue:
        for side in ("L", "R"):
            base = np.asarray(spec.path, float) * (1.0 if side == "L" else mirror)
            pts, tang, nrm = lay_path(scale(base), spec.depth, skin, grid, closed=spec.closed,
                                      n=32 if spec.closed else 24, along_z=spec.ring)
            k = len(pts)
            W = np.interp(np.linspace(0, 1, k), [0, 1], spec.width)
            H = np.interp(np.linspace(0, 1, k), [0, 1], spec.thickness)
            reach = float(W.max() + H.max()) + 12.0
            lo, hi = pts.min(0) - reach, pts.max(0) + reach
            cand = np.flatnonzero(np.all((centroid > lo) & (centroid < hi), axis=1))
            Pc = np.ascontiguousarray(P.reshape(len(tets), q, 3)[cand].reshape(-1, 3))
            inside, fib = _inside_ribbon(Pc, pts, tang, nrm, W, H, spec.closed)
            inside = inside.reshape(-1, q)
            frac = inside.mean(axis=1)
            f = fib.reshape(-1, q, 3) * inside[:, :, None]
            # a fibre field that reverses within a tet (ring ends) is averaged by sign-aligned sum
            ref = fib.reshape(-1, q, 3)[:, 0]
            sign = np.sign(np.einsum("tqj,tj->tq", fib.reshape(-1, q, 3), ref))
            fsum = (f * sign[:, :, None]).sum(axis=1)
            keep = (frac >= min_fraction) & (np.linalg.norm(fsum, axis=1) > 1e-9)
            m = len(names)
            names.append(f"{spec.name}_{side}")
            sides.append(side)
            sig.append(spec.sigma_max)
            e_m.append(np.full(keep.sum(), m, np.int32))
            e_t.append(cand[keep].astype(np.int32))
            e_f.append(frac[keep])
            e_d.append(fsum[keep] / np.linalg.norm(fsum[keep], axis=1, keepdims=True))
            paths[names[-1]] = (pts, tang)
    muscles = MuscleSet(names=tuple(names), sides=tuple(sides), sigma_max=np.array(sig),
                        muscle=np.concatenate(e_m), tet=np.concatenate(e_t), fraction=np.concatenate(e_f),
                        fibre=np.concatenate(e_d))
    return muscles, paths
