"""Any fitted jaw rig as the simulator's jaw model (docs/architecture.md: "empirical jaw rigs can replace the
kinematic model").

:class:`RigJaw` wraps a :class:`~facesim.jaw.posselt.PosseltRig` (controls: the sliders
s in [0, 1]³), a :class:`~facesim.jaw.nlpca.NlpcaRig` (d1, d2, d3 with opening-dependent ranges)
or a :class:`~facesim.jaw.classic.ClassicRig` (its angles and translations within the fitted
ranges) in the jaw-model interface of :class:`~facesim.kinematics.condyle.SlidingCondyleJaw`:
``name``, ``n_params``, ``transform(q) -> 4x4``, ``jacobian(q) -> (4, 4, n)``,
``penalty(q) -> (value, gradient, Hessian)``, ``bounds (n, 2)``, plus ``rest`` (the controls of
the rest pose) and ``parameters(T)`` (a pose's controls).

Frames. A rig works in its jaw frame (Zoss et al. 2018 section 3.1) and returns poses in the
skull frame of the data it was fitted on. When that is the model's own skull frame (the rig's
reference point is the model's incisor: rigs fitted to motion generated for, or captured on, this
model) the poses are used as they are; otherwise the rig's jaw frame is placed onto the model's
(``JawFrame.from_geometry(model.jaw)``): T_model = F_m⁻¹ (F_r T F_r⁻¹) F_m, with F_r, F_m the maps
from skull to jaw coordinates of the rig and of the model.

Outside its bounds a rig is continued smoothly (the shield's splines, the RBF, the autoencoder
and the classic rotations all extrapolate), so ``transform`` and ``jacobian`` stay consistent
there; the range penalty -- ``penalty_weight`` times the squared distance outside the ranges,
for an NLPCA rig the d1-dependent ranges of d2 and d3 -- and the solver's bounds bring the
controls back. ``jacobian`` is a central difference with a step of 1e-6 of each parameter's range.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw.frame import JawFrame
from facesim.jaw.posselt import PosseltRig
from facesim.jaw.rigs import KINDS

#: mm: a rig whose reference point lies this close to the model's incisor was fitted in its skull frame
SAME_FRAME_TOLERANCE = 1.0


class RigJaw:
    """A fitted rig as a jaw model (module docstring).

    rig : PosseltRig, NlpcaRig or ClassicRig.
    frame : JawFrame of the model onto which the rig's jaw frame is placed (model frame), or
        None to use the rig's poses as they are (the rig was fitted in the model's skull frame).
    penalty_weight : scalar or (n,), weight of the squared distance outside the ranges (per unit²
        of each parameter: sliders, NLPCA units, rad or mm).
    """

    def __init__(self, rig, frame: JawFrame | None = None, penalty_weight=1.0):
        kind = KINDS.get(type(rig))
        if kind is None:
            raise FacesimError(f"RigJaw: expected a PosseltRig, NlpcaRig or ClassicRig, got {type(rig).__name__}")
        self.rig, self.kind = rig, kind
        self.name = f"{kind}-rig" if kind != "classic" else f"{rig.dof}-rig"
        self.n_params = 3 if kind != "classic" else rig.n_params
        self.frame = frame
        # placement P: model pose = P T P⁻¹ (identity when the rig's skull frame is the model's)
        self._place = np.eye(4) if frame is None else se3.inverse(frame.matrix) @ rig.frame.matrix
        self._unplace = se3.inverse(self._place)
        bounds = np.array(rig.bounds, dtype=np.float64)
        if kind == "classic" and not np.isfinite(bounds).all():
            raise FacesimError("RigJaw: the classic rig has unbounded parameters (fit it with fit_classic)")
        self._bounds = bounds
        self._bounds.setflags(write=False)
        w = np.broadcast_to(np.asarray(penalty_weight, dtype=np.float64), (self.n_params,)).copy()
        if not np.isfinite(w).all() or (w < 0).any():
            raise FacesimError("RigJaw: expected finite non-negative penalty weights")
        self.penalty_weight = w
        self._step = 1e-6 * np.maximum(bounds[:, 1] - bounds[:, 0], 1e-3)
        if kind == "posselt":
            self.rest = np.array(rig.shield.sliders(np.zeros((1, 3)))[0][0])
        else:
            self.rest = np.zeros(self.n_params)
        self.rest.setflags(write=False)
        self.param_names = {"posselt": ("sx", "sy", "sz"), "nlpca": ("d1", "d2", "d3")}.get(
            kind, tuple(f"q{k}" for k in range(self.n_params)))

    # --- the map -------------------------------------------------------------------------------

    def _q(self, q) -> np.ndarray:
        if q is None:
            return np.array(self.rest)
        q = np.asarray(q, dtype=np.float64).reshape(-1)
        if q.shape != (self.n_params,) or not np.isfinite(q).all():
            raise FacesimError(f"controls.jaw: expected {self.n_params} finite {self.name} parameters, got shape "
                               f"{np.shape(q)}")
        return q

    def _rig_poses(self, Q) -> np.ndarray:
        """Rig poses ``(m, 4, 4)`` in the rig's skull frame for parameters ``Q (m, n)``, continued
        smoothly outside the bounds (no clipping)."""
        rig = self.rig
        if self.kind == "posselt":
            return rig.frame.pose_to_world(rig._pose_local(rig.shield.point(Q)))
        return rig.transform(Q)

    def _poses(self, Q) -> np.ndarray:
        return self._place @ self._rig_poses(Q) @ self._unplace

    def transform(self, q=None) -> np.ndarray:
        """4x4 mandible transform relative to the cranium (model frame, mm) for ``q (n,)``
        (None: the rest controls)."""
        return self._poses(self._q(q)[None])[0]

    def jacobian(self, q=None) -> np.ndarray:
        """``(4, 4, n)`` derivative of ``transform`` (central differences, module docstring)."""
        q = self._q(q)
        E = np.diag(self._step)
        T = self._poses(np.concatenate([q + E, q - E]))
        return np.moveaxis((T[:self.n_params] - T[self.n_params:]) / (2 * self._step[:, None, None]), 0, 2)

    # --- ranges --------------------------------------------------------------------------------

    @property
    def bounds(self) -> np.ndarray:
        """``(n, 2)`` [lower, upper] per parameter (Posselt: the unit cube; NLPCA: the d1 range and
        the widest d2, d3 ranges; classic: the fitted ranges)."""
        return self._bounds.copy()

    def clamp(self, q) -> np.ndarray:
        """``q (n,)`` moved into the valid ranges (for an NLPCA rig the d1-dependent ones)."""
        q = self._q(q)
        if self.kind == "nlpca":
            return self.rig.clamp(q)
        return np.clip(q, self._bounds[:, 0], self._bounds[:, 1])

    def penalty_box(self):
        """``(lower, upper, weight)`` when :meth:`penalty` is the box penalty of fixed ranges (a
        Posselt rig), None for an NLPCA rig (its ranges move with d1)."""
        if self.kind == "nlpca":
            return None
        lower, upper = self._bounds.T
        return lower.copy(), upper.copy(), np.array(self.penalty_weight, dtype=np.float64)

    def penalty(self, q=None):
        """Range penalty Σ_i w_i e_i² with e the distance outside the ranges: (value, gradient (n,),
        Hessian (n, n)); zero inside. For an NLPCA rig e_2, e_3 are measured against the ranges at
        the current d1, so the derivatives include those of the range curves."""
        q = self._q(q)
        w = self.penalty_weight
        if self.kind == "nlpca":
            e, J, H = self.rig.range_excess(q)
        else:
            lower, upper = self._bounds.T
            e = np.maximum(q - upper, 0.0) + np.minimum(q - lower, 0.0)
            J = np.diag((e != 0.0).astype(np.float64))
            H = np.zeros((self.n_params,) * 3)
        value = float(np.sum(w * e * e))
        grad = 2.0 * J.T @ (w * e)
        hess = 2.0 * (J.T * w) @ J + 2.0 * np.einsum("i,ijk->jk", w * e, H)
        return value, grad, hess

    # --- inverse -------------------------------------------------------------------------------

    def parameters(self, T) -> np.ndarray:
        """Controls ``(n,)`` of the rig pose closest to the model-frame pose ``T (4, 4)`` (Posselt:
        the sliders of the reference point; NLPCA: inverse kinematics; classic: the parameter fit on
        points around the reference point)."""
        T = se3.check_rigid(T, "jaw pose")
        if T.shape != (4, 4):
            raise FacesimError(f"jaw pose: expected one 4x4 transform, got shape {T.shape}")
        pose = (self._unplace @ T @ self._place)[None]          # in the rig's skull frame
        if self.kind == "posselt":
            return self.rig.sliders_of(pose)[0]
        if self.kind == "nlpca":
            return self.rig.parameters(pose)[0]
        around = np.array([[0.0, 0.0, 0.0], [40.0, 0.0, -60.0], [-40.0, 0.0, -60.0], [0.0, 30.0, -60.0]])
        return self.rig.fit_parameters(pose, self.rig.frame.to_world(around))[0]


def rig_jaw_from_spec(model, spec: str, penalty_weight=1.0) -> RigJaw:
    """A :class:`RigJaw` from ``"posselt:RIG.npz"``, ``"nlpca:RIG.npz"`` or ``"classic:RIG.npz"``
    (``"rig:RIG.npz"`` takes any kind) for the model ``model`` (its ``jaw`` geometry places rigs
    fitted in another skull frame, module docstring)."""
    from facesim.jaw.rigfile import rig_kind
    from facesim.jaw.rigs import load_rig

    kind, sep, path = str(spec).partition(":")
    if not sep or kind not in ("posselt", "nlpca", "classic", "rig") or not path:
        raise FacesimError(f"jaw model: expected posselt:RIG.npz, nlpca:RIG.npz, classic:RIG.npz or rig:RIG.npz, "
                           f"got {spec!r}")
    path = Path(path)
    if not path.is_file():
        raise FacesimError(f"{path}: no such file (expected a {kind if kind != 'rig' else 'jaw'} rig .npz)")
    found = rig_kind(path)
    if kind != "rig" and found != kind:
        raise FacesimError(f"{path}: field 'meta.kind': expected a {kind!r} rig, got {found!r}")
    rig = load_rig(path)
    near = np.linalg.norm(rig.frame.origin - model.jaw.incisor) <= SAME_FRAME_TOLERANCE
    return RigJaw(rig, None if near else JawFrame.from_geometry(model.jaw), penalty_weight)


def model_rig_jaw(model, model_path=None, penalty_weight=1.0) -> RigJaw:
    """The :class:`RigJaw` of the model's own Posselt rig (``--jaw-model posselt`` without a file):
    the rig fitted to motion generated for ``model.jaw`` (:mod:`facesim.jaw.model_rig`), found next
    to ``model_path`` (``<model>_posselt.npz``) or among the shipped rigs by its recorded TMJ."""
    from facesim.jaw.model_rig import find_model_rig, model_rig_path

    path = find_model_rig(model.jaw, model_path)
    if path is None:
        where = f"{model_rig_path(model_path)} or " if model_path is not None else ""
        name = model_path if model_path is not None else "M.npz"
        raise FacesimError(f"jaw model 'posselt': no posselt rig fitted for this model's TMJ in {where}meshes/*_posselt.npz; "
                           f"make one with 'facesim jaw fit-model --model {name}' and pass "
                           f"--jaw-model posselt:{model_rig_path(name)}")
    return RigJaw(PosseltRig.load(path), None, penalty_weight)


__all__ = ["KINDS", "RigJaw", "model_rig_jaw", "rig_jaw_from_spec"]
