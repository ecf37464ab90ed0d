"""The empirical jaw rig on Posselt's envelope (Zoss, Bradley, Bérard, Beeler 2018).

The lower incisal point (the reference point) of a jaw can only reach a bounded volume, Posselt's
envelope of motion, shaped like a shield. Every point inside it is reached by essentially one
mandible pose, so the rig maps a 3D point to a 6D pose (eq. 3) and exposes three controls: the
point itself (direct manipulation) or three sliders in the unit cube.

Pieces, all in the jaw frame (:mod:`facesim.jaw.frame`; x left, y up, z forward, origin at the
reference point at rest):

- ``Shield`` -- the envelope surface from captured border movements (section 3.4): six curves
  from tooth contact (s_y = 0) down to the maximum opening (s_y = 1), each fitted by a smoothing
  spline (least squares, cubic) of its lateral and antero-posterior coordinates against its
  normalised height: the
  posterior (retruded) and anterior (protruded) midline curves and the four vertical boundary
  curves at the right/left posterior and anterior corners. The unit cube maps onto the envelope::

      S(s) = (1 − s_z) E(C_RP, P, C_LP; s_x) + s_z E(C_RA, A, C_LA; s_x)     (curves at s_y)

  where E runs linearly from the right corner curve (s_x = 0) to the midline curve (s_x = 1/2)
  and on to the left corner curve (s_x = 1): the horizontal sections are the "gothic arch" of
  the envelope, with the midline curves as its ridges. The six cube faces map to the six faces
  of the shield; ``bijectivity`` measures how far the map is from folding (eq. 15).
- ``PosseltRig`` -- the RBF map (eq. 3): the pose of a reference-point position p is the
  rotation ``exp(omega(p))`` about the reference point followed by the translation taking it to
  p, with omega(p) = Σ_i w_i phi(|p − c_i|) + a + B p a cubic radial basis function
  (phi(r) = r³) over centres c_i chosen by farthest-point sampling, fitted to the captured
  (p, omega) pairs by ridge-regularised least squares (eq. 9). The translation is thus exact
  (the point is where it is asked to be) and only the rotation is interpolated.
- Points outside the envelope are projected onto the shield (the closest point of the
  parameterised solid), so the rig only produces poses the subject could reach.
- ``detect_border`` -- the six border curves found in an unlabelled capture (no movement labels),
  from the reference-point cloud alone, however the capture covered the border: the border
  protocol in any order and speed, or mostly chewing with a few maximal excursions. The shield
  is then the envelope of what was captured:

  * consecutive frames are joined by the segment between them (the jaw went that way), so a
    border movement passed in two or three frames still bounds the cloud;
  * the cloud is cut into horizontal sections every ``step`` mm of height, each the section of
    the convex hull of the points within ``slab`` mm of it (the envelope is convex at that
    scale, not over its whole height);
  * the midline runs from the rest position (the frame origin) to the deepest point; the
    posterior and anterior curves are the back and front of the sections of the points within
    ``band`` mm of it (the bottom of the envelope can be concave there: the lateral openings end
    behind the maximum opening);
  * the four corner curves are searched on the right and left halves of the sections: each
    starts where it leaves tooth contact, the cloud's extreme point in an upward tilted direction
    (right posterior back-right-up, right anterior front-right-up, mirrored on the left), takes
    in each section the extreme point along the bisector of the outward normals of the two
    hexagon edges meeting at it (edges to the nearest corners at least ``apart`` mm away, so two
    corners on one border path act as one; the extreme nearest the curve so far among those
    within ``tie`` mm), and ends where it turns onto the bottom face (moving inward faster than
    down).

  A movement the capture lacks altogether (no wide opening, protrusion, or lateral excursion to
  one side) is named in a one-line error. The curves are then fitted like labelled frames
  (``Shield.from_points``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline, make_lsq_spline
from scipy.linalg import solve
from scipy.spatial import ConvexHull, QhullError

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import BORDER_CURVES
from facesim.jaw.points import farthest_points
from facesim.jaw.rigfile import load_rig, save_rig
from facesim.model import JawGeometry

CURVES = BORDER_CURVES    # ("posterior", "anterior", "right_posterior", "left_posterior", "right_anterior", "left_anterior")
_KNOTS = 41               # samples stored per curve, s_y = linspace(0, 1, _KNOTS)


# --- the envelope ------------------------------------------------------------------------------

def _fit_curve(points: np.ndarray, name: str) -> np.ndarray:
    """``(_KNOTS, 3)`` samples of one border curve from its reference-point positions ``(n, 3)``
    (jaw frame, mm): x and z smoothed against t = normalised depth below the highest point."""
    if len(points) < 8:
        raise FacesimError(f"border movement {name!r}: expected at least 8 frames, got {len(points)}")
    y = points[:, 1]
    top, bottom = y.max(), y.min()
    if top - bottom < 5.0:
        raise FacesimError(f"border movement {name!r}: the reference point moves only {top - bottom:.1f} mm "
                           f"vertically (expected an opening to the maximum)")
    t = (top - y) / (top - bottom)
    # average repeated depths (opening and closing passes), then a least-squares cubic spline
    # with knots at quantiles of the data (so every knot span holds data)
    bins = np.clip((t * 80).astype(int), 0, 79)
    used = np.unique(bins)
    tb = np.array([t[bins == b].mean() for b in used])
    xz = np.array([points[bins == b][:, [0, 2]].mean(axis=0) for b in used])
    knots = np.linspace(0.0, 1.0, _KNOTS)
    out = np.empty((_KNOTS, 3))
    out[:, 1] = top - knots * (top - bottom)
    n_inner = int(np.clip(len(tb) // 6, 0, 10))
    if len(tb) >= 6:
        inner = np.quantile(tb, np.linspace(0, 1, n_inner + 2)[1:-1])
        inner = inner[(inner > tb[0] + 1e-9) & (inner < tb[-1] - 1e-9)]
        tk = np.r_[[tb[0]] * 4, inner, [tb[-1]] * 4]
        spline = make_lsq_spline(tb, xz, tk, k=3)
        out[:, [0, 2]] = spline(np.clip(knots, tb[0], tb[-1]))
    else:
        out[:, [0, 2]] = np.stack([np.interp(knots, tb, xz[:, k]) for k in range(2)], axis=1)
    return out


def _untangle(curves: np.ndarray, gap: float = 0.05) -> np.ndarray:
    """Curves ``(6, K, 3)`` with every anterior curve at least ``gap`` mm in front of its
    posterior partner and every section ordered right < midline < left by ``gap`` mm.

    Toward the maximum opening the sections shrink to a line and the fitted curves, each
    carrying its own noise, may cross by a fraction of a millimetre; crossing pairs are moved
    apart symmetrically about their mean, so the cube map cannot fold over itself."""
    c = curves.copy()
    idx = {name: i for i, name in enumerate(CURVES)}

    def separate(lo, hi, axis):
        a, b = c[lo, :, axis], c[hi, :, axis]
        short = b - a < gap
        mean = 0.5 * (a + b)
        c[lo, short, axis], c[hi, short, axis] = mean[short] - gap / 2, mean[short] + gap / 2

    for back, front in (("posterior", "anterior"), ("right_posterior", "right_anterior"),
                        ("left_posterior", "left_anterior")):
        separate(idx[back], idx[front], 2)
    for right, mid, left in (("right_posterior", "posterior", "left_posterior"),
                             ("right_anterior", "anterior", "left_anterior")):
        separate(idx[right], idx[mid], 0)
        separate(idx[mid], idx[left], 0)
    return c


_RING = ("posterior", "right_posterior", "right_anterior", "anterior", "left_anterior", "left_posterior")
#: degrees from +x toward +z of the horizontal part of the directions that find the corner tops
_TOP_DIRECTIONS = {"right_posterior": 210.0, "right_anterior": 120.0, "left_anterior": 60.0, "left_posterior": 330.0}
_TOP_TILT = 1.0           # weight of the height in those directions (and in the corners' ends)
#: a movement counts as present when at least this many frames go this far (mm) from rest
_EXCURSION = {"opening": 10.0, "protrusion": 2.0, "lateral": 2.0}
_EXCURSION_FRAMES = 2
_CURVE_WORDS = {"posterior": "posterior border (the retruded opening)",
                "anterior": "anterior border (the protruded opening)",
                "right_posterior": "right posterior border (the opening from the right lateral excursion)",
                "right_anterior": "right anterior border (the opening from the right protrusive corner)",
                "left_anterior": "left anterior border (the opening from the left protrusive corner)",
                "left_posterior": "left posterior border (the opening from the left lateral excursion)"}


def _edge_normal(a, b):
    """Outward unit normal ``(2,)`` in (x, z) of the hexagon edge a -> b (the ring is clockwise
    there), or None when the edge is shorter than 0.5 mm."""
    e = b - a
    length = np.hypot(e[0], e[1])
    return None if length < 0.5 else np.array([-e[1], e[0]]) / length


def _densify(P, spacing: float, link: float) -> np.ndarray:
    """``P (n, 3)`` followed by points every ``spacing`` mm along the segments between consecutive
    frames that are more than ``spacing`` and at most ``link`` mm apart (the jaw went that way)."""
    d = np.linalg.norm(np.diff(P, axis=0), axis=1)
    k = np.where((d > spacing) & (d <= link), np.ceil(d / spacing).astype(int) - 1, 0)
    if not k.any():
        return P
    i = np.repeat(np.arange(len(d)), k)
    t = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k) + 1) / np.repeat(k + 1, k)
    return np.concatenate([P, P[i] + t[:, None] * (P[i + 1] - P[i])])


def _hull(q):
    """Counter-clockwise vertices of the convex hull of the 2D points ``q (k, 2)``, or None."""
    try:
        return q[ConvexHull(q).vertices] if len(q) >= 3 else None
    except (QhullError, ValueError):
        return None


def _section(P, level: float, slab: float):
    """``(k, 2)`` (x, z) vertices of the section at height ``level`` of the convex hull of the
    points ``P (n, 3)`` within ``slab`` mm of that height (the hull's edges cut by the plane); the
    hull of their horizontal projection when they span no volume; None when there are none."""
    near = P[np.abs(P[:, 1] - level) <= slab]
    if len(near) < 4:
        return _hull(near[:, [0, 2]])
    try:
        s = ConvexHull(near).simplices
    except (QhullError, ValueError):
        return _hull(near[:, [0, 2]])
    e = np.unique(np.sort(np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [0, 2]]]), axis=1), axis=0)
    a, b = near[e[:, 0]], near[e[:, 1]]
    da, db = a[:, 1] - level, b[:, 1] - level
    cut = (da * db <= 0) & (da != db)
    q = a[cut] + (da[cut] / (da[cut] - db[cut]))[:, None] * (b[cut] - a[cut])
    return _hull(q[:, [0, 2]])


def _midline_extent(Q, level: float, slab: float):
    """(back z, front z) mm at height ``level`` of the section of the convex hull of the (y, z)
    points ``Q (n, 2)`` within ``slab`` mm of that height, or None."""
    near = Q[np.abs(Q[:, 0] - level) <= slab]
    v = _hull(near)
    if v is None:
        return (near[:, 1].min(), near[:, 1].max()) if len(near) else None
    u = np.roll(v, -1, axis=0)
    da, db = v[:, 0] - level, u[:, 0] - level
    cut = (da * db <= 0) & (da != db)
    if not cut.any():
        return None
    z = v[cut, 1] + da[cut] / (da[cut] - db[cut]) * (u[cut, 1] - v[cut, 1])
    return z.min(), z.max()


def _check_movements(depth, forward, lateral):
    """Raise a one-line error naming each border movement the capture lacks: ``depth``,
    ``forward``, ``lateral`` (N,) mm of every frame below, in front of and to the subject's left
    of the rest position (lateral: of the midline)."""
    need = _EXCURSION_FRAMES
    missing = []
    for name, amount, far, words in (
            ("wide opening", depth, _EXCURSION["opening"], "drops more than {:.1f} mm below its rest position"),
            ("protrusion", forward, _EXCURSION["protrusion"], "moves more than {:.1f} mm forward of its rest position"),
            ("right lateral excursion", -lateral, _EXCURSION["lateral"],
             "moves more than {:.1f} mm to the subject's right of the midline"),
            ("left lateral excursion", lateral, _EXCURSION["lateral"],
             "moves more than {:.1f} mm to the subject's left of the midline")):
        found = int((amount > far).sum())
        if found < need:
            missing.append(f"no {name}: the incisor never {words.format(max(float(amount.max()), 0.0))} "
                           f"({found} frames beyond {far:g} mm, need at least {need})")
    if missing:
        raise FacesimError(f"border detection: {'; '.join(missing)}")


def detect_border(points, band: float = 2.0, step: float = 0.5, slab: float = 1.0, link: float = 30.0,
                  tie: float = 0.3, apart: float = 2.0) -> dict[str, np.ndarray]:
    """The six border curves of an unlabelled capture (module docstring).

    points : (N, 3) mm, reference-point positions in the jaw frame (x left, y up, z forward; the
        origin is the rest position), the frames of the capture in time order.
    band : mm, half-width of the midline strip the posterior and anterior curves are read from
        (and the overlap of the right and left halves); step : mm of height between sections;
        slab : mm, half-height of the local hull a section is cut from; link : mm, consecutive
        frames at most this far apart are joined by the segment between them; tie : mm, corner
        candidates this close to the extreme one count as extreme (the one nearest the curve so
        far is taken); apart : mm, corners closer than this act as one when the search
        directions are turned.
    Returns ``{curve name: (n, 3) mm points}`` for the ``CURVES``, each from its top down.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(P) < 20 or not np.isfinite(P).all():
        raise FacesimError(f"border detection: expected at least 20 finite reference points, got {len(P)}")
    rest = int(np.argmin(np.linalg.norm(P, axis=1)))
    deep = int(np.argmin(P[:, 1]))
    opening = P[rest, 1] - P[deep, 1]
    top_y, bottom_y, x_rest, x_deep = P[rest, 1], P[deep, 1], P[rest, 0], P[deep, 0]

    def x_mid(height):          # the midline: rest to the deepest point
        return x_rest + (top_y - height) / max(opening, 1e-9) * (x_deep - x_rest)

    _check_movements(top_y - P[:, 1], P[:, 2] - P[rest, 2], P[:, 0] - x_mid(P[:, 1]))
    Q = _densify(P, 0.5, link)
    x, y, z = Q.T
    xz = Q[:, [0, 2]]
    offset = x - x_mid(y)
    halves = {"right": Q[offset <= band], "left": Q[offset >= -band]}
    strip = Q[np.abs(offset) <= band][:, [1, 2]]
    everything = np.arange(len(Q))
    tops = {"posterior": rest}
    on_mid = everything[np.abs(offset) <= band]
    tops["anterior"] = int(on_mid[np.argmax(z[on_mid] + _TOP_TILT * y[on_mid])])
    direction = {}
    for c, degrees in _TOP_DIRECTIONS.items():
        idx = everything[offset < 0] if c.startswith("right") else everything[offset > 0]
        direction[c] = np.array([np.cos(np.radians(degrees)), np.sin(np.radians(degrees))])
        tops[c] = int(idx[np.argmax(xz[idx] @ direction[c] + _TOP_TILT * y[idx])])
    current = {c: xz[tops[c]].copy() for c in _RING}         # each curve's last pick
    picks = {c: [Q[tops[c]]] for c in _RING}

    def turn():
        # a corner's search direction: the bisector of the outward normals of the hexagon edges to
        # the nearest corners, on either side, at least ``apart`` mm away (coincident corners --
        # a section with one corner where the hexagon has two -- act as one)
        for k, c in enumerate(_RING):
            if c in ("posterior", "anterior"):
                continue
            normals = []
            for sign in (-1, 1):
                other = next((current[_RING[(k + sign * t) % 6]] for t in range(1, 6)
                              if np.hypot(*(current[_RING[(k + sign * t) % 6]] - current[c])) >= apart), None)
                if other is not None:
                    normals.append(_edge_normal(other, current[c]) if sign < 0 else _edge_normal(current[c], other))
            if len(normals) == 2:
                v = normals[0] + normals[1]
                if np.hypot(v[0], v[1]) > 1e-9:
                    direction[c] = v / np.hypot(v[0], v[1])

    turn()
    level = top_y - step
    while level > bottom_y:
        found = {}
        extent = _midline_extent(strip, level, slab)
        if extent is not None:
            found["posterior"] = np.array([x_mid(level), extent[0]])
            found["anterior"] = np.array([x_mid(level), extent[1]])
        for name, half in halves.items():
            section = _section(half, level, slab)
            if section is None:
                continue
            section = section[(section[:, 0] < x_mid(level)) if name == "right" else (section[:, 0] > x_mid(level))]
            if not len(section):
                continue
            for c in (f"{name}_posterior", f"{name}_anterior"):
                v = section @ direction[c]
                close = np.flatnonzero(v >= v.max() - tie)
                found[c] = section[close[np.argmin(np.linalg.norm(section[close] - current[c], axis=1))]]
        for c, q in found.items():
            if level < y[tops[c]]:
                current[c] = q
                picks[c].append(np.array([q[0], level, q[1]]))
        turn()
        level -= step
    border = {}
    for c in CURVES:
        curve = np.array(picks[c])
        if c in ("posterior", "anterior"):
            curve = np.vstack([curve, Q[deep]])
        else:   # a corner ends where it turns onto the bottom face (moving inward faster than down)
            outward = (x_mid(curve[:, 1]) - curve[:, 0]) * (1 if c.startswith("right") else -1)
            curve = curve[:int(np.argmax(outward - _TOP_TILT * curve[:, 1])) + 1]
        height = curve[0, 1] - curve[:, 1].min()
        if len(curve) < 8 or height < 5.0:
            raise FacesimError(f"border detection: the {_CURVE_WORDS[c]} spans only {height:.1f} mm of height "
                               f"({len(curve)} sections, need at least 8 over 5 mm)")
        border[c] = curve
    return border


class Shield:
    """Posselt's envelope as six border curves and the unit-cube map ``S``.

    curves : (6, K, 3) mm, jaw frame, samples of the ``CURVES`` at s_y = linspace(0, 1, K).
    """

    def __init__(self, curves):
        curves = np.array(curves, dtype=np.float64)
        if curves.ndim != 3 or curves.shape[0] != len(CURVES) or curves.shape[2] != 3 or curves.shape[1] < 4:
            raise FacesimError(f"shield: expected curves (6, K >= 4, 3), got {curves.shape}")
        if not np.isfinite(curves).all():
            raise FacesimError("shield: curves must be finite")
        extent = float(np.linalg.norm(np.ptp(curves.reshape(-1, 3), axis=0)))
        if not extent > 1e-3:   # the envelope spans millimetres; a point-like one maps every slider to it
            raise FacesimError(f"shield: the border curves span {extent:.3g} mm; expected an envelope of the "
                               "jaw's range of motion (millimetres)")
        curves.setflags(write=False)
        self.curves = curves
        knots = np.linspace(0.0, 1.0, curves.shape[1])
        self._spline = CubicSpline(knots, np.moveaxis(curves, 1, 0), bc_type="natural")   # s_y -> (6, 3)
        self._dspline = self._spline.derivative()
        # a coarse table of the map, for the initial guesses of ``sliders``
        g = np.stack(np.meshgrid(np.linspace(0, 1, 9), np.linspace(0, 1, 17), np.linspace(0, 1, 9),
                                 indexing="ij"), -1).reshape(-1, 3)
        self._table = (g, self.point(g))

    @classmethod
    def from_points(cls, border: dict[str, np.ndarray]) -> Shield:
        """Shield from the reference-point positions ``{curve name: (n, 3) mm, jaw frame}`` of the
        six border movements."""
        missing = [c for c in CURVES if c not in border]
        if missing:
            raise FacesimError(f"border movements missing: {', '.join(missing)} (need all of {', '.join(CURVES)})")
        return cls(_untangle(np.stack([_fit_curve(np.asarray(border[c], dtype=np.float64).reshape(-1, 3), c)
                                       for c in CURVES])))

    @classmethod
    def from_cloud(cls, points, **options) -> Shield:
        """Shield from an unlabelled cloud of reference-point positions ``(N, 3)`` mm (jaw frame)
        that includes the border movements (:func:`detect_border`; ``options`` go to it)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return cls.from_points(detect_border(points, **options))

    def _edges(self, s, derivative: bool = False):
        """Posterior and anterior section edges at s (N, 3) -> (N, 3) each, plus their s_x and s_y
        derivatives when asked."""
        c = self._spline(s[:, 1])                                # (N, 6, 3)
        sx = s[:, 0][:, None]
        right = sx < 0.5
        a = np.where(right, 2 * sx, 2 * sx - 1)                 # position within the half
        # E(corner_R, mid, corner_L): corner_R -> mid on [0, 1/2], mid -> corner_L on [1/2, 1]
        def edge(cr, mid, cl):
            return np.where(right, cr + a * (mid - cr), mid + a * (cl - mid))

        post = edge(c[:, 2], c[:, 0], c[:, 3])
        ante = edge(c[:, 4], c[:, 1], c[:, 5])
        if not derivative:
            return post, ante
        dc = self._dspline(s[:, 1])

        def dedge_dx(cr, mid, cl):
            return np.where(right, 2 * (mid - cr), 2 * (cl - mid))

        return (post, ante, dedge_dx(c[:, 2], c[:, 0], c[:, 3]), dedge_dx(c[:, 4], c[:, 1], c[:, 5]),
                edge(dc[:, 2], dc[:, 0], dc[:, 3]), edge(dc[:, 4], dc[:, 1], dc[:, 5]))

    def point(self, s) -> np.ndarray:
        """Envelope points ``(..., 3)`` mm (jaw frame) of sliders ``s (..., 3)`` in [0, 1]³
        (s_x right -> left, s_y closed -> open, s_z retruded -> protruded)."""
        s = np.asarray(s, dtype=np.float64)
        flat = s.reshape(-1, 3)
        post, ante = self._edges(flat)
        sz = flat[:, 2:3]
        return ((1 - sz) * post + sz * ante).reshape(s.shape)

    def jacobian(self, s) -> np.ndarray:
        """``(N, 3, 3)`` derivative of ``point`` (rows x, y, z; columns s_x, s_y, s_z) at ``s (N, 3)``."""
        flat = np.asarray(s, dtype=np.float64).reshape(-1, 3)
        post, ante, dpx, dax, dpy, day = self._edges(flat, derivative=True)
        sz = flat[:, 2:3]
        return np.stack([(1 - sz) * dpx + sz * dax, (1 - sz) * dpy + sz * day, ante - post], axis=2)

    def _initial(self, p):
        g, X = self._table
        d2 = (p * p).sum(1)[:, None] - 2 * p @ X.T + (X * X).sum(1)[None]
        return g[np.argmin(d2, axis=1)].copy()

    def sliders(self, points, iterations: int = 40):
        """Closest cube parameters of envelope points.

        points : (N, 3) mm, jaw frame. Returns ``s (N, 3)`` in [0, 1]³ minimising |S(s) − p| (a
        bound-constrained Gauss-Newton per point, batched) and the distance ``(N,)`` mm from
        each point to S(s): zero inside the envelope, the distance to the shield outside.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        s = self._initial(p)
        mu = np.full(len(p), 1e-6)
        r = self.point(s) - p
        cost = (r * r).sum(1)
        active = np.flatnonzero(cost > 1e-24)
        for _ in range(iterations):
            sa, ra = s[active], r[active]
            J = self.jacobian(sa)
            g = np.einsum("nij,ni->nj", J, ra)
            # variables held at a bound by a gradient pushing outward are frozen
            free = ~(((sa <= 0) & (g > 0)) | ((sa >= 1) & (g < 0)))
            H = np.einsum("nij,nil->njl", J, J) * free[:, :, None] * free[:, None, :]
            H += np.eye(3) * (mu[active, None, None] * (1 + np.diagonal(H, axis1=1, axis2=2))[:, None, :]
                              + (~free)[:, None, :])
            step = -np.linalg.solve(H, (g * free)[..., None])[..., 0]
            s_new = np.clip(sa + step, 0.0, 1.0)
            r_new = self.point(s_new) - p[active]
            cost_new = (r_new * r_new).sum(1)
            better = cost_new < cost[active]
            idx = active[better]
            s[idx], r[idx], cost[idx] = s_new[better], r_new[better], cost_new[better]
            mu[active] = np.where(better, np.maximum(mu[active] / 5, 1e-12), mu[active] * 10)
            moved = np.abs(s_new - sa).max(axis=1)
            done = (cost[active] < 1e-24) | (better & (moved < 1e-10)) | (mu[active] > 1e6)
            active = active[~done]
            if len(active) == 0:
                break
        return s, np.sqrt(cost)

    def project(self, points):
        """``(N, 3)`` points of the envelope closest to ``points (N, 3)`` (jaw frame, mm): inside
        points unchanged, outside points onto the shield."""
        s, d = self.sliders(points)
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.where((d < 1e-6)[:, None], p, self.point(s))

    def bijectivity(self, n: int = 16) -> float:
        """Zoss eq. 15 in the form |∫ det J ds| / ∫ |det J| ds over the unit cube (midpoint rule,
        ``n`` samples per axis): 1 when the cube map never folds (det J keeps its sign), smaller
        the more of the cube is mapped inside out."""
        c = (np.arange(n) + 0.5) / n
        s = np.stack(np.meshgrid(c, c, c, indexing="ij"), -1).reshape(-1, 3)
        det = np.linalg.det(self.jacobian(s))
        return float(abs(det.sum()) / max(np.abs(det).sum(), 1e-300))

    def face_samples(self, n: int = 9) -> np.ndarray:
        """``(6 n², 3)`` slider values covering the six faces of the unit cube."""
        c = np.linspace(0.0, 1.0, n)
        a, b = (v.ravel() for v in np.meshgrid(c, c, indexing="ij"))
        faces = []
        for axis in range(3):
            for value in (0.0, 1.0):
                s = np.empty((len(a), 3))
                s[:, axis] = value
                s[:, [k for k in range(3) if k != axis]] = np.c_[a, b]
                faces.append(s)
        return np.concatenate(faces)


# --- the rig -----------------------------------------------------------------------------------

_TMJ_FIELDS = ("condyle_right", "condyle_left", "track_direction", "track_length", "max_opening", "incisor")


def _tmj_values(geometry) -> dict:
    """The fields of a JawGeometry as JSON-ready numbers (None: just the field names)."""
    if geometry is None:
        return dict.fromkeys(_TMJ_FIELDS)
    return {k: np.asarray(getattr(geometry, k), dtype=np.float64).tolist() for k in _TMJ_FIELDS}


def _design(p, centres, scale):
    """RBF design matrix ``(N, M + 4)``: [phi(|p − c_i| / scale) | 1 | p / scale], phi(r) = r³."""
    d = np.linalg.norm(p[:, None, :] - centres[None], axis=2) / scale
    return np.concatenate([d**3, np.ones((len(p), 1)), p / scale], axis=1)


@dataclass(frozen=True)
class PosseltRig:
    """A fitted Posselt-envelope rig.

    frame : JawFrame; shield : Shield (jaw frame);
    centres : (M, 3) mm RBF centres (jaw frame); coefficients : (M + 4, 3) the weights and the
        affine part of omega(p) (rad); scale : mm, the RBF length unit;
    tmj : the :class:`~facesim.model.JawGeometry` whose generated motion the rig was fitted to
        (a face model's own rig, ``facesim jaw fit-model``), or None (fitted to capture).

    Poses are mandible-relative-to-skull transforms in the skull frame (mm); points are
    reference-point positions in the skull frame unless a method says otherwise.
    """

    frame: JawFrame
    shield: Shield
    centres: np.ndarray
    coefficients: np.ndarray
    scale: float
    tmj: JawGeometry | None = None

    def __post_init__(self):
        se3.check_rigid(se3.from_rt(self.frame.axes, self.frame.origin),
                        "posselt rig: jaw frame (fields 'frame_origin', 'frame_axes')")
        for name in ("centres", "coefficients"):
            a = np.asarray(getattr(self, name))
            if a.dtype.kind not in "fiu" or not np.isfinite(a).all():
                raise FacesimError(f"posselt rig: field {name!r}: expected finite numbers (the RBF map), "
                                   f"got {'NaN or inf' if a.dtype.kind in 'fiu' else f'dtype {a.dtype}'}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise FacesimError(f"posselt rig: field 'meta.scale': expected a finite RBF length unit > 0 mm, "
                               f"got {self.scale!r}")

    def made_for(self, geometry: JawGeometry, tolerance: float = 1e-6) -> bool:
        """Whether the rig was fitted to motion generated for the TMJ ``geometry`` (condyles,
        track, incisor within ``tolerance`` mm, same track length and maximum opening)."""
        if self.tmj is None:
            return False
        a, b = _tmj_values(self.tmj), _tmj_values(geometry)
        return all(np.abs(np.asarray(a[k]) - np.asarray(b[k])).max() <= tolerance for k in a)

    @property
    def reference_point(self) -> np.ndarray:
        """(3,) mm, the reference point at rest (skull frame)."""
        return self.frame.origin

    def _pose_local(self, p_local: np.ndarray) -> np.ndarray:
        omega = _design(p_local, self.centres, self.scale) @ self.coefficients
        return se3.from_rt(se3.so3_exp(omega), p_local)

    def pose_at(self, points, project: bool = True) -> np.ndarray:
        """Direct manipulation: poses ``(N, 4, 4)`` placing the reference point at ``points (N, 3)``
        mm (skull frame); with ``project`` points outside the envelope go to the shield first."""
        p = self.frame.to_local(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if project:
            p = self.shield.project(p)
        return self.frame.pose_to_world(self._pose_local(p))

    def pose_from_sliders(self, s) -> np.ndarray:
        """Slider control: poses ``(N, 4, 4)`` of ``s (N, 3)`` in [0, 1]³ (values are clipped)."""
        s = np.clip(np.asarray(s, dtype=np.float64).reshape(-1, 3), 0.0, 1.0)
        return self.frame.pose_to_world(self._pose_local(self.shield.point(s)))

    def sliders_of(self, poses) -> np.ndarray:
        """Slider values ``(N, 3)`` of the reference point of ``poses (N, 4, 4)``."""
        return self.shield.sliders(self.reference_trajectory(poses))[0]

    def reference_trajectory(self, poses) -> np.ndarray:
        """``(N, 3)`` mm jaw-frame positions of the reference point under ``poses (N, 4, 4)``."""
        return self.frame.pose_to_local(np.asarray(poses, dtype=np.float64))[:, :3, 3]

    def reproduce(self, poses, points=None, weights=None) -> np.ndarray:
        """The rig driven by the captured reference point: ``(N, 4, 4)`` (``points`` and ``weights``
        are unused; the signature matches the classic rigs)."""
        return self.frame.pose_to_world(self._pose_local(self.shield.project(self.reference_trajectory(poses))))

    @property
    def bounds(self) -> np.ndarray:
        """``(3, 2)`` slider ranges: the unit cube."""
        return np.array([[0.0, 1.0]] * 3)

    def bijectivity(self, n: int = 16) -> float:
        """The shield map's bijectivity measure (:meth:`Shield.bijectivity`)."""
        return self.shield.bijectivity(n)

    # --- files ----------------------------------------------------------------------------------

    def save(self, path):
        """Write the rig to a versioned ``.npz`` (:mod:`facesim.jaw.rigfile`)."""
        meta = {"scale": self.scale, "curves": list(CURVES)}
        if self.tmj is not None:
            meta["tmj"] = _tmj_values(self.tmj)
        return save_rig(path, "posselt", {
            "frame_origin": self.frame.origin, "frame_axes": self.frame.axes, "curves": self.shield.curves,
            "centres": self.centres, "coefficients": self.coefficients}, meta)

    @staticmethod
    def load(path) -> PosseltRig:
        """Read a rig written by :meth:`save` (one-line errors naming the file and field)."""
        arrays, meta = load_rig(path, "posselt", ("frame_origin", "frame_axes", "curves", "centres", "coefficients"),
                                ("scale", "curves"))
        if not isinstance(meta["curves"], list) or tuple(meta["curves"]) != CURVES:
            raise ModelFileError(path, f"field 'meta.curves': expected {list(CURVES)}")
        c, w = arrays["centres"], arrays["coefficients"]
        if c.ndim != 2 or c.shape[1] != 3 or w.shape != (len(c) + 4, 3):
            raise ModelFileError(path, f"fields 'centres' / 'coefficients': expected (M, 3) and (M + 4, 3), "
                                       f"got {c.shape} and {w.shape}")
        try:
            tmj = None if meta.get("tmj") is None else JawGeometry(**meta["tmj"])
        except (TypeError, ValueError, FacesimError) as exc:
            raise ModelFileError(path, f"field 'meta.tmj': expected the jaw geometry's fields "
                                       f"({', '.join(_tmj_values(None))}): {exc}") from None
        try:
            return PosseltRig(JawFrame(arrays["frame_origin"], arrays["frame_axes"]), Shield(arrays["curves"]),
                              c.astype(np.float64), w.astype(np.float64), float(meta["scale"]), tmj)
        except FacesimError as exc:
            raise ModelFileError(path, str(exc)) from None
        except (TypeError, ValueError) as exc:      # strings where numbers belong, a scale that is not a number
            raise ModelFileError(path, f"unreadable posselt rig data ({type(exc).__name__}: {exc})") from None


def _check_units(p, omega):
    """A one-line error when the reference point ``p (N, 3)`` mm moves far too little for the
    rotations ``omega (N, 3)`` rad of the poses (translations in metres or centimetres): a jaw
    turning by theta moves its incisors, ~100 mm from the joints, by ~100 theta mm."""
    turn = float(np.linalg.norm(omega, axis=1).max())
    reach = float(np.linalg.norm(p, axis=1).max())
    if turn < np.radians(5.0) or reach >= 20.0 * turn:
        return
    factor = 100.0 * turn / max(reach, 1e-12)
    unit = "metres" if factor > 300 else "centimetres" if factor < 30 else "another unit"
    raise FacesimError(f"poses: the reference point moves at most {reach:.3g} mm while the mandible turns by up to "
                       f"{np.degrees(turn):.0f} degrees, which moves the incisors by tens of mm: the translations "
                       f"look about {float(f'{factor:.2g}'):g} times too small ({unit}?); expected millimetres")


def fit_posselt(session=None, *, poses=None, reference_point=None, border=None, frame: JawFrame | None = None,
                centres: int = 300, smoothing: float = 1e-6, scale: float = 10.0, tmj=None) -> PosseltRig:
    """Fit a :class:`PosseltRig` to captured poses.

    session : a :class:`facesim.jaw.motion.Session` (poses, reference point and labelled border
        movements); or give ``poses (N, 4, 4)`` and ``reference_point (3,)`` mm instead.
    border : ``{curve name: frame indices}`` for the six ``CURVES``; None: the session's labels,
        or without a session the border movements found in the poses (:func:`detect_border`);
        ``"detect"``: found in the poses even when a session has labels.
    frame : jaw frame (default ``JawFrame.from_poses``).
    centres : number of RBF centres (farthest-point sample of the data); smoothing : ridge weight
        of eq. 9 relative to the data term; scale : mm, RBF length unit.
    tmj : the :class:`facesim.model.JawGeometry` the poses were generated for, recorded in the rig
        (None for captured poses).
    """
    if session is not None:
        poses, reference_point = session.poses, session.reference_point
        if border is None:
            border = {c: session.frames(c) for c in CURVES}
    if poses is None or reference_point is None:
        raise FacesimError("fit_posselt: expected a session, or poses and reference_point")
    poses = se3.check_poses(poses, minimum=10)
    if not smoothing >= 0 or not scale > 0 or int(centres) < 4:
        raise FacesimError("fit_posselt: expected smoothing >= 0, scale > 0 mm and at least 4 centres")
    if isinstance(border, str) and border != "detect":
        raise FacesimError(f"fit_posselt: border must be frame indices per curve, None or 'detect', got {border!r}")
    if frame is None:
        frame = JawFrame.from_poses(poses, reference_point)
    local = frame.pose_to_local(poses)
    p = local[:, :3, 3]
    omega = se3.so3_log(local[:, :3, :3])
    _check_units(p, omega)
    if border is None or isinstance(border, str):
        shield = Shield.from_cloud(p)
    else:
        shield = Shield.from_points({c: p[np.asarray(border[c], dtype=int)] for c in CURVES if c in border})
    C = p[farthest_points(p, int(centres))]
    A = _design(p, C, scale)
    # eq. 9: least squares on the data with a ridge on the RBF weights (not on the affine part)
    # (normal equations: a dense least-squares solver is no more accurate here and, on a busy
    # multi-threaded BLAS, a hundred times slower)
    H = A.T @ A
    H[np.arange(len(C)), np.arange(len(C))] += smoothing * len(p)
    coefficients = solve(H, A.T @ omega, assume_a="sym")
    return PosseltRig(frame, shield, C, coefficients, float(scale), tmj)


__all__ = ["CURVES", "PosseltRig", "Shield", "detect_border", "fit_posselt"]
