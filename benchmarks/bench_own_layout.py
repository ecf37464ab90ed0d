"""A capture with its own marker layout against the model's own markers (issue 15, part 1).

    NUMBA_NUM_THREADS=2 python benchmarks/bench_own_layout.py [--frames 30] [--out /tmp/own_layout]

The capture is made here, independently of ``facesim.mocap.layout``: the demo's performance
(activations and sliding-condyle jaw per frame from ``meshes/demo_clip_truth.npz``: its 6
neutral frames, then ``--frames`` frames evenly spread over the rest of the clip) is simulated
again on the MEDIUM face (the truth file keeps markers, not equilibria; the re-simulated model
markers are checked against the stored ones). Two captures of that one performance:

* **own layout**: 50 skin points chosen by a rule of this script (seeded random skin triangles
  facing forward, in front of the ears, above the chin, below the hairline, away from the
  eyes; Dirichlet barycentric points), carried by their triangles through the deformed skin,
  and a 4-marker headband rigid with the skull 15 mm off the skin (two high on the forehead, two
  on the temples); named p00..p49 and
  hb0..hb3 (no name in common with the model); a known head motion (up to ~2.3 deg, ~4 mm);
  0.3 mm noise per axis; gaps (runs and drop-outs, NaN); moved into a capture frame (z up,
  x forward, turned 25 deg about z, 1-2 m from the origin) and written as a TRC in metres.
  Solved with ``--layout capture --head-markers hb0,hb1,hb2,hb3 --bind-frames 0:5``.
* **model layout**: the medium face's own 81 markers through the same head motion, noise level
  and gap rule, in the model's frame, mm, with the model's names; solved with
  ``--bind-frames 0:5`` (the model's markers rebound to the neutral frames, as the demo does).

Both are solved on the COARSE face through ``facesim.cli.main`` with the same options
(sliding-condyle jaw, ``--no-contact`` as the demo solves, ``--noise 0.3``,
``--head-smoothing 5``) and scored against the truth: marker RMS (the solve's own residual
RMS, mm), per driven muscle (true activation > 0.05 somewhere in the frames) Pearson
correlation of the solved and true activation curves and mean absolute error, the mean absolute
error over the muscles the markers see (``facesim.demo.VISIBLE_MM``; procerus and the left
corrugator are driven but hardly move a marker, so their curves are not identifiable), the same
two over the driven muscles that are visible, and the jaw opening error.
For the own layout, also how far each placed marker's rest position on the coarse skin lands
from where the point was chosen on the medium face (registration + binding + mesh gap).
Benchmarks are not tests: nothing here is asserted.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import platform
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
MEDIUM, COARSE = ROOT / "meshes" / "face_medium.npz", ROOT / "meshes" / "face_coarse.npz"
TRUTH = ROOT / "meshes" / "demo_clip_truth.npz"
N_SKIN, HEADBAND_MM, NOISE_MM = 50, 15.0, 0.3
#: where the headband sits (mm, model frame): two high on the forehead, two on the temples, as a
#: band round the head does (four markers in a row across the forehead would leave the nod, the
#: rotation about their common line, to the noise)
HEADBAND_AT = np.array([[-22.0, 90.0, 80.0], [22.0, 90.0, 80.0], [-62.0, 62.0, 45.0], [62.0, 62.0, 45.0]])
#: the capture frame: model (x left, y up, z forward) -> capture (x forward, y left, z up), then
#: 25 deg about the capture's z, then 1-2 m off the capture's origin; metres on the file
TO_CAPTURE = Rotation.from_euler("z", 25, degrees=True).as_matrix() @ np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])
CAPTURE_ORIGIN_MM = np.array([1200.0, -450.0, 1550.0])


def _normals(X, S):
    n = np.cross(X[S[:, 1]] - X[S[:, 0]], X[S[:, 2]] - X[S[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def choose_layout(model, seed=0):
    """``(tri (50,), bary (50, 3), band (4, 3) mm)``: the skin points and the headband, model frame.

    Skin: triangles whose normal faces forward (n_z > 0.5), in front of the ears (centroid z > 40,
    |x| < 62), above the chin (y > -85), below the hairline (y < 72), more than 17 mm (in x, y)
    from either eye centre (+-33, 27) mm, drawn at random without two within 12 mm; Dirichlet(3, 3,
    3) barycentric points. Headband: the skin triangles nearest :data:`HEADBAND_AT`, their centres
    pushed 15 mm out along their normals."""
    rng = np.random.default_rng(seed)
    X, S = model.X, model.skin
    n, c = _normals(X, S), X[S].mean(axis=1)
    eye = np.array([[33.0, 27.0], [-33.0, 27.0]])
    away = np.min(np.linalg.norm(c[:, None, :2] - eye[None], axis=2), axis=1) > 17.0
    front = np.flatnonzero((n[:, 2] > 0.5) & (c[:, 2] > 40) & (np.abs(c[:, 0]) < 62) & (c[:, 1] > -85)
                           & (c[:, 1] < 72) & away)
    tri = []
    for t in rng.permutation(front):   # spread out: no two chosen points within 12 mm
        if all(np.linalg.norm(c[t] - c[u]) > 12.0 for u in tri):
            tri.append(t)
        if len(tri) == N_SKIN:
            break
    tri = np.array(tri)
    bary = rng.dirichlet([3.0, 3.0, 3.0], len(tri))
    band = []
    for target in HEADBAND_AT:   # the skin triangle nearest each spot, its centre pushed out along its normal
        t = int(np.argmin(np.linalg.norm(c - target, axis=1)))
        band.append(c[t] + HEADBAND_MM * n[t])
    return tri, bary, np.array(band)


def head_motion(centre, n_frames):
    """``(F, 3, 3), (F, 3)``: a known head motion about ``centre``: rotations up to ~2.3 deg (nod,
    turn, tilt at different rates), translations up to ~4 mm."""
    u = np.linspace(0.0, 1.0, n_frames)
    rotvec = np.c_[0.04 * np.sin(2 * np.pi * u), -0.025 * np.sin(2 * np.pi * 0.6 * u + 0.5), 0.015 * np.cos(5 * u)]
    R = Rotation.from_rotvec(rotvec).as_matrix()
    shift = np.c_[3.0 * np.sin(2 * np.pi * 0.4 * u), 2.0 * np.sin(3 * u), -2.5 * np.sin(2 * np.pi * 0.8 * u)]
    t = centre - np.einsum("fij,j->fi", R, centre) + shift
    return R, t


def spoil(clean, head, rng, n_neutral):
    """Noise (``NOISE_MM`` per axis) on every sample; gaps: one run of 2-5 frames per ~6 frames on
    a random skin marker after the neutral frames, and 0.5 % isolated drop-outs of skin markers."""
    F, r, _ = clean.shape
    skin = np.flatnonzero(~head)
    P = clean + rng.normal(0.0, NOISE_MM, clean.shape)
    gap = np.zeros((F, r), bool)
    for _ in range(max(1, F // 6)):
        length = int(rng.integers(2, 6))
        start = int(rng.integers(n_neutral, max(n_neutral + 1, F - length)))
        gap[start:start + length, rng.choice(skin)] = True
    k = max(1, round(0.005 * F * len(skin)))
    flat = rng.choice(F * len(skin), k, replace=False)
    gap[flat // len(skin), skin[flat % len(skin)]] = True
    P[gap] = np.nan
    return P, gap


def _unit_rows(b):
    """Barycentric rows read back from 6 significant digits, summing to 1 again."""
    return b / b.sum(axis=1, keepdims=True)


def _solve(argv, log):
    from facesim.cli import main

    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        code = main(argv)
    log.append(buf.getvalue())
    if code != 0:
        raise SystemExit(f"solve-mocap failed ({code}):\n{buf.getvalue()}")
    return time.perf_counter() - t0


def score(out, A_true, q_true, visible):
    """Marker RMS, per driven muscle correlation and mean abs error, visible-muscle error, jaw."""
    from facesim.framelog import read_log

    _, A = read_log(out / "activations.csv")
    _, J = read_log(out / "jaw.csv")
    _, R = read_log(out / "residuals.csv")
    with open(out / "frames.csv") as fh:
        converged = sum(r["converged"] in ("1", "True", "true") for r in csv.DictReader(fh))
    A, q = A[:, 1:], J[:, 1]
    driven = np.flatnonzero(A_true.max(axis=0) > 0.05)
    corr = np.array([np.corrcoef(A[:, i], A_true[:, i])[0, 1] for i in driven])
    mae = np.abs(A - A_true).mean(axis=0)
    seen = visible[driven]
    return {"rms_mean": float(np.nanmean(R[:, 1])), "rms_max": float(np.nanmax(R[:, 1])), "driven": driven,
            "corr": corr, "corr_visible": corr[seen], "mae_visible_driven": float(mae[driven][seen].mean()), "mae": mae[driven], "visible_mae": float(np.abs(A - A_true)[:, visible].mean()),
            "jaw_mean_deg": float(np.degrees(np.abs(q - q_true)).mean()),
            "jaw_max_deg": float(np.degrees(np.abs(q - q_true)).max()), "converged": converged, "frames": len(A)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=30, help="performance frames after the 6 neutral ones")
    ap.add_argument("--out", default="/tmp/own_layout", help="work folder (captures, solves)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--head", choices=("procrustes", "solve"), default="procrustes",
                    help="solve-mocap --head of both solves (procrustes with --head-smoothing 5)")
    args = ap.parse_args(argv)

    from facesim.demo import VISIBLE_MM, neutral_frames
    from facesim.mocap.io import write_trc
    from facesim.model import load_model
    from facesim.session import Simulation

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    truth = dict(np.load(TRUTH))
    n_clip = len(truth["frames"])
    hold = neutral_frames(n_clip)
    pick = np.r_[np.arange(hold), np.unique(np.linspace(hold, n_clip - 1, args.frames).round().astype(int))]
    A_true, Q_true = truth["activations"][pick], truth["jaw"][pick]
    F = len(pick)
    print(f"# own layout vs model layout: {F} frames of the demo performance (clip frames {pick.tolist()}), "
          f"{hold} neutral; {platform.processor() or platform.machine()}")

    # ---- the performance, again on the medium face
    medium = load_model(MEDIUM)
    sim = Simulation(medium, jaw_model="sliding-condyle")
    t0 = time.perf_counter()
    X_skin, model_markers = [], []
    for k in range(F):
        f = sim.step(A_true[k], jaw=Q_true[k])
        if not f.converged:
            raise SystemExit(f"medium face: clip frame {pick[k]} did not converge ({f.error})")
        X_skin.append(f.x)
        model_markers.append(f.markers)
    t_sim = time.perf_counter() - t0
    model_markers = np.array(model_markers)
    check = np.abs(model_markers - truth["markers_face"][pick]).max()
    print(f"re-simulated on the medium face ({medium.n_tets:,} tets) in {t_sim:.0f} s; its markers differ from "
          f"the stored truth by at most {check:.2e} mm")

    # ---- own layout: skin points tracked through the deformed skin, headband rigid with the skull
    tri, bary, band = choose_layout(medium, args.seed)
    S = medium.skin[tri]
    skin_pts = np.array([np.einsum("rk,rkj->rj", bary, x[S]) for x in X_skin])      # (F, 50, 3)
    own_clean_face = np.concatenate([skin_pts, np.broadcast_to(band, (F, 4, 3))], axis=1)
    centre = medium.X[medium.cranium_nodes].mean(axis=0)
    Rh, th = head_motion(centre, F)
    move = lambda P: np.einsum("fij,frj->fri", Rh, P) + th[:, None]   # noqa: E731
    rng = np.random.default_rng(args.seed + 1)
    own_head = np.r_[np.zeros(len(tri), bool), np.ones(4, bool)]
    own_P, own_gap = spoil(move(own_clean_face), own_head, rng, hold)
    names = [f"p{i:02d}" for i in range(len(tri))] + [f"hb{i}" for i in range(4)]
    assert not set(names) & set(medium.markers.names)
    cap = own_P @ TO_CAPTURE.T + CAPTURE_ORIGIN_MM
    own_file = write_trc(out / "own_layout.trc", np.arange(F), names, cap, fps=12.0, units="m")
    # ---- model layout: the medium face's own markers, same head motion, noise and gap rule
    model_P, model_gap = spoil(move(model_markers), medium.markers.head, np.random.default_rng(args.seed + 2), hold)
    model_file = write_trc(out / "model_layout.trc", np.arange(F), list(medium.markers.names), model_P, fps=12.0)
    print(f"captures: {own_file} ({len(names)} markers, metres, z up; {int(own_gap.sum())} missing samples), "
          f"{model_file} ({medium.n_markers} markers, mm, model frame; {int(model_gap.sum())} missing)")

    head = ["--head-smoothing", "5"] if args.head == "procrustes" else ["--head", "solve"]
    common = ["--model", str(COARSE), "--no-contact", "--noise", str(NOISE_MM), *head,
              "--jaw-model", "sliding-condyle", "--bind-frames", f"0:{hold - 1}", "--overwrite", "-q"]
    log = []
    t_own = _solve(["solve-mocap", "--markers", str(own_file), "-o", str(out / "solve_own"), "--layout", "capture",
                    "--head-markers", "hb0,hb1,hb2,hb3", *common], log)
    print("\n".join("  | " + line for line in log[-1].strip().splitlines()))
    t_model = _solve(["solve-mocap", "--markers", str(model_file), "-o", str(out / "solve_model"), *common], log)

    # ---- placement: where each placed marker's rest position lands vs where it was chosen
    coarse = load_model(COARSE)
    with open(out / "solve_own" / "markers_placed.csv") as fh:
        rows = list(csv.DictReader(fh))
    from facesim.model import MarkerSet

    placed = MarkerSet(tuple(r["name"] for r in rows), np.array([int(r["triangle"]) for r in rows]),
                       _unit_rows(np.array([[float(r[b]) for b in ("b0", "b1", "b2")] for r in rows])),
                       np.array([float(r["offset_mm"]) for r in rows]), np.array([r["role"] == "head" for r in rows]))
    rest = coarse.with_(markers=placed).marker_positions()
    chosen = {n: p for n, p in zip(names, own_clean_face[0])}
    miss = np.array([np.linalg.norm(rest[i] - chosen[n]) for i, n in enumerate(placed.names) if not placed.head[i]])

    visible = np.asarray(truth["sensitivity"]) >= VISIBLE_MM
    s_own = score(out / "solve_own", A_true, Q_true[:, 0], visible)
    s_mod = score(out / "solve_model", A_true, Q_true[:, 0], visible)
    muscles = list(truth["muscle_names"])
    print(f"\nplaced {len(rows)} of {len(names)} own markers; skin markers' rest positions on the coarse face are "
          f"{np.median(miss):.2f} mm (median), {miss.max():.2f} mm (max) from the chosen medium-face points\n")
    print("| measure | own layout (50 + 4 headband, m, z up) | model layout (81, model names) |")
    print("|---|---|---|")
    rows_out = [
        ("frames converged", f"{s_own['converged']} / {s_own['frames']}", f"{s_mod['converged']} / {s_mod['frames']}"),
        ("marker RMS mean / max, mm", f"{s_own['rms_mean']:.2f} / {s_own['rms_max']:.2f}",
         f"{s_mod['rms_mean']:.2f} / {s_mod['rms_max']:.2f}"),
        ("driven muscles: correlation median / min", f"{np.median(s_own['corr']):.3f} / {s_own['corr'].min():.3f}",
         f"{np.median(s_mod['corr']):.3f} / {s_mod['corr'].min():.3f}"),
        ("driven muscles: mean abs error", f"{s_own['mae'].mean():.3f}", f"{s_mod['mae'].mean():.3f}"),
        (f"driven and visible ({len(s_own['corr_visible'])}): correlation median / min",
         f"{np.median(s_own['corr_visible']):.3f} / {s_own['corr_visible'].min():.3f}",
         f"{np.median(s_mod['corr_visible']):.3f} / {s_mod['corr_visible'].min():.3f}"),
        (f"driven and visible ({len(s_own['corr_visible'])}): mean abs error", f"{s_own['mae_visible_driven']:.3f}",
         f"{s_mod['mae_visible_driven']:.3f}"),
        (f"visible muscles ({int(visible.sum())}): mean abs error", f"{s_own['visible_mae']:.3f}",
         f"{s_mod['visible_mae']:.3f}"),
        ("jaw opening error mean / max, deg", f"{s_own['jaw_mean_deg']:.2f} / {s_own['jaw_max_deg']:.2f}",
         f"{s_mod['jaw_mean_deg']:.2f} / {s_mod['jaw_max_deg']:.2f}"),
        ("solve wall time, s", f"{t_own:.0f}", f"{t_model:.0f}"),
    ]
    for r in rows_out:
        print("| " + " | ".join(r) + " |")
    print("\n| driven muscle (peak) | own: corr | own: MAE | model: corr | model: MAE |\n|---|---|---|---|---|")
    for k, i in enumerate(s_own["driven"]):
        mark = "" if visible[i] else ", not visible"
        print(f"| {muscles[i]} ({A_true[:, i].max():.2f}{mark}) | {s_own['corr'][k]:.3f} | {s_own['mae'][k]:.3f} | "
              f"{s_mod['corr'][k]:.3f} | {s_mod['mae'][k]:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
