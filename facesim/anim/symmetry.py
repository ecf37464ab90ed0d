"""Left for right: a performance mirrored across the model's midsagittal plane.

Model coordinates put x toward the subject's left with the origin between the condyles, so the
midsagittal plane is ``x = c`` with ``c`` the condyle midpoint's x (0 on the shipped models), and
the mirror is the reflection ``S: (x, y, z) -> (2c - x, y, z)`` (a 4x4 matrix, its own inverse).

* activations: each ``_L`` muscle takes its ``_R`` partner's values and back (midline muscles,
  side ``M``, keep theirs); the gains likewise;
* jaw: the sliding-condyle jaw swaps its right and left slides (exactly the mirrored pose on a
  model symmetric about the plane: the opening about the intercondylar axis commutes with S, the
  yaw ``asin((s_R - s_L)/l)`` changes sign); a rigid jaw's poses become ``S T S``; every other
  jaw model (affine frames, fitted rigs) maps ``S T(q) S`` back to its parameters with
  ``parameters()``, clamped to its bounds;
* head: ``H_k -> W H_k S`` with ``W = H_0 S H_0^-1`` the mirror across the plane where the first
  frame puts the head's midsagittal plane in the capture: the first frame's head pose stays,
  the head's motion from it is mirrored.

Mirroring twice gives the sequence back (bit for bit for activations, gains and the
sliding-condyle jaw; to rounding for poses).
"""

from __future__ import annotations

import numpy as np

from facesim import se3
from facesim.anim.sequence import ControlsSequence
from facesim.errors import FacesimError


def mirror_matrix(model) -> np.ndarray:
    """``(4, 4)`` reflection across the model's midsagittal plane ``x = c`` (c: the condyle
    midpoint's x, mm): ``x -> 2c - x``."""
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    S[0, 3] = 2.0 * float(model.jaw.midpoint[0])
    return S


def partners(muscles) -> np.ndarray:
    """``(m,)`` index of each muscle's mirror partner in a :class:`~facesim.model.MuscleSet`: ``X_L``
    <-> ``X_R``, a midline muscle itself. One-line error for a sided muscle without its partner."""
    names, sides = tuple(muscles.names), tuple(muscles.sides)
    index = {n: i for i, n in enumerate(names)}
    out = np.arange(len(names))
    for i, (name, side) in enumerate(zip(names, sides)):
        if side == "M":
            continue
        other = "R" if side == "L" else "L"
        base, _, suffix = name.rpartition("_")
        partner = f"{base}_{other}" if suffix == side else None
        if partner is None or partner not in index or sides[index[partner]] != other:
            raise FacesimError(f"mirror: muscle {name!r} (side {side}) has no {'right' if other == 'R' else 'left'} "
                               f"partner {(partner or name + '_' + other)!r} in the model; expected muscles in "
                               "_L/_R pairs (or midline, side M)")
        out[i] = index[partner]
    return out


def mirror(seq: ControlsSequence, model, model_path=None) -> ControlsSequence:
    """``seq`` mirrored left for right across ``model``'s midsagittal plane (module doc).
    ``model_path``: where the model was read (to rebuild the model's own Posselt rig)."""
    from facesim.runfolder import parts

    if tuple(seq.muscles) != tuple(model.muscles.names) or dict(seq.model_parts) != parts(model):
        raise FacesimError("mirror: the controls are for another model than the one given")
    perm = partners(model.muscles)
    S = mirror_matrix(model)
    spec = seq.jaw_model
    jaw = seq.jaw
    if spec.posed:
        jaw = None if jaw is None else S @ jaw @ S
    elif spec.name == "sliding-condyle":
        names = list(spec.param_names)
        swap = np.arange(len(names))
        r, l = names.index("right_slide"), names.index("left_slide")
        swap[r], swap[l] = l, r
        jaw = jaw[:, swap]
    else:
        jaw_model = spec.build(model, model_path)
        lo, hi = spec.bounds.T
        jaw = np.clip(np.array([jaw_model.parameters(S @ jaw_model.transform(q) @ S) for q in jaw]), lo, hi)
    head = seq.head
    if head is not None:
        W = head[0] @ S @ se3.inverse(head[0])
        head = W @ head @ S
        head[0] = seq.head[0]
    return seq.replace(A=seq.A[:, perm], gain=seq.gain[perm], jaw=jaw, head=head)


__all__ = ["mirror", "mirror_matrix", "partners"]
