"""The markerless jaw predictor in the loop: a prior on each frame's jaw (issue 17, item 8).

A marker capture often has few markers on the chin, so the markers pin the jaw poorly. A
predictor trained on the model's markers (``facesim jaw markerless train --features markers``,
Zoss et al. 2019 with the markers as the skin features) predicts, from all of a frame's markers,
where ``B`` points of the mandible are. :class:`JawPrior` turns that prediction into

* the **start** of a cold frame: the jaw parameters whose pose is closest to the predicted one
  (the jaw model's ``parameters`` of the Kabsch pose of the predicted points), and
* a **prior** in every frame's objective (:func:`~facesim.inverse.gauss_newton.fit_frame`'s
  ``jaw_prior``): virtual markers on the mandible, the bone points ``p_b(q) = T(q) X_b`` of the
  solved jaw parameters ``q`` drawn to their predicted positions ``p^_b`` with a standard deviation
  of ``sigma`` mm per coordinate::

      F(c) = 1/2 sum_r w_r |P_r - T_r|^2 + 1/2 (noise / sigma)^2 sum_b |p_b(q) - p^_b|^2 + mu B(c)

  -- the same units (mm^2) and the same noise model as the markers: a marker of noise ``noise``
  weighs 1, a predicted bone point ``(noise / sigma)^2``. The residual rows join the marker rows
  of the Gauss-Newton model (their Jacobian ``dp_b/dq`` from the jaw model's ``jacobian``), so the
  penalty schedule, the line search and the stopping rule see one objective.

The predictor's features are the markers' displacements from the model's rest markers in the
skull frame (the frame the tracker stabilises the capture into); a missing marker's displacement
is taken from the frame's warm start (the previous frame's fit), so a drop-out does not bias the
prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facesim.errors import FacesimError


@dataclass(frozen=True, eq=False)
class JawPrior:
    """A marker-reading predictor (:class:`facesim.jaw.markerless.Predictor` with marker features)
    bound to a model: ``bone_rest (B, 3)`` the model's bone feature points at rest (skull frame, mm;
    :func:`facesim.jaw.markerless_features.bone_rest_points`), ``marker_names`` the model's markers
    (the predictor reads some of them: those it was trained on, e.g. the ones a capture has),
    ``sigma`` the prior's standard deviation per bone-point coordinate, mm."""

    predictor: object
    bone_rest: np.ndarray
    marker_names: tuple[str, ...]
    sigma: float = 1.0

    def __post_init__(self):
        from facesim.jaw.markerless import feature_kind

        kind, names = feature_kind(self.predictor.meta)
        if kind != "markers":
            raise FacesimError("jaw prior: the predictor reads skin features; train one on the model's markers "
                               "('facesim jaw markerless train --features markers')")
        missing = [n for n in names if n not in self.marker_names]
        if missing or not names:
            raise FacesimError(f"jaw prior: the predictor reads {len(names)} markers, the model has no "
                               f"{', '.join(missing[:5]) or 'markers'}")
        object.__setattr__(self, "index", np.array([list(self.marker_names).index(n) for n in names], dtype=np.int64))
        if np.shape(self.bone_rest) != (self.predictor.n_bone, 3):
            raise FacesimError(f"jaw prior: {np.shape(self.bone_rest)} bone points, the predictor predicts "
                               f"{self.predictor.n_bone}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise FacesimError(f"jaw prior sigma: expected a distance > 0 mm, got {self.sigma}")

    def predict(self, model, markers, fallback=None) -> np.ndarray:
        """Predicted bone points ``(B, 3)`` mm (skull frame) from the frame's markers ``(r, 3)`` in
        the skull frame (NaN rows missing: taken from ``fallback (r, 3)``, else from rest)."""
        from facesim.jaw.markerless import predict_bone_points
        from facesim.jaw.markerless_data import MarkerlessData

        rest = model.marker_positions()[self.index]
        m = np.array(markers, dtype=np.float64)[self.index]
        gone = ~np.isfinite(m).all(axis=1)
        if gone.any():
            m[gone] = rest[gone] if fallback is None else np.asarray(fallback, dtype=np.float64)[self.index][gone]
        r = len(rest)
        data = MarkerlessData(m[None], rest, np.asarray(self.bone_rest, dtype=np.float64), None, np.ones(1, bool),
                              np.zeros(r, np.int64), np.full((r, 3), 1.0 / 3.0),
                              meta={"features": {"kind": "markers",
                                                 "names": [self.marker_names[i] for i in self.index]}})
        return predict_bone_points(self.predictor, data)[0]

    def start(self, jaw_model, points) -> np.ndarray:
        """The jaw parameters of the pose closest to the predicted ``points (B, 3)``."""
        from facesim import se3

        T = se3.rigid_fit(np.asarray(self.bone_rest, dtype=np.float64), np.asarray(points, dtype=np.float64))
        return np.asarray(jaw_model.parameters(T), dtype=np.float64)

    def rows(self, points, noise: float) -> "PriorRows":
        """The prior's residual rows for a frame whose predicted bone points are ``points (B, 3)``,
        with the markers' ``noise`` (mm)."""
        return PriorRows(np.asarray(self.bone_rest, dtype=np.float64), np.asarray(points, dtype=np.float64),
                         (noise / self.sigma) ** 2)


@dataclass(frozen=True, eq=False)
class PriorRows:
    """Residual rows ``r(q) = (T(q) X_b - p^_b)`` ``(3B,)`` mm of bone points ``rest (B, 3)`` drawn
    to ``target (B, 3)`` with ``weight`` per coordinate (the marker weights' units)."""

    rest: np.ndarray
    target: np.ndarray
    weight: float

    def residual(self, jaw_model, q) -> np.ndarray:
        from facesim import se3

        return (se3.transform_points(jaw_model.transform(q), self.rest) - self.target).ravel()

    def jacobian(self, jaw_model, q) -> np.ndarray:
        """``(3B, n_params)`` derivative of :meth:`residual` in the jaw parameters."""
        dT = np.asarray(jaw_model.jacobian(q), dtype=np.float64)          # (4, 4, k)
        d = np.einsum("ijk,bj->bik", dT[:3, :3], self.rest) + dT[:3, 3][None]
        return d.reshape(-1, dT.shape[2])


__all__ = ["JawPrior", "PriorRows"]
