"""The jaw opens with the sliding-condyle model, then a ball presses into the smiling cheek.

Drives a :class:`facesim.Simulation` frame by frame on the shipped coarse face:

1. the mouth opens to the maximum along the natural path of the sliding-condyle jaw (pure
   rotation for the first ~18 mm at the incisors, then the condyles slide down their tracks),
   and closes again;
2. the face smiles (zygomaticus major and minor, risorius) while a rigid ball of radius 12 mm
   comes in along the normal of the left cheek, presses 10 mm into it, and leaves.

Lips are kept out of the teeth and out of each other (teeth and lip contact). Every frame is
rendered (three-quarter view, the ball drawn in blue) into ``OUT/png/``, and the frames into
``OUT/video.mp4`` (or ``video.gif`` without imageio-ffmpeg). A table of what the solver did
per frame is printed and written to ``OUT/frames.csv``.

    python examples/02_jaw_and_contact.py --out jaw_and_contact/ [--frames 30] [--size 480]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from facesim import Simulation, load_model
from facesim.contact import Collider, KinematicPath, Sphere
from facesim.model import signed_volumes

SMILE = {"zygomaticus_major": 1.0, "zygomaticus_minor": 0.4, "risorius": 0.5}
BALL_RADIUS = 12.0   # mm
PRESS = 10.0         # mm into the cheek


def script(n_frames: int, max_opening: float, press: float = PRESS):
    """Per frame: (opening rad, smile level, ball depth into the cheek mm; negative = away)."""
    n_open = max(3, round(0.45 * n_frames))   # open and close
    n_press = n_frames - n_open
    half = n_open // 2 + 1
    opening = np.r_[np.linspace(0.0, max_opening, half), np.linspace(max_opening, 0.0, n_open - half + 2)[1:-1],
                    np.zeros(n_press)][:n_frames]
    smile = np.r_[np.zeros(n_open), np.clip(np.linspace(0.0, 2.0, n_press), 0.0, 1.0)]   # ramp, hold
    # the ball: from 20 mm away to ``press`` mm deep, held, then out to 40 mm away
    t = np.linspace(0.0, 1.0, n_press)
    depth = np.r_[np.full(n_open, -40.0), np.interp(t, [0.0, 0.6, 0.75, 1.0], [-20.0, press, press, -40.0])]
    return opening, smile, depth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="jaw_and_contact", help="output folder")
    ap.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "meshes" / "face_coarse.npz"))
    ap.add_argument("--frames", type=int, default=30, help="number of frames (>= 6)")
    ap.add_argument("--max-opening", type=float, default=None,
                    help="largest opening angle, rad (default: the model's maximum)")
    ap.add_argument("--press", type=float, default=PRESS, help="how deep the ball presses into the cheek, mm")
    ap.add_argument("--size", type=int, default=480, help="picture size in pixels (square)")
    ap.add_argument("--fps", type=float, default=10.0, help="frame rate of the video")
    ap.add_argument("--no-lip-contact", action="store_true", help="let the lips pass through each other")
    args = ap.parse_args(argv)
    if args.frames < 6:
        ap.error("--frames: expected at least 6")
    from facesim.viz.render import render_model
    from facesim.viz.video import write_video

    model = load_model(args.model)
    out = Path(args.out)
    (out / "png").mkdir(parents=True, exist_ok=True)
    max_opening = model.jaw.max_opening if args.max_opening is None else args.max_opening
    opening, smile, depth = script(args.frames, max_opening, args.press)

    # the ball moves along the outward normal of the left cheek
    cheek = model.marker_positions()[list(model.markers.names).index("cheek_mid_L")]
    normal = np.array([0.6, 0.0, 0.8])
    centres = cheek[None] + (BALL_RADIUS - depth)[:, None] * normal
    ball = KinematicPath.from_centres(Collider(Sphere((0.0, 0.0, 0.0), BALL_RADIUS), name="ball"),
                                      np.arange(args.frames), centres)
    sim = Simulation(model, jaw_model="sliding-condyle", colliders=[ball], teeth_contact=True,
                     lip_contact=not args.no_lip_contact)
    jaw = sim.jaw_model

    rows, pngs = [], []
    header = ("frame", "opening_rad", "slide_mm", "smile", "ball_depth_mm", "converged", "iterations",
              "penetration_mm", "inverted_tets", "seconds")
    print(" ".join(f"{h:>14}" for h in header), flush=True)
    for k in range(args.frames):
        p = jaw.natural_parameters(opening[k])
        f = sim.step({name: level * smile[k] for name, level in SMILE.items()}, jaw=p, frame=k)
        inverted = int((signed_volumes(f.x, model.tets)[model.simulated] <= 0).sum())
        row = (k, round(float(opening[k]), 4), round(float(p[1]), 3), round(float(smile[k]), 3),
               round(float(depth[k]), 2), int(f.converged), f.iterations, round(f.penetration, 4), inverted,
               round(f.seconds, 2))
        rows.append(row)
        print(" ".join(f"{v:>14}" for v in row), flush=True)
        png = out / "png" / f"frame_{k:05d}.png"
        render_model(model, png, view="three_quarter", show=("skin", "bones", "colliders"), skin_opacity=1.0,
                     size=(args.size, args.size), x=f.x, legend=False, frame_on=model.X,
                     title=f"frame {k}: opening {np.degrees(opening[k]):4.1f} deg, smile {smile[k]:.1f}",
                     extra=[c.surface() for c in f.colliders])
        pngs.append(png)
    with open(out / "frames.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    video, note = write_video(pngs, out, args.fps)
    print(f"{sum(r[5] for r in rows)} of {len(rows)} frames converged; worst penetration "
          f"{max(r[7] for r in rows):.3f} mm; inverted tets at most {max(r[8] for r in rows)}; video {video}"
          + (f" ({note})" if note else ""))
    return rows


if __name__ == "__main__":
    main()
