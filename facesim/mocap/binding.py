"""Binding a capture's markers to the model's skin at the neutral pose (Sifakis et al. 2005).

A model's markers are named points bound to its skin: a skin triangle, barycentric coordinates
and an offset along the triangle's normal (``FaceModel.markers``). Those bindings come from the
model's anatomy; the physical markers of a capture sit wherever the performer's markers were
glued, and on a model of another resolution a "same" landmark can land millimetres away (a skin
fold projects differently). :func:`rebind_markers` moves each binding to where a neutral frame
of the capture puts that marker: the closest point of the skin near the model's own binding
(triangles within ``radius`` of it whose normal agrees with its triangle's), plus the normal
offset of the captured point from that surface. The capture's frame must show the neutral face,
already in the model's head frame (stabilised); :func:`bind_neutral` does that for a simulator and
several neutral frames (stabilised, per-marker median). :func:`match_markers` pairs the capture's
marker names with the model's.
"""

from __future__ import annotations

import copy
import warnings

import numpy as np
import trimesh

from facesim.errors import FacesimError
from facesim.mocap.stabilise import stabilise
from facesim.model import FaceModel, MarkerSet

#: Skin triangles farther than this from a marker's own binding are not candidates (mm).
SEARCH_RADIUS = 15.0
#: ... nor those whose rest normal differs from the binding triangle's by more than ~60 degrees
#: (keeps a lip marker off the mouth lining a few mm behind it).
MIN_NORMAL_COS = 0.5


def triangle_normals(X, tris) -> np.ndarray:
    """(s, 3) unit normals of the triangles ``tris (s, 3)`` at node positions ``X (n, 3)``."""
    n = np.cross(X[tris[:, 1]] - X[tris[:, 0]], X[tris[:, 2]] - X[tris[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def bind_point(corners, closest, point, normal) -> tuple[np.ndarray, float]:
    """How a marker at ``point (3,)`` is bound to the skin triangle ``corners (3, 3)`` whose point
    ``closest (3,)`` is nearest to it (Sifakis 2005): the barycentric coordinates of ``closest``
    (clipped to the triangle, summing to 1) and the offset along the triangle's unit ``normal``, mm."""
    b = trimesh.triangles.points_to_barycentric(np.asarray(corners)[None], np.asarray(closest)[None])[0]
    b = np.clip(b, 0.0, None)
    return b / b.sum(), float((np.asarray(point) - closest) @ normal)


def rebind_markers(model: FaceModel, neutral, radius: float = SEARCH_RADIUS,
                   max_distance: float = 10.0) -> tuple[FaceModel, np.ndarray]:
    """The model with its markers bound where ``neutral (r, 3)`` (mm, model marker order, NaN:
    keep the model's binding) puts them at rest, and the distance each binding moved (mm, 0 for
    kept ones).

    A captured point farther than ``max_distance`` mm from every candidate surface point is a
    bad neutral frame or a mislabelled marker: FacesimError names it.
    """
    P = np.asarray(neutral, dtype=np.float64)
    if P.shape != (model.n_markers, 3):
        raise FacesimError(f"neutral markers: expected ({model.n_markers}, 3) positions, got {P.shape}")
    X, skin, m = model.X, model.skin, model.markers
    rest = model.marker_positions()
    centroids = X[skin].mean(axis=1)
    normals = triangle_normals(X, skin)
    tri, bary, offset = m.triangle.copy(), m.bary.copy(), m.offset.copy()
    for i in np.flatnonzero(np.isfinite(P).all(axis=1)):   # one small query per marker (tens of them)
        near = np.flatnonzero((np.linalg.norm(centroids - rest[i], axis=1) < radius)
                              & (normals @ normals[m.triangle[i]] > MIN_NORMAL_COS))
        near = np.union1d(near, [m.triangle[i]])
        mesh = trimesh.Trimesh(X, skin[near], process=False)
        closest, distance, k = trimesh.proximity.closest_point(mesh, P[i][None])
        if distance[0] > max_distance:
            raise FacesimError(f"neutral markers: {m.names[i]} is {distance[0]:.1f} mm from the skin near its "
                               f"binding (expected <= {max_distance:g} mm); is the frame neutral and stabilised?")
        t = int(near[k[0]])
        tri[i] = t
        bary[i], offset[i] = bind_point(X[skin[t]], closest[0], P[i], normals[t])
    new = MarkerSet(names=m.names, triangle=tri.astype(m.triangle.dtype), bary=bary, offset=offset, head=m.head)
    out = model.with_(markers=new)
    moved = np.linalg.norm(out.marker_positions() - rest, axis=1)
    return out, moved


def match_markers(model_names, data_names) -> tuple[np.ndarray, list[str], list[str]]:
    """Index of each model marker in the capture (-1 if absent), the capture's names the model
    does not have and the model's names the capture does not have. Names match exactly, then
    case-insensitively."""
    data_names = list(data_names)
    exact = {n: i for i, n in enumerate(data_names)}
    folded = {n.lower(): i for i, n in enumerate(data_names)}
    index = np.array([exact.get(n, folded.get(n.lower(), -1)) for n in model_names], dtype=np.int64)
    used = set(index[index >= 0].tolist())
    unmatched_data = [n for i, n in enumerate(data_names) if i not in used]
    missing_model = [n for n, i in zip(model_names, index) if i < 0]
    return index, unmatched_data, missing_model


def with_markers(sim, markers):
    """``sim`` whose model carries ``markers`` (a :class:`~facesim.model.MarkerSet`; None: ``sim``
    itself). A shallow copy: the mesh, its sparsity pattern and solvers are shared."""
    if markers is None or markers is sim.model.markers:
        return sim
    other = copy.copy(sim)
    other.model = sim.model.with_(markers=markers)
    return other


def bind_neutral(sim, neutral, head: str = "procrustes"):
    """``sim`` with its model's markers bound where the capture's neutral frames ``neutral (r, 3)``
    or ``(k, r, 3)`` put them (model marker order, NaN missing; stabilised first with
    ``head="procrustes"``, with ``head="solve"`` by the rigid fit of all their markers onto the
    model's, as the head markers may be too few or too noisy; several frames: the per-marker median, robust to an outlier in one
    frame) by :func:`rebind_markers`, and a summary of how far the markers
    moved (mm)."""
    model = sim.model
    neutral = np.asarray(neutral, dtype=np.float64)
    neutral = neutral[None] if neutral.ndim == 2 else neutral
    if neutral.ndim != 3 or neutral.shape[1:] != (model.n_markers, 3) or not len(neutral):
        raise FacesimError(f"neutral markers: expected (k, {model.n_markers}, 3) positions, got {neutral.shape}")
    if head == "procrustes":
        neutral = stabilise(model, neutral)[0]
    elif head == "solve":   # the head markers may be too few or noisy: all markers, rigidly onto the model's
        from facesim.se3 import rigid_fit

        rest = model.marker_positions()
        for f, frame in enumerate(neutral):
            ok = np.isfinite(frame).all(axis=1)
            if ok.sum() >= 3:
                T = rigid_fit(frame[ok], rest[ok])
                neutral[f] = frame @ T[:3, :3].T + T[:3, 3]
    with warnings.catch_warnings():   # a marker missing in every neutral frame keeps its binding
        warnings.simplefilter("ignore", RuntimeWarning)
        neutral = np.nanmedian(neutral, axis=0)
    bound, moved = rebind_markers(model, neutral)
    summary = {"markers_moved_mm": {"mean": round(float(moved.mean()), 3), "max": round(float(moved.max()), 3)},
               "largest": {model.markers.names[j]: round(float(moved[j]), 3) for j in np.argsort(moved)[-3:][::-1]}}
    return with_markers(sim, bound.markers), summary


__all__ = ["SEARCH_RADIUS", "bind_neutral", "match_markers", "rebind_markers", "with_markers"]
