"""The markerless jaw tracker's data (Zoss et al. 2019): one subject's frames of skin and jaw.

A :class:`MarkerlessData` holds, for one subject, ``N`` frames of

- ``skin (N, P, 3)``: the positions of its ``P`` skin feature points, in the skull frame (mm);
  ``skin_rest (P, 3)`` their rest (neutral) positions. The skin features of the paper (section
  5.1) are the displacements ``skin - skin_rest``.
- ``poses (N, 4, 4)`` (optional: a capture to predict has none): the mandible's rigid transform
  relative to the skull (mm), the format ``facesim jaw fit`` reads;
- ``bone_rest (B, 3)``: the bone feature points on the mandible at rest, skull frame (mm), whose
  displacements under ``poses`` are what the regression predicts (the paper uses B = 5);
- ``ok (N,)``: False for a frame whose equilibrium did not converge (kept, flagged, not learned);
- ``feature_tri (P,)``, ``feature_bary (P, 3)``: where each skin feature point lies on the
  subject's skin surface (triangle of ``model.skin`` and barycentric weights), so a skin mesh of the
  model's topology (what ``simulate`` writes) can be turned into features;
- ``activations (N, M)`` with ``muscles`` (M names): the expression of each frame (for reports);
- ``meta``: JSON (subject name, model source, feature layout version, how the frames were made);
- ``markers`` (optional, a :class:`MarkerTrack`): the model's markers in the same frames (skull
  frame, mm) with their names, rest positions and skin triangles -- the features of a predictor
  that reads a marker capture (``solve-mocap --jaw-prior``): :meth:`MarkerlessData.marker_features`
  is the dataset with the markers as its feature points.

Files are one compressed ``.npz`` (``facesim-markerless-data`` version 1), read with one-line
errors naming the file and the field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facesim._files import NpzFormat, read_npz, write_npz
from facesim.errors import FacesimError, ModelFileError

DATA_FORMAT = NpzFormat("facesim-markerless-data", 1, what="a markerless jaw dataset .npz (facesim jaw markerless dataset)",
                        name="a facesim markerless jaw dataset", label="markerless dataset format")


@dataclass(frozen=True)
class MarkerTrack:
    """The model's markers over a dataset's frames: ``positions (N, r, 3)`` and ``rest (r, 3)``
    skull frame, mm; ``names`` (r,); ``triangle (r,)`` int64 skin triangles and ``bary (r, 3)``
    barycentric weights (where each marker sits on the skin, its height off it ignored)."""

    positions: np.ndarray
    rest: np.ndarray
    names: tuple[str, ...]
    triangle: np.ndarray
    bary: np.ndarray

    def __post_init__(self):
        r = len(self.names)
        if self.positions.ndim != 3 or self.positions.shape[1:] != (r, 3) or self.rest.shape != (r, 3) or \
                self.triangle.shape != (r,) or self.bary.shape != (r, 3):
            raise ValueError(f"markers: positions {self.positions.shape}, rest {self.rest.shape}, triangle "
                             f"{self.triangle.shape}, bary {self.bary.shape} disagree with {r} names")


@dataclass(frozen=True)
class MarkerlessData:
    """One subject's frames (module docstring). Arrays are float64 mm unless stated."""

    skin: np.ndarray                 # (N, P, 3) skin feature points, skull frame
    skin_rest: np.ndarray            # (P, 3)
    bone_rest: np.ndarray            # (B, 3)
    poses: np.ndarray | None         # (N, 4, 4) mandible relative to skull, or None
    ok: np.ndarray                   # (N,) bool
    feature_tri: np.ndarray          # (P,) int64 triangles of the model's skin
    feature_bary: np.ndarray         # (P, 3) barycentric weights
    activations: np.ndarray | None = None   # (N, M)
    muscles: tuple[str, ...] = ()
    meta: dict = field(default_factory=dict)
    markers: MarkerTrack | None = None

    def __post_init__(self):
        N, P = self.skin.shape[:2]
        if self.markers is not None and len(self.markers.positions) != N:
            raise ValueError(f"markers: {len(self.markers.positions)} frames, skin {N}")
        if self.skin.shape != (N, P, 3) or self.skin_rest.shape != (P, 3):
            raise ValueError(f"skin {self.skin.shape} and skin_rest {self.skin_rest.shape} disagree")
        if self.poses is not None and self.poses.shape != (N, 4, 4):
            raise ValueError(f"poses {self.poses.shape}: expected ({N}, 4, 4)")
        if self.ok.shape != (N,) or self.feature_tri.shape != (P,) or self.feature_bary.shape != (P, 3):
            raise ValueError("ok, feature_tri or feature_bary has the wrong shape")
        if self.bone_rest.ndim != 2 or self.bone_rest.shape[1] != 3:
            raise ValueError(f"bone_rest {self.bone_rest.shape}: expected (B, 3)")

    @property
    def n_frames(self) -> int:
        return int(self.skin.shape[0])

    @property
    def n_features(self) -> int:
        return int(self.skin.shape[1])

    @property
    def skin_displacement(self) -> np.ndarray:
        """``(N, P, 3)`` the paper's skin features: displacement from rest in the skull frame, mm."""
        return self.skin - self.skin_rest[None]

    def bone_points(self) -> np.ndarray:
        """``(N, B, 3)`` the bone feature points moved by ``poses`` (mm); needs poses."""
        if self.poses is None:
            raise ValueError("this dataset has no jaw poses")
        R, t = self.poses[:, :3, :3], self.poses[:, :3, 3]
        return np.einsum("nij,bj->nbi", R, self.bone_rest) + t[:, None, :]

    def subset(self, frames) -> "MarkerlessData":
        """The frames ``frames`` (indices or a boolean mask) as a new dataset."""
        idx = np.arange(self.n_frames)[frames]
        mk = self.markers
        return MarkerlessData(self.skin[idx], self.skin_rest, self.bone_rest,
                              None if self.poses is None else self.poses[idx], self.ok[idx], self.feature_tri,
                              self.feature_bary, None if self.activations is None else self.activations[idx],
                              self.muscles, dict(self.meta),
                              None if mk is None else dataclasses.replace(mk, positions=mk.positions[idx]))

    def marker_features(self, names=None) -> "MarkerlessData":
        """This dataset with the model's markers as its feature points (``meta["features"]``:
        ``{"kind": "markers", "names": [...]}``): what a predictor for marker captures learns.
        ``names``: only these markers, in this order (e.g. those a capture has; None: all). A
        one-line error when the dataset recorded no markers or lacks one of ``names``."""
        mk = self.markers
        where = self.meta.get("name", "this dataset")
        if mk is None:
            raise FacesimError(f"{where}: no markers recorded (field 'marker_positions'); rebuild it with "
                               "'facesim jaw markerless dataset' to train on markers")
        idx = np.arange(len(mk.names))
        if names is not None:
            names = [str(n) for n in names]
            missing = [n for n in names if n not in mk.names]
            if missing:
                raise FacesimError(f"{where}: no marker {', '.join(missing[:5])} among the {len(mk.names)} recorded "
                                   f"({', '.join(mk.names[:3])}, ...)")
            if len(set(names)) != len(names) or len(names) < 3:
                raise FacesimError(f"markers: expected at least 3 distinct marker names, got {len(names)}")
            idx = np.array([mk.names.index(n) for n in names])
        return MarkerlessData(mk.positions[:, idx], mk.rest[idx], self.bone_rest, self.poses, self.ok, mk.triangle[idx],
                              mk.bary[idx], self.activations, self.muscles,
                              {**self.meta, "features": {"kind": "markers", "names": [mk.names[i] for i in idx]}})

    def save(self, path) -> Path:
        arrays = dict(skin=self.skin, skin_rest=self.skin_rest, bone_rest=self.bone_rest, ok=self.ok,
                      feature_tri=self.feature_tri, feature_bary=self.feature_bary)
        if self.poses is not None:
            arrays["poses"] = self.poses
        if self.activations is not None:
            arrays["activations"] = self.activations
            arrays["muscles"] = np.array(self.muscles, dtype=str)
        if self.markers is not None:
            mk = self.markers
            arrays.update(marker_positions=mk.positions, marker_rest=mk.rest, marker_names=np.array(mk.names, dtype=str),
                          marker_triangle=mk.triangle, marker_bary=mk.bary)
        return write_npz(path, DATA_FORMAT, arrays, dict(self.meta))


def _checked(archive, key: str, shape_ok, expected: str, kind: str = "f") -> np.ndarray:
    a = archive.array(key)
    if a.dtype.kind not in ("fiu" if kind == "f" else kind):
        raise ModelFileError(archive.path, f"field {key!r}: expected {expected}, got dtype {a.dtype}")
    if not shape_ok(a.shape):
        raise ModelFileError(archive.path, f"field {key!r}: expected {expected}, got shape {a.shape}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise ModelFileError(archive.path, f"field {key!r}: expected finite values, got NaN or inf")
    return a


def load_data(path) -> MarkerlessData:
    """Read a dataset written by :meth:`MarkerlessData.save`; one-line errors name file and field."""
    path = Path(path)
    with read_npz(path, DATA_FORMAT) as ar:
        skin = _checked(ar, "skin", lambda s: len(s) == 3 and s[2] == 3 and s[0] >= 1 and s[1] >= 1,
                        "(N, P, 3) skin feature points, mm").astype(np.float64)
        N, P = skin.shape[:2]
        skin_rest = _checked(ar, "skin_rest", lambda s: s == (P, 3), f"({P}, 3) mm").astype(np.float64)
        bone_rest = _checked(ar, "bone_rest", lambda s: len(s) == 2 and s[1] == 3 and s[0] >= 3,
                             "(B, 3) bone points, B >= 3, mm").astype(np.float64)
        poses = None
        if "poses" in ar.files:
            poses = _checked(ar, "poses", lambda s: s == (N, 4, 4), f"({N}, 4, 4) transforms, mm").astype(np.float64)
        ok = _checked(ar, "ok", lambda s: s == (N,), f"({N},) booleans", kind="b").astype(bool)
        tri = _checked(ar, "feature_tri", lambda s: s == (P,), f"({P},) triangle indices", kind="iu").astype(np.int64)
        bary = _checked(ar, "feature_bary", lambda s: s == (P, 3), f"({P}, 3) barycentric weights").astype(np.float64)
        acts, muscles = None, ()
        if "activations" in ar.files:
            acts = _checked(ar, "activations", lambda s: len(s) == 2 and s[0] == N, f"({N}, M) activations")
            names = ar.array("muscles") if "muscles" in ar.files else None
            if names is None or names.shape != (acts.shape[1],) or names.dtype.kind not in "US":
                raise ModelFileError(path, f"field 'muscles': expected {acts.shape[1]} muscle names with 'activations'")
            acts, muscles = acts.astype(np.float64), tuple(str(n) for n in names)
        markers = None
        if "marker_positions" in ar.files:
            pos = _checked(ar, "marker_positions", lambda s: len(s) == 3 and s[0] == N and s[2] == 3 and s[1] >= 1,
                           f"({N}, r, 3) marker positions, mm").astype(np.float64)
            r = pos.shape[1]
            names = ar.array("marker_names") if "marker_names" in ar.files else None
            if names is None or names.shape != (r,) or names.dtype.kind not in "US":
                raise ModelFileError(path, f"field 'marker_names': expected {r} marker names with 'marker_positions'")
            markers = MarkerTrack(
                pos, _checked(ar, "marker_rest", lambda s: s == (r, 3), f"({r}, 3) mm").astype(np.float64),
                tuple(str(n) for n in names),
                _checked(ar, "marker_triangle", lambda s: s == (r,), f"({r},) triangle indices", kind="iu").astype(np.int64),
                _checked(ar, "marker_bary", lambda s: s == (r, 3), f"({r}, 3) barycentric weights").astype(np.float64))
        meta = {k: v for k, v in ar.meta.items() if k not in ("format", "version")}
    return MarkerlessData(skin, skin_rest, bone_rest, poses, ok, tri, bary, acts, muscles, meta, markers)
