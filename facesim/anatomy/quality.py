"""Mesh quality of a tetrahedral mesh: volumes, dihedral angles, volume ratio.

The volume ratio of a tet is ``V / V_regular(l_rms)``, its signed volume over the volume of
the regular tet whose edge is the root-mean-square edge length of the tet
(``V_regular(l) = l^3 / (6 sqrt 2)``): 1 for a regular tet, towards 0 for slivers and needles,
negative for inverted tets. It is scale invariant.
"""

from __future__ import annotations

import numpy as np

from facesim._kernels.quality import tet_quality_kernel
from facesim.errors import FacesimError

#: Tets whose volume ratio is below this are counted as degenerate by :func:`quality_summary`.
DEGENERATE_RATIO = 1e-3


def _pack(X, tets) -> tuple[np.ndarray, np.ndarray]:
    X = np.ascontiguousarray(X, dtype=np.float64)
    tets_in = np.asarray(tets)
    if X.ndim != 2 or X.shape[1] != 3:
        raise FacesimError(f"X: expected shape (n, 3), got {X.shape}")
    if tets_in.ndim != 2 or tets_in.shape[1] != 4:
        raise FacesimError(f"tets: expected shape (m, 4), got {tets_in.shape}")
    if tets_in.size and not np.issubdtype(tets_in.dtype, np.integer):
        raise FacesimError(f"tets: expected integer node indices, got {tets_in.dtype}")
    if tets_in.size and (tets_in.min() < 0 or tets_in.max() >= len(X)):
        raise FacesimError(f"tets: indices must lie in [0, {len(X)}), got [{tets_in.min()}, {tets_in.max()}]")
    return X, np.ascontiguousarray(tets_in, dtype=np.int32)


def tet_quality(X, tets) -> dict[str, np.ndarray]:
    """Per-tet quality measures.

    Parameters
    ----------
    X : (n, 3) float, node positions, mm.
    tets : (m, 4) int, node indices per tet.

    Returns
    -------
    dict of (m,) float64 arrays:
        ``volume`` signed volume, mm^3 (positive for positively oriented tets);
        ``min_dihedral_deg``, ``max_dihedral_deg`` smallest and largest of the six interior
        dihedral angles, degrees (70.53 for a regular tet; a face of zero area counts as 0);
        ``volume_ratio`` V / V_regular(rms edge), 1 regular, ~0 sliver, < 0 inverted.
    """
    X, tets = _pack(X, tets)
    m = len(tets)
    volume, lo, hi, ratio = (np.empty(m) for _ in range(4))
    if m:
        tet_quality_kernel(X, tets, volume, lo, hi, ratio)
    return {
        "volume": volume,
        "min_dihedral_deg": np.degrees(lo),
        "max_dihedral_deg": np.degrees(hi),
        "volume_ratio": ratio,
    }


def quality_summary(X, tets) -> dict[str, float | int]:
    """Whole-mesh quality figures of ``X (n, 3)`` mm and ``tets (m, 4)``, m >= 1.

    Returns a JSON-serialisable dict: ``n_tets``; ``min_dihedral_deg`` and ``max_dihedral_deg``
    over all tets (degrees); ``worst_volume_ratio`` (minimum) and ``mean_volume_ratio``;
    ``n_inverted`` (volume < 0); ``n_degenerate`` (volume ratio < :data:`DEGENERATE_RATIO`,
    inverted tets included); ``min_volume_mm3`` (smallest signed volume).
    """
    q = tet_quality(X, tets)
    if not len(q["volume"]):
        raise FacesimError("tets: expected at least one tet to measure mesh quality")
    return {
        "n_tets": int(len(q["volume"])),
        "min_dihedral_deg": float(q["min_dihedral_deg"].min()),
        "max_dihedral_deg": float(q["max_dihedral_deg"].max()),
        "worst_volume_ratio": float(q["volume_ratio"].min()),
        "mean_volume_ratio": float(q["volume_ratio"].mean()),
        "n_inverted": int((q["volume"] < 0).sum()),
        "n_degenerate": int((q["volume_ratio"] < DEGENERATE_RATIO).sum()),
        "min_volume_mm3": float(q["volume"].min()),
    }
