"""The silhouette energy of rigid teeth poses against segmented images, and its Gauss-Newton model.

For every camera the model (upper and lower teeth, each at its world pose) is rasterised
(:mod:`facesim.teeth.raster`); its *contour* is the inner boundary of the union of both
projections (the z-buffer decides which tooth a contour pixel belongs to, so the upper teeth
occlude the lower ones), and each contour pixel is traced back to the point of the tooth it
sees (a fixed point of that body for the linearisation). The data's contour is the inner
boundary of the segmented teeth mask. Both sets leave out pixels within ``occluder_px`` of an
occluder (lips): there a model contour may be hidden and a data contour is the lip's edge,
not a tooth's. Two terms, each the mean over its points of a truncated squared distance
(px^2, truncated at the gate ``gate_px``):

* model -> data: every visible model contour point to the nearest data contour pixel (the
  distance transform of the data contour, ``cv2.distanceTransform``);
* data -> model: every data contour pixel to the nearest model contour point, so the model cannot
  slide off or shrink into part of the mask.

Gauss-Newton works on the same pairs as point-to-line residuals ``n . (pi(P X) - q)`` (``n`` the
data contour's normal at ``q``), with Huber weights, on a 6-vector ``(omega rad, v mm)`` that
moves a body about its contour points' centroid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from facesim.teeth.cameras import projection_jacobian
from facesim.teeth.raster import contour_points
from facesim.teeth.segment import OCCLUDER, TEETH


def _inner_boundary(mask) -> np.ndarray:
    """``(h, w) bool``: pixels of ``mask`` with a 4-neighbour outside it (or on the image's edge)."""
    m = np.asarray(mask, bool)
    inner = m.copy()
    inner[1:, :] &= m[:-1, :]
    inner[:-1, :] &= m[1:, :]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    inner[0, :] = inner[-1, :] = inner[:, 0] = inner[:, -1] = False
    return m & ~inner


@dataclass
class View:
    """One camera's data at one resolution.

    camera : the (scaled) :class:`~facesim.teeth.cameras.Camera`.
    usable : (h, w) bool, pixels away from occluders and the image's border.
    edges : (k, 2) float64 (u, v) px of the usable data contour pixels; normals : (k, 2) unit.
    distance : (h, w) float32 px to the nearest data contour pixel; tree : cKDTree of ``edges``.
    """

    camera: object
    usable: np.ndarray
    edges: np.ndarray
    normals: np.ndarray
    distance: np.ndarray
    tree: cKDTree | None

    @classmethod
    def of(cls, camera, labels, occluder_px: float = 3.0, border_px: int = 2) -> View:
        """The view of ``labels (h, w) uint8`` (:mod:`facesim.teeth.segment`) in ``camera``."""
        import cv2

        teeth = labels == TEETH
        occ = (labels == OCCLUDER).astype(np.uint8)
        r = max(1, int(round(occluder_px)))
        near = cv2.dilate(occ, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) > 0
        usable = ~near
        b = border_px
        usable[:b, :] = usable[-b:, :] = usable[:, :b] = usable[:, -b:] = False
        contour = _inner_boundary(teeth) & usable
        rows, cols = np.nonzero(contour)
        smooth = cv2.GaussianBlur(teeth.astype(np.float32), (0, 0), 1.5)
        gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)[rows, cols]
        gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)[rows, cols]
        g = np.hypot(gx, gy)
        ok = g > 1e-6
        edges = np.column_stack([cols[ok], rows[ok]]).astype(np.float64)
        normals = np.column_stack([gx[ok] / g[ok], gy[ok] / g[ok]]).astype(np.float64)
        src = np.full(teeth.shape, 255, np.uint8)
        src[rows[ok], cols[ok]] = 0
        distance = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) if len(edges) else \
            np.full(teeth.shape, 1e6, np.float32)
        return cls(camera, usable, edges, normals, distance, cKDTree(edges) if len(edges) else None)


@dataclass
class Contour:
    """The model contour in one view: ``uv (k, 2)`` px of the contour pixels, ``rest (k, 3)`` mm
    the points they see on the rest teeth, ``body (k,)`` 0 upper / 1 lower, ``visible (k,)``
    those on usable pixels."""

    uv: np.ndarray
    rest: np.ndarray
    body: np.ndarray
    visible: np.ndarray


class Model:
    """The dentition as one mesh (upper first) posed by two world poses."""

    def __init__(self, dentition):
        self.V, self.F, self.n_upper_F = dentition.merged()
        self.n_upper_V = len(dentition.upper_V)

    def posed(self, upper, lower) -> np.ndarray:
        """``(n, 3)`` world vertices with the upper teeth at ``upper (4, 4)`` and the lower at ``lower``."""
        Vu, Vl = self.V[:self.n_upper_V], self.V[self.n_upper_V:]
        return np.concatenate([Vu @ upper[:3, :3].T + upper[:3, 3], Vl @ lower[:3, :3].T + lower[:3, 3]])

    def contour(self, view: View, upper, lower) -> Contour:
        """The model contour of the poses in ``view``."""
        rows, cols, tri, rest = contour_points(view.camera, self.posed(upper, lower), self.F, self.V)
        body = (tri >= self.n_upper_F).astype(np.int8)
        return Contour(np.column_stack([cols, rows]).astype(np.float64), rest, body, view.usable[rows, cols])


@dataclass
class Pairs:
    """Matched points of one view for one body: ``rest (k, 3)`` mm on the body, targets ``q (k, 2)``
    px, normals ``n (k, 2)``, ``kind (k,)`` 0 model->data, 1 data->model."""

    rest: np.ndarray
    q: np.ndarray
    n: np.ndarray
    kind: np.ndarray


def energy_and_pairs(view: View, contour: Contour, body: int | None, gate: float):
    """``(energy px^2, pairs, stats)`` of one view: the two truncated terms (module docstring) over
    all bodies, and the pairs of ``body`` (None: no pairs). ``stats`` = (visible model points of
    each body (2,), of them within ``gate / 2`` of the data (2,), all model points of each body (2,),
    (data contour pixels, of them within ``gate / 2`` of the model) (2,))."""
    g2 = gate * gate
    vis = contour.visible
    uv = contour.uv
    counts = np.array([(contour.body == b).sum() for b in (0, 1)])
    if view.tree is None or not vis.any():
        stats = (np.array([(vis & (contour.body == b)).sum() for b in (0, 1)]), np.zeros(2, int), counts,
                 np.array([len(view.edges), 0]))
        return 2.0 * g2, None, stats
    iu = np.clip(np.rint(uv[vis]).astype(int), 0, None)
    d_md = view.distance[iu[:, 1], iu[:, 0]].astype(np.float64)
    e_md = np.minimum(d_md * d_md, g2).mean()
    mtree = cKDTree(uv)
    d_dm, j_dm = mtree.query(view.edges, distance_upper_bound=gate)
    found = np.isfinite(d_dm)
    e_dm = np.where(found, d_dm * d_dm, g2).mean()
    near = d_md < 0.5 * gate
    stats = (np.array([(contour.body[vis] == b).sum() for b in (0, 1)]),
             np.array([((contour.body[vis] == b) & near).sum() for b in (0, 1)]), counts,
             np.array([len(found), int((d_dm < 0.5 * gate).sum())]))
    pairs = None
    if body is not None:
        # model -> data: visible model points of the body to their nearest data contour pixel
        sel = vis & (contour.body == body)
        d, i = view.tree.query(uv[sel], distance_upper_bound=gate)
        ok = np.isfinite(d)
        rest_a, q_a, n_a = contour.rest[sel][ok], view.edges[i[ok]], view.normals[i[ok]]
        # data -> model: data contour pixels whose nearest model point is of the body
        jj = j_dm[found]
        mine = contour.body[jj] == body
        rest_b, q_b, n_b = contour.rest[jj[mine]], view.edges[found][mine], view.normals[found][mine]
        pairs = Pairs(np.concatenate([rest_a, rest_b]), np.concatenate([q_a, q_b]), np.concatenate([n_a, n_b]),
                      np.concatenate([np.zeros(len(q_a), np.int8), np.ones(len(q_b), np.int8)]))
    return e_md + e_dm, pairs, stats


def normal_equations(view: View, pairs: Pairs, pose, centre, huber: float):
    """``(JtWJ (6, 6), JtWr (6,), JtHJ (6, 6), sum h r^2, sum h, residuals (k,))`` of the
    point-to-line residuals of ``pairs`` for the body at world pose ``pose (4, 4)``: ``W`` the Huber
    weights ``h`` divided by the number of pairs of each term (the two terms weigh the same),
    ``JtHJ`` with the plain Huber weights (for the covariance). The 6-vector moves the body by
    ``X -> X + omega x (X - centre) + v`` in the world (``centre (3,)`` mm)."""
    cam = view.camera
    Xw = pairs.rest @ pose[:3, :3].T + pose[:3, 3]
    Y = cam.to_camera(Xw)
    h = Y @ cam.K.T
    uv = h[:, :2] / h[:, 2:3]
    r = np.einsum("ij,ij->i", pairs.n, uv - pairs.q)
    Jp = projection_jacobian(cam.K, Y)                       # (k, 2, 3)
    g = np.einsum("ki,kij->kj", pairs.n, Jp) @ cam.R          # (k, 3): d r / d X_world
    d = Xw - centre
    J = np.column_stack([np.cross(d, g), g])                  # d r / d (omega, v): (d x g, g)
    a = np.abs(r)
    hub = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-12))
    w = hub.copy()
    for kind in (0, 1):   # the two terms weigh the same whatever their numbers of points
        m = pairs.kind == kind
        if m.any():
            w[m] /= m.sum()
    JW = J * w[:, None]
    return JW.T @ J, JW.T @ r, (J * hub[:, None]).T @ J, float((hub * r * r).sum()), float(hub.sum()), r


def moved(pose, delta, centre) -> np.ndarray:
    """``(4, 4)``: ``pose`` moved by ``delta = (omega rad, v mm)`` about ``centre (3,)`` mm (world)."""
    from facesim import se3

    R = se3.so3_exp(delta[:3])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ centre + delta[3:]
    return T @ pose


__all__ = ["Contour", "Model", "Pairs", "View", "energy_and_pairs", "moved", "normal_equations"]
