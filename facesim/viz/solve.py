"""Side-by-side video of a solved capture: the captured markers, and the simulated face that reproduces them.

:func:`render_solve` re-simulates the frames a :func:`~facesim.inverse.tracking.track` run solved
(the controls in ``OUT/activations.csv`` and ``OUT/jaw.csv``, read by
:func:`facesim.controls_io.read_solution`; equilibria warm-started frame to
frame) and renders each frame as two panels seen by the same fixed camera:

* left, *capture*: the captured markers, stabilised into the model's head frame (orange; head
  markers yellow; samples the solve reported as outliers red), over a faint ghost of the
  neutral face -- what the capture system saw;
* right, *simulation*: the simulated face (opaque skin) with its markers (cyan), the captured
  markers (orange, smaller; reported outliers red) and a line from each simulated marker to its
  captured one -- the residual the solve left, with the frame's RMS (outliers left out) in the
  caption. ``color_by="displacement"`` colours the skin by ``|x - X|`` (mm, colour bar);
  ``color_by="activation"`` shows the muscles through a translucent skin, each coloured by its
  solved activation in the frame (0 to 1, colour bar).

The camera is fixed, framed on the model's rest markers.

Pictures go to ``OUT/render/frame_KKKKK.png``, the video to ``OUT/render/video.mp4`` (an
animated GIF ``video.gif`` when imageio-ffmpeg is not installed).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from facesim.controls_io import read_head_poses, read_solution
from facesim.errors import FacesimError
from facesim.mocap.stabilise import stabilise
from facesim.viz.render import (ACTIVATION_SKIN_OPACITY, BACKGROUND, COLOR_BY, HEAD_MARKER_COLOUR, MARKER_COLOUR,
                                SKIN_COLOUR, VIEWS, add_muscles, add_skin, annotate, colour_bar, legend_layout,
                                polydata, pyvista_offscreen, save_png, set_camera)
from facesim.viz.video import write_video

CAPTURED_COLOUR = "#ff9a1f"
OUTLIER_COLOUR = "#ff2d2d"
GHOST_OPACITY = 0.12


class _Panel:
    """One off-screen plotter reused for every frame of a sequence (fixed camera on the rest face)."""

    def __init__(self, model, size, view: str, entries, bar=None):
        self.pv = pyvista_offscreen()
        self.size = size
        self.entries = entries
        width = size[0] - legend_layout(entries, size, bar)[2]   # the panel of the widest bar labels
        self.plotter = self.pv.Plotter(off_screen=True, window_size=(width, size[1]))
        self.plotter.set_background(BACKGROUND[0], top=BACKGROUND[1])
        lo, hi = model.bounding_box()
        self.radius = 0.008 * float(np.linalg.norm(hi - lo))
        self.sphere = self.pv.Sphere(radius=1.0, theta_resolution=12, phi_resolution=12)
        # framed on the rest markers with a margin: the face fills the picture, and the camera stays put
        p = model.marker_positions() if model.n_markers >= 3 else model.X
        centre = 0.5 * (p.min(axis=0) + p.max(axis=0))
        self.camera = (centre + 1.3 * (p - centre), view)

    def points(self, name: str, p, colour: str, scale: float = 1.0) -> None:
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1)]
        if not len(p):
            self.plotter.remove_actor(name)
            return
        glyphs = self.pv.PolyData(p).glyph(geom=self.sphere.scale(scale * self.radius), scale=False, orient=False)
        self.plotter.add_mesh(glyphs, color=colour, smooth_shading=True, name=name)

    def surface(self, name: str, vertices, faces, colour: str, opacity: float) -> None:
        self.plotter.add_mesh(polydata(vertices, faces), color=colour, opacity=opacity, smooth_shading=True,
                              specular=0.1, name=name)

    def lines(self, name: str, a, b, colour: str) -> None:
        ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
        if not ok.any():
            self.plotter.remove_actor(name)
            return
        n = int(ok.sum())
        cells = np.column_stack([np.full(n, 2), np.arange(n), n + np.arange(n)]).ravel()
        poly = self.pv.PolyData(np.vstack([a[ok], b[ok]]), lines=cells)
        self.plotter.add_mesh(poly, color=colour, line_width=2, name=name)

    def image(self, title: str, bar=None) -> np.ndarray:
        if self.camera is not None:   # set once, after the first actors exist (VTK clips to what is drawn)
            points, view = self.camera
            set_camera(self.plotter, points, view, fit_drawn=False)
            self.camera = None
        self.plotter.reset_camera_clipping_range()
        shot = self.plotter.screenshot(None, return_img=True)
        return annotate(np.ascontiguousarray(shot[..., :3]), self.entries, title, self.size, bar)

    def close(self) -> None:
        self.plotter.close()


def _widest_bar(color_by: str, model):
    """A colour bar with labels as wide as any frame's (the panel width is fixed for the sequence)."""
    bar = colour_bar(color_by, model, None, np.ones(model.n_muscles))
    return None if bar is None else (bar[0], bar[1], max(bar[2], 99.9), bar[3])


def render_solve(sim, out_dir, frames, P, *, head: str = "procrustes", fps: float = 30.0, size=(1280, 640),
                 view: str = "front", progress: bool = True, head_smoothing: int = 0, color_by: str = "none") -> Path:
    """Render the solve in ``out_dir`` side by side with its capture and make the video (module doc).

    Parameters
    ----------
    sim : the :class:`~facesim.fem.equilibrium.FaceSimulator` of the solve (model and jaw model).
    out_dir : the folder of the solve (``activations.csv``, ``jaw.csv``, ``residuals.csv``,
        ``report.json``); pictures and video go to ``out_dir/render/``.
    frames : (F,) frame numbers of ``P``; P : (F, r, 3) the capture in the model's marker order,
        mm, NaN missing, as given to ``track`` (``head="procrustes"`` stabilises it the same way,
        over ``head_smoothing`` frames as the solve did; ``head="solve"`` moves it into the head
        frame by the poses of ``OUT/head.csv``).
    fps : video frame rate, Hz; size : (width, height) of a picture in pixels (two panels);
    view : camera of both panels, one of :data:`facesim.viz.render.VIEWS`;
    color_by : the simulated face's colouring, one of :data:`facesim.viz.render.COLOR_BY` (module doc).

    Returns the path of the video.
    """
    from tqdm import tqdm

    if view not in VIEWS:
        raise FacesimError(f"view: unknown view {view!r}; expected one of {', '.join(VIEWS)}")
    if color_by not in COLOR_BY:
        raise FacesimError(f"color_by: unknown colouring {color_by!r}; expected one of {', '.join(COLOR_BY)}")
    model = sim.model
    out = Path(out_dir)
    P = np.asarray(P, dtype=np.float64)
    frames = np.asarray(frames, dtype=np.int64)
    if P.shape != (len(frames), model.n_markers, 3):
        raise FacesimError(f"markers: expected ({len(frames)}, {model.n_markers}, 3) positions, got {P.shape}")
    if head == "procrustes":
        P, _ = stabilise(model, P, head_smoothing)
    elif head == "solve":   # into the head frame by the solved head poses (frames without one stay)
        poses = read_head_poses(out)
        P = P.copy()
        for i, f in enumerate(frames):
            if int(f) in poses:
                T = np.linalg.inv(poses[int(f)])
                P[i] = P[i] @ T[:3, :3].T + T[:3, 3]
    solved, controls = read_solution(out, model)
    row = {int(f): i for i, f in enumerate(frames)}
    pick = [i for i, f in enumerate(solved) if int(f) in row]
    if not pick:
        raise FacesimError(f"{out}: no solved frame to render (activations.csv and jaw.csv share no frame with the "
                           "capture)")
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    names = list(model.markers.names)
    flagged = {int(f): [names.index(n) for n in ns if n in names] for f, ns in report.get("outliers", {}).items()}
    w, h = (int(v) for v in size)
    panel = (w // 2, h)
    left = _Panel(model, panel, view, [("captured", CAPTURED_COLOUR), ("head marker", HEAD_MARKER_COLOUR),
                                       ("reported outlier", OUTLIER_COLOUR)])
    right = _Panel(model, panel, view, [("simulated marker", MARKER_COLOUR), ("captured", CAPTURED_COLOUR),
                                        ("reported outlier", OUTLIER_COLOUR)],
                   _widest_bar(color_by, model))
    head_mask = model.markers.head
    pngs = []
    x = None
    try:
        left.surface("ghost", model.X, model.skin, SKIN_COLOUR, GHOST_OPACITY)
        for i in tqdm(pick, desc="render", unit="frame", disable=not progress):
            k = int(solved[i])
            eq = sim.equilibrium(controls[i], x0=x)
            ok = bool(np.isfinite(eq.x).all())
            x = eq.x if ok else None
            xs = eq.x if ok else model.X
            target = P[row[k]]
            mine = model.marker_positions(xs)
            bad = np.zeros(model.n_markers, dtype=bool)
            bad[flagged.get(k, [])] = True
            left.points("captured", target[~head_mask & ~bad], CAPTURED_COLOUR)
            left.points("head", target[head_mask], HEAD_MARKER_COLOUR)
            left.points("outliers", target[bad], OUTLIER_COLOUR)
            bar = colour_bar(color_by, model, xs, controls[i].a)
            if color_by == "activation":
                add_muscles(right.plotter, model, xs, 0.3, controls[i].a, name="muscle")
            add_skin(right.plotter, model, xs, ACTIVATION_SKIN_OPACITY if color_by == "activation" else 1.0,
                     bar if color_by == "displacement" else None, name="skin")
            right.points("simulated", mine, MARKER_COLOUR, scale=0.8)
            right.points("captured", target[~bad], CAPTURED_COLOUR, scale=0.55)
            right.points("outliers", target[bad], OUTLIER_COLOUR, scale=0.55)
            right.lines("residual", mine, target, CAPTURED_COLOUR)
            d = np.linalg.norm(mine - target, axis=1)[~bad]
            rms = float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else float("nan")
            status = "" if eq.converged else ", not converged"
            image = np.hstack([left.image(f"capture  frame {k}"),
                               right.image(f"simulation  RMS {rms:.2f} mm{status}", bar)])
            pngs.append(save_png(image, out / "render" / f"frame_{k:05d}.png"))
    finally:
        left.close()
        right.close()
    path, _ = write_video(pngs, out / "render", fps)
    return path


__all__ = ["render_solve"]
