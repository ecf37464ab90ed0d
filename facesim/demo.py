"""The demo capture, and solving it: a known performance, played on a finer face, read back as mocap.

:func:`make_demo_clip` plays a scripted performance (:data:`PERFORMANCE`: talking -- the jaw
opening and closing with the lip muscles --, a smile, a frown and a wide jaw opening, under a
gentle head motion) on a *fine* model with the sliding-condyle jaw, samples the model's markers
and spoils them the way a capture is spoiled: Gaussian noise (0.5 mm per axis), a few outliers
(1.5 % of the face-marker samples moved 5-10 mm in a random direction) and gaps (markers
missing for runs of frames, and isolated drop-outs). It writes ``demo_clip.c3d``,
``demo_clip.trc`` and ``demo_clip_truth.npz`` (what is known about the clip: activations, jaw
parameters, head motion, noiseless markers, which samples are outliers or gaps, and how far each
muscle moves the markers).

:func:`run_demo` solves the clip on another (coarser) model -- the inverse crime of solving on
the mesh that made the data is avoided -- with :func:`~facesim.inverse.tracking.track` and
scores the solve against the truth (:func:`score_solve`): marker RMS, activation error of the
muscles the markers can see, jaw error, and how many planted outliers were reported.

Regenerate the shipped clip (on ``meshes/face_medium.npz``; prints how long it took)::

    python -m facesim.demo --make [--model meshes/face_medium.npz] [--out meshes/]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from facesim._files import MESHES, atomic_write, open_npz
from facesim.errors import FacesimError, ModelFileError
from facesim.model import FaceModel

#: The shipped clip (its truth is ``<stem>_truth.npz`` beside it).
DEMO_CLIP = MESHES / "demo_clip.c3d"
#: The model the shipped clip is made on, and the one the demo solves with.
FINE_MODEL = MESHES / "face_medium.npz"
SOLVE_MODEL = MESHES / "face_coarse.npz"

_SMILE = {"zygomaticus_major": 0.9, "zygomaticus_minor": 0.4, "risorius": 0.4, "orbicularis_oculi": 0.3,
          "levator_anguli_oris": 0.3}
_FROWN = {"depressor_anguli_oris": 0.9, "depressor_labii_inferioris": 0.4, "mentalis": 0.6,
          "corrugator_supercilii": 0.8, "procerus": 0.4}
#: Opening of "jaw open wide", rad (0.3 rad: the incisors drop about 26 mm, the condyles slide
#: 3.8 mm forward along the natural path of
#: :meth:`facesim.kinematics.condyle.SlidingCondyleJaw.natural_parameters`).
WIDE_OPEN = 0.3


def performance_keys(wide_open: float = WIDE_OPEN) -> tuple:
    """The performance: key poses ``(fraction of the clip, {muscle base name: activation}, jaw
    opening rad)``, blended by a smooth step between keys; base names activate both sides.
    ``wide_open``: the jaw opening of "jaw open wide", rad. The clip starts by holding the
    neutral face for :data:`NEUTRAL_HOLD` of its length (the markers are bound to the skin there,
    as a capture session starts with a neutral pose)."""
    keys = (
        (0.00, {}, 0.0),                                                                      # neutral
        (0.08, {"depressor_labii_inferioris": 0.4, "levator_labii_superioris": 0.3}, 0.12),   # talk: "ah"
        (0.16, {"orbicularis_oris_upper": 0.6, "orbicularis_oris_lower": 0.6}, 0.02),         # "m": lips pressed
        (0.24, {"risorius": 0.5, "depressor_labii_inferioris": 0.3}, 0.08),                   # "ee"
        (0.32, {"orbicularis_oris_upper": 0.7, "orbicularis_oris_lower": 0.7, "mentalis": 0.3}, 0.04),  # "oo"
        (0.44, _SMILE, 0.03),                                                                 # smile
        (0.54, _SMILE, 0.03),
        (0.66, _FROWN, 0.0),                                                                  # frown
        (0.75, _FROWN, 0.0),
        (0.90, {"depressor_labii_inferioris": 0.3, "levator_labii_superioris": 0.2}, wide_open),  # jaw open wide
        (1.00, {}, 0.05),                                                                     # relax
    )
    return ((0.0, {}, 0.0),) + tuple((NEUTRAL_HOLD + (1.0 - NEUTRAL_HOLD) * t, pose, q) for t, pose, q in keys)


#: Fraction of the clip that holds the neutral face at its start.
NEUTRAL_HOLD = 0.08


def neutral_frames(n_frames: int) -> int:
    """How many frames at the start of an ``n_frames`` clip show the neutral face."""
    return int(np.sum(np.linspace(0.0, 1.0, n_frames) <= NEUTRAL_HOLD)) if n_frames > 1 else 1


#: The shipped clip's performance (:func:`performance_keys`).
PERFORMANCE = performance_keys()
#: Noise, outliers and gaps of the capture (see :func:`spoil`).
NOISE_MM = 0.5
OUTLIER_FRACTION = 0.015
OUTLIER_MM = (5.0, 10.0)
DROPOUT_FRACTION = 0.005
#: A muscle is scored when one unit of its activation moves some face marker by at least this
#: much (mm): an activation error of 0.1 then moves that marker by >= the noise (0.5 mm), so the
#: data pins the activation to about 0.1 or better. Weaker muscles are not identifiable from the
#: markers (their activation trades off against others' at no cost in marker distance).
VISIBLE_MM = 5.0
#: Length (frames) and rate (Hz) of the shipped clip.
CLIP_FRAMES, CLIP_FPS = 72, 24.0
#: Frames the demo smooths the head stabilisation over (``solve-mocap --head-smoothing``): 0.375 s
#: of the 24 Hz clip, shorter than its gentle head motion, long enough to average the noise of
#: the six head markers (on the clip: stabilised markers 1.18 mm RMS from the truth unsmoothed,
#: worst frame 2.7 mm; 0.96 mm, worst frame 1.24 mm, smoothed; the noise alone is 0.87 mm).
HEAD_SMOOTHING = 9


def truth_path(clip) -> Path:
    """The truth file of a clip: ``<stem>_truth.npz`` beside ``clip``."""
    clip = Path(clip)
    return clip.with_name(f"{clip.stem}_truth.npz")


# ------------------------------------------------------------------ the performance
def performance(model: FaceModel, n_frames: int, keys=PERFORMANCE) -> tuple[np.ndarray, np.ndarray]:
    """Activations ``A (n_frames, n_muscles)`` and jaw openings ``(n_frames,)`` rad of the key poses
    ``keys`` sampled at ``n_frames`` evenly spaced instants from the first key to the last (so a
    short clip still visits every part of the performance, coarsely)."""
    from facesim.session import activation_vector

    if n_frames < 1:
        raise FacesimError(f"frames: expected at least 1, got {n_frames}")
    times = np.array([k[0] for k in keys], dtype=np.float64)
    poses = np.array([activation_vector(model, k[1]) for k in keys])
    openings = np.array([k[2] for k in keys], dtype=np.float64)
    u = np.linspace(times[0], times[-1], n_frames) if n_frames > 1 else times[:1]
    i = np.clip(np.searchsorted(times, u, side="right") - 1, 0, len(times) - 2)
    s = np.clip((u - times[i]) / (times[i + 1] - times[i]), 0.0, 1.0)
    s = s * s * (3.0 - 2.0 * s)     # smooth step: no velocity jumps at the keys
    A = (1.0 - s)[:, None] * poses[i] + s[:, None] * poses[i + 1]
    return A, (1.0 - s) * openings[i] + s * openings[i + 1]


def head_motion(model: FaceModel, n_frames: int) -> np.ndarray:
    """``(n_frames, 4, 4)`` a gentle rigid head motion (nod up to ~1.7 deg, turn ~1.1 deg, tilt
    ~0.6 deg about the cranium centroid, and up to ~3 mm of drift) that the solve must undo by
    stabilising on the head markers."""
    from facesim.controls import rotation_about

    centre = model.X[model.cranium_nodes].mean(axis=0) if len(model.cranium_nodes) else model.X.mean(axis=0)
    u = np.linspace(0.0, 1.0, n_frames)
    out = np.empty((n_frames, 4, 4))
    for k, t in enumerate(u):
        rotvec = [0.03 * np.sin(2 * np.pi * t), 0.02 * np.sin(2 * np.pi * 0.7 * t + 1.0), 0.01 * np.sin(3 * t)]
        T = rotation_about(rotvec, centre)
        T[:3, 3] += [1.5 * np.sin(2 * np.pi * 0.5 * t), 1.0 * np.sin(4 * t), 2.0 * np.sin(2 * np.pi * 0.3 * t)]
        out[k] = T
    return out


def spoil(clean: np.ndarray, head: np.ndarray, rng: np.random.Generator, noise: float = NOISE_MM):
    """A capture from noiseless markers ``clean (F, r, 3)`` mm: Gaussian noise ``noise`` mm per axis
    on every sample; outliers (``OUTLIER_FRACTION`` of the face-marker samples, at least one,
    moved ``OUTLIER_MM`` mm in a random direction); gaps (about one face marker per 10 frames
    missing for a run of frames, plus ``DROPOUT_FRACTION`` isolated drop-outs). Head markers
    (``head (r,)`` bool) get noise only: the rigid stabilisation is not robust to them.

    Returns the captured positions ``(F, r, 3)`` (NaN in the gaps), the outlier and gap masks
    ``(F, r)`` bool."""
    F, r, _ = clean.shape
    face = np.flatnonzero(~head)
    gap = np.zeros((F, r), dtype=bool)
    for _ in range(max(1, round(F / 10))):
        length = int(rng.integers(2, max(3, F // 6) + 1))
        start = int(rng.integers(0, max(1, F - length + 1)))
        gap[start:start + length, rng.choice(face)] = True
    n_drop = round(DROPOUT_FRACTION * F * len(face))
    flat = rng.choice(F * len(face), size=n_drop, replace=False)
    gap[flat // len(face), face[flat % len(face)]] = True
    candidates = np.flatnonzero((~gap[:, face]).ravel())
    n_out = max(1, round(OUTLIER_FRACTION * F * len(face)))
    pick = rng.choice(candidates, size=min(n_out, len(candidates)), replace=False)
    outlier = np.zeros((F, r), dtype=bool)
    outlier[pick // len(face), face[pick % len(face)]] = True
    P = clean + rng.normal(0.0, noise, size=clean.shape)
    direction = rng.normal(size=(int(outlier.sum()), 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    P[outlier] += direction * rng.uniform(*OUTLIER_MM, size=(len(direction), 1))
    P[gap] = np.nan
    return P, outlier, gap


def muscle_sensitivity(sim) -> np.ndarray:
    """``(n_muscles,)`` mm: how far one unit of each muscle's activation moves the furthest face
    (non-head) marker, to first order at rest (the implicit marker Jacobian of
    :func:`~facesim.inverse.jacobian.equilibrium_jacobian`). ``sim``: a FaceSimulator."""
    from facesim.controls import Controls
    from facesim.inverse.jacobian import ControlSpace, equilibrium_jacobian

    model = sim.model
    space = ControlSpace.of(sim, jaw=False)
    rest = Controls(np.zeros(model.n_muscles), jaw=sim.jaw_model.rest)
    J = equilibrium_jacobian(sim, rest, model.X, space).dP.reshape(model.n_markers, 3, -1)
    return np.linalg.norm(J, axis=1)[~model.markers.head].max(axis=0)


# ------------------------------------------------------------------ making the clip
def make_demo_clip(fine_model: FaceModel, out_dir, *, seed: int = 0, n_frames: int = CLIP_FRAMES,
                   fps: float = CLIP_FPS, stem: str = "demo_clip", noise: float = NOISE_MM, keys=PERFORMANCE,
                   progress: bool = True) -> dict:
    """Play :data:`PERFORMANCE` on ``fine_model`` and write a spoiled capture of its markers.

    Parameters
    ----------
    fine_model : FaceModel the clip is made on (the demo solves on a coarser one).
    out_dir : folder for ``<stem>.c3d``, ``<stem>.trc`` and ``<stem>_truth.npz``.
    seed : seed of the noise, outliers and gaps (the clip is deterministic given the model).
    n_frames, fps : length (the whole performance is sampled whatever the length) and rate, Hz.
    noise : Gaussian noise, mm per axis.
    keys : the performance (default :data:`PERFORMANCE`).

    The truth ``.npz`` holds ``frames (F,)``, ``fps``, ``marker_names (r,)``, ``head_markers (r,)``
    bool, ``muscle_names (m,)``, ``activations (F, m)``, ``jaw (F, 3)`` sliding-condyle parameters
    (opening rad, right slide mm, left slide mm), ``head (F, 4, 4)`` the head motion,
    ``markers (F, r, 3)`` noiseless markers in the capture (with the head motion),
    ``markers_face (F, r, 3)`` the same without it, ``rest_markers (r, 3)`` the fine model's markers
    at rest, ``outliers (F, r)`` and ``gaps (F, r)`` bool,
    ``sensitivity (m,)`` mm per unit activation (:func:`muscle_sensitivity`), ``noise``, ``seed``
    and ``meta`` (JSON: the fine model's size, solver statistics).

    Returns a summary dict (paths, seconds, Newton iterations). Raises FacesimError if a frame
    of the performance does not converge on ``fine_model``.
    """
    from tqdm import tqdm

    from facesim.mocap.io import write_c3d, write_trc
    from facesim.session import Simulation

    t0 = time.perf_counter()
    out = Path(out_dir)
    A, openings = performance(fine_model, n_frames, keys)
    sim = Simulation(fine_model, jaw_model="sliding-condyle")
    Q = np.array([sim.jaw_model.natural_parameters(o) for o in openings])
    face = np.empty((n_frames, fine_model.n_markers, 3))
    iterations = []
    for k in tqdm(range(n_frames), desc="demo clip", unit="frame", disable=not progress):
        f = sim.step(A[k], jaw=Q[k])
        if not f.converged:
            raise FacesimError(f"demo clip: frame {k} (opening {openings[k]:.3f} rad) did not converge on the fine "
                               f"model after {f.iterations} Newton iterations {f.error}".strip())
        face[k] = f.markers
        iterations.append(f.iterations)
    t_sim = time.perf_counter() - t0
    sensitivity = muscle_sensitivity(sim.simulator)
    H = head_motion(fine_model, n_frames)
    clean = np.einsum("fij,frj->fri", H[:, :3, :3], face) + H[:, None, :3, 3]
    rng = np.random.default_rng(seed)
    P, outliers, gaps = spoil(clean, fine_model.markers.head, rng, noise)
    frames = np.arange(n_frames)
    names = list(fine_model.markers.names)
    paths = {"c3d": write_c3d(out / f"{stem}.c3d", frames, names, P, fps),
             "trc": write_trc(out / f"{stem}.trc", frames, names, P, fps)}
    meta = {"model": {"n_nodes": fine_model.n_nodes, "n_tets": fine_model.n_tets, "build": fine_model.meta},
            "newton_iterations": iterations, "simulate_seconds": round(t_sim, 1), "keys": [list(k) for k in keys]}
    truth = {"frames": frames, "fps": float(fps), "marker_names": np.array(names),
             "head_markers": fine_model.markers.head, "muscle_names": np.array(fine_model.muscles.names),
             "activations": A, "jaw": Q, "head": H, "markers": clean, "markers_face": face,
             "rest_markers": fine_model.marker_positions(), "outliers": outliers, "gaps": gaps,
             "sensitivity": sensitivity, "noise": float(noise), "seed": int(seed),
             "meta": json.dumps(meta, default=str)}
    paths["truth"] = atomic_write(truth_path(paths["c3d"]), lambda tmp: np.savez_compressed(tmp, **truth))
    return {"paths": paths, "frames": n_frames, "fps": fps, "seconds": time.perf_counter() - t0,
            "simulate_seconds": t_sim, "newton_iterations": iterations, "outliers": int(outliers.sum()),
            "gaps": int(gaps.sum()), "samples": int(P.shape[0] * P.shape[1])}


def load_truth(clip) -> dict:
    """The truth ``.npz`` of a clip as a dict of arrays (see :func:`make_demo_clip`)."""
    path = truth_path(clip)
    if not path.is_file():
        raise FacesimError(f"{path}: no truth file for the clip {clip}; make the clip with "
                           "'python -m facesim.demo --make'")
    with open_npz(path, "a demo clip truth .npz ('python -m facesim.demo --make')") as z:
        try:
            truth = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 (a corrupt member: zlib.error, BadZipFile, ValueError ...)
            raise ModelFileError(path, f"unreadable field ({type(exc).__name__}); make the clip again") from None
    try:
        truth["meta"] = json.loads(str(truth["meta"]))
    except (KeyError, ValueError):
        truth["meta"] = None
    if not isinstance(truth["meta"], dict):
        raise ModelFileError(path, "field 'meta': expected a JSON object; make the clip again")
    return truth


# ------------------------------------------------------------------ scoring a solve
def _groups(names) -> dict[str, list[int]]:
    from facesim.viz.plots import GROUPS

    return {g: [i for i, n in enumerate(names) if any(n.startswith(s) for s in stems)] for g, stems in GROUPS.items()}


def score_solve(truth: dict, out_dir, model: FaceModel | None = None) -> dict:
    """Compare the solve in ``out_dir`` (the files :func:`track` wrote) with the clip's ``truth``
    (:func:`load_truth`), over the frames solved; ``model``: the solve model with its markers as
    the solve bound them, to measure how far its rest markers sit from the clip model's
    (``marker_rms["mesh_gap"]``, face markers, mm, and ``marker_rms["worst_placed"]`` the worst
    marker and its distance): a floor under the marker RMS.

    Returns a JSON-serialisable dict: ``frames``; ``marker_rms`` (mm, per frame RMS over the markers
    the fit used: ``mean``, ``max``, ``noise_rms`` the noise's own 3-D RMS); ``activation``
    (absolute error over frames and the visible muscles: ``mean``, ``max`` with its muscle and
    frame, ``groups`` mean per muscle group, ``per_muscle`` mean, ``visible`` and ``not_visible``
    names, ``threshold_mm``); ``jaw`` (opening error in degrees and slide errors in mm, mean and
    max); ``outliers`` (planted, reported, of which planted, false alarms)."""
    from facesim.framelog import read_log

    out = Path(out_dir)
    header, A = read_log(out / "activations.csv")
    jaw_header, J = read_log(out / "jaw.csv")
    _, R = read_log(out / "residuals.csv")
    muscles = list(truth["muscle_names"])
    if header[1:] != muscles:
        raise FacesimError(f"{out / 'activations.csv'}: muscles differ from the clip's truth (the solve model and "
                           "the clip's model must share their muscle names)")
    row = {int(f): i for i, f in enumerate(truth["frames"])}
    frames = [int(f) for f in A[:, 0] if int(f) in row]
    if not frames:
        raise FacesimError(f"{out}: no solved frame belongs to the clip")
    ti = [row[f] for f in frames]
    fit = {int(f): i for i, f in enumerate(A[:, 0])}
    fi = [fit[f] for f in frames]
    err = np.abs(A[fi, 1:] - truth["activations"][ti])
    visible = np.asarray(truth["sensitivity"]) >= VISIBLE_MM
    ev = err[:, visible]
    vis_idx = np.flatnonzero(visible)
    worst = np.unravel_index(int(np.argmax(ev)), ev.shape) if ev.size else (0, 0)
    groups = {g: float(err[:, [i for i in idx if visible[i]]].mean())
              for g, idx in _groups(muscles).items() if any(visible[i] for i in idx)}
    activation = {
        "mean": float(ev.mean()) if ev.size else float("nan"),
        "max": float(ev.max()) if ev.size else float("nan"),
        "worst_muscle": muscles[vis_idx[worst[1]]] if ev.size else None,
        "worst_frame": frames[worst[0]],
        "groups": groups,
        "per_muscle": {muscles[i]: float(err[:, i].mean()) for i in vis_idx},
        "visible": [muscles[i] for i in vis_idx],
        "not_visible": [m for m, v in zip(muscles, visible) if not v],
        "threshold_mm": VISIBLE_MM,
        "mean_all_muscles": float(err.mean()),
    }
    jaw = {}
    if jaw_header[1:2] == ["opening"] and len(J):
        jrow = {int(f): i for i, f in enumerate(J[:, 0])}
        ji = [jrow[f] for f in frames]
        dq = np.abs(J[ji, 1:4] - truth["jaw"][ti])
        jaw = {"opening_deg_mean": float(np.degrees(dq[:, 0]).mean()), "opening_deg_max": float(np.degrees(dq[:, 0]).max()),
               "slide_mm_mean": float(dq[:, 1:].mean()), "slide_mm_max": float(dq[:, 1:].max())}
    rrow = {int(f): i for i, f in enumerate(R[:, 0])}
    rms = R[[rrow[f] for f in frames], 1]
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    names = list(truth["marker_names"])
    reported = {(int(f), names.index(n)) for f, ns in report.get("outliers", {}).items() if int(f) in row
                for n in ns if n in names}
    planted = {(f, int(j)) for f in frames for j in np.flatnonzero(truth["outliers"][row[f]])}
    marker_rms = {"mean": float(np.nanmean(rms)), "max": float(np.nanmax(rms)),
                  "noise_rms": float(np.sqrt(3.0) * truth["noise"]), "per_frame": [float(v) for v in rms]}
    if model is not None and "rest_markers" in truth and list(model.markers.names) == names:
        face = ~np.asarray(truth["head_markers"], dtype=bool)
        gap = np.linalg.norm(truth["rest_markers"] - model.marker_positions(), axis=1)[face]
        worst = int(np.argmax(gap))
        marker_rms["mesh_gap"] = float(np.sqrt(np.mean(gap**2)))
        marker_rms["worst_placed"] = [names[int(np.flatnonzero(face)[worst])], float(gap[worst])]
    return {
        "frames": frames,
        "marker_rms": marker_rms,
        "activation": activation,
        "jaw": jaw,
        "outliers": {"planted": len(planted), "reported": len(reported), "found": len(planted & reported),
                     "false_alarms": len(reported - planted)},
        "gaps": int(truth["gaps"][ti].sum()),
    }


def format_score(s: dict) -> str:
    """Human-readable lines of :func:`score_solve`."""
    a, m, j, o = s["activation"], s["marker_rms"], s["jaw"], s["outliers"]
    lines = [
        (f"marker RMS      mean {m['mean']:.2f} mm, max {m['max']:.2f} mm over {len(s['frames'])} frames "
         f"(the noise alone: {m['noise_rms']:.2f} mm)"),
        (f"activations     mean abs error {a['mean']:.3f}, max {a['max']:.3f} ({a['worst_muscle']}, frame "
         f"{a['worst_frame']}) over the {len(a['visible'])} visible muscles"),
        ("                (visible: one unit of activation moves a face marker >= "
         f"{a['threshold_mm']:g} mm; all {len(a['visible']) + len(a['not_visible'])} muscles: "
         f"{a['mean_all_muscles']:.3f})"),
        "  per group     " + ", ".join(f"{g} {v:.3f}" for g, v in a["groups"].items()),
    ]
    if "mesh_gap" in m:
        lines.insert(1, f"                the markers as bound sit {m['mesh_gap']:.2f} mm RMS from the clip's at rest "
                        f"(worst {m['worst_placed'][0]}, {m['worst_placed'][1]:.1f} mm): a floor under the RMS")
    if a["not_visible"]:
        lines.append(f"  not scored    {', '.join(a['not_visible'])}")
    if j:
        lines.append(f"jaw             opening error mean {j['opening_deg_mean']:.2f} deg, max "
                     f"{j['opening_deg_max']:.2f} deg; condyle slides mean {j['slide_mm_mean']:.2f} mm, max "
                     f"{j['slide_mm_max']:.2f} mm")
    lines.append(f"outliers        {o['found']} of {o['planted']} planted outliers reported, {o['false_alarms']} "
                 f"other samples reported; {s['gaps']} missing samples dropped")
    return "\n".join(lines)


def plot_recovery(truth: dict, out_dir) -> Path:
    """``recovery.png`` in ``out_dir``: per muscle group, the true (dashed) and solved (solid)
    activation curves of the left-side muscles the performance uses, and the jaw opening."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from facesim.framelog import read_log

    out = Path(out_dir)
    _, A = read_log(out / "activations.csv")
    jaw_header, J = read_log(out / "jaw.csv")
    muscles = list(truth["muscle_names"])
    T, tf = truth["activations"], list(truth["frames"])
    used = [i for i, n in enumerate(muscles) if not n.endswith("_R") and T[:, i].max() > 0.05]
    groups = {g: [i for i in idx if i in used] for g, idx in _groups(muscles).items()}
    groups = {g: idx for g, idx in groups.items() if idx}
    fig, axes = plt.subplots(len(groups) + 1, 1, figsize=(9, 1.9 * (len(groups) + 1)), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (g, idx) in zip(axes, groups.items()):
        for c, i in enumerate(idx):
            col = colours[c % len(colours)]
            ax.plot(tf, T[:, i], "--", color=col, lw=1.0)
            label = muscles[i].removesuffix("_L") + ("" if truth["sensitivity"][i] >= VISIBLE_MM else " (not visible)")
            ax.plot(A[:, 0], A[:, 1 + i], "-", color=col, lw=1.5, label=label)
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel("activation")
        ax.set_title(f"{g} (left side; dashed: truth, solid: solved)", fontsize=9, loc="left")
        ax.legend(fontsize=6, ncol=3, loc="upper right")
    ax = axes[-1]
    ax.plot(tf, np.degrees(truth["jaw"][:, 0]), "k--", lw=1.0, label="truth")
    if jaw_header[1:2] == ["opening"]:
        ax.plot(J[:, 0], np.degrees(J[:, 1]), "k-", lw=1.5, label="solved")
    ax.set_ylabel("jaw opening (deg)")
    ax.set_xlabel("frame")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path = atomic_write(out / "recovery.png", lambda tmp: fig.savefig(tmp, dpi=110))
    plt.close(fig)
    return path


# ------------------------------------------------------------------ the demo
def run_demo(out_dir, model=None, clip=None, *, frames=None, render: bool = False, progress: bool = True,
             say=print, jaw_prior=None, drop=()) -> dict:
    """Solve the demo clip on ``model`` and score the solve against the clip's truth.

    Parameters
    ----------
    out_dir : results folder (the files of :func:`~facesim.inverse.tracking.track`, its plots,
        ``recovery.png``, ``recovery.json`` and, with ``render``, ``render/`` with the video).
    model : FaceModel or path (default: the shipped coarse model).
    clip : the capture, ``.c3d`` or ``.trc`` (default: the shipped ``meshes/demo_clip.c3d``);
        its truth is ``<stem>_truth.npz`` beside it.
    frames : ``"FIRST:LAST"`` (inclusive) to solve part of the clip.
    say : where the one-line messages go (None: nowhere).
    jaw_prior : a :class:`~facesim.inverse.jaw_prior.JawPrior` for the model (``solve-mocap
        --jaw-prior``), or None.
    drop : names of markers taken out of the clip (a capture with fewer markers, e.g. none on the chin).

    Returns ``{"score": score_solve(...), "track": track summary, "outputs": [...], "seconds": s}``.
    """
    from facesim.fem.equilibrium import FaceSimulator
    from facesim.inverse.gauss_newton import FitOptions
    from facesim.inverse.tracking import TrackOptions, track
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.mocap.binding import bind_neutral, match_markers
    from facesim.mocap.io import frame_mask, read_markers
    from facesim.mocap.stabilise import stabilise
    from facesim.model import load_model
    from facesim.viz.plots import plot_track

    say = say or (lambda *_: None)
    t0 = time.perf_counter()
    clip = Path(clip or DEMO_CLIP)
    if not clip.is_file():
        raise FacesimError(f"{clip}: no such clip; make it with 'python -m facesim.demo --make'")
    truth = load_truth(clip)
    if not isinstance(model, FaceModel):
        model = load_model(model or SOLVE_MODEL)
    data = read_markers(clip)
    index, _, _ = match_markers(model.markers.names, data.names)
    if (index >= 0).sum() < 3 or (index[model.markers.head] >= 0).sum() < 3:
        raise FacesimError(f"{clip}: the clip's markers are not the model's ({int((index >= 0).sum())} of "
                           f"{model.n_markers} names match, 3 head markers needed); the demo needs a model of the "
                           "procedural head ('facesim model build')")
    P = np.full((len(data.frames), model.n_markers, 3), np.nan)
    P[:, index >= 0] = data.P[:, index[index >= 0]]
    unknown = [n for n in drop if n not in model.markers.names]
    if unknown:
        raise FacesimError(f"drop: no marker {', '.join(unknown)} in the model")
    P[:, [model.markers.names.index(n) for n in drop]] = np.nan
    # stabilise the whole clip once, the head transforms smoothed over time (the same whichever
    # frames are solved); the solve then takes the clip as stabilised
    P_all, _ = stabilise(model, P, HEAD_SMOOTHING)
    keep = frame_mask(frames, data.frames)
    frame_numbers, P = data.frames[keep], P_all[keep]
    fine = truth["meta"]["model"]
    say(f"clip {clip.name}: {len(data.frames)} frames at {data.rate or truth['fps']:g} Hz, {len(data.names)} markers, "
        f"made on a {fine['n_tets']:,}-tet face; solving {len(frame_numbers)} frames on a {model.n_tets:,}-tet face")
    sim = FaceSimulator(model, jaw_model=SlidingCondyleJaw(model.jaw))
    options = TrackOptions(fit=FitOptions(noise=float(truth["noise"])), head="none", jaw_prior=jaw_prior)
    # bind the markers to the skin on the neutral frames the clip starts with (Sifakis 2005): the
    # clip was made on another mesh, where the same landmark can sit millimetres away
    hold = neutral_frames(len(data.frames))
    summary = track(sim, frame_numbers, P, out_dir, options=options, progress=progress, neutral=P_all[:hold],
                    overwrite=True)   # the demo always solves its clip afresh
    bound = bind_neutral(sim, P_all[:hold], options.head)[0]   # the markers as track bound them (~0.1 s)
    outputs = plot_track(out_dir)
    outputs.append(plot_recovery(truth, out_dir))
    score = score_solve(truth, out_dir, bound.model)
    out = Path(out_dir)
    outputs.append(atomic_write(out / "recovery.json", lambda tmp: tmp.write_text(json.dumps(score, indent=2) + "\n")))
    if render:
        from facesim.viz.solve import render_solve

        outputs.append(render_solve(bound, out_dir, frame_numbers, P, head="none", fps=float(data.rate or truth["fps"]),
                                    progress=progress))
    return {"score": score, "track": summary, "outputs": outputs, "seconds": time.perf_counter() - t0}


# ------------------------------------------------------------------ command line
def main(argv=None) -> int:
    """``python -m facesim.demo --make``: regenerate the demo clip (see the module doc)."""
    ap = argparse.ArgumentParser(prog="python -m facesim.demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--make", action="store_true", help="make the demo clip")
    ap.add_argument("--model", default=str(FINE_MODEL), help="the fine model the clip is made on (default: %(default)s)")
    ap.add_argument("--out", default=str(MESHES), help="folder for the clip files (default: %(default)s)")
    ap.add_argument("--frames", type=int, default=CLIP_FRAMES, help="number of frames (default: %(default)s)")
    ap.add_argument("--fps", type=float, default=CLIP_FPS, help="frame rate, Hz (default: %(default)s)")
    ap.add_argument("--wide-open", type=float, default=WIDE_OPEN,
                    help="jaw opening of 'jaw open wide', rad (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the noise, outliers and gaps (default: %(default)s)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if not args.make:
        ap.print_help()
        return 0
    from facesim.model import load_model

    try:
        t0 = time.perf_counter()
        model = load_model(args.model)
        s = make_demo_clip(model, args.out, seed=args.seed, n_frames=args.frames, fps=args.fps,
                           keys=performance_keys(args.wide_open), progress=not args.quiet)
    except FacesimError as exc:
        print(f"facesim: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(f"made the demo clip on {args.model} ({model.n_tets:,} tets): {s['frames']} frames at {s['fps']:g} Hz, "
          f"{s['outliers']} outliers and {s['gaps']} missing of {s['samples']} samples, in "
          f"{time.perf_counter() - t0:.0f} s (simulation {s['simulate_seconds']:.0f} s, Newton iterations per frame "
          f"{min(s['newton_iterations'])}-{max(s['newton_iterations'])})")
    for p in s["paths"].values():
        print(f"  {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
