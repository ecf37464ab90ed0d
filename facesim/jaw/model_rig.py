"""A face model's own Posselt rig: fitted to jaw motion generated for the model's TMJ.

A face model carries its temporomandibular joints (``model.jaw``: condyles, sliding tracks,
maximum opening, incisor), not a jaw rig. Its own rig is fitted to a session of
:class:`~facesim.jaw.motion.JawMotion` for that geometry and the subject of
:func:`~facesim.jaw.motion.subject_for` (the maximum opening is the geometry's, the condylar
translation within its tracks), and records the geometry (``PosseltRig.tmj``). It is stored
next to the model as ``<model>_posselt.npz`` (``facesim jaw fit-model``); the shipped
``meshes/face_coarse_posselt.npz`` is the one of ``meshes/face_coarse.npz``.

The rig depends on the TMJ alone, so it serves every model with the same joint geometry (the
shipped coarse and medium models share theirs): :func:`find_model_rig` looks next to the model
file first, then among the shipped rigs, and takes the first whose recorded TMJ is the model's.
"""

from __future__ import annotations

from pathlib import Path

from facesim._files import MESHES
from facesim.errors import FacesimError
from facesim.jaw.frame import JawFrame
from facesim.jaw.motion import JawMotion, Session, subject_for
from facesim.jaw.posselt import PosseltRig, fit_posselt
from facesim.model import JawGeometry

RIG_SUFFIX = "_posselt.npz"
TRAIN_SEED, TEST_SEED = 1, 2      # the sessions a model rig is fitted on and checked against


def model_rig_path(model_path) -> Path:
    """Where the rig of the model file ``model_path`` lives: ``<stem>_posselt.npz`` next to it."""
    model_path = Path(model_path)
    return model_path.with_name(model_path.stem + RIG_SUFFIX)


def model_motion(geometry: JawGeometry, seed: int = TRAIN_SEED, noise: float = 0.0) -> Session:
    """A capture-like session (border movements, chewing, speech, free moves) of the model TMJ
    ``geometry`` with the subject of :func:`~facesim.jaw.motion.subject_for`; ``noise`` mm."""
    return JawMotion(geometry, subject_for(geometry)).session(seed=seed, noise=noise)


def fit_model_rig(geometry: JawGeometry, seed: int = TRAIN_SEED, noise: float = 0.0) -> PosseltRig:
    """The Posselt rig of the TMJ ``geometry``, fitted to :func:`model_motion` (session ``seed``,
    ``noise`` mm) in the model's skull frame and its jaw frame (``JawFrame.from_geometry``: x along
    the intercondylar axis), with the geometry recorded (``rig.tmj``)."""
    return fit_posselt(model_motion(geometry, seed, noise), frame=JawFrame.from_geometry(geometry), tmj=geometry)


def find_model_rig(geometry: JawGeometry, model_path=None) -> Path | None:
    """The file of a Posselt rig fitted for the TMJ ``geometry``: ``<model>_posselt.npz`` next to
    ``model_path`` (when given), else a shipped ``meshes/*_posselt.npz``; None if no rig there
    records this geometry."""
    candidates = [model_rig_path(model_path)] if model_path is not None else []
    if MESHES.is_dir():
        candidates += sorted(MESHES.glob("*" + RIG_SUFFIX))
    for path in candidates:
        if not path.is_file():
            continue
        try:
            rig = PosseltRig.load(path)
        except FacesimError:
            continue
        if rig.made_for(geometry):
            return path
    return None


__all__ = ["RIG_SUFFIX", "find_model_rig", "fit_model_rig", "model_motion", "model_rig_path"]
