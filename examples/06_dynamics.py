"""A quick head shake with softened nose tissue: quasistatic against dynamic (issue 18).

The coarse face at rest is shaken (yaw 10 deg x sin^3(2 pi 3 t), starting from rest) with its
nose cartilage softened to 0.2 of its stiffness. Quasistatically the face just turns with the
skull (the flesh energy does not see a rigid motion); dynamically (``facesim.fem.dynamics``: BDF2,
lumped mass, Rayleigh damping) the soft nose lags and overshoots -- Sifakis et al. 2005's ballistic
example. The nose tip's path in the head frame is plotted for both (``nose_path.png``), the
largest difference printed, and the dynamic face rendered frame by frame into a short video
(``video.mp4``, or ``video.gif`` without imageio-ffmpeg, at a quarter speed).

    python examples/06_dynamics.py --out dynamics/ [--frames 12] [--substeps 4] [--size 320] [--no-video]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.controls import Controls, rotation_about
from facesim.fem.dynamics import DynamicsOptions, DynamicSimulator, DynamicState
from facesim.fem.equilibrium import EquilibriumOptions
from facesim.model import load_model

FPS = 24.0


def shake(model, n: int, degrees: float = 10.0, hz: float = 3.0) -> list[Controls]:
    """Rest activations and jaw, the skull yawing about the condyle midpoint, frames 0..n."""
    centre = model.jaw.midpoint
    out = []
    for k in range(n + 1):
        yaw = np.radians(degrees) * np.sin(2 * np.pi * hz * k / FPS) ** 3
        out.append(Controls(np.zeros(model.n_muscles), jaw=[0.0, 0.0, 0.0], head=rotation_about([0.0, yaw, 0.0], centre)))
    return out


def nose_tip_in_head_frame(model, x, head) -> np.ndarray:
    """The nose-tip marker (mm) moved back into the head frame by the inverse of ``head``."""
    p = model.marker_positions(x)[model.markers.names.index("nose_tip")]
    Hi = np.linalg.inv(head)
    return Hi[:3, :3] @ p + Hi[:3, 3]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="dynamics", help="output folder")
    ap.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "meshes" / "face_coarse.npz"))
    ap.add_argument("--frames", type=int, default=12, help="frames at 24 fps")
    ap.add_argument("--substeps", type=int, default=4, help="time steps per frame")
    ap.add_argument("--size", type=int, default=320, help="video size in pixels (square)")
    ap.add_argument("--no-video", action="store_true", help="skip the video")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model = load_model(args.model)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    controls = shake(model, args.frames)
    dyn = DynamicSimulator(model, EquilibriumOptions(), jaw_model="sliding-condyle",
                           dynamics=DynamicsOptions(soften=("nose:0.2",), substeps=args.substeps))
    sim, m = dyn.sim, dyn.model
    eq = sim.equilibrium(controls[0])
    state = DynamicState.at_rest(eq.x, eq.controls)
    qs, dy, xs, x = [nose_tip_in_head_frame(m, eq.x, controls[0].head)], [], [state.x], eq.x
    dy.append(qs[0])
    t0 = time.perf_counter()
    for k, c in enumerate(controls[1:], start=1):
        x = sim.equilibrium(c, x0=x).x
        qs.append(nose_tip_in_head_frame(m, x, c.head))
        state, report = dyn.advance(state, c, 1.0 / FPS, substeps=args.substeps)
        dy.append(nose_tip_in_head_frame(m, state.x, c.head))
        xs.append(state.x)
        print(f"frame {k:2d}: dynamic converged {report.converged}, {report.iterations} Newton iterations, "
              f"kinetic energy {report.kinetic_energy:.3g} mJ, nose tip {np.linalg.norm(dy[-1] - qs[-1]):.2f} mm "
              f"from the quasistatic one")
    qs, dy = np.array(qs), np.array(dy)
    gap = float(np.linalg.norm(dy - qs, axis=1).max())
    print(f"{args.frames} frames in {time.perf_counter() - t0:.1f} s; largest nose-tip difference {gap:.2f} mm")
    t = np.arange(len(qs)) / FPS
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, axis in enumerate("xyz"):
        ax.plot(t, qs[:, i] - qs[0, i], "--", color=f"C{i}", label=f"{axis} quasistatic")
        ax.plot(t, dy[:, i] - qs[0, i], "-", color=f"C{i}", label=f"{axis} dynamic")
    ax.set_xlabel("time, s")
    ax.set_ylabel("nose tip in the head frame, mm")
    ax.set_title("head shake 10 deg at 3 Hz, nose cartilage softened to 0.2")
    ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(out / "nose_path.png", dpi=120)
    plt.close(fig)
    video = None
    if not args.no_video:
        from facesim.viz.render import render_image, save_png
        from facesim.viz.video import write_video

        (out / "frames").mkdir(exist_ok=True)
        pngs = [save_png(render_image(m, "three_quarter", show=("skin",), skin_opacity=1.0,
                                      size=(args.size, args.size), x=x_k, legend=False, title=f"t = {k / FPS:.2f} s"),
                         out / "frames" / f"frame_{k:05d}.png") for k, x_k in enumerate(xs)]
        video, note = write_video(pngs, out, fps=FPS / 4)   # a quarter speed
        print(f"wrote {video}" + (f" ({note})" if note else ""))
    return {"quasistatic": qs, "dynamic": dy, "gap_mm": gap, "video": video}


if __name__ == "__main__":
    main()
