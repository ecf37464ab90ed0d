"""Contact: rigid colliders as signed distance functions and penalty energy terms.

Shapes (local frame, mm, negative inside): :class:`Sphere`, :class:`Plane`, :class:`Capsule`,
:class:`MeshSDF` (grid of a closed triangle mesh). :class:`Collider` poses a shape rigidly
(follows a bone, ``at(T)``); :class:`KinematicPath` scripts its pose per frame.
:class:`ContactTerm` is the penalty energy of flesh nodes against colliders, summed by the
equilibrium solver like any other term; :class:`SurfaceContactTerm` (``lip_contact_term``) keeps
the upper and lower lips out of each other.
"""

from facesim.contact.penalty import DEFAULT_STIFFNESS, ContactTerm, node_areas
from facesim.contact.sdf import (SDF, Capsule, Collider, KinematicPath, MeshSDF, Plane, Sphere, as_collider,
                                 rigid_transform, translation)
from facesim.contact.self_contact import SurfaceContactTerm, lip_contact_term

__all__ = ["SDF", "Sphere", "Plane", "Capsule", "MeshSDF", "Collider", "KinematicPath", "as_collider",
           "rigid_transform", "translation", "ContactTerm", "node_areas", "DEFAULT_STIFFNESS", "SurfaceContactTerm",
           "lip_contact_term"]
