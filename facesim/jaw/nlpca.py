"""Jaw poses in se(3) and the hierarchical nonlinear-PCA rig (Yang et al. 2018).

Yang et al. describe captured mandible poses by their twists in se(3) (the log map of SE(3))
and reduce them to three ordered nonlinear parameters with Scholz's hierarchical nonlinear PCA
(an autoencoder whose latent components are ordered by a hierarchical error), linear PCA being
the baseline it beats. The parameters read as opening,
lateral and protrusive motion; the valid ranges of the second and third depend on the first
(the envelope narrows as the mouth opens) and come from an alpha shape of the training
parameters. Poses map to parameters by a local search (inverse kinematics), and animation
keys are interpolated in parameter space.

Pieces, all in the jaw frame (:mod:`facesim.jaw.frame`):

- ``Se3Chart`` -- coordinates ``y = R ξ`` of a pose T, ξ = log(F T F⁻¹) the twist in the jaw frame
  and R (upper triangular, Rᵀ R = G) the square root of the metric the mandible points induce
  on twists: a small twist δξ moves a point x by δω × x + δv, so the weighted mean squared
  displacement is δξᵀ G δξ with G = Σ_j w_j A_jᵀ A_j / Σ_j w_j, A_j = [−hat(x_j) | I]. Distances in
  y are (to first order) the rigs' weighted vertex error in mm, whatever mix of rotation and
  translation moves the jaw; PCA and NLPCA both work in y.
- ``LinearPca`` / ``fit_pca`` -- the linear baseline: the mean and the leading principal axes of y.
- ``Autoencoder`` / ``fit_hnlpca`` -- Scholz's network 6-h-k-h-6 (tanh hidden layers, linear
  bottleneck and output) with a linear bypass around each half::

      z = A y' + W2 tanh(W1 y' + b1) + b2           (encoder; y' the centred, scaled y)
      y' = B z + W4 tanh(W3 z + b3) + b4            (decoder)

  trained by L-BFGS (``scipy.optimize.minimize``) on the hierarchical error
  E_H = Σ_i c_i E_{1..i} + decay Σ |W|², where E_{1..i} is the mean squared reconstruction error
  with the latent components after i set to zero (Scholz, Fraunholz & Selbig 2008). The
  bypass starts at linear PCA (A, B the principal axes, W2 = W4 = 0): training starts from
  the linear solution and lowers the hierarchical error from there. Plain Scholz uses c_i = 1; here c_i = 1 / E_{1..i} of that linear start:
  with equal weights the one-component error, an order of magnitude larger than the others,
  dominates and the optimiser trades the three-component fit (the one the rig uses) for it.
- ``NlpcaRig`` / ``fit_nlpca`` -- the 3-parameter rig: parameters d = gain (z − z_rest), zero at the
  model pose closest to rest and signed so that each grows with the motion it stands for;
  ``components`` splits the decoded twist into Phi1(d1) + Phi2(d1, d2) + Phi3(d1, d2, d3), the
  increments of the hierarchy. ``fit_hnlpca(components=5)`` gives the 5-D model first (its
  fourth and fifth components explain little, ``reconstruction_errors``); the rig then trains
  its three components directly, which fits better than truncating the 5-D network (held-out
  mean 0.09 against 0.21 mm on the default subject).

Valid ranges (``_alpha_ranges``): for each of the planes (d1, d2) and (d1, d3) the alpha shape
of the training parameters -- the Delaunay triangles (``scipy.spatial.Delaunay``) whose
circumradius is at most alpha, alpha the 99th percentile over the points of the smallest
circumradius among each point's triangles, so that all but the outermost 1 % of the points lie
in the shape. At each d1 of a grid the valid interval is the hull of where the line d1 = const
crosses the kept triangles. The interval ends are dilated over five neighbouring samples,
smoothed by a least-squares cubic spline and shifted outward until they contain the dilated
ends -- conservative: every training parameter in the alpha shape is valid, and the rest pose --
and read back through a natural cubic spline (C²), so the range penalty of
``facesim.kinematics.rig_jaw`` has continuous derivatives.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator, make_lsq_spline
from scipy.linalg import solve_triangular
from scipy.optimize import minimize
from scipy.spatial import Delaunay, QhullError

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw._lm import levenberg_marquardt
from facesim.jaw.frame import JawFrame
from facesim.jaw.points import farthest_points, front_weights, mandible_points, second_moment_factor
from facesim.jaw.rigfile import load_rig, save_rig

MOTIONS = ("opening", "lateral", "protrusion")   # what the parameters can stand for
_WEIGHT_NAMES = ("A", "W1", "b1", "W2", "b2", "B", "W3", "b3", "W4", "b4")
_GRID = 48                                       # d1 samples of the valid-range table


def _poses(poses, what: str = "poses", minimum: int = 1) -> np.ndarray:
    return se3.check_poses(poses, what, minimum)


# --- the se(3) chart ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Se3Chart:
    """se(3) coordinates of mandible poses, metric-whitened (module docstring).

    frame : JawFrame; metric : (6, 6) upper triangular R with Rᵀ R = G (rows of ``y`` in mm).
    """

    frame: JawFrame
    metric: np.ndarray

    @classmethod
    def of(cls, frame: JawFrame, points, weights=None) -> Se3Chart:
        """The chart of the mandible ``points (P, 3)`` mm (skull frame, at rest), ``weights (P,)``."""
        X = frame.to_local(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        w = np.ones(len(X)) if weights is None else np.asarray(weights, dtype=np.float64)
        if len(X) < 3 or w.shape != (len(X),) or not (w >= 0).all() or not w.sum() > 0:
            raise FacesimError(f"points/weights: expected >= 3 points (P, 3) and P non-negative weights with a "
                               f"positive sum, got {X.shape} and {w.shape}")
        A = np.zeros((len(X), 3, 6))
        A[:, :, :3] = -se3.hat(X)
        A[:, :, 3:] = np.eye(3)
        G = np.einsum("n,nij,nik->jk", w / w.sum(), A, A)
        try:
            C = np.linalg.cholesky(G)
        except np.linalg.LinAlgError:
            raise FacesimError("points: collinear mandible points do not fix a rigid pose") from None
        return cls(frame, C.T)

    def coordinates(self, poses) -> np.ndarray:
        """``(N, 6)`` mm: y = R log(F T F⁻¹) of ``poses (N, 4, 4)`` (skull frame)."""
        return se3.log(self.frame.pose_to_local(poses)) @ self.metric.T

    def twist(self, y) -> np.ndarray:
        """Jaw-frame twists ``(..., 6)`` of coordinates ``y (..., 6)``."""
        y = np.asarray(y, dtype=np.float64)
        flat = solve_triangular(self.metric, y.reshape(-1, 6).T, lower=False).T
        return flat.reshape(y.shape)

    def poses(self, y) -> np.ndarray:
        """Skull-frame poses ``(..., 4, 4)`` of coordinates ``y (..., 6)``."""
        return self.frame.pose_to_world(se3.exp(self.twist(y)))


# --- linear PCA --------------------------------------------------------------------------------

@dataclass(frozen=True)
class LinearPca:
    """Linear PCA of chart coordinates: ``y = mean + c @ axes`` with ``c (..., k)`` (mm).

    chart : Se3Chart; mean : (6,) mm; axes : (k, 6) orthonormal rows, by decreasing variance;
    variance : (6,) mm², the variance along every principal axis (all six).
    """

    chart: Se3Chart
    mean: np.ndarray
    axes: np.ndarray
    variance: np.ndarray

    @property
    def n_params(self) -> int:
        return len(self.axes)

    def parameters(self, poses) -> np.ndarray:
        """``(N, k)``: the orthogonal projection of ``poses (N, 4, 4)`` onto the principal axes."""
        return (self.chart.coordinates(_poses(poses)) - self.mean) @ self.axes.T

    def transform(self, c) -> np.ndarray:
        """Poses ``(..., 4, 4)`` of parameters ``c (..., k)``."""
        return self.chart.poses(self.mean + np.asarray(c, dtype=np.float64) @ self.axes)

    def reproduce(self, poses, points=None, weights=None) -> np.ndarray:
        """The k-component reconstruction ``(N, 4, 4)`` of ``poses`` (``points``/``weights`` unused)."""
        return self.transform(self.parameters(poses))


def fit_pca(poses, chart: Se3Chart, components: int = 3) -> LinearPca:
    """Linear PCA of ``poses (N, 4, 4)`` in ``chart``, keeping ``components`` (1..6) axes."""
    Y = chart.coordinates(_poses(poses, minimum=2))
    if not 1 <= int(components) <= 6:
        raise FacesimError(f"pca: expected 1 to 6 components, got {components}")
    mean = Y.mean(axis=0)
    _, S, Vt = np.linalg.svd(Y - mean, full_matrices=False)
    return LinearPca(chart, mean, Vt[:int(components)], S**2 / len(Y))


# --- Scholz's autoencoder ----------------------------------------------------------------------

@dataclass(frozen=True)
class Autoencoder:
    """The network of the module docstring on normalised coordinates y' = (y − centre) / scale.

    weights : dict of the arrays ``A (k, 6), W1 (h, 6), b1 (h,), W2 (k, h), b2 (k,), B (6, k),
    W3 (h, k), b3 (h,), W4 (6, h), b4 (6,)``; centre : (6,) mm; scale : mm.
    """

    weights: dict
    centre: np.ndarray
    scale: float

    @property
    def components(self) -> int:
        return self.weights["A"].shape[0]

    @property
    def hidden(self) -> int:
        return self.weights["W1"].shape[0]

    def encode(self, y) -> np.ndarray:
        """Latent ``z (N, k)`` of chart coordinates ``y (N, 6)`` mm."""
        u = (np.asarray(y, dtype=np.float64).reshape(-1, 6) - self.centre) / self.scale
        return _encoded(self.weights, u)[1]

    def decode(self, z, components: int | None = None) -> np.ndarray:
        """Chart coordinates ``(..., 6)`` mm of latent ``z (..., k)``, keeping only the first
        ``components`` (the others set to zero, as in the hierarchical error)."""
        z = np.asarray(z, dtype=np.float64)
        if z.shape[-1:] != (self.components,):
            raise FacesimError(f"autoencoder: expected (..., {self.components}) latent values, got {z.shape}")
        u = _decoded(self.weights, z, self.components if components is None else int(components))[2]
        return self.centre + self.scale * u


def _encoded(w: dict, U):
    """Encoder of normalised coordinates ``U (N, 6)``: hidden layer (N, h) and latent (N, k)."""
    H1 = np.tanh(U @ w["W1"].T + w["b1"])
    return H1, U @ w["A"].T + H1 @ w["W2"].T + w["b2"]


def _decoded(w: dict, Z, i: int):
    """Decoder of the first ``i`` components of ``Z (..., k)``: the truncated latent, the hidden
    layer and the normalised output (..., 6)."""
    Zi = np.array(Z, dtype=np.float64)
    Zi[..., i:] = 0.0
    H3 = np.tanh(Zi @ w["W3"].T + w["b3"])
    return Zi, H3, Zi @ w["B"].T + H3 @ w["W4"].T + w["b4"]


def _initial_weights(U, components: int, hidden: int, rng) -> dict:
    """Weights whose bypass is linear PCA of ``U (N, 6)`` (unit-variance latent) and whose
    nonlinear branches are silent (W2 = W4 = 0) with random hidden layers."""
    _, S, Vt = np.linalg.svd(U, full_matrices=False)
    S = np.maximum(S / np.sqrt(len(U)), 1e-9 * S[0] / np.sqrt(len(U)))
    k, h = components, hidden
    return {"A": Vt[:k] / S[:k, None], "W1": rng.normal(scale=1 / np.sqrt(6), size=(h, 6)),
            "b1": rng.normal(scale=0.5, size=h), "W2": np.zeros((k, h)), "b2": np.zeros(k),
            "B": Vt[:k].T * S[:k], "W3": rng.normal(scale=1 / np.sqrt(k), size=(h, k)),
            "b3": rng.normal(scale=0.5, size=h), "W4": np.zeros((6, h)), "b4": np.zeros(6)}


def _pack(w: dict) -> np.ndarray:
    return np.concatenate([w[n].ravel() for n in _WEIGHT_NAMES])


def _unpack(theta, like: dict) -> dict:
    out, i = {}, 0
    for n in _WEIGHT_NAMES:
        size = like[n].size
        out[n] = theta[i:i + size].reshape(like[n].shape)
        i += size
    return out


def _level_errors(w: dict, U) -> np.ndarray:
    """Mean squared errors E_{1..i}, i = 1..k, of the truncated reconstructions of ``U (N, 6)``."""
    Z = _encoded(w, U)[1]
    R = [_decoded(w, Z, i)[2] - U for i in range(1, Z.shape[1] + 1)]
    return np.array([np.einsum("ij,ij->", r, r) / len(U) for r in R])


def _hierarchical_loss(theta, like: dict, U, c, decay: float):
    """E_H = Σ_i c_i E_{1..i} + decay Σ |W|² and its gradient (backpropagation, one encoder pass
    and one decoder pass per level)."""
    w = _unpack(theta, like)
    g = {n: np.zeros_like(v) for n, v in w.items()}
    N = len(U)
    H1, Z = _encoded(w, U)
    dZ = np.zeros_like(Z)
    f = 0.0
    for i in range(1, Z.shape[1] + 1):
        Zi, H3, Y = _decoded(w, Z, i)
        R = Y - U
        f += c[i - 1] * np.einsum("ij,ij->", R, R) / N
        dY = (2.0 * c[i - 1] / N) * R
        g["B"] += dY.T @ Zi
        g["W4"] += dY.T @ H3
        g["b4"] += dY.sum(axis=0)
        dA3 = (dY @ w["W4"]) * (1.0 - H3 * H3)
        g["W3"] += dA3.T @ Zi
        g["b3"] += dA3.sum(axis=0)
        dz = dA3 @ w["W3"] + dY @ w["B"]
        dz[:, i:] = 0.0
        dZ += dz
    g["A"] += dZ.T @ U
    g["W2"] += dZ.T @ H1
    g["b2"] += dZ.sum(axis=0)
    dA1 = (dZ @ w["W2"]) * (1.0 - H1 * H1)
    g["W1"] += dA1.T @ U
    g["b1"] += dA1.sum(axis=0)
    for n in ("W1", "W2", "W3", "W4"):
        f += decay * np.einsum("ij,ij->", w[n], w[n])
        g[n] += 2.0 * decay * w[n]
    return f, _pack(g)


def fit_hnlpca(poses, chart: Se3Chart, components: int = 3, hidden: int = 12, iterations: int = 1000,
               decay: float = 1e-6, seed: int = 0, max_samples: int = 3000) -> Autoencoder:
    """Train the hierarchical autoencoder on ``poses (N, 4, 4)`` (skull frame) in ``chart``.

    components : latent size k (1..5); hidden : units per tanh layer; iterations : L-BFGS
    iterations; decay : weight decay on the W matrices (normalised units); seed : the random
    hidden layers; max_samples : a farthest-point subsample of the frames trains when N is larger.
    """
    Y = chart.coordinates(_poses(poses, minimum=10))
    if not 1 <= int(components) <= 5 or int(hidden) < 1 or int(iterations) < 1 or not decay >= 0:
        raise FacesimError("nlpca: expected 1 to 5 components, hidden >= 1, iterations >= 1 and decay >= 0")
    if len(Y) > max_samples:
        Y = Y[np.sort(farthest_points(Y, int(max_samples)))]
    centre = Y.mean(axis=0)
    scale = float(np.sqrt(((Y - centre) ** 2).sum(axis=1).mean()))
    if not scale > 1e-9:
        raise FacesimError("poses: the jaw does not move in the data")
    U = (Y - centre) / scale
    w0 = _initial_weights(U, int(components), int(hidden), np.random.default_rng(seed))
    # relative hierarchical weights (module docstring); floor for data of exactly i dimensions
    e0 = _level_errors(w0, U)
    c = 1.0 / np.maximum(e0, 1e-8 * max(e0[0], 1e-12))
    result = minimize(_hierarchical_loss, _pack(w0), args=(w0, U, c, float(decay)), jac=True, method="L-BFGS-B",
                      options={"maxiter": int(iterations), "maxfun": 2 * int(iterations)})
    weights = {n: np.array(v) for n, v in _unpack(result.x, w0).items()}
    return Autoencoder(weights, centre, scale)


def reconstruction_errors(net: Autoencoder, chart: Se3Chart, poses, points, weights=None) -> np.ndarray:
    """``(k, N)`` mm: weighted vertex error of every frame of ``poses`` reconstructed by the first
    1, 2, ..., k components of ``net`` (encoder, truncation, decoder)."""
    poses = _poses(poses)
    z = net.encode(chart.coordinates(poses))
    return np.stack([se3.vertex_errors(chart.poses(net.decode(z, i)), poses, points, weights)
                     for i in range(1, net.components + 1)])


# --- valid ranges ------------------------------------------------------------------------------

def _alpha_intervals(P, grid, quantile: float = 0.99):
    """Lower and upper ends ``(G,)`` of the section of the alpha shape of ``P (N, 2)`` by the lines
    x = ``grid (G,)`` (NaN where the line misses it); module docstring."""
    lo_, span = P.min(axis=0), np.maximum(np.ptp(P, axis=0), 1e-12)
    Q = (P - lo_) / span                                   # alpha in unit-box coordinates
    try:
        tri = Delaunay(Q)
    except QhullError:
        raise FacesimError("nlpca: the training parameters are degenerate (no area in a parameter plane)") from None
    V = Q[tri.simplices]                                  # (T, 3, 2)
    a = np.linalg.norm(V[:, 1] - V[:, 2], axis=1)
    b = np.linalg.norm(V[:, 0] - V[:, 2], axis=1)
    c = np.linalg.norm(V[:, 0] - V[:, 1], axis=1)
    e1, e2 = V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]
    area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    radius = a * b * c / np.maximum(2.0 * area2, 1e-300)
    smallest = np.full(len(Q), np.inf)
    np.minimum.at(smallest, tri.simplices.ravel(), np.repeat(radius, 3))
    alpha = np.quantile(smallest[np.isfinite(smallest)], quantile)
    V = V[radius <= alpha]
    x = (np.asarray(grid) - lo_[0]) / span[0]
    lo = np.full(len(x), np.inf)
    hi = np.full(len(x), -np.inf)
    for e0, e1 in ((0, 1), (1, 2), (2, 0)):
        xa, ya, xb, yb = V[:, e0, 0], V[:, e0, 1], V[:, e1, 0], V[:, e1, 1]
        dx = np.where(xb == xa, 1.0, xb - xa)
        t = (x[:, None] - xa) / dx                        # (G, T)
        hit = (t >= 0) & (t <= 1) & (xb != xa)
        y = ya + t * (yb - ya)
        lo = np.minimum(lo, np.where(hit, y, np.inf).min(axis=1))
        hi = np.maximum(hi, np.where(hit, y, -np.inf).max(axis=1))
    missed = ~np.isfinite(lo)
    lo, hi = lo * span[1] + lo_[1], hi * span[1] + lo_[1]
    lo[missed] = hi[missed] = np.nan
    return lo, hi


def _smooth(grid, values, side: int) -> np.ndarray:
    """``values (G,)`` (NaN = missing) dilated over five neighbouring samples toward ``side`` (+1:
    upper end, max; −1: lower end, min), smoothed by a least-squares cubic spline and shifted
    outward until it contains the dilated values: ``(G,)`` at ``grid``."""
    ok = np.isfinite(values)
    x, v = grid[ok], values[ok]
    if len(x) < 8:
        return np.interp(grid, x, v) if len(x) else np.zeros_like(grid)
    pad = np.pad(side * v, 2, mode="edge")
    v = side * np.max(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    inner = np.linspace(x[0], x[-1], 8)[1:-1]
    fitted = make_lsq_spline(x, v, np.r_[[x[0]] * 4, inner, [x[-1]] * 4], k=3)
    shift = max(0.0, float(np.max(side * (v - fitted(x)))))
    return fitted(np.clip(grid, x[0], x[-1])) + side * shift


def _alpha_ranges(D):
    """The valid-range table of parameters ``D (N, 3)``: (d1 grid (G,), lower (G, 2), upper (G, 2))
    for d2 and d3 as functions of d1."""
    d1 = D[:, 0]
    pad = 1e-3 * np.ptp(d1)
    grid = np.linspace(d1.min() + pad, d1.max() - pad, _GRID)
    lower, upper = np.empty((_GRID, 2)), np.empty((_GRID, 2))
    for j in (1, 2):
        lo, hi = _alpha_intervals(D[:, [0, j]], grid)
        lower[:, j - 1], upper[:, j - 1] = _smooth(grid, lo, -1), _smooth(grid, hi, 1)
    return grid, lower, upper


# --- the rig -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class NlpcaRig:
    """A fitted 3-parameter NLPCA jaw rig.

    chart : Se3Chart (its frame is the rig's jaw frame); net : Autoencoder with 3 components;
    z_rest : (3,) latent of the rest pose; gain : (3,) signed scale, d = gain (z − z_rest);
    grid : (G,) d1 samples; lower, upper : (G, 2) valid ranges of (d2, d3) at those d1;
    names : the motion each parameter stands for (``MOTIONS``, from the direction the reference
    point moves along each parameter, ``_orientation``).

    ``d (..., 3)`` are dimensionless (one unit ~ one standard deviation of the training
    parameters); ``transform(d)`` gives mandible-relative-to-skull poses ``(..., 4, 4)`` (skull
    frame, mm).
    """

    chart: Se3Chart
    net: Autoencoder
    z_rest: np.ndarray
    gain: np.ndarray
    grid: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    names: tuple = MOTIONS

    def __post_init__(self):
        se3.check_rigid(se3.from_rt(self.frame.axes, self.frame.origin),
                        "nlpca rig: jaw frame (fields 'frame_origin', 'frame_axes')")
        arrays = {"metric": self.chart.metric, "centre": self.net.centre, "z_rest": self.z_rest, "gain": self.gain,
                  "grid": self.grid, "lower": self.lower, "upper": self.upper,
                  **{f"net_{n}": w for n, w in self.net.weights.items()}}
        for name, a in arrays.items():
            a = np.asarray(a)
            if a.dtype.kind not in "fiu" or not np.isfinite(a).all():
                raise FacesimError(f"nlpca rig: field {name!r}: expected finite numbers, "
                                   f"got {'NaN or inf' if a.dtype.kind in 'fiu' else f'dtype {a.dtype}'}")
        if not (np.abs(np.diagonal(self.chart.metric)) > 0).all():
            raise FacesimError("nlpca rig: field 'metric': expected an invertible upper triangular metric factor "
                               "(non-zero diagonal)")
        if not (np.isfinite(self.net.scale) and self.net.scale > 0):
            raise FacesimError(f"nlpca rig: field 'meta.scale': expected a finite scale > 0 mm, got {self.net.scale!r}")
        if self.net.components != 3:
            raise FacesimError(f"nlpca rig: expected a 3-component autoencoder, got {self.net.components}")
        G = len(self.grid)
        if G < 4 or self.lower.shape != (G, 2) or self.upper.shape != (G, 2) or np.any(np.diff(self.grid) <= 0):
            raise FacesimError("nlpca rig: expected an increasing d1 grid (G >= 4) and ranges (G, 2)")
        if np.any(self.gain == 0) or not np.isfinite(self.gain).all():
            raise FacesimError("nlpca rig: expected finite non-zero gains")
        object.__setattr__(self, "_lo", CubicSpline(self.grid, self.lower, bc_type="natural"))
        object.__setattr__(self, "_hi", CubicSpline(self.grid, self.upper, bc_type="natural"))

    n_params = 3

    @property
    def frame(self) -> JawFrame:
        return self.chart.frame

    @property
    def reference_point(self) -> np.ndarray:
        return self.frame.origin

    def _d(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=np.float64)
        if d.shape[-1:] != (3,) or not np.isfinite(d).all():
            raise FacesimError(f"nlpca rig: expected (..., 3) finite parameters (d1, d2, d3), got shape {d.shape}")
        return d

    def coordinates(self, d) -> np.ndarray:
        """Chart coordinates ``(..., 6)`` mm of parameters ``d (..., 3)``."""
        return self.net.decode(self.z_rest + self._d(d) / self.gain)

    def transform(self, d) -> np.ndarray:
        """Poses ``(..., 4, 4)`` (skull frame, mm) of parameters ``d (..., 3)``."""
        return self.chart.poses(self.coordinates(d))

    def components(self, d) -> np.ndarray:
        """``(3, ..., 6)`` jaw-frame twists Phi1(d1), Phi2(d1, d2), Phi3(d1, d2, d3): the increments of
        the hierarchy, whose sum is the twist of ``transform(d)``."""
        z = self.z_rest + self._d(d) / self.gain
        partial = [self.net.decode(np.where(np.arange(3) < i, z, 0.0)) for i in (1, 2, 3)]
        return np.stack([self.chart.twist(partial[0]), self.chart.twist(partial[1] - partial[0]),
                         self.chart.twist(partial[2] - partial[1])])

    # --- ranges ---------------------------------------------------------------------------------

    @property
    def bounds(self) -> np.ndarray:
        """``(3, 2)`` [lower, upper]: the d1 range of the data and the widest d2, d3 ranges."""
        return np.array([[self.grid[0], self.grid[-1]],
                         [self.lower[:, 0].min(), self.upper[:, 0].max()],
                         [self.lower[:, 1].min(), self.upper[:, 1].max()]])

    def ranges(self, d1, derivative: int = 0):
        """Valid ranges of (d2, d3) at ``d1 (...)``: ``lower, upper (..., 2)`` (d1 clamped to its
        range), or their ``derivative``-th derivatives in d1 (zero outside the d1 range)."""
        d1 = np.asarray(d1, dtype=np.float64)
        c = np.clip(d1, self.grid[0], self.grid[-1])
        lo, hi = self._lo(c, derivative), self._hi(c, derivative)
        if derivative:
            outside = ((d1 < self.grid[0]) | (d1 > self.grid[-1]))[..., None]
            lo, hi = np.where(outside, 0.0, lo), np.where(outside, 0.0, hi)
        return lo, hi

    def clamp(self, d) -> np.ndarray:
        """``d (..., 3)`` moved into the valid ranges: d1 into its range, then d2, d3 into theirs."""
        d = np.array(self._d(d))
        d[..., 0] = np.clip(d[..., 0], self.grid[0], self.grid[-1])
        lo, hi = self.ranges(d[..., 0])
        d[..., 1:] = np.clip(d[..., 1:], lo, hi)
        return d

    def range_excess(self, d):
        """How far ``d (3,)`` is outside the valid ranges: ``e (3,)`` (zero inside), its Jacobian
        ``(3, 3)`` and the Hessians ``(3, 3, 3)`` of its entries (for the jaw-model penalty)."""
        d = self._d(d).reshape(3)
        e, J, H = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3, 3))
        e[0] = max(d[0] - self.grid[-1], 0.0) + min(d[0] - self.grid[0], 0.0)
        J[0, 0] = float(e[0] != 0.0)
        (lo, hi), (dlo, dhi), (ddlo, ddhi) = (self.ranges(d[0], k) for k in range(3))
        for j in (1, 2):
            for bound, dbound, ddbound, side in ((hi, dhi, ddhi, 1), (lo, dlo, ddlo, -1)):
                gap = d[j] - bound[j - 1]
                if side * gap > 0:
                    e[j] = gap
                    J[j, j], J[j, 0] = 1.0, -dbound[j - 1]
                    H[j, 0, 0] = -ddbound[j - 1]
        return e, J, H

    # --- inverse kinematics and keyframes -------------------------------------------------------

    def parameters(self, poses, points=None, weights=None, d0=None, iterations: int = 40,
                   clamp: bool = False) -> np.ndarray:
        """Inverse kinematics: parameters ``(N, 3)`` of the rig poses closest to ``poses (N, 4, 4)``
        (skull frame). The closeness is the weighted mean squared distance of ``points (P, 3)`` mm
        (skull frame, at rest) with ``weights (P,)``, or without points the chart distance (its
        first-order equivalent). A local search: batched Levenberg-Marquardt with central-difference
        Jacobians from ``d0 (N, 3)`` (default the encoder's guess); ``clamp`` moves the result into
        the valid ranges."""
        poses = _poses(poses)
        if points is None:
            target = self.chart.coordinates(poses)

            def residual(d, rows):
                return self.coordinates(d) - target[rows]
        else:
            local = self.frame.pose_to_local(poses)
            L = second_moment_factor(self.frame.to_local(points), weights)

            def residual(d, rows):
                T = se3.exp(self.chart.twist(self.coordinates(d)))
                return ((T - local[rows])[:, :3] @ L).reshape(len(d), 12)

        d = self.gain * (self.net.encode(self.chart.coordinates(poses)) - self.z_rest) if d0 is None else \
            np.array(self._d(d0), dtype=np.float64).reshape(-1, 3)
        d = _levenberg_marquardt(residual, d, iterations)
        return self.clamp(d) if clamp else d

    def reproduce(self, poses, points=None, weights=None) -> np.ndarray:
        """The rig's best approximation ``(N, 4, 4)`` of ``poses`` (``parameters`` then ``transform``)."""
        return self.transform(self.parameters(poses, points, weights))

    def interpolate(self, key_times, key_params, times) -> np.ndarray:
        """Keyframe interpolation in parameter space: ``(M, 3)`` parameters at ``times (M,)`` from
        keys ``key_params (K, 3)`` at increasing ``key_times (K,)`` -- shape-preserving cubic
        (PCHIP, no overshoot between keys) per parameter, then clamped into the valid ranges."""
        t = np.asarray(key_times, dtype=np.float64)
        keys = self._d(key_params).reshape(-1, 3)
        if t.shape != (len(keys),) or len(t) < 2 or np.any(np.diff(t) <= 0):
            raise FacesimError(f"keyframes: expected K >= 2 increasing key times and (K, 3) parameters, got "
                               f"{t.shape} and {keys.shape}")
        return self.clamp(PchipInterpolator(t, keys, axis=0, extrapolate=False)(
            np.clip(np.asarray(times, dtype=np.float64), t[0], t[-1])))

    # --- files ----------------------------------------------------------------------------------

    def save(self, path):
        """Write the rig to a versioned ``.npz`` (:mod:`facesim.jaw.rigfile`)."""
        arrays = {"frame_origin": self.frame.origin, "frame_axes": self.frame.axes, "metric": self.chart.metric,
                  "centre": self.net.centre, "z_rest": self.z_rest, "gain": self.gain, "grid": self.grid,
                  "lower": self.lower, "upper": self.upper}
        arrays.update({f"net_{n}": self.net.weights[n] for n in _WEIGHT_NAMES})
        return save_rig(path, "nlpca", arrays, {"scale": self.net.scale, "names": list(self.names)})

    @staticmethod
    def load(path) -> NlpcaRig:
        """Read a rig written by :meth:`save` (one-line errors naming the file and field)."""
        keys = ("frame_origin", "frame_axes", "metric", "centre", "z_rest", "gain", "grid", "lower", "upper")
        arrays, meta = load_rig(path, "nlpca", keys + tuple(f"net_{n}" for n in _WEIGHT_NAMES), ("scale", "names"))
        w = {n: arrays[f"net_{n}"] for n in _WEIGHT_NAMES}
        h = w["W1"].shape[0] if w["W1"].ndim == 2 else -1
        expected = {"A": (3, 6), "W1": (h, 6), "b1": (h,), "W2": (3, h), "b2": (3,), "B": (6, 3), "W3": (h, 3),
                    "b3": (h,), "W4": (6, h), "b4": (6,)}
        for n, shape in expected.items():
            if w[n].shape != shape:
                raise ModelFileError(path, f"field 'net_{n}': expected shape {shape}, got {w[n].shape}")
        for key, shape in (("metric", (6, 6)), ("centre", (6,)), ("z_rest", (3,)), ("gain", (3,))):
            if arrays[key].shape != shape:
                raise ModelFileError(path, f"field {key!r}: expected shape {shape}, got {arrays[key].shape}")
        try:
            chart = Se3Chart(JawFrame(arrays["frame_origin"], arrays["frame_axes"]), arrays["metric"].astype(np.float64))
            net = Autoencoder({n: a.astype(np.float64) for n, a in w.items()}, arrays["centre"].astype(np.float64),
                              float(meta["scale"]))
            return NlpcaRig(chart, net, arrays["z_rest"].astype(np.float64), arrays["gain"].astype(np.float64),
                            arrays["grid"].astype(np.float64), arrays["lower"].astype(np.float64),
                            arrays["upper"].astype(np.float64), tuple(str(n) for n in meta["names"]))
        except FacesimError as exc:
            raise ModelFileError(path, str(exc)) from None
        except (TypeError, ValueError) as exc:      # strings where numbers belong, a scale that is not a number
            raise ModelFileError(path, f"unreadable nlpca rig data ({type(exc).__name__}: {exc})") from None


def _levenberg_marquardt(residual, d, iterations: int, h: float = 1e-6):
    """Minimise |residual(d_n)|² for every row of ``d (N, 3)`` at once (``residual(x (n, 3), rows (n,))``
    gives the (n, m) residuals of the rows ``rows``); central-difference Jacobians with step ``h``.
    Rows drop out once their step falls below 1e-10 or their cost stops falling."""

    def evaluate(x, rows):
        J = np.stack([(residual(x + e, rows) - residual(x - e, rows)) / (2 * h) for e in h * np.eye(3)], axis=2)
        return residual(x, rows), J

    return levenberg_marquardt(evaluate, d, iterations, mu=1e-4, floor=1e-12)[0]


def _orientation(rig: NlpcaRig, D) -> tuple[np.ndarray, np.ndarray]:
    """Per parameter: the motion it stands for (index into ``MOTIONS``) and the sign making it grow
    with that motion. The reference point's velocity along each parameter is averaged over the
    training parameters ``D (N, 3)`` as direction cosines with the (down, left, forward) axes of
    the jaw frame; in the order of the hierarchy each parameter takes the motion of largest
    |cosine| not yet taken. (Correlations with the displacement would not do: opening and
    retrusion go together, and the third component mixes protrusion with some opening.)"""
    sample = D[np.sort(farthest_points(D, min(len(D), 200)))]
    axes = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])     # opening, lateral, protrusion
    h = 1e-4
    cos = np.zeros((3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        v = rig.frame.pose_to_local(rig.transform(sample + e))[:, :3, 3] - \
            rig.frame.pose_to_local(rig.transform(sample - e))[:, :3, 3]
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
        cos[k] = (v @ axes.T).mean(axis=0)
    meaning = []
    for k in range(3):
        free = [m for m in range(3) if m not in meaning]
        meaning.append(free[int(np.argmax(np.abs(cos[k, free])))])
    meaning = np.array(meaning)
    return meaning, np.where(cos[np.arange(3), meaning] < 0, -1.0, 1.0)


def _unranged(chart, net, z_rest, gain) -> NlpcaRig:
    """A rig with a placeholder range table, for the steps of :func:`fit_nlpca`."""
    return NlpcaRig(chart, net, z_rest, gain, np.arange(4.0), np.zeros((4, 2)), np.ones((4, 2)))


def fit_nlpca(poses, frame: JawFrame | None = None, reference_point=None, points=None, weights=None,
              hidden: int = 12, iterations: int = 1000, decay: float = 1e-6, seed: int = 0) -> NlpcaRig:
    """Fit a 3-parameter :class:`NlpcaRig` to ``poses (N, 4, 4)`` (mandible relative to skull, mm).

    frame : jaw frame (default ``JawFrame.from_poses(poses, reference_point)``); points, weights :
    mandible points ``(P, 3)`` mm (skull frame) and ``(P,)`` weights of the chart metric and of the
    inverse kinematics (default the shipped model's mandible, front-weighted); hidden, iterations,
    decay, seed : see :func:`fit_hnlpca`.
    """
    poses = _poses(poses, minimum=10)
    if frame is None:
        if reference_point is None:
            raise FacesimError("fit_nlpca: expected a jaw frame or the reference point (3,) mm")
        frame = JawFrame.from_poses(poses, reference_point)
    if points is None:
        points = mandible_points()
        weights = front_weights(points, frame)
    chart = Se3Chart.of(frame, points, weights)
    net = fit_hnlpca(poses, chart, 3, hidden, iterations, decay, seed)
    # latent of the rest pose (the model pose closest to the identity), then the training
    # parameters relative to it, scaled to unit deviation and oriented
    z_rest = _unranged(chart, net, np.zeros(3), np.ones(3)).parameters(np.eye(4)[None], points, weights)[0]
    z = _unranged(chart, net, z_rest, np.ones(3)).parameters(poses, points, weights)
    scale = 1.0 / np.maximum(z.std(axis=0), 1e-12)
    meaning, sign = _orientation(_unranged(chart, net, z_rest, scale), z * scale)
    gain = sign * scale
    D = z * gain
    grid, lower, upper = _alpha_ranges(D)
    return NlpcaRig(chart, net, z_rest, gain, grid, lower, upper, tuple(MOTIONS[m] for m in meaning))


@dataclass(frozen=True)
class NlpcaReport:
    """Reconstruction errors (mm, weighted mandible-vertex) of :func:`compare_reconstruction`:
    ``pca`` and ``nlpca`` per number of parameters 1..k, each ``(mean, max)`` on the frames given,
    and the training ``seconds`` of the autoencoder."""

    pca: dict
    nlpca: dict
    seconds: float


def compare_reconstruction(train, test, frame: JawFrame, points, weights=None, components: int = 3,
                           **options) -> NlpcaReport:
    """Linear PCA against hierarchical NLPCA with 1..``components`` parameters: both fitted on the
    ``train`` poses ``(N, 4, 4)``, measured on the ``test`` poses (encoder, truncation, decoder for
    NLPCA; orthogonal projection for PCA) with the weighted vertex error of ``points``."""
    chart = Se3Chart.of(frame, points, weights)
    start = time.perf_counter()
    net = fit_hnlpca(train, chart, components, **options)
    seconds = time.perf_counter() - start
    test = _poses(test)
    nl = reconstruction_errors(net, chart, test, points, weights)
    pca = {}
    for k in range(1, components + 1):
        e = se3.vertex_errors(fit_pca(train, chart, k).reproduce(test), test, points, weights)
        pca[k] = (float(e.mean()), float(e.max()))
    return NlpcaReport(pca, {k + 1: (float(e.mean()), float(e.max())) for k, e in enumerate(nl)}, seconds)


__all__ = [
    "MOTIONS",
    "Autoencoder",
    "LinearPca",
    "NlpcaReport",
    "NlpcaRig",
    "Se3Chart",
    "compare_reconstruction",
    "fit_hnlpca",
    "fit_nlpca",
    "fit_pca",
    "reconstruction_errors",
]
