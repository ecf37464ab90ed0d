"""Off-screen pictures of a face model with pyvista: skin, bones, colliders, muscles, markers.

Everything renders off screen (no display needed: on Linux without ``DISPLAY`` VTK is pointed
at EGL when ``libEGL`` is present, otherwise it picks its own fallback), so the functions
work the same on a laptop, a server and CI.

Coordinates: x toward the subject's left, y up, z toward the nose (mm). The ``"front"`` view
looks from +z toward -z with +y up, ``"side"`` from +x (the subject's left), ``"top"`` and
``"bottom"`` from +y and -y with the nose (+z) up in the picture.
"""

from __future__ import annotations

import ctypes.util
import math
import os
import re
import sys
from pathlib import Path

import numpy as np

from facesim._files import atomic_write, require_suffix
from facesim.errors import FacesimError
from facesim.model import FaceModel

#: Direction from the model centre to the camera, and the camera's up vector, per view.
VIEWS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "front": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "side": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
    "three_quarter": ((0.7, 0.15, 1.0), (0.0, 1.0, 0.0)),
    "top": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "bottom": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
}
#: What can be drawn; ``show`` and the CLI's ``--hide`` take these names.
LAYERS = ("skin", "bones", "colliders", "muscles", "markers")
DEFAULT_SHOW = LAYERS
#: What a picture can colour by (``color_by`` and the CLI's ``--color-by``): ``none`` (skin colour,
#: one colour per muscle), ``displacement`` (the skin by ``|x - X|``, mm), ``activation`` (each
#: muscle by its activation in the frame, 0 to 1).
COLOR_BY = ("none", "displacement", "activation")
#: Skin opacity when none is given: opaque, so the picture shows the expression; translucent when
#: the muscles' activations are what the picture is about (they lie under the skin).
SKIN_OPACITY = 1.0
ACTIVATION_SKIN_OPACITY = 0.35
#: Sequential colour maps (matplotlib names) of ``color_by``; both stay visible on the dark background.
DISPLACEMENT_CMAP = "viridis"
ACTIVATION_CMAP = "plasma"

SKIN_COLOUR = "#e3b196"
BONE_COLOUR = "#fffff0"  # ivory
TEETH_COLOUR = "#fbfbf8"
EYE_COLOUR = "#dfe8f2"
GUM_COLOUR = "#c8707a"
OTHER_COLLIDER_COLOUR = "#b8bcc4"
MARKER_COLOUR = "#00d0ff"
HEAD_MARKER_COLOUR = "#ffd21f"
#: Smallest side of the off-screen 3D view: smaller pictures are rendered at this size and shrunk.
MIN_RENDER_PX = 160
EXTRA_COLOUR = "#5b8fd9"   # external colliders (spheres, capsules, meshes of a scene)
BACKGROUND = ("#16181d", "#3b404c")  # bottom, top of the gradient
TEXT_COLOUR = "#f0f0f0"

#: Categorical colours for muscles: strong, mutually distinct, none close to skin or ivory.
PALETTE = (
    "#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45",
    "#469990", "#9a6324", "#800000", "#aaffc3", "#808000", "#000075", "#dcbeff", "#ff6f91",
    "#2f4f4f", "#ffe119", "#6a5acd", "#ff4500", "#20b2aa", "#8b008b", "#556b2f", "#d2691e",
)
#: Facial muscles with a colour of their own (index into :data:`PALETTE`), so a muscle keeps
#: its colour in every model and picture; other names take the unused colours in name order.
KNOWN_MUSCLES = (
    "zygomaticus_major", "levator_labii_superioris", "orbicularis_oris", "depressor_anguli_oris",
    "frontalis", "buccinator", "corrugator_supercilii", "mentalis", "risorius", "masseter",
    "depressor_labii_inferioris", "levator_anguli_oris", "temporalis", "procerus",
    "orbicularis_oculi", "zygomaticus_minor", "platysma", "nasalis",
    "levator_labii_superioris_alaeque_nasi", "depressor_septi", "incisivus", "pterygoid",
    "digastric", "auricularis",
)

_SIDE_SUFFIX = re.compile(r"[_\-. ](l|r|left|right)$", re.IGNORECASE)


def pyvista_offscreen():
    """pyvista, set up for off-screen rendering; imported on first use (it takes about a second)."""
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and ctypes.util.find_library("EGL"):
        # Without an X server VTK first tries X (printing a warning), then EGL: go to EGL directly.
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista

    pyvista.OFF_SCREEN = True
    return pyvista


def muscle_base_name(name: str) -> str:
    """Muscle name without its side suffix: ``"zygomaticus_major_L"`` -> ``"zygomaticus_major"``."""
    return _SIDE_SUFFIX.sub("", name)


def muscle_colours(names) -> dict[str, str]:
    """Hex colour per muscle name; the left and right muscle of a pair share one colour."""
    bases = sorted({muscle_base_name(n) for n in names})
    fixed = {b: PALETTE[KNOWN_MUSCLES.index(b.lower()) % len(PALETTE)]
             for b in bases if b.lower() in KNOWN_MUSCLES}
    spare = [c for c in PALETTE if c not in fixed.values()] or list(PALETTE)
    others = [b for b in bases if b not in fixed]
    fixed.update({b: spare[i % len(spare)] for i, b in enumerate(others)})
    return {n: fixed[muscle_base_name(n)] for n in names}


def _collider_colour(name: str) -> str:
    low = name.lower()
    if "teeth" in low or "tooth" in low or "incisor" in low or "molar" in low:
        return TEETH_COLOUR
    if "eye" in low:
        return EYE_COLOUR
    if "gum" in low or "gingiva" in low:
        return GUM_COLOUR
    return OTHER_COLLIDER_COLOUR


def _check(view: str, show) -> tuple[str, ...]:
    if view not in VIEWS:
        raise FacesimError(f"view: unknown view {view!r}; expected one of {', '.join(VIEWS)}")
    show = (show,) if isinstance(show, str) else tuple(show)
    unknown = [s for s in show if s not in LAYERS]
    if unknown:
        raise FacesimError(f"show: unknown layer {unknown[0]!r}; expected some of {', '.join(LAYERS)}")
    return show


def check_color_by(model: FaceModel, color_by: str, a) -> np.ndarray | None:
    """Validate ``color_by`` (one of :data:`COLOR_BY`) and the activations it needs; return ``a``
    as ``(n_muscles,)`` float64 (None unless colouring by activation)."""
    if color_by not in COLOR_BY:
        raise FacesimError(f"color_by: unknown colouring {color_by!r}; expected one of {', '.join(COLOR_BY)}")
    if color_by != "activation":
        return None
    if a is None:
        raise FacesimError("color_by='activation': needs the frame's activations a (a model at rest has none)")
    a = np.asarray(a, dtype=np.float64).ravel()
    if a.shape != (model.n_muscles,) or not np.isfinite(a).all():
        raise FacesimError(f"a: expected {model.n_muscles} finite activations, got shape {a.shape}")
    return a


def polydata(vertices: np.ndarray, faces: np.ndarray):
    """pyvista.PolyData of a triangle surface ``vertices (k, 3)``, ``faces (l, 3)``."""
    cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces.astype(np.int64)])
    return pyvista_offscreen().PolyData(np.asarray(vertices, dtype=np.float64), cells.ravel())


def bone_motion(model: FaceModel, x) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per bone, the affine map ``(A (3, 3), t (3,))`` carrying rest to current positions.

    Fitted by least squares to the bone's attached nodes (exact when they move affinely, as
    the cranium and jaw frames do); the identity when ``x`` is None, and a pure translation
    when a bone has too few non-coplanar nodes to fix an affine map.
    """
    identity = (np.eye(3), np.zeros(3))
    motion = {"cranium": identity, "jaw": identity}
    if x is None:
        return motion
    x = np.asarray(x, dtype=np.float64)
    for bone, nodes in (("cranium", model.cranium_nodes), ("jaw", model.jaw_nodes)):
        if not len(nodes):
            continue
        X0, x0 = model.X[nodes], x[nodes]
        H = np.hstack([X0, np.ones((len(nodes), 1))])
        if len(nodes) >= 4 and np.linalg.matrix_rank(H) == 4:
            M = np.linalg.lstsq(H, x0, rcond=None)[0]  # (4, 3): x = X A^T + t
            motion[bone] = (M[:3].T, M[3])
        else:
            motion[bone] = (np.eye(3), (x0 - X0).mean(axis=0))
    return motion


def _add_surfaces(plotter, model: FaceModel, x, show) -> None:
    motion = bone_motion(model, x)
    groups = (("bones", model.bones, lambda s: BONE_COLOUR),
              ("colliders", model.colliders, lambda s: _collider_colour(s.name)))
    for layer, surfaces, colour in groups:
        if layer not in show:
            continue
        for s in surfaces:
            A, t = motion[s.bone]
            mesh = polydata(s.vertices @ A.T + t, s.faces)
            plotter.add_mesh(mesh, color=colour(s), smooth_shading=True, specular=0.25)


#: The four faces of a positively oriented tet (a, b, c, d), outward normals.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def muscle_surfaces(model: FaceModel, threshold: float) -> list[tuple[int, np.ndarray]]:
    """Per muscle with tets of volume fraction > ``threshold``: ``(m, faces (k, 3) int64)``, the
    boundary triangles of those tets in model node indices (so any ``x (n, 3)`` poses them)."""
    mus = model.muscles
    out = []
    for m in range(model.n_muscles):
        sl = mus.entries(m)
        cells = mus.tet[sl][mus.fraction[sl] > threshold]
        if not len(cells):
            continue
        faces = model.tets[cells][:, _TET_FACES].reshape(-1, 3).astype(np.int64)
        _, inverse, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
        out.append((m, faces[counts[inverse.ravel()] == 1]))
    return out


def activation_colour(a: float) -> str:
    """Hex colour of activation ``a`` in [0, 1] on :data:`ACTIVATION_CMAP`."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    return to_hex(colormaps[ACTIVATION_CMAP](float(np.clip(a, 0.0, 1.0))))


def add_muscles(plotter, model: FaceModel, points, threshold: float, a=None, name: str | None = None):
    """Draw each muscle's tets with fraction > threshold, in its own colour, or with ``a (n_muscles,)``
    in the colour of its activation (:data:`ACTIVATION_CMAP`). Returns the legend entries
    ``[(base name, colour)]`` of the muscles drawn (none when coloured by activation).
    ``name``: actor name prefix, so a sequence replaces the muscles of the previous frame."""
    colours = muscle_colours(model.muscles.names)
    legend = {}
    for m, faces in muscle_surfaces(model, threshold):
        muscle = model.muscles.names[m]
        colour = colours[muscle] if a is None else activation_colour(a[m])
        plotter.add_mesh(polydata(points, faces), color=colour, smooth_shading=False, specular=0.2,
                         name=None if name is None else f"{name}{m}")
        legend.setdefault(muscle_base_name(muscle), colours[muscle])
    return [] if a is not None else sorted(legend.items())


def skin_displacement(model: FaceModel, x) -> np.ndarray:
    """(n,) float64 |x - X| per node, mm (zero at rest, ``x`` None)."""
    return np.zeros(model.n_nodes) if x is None else np.linalg.norm(np.asarray(x, dtype=np.float64) - model.X, axis=1)


def colour_bar(color_by: str, model: FaceModel, x, a):
    """The colour bar ``(label, low, high, cmap)`` of ``color_by`` (None for ``"none"``): displacement
    from 0 to the largest skin displacement (mm), activation from 0 to 1."""
    if color_by == "displacement":
        d = skin_displacement(model, x)[np.unique(model.skin)] if len(model.skin) else np.zeros(1)
        return ("|x - X| mm", 0.0, max(float(d.max()), 1e-3), DISPLACEMENT_CMAP)
    if color_by == "activation":
        return ("activation", 0.0, 1.0, ACTIVATION_CMAP)
    return None


def _add_markers(plotter, model: FaceModel, x) -> None:
    if not model.n_markers:
        return
    lo, hi = model.bounding_box()
    radius = 0.008 * float(np.linalg.norm(hi - lo))
    p = model.marker_positions(x)
    pv = pyvista_offscreen()
    sphere = pv.Sphere(radius=radius, theta_resolution=12, phi_resolution=12)
    for mask, colour in ((~model.markers.head, MARKER_COLOUR), (model.markers.head, HEAD_MARKER_COLOUR)):
        if mask.any():
            glyphs = pv.PolyData(p[mask]).glyph(geom=sphere, scale=False, orient=False)
            plotter.add_mesh(glyphs, color=colour, smooth_shading=True)


def set_camera(plotter, points: np.ndarray, view: str, fit_drawn: bool = True) -> None:
    """Camera looking along ``view`` at the bounding box of ``points``. ``fit_drawn``: fit the
    distance to what is drawn (VTK's reset); otherwise to the box of ``points`` alone, so a
    sequence framed on the same points keeps one camera."""
    direction, up = (np.asarray(v, dtype=np.float64) for v in VIEWS[view])
    direction /= np.linalg.norm(direction)
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    if fit_drawn:
        distance = 3.0 * float(np.linalg.norm(hi - lo)) + 1.0
    else:
        angle = np.deg2rad(plotter.camera.view_angle)
        distance = 0.5 * float(np.linalg.norm(hi - lo)) / np.sin(angle / 2) / 1.35
    plotter.camera_position = [tuple(centre + distance * direction), tuple(centre), tuple(up)]
    if fit_drawn:
        plotter.reset_camera()  # keeps the direction, fits the distance to what is drawn
        plotter.camera.zoom(1.35)  # reset_camera fits the bounding sphere, which leaves wide margins
    else:
        plotter.reset_camera_clipping_range()


def render_image(model: FaceModel, view: str = "front", show=DEFAULT_SHOW, skin_opacity: float | None = None,
                 size=(1200, 1200), x=None, legend: bool = True, title: str | None = None,
                 muscle_threshold: float = 0.3, frame_on=None, extra=(), *, color_by: str = "none",
                 a=None) -> np.ndarray:
    """Render the model and return the picture as an ``(h, w, 3)`` uint8 RGB array.

    Parameters are those of :func:`render_model` (without the path).
    """
    show = _check(view, show)
    a = check_color_by(model, color_by, a)
    points = model.X if x is None else np.asarray(x, dtype=np.float64)
    if points.shape != model.X.shape:
        raise FacesimError(f"x: expected node positions of shape {model.X.shape}, got {points.shape}")
    if skin_opacity is None:
        skin_opacity = ACTIVATION_SKIN_OPACITY if color_by == "activation" else SKIN_OPACITY
    if not 0.0 <= skin_opacity <= 1.0:
        raise FacesimError(f"skin_opacity: expected a value in [0, 1], got {skin_opacity}")
    out_size = tuple(int(v) for v in size)
    if len(out_size) != 2 or min(out_size) < 1:
        raise FacesimError(f"size: expected (width, height) in pixels >= 1, got {tuple(size)}")
    # VTK cannot make an off-screen surface for tiny windows (EGL fails below ~100 px, and a window
    # narrower than its legend panel aborts): small pictures are rendered at MIN_RENDER_PX and shrunk
    scale = max(1.0, MIN_RENDER_PX / min(out_size))
    width, height = (int(round(v * scale)) for v in out_size)
    skin = "skin" in show and len(model.skin)
    # an opaque skin hides the muscles: then no muscle legend (and no activation colour bar)
    muscles_seen = "muscles" in show and not (skin and skin_opacity >= 1.0)
    bar = colour_bar(color_by, model, points, a) if legend else None
    if color_by == "displacement" and not skin or color_by == "activation" and not muscles_seen:
        bar = None
    plotter = pyvista_offscreen().Plotter(off_screen=True, window_size=(width, height))
    try:
        plotter.set_background(BACKGROUND[0], top=BACKGROUND[1])
        entries = []
        if "muscles" in show:
            entries = add_muscles(plotter, model, points, muscle_threshold, a)
        _add_surfaces(plotter, model, x, show)
        if "markers" in show:
            _add_markers(plotter, model, x)
        for vertices, faces in extra:   # external colliders (world frame)
            plotter.add_mesh(polydata(np.asarray(vertices, dtype=np.float64), np.asarray(faces)), color=EXTRA_COLOUR,
                             smooth_shading=True, specular=0.4)
        if skin:
            # No depth peeling: it renders blank on Mesa's llvmpipe through EGL. VTK draws
            # translucent actors after the opaque ones, which is enough for one skin layer.
            add_skin(plotter, model, points, skin_opacity, bar if color_by == "displacement" else None)
        entries = entries if legend and muscles_seen else []
        panel = legend_layout(entries, (width, height), bar)[2]
        if panel:
            plotter.window_size = (width - panel, height)
        if frame_on is None:
            set_camera(plotter, points, view)
        else:   # a camera that does not move between the frames of a sequence
            set_camera(plotter, np.asarray(frame_on, dtype=np.float64), view, fit_drawn=False)
        image = plotter.screenshot(None, return_img=True)
    finally:
        plotter.close()
    image = annotate(np.ascontiguousarray(image[..., :3]), entries, title, (width, height), bar)
    if (width, height) != out_size:
        from PIL import Image

        image = np.asarray(Image.fromarray(image).resize(out_size, Image.Resampling.LANCZOS))
    return image


def add_skin(plotter, model: FaceModel, points, opacity: float, bar=None, name: str | None = None) -> None:
    """Draw the skin at ``points (n, 3)``: in the skin colour, or with the displacement colour
    ``bar`` (from :func:`colour_bar`) coloured by ``|x - X|`` per node."""
    mesh = polydata(points, model.skin)
    if bar is None:
        plotter.add_mesh(mesh, color=SKIN_COLOUR, opacity=opacity, smooth_shading=True, specular=0.1, name=name)
        return
    _, low, high, cmap = bar
    mesh.point_data["displacement"] = np.linalg.norm(np.asarray(points) - model.X, axis=1)
    plotter.add_mesh(mesh, scalars="displacement", cmap=cmap, clim=(low, high), opacity=opacity,
                     smooth_shading=True, specular=0.1, show_scalar_bar=False, name=name)


def _bar_labels(bar) -> list[str]:
    label, low, high, _ = bar
    digits = 0 if high >= 20 else 1 if high >= 2 else 2
    return [label] + [f"{v:.{digits}f}" for v in (high, 0.5 * (low + high), low)]


def legend_layout(entries, size, bar=None):
    """Font, line height and width of the legend panel drawn right of the picture (0 without legend).

    ``entries`` : ``[(name, colour)]`` swatches; ``bar`` : an optional colour bar
    ``(label, low, high, cmap)`` drawn below them."""
    from PIL import ImageDraw, ImageFont, Image

    w, h = size
    px = max(10, min(w, h) // 60)
    font = ImageFont.load_default(size=px)
    if not entries and bar is None:
        return font, px, 0
    draw = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    labels = [name.replace("_", " ") for name, _ in entries] + ([] if bar is None else _bar_labels(bar))
    text_w = max(draw.textlength(t, font=font) for t in labels)
    # never more than a third of the picture: shrink the font for long legends on small pictures
    while 4 * (px // 2) + px + text_w > 0.32 * w and px > 6:
        px -= 1
        font = ImageFont.load_default(size=px)
        text_w = max(draw.textlength(t, font=font) for t in labels)
    if 4 * (px // 2) + px + text_w > 0.4 * w:   # no room for a legible legend: none
        return font, px, 0
    return font, px, int(4 * (px // 2) + px + text_w)


def annotate(image: np.ndarray, entries, title: str | None, size, bar=None) -> np.ndarray:
    """Add the muscle legend and colour bar as a panel right of the rendered view, and the caption (lower left).

    ``image`` is the 3D view, narrower than ``size`` by the legend panel; the result has ``size``.
    ``bar`` : optional ``(label, low, high, cmap)``, a vertical colour bar below the swatches.
    Drawn with PIL rather than VTK so that labels stay white and legible whatever the muscle
    colour, look the same at every picture size, and never cover the face.
    """
    w, h = size
    if not entries and bar is None and not title and image.shape[1] == w:
        return image
    from PIL import Image, ImageDraw, ImageFont

    font, px, panel = legend_layout(entries, size, bar)
    entries, bar = (entries, bar) if panel else ([], None)
    canvas = Image.new("RGB", (w, h), BACKGROUND[0])
    canvas.paste(Image.fromarray(image), (0, 0))
    draw = ImageDraw.Draw(canvas)
    line, pad, swatch = int(1.45 * px), px // 2, px
    x0, y0 = w - panel, pad
    labels = [name.replace("_", " ") for name, _ in entries]
    for k, (label, (_, colour)) in enumerate(zip(labels, entries)):
        y = y0 + pad + k * line
        draw.rectangle([x0 + pad, y + (line - swatch) // 2, x0 + pad + swatch, y + (line + swatch) // 2],
                       fill=colour, outline=TEXT_COLOUR)
        draw.text((x0 + 2 * pad + swatch, y + line // 2), label, font=font, fill=TEXT_COLOUR, anchor="lm")
    if bar is not None:
        from matplotlib import colormaps

        name, high, mid, low = _bar_labels(bar)
        top = y0 + pad + len(entries) * line + (line if entries else 0)
        draw.text((x0 + pad, top + line // 2), name, font=font, fill=TEXT_COLOUR, anchor="lm")
        top += line + line // 2
        bottom = min(h - 3 * line, top + max(4 * line, h // 3))
        if bottom > top + line:
            ramp = colormaps[bar[3]](np.linspace(1.0, 0.0, bottom - top))[:, :3]   # high at the top
            strip = np.repeat((255 * ramp[:, None, :]).astype(np.uint8), swatch, axis=1)
            canvas.paste(Image.fromarray(strip), (x0 + pad, top))
            draw.rectangle([x0 + pad, top, x0 + pad + swatch, bottom], outline=TEXT_COLOUR)
            for text, y in ((high, top), (mid, (top + bottom) // 2), (low, bottom)):
                draw.text((x0 + 2 * pad + swatch, y), text, font=font, fill=TEXT_COLOUR, anchor="lm")
    if title:
        draw.text((px, h - px), title, font=ImageFont.load_default(size=int(1.4 * px)), fill=TEXT_COLOUR,
                  anchor="ls")
    return np.asarray(canvas)


def save_png(image: np.ndarray, path) -> Path:
    from PIL import Image

    path = require_suffix(path, (".png",), "a picture file name")
    return atomic_write(path, lambda tmp: Image.fromarray(image).save(tmp, format="PNG"))


def render_model(model: FaceModel, path, view: str = "front", show=DEFAULT_SHOW, skin_opacity: float | None = None,
                 size=(1200, 1200), x=None, legend: bool = True, title: str | None = None,
                 muscle_threshold: float = 0.3, frame_on=None, extra=(), *, color_by: str = "none",
                 a=None) -> Path:
    """Render one view of the model to a PNG and return its path.

    Parameters
    ----------
    model : FaceModel.
    path : output file, ``.png``.
    view : one of :data:`VIEWS` (``front``, ``side``, ``three_quarter``, ``top``, ``bottom``).
    show : layers to draw, some of :data:`LAYERS`: the skin, bones (ivory), colliders (teeth,
        eyes, gums), muscles (boundary of the tets where the muscle's volume fraction exceeds
        ``muscle_threshold``; one colour per muscle, shared by a left/right pair) and markers
        (small spheres; head markers yellow, the others cyan).
    skin_opacity : in [0, 1]; None: opaque (:data:`SKIN_OPACITY`), or
        :data:`ACTIVATION_SKIN_OPACITY` with ``color_by="activation"`` so the muscles show.
        The muscle legend is drawn only where the muscles can be seen (not under an opaque skin).
    size : (width, height) in pixels.
    x : (n, 3) float64 current node positions, mm, or None for the rest shape; bones and
        colliders then follow the affine motion of their attached nodes (:func:`bone_motion`).
    legend : draw a legend of the muscle names shown (and the colour bar of ``color_by``).
    title : optional caption in the lower left corner.
    frame_on : optional ``(k, 3)`` points (e.g. ``model.X``) the camera is fitted to instead of
        what is drawn, so the frames of a sequence share one camera.
    extra : ``(vertices (nv, 3), faces (nf, 3))`` surfaces to draw as well, in world mm (external
        colliders, e.g. ``Collider.surface()``).
    color_by : one of :data:`COLOR_BY`: ``"none"``; ``"displacement"``, the skin coloured by
        ``|x - X|`` per node (mm, :data:`DISPLACEMENT_CMAP` from 0 to the frame's largest skin
        displacement, shown in a colour bar); ``"activation"``, each muscle coloured by its
        activation ``a`` (:data:`ACTIVATION_CMAP` from 0 to 1, colour bar) instead of its own colour.
    a : (n_muscles,) float64 activations of the frame, in [0, 1]; required by ``color_by="activation"``.
    """
    return save_png(render_image(model, view, show, skin_opacity, size, x, legend, title, muscle_threshold,
                                  frame_on, extra, color_by=color_by, a=a), path)


def tile_images(images, columns: int | None = None, fill=BACKGROUND[0]) -> np.ndarray:
    """Tile equally sized ``(h, w, 3)`` uint8 images row by row into one image.

    ``columns`` defaults to ceil(sqrt(len(images))); empty cells are filled with ``fill``.
    """
    images = list(images)
    if not images:
        raise FacesimError("contact sheet: expected at least one view")
    h, w = images[0].shape[:2]
    columns = columns or math.ceil(math.sqrt(len(images)))
    rows = math.ceil(len(images) / columns)
    rgb = np.array([int(fill[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.uint8)
    sheet = np.empty((rows * h, columns * w, 3), dtype=np.uint8)
    sheet[:] = rgb
    for k, image in enumerate(images):
        r, c = divmod(k, columns)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = image
    return sheet


def render_contact_sheet(model: FaceModel, path, views=("front", "side", "three_quarter", "top"),
                         show=DEFAULT_SHOW, skin_opacity: float | None = None, tile_size=(600, 600), x=None,
                         columns: int | None = None, progress: bool = True, muscle_threshold: float = 0.3, *,
                         legend: bool = True, color_by: str = "none", a=None) -> Path:
    """Render several views, each captioned with its name, tiled into one PNG; return its path.

    ``views`` : names from :data:`VIEWS`; ``tile_size`` : (width, height) of one view in pixels;
    ``columns`` : views per row (default: a square-ish grid); the muscle legend (``legend``) is drawn in
    the first view only (so is the colour bar). Other parameters as in :func:`render_model`. A tqdm bar on stderr
    reports progress unless ``progress`` is False.
    """
    from tqdm import tqdm

    views = (views,) if isinstance(views, str) else tuple(views)
    for v in views:
        _check(v, show)
    images = [render_image(model, v, show, skin_opacity, tile_size, x, legend=legend and k == 0,
                           title=v.replace("_", " "), muscle_threshold=muscle_threshold, color_by=color_by, a=a)
              for k, v in enumerate(tqdm(views, desc="rendering views", unit="view", disable=not progress))]
    return save_png(tile_images(images, columns), path)
