"""Pictures of jaw rigs (matplotlib, off screen): the envelope of the incisal point.

``envelope_figure`` draws a rig's envelope in its jaw frame (x left, y up, z forward, mm) three
ways: in 3D, and projected on the sagittal (z, y) and frontal (x, y) planes -- the classic views
of Posselt's figure. A Posselt rig shows its shield (the six cube faces) and border curves, an
NLPCA rig the boundary of its valid parameter ranges; the reference points of data poses and a
second set of border curves (e.g. a shield found in unlabelled poses) can be drawn over it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _envelope_geometry(rig, n: int = 25):
    """``(surfaces, lines)`` of a rig's envelope, jaw frame, mm: surfaces ``(n, n, 3)`` (the shield's
    faces; none for an NLPCA rig) and lines ``(m, 3)`` (border curves or range boundaries)."""
    from facesim.jaw.posselt import PosseltRig

    if isinstance(rig, PosseltRig):
        c = np.linspace(0.0, 1.0, n)
        a, b = np.meshgrid(c, c, indexing="ij")
        surfaces = []
        for axis in range(3):
            for value in (0.0, 1.0):
                s = np.empty((n, n, 3))
                s[..., axis] = value
                s[..., [k for k in range(3) if k != axis]] = np.stack([a, b], -1)
                surfaces.append(rig.shield.point(s))
        # the six border curves, and the sections at tooth contact (s_y = 0) and at the maximum
        # opening (s_y = 1) along their posterior and anterior edges
        rings = [rig.shield.point(np.c_[c, np.full(n, sy), np.full(n, sz)]) for sy in (0.0, 1.0) for sz in (0.0, 1.0)]
        return surfaces, list(rig.shield.curves) + rings
    d1 = np.linspace(rig.grid[0], rig.grid[-1], 40)
    lo, hi = rig.ranges(d1)
    lines = []
    for t in np.linspace(0.0, 1.0, 7):
        for u in np.linspace(0.0, 1.0, 7):
            if 0.0 < t < 1.0 and 0.0 < u < 1.0:
                continue
            d = np.c_[d1, lo[:, 0] + t * (hi[:, 0] - lo[:, 0]), lo[:, 1] + u * (hi[:, 1] - lo[:, 1])]
            lines.append(rig.frame.pose_to_local(rig.transform(d))[:, :3, 3])
    return [], lines


def envelope_figure(rig, path, data=None, title: str = "", compare=None, compare_label: str = "",
                    dpi: int = 120) -> Path:
    """Write a PNG of the envelope of ``rig`` (Posselt or NLPCA) to ``path``.

    data : (N, 4, 4) poses whose reference points are drawn (red dots), or None.
    compare : (6, K, 3) border curves in the rig's jaw frame drawn dashed (``compare_label`` in
        the legend), or None.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facesim._files import atomic_write

    surfaces, lines = _envelope_geometry(rig)
    points = None if data is None else rig.frame.pose_to_local(np.asarray(data, dtype=np.float64))[:, :3, 3]
    fig = plt.figure(figsize=(15, 5.4))
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    for P in surfaces:
        ax3.plot_surface(P[..., 0], P[..., 2], P[..., 1], alpha=0.25, color="tab:blue", linewidth=0)
    views = [fig.add_subplot(1, 3, 2), fig.add_subplot(1, 3, 3)]
    for k, line in enumerate(lines):
        label = "envelope" if k == 0 else None
        ax3.plot(line[:, 0], line[:, 2], line[:, 1], color="navy", linewidth=1.2)
        views[0].plot(line[:, 2], line[:, 1], color="navy", linewidth=1.2, label=label)
        views[1].plot(line[:, 0], line[:, 1], color="navy", linewidth=1.2, label=label)
    if compare is not None:
        for k, line in enumerate(np.asarray(compare, dtype=np.float64)):
            label = compare_label or "compared" if k == 0 else None
            views[0].plot(line[:, 2], line[:, 1], color="tab:orange", linestyle="--", linewidth=1.2, label=label)
            views[1].plot(line[:, 0], line[:, 1], color="tab:orange", linestyle="--", linewidth=1.2, label=label)
    if points is not None:
        ax3.scatter(points[:, 0], points[:, 2], points[:, 1], s=2, color="tab:red", alpha=0.4)
        views[0].scatter(points[:, 2], points[:, 1], s=1, color="tab:red", alpha=0.3, label="data")
        views[1].scatter(points[:, 0], points[:, 1], s=1, color="tab:red", alpha=0.3, label="data")
    ax3.set_xlabel("x, left (mm)")
    ax3.set_ylabel("z, forward (mm)")
    ax3.set_zlabel("y, up (mm)")
    for ax, (xlabel, name) in zip(views, (("z, forward (mm)", "sagittal"), ("x, left (mm)", "frontal"))):
        ax.set_xlabel(xlabel)
        ax.set_ylabel("y, up (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{name} view")
        ax.grid(alpha=0.3)
    views[0].legend(loc="lower left", fontsize=8, markerscale=4)
    fig.suptitle(title)
    fig.tight_layout()
    path = atomic_write(Path(path), lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))
    plt.close(fig)
    return path


__all__ = ["envelope_figure"]
