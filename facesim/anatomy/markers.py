"""The mocap marker set and its binding to skin triangles.

About 80 markers in the pattern of a facial capture session: dense around the lips and the
jaw line, rows over the cheeks, brows and nose; plus head markers on regions that barely move
(forehead, nose bridge, temples) for stabilisation. Positions are canonical guesses (mm); each
marker is bound to the closest triangle of the outer skin with barycentric coordinates.
"""

from __future__ import annotations

import numpy as np
import trimesh

from facesim.model import MarkerSet

_M = np.array([-1.0, 1.0, 1.0])

#: (name, canonical position, head marker). Names ending in _L are mirrored to _R.
LEFT_AND_MIDLINE: tuple[tuple[str, tuple[float, float, float], bool], ...] = (
    # head (stabilisation)
    ("head_forehead_C", (0, 88, 84), True), ("head_forehead_L", (30, 84, 78), True),
    ("head_nose_bridge", (0, 36, 88), True), ("head_temple_L", (64, 44, 30), True),
    # forehead and brows
    ("forehead_low_L", (22, 64, 86), False), ("forehead_low_C", (0, 64, 88), False),
    ("brow_inner_L", (13, 47, 88), False), ("brow_mid_L", (29, 50, 85), False), ("brow_outer_L", (45, 45, 74), False),
    # eyes
    ("eye_outer_L", (48, 26, 68), False), ("lower_lid_L", (32, 12, 80), False),
    # nose
    ("nose_tip", (0, -3, 116), False), ("nose_dorsum", (0, 14, 102), False), ("nose_ala_L", (18, -8, 100), False),
    # cheeks
    ("cheek_upper_L", (44, 2, 74), False), ("cheek_malar_L", (56, -8, 62), False),
    ("cheek_mid_L", (40, -18, 82), False), ("cheek_lateral_L", (60, -24, 46), False),
    ("cheek_low_L", (50, -36, 68), False), ("cheek_buccal_L", (40, -32, 84), False),
    ("cheek_jaw_L", (60, -48, 38), False), ("cheek_zygoma_L", (60, 4, 44), False),
    # nasolabial fold and upper lip skin
    ("nasolabial_upper_L", (21, -16, 96), False), ("nasolabial_lower_L", (30, -30, 92), False),
    ("philtrum", (0, -22, 102), False), ("upper_lip_skin_L", (10, -26, 100), False),
    # lips
    ("lip_upper_C", (0, -35, 102), False), ("lip_upper_inner_L", (8, -35.5, 101), False),
    ("lip_upper_outer_L", (17, -37, 97), False), ("mouth_corner_L", (27, -40, 88), False),
    ("lip_lower_C", (0, -45, 100), False), ("lip_lower_inner_L", (8, -45, 99), False),
    ("lip_lower_outer_L", (17, -43.5, 95), False),
    ("mouth_outer_upper_L", (30, -33, 90), False), ("mouth_outer_lower_L", (30, -48, 88), False),
    # chin
    ("mentolabial_C", (0, -58, 92), False), ("mentolabial_L", (13, -60, 90), False),
    ("chin_C", (0, -78, 92), False), ("chin_L", (16, -76, 88), False),
    ("chin_low_C", (0, -92, 78), False), ("under_chin_L", (20, -94, 62), False),
    ("depressor_L", (32, -62, 82), False),
    # jaw line
    ("jaw_front_L", (36, -82, 55), False), ("jaw_mid_L", (46, -72, 40), False),
    ("jaw_angle_L", (56, -62, 14), False), ("jaw_ramus_L", (60, -40, 6), False),
)


def marker_table() -> list[tuple[str, np.ndarray, bool]]:
    """All markers as ``(name, canonical position (3,), head)``: left, midline and mirrored right."""
    out = []
    for name, p, head in LEFT_AND_MIDLINE:
        p = np.asarray(p, float)
        out.append((name, p, head))
        if name.endswith("_L"):
            out.append((name[:-2] + "_R", p * _M, head))
    return out


def bind_markers(X: np.ndarray, skin: np.ndarray, outer: np.ndarray, scale=None) -> MarkerSet:
    """Bind every marker to the closest outer-skin triangle.

    ``skin (s, 3)`` are the model's skin triangles and ``outer (s,) bool`` marks those on the
    outside of the face (not the mouth lining); ``scale`` maps canonical mm to the subject.
    """
    scale = scale or (lambda p: p)
    table = marker_table()
    pos = scale(np.array([p for _, p, _ in table]))
    sub = np.flatnonzero(outer)
    mesh = trimesh.Trimesh(X, skin[sub], process=False)
    closest, _, tri = trimesh.proximity.closest_point(mesh, pos)
    corners = X[skin[sub[tri]]]
    bary = trimesh.triangles.points_to_barycentric(corners, closest)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    return MarkerSet(names=tuple(n for n, _, _ in table), triangle=sub[tri].astype(np.int32), bary=bary,
                     offset=np.zeros(len(table)), head=np.array([h for _, _, h in table]))
