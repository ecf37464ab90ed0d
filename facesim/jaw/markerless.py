"""Markerless jaw tracking (Zoss, Beeler, Gross & Bradley 2019): the jaw pose from the skin alone.

The learning half of the method, on :class:`~facesim.jaw.markerless_data.MarkerlessData`:

- **Regression** (paper section 5.2). A frame's input is the vector of all its skin feature
  displacements ``skin - skin_rest`` (``3P`` values, mm, skull frame), standardised; its outputs
  are the ``3B`` coordinates of the bone-point displacements (mm), standardised too. One
  epsilon-SVR with an RBF kernel per output coordinate (scikit-learn ``SVR`` to train; the
  predictor keeps only plain arrays and evaluates the kernel expansion itself).
- **Rigid fit** (5.3): the jaw pose is the Kabsch fit of ``bone_rest`` onto the predicted bone
  points (:func:`facesim.se3.fit_rotation`, det +1).
- **Baseline** (section 7): the rigid Procrustes motion of the skin feature points from rest,
  taken as the jaw's motion (what an artist does by hand with chin markers).
- **Error** (section 7): per frame the mean distance (mm) over the bone points between the pose
  found and the true one (:func:`facesim.se3.vertex_errors`).
- **Retargeting** (6.1): per-feature maps ``M_v`` taking a new subject's displacements into the
  source subject's feature space, solved from a few calibration frames with known jaw poses by
  ``scipy.optimize.least_squares`` with a smoothness and a closeness-to-identity regulariser
  (the paper's eqs. 2-3; :func:`retarget` says which maps and why).
- **Multi-subject mapping** (6.2): each further subject is turned into the first (primary)
  subject's frame by one rigid transform fitted to their rest feature and bone points (the
  points correspond index by index across subjects), and one SVR set learns from all frames.

Frames: every subject is moved into the predictor's *source* frame (its primary training
subject's) by the rigid fit of its rest points (``skin_rest`` and ``bone_rest``) onto the
source's; displacements turn with its rotation ``R_g`` on the way in and with ``R_gᵀ`` on the
way out. For the training subject itself ``R_g`` is the identity, for a new subject it removes
a different placement of its head in its own skull frame.

Predictors are files of their own: one compressed ``.npz`` (``facesim-markerless-predictor``
version 1) of plain arrays -- support vectors, dual coefficients, intercepts, kernel width,
scalers, rest points, per-feature maps -- and a JSON ``meta`` (hyper-parameters, training
subjects and frame counts, retargeting). No pickles.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from facesim import se3
from facesim._files import NpzFormat, read_npz, write_npz
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw.markerless_data import MarkerlessData

PREDICTOR_FORMAT = NpzFormat("facesim-markerless-predictor", 1,
                             what="a markerless jaw predictor .npz (facesim jaw markerless train)",
                             name="a facesim markerless jaw predictor", label="markerless predictor format")

#: The cross-validation grid of :func:`train`. ``C`` and ``epsilon`` act on standardised outputs
#: (epsilon in output standard deviations); ``gamma`` is in units of 1 / (number of inputs), the
#: kernel width scikit-learn calls "scale" for standardised inputs.
DEFAULT_GRID = {"C": (1.0, 10.0, 100.0), "epsilon": (0.01, 0.03), "gamma": (0.1, 0.3, 1.0)}

#: Rows of inputs per block of the kernel matrix in :meth:`Predictor.regress` (memory: rows x
#: support vectors doubles).
_BLOCK = 512
#: Floor of the input scale of marker features, mm (see :func:`train`).
MARKER_SCALE_MM = 4.0


@dataclass(frozen=True, eq=False)
class Predictor:
    """A trained (and possibly retargeted) skin-to-jaw predictor. Arrays float64.

    The regression, in the source frame: ``z = (M_v R_g d_v - x_mean) / x_scale`` stacked over
    the features v, ``y_k = y_mean_k + y_scale_k (Σ_i dual_ki exp(-gamma |z - support_i|²) +
    intercept_k)``; ``y`` reshaped ``(B, 3)`` is the bone-point displacement (mm).

    support : (S, 3P) standardised support vectors (the union over the outputs).
    dual : (3B, S) dual coefficients per output (zero where a vector is not one of its supports).
    intercept : (3B,) ; gamma : kernel width, 1 / (standardised input units)².
    x_mean, x_scale : (3P,) input scaler, mm; y_mean, y_scale : (3B,) output scaler, mm.
    source_skin_rest (P, 3), source_bone_rest (B, 3) : the primary training subject's rest points
        (mm): the frame of the regression.
    skin_rest (P, 3), bone_rest (B, 3) : the rest points of the subject the predictor reads when
        given bare skin positions (the source, or the subject it was retargeted to), mm.
    feature_maps : (P, 3, 3) ``M_v``, the identity unless retargeted (:func:`retarget`).
    meta : hyper-parameters, training subjects and frame counts, retargeting (JSON-serialisable).
    """

    support: np.ndarray
    dual: np.ndarray
    intercept: np.ndarray
    gamma: float
    x_mean: np.ndarray
    x_scale: np.ndarray
    y_mean: np.ndarray
    y_scale: np.ndarray
    source_skin_rest: np.ndarray
    source_bone_rest: np.ndarray
    skin_rest: np.ndarray
    bone_rest: np.ndarray
    feature_maps: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def n_features(self) -> int:
        """P, the number of skin feature points read."""
        return int(self.skin_rest.shape[0])

    @property
    def n_bone(self) -> int:
        """B, the number of bone points predicted."""
        return int(self.bone_rest.shape[0])

    @property
    def retargeted(self) -> bool:
        """Whether :func:`retarget` made this predictor (its ``feature_maps`` are not the identity)."""
        return "retarget" in self.meta

    def regress(self, features: np.ndarray) -> np.ndarray:
        """Bone displacements ``(N, B, 3)`` mm from source-frame skin displacements ``features
        (N, P, 3)`` mm (``M_v`` applied here, ``R_g`` not): the RBF expansion, vectorised."""
        m = np.einsum("pij,npj->npi", self.feature_maps, features).reshape(len(features), -1)
        z = (m - self.x_mean) / self.x_scale
        out = np.empty((len(z), len(self.intercept)))
        sq = np.einsum("ij,ij->i", self.support, self.support)
        for s in range(0, len(z), _BLOCK):
            out[s:s + _BLOCK] = _kernel(z[s:s + _BLOCK], self.support, sq, self.gamma) @ self.dual.T
        y = (out + self.intercept) * self.y_scale + self.y_mean
        return y.reshape(len(z), -1, 3)


def _kernel(Z: np.ndarray, S: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """``(n, s)`` exp(-gamma |z - s|²) of rows ``Z (n, d)`` and ``S (s, d)`` (``sq`` = |s|²); the
    same expansion of the square as libsvm's, so the two agree to rounding."""
    d2 = np.einsum("ij,ij->i", Z, Z)[:, None] + sq[None, :] - 2.0 * (Z @ S.T)
    return np.exp(-gamma * np.maximum(d2, 0.0))


# ---------------------------------------------------------------------------------------------
# frames and rigid fits


def rigid_poses(rest, points) -> np.ndarray:
    """Kabsch poses ``(N, 4, 4)`` taking ``rest (B, 3)`` mm closest to each frame of ``points
    (N, B, 3)`` mm in least squares (equal weights; a proper rotation, det +1, even where the
    points are planar or noisy enough for the unconstrained fit to reflect): the paper's 5.3."""
    return se3.rigid_fit(np.asarray(rest, dtype=np.float64)[None], points)


def _rest_points(skin_rest: np.ndarray, bone_rest: np.ndarray) -> np.ndarray:
    return np.concatenate([skin_rest, bone_rest])


def alignment(skin_rest, bone_rest, to_skin_rest, to_bone_rest) -> np.ndarray:
    """``(3, 3)`` rotation ``R_g`` of the rigid fit of a subject's rest points (``skin_rest (P, 3)``
    and ``bone_rest (B, 3)``, mm) onto another's (``to_...``, the same P and B, corresponding
    index by index): the map of displacement vectors from its frame into the other's (6.2)."""
    A, B = _rest_points(skin_rest, bone_rest), _rest_points(to_skin_rest, to_bone_rest)
    if np.array_equal(A, B):     # the same subject: exactly the identity, not an SVD's rounding of it
        return np.eye(3)
    return se3.rigid_fit(A, B)[:3, :3]


def _check_layout(pred: Predictor, n_features: int, n_bone: int | None = None) -> None:
    if n_features != pred.n_features:
        raise FacesimError(f"predictor expects {pred.n_features} skin features, data has {n_features}")
    if n_bone is not None and n_bone != pred.n_bone:
        raise FacesimError(f"predictor predicts {pred.n_bone} bone points, data has {n_bone}")


def feature_kind(meta: dict) -> tuple[str, tuple[str, ...]]:
    """``("skin", ())`` or ``("markers", names)``: what the feature points of a dataset's or a
    predictor's ``meta`` are (:meth:`MarkerlessData.marker_features`)."""
    f = meta.get("features") or {}
    if f.get("kind") == "markers":
        return "markers", tuple(str(n) for n in f.get("names", ()))
    return "skin", ()


def features_for(pred: Predictor, data: MarkerlessData) -> MarkerlessData:
    """``data`` with the feature points ``pred`` reads: its skin features, or its markers for a
    predictor trained on markers (their names must match the predictor's, in order)."""
    kind, names = feature_kind(pred.meta)
    have, have_names = feature_kind(data.meta)
    if kind == have:
        out = data
    elif kind == "markers":
        out = data.marker_features()
        have_names = feature_kind(out.meta)[1]
    else:
        raise FacesimError("the predictor reads skin features, the data holds markers")
    if kind == "markers" and have_names != names:
        missing = [n for n in names if n not in have_names]
        raise FacesimError(f"the predictor reads the markers {', '.join(names[:4])}, ... ({len(names)}); the data has "
                           + (f"no {', '.join(missing[:5])}" if missing else "them in another order"))
    return out


def _subject_frame(pred: Predictor, data) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(displacements (N, P, 3), bone_rest (B, 3), R_g (3, 3)) of ``data``: a MarkerlessData or
    bare skin positions (N, P, 3) of the predictor's own subject."""
    if isinstance(data, MarkerlessData):
        data = features_for(pred, data)
        _check_layout(pred, data.n_features, len(data.bone_rest))
        R = alignment(data.skin_rest, data.bone_rest, pred.source_skin_rest, pred.source_bone_rest)
        return data.skin_displacement, data.bone_rest, R
    skin = np.asarray(data, dtype=np.float64)
    if skin.ndim == 2:
        skin = skin[None]
    if skin.ndim != 3 or skin.shape[2] != 3:
        raise FacesimError(f"skin: expected (N, P, 3) feature point positions, mm, got shape {skin.shape}")
    _check_layout(pred, skin.shape[1])
    if not np.isfinite(skin).all():
        raise FacesimError("skin: expected finite feature point positions, got NaN or inf")
    R = alignment(pred.skin_rest, pred.bone_rest, pred.source_skin_rest, pred.source_bone_rest)
    return skin - pred.skin_rest[None], pred.bone_rest, R


# ---------------------------------------------------------------------------------------------
# prediction, baseline, errors


def predict_bone_points(pred: Predictor, data) -> np.ndarray:
    """Predicted bone points ``(N, B, 3)`` mm (skull frame of ``data``) from a
    :class:`MarkerlessData` or bare skin feature positions ``(N, P, 3)`` mm of the predictor's
    own subject (``pred.skin_rest``). Needs no poses."""
    disp, bone_rest, R = _subject_frame(pred, data)
    y = pred.regress(disp @ R.T)                 # into the source frame, regress ...
    return bone_rest[None] + y @ R               # ... and back: R_gᵀ y


def predict_poses(pred: Predictor, data) -> np.ndarray:
    """Jaw poses ``(N, 4, 4)`` (mandible relative to skull, mm): the Kabsch fit of the bone rest
    points onto :func:`predict_bone_points`. ``data`` as there."""
    points = predict_bone_points(pred, data)
    bone_rest = data.bone_rest if isinstance(data, MarkerlessData) else pred.bone_rest
    return rigid_poses(bone_rest, points)


def baseline_poses(data: MarkerlessData) -> np.ndarray:
    """The paper's baseline (section 7): poses ``(N, 4, 4)``, each the rigid Procrustes transform
    of ``skin_rest`` onto the frame's skin feature points, taken as the jaw's pose."""
    return rigid_poses(data.skin_rest, data.skin)


def pose_error(poses, true_poses, bone_rest) -> np.ndarray:
    """``(N,)`` mm: per frame the mean distance over ``bone_rest (B, 3)`` between the points moved
    by ``poses (N, 4, 4)`` and by ``true_poses (N, 4, 4)`` (the paper's error measure)."""
    return se3.vertex_errors(poses, true_poses, bone_rest)


def _summary(e: np.ndarray) -> dict:
    if len(e) == 0:
        return {"mean_mm": float("nan"), "p95_mm": float("nan"), "max_mm": float("nan")}
    return {"mean_mm": float(e.mean()), "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max())}


def evaluate(pred: Predictor, data: MarkerlessData) -> dict:
    """Predictor and baseline errors on ``data`` (needs poses), over its frames with ``ok``:
    ``{"predictor": {"mean_mm", "p95_mm", "max_mm"}, "baseline": {...}, "frames": N,
    "excluded": [indices of the frames with ok False, not evaluated]}``."""
    if data.poses is None:
        raise FacesimError("data has no jaw poses (field 'poses'): evaluation needs the true jaw")
    keep = np.flatnonzero(data.ok)
    sub = features_for(pred, data).subset(keep)
    e_pred = pose_error(predict_poses(pred, sub), sub.poses, sub.bone_rest) if len(keep) else np.zeros(0)
    e_base = pose_error(baseline_poses(sub), sub.poses, sub.bone_rest) if len(keep) else np.zeros(0)
    return {"predictor": _summary(e_pred), "baseline": _summary(e_base), "frames": int(len(keep)),
            "excluded": [int(i) for i in np.flatnonzero(~data.ok)]}


# ---------------------------------------------------------------------------------------------
# training


def _training_set(data: MarkerlessData, R: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(inputs (n, 3P), outputs (n, 3B)) mm of ``data``'s ok frames, turned by ``R`` (3, 3)."""
    if data.poses is None:
        raise FacesimError(f"{what}: no jaw poses (field 'poses'): training needs them")
    ok = np.flatnonzero(data.ok)
    X = (data.skin_displacement[ok] @ R.T).reshape(len(ok), -1)
    Y = ((data.bone_points()[ok] - data.bone_rest[None]) @ R.T).reshape(len(ok), -1)
    return X, Y


def _scaler(A: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    mean, scale = A.mean(axis=0), A.std(axis=0)
    scale = np.maximum(scale, floor)
    return mean, np.where(scale > 1e-12 * max(float(scale.max()), 1.0), scale, 1.0)


def _fit_svrs(Z: np.ndarray, V: np.ndarray, C: float, epsilon: float, gamma: float) -> list:
    from sklearn.svm import SVR   # imported here: reading and applying predictors needs no scikit-learn

    return [SVR(kernel="rbf", C=C, epsilon=epsilon, gamma=gamma, cache_size=500).fit(Z, V[:, k])
            for k in range(V.shape[1])]


def _pack(svrs: list, n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices (S,) of the training rows that are a support vector of any output, dual (K, S),
    intercept (K,)) of fitted SVRs."""
    used = np.unique(np.concatenate([m.support_ for m in svrs]))
    where = np.full(n_rows, -1)
    where[used] = np.arange(len(used))
    dual = np.zeros((len(svrs), len(used)))
    for k, m in enumerate(svrs):
        dual[k, where[m.support_]] = m.dual_coef_[0]
    return used, dual, np.array([float(m.intercept_[0]) for m in svrs])


def _point_error(Y_pred: np.ndarray, Y_true: np.ndarray) -> float:
    """Mean bone-point distance (mm) between two (n, 3B) displacement sets."""
    d = (Y_pred - Y_true).reshape(len(Y_true), -1, 3)
    return float(np.linalg.norm(d, axis=2).mean())


def _folds(counts: Sequence[int], cv_frames: int, cv_folds: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, fold of each row) for cross-validation: of each subject (``counts`` rows each, in
    order) an evenly strided subsample, ``cv_frames`` rows in all at most, cut into ``cv_folds``
    contiguous blocks; fold k holds the k-th block of every subject, so a held-out fold is a part
    of each sequence the others did not see (frames next to each other in time are alike, and
    shuffled folds would let neighbours of the test frames into training)."""
    total = sum(counts)
    rows, folds, start = [], [], 0
    for n in counts:
        m = min(n, max(cv_folds, int(np.ceil(cv_frames * n / total))))
        idx = np.unique(np.linspace(0, n - 1, m).round().astype(int))
        rows.append(start + idx)
        folds.append(np.arange(len(idx)) * cv_folds // len(idx))
        start += n
    return np.concatenate(rows), np.concatenate(folds)


def train(datasets, *, cv_folds: int = 3, grid: dict | None = None, cv_frames: int = 500) -> Predictor:
    """Train the skin-to-jaw regression on one subject or several (the multi-subject mapping).

    datasets : a MarkerlessData or a sequence of them, all with poses and the same feature layout
        (P skin and B bone points, corresponding index by index). The first is the primary
        subject: the others are turned into its frame by :func:`alignment` (6.2). Frames with
        ``ok`` False are left out.
    cv_folds, grid, cv_frames : the hyper-parameters (C, epsilon, gamma) are the grid point
        (``grid``: lists under "C", "epsilon", "gamma", units of :data:`DEFAULT_GRID`) with the
        least cross-validated mean bone-point distance, over ``cv_folds`` folds of at most
        ``cv_frames`` frames (:func:`_folds`); then every frame is learned with them.

    One set of hyper-parameters serves all 3B outputs: they are coordinates of five points of
    one rigid bone, all driven by the same few degrees of freedom from the same inputs, so the
    kernel width that suits one suits the others (outputs are standardised, so C and epsilon
    mean the same for each); and the criterion is the paper's error, which involves all outputs
    at once. A search per output would cost 3B times as much for no gain visible in that error.

    Returns a :class:`Predictor` whose ``meta`` records the hyper-parameters, the CV errors of
    the grid, and per subject its name and frame counts (used, excluded).
    """
    datasets = [datasets] if isinstance(datasets, MarkerlessData) else list(datasets)
    if not datasets:
        raise FacesimError("train: expected at least one dataset")
    primary = datasets[0]
    grid = {**DEFAULT_GRID, **(grid or {})}
    if cv_folds < 2:
        raise FacesimError(f"cv_folds: expected at least 2, got {cv_folds}")
    Xs, Ys, subjects = [], [], []
    kind = feature_kind(primary.meta)
    for i, d in enumerate(datasets):
        name = str(d.meta.get("subject", f"subject {i}"))
        if feature_kind(d.meta) != kind:
            raise FacesimError(f"{name}: its features are {feature_kind(d.meta)[0]} "
                               f"({len(feature_kind(d.meta)[1])} markers), the primary subject's {kind[0]} "
                               f"({len(kind[1])} markers); expected the same feature points")
        if d.n_features != primary.n_features or d.bone_rest.shape != primary.bone_rest.shape:
            raise FacesimError(f"{name}: {d.n_features} skin and {len(d.bone_rest)} bone points, the primary subject "
                               f"has {primary.n_features} and {len(primary.bone_rest)}")
        R = alignment(d.skin_rest, d.bone_rest, primary.skin_rest, primary.bone_rest)
        X, Y = _training_set(d, R, name)
        Xs.append(X)
        Ys.append(Y)
        subjects.append({"name": name, "frames": int(len(X)), "excluded": int((~d.ok).sum()),
                         "alignment_deg": float(np.degrees(np.linalg.norm(se3.so3_log(R))))})
    X, Y = np.concatenate(Xs), np.concatenate(Ys)
    if len(X) < 2 * cv_folds:
        raise FacesimError(f"train: {len(X)} usable frames (ok, with poses), expected at least {2 * cv_folds}")
    # Marker features include markers that hardly move with the jaw (forehead, temples): scaled by
    # their own spread (hundredths of a mm) a capture's noise or a marker placed a millimetre off
    # would be hundreds of standard deviations and blank the RBF kernel. Their scale is floored at
    # MARKER_SCALE_MM, so the kernel measures the markers' motion in millimetres wherever they move
    # less than that. Measured (benchmarks/RESULTS.md, issue 17): held-out frames of the coarse face
    # 0.25 mm with a 0.5 mm floor, 0.23 with 2 mm, 0.20 with 4 mm; the demo clip (made on the medium
    # face: another mesh, 0.5 mm noise) 1.85, 1.48 and 1.35 mm. The skin features all move with the
    # jaw (the chin and jaw mask) and are scaled as the paper has them.
    x_mean, x_scale = _scaler(X, MARKER_SCALE_MM if kind[0] == "markers" else 0.0)
    y_mean, y_scale = _scaler(Y)
    Z, V = (X - x_mean) / x_scale, (Y - y_mean) / y_scale

    rows, fold = _folds([len(x) for x in Xs], cv_frames, cv_folds)
    scores = []
    for C in grid["C"]:
        for eps in grid["epsilon"]:
            for g in grid["gamma"]:
                gamma = float(g) / Z.shape[1]
                err = []
                for k in range(cv_folds):
                    tr, te = rows[fold != k], rows[fold == k]
                    svrs = _fit_svrs(Z[tr], V[tr], C, eps, gamma)
                    V_pred = np.stack([m.predict(Z[te]) for m in svrs], axis=1)
                    err.append(_point_error(V_pred * y_scale, V[te] * y_scale))
                scores.append({"C": float(C), "epsilon": float(eps), "gamma": float(g), "cv_mm": float(np.mean(err))})
    best = min(scores, key=lambda s: s["cv_mm"])
    gamma = best["gamma"] / Z.shape[1]
    svrs = _fit_svrs(Z, V, best["C"], best["epsilon"], gamma)
    used, dual, intercept = _pack(svrs, len(Z))
    meta = {"hyper": {"C": best["C"], "epsilon": best["epsilon"], "gamma": gamma, "gamma_units": best["gamma"],
                      "cv_mm": best["cv_mm"], "cv_folds": cv_folds, "cv_frames": int(len(rows)), "grid": scores},
            "subjects": subjects, "frames": int(len(X)), "support_vectors": int(len(used)),
            "features": {"kind": kind[0], "names": list(kind[1])}}
    return Predictor(Z[used], dual, intercept, gamma, x_mean, x_scale, y_mean, y_scale,
                     primary.skin_rest.copy(), primary.bone_rest.copy(), primary.skin_rest.copy(),
                     primary.bone_rest.copy(), np.broadcast_to(np.eye(3), (primary.n_features, 3, 3)).copy(), meta)


# ---------------------------------------------------------------------------------------------
# retargeting


def _rotation_jacobian(omega: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` d(exp(omega) d)/d omega at ``omega (..., 3)`` where ``y = exp(omega) d``:
    -[y]× J_l(omega), J_l the left Jacobian of SO(3) (the V of :mod:`facesim.se3`)."""
    theta = np.linalg.norm(omega, axis=-1)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    B = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(t)) / t**2)
    Cc = np.where(small, 1 / 6 - theta**2 / 120, (t - np.sin(t)) / t**3)
    K = se3.hat(omega)
    J = np.eye(3) + B[..., None, None] * K + Cc[..., None, None] * (K @ K)
    return -se3.hat(y) @ J


def _neighbour_edges(points: np.ndarray, k: int) -> np.ndarray:
    """``(E, 2)`` the undirected edges joining each of ``points (P, 3)`` to its k nearest others."""
    from scipy.spatial import cKDTree

    k = min(k, len(points) - 1)
    if k < 1:
        return np.zeros((0, 2), dtype=int)
    _, nn = cKDTree(points).query(points, k + 1)
    edges = np.sort(np.stack([np.repeat(np.arange(len(points)), k), nn[:, 1:].ravel()], axis=1), axis=1)
    return np.unique(edges, axis=0)


class _Calibration:
    """The least-squares problem of :func:`retarget`: parameters ``x (P * n)``, per feature the
    rotation vector ``w_v`` (rad) and, with ``scale``, the log scale ``s_v``; residuals the fit
    (F x 3B, mm, over sqrt F), then sqrt(smoothness) x the parameter differences along ``edges``,
    then sqrt(identity) x the parameters.

    pred : the source predictor; D : (F, P, 3) calibration displacements in the source frame, mm;
    target : (F, 3B) their true bone displacements in the source frame, mm; edges : (E, 2).
    """

    def __init__(self, pred: Predictor, D, target, edges, smoothness: float, identity: float, scale: bool):
        from scipy import sparse

        self.pred, self.D, self.target, self.scale = pred, D, target, scale
        self.F, self.P = D.shape[:2]
        self.n = 4 if scale else 3
        self.n_params = self.P * self.n
        self.sq = np.einsum("ij,ij->i", pred.support, pred.support)
        self.w_fit = 1.0 / np.sqrt(self.F)
        # the regularisers are linear in the parameters: constant sparse rows
        E, c, n = len(edges), np.arange(self.n), self.n
        rows = (np.arange(E)[:, None] * n + c).ravel()
        cols = np.r_[(edges[:, :1] * n + c).ravel(), (edges[:, 1:] * n + c).ravel()]
        Gs = sparse.csr_matrix((np.r_[np.ones(E * n), -np.ones(E * n)], (np.r_[rows, rows], cols)),
                               shape=(E * n, self.n_params))
        self.G = sparse.vstack([np.sqrt(smoothness) * Gs, np.sqrt(identity) * sparse.identity(self.n_params)]).tocsr()

    def maps(self, x):
        """(parameters (P, n), rotations (P, 3, 3), scales (P,)) of ``x``."""
        p = x.reshape(self.P, self.n)
        return p, se3.so3_exp(p[:, :3]), np.exp(p[:, 3]) if self.scale else np.ones(self.P)

    def fit(self, x):
        """(z (F, 3P), K (F, S), mapped displacements m (F, P, 3), fit residuals (F, 3B) mm)."""
        pred = self.pred
        _, Rv, sv = self.maps(x)
        m = sv[None, :, None] * np.einsum("pij,fpj->fpi", Rv, self.D)
        z = (m.reshape(self.F, -1) - pred.x_mean) / pred.x_scale
        K = _kernel(z, pred.support, self.sq, pred.gamma)
        y = ((K @ pred.dual.T) + pred.intercept) * pred.y_scale + pred.y_mean
        return z, K, m, y - self.target

    def bone_error(self, x) -> float:
        """Mean calibration bone-point distance (mm) with the maps of ``x``."""
        r = self.fit(x)[3]
        return _point_error(r + self.target, self.target)

    def residuals(self, x):
        return np.concatenate([self.w_fit * self.fit(x)[3].ravel(), self.G @ x])

    def jacobian(self, x):
        from scipy import sparse

        pred, F, P = self.pred, self.F, self.P
        p, Rv, sv = self.maps(x)
        z, K, m, _ = self.fit(x)
        # dy_k/dz (F, 3B, 3P) = y_scale_k (-2 gamma) Σ_i dual_ki K_fi (z_f - support_i)
        W = pred.dual[None] * K[:, None, :]
        dz = -2.0 * pred.gamma * (W.sum(axis=2)[:, :, None] * z[:, None, :] - W @ pred.support)
        dm = (dz * pred.y_scale[None, :, None] / pred.x_scale[None, None, :]).reshape(F, -1, P, 3)
        # dm_fv/dparams_v (F, P, 3, n): the rotation through the left Jacobian, the log scale gives m
        rot = sv[None, :, None, None] * _rotation_jacobian(np.broadcast_to(p[:, :3], (F, P, 3)),
                                                            np.einsum("pij,fpj->fpi", Rv, self.D))
        dp = np.concatenate([rot, m[..., None]], axis=3) if self.scale else rot
        J = np.einsum("fkpi,fpic->fkpc", dm, dp).reshape(-1, self.n_params)
        return sparse.vstack([sparse.csr_matrix(self.w_fit * J), self.G]).tocsr()


def calibration_frames(data: MarkerlessData, count: int = 5) -> np.ndarray:
    """``(count,)`` indices of the frames of ``data`` (with poses and ``ok``) to calibrate a
    retargeting with: the paper's handful of calibration poses, the extremes of the jaw's range --
    the frame nearest rest, then the widest opening, the farthest to the left and to the right,
    the most protruded (facesim's frame: x left, y up, z forward; the bone points' mean
    displacement), then, beyond five, farthest-point samples of the bone displacements."""
    if data.poses is None:
        raise FacesimError("calibration frames: the data has no jaw poses")
    ok = np.flatnonzero(data.ok)
    if len(ok) < count:
        raise FacesimError(f"calibration frames: {count} wanted, the data has {len(ok)} converged frames")
    d = data.bone_points()[ok] - data.bone_rest[None]        # (n, B, 3)
    mean = d.mean(axis=1)
    picks = [int(np.argmin(np.linalg.norm(d, axis=2).sum(axis=1))), int(np.argmin(mean[:, 1])),
             int(np.argmax(mean[:, 0])), int(np.argmin(mean[:, 0])), int(np.argmax(mean[:, 2]))]
    chosen: list[int] = []
    for i in picks:
        if i not in chosen and len(chosen) < count:
            chosen.append(i)
    flat = d.reshape(len(d), -1)
    while len(chosen) < count:
        dist = np.min(np.linalg.norm(flat[:, None] - flat[chosen][None], axis=2), axis=1)
        chosen.append(int(np.argmax(dist)))
    return ok[np.array(chosen)]


def retarget(pred: Predictor, calibration: MarkerlessData, *, smoothness: float = 1.0, identity: float = 0.1,
             neighbours: int = 6, scale: bool = True) -> Predictor:
    """The predictor ``pred`` (source subject) retargeted to a new subject from a few frames of it
    with known jaw poses (``calibration``; the paper uses about five): a new :class:`Predictor`
    that reads the new subject's features directly.

    Formulation (the paper's 6.1, eqs. 2-3). The new subject's displacements ``d_fv`` (frame f,
    feature v) are first turned into the source frame by ``R_g`` (:func:`alignment`, as every
    prediction does); then each feature gets its own map ``M_v = exp(s_v) exp(hat(w_v))``, a
    rotation (``w_v``, rad) and a uniform scale (``s_v``, log), solved by least squares from

        E = Σ_f |Φ(M ⊙ R_g d_f) - R_g Δb_f|² / F                         (fit, mm²)
          + smoothness Σ_(u,v) |w_u - w_v|² + (s_u - s_v)²               (eq. 2, mm²)
          + identity Σ_v |w_v|² + s_v²                                   (eq. 3, mm²)

    with Φ the source regression (its RBF gradient analytic: ``dΦ_k/dz = -2 gamma Σ_i dual_ki
    K_i (z - support_i)``), Δb_f the calibration frame's true bone displacement, and (u, v) the
    pairs of ``neighbours``-nearest features by rest position. The map of a displacement is
    linear (no translation: a translation would make a feature at rest non-zero and so move the
    predicted jaw of the neutral face) and is a rotation -- the skin's local frame differs between
    faces -- times a scale -- thicker or softer tissue moves the skin less for the same jaw
    motion (the paper's higher-BMI subject). A full 3x3 per feature would add shears that five
    frames cannot determine. ``scale=False`` keeps rotations only. Near the identity the
    parameter differences of eqs. 2-3 equal the Frobenius differences of the maps (up to a
    factor), and stay quadratic, so the regularisers' Jacobian is constant.

    Frames of ``calibration`` with ``ok`` False are left out. The result's ``meta["retarget"]``
    records the weights, the number of calibration frames and the calibration bone error (mm)
    before and after.
    """
    from scipy.optimize import least_squares

    if calibration.poses is None:
        raise FacesimError("calibration: no jaw poses (field 'poses'): retargeting needs them")
    calibration = features_for(pred, calibration)
    _check_layout(pred, calibration.n_features, len(calibration.bone_rest))
    cal = calibration.subset(np.flatnonzero(calibration.ok))
    F, P = cal.n_frames, cal.n_features
    if F < 1:
        raise FacesimError("calibration: no frame with ok True")
    if not np.allclose(pred.feature_maps, np.eye(3)):
        raise FacesimError("retarget: the predictor is already retargeted; retarget its source predictor")
    R = alignment(cal.skin_rest, cal.bone_rest, pred.source_skin_rest, pred.source_bone_rest)
    problem = _Calibration(pred, cal.skin_displacement @ R.T,
                           ((cal.bone_points() - cal.bone_rest[None]) @ R.T).reshape(F, -1),
                           _neighbour_edges(cal.skin_rest, neighbours), smoothness, identity, scale)
    x0 = np.zeros(problem.n_params)
    sol = least_squares(problem.residuals, x0, jac=problem.jacobian, method="trf", tr_solver="lsmr", max_nfev=200)
    p, Rv, sv = problem.maps(sol.x)
    before, after = problem.bone_error(x0), problem.bone_error(sol.x)
    M = sv[:, None, None] * Rv
    meta = dict(pred.meta)
    meta["retarget"] = {"subject": str(calibration.meta.get("subject", "new subject")), "frames": int(F),
                        "excluded": int((~calibration.ok).sum()), "smoothness": float(smoothness),
                        "identity": float(identity), "neighbours": int(neighbours), "scale": bool(scale),
                        "calibration_mm_before": before, "calibration_mm_after": after,
                        "evaluations": int(sol.nfev), "mean_scale": float(sv.mean()),
                        "mean_rotation_deg": float(np.degrees(np.linalg.norm(p[:, :3], axis=1)).mean())}
    # the maps act after R_g: M_v R_g d is what the regression reads; store M_v and read the new
    # subject's rest points, so predictions find the same R_g again
    return replace(pred, skin_rest=cal.skin_rest.copy(), bone_rest=cal.bone_rest.copy(), feature_maps=M, meta=meta)


# ---------------------------------------------------------------------------------------------
# files

_ARRAYS = ("support", "dual", "intercept", "x_mean", "x_scale", "y_mean", "y_scale", "source_skin_rest",
           "source_bone_rest", "skin_rest", "bone_rest", "feature_maps")


def save_predictor(pred: Predictor, path, single: bool = False) -> Path:
    """Write ``pred`` to ``path`` (one compressed ``.npz`` of arrays and JSON meta), atomically.
    ``single``: the support vectors and dual coefficients -- nearly all of the file -- in float32
    (half the size; predictions change by ~1e-6 of the jaw's motion, they are read back as
    float64); used for the shipped predictor."""
    arrays = {k: getattr(pred, k) for k in _ARRAYS}
    if single:
        arrays["support"] = arrays["support"].astype(np.float32)
        arrays["dual"] = arrays["dual"].astype(np.float32)
    return write_npz(path, PREDICTOR_FORMAT, arrays, {"gamma": float(pred.gamma), **pred.meta})


def load_predictor(path) -> Predictor:
    """Read a predictor written by :func:`save_predictor`; a one-line :class:`ModelFileError`
    naming the file and the field for anything else (a dataset, a rig, a damaged file)."""
    path = Path(path)
    with read_npz(path, PREDICTOR_FORMAT) as ar:
        a = {}
        for key in _ARRAYS:
            v = ar.array(key)
            if v.dtype.kind not in "fiu":
                raise ModelFileError(path, f"field {key!r}: expected real numbers, got dtype {v.dtype}")
            if not np.isfinite(v).all():
                raise ModelFileError(path, f"field {key!r}: expected finite values, got NaN or inf")
            a[key] = v.astype(np.float64)
        gamma = ar.field("gamma")
        meta = {k: v for k, v in ar.meta.items() if k not in ("format", "version", "gamma")}
    S, D = a["support"].shape if a["support"].ndim == 2 else (-1, -1)
    P, B = len(a["skin_rest"]), len(a["bone_rest"])
    shapes = {"support": (S, 3 * P), "dual": (3 * B, S), "intercept": (3 * B,), "x_mean": (3 * P,),
              "x_scale": (3 * P,), "y_mean": (3 * B,), "y_scale": (3 * B,), "source_skin_rest": (P, 3),
              "source_bone_rest": (B, 3), "skin_rest": (P, 3), "bone_rest": (B, 3), "feature_maps": (P, 3, 3)}
    for key, shape in shapes.items():
        if a[key].shape != shape:
            raise ModelFileError(path, f"field {key!r}: expected shape {shape} for {P} skin and {B} bone points, "
                                       f"got {a[key].shape}")
    if not isinstance(gamma, (int, float)) or not gamma > 0:
        raise ModelFileError(path, f"field 'meta.gamma': expected a positive number, got {gamma!r}")
    if not (a["x_scale"] > 0).all() or not (a["y_scale"] > 0).all():
        raise ModelFileError(path, "field 'x_scale' or 'y_scale': expected positive scales")
    return Predictor(a["support"], a["dual"], a["intercept"], float(gamma), a["x_mean"], a["x_scale"], a["y_mean"],
                     a["y_scale"], a["source_skin_rest"], a["source_bone_rest"], a["skin_rest"], a["bone_rest"],
                     a["feature_maps"], meta)


__all__ = [
    "DEFAULT_GRID",
    "PREDICTOR_FORMAT",
    "Predictor",
    "alignment",
    "baseline_poses", "calibration_frames",
    "evaluate",
    "feature_kind", "features_for",
    "load_predictor",
    "pose_error",
    "predict_bone_points",
    "predict_poses",
    "retarget",
    "rigid_poses",
    "save_predictor",
    "train",
]
