"""Anatomical landmarks of an imported face: found on the meshes, read from and written to JSON,
and the TMJ geometry built from them.

Every landmark is a point in mm in facesim's frame (x left, y up, z forward, origin between the
condyles). The finder works on surfaces already in that frame (:func:`detect`), or on the
user's surfaces with a :class:`~facesim.importing.frame.FrameFit` (:func:`find_landmarks`).
"Midline" means the midsagittal section of a surface (the plane x = ``x_mid``, the fitted
symmetry plane) together with its vertices within ``MIDLINE_MM`` of it; "front" the largest z,
"top" the largest y. Extremes of bone points are soft (:func:`soft_extreme`: a mean weighted by
``exp((score - max) / SOFT_MM)``), so a landmark moves continuously with the frame.

Bones (always, from the mandible; the teeth and cranium when given):

* ``condyle_left`` / ``condyle_right``: centre of each condylar head. The head's top is the
  highest point within 10 mm of the mandible's posterior-superior extreme on that side
  (largest ``y cos 30 - z sin 30``); its
  centre lies below the top by the head's radius (the circle through the top and the ends of
  its antero-posterior chord ``CAP_MM`` below it) or its antero-posterior half-thickness (the
  largest down to there), whichever is less (an oval head is flatter on top than round), in
  the middle of that cross-section in x and z.
* ``incisor``: the lower incisal point: the top of the lower teeth's midline (leaning to the
  front: the largest ``y + 0.5 z``), on each side of the midline, and the mean of the two (the
  tip between the central incisors); without lower teeth the top of the mandible's midline (the
  alveolar crest between the lower incisors, infradentale).
* ``upper_incisor``: the same with the lowest point of the upper teeth's midline;
  without upper teeth the lowest midline point of the cranium within 30 mm of the lower
  incisal point and above it (prosthion).
* ``menton``: lowest midline point of the mandible; ``pogonion``: most anterior midline point of
  the mandible below halfway from the menton up to its top.
* ``gonion_left`` / ``gonion_right``: the mandibular angle: the mandible point farthest along the
  bisector of the angle between the tangent to the lower border through the menton and the
  tangent to the posterior border of the ramus through the back of the condyle.

Skin (when given), on its depth map seen from the front (the largest z of the skin at every
point of a 0.5 mm grid in x, y; the profile is its column at x = ``x_mid``):

* ``pronasale``: the most anterior skin point within 12 mm of the midline between 5 and 90 mm
  above the upper incisal point.
* ``nasion``: the profile point deepest behind the chord from the pronasale to the profile 60 mm
  above it; where the skin ends sooner (a mask open around the eyes) the chord ends at its top
  and the landmark is marked as an estimate in ``how``.
* ``stomion``: the deepest point of the profile between 8 mm below the lower incisal point and
  8 mm above the upper one (the crease or gap between the lips); across a gap (rows of the depth
  map with no skin between rows with skin, however far apart the lips' depths), the midpoint of
  the lips' edges above and below it (those edges are the ends of the lips' profiles below).
* ``subnasale``: the profile point deepest behind the chord pronasale - upper lip's edge (where
  the nose meets the lip); ``labiale_superius``: the profile point farthest in front of the
  chord subnasale - upper lip's edge; ``labiale_inferius``: most anterior profile point within
  15 mm below the lower lip's edge; ``soft_pogonion``: most anterior profile point between the menton's height and
  halfway up to the labiale inferius.
* ``cheilion_left`` / ``cheilion_right``: the mouth corners: the lips' crease followed outward
  from the stomion column by column of the depth map, within 3 mm of its height in the last
  column, until it is shallower than 1 mm; the corner is its last point.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from facesim.errors import FacesimError

if TYPE_CHECKING:
    from facesim.importing.frame import FrameFit
    from facesim.importing.meshes import Surface
    from facesim.model import JawGeometry

#: The landmark names, bones first (another module relies on these exact names).
BONE_LANDMARKS = ("condyle_left", "condyle_right", "incisor", "upper_incisor", "menton", "pogonion",
                  "gonion_left", "gonion_right")
SKIN_LANDMARKS = ("pronasale", "subnasale", "nasion", "stomion", "cheilion_left", "cheilion_right",
                  "labiale_superius", "labiale_inferius", "soft_pogonion")
LANDMARK_NAMES = BONE_LANDMARKS + SKIN_LANDMARKS

#: Half-width (mm) of the midline slab whose vertices join the midsagittal section.
MIDLINE_MM = 3.0
#: Depth (mm) below the condyle's top of the cross-section that measures the head's radius.
CAP_MM = 4.0
#: Grid step of the skin's depth map, mm.
DEPTH_STEP_MM = 0.5
#: A crease of the lips shallower than this (mm) has ended: the mouth corner.
CREASE_MM = 1.0

#: ``how`` of the incisal points found on bone (no teeth given): another point than on teeth.
HOW_INFRADENTALE = "top of the mandible's midline (infradentale; no lower teeth)"
HOW_PROSTHION = "lowest midline point of the cranium above the lower incisor (prosthion; no upper teeth)"

FORMAT = "facesim-landmarks"
VERSION = 1


# ============================================================================ geometry helpers
def section(V: np.ndarray, E: np.ndarray, x: float) -> np.ndarray:
    """(k, 3) points where the edges ``E (e, 2)`` of ``V (n, 3)`` cross the plane X = ``x``."""
    a, b = V[E[:, 0]], V[E[:, 1]]
    da, db = a[:, 0] - x, b[:, 0] - x
    cross = (da < 0) != (db < 0)
    t = da[cross] / (da[cross] - db[cross])
    return a[cross] + t[:, None] * (b[cross] - a[cross])


def midline(mesh: "Mesh", x_mid: float, half_width: float = MIDLINE_MM) -> np.ndarray:
    """(k, 3) the midsagittal section of ``mesh`` at x = ``x_mid`` and its vertices within
    ``half_width`` of that plane."""
    V = mesh.V
    return np.concatenate([section(V, mesh.E, x_mid), V[np.abs(V[:, 0] - x_mid) <= half_width]])


#: Width (mm) of the soft maximum that turns "the highest point" into a weighted mean of the
#: nearly highest points: a landmark then moves continuously with the frame instead of jumping
#: between the vertices of a flat crown or a flat chin.
SOFT_MM = 0.3


def soft_extreme(P: np.ndarray, score: np.ndarray, tau: float = SOFT_MM) -> np.ndarray:
    """(3,) the mean of the points ``P (k, 3)`` weighted by ``exp((score - max score) / tau)``:
    the point of largest ``score`` (mm), softened over a width ``tau``."""
    w = np.exp((score - score.max()) / tau)
    return (w[:, None] * P).sum(axis=0) / w.sum()


def _extreme(P: np.ndarray, key: np.ndarray, band: float, then: np.ndarray) -> np.ndarray:
    """The (soft) extreme of ``key``, leaning toward large ``then`` (half as much)."""
    del band
    return soft_extreme(P, key + 0.5 * then)


def edges_of(F: np.ndarray) -> np.ndarray:
    """(e, 2) the unique edges (sorted node pairs) of the triangles ``F``."""
    return np.unique(np.sort(np.asarray(F)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)


def _incisal(P: np.ndarray, x_mid: float, down: bool) -> np.ndarray:
    """The incisal point between the central incisors from midline points ``P``: on each side of
    the midline the highest (``down``: lowest) point, leaning to the front (soft); their
    mean (one side alone if the other has none)."""
    key = -P[:, 1] if down else P[:, 1]
    # points within 0.25 mm of the midline count on both sides (a vertex on it must not flip)
    sides = (P[:, 0] >= x_mid - 0.25, P[:, 0] <= x_mid + 0.25)
    tips = [_extreme(P[s], key[s], 1.0, P[s][:, 2]) for s in sides if s.any()]
    return np.mean(tips, axis=0)


@dataclass(frozen=True)
class Mesh:
    """A surface in facesim's frame: ``V (n, 3)`` mm, ``F (m, 3)`` int, ``E (e, 2)`` its edges
    (computed when not given; pass them when the same faces are moved many times)."""

    V: np.ndarray
    F: np.ndarray
    E: np.ndarray | None = None

    def __post_init__(self):
        if self.E is None:
            object.__setattr__(self, "E", edges_of(self.F))

    @staticmethod
    def join(meshes: Sequence["Mesh"]) -> "Mesh | None":
        meshes = [m for m in meshes if m is not None]
        if not meshes:
            return None
        if len(meshes) == 1:
            return meshes[0]
        off = np.cumsum([0] + [len(m.V) for m in meshes])
        return Mesh(np.concatenate([m.V for m in meshes]), np.concatenate([m.F + o for m, o in zip(meshes, off)]),
                    np.concatenate([m.E + o for m, o in zip(meshes, off)]))


# =============================================================================== the bones
def condyle(mandible: "Mesh", side: float, x_mid: float) -> tuple[np.ndarray, str]:
    """The condylar head's centre on ``side`` (+1 left, -1 right) of the mandible (mm, facesim
    frame); see the module docstring. Returns ``(point (3,), how)``."""
    V, e = mandible.V, mandible.E
    lat = side * (V[:, 0] - x_mid)
    S = V[lat > 0.3 * lat.max()]
    a = np.deg2rad(30.0)
    extreme = S[np.argmax(S[:, 1] * np.cos(a) - S[:, 2] * np.sin(a))]
    near = S[np.linalg.norm(S - extreme, axis=1) < 10.0]
    top = near[np.argmax(near[:, 1])]                  # the highest point of that process
    # cross-sections of the head below its top: where mandible edges cross each height
    pa, pb = V[e[:, 0]], V[e[:, 1]]
    near = np.linalg.norm((pa - top)[:, [0, 2]], axis=1) < 20.0
    pa, pb = pa[near], pb[near]

    def cut(depth):
        y = top[1] - depth
        cross = (pa[:, 1] < y) != (pb[:, 1] < y)
        t = (y - pa[cross, 1]) / (pb[cross, 1] - pa[cross, 1])
        C = pa[cross] + t[:, None] * (pb[cross] - pa[cross])
        return C[np.linalg.norm((C - top)[:, [0, 2]], axis=1) < 15.0]

    C = cut(CAP_MM)
    if len(C) < 3:
        return top - np.array([0.0, 5.0, 0.0]), "condylar head top lowered 5 mm (its cross-section was not found)"
    chord = 0.5 * np.ptp(C[:, 2])
    radius = float(np.clip((chord ** 2 + CAP_MM ** 2) / (2 * CAP_MM), 2.0, 10.0))
    # an oval head is flatter on top than round: its centre lies no deeper than its half-thickness
    widths = [np.ptp(c[:, 2]) for h in np.arange(1.0, radius + 0.01, 0.5) if len(c := cut(h)) >= 3]
    depth = min(radius, 0.5 * max(widths))
    C = cut(depth)
    if len(C) < 3:
        C = cut(CAP_MM)
    lo, hi = C.min(axis=0), C.max(axis=0)
    centre = np.array([0.5 * (lo[0] + hi[0]), top[1] - depth, 0.5 * (lo[2] + hi[2])])
    return centre, f"condylar head: {depth:.1f} mm below its top (its radius or half-thickness)"


def gonion(V: np.ndarray, side: float, x_mid: float, menton: np.ndarray, cond: np.ndarray) -> tuple[np.ndarray, str]:
    """The mandibular angle on ``side``; see the module docstring."""
    lat = side * (V[:, 0] - x_mid)
    S = V[lat > 0.3 * lat.max()]
    yz = S[:, [1, 2]]
    # lower border: the tangent from the menton touching the border behind it (lowest line)
    m = menton[[1, 2]]
    behind = yz[:, 1] < m[1] - 10.0
    if not behind.any():
        return S[np.argmax(-S[:, 1] - S[:, 2])], "the mandible's down-back extreme (no lower border found)"
    d = yz[behind] - m
    p1 = yz[behind][np.argmin(np.arctan2(d[:, 0], -d[:, 1]))]
    t1 = (p1 - m) / np.linalg.norm(p1 - m)
    n1 = np.array([-t1[1], t1[0]])
    n1 = n1 if n1[0] < 0 else -n1                          # points down
    # posterior border of the ramus: the tangent from the back of the condyle touching it below
    c = np.array([cond[1], cond[2] - 5.0])
    below = yz[:, 0] < c[0] - 10.0
    d = yz[below] - c
    p2 = yz[below][np.argmax(np.arctan2(-d[:, 1], -d[:, 0]))]
    t2 = (p2 - c) / np.linalg.norm(p2 - c)
    n2 = np.array([-t2[1], t2[0]])
    n2 = n2 if n2[1] < 0 else -n2                          # points back
    b = n1 + n2
    b /= np.linalg.norm(b)
    return S[np.argmax(yz @ b)], "extreme of the mandibular angle along the bisector of the border tangents"


def bone_landmarks(mandible: Mesh, cranium: Mesh | None, teeth_upper: Mesh | None, teeth_lower: Mesh | None,
                   x_mid: float = 0.0) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The bone landmarks (mm, facesim frame) of surfaces already in facesim's frame; see the
    module docstring. Returns ``(landmarks, how)``."""
    out, how = {}, {}
    V = mandible.V
    for name, side in (("condyle_left", 1.0), ("condyle_right", -1.0)):
        out[name], how[name] = condyle(mandible, side, x_mid)
    mid = midline(mandible, x_mid)
    if len(mid) < 3:
        raise FacesimError("mandible: its midline could not be found (is it a whole mandible?)")
    out["menton"], how["menton"] = soft_extreme(mid, -mid[:, 1]), "lowest midline point of the mandible"
    infradentale = _extreme(mid, mid[:, 1], 1.0, mid[:, 2])
    low = mid[mid[:, 1] < 0.5 * (out["menton"][1] + infradentale[1])]
    out["pogonion"] = soft_extreme(low, low[:, 2])
    how["pogonion"] = "most anterior midline point of the mandible's lower half"
    if teeth_lower is not None and len(t := midline(teeth_lower, x_mid)):
        out["incisor"], how["incisor"] = _incisal(t, x_mid, down=False), "top of the lower teeth's midline"
    else:
        out["incisor"], how["incisor"] = infradentale, HOW_INFRADENTALE
    inc = out["incisor"]
    if teeth_upper is not None and len(t := midline(teeth_upper, x_mid)):
        out["upper_incisor"] = _incisal(t, x_mid, down=True)
        how["upper_incisor"] = "bottom of the upper teeth's midline"
    elif cranium is not None:
        t = midline(cranium, x_mid)
        t = t[(np.linalg.norm(t - inc, axis=1) < 30.0) & (t[:, 1] > inc[1] - 3.0)]
        if len(t):
            out["upper_incisor"] = _extreme(t, -t[:, 1], 1.0, t[:, 2])
            how["upper_incisor"] = HOW_PROSTHION
    for name, side in (("gonion_left", 1.0), ("gonion_right", -1.0)):
        cond = out["condyle_left" if side > 0 else "condyle_right"]
        out[name], how[name] = gonion(V, side, x_mid, out["menton"], cond)
    return out, how


# ================================================================================ the skin
@dataclass(frozen=True)
class DepthMap:
    """The skin seen from the front: ``z (nx, ny)`` largest z (mm; -inf where no skin) at
    ``(x0 + i h, y0 + j h)``."""

    z: np.ndarray
    x0: float
    y0: float
    h: float

    @staticmethod
    def of(mesh: Mesh, lo: np.ndarray, hi: np.ndarray, h: float = DEPTH_STEP_MM) -> "DepthMap":
        from facesim._kernels.importing import front_depth

        nx, ny = (np.ceil((np.asarray(hi) - lo) / h).astype(int) + 1)[:2]
        z = np.full((int(nx), int(ny)), -np.inf)
        front_depth(np.ascontiguousarray(mesh.V, dtype=np.float64), np.ascontiguousarray(mesh.F, dtype=np.int64),
                    float(lo[0]), float(lo[1]), float(h), z)
        return DepthMap(z, float(lo[0]), float(lo[1]), float(h))

    def i(self, x: float) -> int:
        return int(np.clip(round((x - self.x0) / self.h), 0, self.z.shape[0] - 1))

    def j(self, y: float) -> int:
        return int(np.clip(round((y - self.y0) / self.h), 0, self.z.shape[1] - 1))

    def point(self, i: int, j: int) -> np.ndarray:
        return np.array([self.x0 + i * self.h, self.y0 + j * self.h, self.z[i, j]])


def _profile_range(dm: DepthMap, i: int, y_lo: float, y_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``j`` and depths of column ``i`` with y in [y_lo, y_hi] (any order)."""
    lo, hi = sorted((dm.j(y_lo), dm.j(y_hi)))
    j = np.arange(lo, hi + 1)
    return j, dm.z[i, j]


def _inner_gap(finite: np.ndarray) -> tuple[int, int] | None:
    """The longest run ``(first, last)`` of False in ``finite`` with True on both sides, or None."""
    best = None
    k, n = 0, len(finite)
    while k < n:
        if finite[k]:
            k += 1
            continue
        e = k
        while e + 1 < n and not finite[e + 1]:
            e += 1
        if k > 0 and e < n - 1 and (best is None or e - k > best[1] - best[0]):
            best = (k, e)
        k = e + 1
    return best


def _most_forward(dm: DepthMap, i: int, y_lo: float, y_hi: float) -> np.ndarray | None:
    j, z = _profile_range(dm, i, y_lo, y_hi)
    if not np.isfinite(z).any():
        return None
    k = int(np.argmax(z))
    return dm.point(i, int(j[k]))


def _deepest_behind(dm: DepthMap, i: int, a: np.ndarray, b: np.ndarray, sign: float = 1.0) -> np.ndarray | None:
    """The profile point between the heights of ``a`` and ``b`` farthest behind their chord
    (``sign`` -1: farthest in front of it)."""
    j, z = _profile_range(dm, i, a[1], b[1])
    y = dm.y0 + j * dm.h
    inside = (y > min(a[1], b[1])) & (y < max(a[1], b[1])) & np.isfinite(z)
    if not inside.any() or a[1] == b[1]:
        return None
    chord = a[2] + (y - a[1]) / (b[1] - a[1]) * (b[2] - a[2])
    k = np.flatnonzero(inside)[np.argmax(sign * (chord - z)[inside])]
    return dm.point(i, int(j[k]))


def skin_landmarks(skin: Mesh, bones: dict[str, np.ndarray], x_mid: float = 0.0) -> tuple[dict, dict]:
    """The skin landmarks (mm, facesim frame) of a skin already in facesim's frame, using the
    bone landmarks ``bones`` for the search windows; see the module docstring."""
    out, how = {}, {}
    ui = bones.get("upper_incisor", bones["incisor"] + np.array([0.0, 2.0, 2.0]))
    li = bones["incisor"]
    lo = np.array([x_mid - 70.0, bones["menton"][1] - 40.0])
    hi = np.array([x_mid + 70.0, ui[1] + 160.0])
    dm = DepthMap.of(skin, lo, hi)
    im = dm.i(x_mid)
    # pronasale: the most anterior point near the midline above the mouth
    band = np.abs(dm.x0 + dm.h * np.arange(dm.z.shape[0]) - x_mid) <= 12.0
    rows = np.arange(dm.j(ui[1] + 5.0), dm.j(ui[1] + 90.0) + 1)
    sub = np.where(band[:, None], dm.z[:, rows], -np.inf)
    if not np.isfinite(sub).any():
        return out, how
    i, k = np.unravel_index(np.argmax(sub), sub.shape)
    prn = dm.point(int(i), int(rows[k]))
    out["pronasale"], how["pronasale"] = prn, "most anterior skin point near the midline above the mouth"
    # nasion: deepest behind the chord from the pronasale to 60 mm above it (or the skin's top)
    j, z = _profile_range(dm, im, prn[1], prn[1] + 60.0)
    valid = np.flatnonzero(np.isfinite(z))
    if len(valid) and dm.y0 + j[valid[-1]] * dm.h > prn[1] + 10.0:
        top = dm.point(im, int(j[valid[-1]]))
        nas = _deepest_behind(dm, im, prn, top)
        if nas is not None:
            out["nasion"] = nas
            short = top[1] < prn[1] + 59.0
            how["nasion"] = ("estimate: the skin ends %.0f mm above the nose tip, the deepest point of the profile "
                             "below its top edge" % (top[1] - prn[1])) if short else \
                "deepest point of the profile behind the chord from the nose tip to 60 mm above it"
            if short and np.linalg.norm(nas - top) < 3.0:
                how["nasion"] += " (at the edge: the skin is open there)"
    # stomion: the deepest point (or gap) of the profile at the teeth; the lips' edges round it
    j, z = _profile_range(dm, im, li[1] - 8.0, ui[1] + 8.0)
    finite = np.isfinite(z)
    if finite.any():
        gap = _inner_gap(finite)
        if gap is not None:   # the lips are apart: rows with no skin between rows with skin
            a, b = gap
        else:                 # they touch in the profile: the crease, where it is deeper than 5 mm
            deep = z < np.max(z) - 5.0
            k = int(np.argmin(z))
            a = b = k
            if deep[k]:
                while a > 0 and deep[a - 1]:
                    a -= 1
                while b < len(z) - 1 and deep[b + 1]:
                    b += 1
            if not (deep[k] and a > 0 and b < len(z) - 1):
                a = b = None
        if a is not None:
            lower, upper = dm.point(im, int(j[a - 1])), dm.point(im, int(j[b + 1]))
            st = 0.5 * (lower + upper)
            how["stomion"] = "midpoint of the lips' edges across the " + ("gap" if gap else "crease") + " between them"
        else:
            st = upper = lower = dm.point(im, int(j[int(np.argmin(np.where(finite, z, np.inf)))]))
            how["stomion"] = "deepest point of the profile between the lips"
        out["stomion"] = st
    if "stomion" in out:
        sn = _deepest_behind(dm, im, prn, upper)
        if sn is not None:
            out["subnasale"], how["subnasale"] = sn, "deepest profile point behind the chord nose tip - upper lip's edge"
            ls = _deepest_behind(dm, im, sn, upper, sign=-1.0)
            if ls is not None:
                out["labiale_superius"] = ls
                how["labiale_superius"] = "profile point farthest in front of the chord subnasale - upper lip's edge"
        lb = _most_forward(dm, im, lower[1] - 15.0, lower[1])
        if lb is not None:
            out["labiale_inferius"], how["labiale_inferius"] = lb, "most anterior point of the lower lip's profile"
            sp = _most_forward(dm, im, bones["menton"][1], 0.5 * (lb[1] + bones["menton"][1]))
            if sp is not None:
                out["soft_pogonion"], how["soft_pogonion"] = sp, "most anterior point of the chin's profile"
        for name, step in (("cheilion_left", 1), ("cheilion_right", -1)):
            c = _mouth_corner(dm, im, out["stomion"], step)
            if c is not None:
                out[name], how[name] = c, "end of the lips' crease followed outward from the stomion"
    return out, how


def _mouth_corner(dm: DepthMap, i0: int, st: np.ndarray, step: int) -> np.ndarray | None:
    """The lateral end of the lips' crease, followed column by column from ``i0`` toward
    ``step`` (+1: +x)."""
    y = st[1]
    last = None
    n_lip = int(round(6.0 / dm.h))
    for i in range(i0, i0 + step * int(round(60.0 / dm.h)), step):   # columns of the map, ~120
        if not 0 <= i < dm.z.shape[0]:
            break
        j, z = _profile_range(dm, i, y - 3.0, y + 3.0)
        zz = np.where(np.isfinite(z), z, -1e9)
        k = int(np.argmin(zz))
        jc = int(j[k])
        above = dm.z[i, jc + 1:jc + 1 + n_lip]
        below = dm.z[i, max(jc - n_lip, 0):jc]
        if not (np.isfinite(above).any() and np.isfinite(below).any()):
            break
        depth = min(np.max(above[np.isfinite(above)]), np.max(below[np.isfinite(below)])) - zz[k]
        if depth < CREASE_MM or abs(dm.y0 + jc * dm.h - st[1]) > 12.0:
            break
        y = dm.y0 + jc * dm.h
        zc = dm.z[i, jc] if np.isfinite(dm.z[i, jc]) else 0.5 * (np.max(above[np.isfinite(above)]) +
                                                                 np.max(below[np.isfinite(below)]))
        last = np.array([dm.x0 + i * dm.h, y, zc])
    return last


def detect(mandible: Mesh, cranium: Mesh | None = None, skin: Mesh | None = None, teeth_upper: Mesh | None = None,
           teeth_lower: Mesh | None = None, x_mid: float = 0.0) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """All landmarks of surfaces already in facesim's frame (mm): the bones', then the skin's
    when a skin is given. Returns ``(landmarks, how)``, ``{name: (3,) float64}`` and
    ``{name: one line}``, in the order of :data:`LANDMARK_NAMES`."""
    out, how = bone_landmarks(mandible, cranium, teeth_upper, teeth_lower, x_mid)
    if skin is not None:
        s, h = skin_landmarks(skin, out, x_mid)
        out.update(s)
        how.update(h)
    order = [n for n in LANDMARK_NAMES if n in out]
    return {n: np.asarray(out[n], dtype=np.float64) for n in order}, {n: how[n] for n in order}


def find_landmarks(fit: "FrameFit", mandible: "Surface", cranium: Sequence["Surface"] = (), skin: "Surface | None" = None,
                   teeth_upper: "Surface | None" = None, teeth_lower: "Surface | None" = None,
                   overrides: "LandmarkFile | None" = None) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The landmarks (mm, facesim frame) of the user's surfaces (input units and frame), placed
    in facesim's frame by ``fit``; ``overrides`` (a user file, see :func:`load_landmarks`)
    replace found ones and add missing ones. Returns ``(landmarks, how)``."""
    def mesh(s):
        return None if s is None else Mesh(fit.to_facesim(s.vertices), s.faces)

    found, how = detect(mesh(mandible), Mesh.join([mesh(c) for c in cranium]), mesh(skin), mesh(teeth_upper),
                        mesh(teeth_lower), x_mid=fit.x_mid)
    if overrides is not None:
        for name, p in overrides.in_facesim(fit).items():
            found[name] = p
            how[name] = f"given in {overrides.path}"
        order = [n for n in LANDMARK_NAMES if n in found]
        found, how = {n: found[n] for n in order}, {n: how[n] for n in order}
    return found, how


# ============================================================================ files
@dataclass(frozen=True)
class LandmarkFile:
    """Landmarks read from a user's JSON file: ``points {name: (3,)}`` in ``frame`` (``"facesim"``:
    mm in facesim's frame; ``"input"``: the input meshes' frame) and units (``scale_to_mm``: a
    number, or None for the input meshes' own units)."""

    points: dict
    frame: str
    scale_to_mm: float | None
    path: str

    def in_facesim(self, fit: "FrameFit | None" = None) -> dict[str, np.ndarray]:
        """The points in mm in facesim's frame (``fit`` needed for the input frame or units)."""
        if self.frame == "facesim" and self.scale_to_mm is not None:
            return {n: self.scale_to_mm * p for n, p in self.points.items()}
        if fit is None:
            raise FacesimError(f"{self.path}: landmarks in the input frame or units need the anatomical frame")
        scale = fit.scale_to_mm if self.scale_to_mm is None else self.scale_to_mm
        if self.frame == "facesim":
            return {n: scale * p for n, p in self.points.items()}
        return {n: fit.mm_to_facesim(scale * p[None])[0] for n, p in self.points.items()}


def load_landmarks(path) -> LandmarkFile:
    """Read landmarks from JSON: ``{"landmarks": {name: [x, y, z]}, "frame": "facesim" | "input",
    "units": "mm" | "cm" | "m" | "input"}`` (defaults: facesim, mm; ``"input"`` units are the
    input meshes' own). Names must be among :data:`LANDMARK_NAMES`; every failure is one line
    naming the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such file (expected a landmarks JSON file)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, ValueError) as exc:
        raise FacesimError(f"{path}: not a JSON file ({type(exc).__name__})") from None
    if not isinstance(data, dict) or not isinstance(data.get("landmarks"), dict):
        raise FacesimError(f"{path}: field 'landmarks': expected an object {{name: [x, y, z]}}")
    frame = data.get("frame", "facesim")
    if frame not in ("facesim", "input"):
        raise FacesimError(f"{path}: field 'frame': expected 'facesim' or 'input', got {frame!r}")
    units = data.get("units", "mm")
    scales = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "input": None}
    if units not in scales:
        raise FacesimError(f"{path}: field 'units': expected mm, cm, m or input, got {units!r}")
    points = {}
    for name, p in data["landmarks"].items():
        if name not in LANDMARK_NAMES:
            raise FacesimError(f"{path}: unknown landmark {name!r}; known: {', '.join(LANDMARK_NAMES)}")
        try:
            a = np.asarray(p, dtype=np.float64)
        except (TypeError, ValueError):
            a = np.zeros(0)
        if a.shape != (3,) or not np.isfinite(a).all():
            raise FacesimError(f"{path}: field 'landmarks.{name}': expected [x, y, z] of 3 finite numbers, got {p!r}")
        points[name] = a
    return LandmarkFile(points=points, frame=frame, scale_to_mm=scales[units], path=str(path))


def write_landmarks(path, landmarks: dict, how: dict | None = None, fit: "FrameFit | None" = None,
                    extra: dict | None = None) -> Path:
    """Write ``landmarks`` (mm, facesim frame) as JSON (atomically): ``{"format", "version",
    "units": "mm", "frame": "facesim", "landmarks": {name: [x, y, z]}, "how": {name: line},
    "input_frame": {...}}`` where ``input_frame`` (when ``fit`` is given) holds the 4x4
    ``T_facesim_from_input_mm``, ``scale_to_mm``, the input units' name and how the frame was
    found, so the points can be written back in the input frame. :func:`load_landmarks` reads it."""
    from facesim._files import atomic_write

    doc = {"format": FORMAT, "version": VERSION, "units": "mm", "frame": "facesim",
           "landmarks": {n: [round(float(v), 6) for v in landmarks[n]] for n in LANDMARK_NAMES if n in landmarks}}
    if how:
        doc["how"] = {n: how[n] for n in doc["landmarks"] if n in how}
    if fit is not None:
        doc["input_frame"] = fit.meta()
    if extra:
        doc.update(extra)
    text = json.dumps(doc, indent=2)
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text + "\n", encoding="utf-8"))


# ============================================================================== the TMJ
#: The procedural model's TMJ: the eminence 35 degrees below forward, 16 mm of sliding, 0.62 rad.
TRACK_ANGLE_DEG = 35.0
TRACK_LENGTH_MM = 16.0
MAX_OPENING_RAD = 0.62


def jaw_geometry_from_landmarks(landmarks: dict, track_angle_deg: float = TRACK_ANGLE_DEG,
                                track_length: float = TRACK_LENGTH_MM,
                                max_opening: float = MAX_OPENING_RAD) -> "JawGeometry":
    """The sliding-condyle TMJ (:class:`facesim.model.JawGeometry`, mm, facesim frame) from the
    landmarks ``condyle_left``, ``condyle_right`` and ``incisor``: tracks ``track_angle_deg`` below
    forward (the articular eminence; made perpendicular to the intercondylar axis), ``track_length``
    mm long (an adult's condyle slides 12-20 mm), opening up to ``max_opening`` rad, as the
    procedural model."""
    from facesim.model import JawGeometry

    missing = [n for n in ("condyle_left", "condyle_right", "incisor") if n not in landmarks]
    if missing:
        raise FacesimError(f"jaw geometry: landmarks {', '.join(missing)} missing")
    left, right = (np.asarray(landmarks[n], float) for n in ("condyle_left", "condyle_right"))
    u = left - right
    u /= np.linalg.norm(u)
    a = np.deg2rad(track_angle_deg)
    v = np.array([0.0, -np.sin(a), np.cos(a)])
    v -= (v @ u) * u
    v /= np.linalg.norm(v)
    return JawGeometry(condyle_right=right, condyle_left=left, track_direction=v, track_length=track_length,
                       max_opening=max_opening, incisor=np.asarray(landmarks["incisor"], float))
