"""The kinds of fitted jaw rig: the class each kind of rig file holds, and any rig file loaded by
its kind."""

from __future__ import annotations

from facesim.jaw.classic import ClassicRig
from facesim.jaw.nlpca import NlpcaRig
from facesim.jaw.posselt import PosseltRig
from facesim.jaw.rigfile import rig_kind

#: rig class -> the ``kind`` its files record (:mod:`facesim.jaw.rigfile`)
KINDS = {PosseltRig: "posselt", NlpcaRig: "nlpca", ClassicRig: "classic"}


def load_rig(path):
    """A fitted rig (:class:`PosseltRig`, :class:`NlpcaRig` or :class:`ClassicRig`) from its ``.npz``,
    by its kind (an unknown kind is refused by the Posselt loader, naming the file and the kind)."""
    loader = {kind: cls.load for cls, kind in KINDS.items()}
    return loader.get(rig_kind(path), PosseltRig.load)(path)


__all__ = ["KINDS", "load_rig"]
