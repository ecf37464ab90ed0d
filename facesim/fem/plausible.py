"""Up-front plausibility of a run's inputs: jaw poses the anatomy allows, colliders the face can get out of.

A solve asked for the impossible does not fail quickly: a jaw rotated 10 rad, a mandible moved
1e30 mm, a ball that holds the whole skull each leave Newton iterating against a load it can
never balance, minutes per frame. These checks run over every frame before the first solve and
refuse such inputs with one line naming the source, the frame and the limit:

* **jaw** (:func:`check_jaw`): the mandible's rotation from rest, relative to the skull, at most
  ``JAW_ROTATION_FACTOR`` times the model's largest opening (``model.jaw.max_opening``, capped at
  pi/2); the condyle midpoint's shift at most twice the condyle track length plus
  ``JAW_SHIFT_MARGIN`` mm (the sliding-condyle jaw moves it by at most one track length);
* **colliders** (:func:`check_colliders`): no node where the simulated flesh is attached to a
  bone may lie deeper than ``ATTACHED_DEPTH`` mm inside a collider at any frame (that flesh cannot
  be pushed out: the penalty on its free neighbours would fight the bone forever), and no collider may hold more than
  ``SKIN_INSIDE_FRACTION`` of the skin nodes (the skin at the frame's bone poses).

Jaw poses inside a fitted rig's bounds pass by construction of the rig; the check matters for
the rigid jaw, whose CSV takes any rotation and translation.
"""

from __future__ import annotations

import math

import numpy as np

from facesim.contact.scene import as_scene_collider
from facesim.errors import FacesimError

JAW_ROTATION_FACTOR = 1.5
JAW_SHIFT_MARGIN = 10.0   # mm
ATTACHED_DEPTH = 1.0      # mm
SKIN_INSIDE_FRACTION = 0.5


def jaw_limits(model) -> tuple[float, float]:
    """``(largest rotation, rad; largest condyle-midpoint shift, mm)`` of the mandible from rest."""
    return (min(math.pi / 2, JAW_ROTATION_FACTOR * model.jaw.max_opening),
            2.0 * model.jaw.track_length + JAW_SHIFT_MARGIN)


def _angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def check_jaw(model, jaw_model, frames, jaw_controls, source: str) -> None:
    """Refuse jaw controls (one per frame of ``frames``, in ``jaw_model``, a
    :class:`~facesim.kinematics.jaw_models.JawModel`) whose mandible pose is beyond
    :func:`jaw_limits`; ``source`` names where they came from."""
    max_angle, max_shift = jaw_limits(model)
    mid = model.jaw.midpoint
    for k, q in zip(frames, jaw_controls):
        T = np.asarray(jaw_model.transform(q), dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise FacesimError(f"{source}: frame {int(k)}: the jaw pose is not a finite 4x4 transform")
        angle = _angle(T[:3, :3])
        if angle > max_angle + 1e-9:
            raise FacesimError(f"{source}: frame {int(k)}: the jaw is rotated {angle:.3g} rad "
                               f"({math.degrees(angle):.0f} deg) from rest; expected at most {max_angle:.3g} rad "
                               f"({JAW_ROTATION_FACTOR:g}x the model's largest opening, {model.jaw.max_opening:.3g} rad)")
        shift = float(np.linalg.norm(T[:3, :3] @ mid + T[:3, 3] - mid))
        if not shift <= max_shift:
            raise FacesimError(f"{source}: frame {int(k)}: the jaw's condyles are moved {shift:.4g} mm from rest; "
                               f"expected at most {max_shift:.3g} mm (twice the model's condyle track, "
                               f"{model.jaw.track_length:.3g} mm, plus {JAW_SHIFT_MARGIN:g} mm)")


def check_colliders(model, colliders, frames, jaw_model=None, jaw_controls=None, source: str = "--collider") -> None:
    """Refuse ``colliders`` (scene colliders, colliders or shapes, as
    :class:`~facesim.fem.equilibrium.EquilibriumOptions` takes them) that reach bone-attached flesh
    or hold most of the skin at any of ``frames``, with the mandible of ``jaw_controls`` (one per
    frame, in ``jaw_model``; None: at rest) and the skull at rest."""
    scene = [as_scene_collider(c, i) for i, c in enumerate(colliders)]
    if not scene:
        return
    # the bone interface of the simulated flesh (nodes only in unsimulated tets move with the skull
    # whatever the colliders do, and carry no force)
    attached = np.intersect1d(np.union1d(model.cranium_nodes, model.jaw_nodes), model.tets[model.simulated])
    skin = np.unique(model.skin)
    frames = np.asarray(frames).ravel()
    Hc = np.eye(4)
    for i, k in enumerate(frames):
        Hj = np.eye(4) if jaw_controls is None else np.asarray(jaw_model.transform(jaw_controls[i]), np.float64)
        x = model.X.copy()
        x[model.jaw_nodes] = model.X[model.jaw_nodes] @ Hj[:3, :3].T + Hj[:3, 3]
        for spec in scene:
            collider = spec.at(float(k), Hc, Hj)
            d_attached = collider.distance(x[attached])
            deepest = int(np.argmin(d_attached)) if len(attached) else -1
            if deepest >= 0 and not d_attached[deepest] >= -ATTACHED_DEPTH:
                raise FacesimError(f"{source}: collider {spec.name!r} at frame {int(k)} reaches "
                                   f"{-d_attached[deepest]:.3g} mm into flesh attached to the bones (node "
                                   f"{int(attached[deepest])}); expected at most {ATTACHED_DEPTH:g} mm: bone-fixed "
                                   "flesh cannot move out of it (move the collider out or make it smaller)")
            inside = float(np.mean(collider.distance(x[skin]) < 0.0))
            if inside > SKIN_INSIDE_FRACTION:
                raise FacesimError(f"{source}: collider {spec.name!r} at frame {int(k)} holds {100 * inside:.0f}% of "
                                   f"the skin; expected a collider pressing on the face (at most "
                                   f"{100 * SKIN_INSIDE_FRACTION:.0f}% of the skin inside it)")


__all__ = ["ATTACHED_DEPTH", "JAW_ROTATION_FACTOR", "JAW_SHIFT_MARGIN", "SKIN_INSIDE_FRACTION", "check_colliders",
           "check_jaw", "jaw_limits"]
