"""Teeth tracking from multi-view images to a 3-parameter jaw rig (Yang et al. 2018, issue 19).

1. Render a synthetic 3-camera capture of the shipped teeth (``facesim teeth render``): a stretch of
   a generated jaw session, image noise, blur, procedural lips whose opening follows the jaw.
2. Track the upper (head) and lower (jaw) teeth by their silhouettes (``facesim teeth track``).
3. Fit the hierarchical NLPCA rig to the tracked poses (``facesim jaw fit --rig nlpca``).
4. Print the tracking error (mm at the lower incisal point, degrees) and the rig's reconstruction
   error against the TRUE poses, next to Yang et al.'s 1.73 mm mean / 7.2 mm max (833 poses), and
   save ``teeth_tracking.png``: a frame with the tracked silhouette over it, and the error per frame.

    python examples/07_teeth_tracking.py --out OUT [--size 1280x720] [--frames 120] [--every 4]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: Yang et al. 2018: reconstruction error of the fitted 3-parameter model over 833 poses, mm.
PAPER = {"mean": 1.73, "max": 7.2}


def pose_errors(A, B, point):
    """``(mm (N,), degrees (N,))`` between pose stacks ``A`` and ``B`` (N, 4, 4) at ``point (3,)``."""
    from facesim import se3

    mm = np.linalg.norm(se3.transform_points(A, point[None])[:, 0] - se3.transform_points(B, point[None])[:, 0], axis=1)
    R = np.einsum("nji,njk->nik", A[:, :3, :3], B[:, :3, :3])
    deg = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return mm, deg


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="teeth_tracking", help="output folder")
    ap.add_argument("--size", default="1280x720", help="image size WxH")
    ap.add_argument("--frames", type=int, default=120, help="frames of the capture")
    ap.add_argument("--every", type=int, default=4, help="every K-th frame of the 30 fps session")
    ap.add_argument("--start", type=int, default=0, help="first session frame")
    ap.add_argument("--iterations", type=int, default=1000, help="NLPCA training iterations")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from facesim.cli import main as facesim
    from facesim.jaw.cli import read_poses
    from facesim.jaw.motion import JawMotion
    from facesim.jaw.nlpca import fit_nlpca

    s = JawMotion().session(seed=0)
    idx = np.arange(args.start, len(s.poses), args.every)[:args.frames]
    np.savez(out / "session.npz", poses=s.poses[idx], reference_point=s.reference_point)
    cap = out / "capture"
    assert facesim(["teeth", "render", "-o", str(cap), "--poses", str(out / "session.npz"), "--every", "1",
                    "--size", args.size, "-q"]) == 0
    assert facesim(["teeth", "track", "--cameras", str(cap / "cameras.json"), "--images", str(cap),
                    "-o", str(out / "tracked.npz"), "-q"]) == 0
    tracked = read_poses(out / "tracked.npz")
    data = np.load(out / "tracked.npz")
    truth = np.load(cap / "truth.npz")["poses"]
    ref = tracked.reference_point
    mm, deg = pose_errors(tracked.poses, truth, ref)
    ok = ~data["flagged"]
    print(f"tracking ({len(mm)} frames, {int((~ok).sum())} flagged and held): incisor error mean {mm.mean():.3f} mm "
          f"(max {mm.max():.3f}), {deg.mean():.3f} deg (max {deg.max():.3f}); trusted frames only: mean "
          f"{mm[ok].mean():.3f} mm, max {mm[ok].max():.3f} mm")
    rig = None
    if len(tracked.poses) >= 10:
        from facesim.jaw.frame import JawFrame

        frame = JawFrame.from_poses(tracked.poses[ok], ref)
        rig = fit_nlpca(tracked.poses[ok], frame, points=tracked.mandible, iterations=args.iterations)
        rec = rig.reproduce(truth)
        if len(rec):
            e_rig, _ = pose_errors(rec, truth, ref)
            print(f"NLPCA rig fitted to the tracked poses, reconstructing the TRUE poses at the incisor: mean "
                  f"{e_rig.mean():.3f} mm, max {e_rig.max():.3f} mm (Yang et al. 2018: {PAPER['mean']} mm mean, "
                  f"{PAPER['max']} mm max over 833 poses)")
    _figure(out, cap, tracked, data, mm)
    return {"mm": mm, "deg": deg, "flagged": data["flagged"], "rig": rig}


def _figure(out, cap, tracked, data, mm):
    """teeth_tracking.png: the centre camera's frame with the tracked silhouette's outline, and the
    error per frame."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facesim.teeth.cameras import read_cameras
    from facesim.teeth.dentition import shipped_dentition
    from facesim.teeth.silhouette import Model
    from facesim.teeth.raster import render_ids

    cam = read_cameras(cap / "cameras.json")[0]
    f = int(np.argmax(np.where(data["flagged"], -1, mm * 0 + np.arange(len(mm)) % 7)))   # a trusted frame
    img = cv2.imread(str(cap / cam.name / f"frame_{f:05d}.png"))[..., ::-1].copy()
    model = Model(shipped_dentition())
    V = model.posed(data["head"][f], data["head"][f] @ tracked.poses[f])
    _, ids = render_ids(cam, V, model.F)
    edge = (ids >= 0) & ~(cv2.erode((ids >= 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    img[edge] = (0, 255, 0)
    fig, ax = plt.subplots(1, 2, figsize=(13, 4.2))
    ax[0].imshow(img)
    ax[0].set_title(f"frame {f}, camera {cam.name}: tracked silhouette (green)")
    ax[0].axis("off")
    ax[1].plot(mm, ".-", label="incisor error, mm")
    fl = np.nonzero(data["flagged"])[0]
    ax[1].plot(fl, mm[fl], "rx", label="flagged (held)")
    ax[1].set_xlabel("frame")
    ax[1].set_ylabel("mm")
    ax[1].legend()
    ax[1].set_title("tracking error at the lower incisal point")
    fig.tight_layout()
    fig.savefig(out / "teeth_tracking.png", dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
