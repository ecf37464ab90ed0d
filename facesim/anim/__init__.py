"""Controls sequences and their editing in activation space (Sifakis et al. 2005 section 9;
docs/architecture.md ``anim/``).

- ``sequence`` -- :class:`ControlsSequence` (activations, jaw, head per frame; fps, gains, jaw
  model), :func:`read_sequence` / :func:`write_sequence` in the files solve-mocap writes.
- ``curves`` -- interpolation through keys: linear, smoothstep, Catmull-Rom; poses on SE(3).
- ``edits`` -- :func:`blend`, :func:`keyframes`, :func:`scale`, :func:`gain`, :func:`splice`,
  :func:`concatenate`, :func:`retime`.
- ``symmetry`` -- :func:`mirror`: left for right across the midsagittal plane.
- ``cli`` -- ``facesim edit {blend,keyframe,scale,gain,splice,retime,mirror}``.

Names are imported on first use (PEP 562), so registering the ``edit`` commands costs nothing.
"""

import importlib

_EXPORTS = {
    "ControlsSequence": "sequence", "JawSpec": "sequence", "read_sequence": "sequence",
    "write_sequence": "sequence", "muscle_indices": "sequence",
    "METHODS": "curves",
    "blend": "edits", "concatenate": "edits", "gain": "edits", "keyframes": "edits", "retime": "edits",
    "scale": "edits", "splice": "edits",
    "mirror": "symmetry",
}


def __getattr__(name):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"facesim.anim.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'facesim.anim' has no attribute {name!r}")


__all__ = sorted(_EXPORTS)
