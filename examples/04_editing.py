"""Editing in activation space (Sifakis et al. 2005, section 9) on the shipped coarse face.

Two expressions (a smile and a frown with the jaw a little open) are blended in activation space
(``facesim.anim.blend``): every in-between is the equilibrium of interpolated controls, so it is
physically attainable -- an interpolated expression sheet. Then the smile is exaggerated two ways,
side by side as in the paper's Fig. 8: by scaling its activations (clamped to [0, 1], so the
zygomaticus cannot go beyond 1) and by the force-length gain (``facesim.anim.gain``: 1, 2, 4 --
beyond what activation 1 can do). Last, two performances are spliced (``facesim.anim.splice``): a
smile that builds up, cut into a frown that opens the jaw, with a cross-fade at the join; each frame
solved warm-started from the one before. Prints each frame's Newton iterations and its mouth-corner
motion and writes ``blend.png``, ``exaggeration.png`` and ``splice.png`` (the controls and the
corners' motion over the spliced frames, and a film strip of them).

    python examples/04_editing.py --out editing/ [--model M.npz] [--size 320] [--steps 5] [--splice-frames 12]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.anim import ControlsSequence, blend, gain, keyframes, scale, splice
from facesim.controls import Controls
from facesim.fem.equilibrium import FaceSimulator
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.model import load_model

SMILE = {"zygomaticus_major": 0.5, "zygomaticus_minor": 0.3, "risorius": 0.3}
FROWN = {"depressor_anguli_oris": 0.8, "mentalis": 0.5, "corrugator_supercilii": 0.6}


def expression(model, spec: dict, opening: float = 0.0) -> ControlsSequence:
    a = np.zeros(model.n_muscles)
    for base, value in spec.items():
        a[[i for i, n in enumerate(model.muscles.names) if n.rsplit("_", 1)[0] == base]] = value
    return ControlsSequence.of(model, a[None], jaw=np.array([[opening, 0.0, 0.0]]), jaw_model="sliding-condyle")


def corner_motion(model, x) -> float:
    """Mean displacement (mm) of the two mouth-corner markers."""
    idx = [i for i, n in enumerate(model.markers.names) if n.startswith("mouth_corner")]
    return float(np.linalg.norm(model.marker_positions(x)[idx] - model.marker_positions()[idx], axis=1).mean())


def solve(sim, seq: ControlsSequence, k: int = 0, x0=None):
    """The equilibrium of frame ``k`` of ``seq`` with its gains."""
    s = sim if np.all(seq.gain == 1.0) else sim.with_gain(seq.gain)
    return s.equilibrium(Controls(seq.A[k], jaw=seq.jaw[k]), x0=x0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="editing", help="output folder")
    ap.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "meshes" / "face_coarse.npz"))
    ap.add_argument("--size", type=int, default=320, help="picture size in pixels (square)")
    ap.add_argument("--steps", type=int, default=5, help="in-betweens of the blend, ends included")
    ap.add_argument("--splice-frames", type=int, default=12, help="frames of each spliced performance (>= 6)")
    args = ap.parse_args(argv)
    from facesim.viz.render import render_image, save_png, tile_images

    model = load_model(args.model)
    sim = FaceSimulator(model, jaw_model=SlidingCondyleJaw(model.jaw))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def picture(x, title):
        return render_image(model, "front", show=("skin",), skin_opacity=1.0, size=(args.size, args.size), x=x,
                            legend=False, title=title)

    results = {"blend": [], "scale": [], "gain": []}
    smile, frown = expression(model, SMILE), expression(model, FROWN, opening=0.1)
    sheet, x = [], None
    for k, t in enumerate(np.linspace(0.0, 1.0, args.steps)):
        t0 = time.perf_counter()
        eq = solve(sim, blend(smile, frown, float(t)), x0=x)
        x = eq.x
        results["blend"].append(eq)
        print(f"blend t={t:.2f}: converged {eq.converged}, {eq.report.iterations} Newton iterations, mouth corners moved "
              f"{corner_motion(model, eq.x):.2f} mm, {time.perf_counter() - t0:.1f} s")
        sheet.append(picture(eq.x, f"t = {t:.2f}"))
    print(f"wrote {save_png(tile_images(sheet), out / 'blend.png')}")
    sheet = []
    for factor in (1.0, 2.0, 4.0):   # activations times 1, 2, 4, clamped to [0, 1]
        eq = solve(sim, scale(smile, factor))
        results["scale"].append(eq)
        print(f"scale {factor:g}: mouth corners moved {corner_motion(model, eq.x):.2f} mm")
        sheet.append(picture(eq.x, f"activation x{factor:g}"))
    for factor in (1.0, 2.0, 4.0):   # the force-length curves times 1, 2, 4 at the smile's activations x 2
        eq = solve(sim, gain(scale(smile, 2.0), factor))
        results["gain"].append(eq)
        print(f"gain {factor:g}: mouth corners moved {corner_motion(model, eq.x):.2f} mm")
        sheet.append(picture(eq.x, f"gain x{factor:g}"))
    print(f"wrote {save_png(tile_images(sheet), out / 'exaggeration.png')}")
    results["splice"], seq = spliced(model, sim, args.splice_frames, out, picture)
    results["splice_sequence"] = seq
    return results


def spliced(model, sim, n: int, out: Path, picture):
    """Two keyframed performances of ``n`` frames spliced at frame ``n // 2`` with a cross-fade of
    ``n // 4`` frames; every frame solved (warm start: the frame before); ``splice.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(int(n), 6)
    rest = expression(model, {})
    build_up = keyframes([rest, expression(model, SMILE), scale(expression(model, SMILE), 1.6)], [0, n // 2, n - 1],
                         method="smoothstep")
    opening = keyframes([expression(model, SMILE), expression(model, FROWN, opening=0.15), expression(model, FROWN)],
                        [0, n // 2, n - 1], method="catmull-rom")
    at, fade = n // 2, max(n // 4, 1)
    seq = splice(build_up, opening, at=at, crossfade=fade)
    eqs, x, strip = [], None, []
    for k in range(seq.n_frames):
        t0 = time.perf_counter()
        eq = solve(sim, seq, k, x0=x)
        x = eq.x if eq.converged else x
        eqs.append(eq)
        print(f"splice frame {seq.frames[k]}: converged {eq.converged}, {eq.report.iterations} Newton iterations, "
              f"mouth corners moved {corner_motion(model, eq.x):.2f} mm, {time.perf_counter() - t0:.1f} s")
    for k in np.unique(np.linspace(0, seq.n_frames - 1, 6).round().astype(int)):
        strip.append(picture(eqs[k].x, f"frame {seq.frames[k]}"))
    from facesim.viz.render import save_png, tile_images

    save_png(tile_images(strip), out / "splice_strip.png")
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    f = seq.frames
    for base, style in (("zygomaticus_major", "-"), ("depressor_anguli_oris", "--"), ("mentalis", ":")):
        i = [j for j, name in enumerate(model.muscles.names) if name.rsplit("_", 1)[0] == base][0]
        top.plot(f, seq.A[:, i], style, label=base.replace("_", " "))
    top.plot(f, seq.jaw[:, 0] / 0.15, "k-.", label="jaw opening / 0.15 rad")
    for ax in (top, bottom):
        ax.axvspan(at - 0.5, at + fade - 0.5, color="0.9", zorder=0)
        ax.axvline(at - 0.5, color="0.5", lw=0.8)
    top.set_ylabel("activation")
    top.set_title("spliced: smile building up | frown opening the jaw (grey: cross-fade)")
    top.legend(fontsize=8, loc="upper left")
    bottom.plot(f, [corner_motion(model, eq.x) for eq in eqs], "o-", ms=3)
    bottom.set_ylabel("mouth corners moved, mm")
    bottom.set_xlabel("frame")
    fig.tight_layout()
    fig.savefig(out / "splice.png", dpi=110)
    plt.close(fig)
    print(f"wrote {out / 'splice.png'} and {out / 'splice_strip.png'}")
    return eqs, seq


if __name__ == "__main__":
    main()
