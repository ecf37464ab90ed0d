"""Data-driven jaw modelling, independent of the FEM (docs/architecture.md ``jaw/``).

- ``frame`` -- the jaw coordinate frame (Zoss et al. 2018 section 3.1).
- ``motion`` -- synthetic TMJ motion: subjects and capture-like sessions.
- ``classic`` -- the traditional 1/3/5/6-DOF rigs with an optimised pivot (Zoss eqs. 1, 6-8).
- ``posselt`` -- the Posselt-envelope rig: shield (from labelled or unlabelled border movements),
  unit-cube sliders, RBF map (Zoss eqs. 3, 9, 15).
- ``model_rig`` -- a face model's own Posselt rig, fitted to motion generated for its TMJ.
- ``retarget`` -- a Posselt rig bent onto a new subject from a few extremal poses (Zoss section 5).
- ``nlpca`` -- se(3) chart, linear PCA, hierarchical nonlinear PCA and the 3-parameter rig (Yang et al. 2018).
- ``points`` -- mandible points, front weights, farthest-point samples.
- ``evaluate`` -- front-weighted errors, train/test comparison of rigs.
- ``rigfile`` -- fitted rigs on disk (versioned .npz); ``rigs`` -- the rig classes by kind, ``load_rig``.
- ``figures`` -- pictures of a rig's envelope.

SE(3) maps and rigid fits are in :mod:`facesim.se3`. Names are imported on first use (PEP 562),
so ``facesim --help``, which registers the ``jaw`` commands of :mod:`facesim.jaw.cli`, does not
pay for scipy and the rigs.
"""

import importlib

_EXPORTS = {
    "DOF": "classic", "ClassicRig": "classic", "fit_classic": "classic",
    "compare_rigs": "evaluate", "pose_errors": "evaluate",
    "JawFrame": "frame",
    "JawMotion": "motion", "Session": "motion", "Subject": "motion", "subject_for": "motion",
    "find_model_rig": "model_rig", "fit_model_rig": "model_rig",
    "NlpcaRig": "nlpca", "Se3Chart": "nlpca", "fit_nlpca": "nlpca", "fit_pca": "nlpca",
    "front_weights": "points", "mandible_points": "points",
    "PosseltRig": "posselt", "Shield": "posselt", "detect_border": "posselt", "fit_posselt": "posselt",
    "retarget_posselt": "retarget",
    "KINDS": "rigs", "load_rig": "rigs",
}


def __getattr__(name):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f"facesim.jaw.{_EXPORTS[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'facesim.jaw' has no attribute {name!r}")


__all__ = [
    "DOF",
    "KINDS",
    "ClassicRig",
    "JawFrame",
    "JawMotion",
    "NlpcaRig",
    "PosseltRig",
    "Se3Chart",
    "Session",
    "Shield",
    "Subject",
    "compare_rigs",
    "detect_border",
    "find_model_rig",
    "fit_classic",
    "fit_model_rig",
    "fit_nlpca",
    "fit_pca",
    "fit_posselt",
    "front_weights",
    "load_rig",
    "mandible_points",
    "pose_errors",
    "retarget_posselt",
    "subject_for",
]
