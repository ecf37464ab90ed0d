"""Plots of a solved capture (matplotlib, written as PNG): activation curves per muscle group and
the marker residual per frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesim._files import atomic_write

GROUPS = {
    "brow": ("frontalis", "corrugator", "procerus"),
    "eyes": ("orbicularis_oculi",),
    "upper lip and cheek": ("levator", "zygomaticus", "risorius", "buccinator"),
    "lower lip and chin": ("depressor", "mentalis"),
    "lips": ("orbicularis_oris",),
}


def plot_track(out_dir) -> list[Path]:
    """``activations.png`` and ``residuals.png`` from the CSV files a
    :func:`~facesim.inverse.tracking.track` run wrote."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    A = np.genfromtxt(out / "activations.csv", delimiter=",", names=True)
    R = np.genfromtxt(out / "residuals.csv", delimiter=",", names=True)
    A, R = np.atleast_1d(A), np.atleast_1d(R)
    muscles = [n for n in A.dtype.names if n != "frame"]
    fig, axes = plt.subplots(len(GROUPS), 1, figsize=(9, 2.0 * len(GROUPS)), sharex=True)
    for ax, (group, stems) in zip(axes, GROUPS.items()):
        for m in muscles:
            if any(m.startswith(s) for s in stems):
                ax.plot(A["frame"], A[m], label=m, lw=1.2)
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel("activation")
        ax.set_title(group, fontsize=9, loc="left")
        if ax.lines:
            ax.legend(fontsize=6, ncol=3, loc="upper right")
    axes[-1].set_xlabel("frame")
    fig.tight_layout()
    paths = [atomic_write(out / "activations.png", lambda tmp: fig.savefig(tmp, dpi=110))]
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 3))
    markers = np.array([[r[n] for n in R.dtype.names[2:]] for r in R])
    ax.plot(R["frame"], R["rms"], "k-", lw=1.5, label="RMS over markers")
    if markers.size:
        ax.plot(R["frame"], np.nanmax(markers, axis=1), "r:", lw=1, label="worst marker")
    ax.set_xlabel("frame")
    ax.set_ylabel("marker distance (mm)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(atomic_write(out / "residuals.png", lambda tmp: fig.savefig(tmp, dpi=110)))
    plt.close(fig)
    return paths
