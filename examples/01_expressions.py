"""Named expressions on the shipped coarse face, rendered as a contact sheet.

Solves the quasistatic equilibrium for a few expressions (smile, frown, pucker, brow raise,
jaw open, sneer) from the rest shape with the default AMG-preconditioned Newton solver, prints
each solve's Newton iterations, residual and time, and writes `expressions.png` (front views,
opaque skin) plus one `<name>.png` per expression.

    python examples/01_expressions.py --out expressions/ [--model M.npz] [--size 480]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from facesim.controls import Controls
from facesim.kinematics.jaw_models import RigidJaw
from facesim.fem.equilibrium import FaceSimulator
from facesim.model import load_model

#: expression -> {muscle base name (both sides): activation}, optional jaw (opening rad, slide mm)
EXPRESSIONS = {
    "rest": ({}, None),
    "smile": ({"zygomaticus_major": 1.0, "zygomaticus_minor": 0.4, "risorius": 0.5, "orbicularis_oculi": 0.3}, None),
    "frown": ({"depressor_anguli_oris": 1.0, "depressor_labii_inferioris": 0.5, "mentalis": 0.6,
               "corrugator_supercilii": 0.8}, None),
    "pucker": ({"orbicularis_oris_upper": 1.0, "orbicularis_oris_lower": 1.0, "mentalis": 0.3}, None),
    "brow_raise": ({"frontalis": 1.0}, None),
    "sneer": ({"levator_labii_superioris_alaeque_nasi": 1.0, "levator_labii_superioris": 0.8, "procerus": 0.6}, None),
    "jaw_open": ({}, (0.2, 4.0)),
}


def activations(model, spec: dict) -> np.ndarray:
    a = np.zeros(model.n_muscles)
    for base, value in spec.items():
        hits = [i for i, n in enumerate(model.muscles.names) if n.rsplit("_", 1)[0] == base]
        if not hits:
            raise SystemExit(f"unknown muscle {base!r}")
        a[hits] = value
    return a


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="expressions", help="output folder")
    ap.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "meshes" / "face_coarse.npz"))
    ap.add_argument("--size", type=int, default=480, help="picture size in pixels (square)")
    ap.add_argument("--only", nargs="*", help="solve only these expressions")
    args = ap.parse_args(argv)
    from facesim.viz.render import render_image, save_png as _save_png, tile_images

    model = load_model(args.model)
    sim = FaceSimulator(model)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pictures, results = [], {}
    for name, (spec, jaw) in EXPRESSIONS.items():
        if args.only and name not in args.only:
            continue
        T = None if jaw is None else RigidJaw.from_rotation(model, jaw[0], translation=jaw[1] * model.jaw.track_direction)
        t = time.perf_counter()
        eq = sim.equilibrium(Controls(activations(model, spec), jaw=T))
        r = eq.report
        moved = np.linalg.norm(model.marker_positions(eq.x) - model.marker_positions(), axis=1).max()
        print(f"{name:>10}: converged {r.converged}, {r.iterations} Newton iterations, relative residual "
              f"{r.relative_residual:.1e}, max marker motion {moved:5.1f} mm, {time.perf_counter() - t:5.1f} s")
        results[name] = eq
        img = render_image(model, "front", show=("skin", "markers"), skin_opacity=1.0, size=(args.size, args.size),
                           x=eq.x, legend=False, title=name.replace("_", " "))
        _save_png(img, out / f"{name}.png")
        pictures.append(img)
    sheet = _save_png(tile_images(pictures), out / "expressions.png")
    print(f"wrote {sheet}")
    return results


if __name__ == "__main__":
    main()
