"""The facesim command: outputs, --help everywhere, one-line errors with exit status 2."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
from PIL import Image

from facesim.cli import default_model_path, main
from facesim.model import load_model

from .test_model import bad_model_files

REPO = Path(__file__).resolve().parent.parent


def run(*args, env=None):
    """``python -m facesim.cli ARGS`` in a fresh interpreter: (exit status, stdout, stderr)."""
    full_env = dict(os.environ, PYTHONPATH=str(REPO), **(env or {}))
    p = subprocess.run([sys.executable, "-m", "facesim.cli", *map(str, args)], capture_output=True, text=True,
                       env=full_env, cwd=REPO, timeout=120)
    return p.returncode, p.stdout, p.stderr


def test_info_json_counts(box_model, box_model_path, capsys):
    assert main(["model", "info", str(box_model_path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_nodes"] == 210 and info["n_tets"] == 720
    assert info["n_simulated_tets"] == box_model.n_simulated == 648
    assert info["n_muscles"] == 2 and info["n_markers"] == 6 and info["n_head_markers"] == 2
    assert info["n_cranium_nodes"] == 42 and info["n_jaw_nodes"] == 21
    assert [m["name"] for m in info["muscles"]] == ["zygomaticus_major_L", "orbicularis_oris"]
    assert [m["n_tets"] for m in info["muscles"]] == [64, 49]
    assert [m["name"] for m in info["markers"] if m["head"]] == ["head_L", "head_R"]
    assert info["quality"]["n_inverted"] == 0 and info["quality"]["min_dihedral_deg"] == pytest.approx(45.0)
    assert info["bounding_box_mm"]["size"] == pytest.approx([60.0, 50.0, 40.0])
    assert info["volume_mm3"] == pytest.approx(120000.0)
    assert info["build"] == {"resolution": "synthetic", "seed": 0}


def test_build_calls_the_anatomy_builder_and_saves(box_model, tmp_path, monkeypatch, capsys):
    import facesim.anatomy

    calls = []

    def fake_build_head(resolution="coarse", seed=0, progress=None, mesh=None):
        calls.append((resolution, seed, progress, mesh))
        return box_model

    monkeypatch.setattr(facesim.anatomy, "build_head", fake_build_head, raising=False)
    out = tmp_path / "m.npz"
    assert main(["model", "build", "--resolution", "test", "--seed", "3", "-o", str(out), "-q"]) == 0
    assert calls == [("test", 3, None, None)]
    assert load_model(out).n_tets == 720
    printed = capsys.readouterr().out
    assert "720 tets" in printed and " s: " in printed and str(out) in printed


def test_info_table(box_model_path, capsys):
    assert main(["model", "info", str(box_model_path)]) == 0
    out = capsys.readouterr().out
    for words in ("720  (simulated 648)", "6  (head 2)", "cranium-attached 42", "jaw-attached 21",
                  "zygomaticus_major_L", "head_L*", "mesh quality", "size 60.0 x 50.0 x 40.0 mm"):
        assert words in out


def test_export_volume_skin_and_surfaces(box_model_path, tmp_path, capsys):
    assert main(["model", "export", str(box_model_path), "-o", str(tmp_path / "m.vtu")]) == 0
    mesh = meshio.read(tmp_path / "m.vtu")
    assert len(mesh.cells[0].data) == 720
    assert {"tissue", "simulated", "muscle", "muscle_fraction", "muscle_total_fraction", "fibre"} <= set(mesh.cell_data)
    assert "attachment" in mesh.point_data
    for suffix in (".ply", ".obj"):
        assert main(["model", "export", str(box_model_path), "-o", str(tmp_path / f"skin{suffix}")]) == 0
        assert len(meshio.read(tmp_path / f"skin{suffix}").cells_dict["triangle"]) == 296
    assert main(["model", "export", str(box_model_path), "--surfaces", str(tmp_path / "s")]) == 0
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == sorted(
        ["cranium.ply", "mandible.ply", "teeth_lower.ply", "eye_L.ply"])
    assert "wrote" in capsys.readouterr().out


def test_render_writes_non_blank_png(box_model_path, tmp_path):
    out = tmp_path / "r.png"
    assert main(["model", "render", str(box_model_path), "-o", str(out), "--view", "three_quarter",
                 "--size", "200x160", "--hide", "markers"]) == 0
    img = np.asarray(Image.open(out).convert("RGB"))
    assert img.shape == (160, 200, 3) and img.reshape(-1, 3).std(axis=0).max() > 15
    assert main(["model", "render", str(box_model_path), "-o", str(tmp_path / "s.png"), "--sheet",
                 "--size", "100x100", "-q"]) == 0
    assert Image.open(tmp_path / "s.png").size == (200, 200)


def test_demo_on_a_model_without_the_clip_markers_is_one_line(box_model_path, tmp_path):
    # the full demo run is in tests/mocap/test_demo.py (it takes a while)
    code, out, err = run("demo", "-o", tmp_path / "demo", env={"FACESIM_MODEL": str(box_model_path)})
    assert_one_line_error(code, out, err, "demo_clip.c3d", "markers")
    assert str(box_model_path) in out and not (tmp_path / "demo").exists()


def test_default_model_is_in_the_repository(monkeypatch):
    monkeypatch.delenv("FACESIM_MODEL", raising=False)
    assert default_model_path() == REPO / "meshes" / "face_coarse.npz"


@pytest.mark.parametrize("command", [[], ["demo"], ["model"], ["model", "build"], ["model", "info"],
                                     ["model", "export"], ["model", "render"]])
def test_help_everywhere(command, capsys):
    assert main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: facesim") and "--help" in out


def test_help_states_units(capsys):
    main(["model", "info", "--help"])
    assert "mm" in capsys.readouterr().out
    main(["model", "render", "--help"])
    assert "pixels" in capsys.readouterr().out


# ------------------------------------------------------------ one-line errors
@pytest.fixture(scope="module")
def bad_files(box_model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("clibad")
    files = {case: path for case, (path, _) in bad_model_files(box_model.save(folder / "good.npz"), folder).items()}
    np.save(folder / "a.npy", np.zeros(3))
    files["npy"] = shutil.copy(folder / "a.npy", folder / "npy.npz")
    data = bytearray((folder / "good.npz").read_bytes())
    data[2000:2100] = bytes(b ^ 0xFF for b in data[2000:2100])
    (folder / "corrupt.npz").write_bytes(bytes(data))
    files["corrupt"] = folder / "corrupt.npz"
    return files


def assert_one_line_error(code, out, err, *words):
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith("facesim") and "error: " in err
    for w in words:
        assert str(w) in err, err


@pytest.mark.parametrize("case", ["missing", "text", "no_meta", "version", "field", "meta_field", "npy", "corrupt"])
def test_bad_model_files_exit_2_with_one_line(bad_files, case):
    path = bad_files[case]
    code, out, err = run("model", "info", path)
    assert_one_line_error(code, out, err, path)


@pytest.mark.parametrize("args, words", [
    (["model", "export", "{m}", "-o", "out.stl"], ["out.stl", ".vtu"]),
    (["model", "export", "{m}"], ["nothing to do"]),
    (["model", "render", "{m}", "-o", "x.jpg"], ["x.jpg", ".png"]),
    (["model", "render", "{m}", "-o", "x.png", "--hide", "hair"], ["hair"]),
    (["model", "render", "{m}", "-o", "x.png", "--view", "back"], ["back"]),
    (["model", "render", "{m}", "-o", "x.png", "--size", "big"], ["WIDTHxHEIGHT"]),
    (["model", "info"], ["required"]),
    (["model", "build", "-o", "m.txt"], ["m.txt", ".npz"]),
    (["model", "build", "-o", "m.npz", "--resolution", "huge"], ["huge"]),
    (["frobnicate"], ["frobnicate"]),
    (["model", "export", "{m}", "-o", "/proc/nope/x.vtu"], ["/proc/nope/x.vtu"]),
])
def test_bad_arguments_exit_2_with_one_line(box_model_path, args, words):
    code, out, err = run(*(a.format(m=box_model_path) for a in args))
    assert_one_line_error(code, out, err, *words)


def test_demo_without_model_says_how_to_build_one(tmp_path):
    missing = tmp_path / "none.npz"
    code, out, err = run("demo", "-o", tmp_path / "d", env={"FACESIM_MODEL": str(missing)})
    assert_one_line_error(code, out, err, missing, "facesim model build")
    assert not (tmp_path / "d").exists()


def test_python_dash_m_facesim_runs_the_cli():
    p = subprocess.run([sys.executable, "-m", "facesim", "--version"], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=60)
    assert p.returncode == 0 and p.stdout.startswith("facesim ")


@pytest.mark.parametrize("args, words", [
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], ["--scheduler", "not allowed with", "--workers"]),
    (["--loss", "tukey"], ["--loss", "tukey"]),
    (["--chunk-size", "ten"], ["--chunk-size", "ten"]),
])
def test_solve_mocap_bad_engine_and_loss_arguments(args, words, tmp_path):
    code, out, err = run("solve-mocap", "--model", tmp_path / "m.npz", "--markers", tmp_path / "m.trc",
                         "-o", tmp_path / "out", *args)
    assert_one_line_error(code, out, err, *words)


def test_solve_mocap_help_names_the_loss_and_the_parallel_engine(capsys):
    assert main(["solve-mocap", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    for words in ("--loss {l2,huber,cauchy}", "--workers N", "--scheduler ADDRESS", "--chunk-size FRAMES",
                  "--no-robust", "dask.distributed"):
        assert words in out


def test_an_unexpected_exception_is_one_line_and_exit_3(box_model_path, capsys, monkeypatch):
    """A bug (an exception facesim did not expect) prints one line saying so, exit 3 -- never a
    traceback, never mistaken for a user error (2); FACESIM_DEBUG=1 lets the traceback through."""
    import facesim.cli as cli

    def broken(model, path=None):
        raise RuntimeError("something\nfacesim did not expect")

    monkeypatch.setattr(cli, "model_summary", broken)
    assert cli.main(["model", "info", str(box_model_path)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("facesim: internal error: RuntimeError: something facesim")
    assert "FACESIM_DEBUG=1" in err and "Traceback" not in err
    monkeypatch.setenv("FACESIM_DEBUG", "1")
    with pytest.raises(RuntimeError):
        cli.main(["model", "info", str(box_model_path)])


def test_head_markers_on_a_line_warn(capsys):
    """Head markers nearly on a line leave the head's rotation about it to their noise: one warning."""
    from types import SimpleNamespace

    import facesim.cli as cli

    def fake(P):
        P = np.asarray(P, dtype=float)
        return SimpleNamespace(marker_positions=lambda: P, markers=SimpleNamespace(head=np.ones(len(P), bool)))

    cli._warn_head_spread(fake([[-40, 100, 60], [-13, 101, 62], [13, 101, 62], [40, 100, 60]]))
    err = capsys.readouterr().err
    assert err.startswith("facesim: warning: the 4 head markers lie nearly on a line") and err.count("\n") == 1
    cli._warn_head_spread(fake([[-40, 100, 60], [40, 100, 60], [-70, 60, 0], [70, 60, 0]]))   # forehead + temples
    assert capsys.readouterr().err == ""
