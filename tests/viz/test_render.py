"""Off-screen rendering: files written, pictures not blank, cameras pointing the right way."""

import numpy as np
import pytest
from PIL import Image

from facesim.errors import FacesimError
from facesim.viz.render import (ACTIVATION_CMAP, DISPLACEMENT_CMAP, KNOWN_MUSCLES, LAYERS, PALETTE, bone_motion,
                                muscle_base_name, muscle_colours, render_contact_sheet, render_image, render_model,
                                tile_images)

SIZE = (240, 200)  # width, height: not square, so a transposed picture would show


def red_mask(img):
    """Pixels of the zygomaticus colour (#e6194b, shaded): strongly red."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > 90) & (r > 2 * g) & (r > 1.5 * b)


def blue_mask(img):
    """Pixels of the orbicularis oris colour (#4363d8, shaded): strongly blue."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (b > 90) & (b > 1.6 * r) & (b > 1.2 * g)


def centre(mask):
    """(column, row) mean of a non-empty mask, as fractions of width and height."""
    rows, cols = np.nonzero(mask)
    assert len(rows) > 50, "colour not found in the picture"
    return cols.mean() / mask.shape[1], rows.mean() / mask.shape[0]


def test_render_model_writes_non_blank_png(box_model, tmp_path):
    path = render_model(box_model, tmp_path / "pics" / "front.png", size=SIZE, skin_opacity=0.35)
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (SIZE[1], SIZE[0], 3)
    assert img.reshape(-1, 3).std(axis=0).max() > 15.0  # not a blank picture
    assert red_mask(img).sum() > 50 and blue_mask(img).sum() > 50


def test_front_view_shows_subjects_left_on_the_right(box_model):
    # zygomaticus_major_L lies at x > 5 (subject's left): a front view shows it right of centre,
    # and above the orbicularis oris (y < 0)
    img = render_image(box_model, "front", show=("muscles",), size=SIZE, legend=False)
    (zx, zy), (ox, oy) = centre(red_mask(img)), centre(blue_mask(img))
    assert zx > 0.55 and zx > ox and zy < oy


def test_side_view_shows_nose_on_the_left(box_model):
    # from +x with y up, +z (the nose side, where both muscles are) is to the viewer's left
    img = render_image(box_model, "side", show=("muscles", "bones"), size=SIZE, legend=False)
    (zx, _), (ox, _) = centre(red_mask(img)), centre(blue_mask(img))
    assert zx < 0.5 and ox < 0.5


def test_top_view_has_nose_up_and_left_on_the_left(box_model):
    # the cranium box lies at z < -25, behind both muscles (z > 0); the zygomaticus is left of the
    # orbicularis oris (x > 5 against |x| < 15)
    img = render_image(box_model, "top", show=("muscles", "bones"), size=SIZE, legend=False)
    (zx, zy), (ox, oy) = centre(red_mask(img)), centre(blue_mask(img))
    assert zy < 0.5 and oy < 0.5  # z > 0 is up in the picture
    assert zx < ox  # seen from above with the nose up, the subject's left is on the left


def test_hiding_layers_changes_the_picture(box_model):
    full = render_image(box_model, "three_quarter", size=SIZE, legend=False, skin_opacity=0.35)
    no_muscles = render_image(box_model, "three_quarter", show=("skin", "bones", "colliders", "markers"),
                              size=SIZE, legend=False, skin_opacity=0.35)
    assert red_mask(full).sum() > 50 and red_mask(no_muscles).sum() == 0


def test_legend_adds_pixels(box_model):
    plain = render_image(box_model, "front", size=SIZE, legend=False, skin_opacity=0.35)
    legend = render_image(box_model, "front", size=SIZE, legend=True, skin_opacity=0.35)
    assert np.abs(plain.astype(int) - legend.astype(int)).sum() > 0


def test_contact_sheet_tiles_views(box_model, tmp_path):
    path = render_contact_sheet(box_model, tmp_path / "sheet.png", views=("front", "side", "top"),
                                tile_size=(120, 100), progress=False)
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (200, 240, 3)  # 2 x 2 grid of 120 x 100 tiles, one empty
    empty = img[100:, 120:]
    assert (empty == empty[0, 0]).all() and img[:100, :120].std() > 10


def test_tile_images_layout():
    tiles = [np.full((2, 3, 3), k, dtype=np.uint8) for k in range(5)]
    sheet = tile_images(tiles, columns=2)
    assert sheet.shape == (6, 6, 3)
    assert sheet[0, 0, 0] == 0 and sheet[0, 3, 0] == 1 and sheet[2, 0, 0] == 2 and sheet[4, 0, 0] == 4


@pytest.mark.parametrize("name, base", [("zygomaticus_major_L", "zygomaticus_major"), ("masseter", "masseter"),
                                        ("temporal", "temporal"), ("buccinator-right", "buccinator"),
                                        ("mentalis", "mentalis"), ("risorius R", "risorius")])
def test_muscle_base_name(name, base):
    assert muscle_base_name(name) == base


def test_muscle_colours_pairs_share_and_names_keep_their_colour():
    names = ["zygomaticus_major_L", "zygomaticus_major_R", "risorius_L", "mystery_L", "mystery_R", "other"]
    c = muscle_colours(names)
    assert c["zygomaticus_major_L"] == c["zygomaticus_major_R"] and c["mystery_L"] == c["mystery_R"]
    assert len({c[n] for n in ("zygomaticus_major_L", "risorius_L", "mystery_L", "other")}) == 4
    # a catalogue muscle has the same colour whatever else is in the model
    assert muscle_colours(["zygomaticus_major_L"])["zygomaticus_major_L"] == c["zygomaticus_major_L"]
    many = muscle_colours(list(KNOWN_MUSCLES))
    assert len(set(many.values())) == min(len(KNOWN_MUSCLES), len(PALETTE))


def test_bone_motion_recovers_affine_maps(box_model):
    rng = np.random.default_rng(0)
    A, t = np.eye(3) + 0.1 * rng.normal(size=(3, 3)), rng.normal(size=3)
    x = box_model.X.copy()
    x[box_model.jaw_nodes] = box_model.X[box_model.jaw_nodes] @ A.T + t
    motion = bone_motion(box_model, x)
    # the jaw nodes of the box lie in one plane (z = -20): only a translation can be fitted
    assert np.allclose(motion["cranium"][0], np.eye(3)) and np.allclose(motion["cranium"][1], 0)
    jaw_nodes = box_model.jaw_nodes
    fitted = box_model.X[jaw_nodes] + motion["jaw"][1]
    np.testing.assert_allclose(fitted.mean(0), x[jaw_nodes].mean(0))
    x2 = box_model.X @ A.T + t  # everything moves affinely: the cranium map is recovered exactly
    np.testing.assert_allclose(bone_motion(box_model, x2)["cranium"][0], A, atol=1e-9)
    np.testing.assert_allclose(bone_motion(box_model, x2)["cranium"][1], t, atol=1e-9)


@pytest.mark.parametrize("kwargs, words", [
    (dict(view="back"), "unknown view 'back'"),
    (dict(show=("skin", "hair")), "unknown layer 'hair'"),
    (dict(skin_opacity=1.5), "skin_opacity"),
])
def test_bad_arguments_are_one_line_errors(box_model, tmp_path, kwargs, words):
    with pytest.raises(FacesimError) as info:
        render_model(box_model, tmp_path / "x.png", size=SIZE, **kwargs)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_png_suffix_required(box_model, tmp_path):
    with pytest.raises(FacesimError, match="x.jpg: expected a picture file name ending in .png"):
        render_model(box_model, tmp_path / "x.jpg", size=SIZE)
    assert set(LAYERS) == {"skin", "bones", "colliders", "muscles", "markers"}


def test_fixed_camera_shows_motion_that_a_fitted_camera_hides(box_model):
    shift = np.array([15.0, 0.0, 0.0])   # to the subject's left: the viewer's right in the front view
    x = box_model.X + shift
    kw = dict(show=("muscles",), size=SIZE, legend=False)
    fitted = centre(blue_mask(render_image(box_model, "front", x=x, **kw)))
    fitted_rest = centre(blue_mask(render_image(box_model, "front", **kw)))
    rest = centre(blue_mask(render_image(box_model, "front", frame_on=box_model.X, **kw)))
    moved = centre(blue_mask(render_image(box_model, "front", x=x, frame_on=box_model.X, **kw)))
    assert moved[0] > rest[0] + 0.05          # with a fixed camera the face moves across the picture
    assert abs(fitted[0] - fitted_rest[0]) < 0.02    # a camera fitted to each frame follows it


@pytest.mark.parametrize("size", ["16x16", "64x64", "40x300"])
def test_tiny_pictures_of_a_full_model_render(size, tmp_path):
    """A model with a long muscle legend at picture sizes where VTK cannot make its surface (below
    ~100 px) or the legend is wider than the picture: rendered large and shrunk, the legend dropped
    where it cannot be read; a separate process, since VTK aborts the process when it fails."""
    import subprocess
    import sys

    from facesim._files import MESHES

    out = tmp_path / "tiny.png"
    run = subprocess.run([sys.executable, "-m", "facesim", "model", "render", str(MESHES / "face_coarse.npz"),
                          "-o", str(out), "--size", size], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-500:]
    assert "ERR|" not in run.stderr and "Traceback" not in run.stderr
    w, h = (int(v) for v in size.split("x"))
    image = np.asarray(Image.open(out))
    assert image.shape[:2] == (h, w) and image.std() > 5   # not blank


# ---------------------------------------------------------------- opaque skin, colouring by displacement / activation
def colour_mask(img, hex_colour, tol=0.07):
    """Pixels of a colour under any shading: chromaticity (r, g, b) / (r + g + b) within ``tol``."""
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=float)
    px = img.astype(float)
    total = px.sum(-1, keepdims=True)
    near = np.abs(px / np.maximum(total, 1) - rgb / rgb.sum()).max(-1) < tol
    return near & (total[..., 0] > 0.4 * rgb.sum())


def cmap_hex(name, v):
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    return to_hex(colormaps[name](v))


def test_default_skin_is_opaque_and_hides_the_muscles(box_model):
    opaque = render_image(box_model, "front", size=SIZE)
    seen = render_image(box_model, "front", size=SIZE, skin_opacity=0.35)
    assert red_mask(opaque).sum() == 0 and red_mask(seen).sum() > 50
    # no muscle legend under an opaque skin: the legend panel would be drawn on the right
    assert np.array_equal(opaque, render_image(box_model, "front", size=SIZE, legend=False))


def test_color_by_displacement_colours_the_skin_and_draws_a_bar(box_model):
    x = box_model.X.copy()
    x[:, 2] += 0.2 * (box_model.X[:, 0] - box_model.X[:, 0].min())   # 0 mm at the right (x min) to 12 mm at the left
    img = render_image(box_model, "front", x=x, size=(360, 240), color_by="displacement", show=("skin",))
    low, high = colour_mask(img, cmap_hex(DISPLACEMENT_CMAP, 0.0)), colour_mask(img, cmap_hex(DISPLACEMENT_CMAP, 1.0))
    # the front view shows the subject's left (large displacement) on the right of the picture
    assert centre(low)[0] < 0.4 and centre(high)[0] > centre(low)[0] + 0.15
    plain = render_image(box_model, "front", x=x, size=(360, 240), show=("skin",))
    assert colour_mask(plain, cmap_hex(DISPLACEMENT_CMAP, 1.0)).sum() == 0
    # the colour bar in the legend panel: a ramp through the whole map
    from matplotlib import colormaps

    ramp = 255 * colormaps[DISPLACEMENT_CMAP](np.linspace(0, 1, 256))[:, :3]
    panel = img[:, -70:].reshape(-1, 1, 3).astype(float)
    dist = np.linalg.norm(panel - ramp[None], axis=-1)
    on_map = dist.min(axis=1) < 8
    values = dist.argmin(axis=1)[on_map] / 255
    assert on_map.sum() > 300 and values.min() < 0.1 and values.max() > 0.9


def test_color_by_activation_colours_each_muscle_by_its_activation(box_model):
    kw = dict(show=("muscles",), size=SIZE, legend=False, color_by="activation")
    hot, cold = cmap_hex(ACTIVATION_CMAP, 1.0), cmap_hex(ACTIVATION_CMAP, 0.0)
    img = render_image(box_model, "front", a=[1.0, 0.0], **kw)   # zygomaticus (subject's left) active
    assert centre(colour_mask(img, hot))[0] > 0.55 and red_mask(img).sum() == 0
    swapped = render_image(box_model, "front", a=[0.0, 1.0], **kw)
    assert centre(colour_mask(swapped, hot))[0] < centre(colour_mask(img, hot))[0] - 0.1
    assert colour_mask(swapped, cold).sum() > 50


def test_color_by_activation_shows_the_muscles_through_the_skin(box_model):
    img = render_image(box_model, "front", size=SIZE, color_by="activation", a=[1.0, 1.0])
    assert colour_mask(img[:, :-70], cmap_hex(ACTIVATION_CMAP, 1.0), 0.1).sum() > 50   # skin translucent by default


@pytest.mark.parametrize("kwargs, words", [
    (dict(color_by="activation"), "needs the frame's activations"),
    (dict(color_by="activation", a=[0.5]), "expected 2 finite activations"),
    (dict(color_by="speed"), "unknown colouring 'speed'"),
])
def test_bad_colourings_are_one_line_errors(box_model, kwargs, words):
    with pytest.raises(FacesimError, match=words):
        render_image(box_model, size=SIZE, **kwargs)


def test_solve_render_colours_the_simulated_face(box_model, box_model_path, tmp_path):
    """solve-mocap --render --color-by activation: the right panel shows the muscles in the colours of their
    solved activations, with the colour bar."""
    from facesim.cli import main
    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.fem.newton import NewtonOptions
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.mocap.io import write_trc

    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct")),
                        jaw_model=SlidingCondyleJaw(box_model.jaw))
    P = np.array([box_model.marker_positions(sim.equilibrium(Controls([0.6 * k, 0.0], jaw=[0.0, 0, 0])).x)
                  for k in range(2)])
    write_trc(tmp_path / "m.trc", np.arange(2), box_model.markers.names, P, fps=10.0)
    out = tmp_path / "out"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.01", "--solver", "direct", "--no-contact", "--render", "-q",
                 "--color-by", "activation"]) == 0
    right = np.asarray(Image.open(out / "render" / "frame_00001.png").convert("RGB"))[:, 640:]
    from matplotlib import colormaps

    ramp = 255 * colormaps[ACTIVATION_CMAP](np.linspace(0, 1, 256))[:, :3]
    bar = right[:, -110:].reshape(-1, 1, 3).astype(float)
    dist = np.linalg.norm(bar - ramp[None], axis=-1)
    assert (dist.min(axis=1) < 8).sum() > 300   # the colour bar of the activations
