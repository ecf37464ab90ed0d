"""The template's muscles and markers carried onto a new anatomy (issue 16; Sifakis et al. 2005
built their face the same way: a template of muscles and fibres morphed onto the subject).

Three steps:

* :func:`template_landmarks` -- the template's anatomical landmarks (mm, facesim frame), found
  on the procedural head by simple geometric rules. Small and replaceable: the landmark finder
  of :mod:`facesim.importing` can stand in for it, so template and subject use one definition.
* :func:`landmark_warp` -- a smooth map R^3 -> R^3 taking the template's landmarks onto the
  subject's: a thin-plate spline (kernel r^2 log r) with an affine part, as
  ``scipy.interpolate.RBFInterpolator(kernel="thin_plate_spline", degree=1)`` builds it, with its
  analytic Jacobian and a Newton-refined inverse (:class:`Warp`).
* :func:`transfer_muscles` and :func:`transfer_markers` -- the template's per-tet muscle
  fractions and fibres re-embedded in the subject's tet mesh (samples in each subject tet pulled
  back by the inverse warp and looked up in the template's tets; fibres pushed forward by the
  warp's Jacobian), and its marker layout warped and bound to the subject's skin. Each returns
  a report (JSON-serialisable dict) naming the muscles and markers that did not carry over.

Units: mm throughout; volumes mm^3; the Jacobian and its determinant are dimensionless.

Fractions. As in the procedural model (``facesim.export.export_volume``), each muscle's fraction
is the share of the tet inside that muscle, in (0, 1]; where muscles interlace (the modiolus,
the lip ring's halves) the sum over muscles may exceed 1, and each muscle acts on its own
fraction. The transfer keeps that meaning: every transferred fraction is an average of template
fractions, so it stays in (0, 1] and a target tet sums above 1 only where the template does
(``cap_total=True`` scales such tets down to a sum of 1 instead).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from facesim._kernels import locate as _k
from facesim.errors import FacesimError
from facesim.fem.meshes import TetLocator
from facesim.mocap.binding import bind_point, triangle_normals
from facesim.model import FaceModel, MarkerSet, MuscleSet, signed_volumes

#: The landmark names of the importer's finder (mm, facesim frame), template and subject alike.
LANDMARK_NAMES = ("condyle_left", "condyle_right", "incisor", "upper_incisor", "menton", "pogonion",
                  "gonion_left", "gonion_right", "pronasale", "subnasale", "nasion", "stomion",
                  "cheilion_left", "cheilion_right", "labiale_superius", "labiale_inferius", "soft_pogonion")
#: A warp needs this many landmarks in common (an affine part has 12 unknowns; 8 points off a
#: plane fix it with some redundancy for the bending part).
MIN_LANDMARKS = 8
#: Landmarks whose smallest spread (singular value of the centred coordinates) is below this
#: share of the largest lie too close to a plane (or line) for the affine part to be defined.
MIN_SPREAD_RATIO = 0.02
#: The warp folds (or nearly: a local volume ratio below this) where det J <= this value.
MIN_JACOBIAN_DET = 0.1
#: Newton tolerance of the inverse warp (mm); points not inverted within INVERSE_MAX_MM are refused.
INVERSE_TOL_MM = 1e-9
INVERSE_MAX_MM = 1e-6
#: the same for the muscle transfer's quadrature samples: they are only located in the template's
#: tets (mm in size) and averaged 20 to a tet, so 0.1 micrometre is ample; Newton from the nodes'
#: interpolant then needs about 2 evaluations of the spline instead of 3.5
SAMPLE_TOL_MM = 1e-4
SAMPLE_MAX_MM = 1e-3


# =========================================================================== landmarks
def template_landmarks(model: FaceModel) -> dict[str, np.ndarray]:
    """The template's landmarks, ``{name: (3,) float64 mm}`` in the model's (facesim) frame.

    Recorded exactly: ``condyle_left``, ``condyle_right``, ``incisor`` (``model.jaw``). The others
    by rules on midsagittal sections (the plane through the condyle midpoint normal to the
    intercondylar axis) of the skin, the bones and the lip contact surfaces, "front" meaning the
    most forward point of the section at each height (every 0.25 mm):

    * ``upper_incisor``: lowest point of the upper teeth (collider ``upper_teeth``, else the
      cranium) within 2 mm of their most forward point;
    * ``menton``: lowest point of the mandible; ``pogonion``: most forward mandible point below
      the incisor-menton midpoint; ``gonion_left/right``: the mandible vertex farthest along
      (+-1, -2, -2)/3 (out, down, back: the angle);
    * ``nasion``: the deepest point of the cranium's front behind the chord from the rhinion
      (most forward cranium point 30 mm or more above the upper incisor) to the front 40 mm
      above it;
    * ``stomion``: midway between the most forward midline points of the upper and lower lip
      contact surfaces; ``cheilion_left/right``: the lateral ends of those surfaces' front
      boundary (within 30 mm behind the stomion);
    * ``pronasale``: most forward skin point between upper incisor and nasion heights;
      ``labiale_superius``: most forward skin point from 3 mm above the stomion to halfway up to
      the pronasale; ``subnasale``: the deepest skin point behind the chord pronasale - labiale
      superius; ``labiale_inferius``: most forward skin point 3 to 15 mm below the stomion;
      ``soft_pogonion``: most forward skin point between the menton and halfway up to the
      labiale inferius.

    The procedural head's profiles are not anatomical everywhere (its frontal bone has no
    glabella, its symphysis is nearly vertical), so a few of these land some mm off the textbook
    spots of ``docs/physics.md`` section 6; what matters for the warp is that template and
    subject use the same rules. A landmark whose rule finds nothing (no lip surfaces, say) is
    left out.
    """
    jaw = model.jaw
    origin = jaw.midpoint
    ex = jaw.u
    ey = np.array([0.0, 1.0, 0.0]) - ex[1] * ex
    ey /= np.linalg.norm(ey)
    R = np.stack([ex, ey, np.cross(ex, ey)])          # rows: local x (left), y (up), z (forward)

    def local(P):
        return (np.asarray(P, float) - origin) @ R.T

    X = local(model.X)
    surfaces = {s.name: s for s in model.bones + model.colliders}
    by_bone = {s.bone: s for s in model.bones}
    cranium = surfaces.get("cranium", by_bone.get("cranium"))
    mandible = surfaces.get("mandible", by_bone.get("jaw"))
    teeth = surfaces.get("upper_teeth", cranium)
    out = {"condyle_left": local(jaw.condyle_left), "condyle_right": local(jaw.condyle_right),
           "incisor": local(jaw.incisor)}
    front = _front(_section(X, model.skin))

    if teeth is not None:
        P = _section(local(teeth.vertices), teeth.faces).reshape(-1, 3)
        if len(P):
            near = P[P[:, 2] >= P[:, 2].max() - 2.0]
            out["upper_incisor"] = near[np.argmin(near[:, 1])]
    if mandible is not None:
        V = local(mandible.vertices)
        segments = _section(V, mandible.faces)
        if len(segments):
            P = segments.reshape(-1, 3)
            out["menton"] = P[np.argmin(P[:, 1])]
            mf = _front(segments)
            low = mf[mf[:, 1] < 0.5 * (out["incisor"][1] + out["menton"][1])]
            if len(low):
                out["pogonion"] = low[np.argmax(low[:, 2])]
        for name, sign in (("gonion_left", 1.0), ("gonion_right", -1.0)):
            side = V[sign * V[:, 0] > 0]
            if len(side):
                out[name] = side[np.argmax(side @ (np.array([sign, -2.0, -2.0]) / 3.0))]
    if cranium is not None and "upper_incisor" in out:
        cf = _front(_section(local(cranium.vertices), cranium.faces))
        above = cf[cf[:, 1] >= out["upper_incisor"][1] + 30.0]
        if len(above):
            rhinion = above[np.argmax(above[:, 2])]
            top = cf[cf[:, 1] >= rhinion[1] + 40.0]
            if len(top):
                nasion = _deepest_behind(cf, rhinion, top[np.argmin(top[:, 1])])
                if nasion is not None:
                    out["nasion"] = nasion
    lips = [_section(X, tri).reshape(-1, 3) for tri in (model.lip_upper, model.lip_lower)]
    if all(len(p) for p in lips):
        upper, lower = (p[np.argmax(p[:, 2])] for p in lips)
        out["stomion"] = 0.5 * (upper + lower)
        rim = _boundary_nodes(np.concatenate([model.lip_upper, model.lip_lower]))
        rim = X[rim][X[rim][:, 2] > out["stomion"][2] - 30.0]
        if len(rim):
            out["cheilion_left"] = rim[np.argmax(rim[:, 0])]
            out["cheilion_right"] = rim[np.argmin(rim[:, 0])]

    def most_forward(lo, hi):
        band = front[(front[:, 1] >= lo) & (front[:, 1] <= hi)]
        return band[np.argmax(band[:, 2])] if len(band) else None

    if len(front) and {"upper_incisor", "nasion"} <= out.keys():
        p = most_forward(out["upper_incisor"][1], out["nasion"][1])
        if p is not None:
            out["pronasale"] = p
    if len(front) and "stomion" in out:
        sto = out["stomion"][1]
        if "pronasale" in out:
            p = most_forward(sto + 3.0, 0.5 * (sto + out["pronasale"][1]))
            if p is not None:
                out["labiale_superius"] = p
                q = _deepest_behind(front, out["pronasale"], p)
                if q is not None:
                    out["subnasale"] = q
        p = most_forward(sto - 15.0, sto - 3.0)
        if p is not None:
            out["labiale_inferius"] = p
            if "menton" in out:
                q = most_forward(out["menton"][1], 0.5 * (p[1] + out["menton"][1]))
                if q is not None:
                    out["soft_pogonion"] = q
    return {name: np.asarray(out[name], float) @ R + origin for name in LANDMARK_NAMES if name in out}


def _section(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(k, 2, 3) segments where the triangles ``F (s, 3)`` of ``V (n, 3)`` cross the plane x = 0
    (a vertex on the plane counts as on the positive side, so a crossing triangle has exactly
    two crossing edges)."""
    V = np.asarray(V, float)
    T = V[np.asarray(F).reshape(-1, 3)]
    neg = T[:, :, 0] < 0
    T = T[neg.any(axis=1) & ~neg.all(axis=1)]
    if not len(T):
        return np.zeros((0, 2, 3))
    a, b = T, np.roll(T, -1, axis=1)                          # edges (0,1), (1,2), (2,0)
    cross = (a[:, :, 0] < 0) != (b[:, :, 0] < 0)              # two per triangle
    t = a[:, :, 0] / np.where(cross, a[:, :, 0] - b[:, :, 0], 1.0)
    pts = a + t[:, :, None] * (b - a)
    return pts[cross].reshape(-1, 2, 3)


def _front(segments: np.ndarray, step: float = 0.25) -> np.ndarray:
    """The front of a midsagittal section: at every ``step`` mm of height the most forward point
    (largest z) of the ``segments (k, 2, 3)`` spanning that height, where it has z > 0.
    Returns (h, 3) points sorted by height."""
    if not len(segments):
        return np.zeros((0, 3))
    y0, y1 = segments[:, 0, 1], segments[:, 1, 1]
    lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
    ys = np.arange(np.floor(lo.min() / step), np.ceil(hi.max() / step) + 1) * step
    span = (ys[:, None] >= lo) & (ys[:, None] <= hi) & (hi > lo)
    t = (ys[:, None] - y0) / np.where(y1 != y0, y1 - y0, 1.0)
    x = segments[:, 0, 0] + t * (segments[:, 1, 0] - segments[:, 0, 0])
    z = np.where(span, segments[:, 0, 2] + t * (segments[:, 1, 2] - segments[:, 0, 2]), -np.inf)
    j = np.argmax(z, axis=1)
    row = np.arange(len(ys))
    keep = z[row, j] > 0
    return np.stack([x[row, j], ys, z[row, j]], axis=1)[keep]


def _deepest_behind(front: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """The point of ``front (k, 3)`` between the heights of ``a`` and ``b`` lying farthest behind
    (in z, at its own height) the chord a-b; None if no point lies between them."""
    lo, hi = sorted((a[1], b[1]))
    P = front[(front[:, 1] > lo) & (front[:, 1] < hi)]
    if not len(P):
        return None
    chord = a[2] + (P[:, 1] - a[1]) / (b[1] - a[1]) * (b[2] - a[2])
    return P[np.argmax(chord - P[:, 2])]


def _boundary_nodes(F: np.ndarray) -> np.ndarray:
    """Nodes on edges used by one triangle only of ``F (s, 3)``."""
    e = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return np.unique(u[c == 1])


# ============================================================================== the warp
@dataclass(frozen=True, eq=False)
class _Spline:
    """f(p) = t + M p + sum_i W_i phi(|p - C_i|), phi(r) = r^2 log r: ``C (l, 3)`` mm,
    ``W (l, 3)``, ``M (3, 3)``, ``t (3,)`` mm."""

    C: np.ndarray
    W: np.ndarray
    M: np.ndarray
    t: np.ndarray

    def evaluate(self, P: np.ndarray, jacobian: bool = False):
        P = _points(P)
        out = np.empty_like(P)
        J = np.empty((len(P), 3, 3)) if jacobian else np.empty((0, 3, 3))
        _k.tps_evaluate(P, self.C, self.W, self.M, self.t, out, J, jacobian)
        return (out, J) if jacobian else out


def _phi(r: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, r * r * np.log(np.where(r > 0, r, 1.0)), 0.0)


def _fit_spline(src: np.ndarray, dst: np.ndarray, smoothing: float) -> _Spline:
    """The thin-plate spline through ``src (l, 3)`` -> ``dst (l, 3)`` with an affine part; the
    polynomial columns are shifted and scaled for conditioning (as scipy does), then the affine
    part is written back in plain coordinates. ``smoothing`` is added to the kernel diagonal
    (scipy's meaning: 0 interpolates)."""
    n = len(src)
    shift = src.mean(axis=0)
    scale = float(np.abs(src - shift).max()) or 1.0
    K = _phi(np.linalg.norm(src[:, None] - src[None], axis=2)) + smoothing * np.eye(n)
    Pm = np.c_[np.ones(n), (src - shift) / scale]
    A = np.block([[K, Pm], [Pm.T, np.zeros((4, 4))]])
    sol = np.linalg.solve(A, np.r_[dst, np.zeros((4, 3))])
    W, a = sol[:n], sol[n:]
    M = a[1:].T / scale                                   # f_j = a0_j + sum_k a_{k+1, j} (p_k - shift_k) / scale
    t = a[0] - M @ shift
    return _Spline(np.ascontiguousarray(src), np.ascontiguousarray(W), np.ascontiguousarray(M), t)


def _points(P) -> np.ndarray:
    """``P`` as a contiguous (k, 3) float64 array (one (3,) point becomes (1, 3))."""
    return np.ascontiguousarray(np.asarray(P, dtype=np.float64).reshape(-1, 3))


@dataclass(frozen=True, eq=False)
class Warp:
    """A smooth map of template space onto subject space, mm -> mm (:func:`landmark_warp`).

    Attributes: ``names`` the landmarks it was built on, ``src (l, 3)`` and ``dst (l, 3)`` their
    template and subject positions (mm), ``smoothing`` (0: ``warp(src) = dst`` exactly).
    """

    names: tuple[str, ...]
    src: np.ndarray
    dst: np.ndarray
    smoothing: float
    forward: _Spline
    backward: _Spline

    def __call__(self, P) -> np.ndarray:
        """(k, 3) subject positions, mm, of template points ``P (k, 3)`` (or one (3,) point)."""
        return self.forward.evaluate(P)

    def jacobian(self, P) -> np.ndarray:
        """(k, 3, 3) Jacobian ``J[i, j, k] = d warp_j / d p_k`` at template points ``P (k, 3)``."""
        return self.forward.evaluate(P, jacobian=True)[1]

    def jacobian_det(self, P) -> np.ndarray:
        """(k,) det J at template points ``P (k, 3)``: the local volume ratio subject / template."""
        return np.linalg.det(self.jacobian(P))

    def inverse(self, Q, guess=None, return_residual: bool = False, tol: float = INVERSE_TOL_MM,
                return_jacobian: bool = False):
        """(k, 3) template points mapped onto the subject points ``Q (k, 3)``, mm.

        Starts from ``guess (k, 3)`` (default: the spline fitted the other way round) and refines
        by Newton steps with the analytic Jacobian until ``|warp(p) - q| <= tol`` mm. With
        ``return_residual`` also returns that residual ``(k,)`` mm (large where the warp folds or
        has no preimage nearby), with ``return_jacobian`` the warp's Jacobian at the points found
        ``(k, 3, 3)`` (as :meth:`jacobian`; Newton has it at no extra cost), in that order.
        """
        Q = _points(Q)
        X0 = self.backward.evaluate(Q) if guess is None else _points(guess)
        X = np.empty_like(Q)
        res = np.empty(len(Q))
        J = np.empty((len(Q), 3, 3))
        f = self.forward
        _k.tps_inverse(Q, X0, f.C, f.W, f.M, f.t, 30, float(tol), X, res, J)
        out = (X,) + ((res,) if return_residual else ()) + ((J,) if return_jacobian else ())
        return out[0] if len(out) == 1 else out

    def landmark_error(self) -> np.ndarray:
        """(l,) mm, ``|warp(src) - dst|`` per landmark (0 up to round-off without smoothing)."""
        return np.linalg.norm(self(self.src) - self.dst, axis=1)

    def check_unfolded(self, P, what: str) -> tuple[float, float]:
        """(min, max) of det J over template points ``P (k, 3)``; a one-line FacesimError naming
        ``what`` and the worst point when the warp folds there (det J <= MIN_JACOBIAN_DET)."""
        P = _points(P)
        det = self.jacobian_det(P)
        i = int(np.argmin(det))
        if not det[i] > MIN_JACOBIAN_DET:
            raise FacesimError(f"landmark warp: folds over {what}: det J = {det[i]:.3g} (need > {MIN_JACOBIAN_DET:g}) "
                               f"at template point ({P[i, 0]:.1f}, {P[i, 1]:.1f}, {P[i, 2]:.1f}) mm; are some "
                               f"landmarks mislabelled (left/right swapped?) or in another frame?")
        return float(det[i]), float(det.max())


def _landmark_array(d: dict, name: str, what: str) -> np.ndarray | None:
    v = d[name]
    if v is None:
        return None
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,):
        raise FacesimError(f"landmark warp: {what} landmark {name!r}: expected a (3,) position in mm, got shape "
                           f"{a.shape}")
    return a if np.isfinite(a).all() else None


def landmark_warp(src: dict, dst: dict, smoothing: float = 0.0, domain=None) -> Warp:
    """The warp taking the template's landmarks ``src`` onto the subject's ``dst`` (``{name: (3,)
    mm}``; None or NaN positions count as missing), built on the names both have.

    A thin-plate spline (kernel r^2 log r) with an affine part: ``warp(src[n]) = dst[n]`` for
    every common name (``smoothing`` > 0, scipy's RBFInterpolator meaning, trades that for a
    smoother map). Needs at least :data:`MIN_LANDMARKS` common landmarks, distinct and not all
    near one plane, on both sides; else a one-line FacesimError naming the missing ones. If
    ``domain (k, 3)`` template points (mm) are given, the warp must not fold there
    (:meth:`Warp.check_unfolded`); it is always checked at the landmarks themselves.
    """
    have_src = {n: a for n in src if (a := _landmark_array(src, n, "template")) is not None}
    have_dst = {n: a for n in dst if (a := _landmark_array(dst, n, "subject")) is not None}
    names = tuple(n for n in have_src if n in have_dst)
    if len(names) < MIN_LANDMARKS:
        def listed(ns):
            return ", ".join(ns) if ns else "none"
        no_dst = [n for n in LANDMARK_NAMES if n in have_src and n not in have_dst]
        no_src = [n for n in LANDMARK_NAMES if n in have_dst and n not in have_src]
        neither = [n for n in LANDMARK_NAMES if n not in have_src and n not in have_dst]
        raise FacesimError(f"landmark warp: {len(names)} landmarks in common, need at least {MIN_LANDMARKS}; "
                           f"missing from the subject: {listed(no_dst)}; missing from the template: "
                           f"{listed(no_src)}; missing from both: {listed(neither)}")
    S = np.array([have_src[n] for n in names])
    D = np.array([have_dst[n] for n in names])
    for what, P in (("template", S), ("subject", D)):
        c = P - P.mean(axis=0)
        s = np.linalg.svd(c, compute_uv=False)
        if s[2] < MIN_SPREAD_RATIO * s[0]:
            thick = s[2] / math.sqrt(len(P))
            raise FacesimError(f"landmark warp: the {len(P)} {what} landmarks lie within ~{thick:.2g} mm of a plane "
                               f"(spread {s[0] / math.sqrt(len(P)):.3g} mm): need some off it, e.g. both condyles, "
                               f"gonions or cheilions besides the midline ones")
        dist = np.linalg.norm(P[:, None] - P[None], axis=2)
        np.fill_diagonal(dist, np.inf)
        i, j = np.unravel_index(np.argmin(dist), dist.shape)
        if dist[i, j] < 1e-6 * s[0]:
            raise FacesimError(f"landmark warp: {what} landmarks {names[i]!r} and {names[j]!r} coincide "
                               f"({dist[i, j]:.2g} mm apart)")
    try:
        ok = math.isfinite(float(smoothing)) and float(smoothing) >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise FacesimError(f"landmark warp: smoothing must be a finite number >= 0, got {smoothing!r}")
    smoothing = float(smoothing)
    warp = Warp(names, S, D, smoothing, _fit_spline(S, D, smoothing), _fit_spline(D, S, smoothing))
    warp.check_unfolded(S, "the landmarks")
    if domain is not None:
        warp.check_unfolded(domain, "the domain")
    return warp


# ================================================================================ sampling
def barycentric_samples(n: int) -> np.ndarray:
    """(n, 4) barycentric sample points of a tet, equal weights: the lattice points
    ``(i, j, k, l) + 1/4`` over ``(L + 1)``, ``i + j + k + l = L`` (all strictly inside, symmetric
    under every vertex permutation). ``n`` is 1 (the centroid), 4, 10, 20 or 35 (L = 0..4)."""
    sizes = {(L + 1) * (L + 2) * (L + 3) // 6: L for L in range(5)}
    if n not in sizes:
        raise FacesimError(f"samples_per_tet: expected one of {', '.join(map(str, sizes))}, got {n!r}")
    L = sizes[n]
    pts = [(i, j, k, L - i - j - k) for i in range(L + 1) for j in range(L + 1 - i) for k in range(L + 1 - i - j)]
    return (np.array(pts, dtype=np.float64) + 0.25) / (L + 1)


def _check_mesh(X, tets, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    X = np.ascontiguousarray(np.asarray(X, dtype=np.float64))
    tets = np.ascontiguousarray(np.asarray(tets), dtype=np.int32)
    if X.ndim != 2 or X.shape[1] != 3 or not len(X) or not np.isfinite(X).all():
        raise FacesimError(f"{what}: expected finite node positions (n, 3) mm, got shape {X.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or not len(tets) or tets.min() < 0 or tets.max() >= len(X):
        raise FacesimError(f"{what}: expected tets (m, 4) indexing its {len(X)} nodes, got shape {tets.shape}")
    vol = signed_volumes(X, tets)
    if not (vol > 0).all():
        raise FacesimError(f"{what}: expected positively oriented tets, {int((vol <= 0).sum()):,} of {len(tets):,} "
                           f"have volume <= 0 (facesim.model.positively_oriented fixes the orientation)")
    return X, tets, vol


def _pull_back(warp: Warp, Q: np.ndarray, guess, what: str, tol: float = INVERSE_TOL_MM,
               limit: float = INVERSE_MAX_MM) -> tuple[np.ndarray, np.ndarray]:
    """``warp.inverse`` of ``Q`` from ``guess`` with its Jacobian there; a one-line error where a
    point is not inverted within ``limit`` mm (the warp folds)."""
    P, res, J = warp.inverse(Q, guess=guess, return_residual=True, tol=tol, return_jacobian=True)
    bad = ~(res <= limit)
    if bad.any():
        i = int(np.argmax(np.where(np.isfinite(res), res, np.inf)))
        raise FacesimError(f"landmark warp: cannot be inverted at {int(bad.sum()):,} of {len(Q):,} {what} (residual "
                           f"up to {res[i]:.3g} mm at ({Q[i, 0]:.1f}, {Q[i, 1]:.1f}, {Q[i, 2]:.1f}) mm): it folds; "
                           f"are some landmarks mislabelled (left/right swapped?) or in another frame?")
    return P, J


# ============================================================================ the muscles
def transfer_muscles(template: FaceModel, warp: Warp, X, tets, samples_per_tet: int = 20, snap: float = 1.0,
                     cap_total: bool = False, min_volume_ratio: float = 0.5,
                     max_outside: float = 0.25) -> tuple[MuscleSet, dict]:
    """The template's muscles re-embedded in the subject's tet mesh ``X (n, 3)`` mm, ``tets (m, 4)``
    (positively oriented), through ``warp`` (template -> subject).

    For every subject tet that can reach a template muscle, ``samples_per_tet`` equal-weight
    points (:func:`barycentric_samples`) are pulled back by the inverse warp and located in the
    template's tets (a point within ``snap`` mm outside the template flesh counts as in its
    nearest tet). Per subject tet and muscle: fraction = the mean over the samples of the
    template tet's fraction of that muscle (0 outside); fibre = the fraction-weighted mean of the
    template fibres pushed forward by the warp's Jacobian at each sample (F d / |F d|,
    sign-aligned), normalised. Names, sides and sigma_max are the template's. Fractions stay in
    (0, 1] per muscle; a tet's sum may exceed 1 where the template's does (module docstring),
    unless ``cap_total`` scales such tets to a sum of 1.

    Returns ``(MuscleSet, report)``. The report (JSON-serialisable) holds ``min_jacobian_det``
    and ``max_jacobian_det`` (over the template's nodes, the pulled-back subject nodes and the
    template's muscle samples), ``target_volume_outside_template`` (share of the subject's volume whose tet centroid
    pulls back outside the template flesh), ``tets_over_full`` (tets summing above 1, template and
    subject), and per muscle (``muscles[name]``): ``template_volume_mm3``,
    ``expected_volume_mm3`` (the template volume times the warp's local volume change, det J,
    integrated over the muscle), ``target_volume_mm3``, ``volume_ratio`` (target / expected),
    ``outside_target`` (share of the warped template muscle falling outside the subject's flesh)
    and ``tets``. ``flagged`` maps each muscle that did not carry over to the reason: no subject
    tet holds it, more than ``max_outside`` of it falls outside the subject's flesh, or its
    volume ratio is below ``min_volume_ratio``. A warp that folds over the subject's mesh or
    the template's muscles raises a one-line FacesimError.
    """
    X, tets, vol = _check_mesh(X, tets, "target mesh")
    mus = template.muscles
    lam = barycentric_samples(samples_per_tet)
    q = len(lam)
    weight = np.full(q, 1.0 / q)
    tvol = template.tet_volumes()

    # the warp must not fold over the template, and must be invertible and unfolded over the
    # subject's nodes pulled back into template space
    det_lo, det_hi = warp.check_unfolded(template.X, "the template mesh")
    Yn, _ = _pull_back(warp, X, None, "target nodes")
    lo, hi = warp.check_unfolded(Yn, "the target mesh")
    det_lo, det_hi = min(det_lo, lo), max(det_hi, hi)

    # template structures, built once: point location, the entries grouped by tet
    loc = TetLocator(template.X, template.tets, snap)
    order = np.argsort(mus.tet, kind="stable")
    ptr = np.zeros(template.n_tets + 1, dtype=np.int64)
    np.add.at(ptr, mus.tet + 1, 1)
    ptr = np.cumsum(ptr)
    e_muscle = np.ascontiguousarray(mus.muscle[order], dtype=np.int32)
    e_fraction = np.ascontiguousarray(mus.fraction[order])
    e_fibre = np.ascontiguousarray(mus.fibre[order])

    # coverage: the subject's volume whose tet centroid pulls back outside the template flesh
    cen = Yn[tets].mean(axis=1)
    t_cen, _ = loc.locate(cen)
    outside_share = float(vol[t_cen < 0].sum() / vol.sum())

    # candidates: subject tets whose pulled-back ball reaches a template muscle tet's ball
    mtets = np.unique(mus.tet)
    if len(mtets):
        mcen = template.X[template.tets[mtets]].mean(axis=1)
        mrad = np.linalg.norm(template.X[template.tets[mtets]] - mcen[:, None], axis=2).max(axis=1)
        rad = np.linalg.norm(Yn[tets] - cen[:, None], axis=2).max(axis=1)
        d, _ = cKDTree(mcen).query(cen, k=1)
        cand = np.flatnonzero(d < rad + mrad.max() + snap + 1.0 + 0.1 * rad)
    else:
        cand = np.zeros(0, dtype=np.int64)

    # samples of the candidates, pulled back (Newton from the linear interpolant of the nodes)
    Ps = np.einsum("sk,ckj->csj", lam, X[tets[cand]]).reshape(-1, 3)
    guess = np.einsum("sk,ckj->csj", lam, Yn[tets[cand]]).reshape(-1, 3)
    Ys, Fs = _pull_back(warp, Ps, guess, "target samples", SAMPLE_TOL_MM, SAMPLE_MAX_MM)
    s_tet, _ = loc.locate(Ys)
    s_tet = np.ascontiguousarray(s_tet.reshape(len(cand), q))
    Fs = np.ascontiguousarray(Fs.reshape(len(cand), q, 3, 3))
    e_t, e_m, e_f, e_d = _k.accumulate_muscles(s_tet, weight, Fs, ptr, e_muscle, e_fraction, e_fibre, mus.n_muscles)
    e_t = cand[e_t].astype(np.int32)
    total = np.bincount(e_t, weights=e_f, minlength=len(tets))
    if cap_total:
        e_f = e_f / np.maximum(total[e_t], 1.0)
    e_f = np.minimum(e_f, 1.0)              # an average of fractions <= 1; clip its round-off
    key = np.lexsort((e_t, e_m))
    out = MuscleSet(names=mus.names, sides=mus.sides, sigma_max=mus.sigma_max, muscle=e_m[key], tet=e_t[key],
                    fraction=e_f[key], fibre=e_d[key])

    # forward check: the template's muscle samples, their volume change and where they land
    S = np.einsum("sk,ckj->csj", lam, template.X[template.tets[mtets]]).reshape(-1, 3)
    if len(S):
        lo, hi = warp.check_unfolded(S, "the template's muscles")
        det_lo, det_hi = min(det_lo, lo), max(det_hi, hi)
    det = warp.jacobian_det(S).reshape(len(mtets), q) if len(S) else np.zeros((0, q))
    inside = (TetLocator(X, tets, snap).locate(warp(S))[0] >= 0).reshape(len(mtets), q) if len(S) \
        else np.zeros((0, q), dtype=bool)
    row = np.searchsorted(mtets, mus.tet)
    grown = tvol[mus.tet] * mus.fraction * (det[row] @ weight)
    kept = tvol[mus.tet] * mus.fraction * ((det * inside)[row] @ weight)
    n = mus.n_muscles
    template_volume = mus.volume_per_muscle(tvol)
    expected = np.bincount(mus.muscle, weights=grown, minlength=n)
    inside_volume = np.bincount(mus.muscle, weights=kept, minlength=n)
    target_volume = out.volume_per_muscle(vol)
    ntets = out.tets_per_muscle()
    report_muscles, flagged = {}, {}
    for m, name in enumerate(mus.names):
        ratio = target_volume[m] / expected[m] if expected[m] > 0 else 0.0
        outside = 1.0 - inside_volume[m] / expected[m] if expected[m] > 0 else 1.0
        report_muscles[name] = {"template_volume_mm3": round(float(template_volume[m]), 3),
                                "expected_volume_mm3": round(float(expected[m]), 3),
                                "target_volume_mm3": round(float(target_volume[m]), 3),
                                "volume_ratio": round(float(ratio), 4), "outside_target": round(float(outside), 4),
                                "tets": int(ntets[m])}
        if outside > max_outside:
            flagged[name] = f"{outside:.0%} of its warped volume falls outside the target flesh" + \
                ("" if ntets[m] else " (no target tet holds it)")
        elif not ntets[m]:
            flagged[name] = "no target tet holds it"
        elif ratio < min_volume_ratio:
            flagged[name] = (f"its target volume {target_volume[m]:.0f} mm^3 is {ratio:.0%} of the warped template "
                             f"volume {expected[m]:.0f} mm^3 (below {min_volume_ratio:.0%})")
    template_total = mus.total_fraction(template.n_tets)
    report = {"samples_per_tet": q, "candidate_tets": int(len(cand)),
              "min_jacobian_det": round(det_lo, 4), "max_jacobian_det": round(det_hi, 4),
              "target_volume_outside_template": round(outside_share, 4),
              "tets_over_full": {"template": int((template_total > 1 + 1e-9).sum()),
                                 "target": int((total > 1 + 1e-9).sum())},
              "max_total_fraction": {"template": round(float(template_total.max(initial=0.0)), 4),
                                     "target": round(float(total.max(initial=0.0)), 4)},
              "capped": bool(cap_total), "muscles": report_muscles, "flagged": flagged}
    return out, report


# ============================================================================ the markers
def transfer_markers(template: FaceModel, warp: Warp, X, skin_tris, max_distance: float = 10.0,
                     min_normal_cos: float = 0.5, edge_tolerance: float = 1.0) -> tuple[MarkerSet, dict]:
    """The template's markers bound to the subject's skin ``skin_tris (s, 3)`` over nodes
    ``X (n, 3)`` mm.

    Each marker's skin point (its barycentric point on its template triangle) is warped, and
    bound to the closest point of the subject's skin among the triangles whose normal agrees
    with the warped template normal (``F^-T n``, cosine >= ``min_normal_cos``; keeps a lip
    marker off the mouth lining): that triangle and the barycentric coordinates of the point
    (:func:`facesim.mocap.binding.bind_point`). The offset (marker height, mm) and head flag are
    the template's. A marker is dropped, with its reason in the report, when no such skin lies
    within ``max_distance`` mm of the warped point, or when its closest point lies on the open
    edge of the subject's skin more than ``edge_tolerance`` mm away (a face mask without the
    forehead or the back of the head).

    Returns ``(MarkerSet, report)``: ``distance_mm`` (per kept marker, warped point to the
    subject's skin), ``max_distance_mm``, ``dropped`` ``{name: reason}``, ``head_markers`` (kept
    head markers) and ``warnings`` (fewer than 3 head markers: stabilisation needs 3). A warp
    that folds over the template's skin raises a one-line FacesimError, as does a subject skin
    no marker lands on.
    """
    X = np.ascontiguousarray(np.asarray(X, dtype=np.float64))
    F = np.ascontiguousarray(np.asarray(skin_tris), dtype=np.int32)
    if F.ndim != 2 or F.shape[1] != 3 or not len(F) or F.min() < 0 or F.max() >= len(X):
        raise FacesimError(f"target skin: expected triangles (s, 3) indexing its {len(X)} nodes, got shape {F.shape}")
    mk = template.markers
    corners = template.X[template.skin[mk.triangle]]
    p = np.einsum("rk,rkj->rj", mk.bary, corners)
    n0 = triangle_normals(template.X, template.skin[mk.triangle])
    warp.check_unfolded(np.r_[p, template.X[np.unique(template.skin)]], "the template skin")
    J = warp.jacobian(p)
    nrm = np.linalg.solve(np.transpose(J, (0, 2, 1)), n0[:, :, None])[:, :, 0]   # normals: F^-T n
    nrm = np.ascontiguousarray(nrm / np.linalg.norm(nrm, axis=1, keepdims=True))
    P = np.ascontiguousarray(warp(p))
    Fn = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    area = np.linalg.norm(Fn, axis=1)
    Fn = np.ascontiguousarray(np.where(area[:, None] > 0, Fn / np.where(area > 0, area, 1.0)[:, None], 0.0))
    r = len(P)
    tri = np.empty(r, dtype=np.int32)
    bary = np.zeros((r, 3))
    region = np.zeros(r, dtype=np.int64)
    dist = np.empty(r)
    _k.closest_on_triangles(X, F, Fn, P, nrm, float(min_normal_cos), tri, bary, region, dist)

    edges = np.sort(F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    u, c = np.unique(edges, axis=0, return_counts=True)
    open_edges = {tuple(e) for e in u[c == 1]}
    open_nodes = set(np.unique(u[c == 1]).tolist())
    keep, dropped, distance = [], {}, {}
    out_tri, out_bary = [], []
    for i, name in enumerate(mk.names):
        if tri[i] < 0 or dist[i] > max_distance:
            what = "no target skin faces its way" if tri[i] < 0 else f"the target skin is {dist[i]:.1f} mm away"
            dropped[name] = f"{what} (max {max_distance:g} mm, normals within " \
                            f"{math.degrees(math.acos(min(max(min_normal_cos, -1), 1))):.0f} deg)"
            continue
        abc = F[tri[i]]
        on = [abc[v] for v in range(3) if region[i] >> v & 1]   # the corners the closest point depends on
        at_edge = (len(on) == 2 and tuple(sorted(on)) in open_edges) or (len(on) == 1 and on[0] in open_nodes)
        if at_edge and dist[i] > edge_tolerance:
            dropped[name] = f"it lands {dist[i]:.1f} mm beyond the open edge of the target skin"
            continue
        closest = bary[i] @ X[abc]
        b, _ = bind_point(X[abc], closest, P[i], Fn[tri[i]])
        keep.append(i)
        out_tri.append(tri[i])
        out_bary.append(b)
        distance[name] = round(float(dist[i]), 4)
    if not keep:
        raise FacesimError(f"target skin: none of the template's {r} markers lands within {max_distance:g} mm of it "
                           f"(is the skin in facesim's frame, in mm?)")
    keep = np.array(keep)
    markers = MarkerSet(names=tuple(mk.names[i] for i in keep), triangle=np.array(out_tri, dtype=np.int32),
                        bary=np.array(out_bary), offset=mk.offset[keep], head=mk.head[keep])
    heads = int(markers.head.sum())
    report = {"distance_mm": distance, "max_distance_mm": round(float(max(distance.values())), 4),
              "dropped": dropped, "head_markers": heads,
              "warnings": [] if heads >= 3 else [f"only {heads} head markers kept (head stabilisation needs 3)"]}
    return markers, report


__all__ = ["LANDMARK_NAMES", "MIN_LANDMARKS", "Warp", "barycentric_samples", "landmark_warp", "template_landmarks",
           "transfer_markers", "transfer_muscles"]
