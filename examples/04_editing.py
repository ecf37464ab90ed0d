"""Editing in activation space (Sifakis et al. 2005, section 9) on the shipped coarse face.

Two expressions (a smile and a frown with the jaw a little open) are blended in activation space
(``facesim.anim.blend``): every in-between is the equilibrium of interpolated controls, so it is
physically attainable -- an interpolated expression sheet. Then the smile is exaggerated two ways,
side by side as in the paper's Fig. 8: by scaling its activations (clamped to [0, 1], so the
zygomaticus cannot go beyond 1) and by the force-length gain (``facesim.anim.gain``: 1, 2, 4 --
beyond what activation 1 can do). Prints each frame's Newton iterations and its mouth-corner motion
and writes ``blend.png`` and ``exaggeration.png``.

    python examples/04_editing.py --out editing/ [--model M.npz] [--size 320] [--steps 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.anim import ControlsSequence, blend, gain, scale
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
    return results


if __name__ == "__main__":
    main()
