"""The numbered examples run at small size."""

import importlib.util
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_01_expressions(tmp_path):
    ex = _load("01_expressions")
    results = ex.main(["--out", str(tmp_path), "--size", "160", "--only", "rest", "smile", "jaw_open"])
    assert set(results) == {"rest", "smile", "jaw_open"}
    assert all(r.converged for r in results.values())
    from PIL import Image

    sheet = np.asarray(Image.open(tmp_path / "expressions.png"))
    assert sheet.shape == (320, 320, 3) and sheet.std() > 10
    assert (tmp_path / "smile.png").is_file()
    # the smile and the open jaw change the face; rest does not
    rest = results["rest"].x
    assert np.abs(results["smile"].x - rest).max() > 2.0
    assert np.abs(results["jaw_open"].x - rest).max() > 10.0


def test_00_uniaxial_block():
    rows = _load("00_uniaxial_block").main(["--cells", "2"])
    assert len(rows) == 10
    for vol, stretch, fe, exact in rows:
        assert abs(fe - exact) <= 1e-6 * abs(exact), (vol, stretch)


def test_02_jaw_and_contact(tmp_path):
    """A short run of the jaw-and-contact example: small opening, a shallow press (the full
    example opens to the maximum and presses 10 mm)."""
    ex = _load("02_jaw_and_contact")
    rows = ex.main(["--out", str(tmp_path), "--frames", "8", "--max-opening", "0.12", "--press", "3",
                    "--size", "96"])
    frame, opening, slide, smile, depth, converged, iterations, penetration, inverted, seconds = map(list, zip(*rows))
    assert len(rows) == 8 and all(converged) and max(inverted) == 0
    assert max(opening) == 0.12 and max(smile) == 1.0 and max(depth) == 3.0
    assert max(penetration) < 0.5 and penetration[depth.index(3.0)] > 0.0   # the ball touched the cheek
    assert len(list((tmp_path / "png").glob("frame_*.png"))) == 8
    assert (tmp_path / "video.mp4").is_file() or (tmp_path / "video.gif").is_file()
    assert (tmp_path / "frames.csv").read_text().count("\n") == 9


def test_04_editing(tmp_path):
    ex = _load("04_editing")
    results = ex.main(["--out", str(tmp_path), "--size", "96", "--steps", "3", "--splice-frames", "8"])
    seq = results.pop("splice_sequence")
    assert all(eq.converged for group in results.values() for eq in group)
    assert seq.n_frames == 4 + 8 and list(seq.frames) == list(range(12))   # a's frames 0-3, then b's 8
    assert np.abs(np.diff(seq.A, axis=0)).max() < 0.35                      # the cross-fade: no jump at the join
    model = ex.load_model(ex.Path(ex.__file__).resolve().parent.parent / "meshes" / "face_coarse.npz")
    scaled = [ex.corner_motion(model, eq.x) for eq in results["scale"]]
    gained = [ex.corner_motion(model, eq.x) for eq in results["gain"]]
    assert scaled[0] < scaled[1] <= scaled[2] + 1e-9          # activation scaling saturates at 1
    assert gained[0] < gained[1] < gained[2]                  # the gain goes on
    assert gained[2] > scaled[2] + 1.0                        # beyond what activation 1 can do (mm)
    assert (tmp_path / "blend.png").is_file() and (tmp_path / "exaggeration.png").is_file()
    assert (tmp_path / "splice.png").is_file() and (tmp_path / "splice_strip.png").is_file()


def test_06_dynamics(tmp_path):
    r = _load("06_dynamics").main(["--out", str(tmp_path), "--frames", "3", "--substeps", "2", "--no-video"])
    qs, dy = r["quasistatic"], r["dynamic"]
    assert np.abs(qs - qs[0]).max() < 0.05        # quasistatically the shaken face only turns (mm, head frame)
    assert r["gap_mm"] > 0.05                     # dynamically the soft nose lags
    assert (tmp_path / "nose_path.png").is_file()


def test_07_teeth_tracking(tmp_path):
    r = _load("07_teeth_tracking").main(["--out", str(tmp_path), "--size", "480x270", "--frames", "12", "--every", "2",
                                         "--start", "48", "--iterations", "100"])
    ok = ~r["flagged"]
    assert ok.sum() >= 8 and r["mm"][ok].mean() < 1.0
    assert r["rig"] is not None and (tmp_path / "teeth_tracking.png").is_file()
