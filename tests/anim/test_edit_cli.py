"""``facesim edit ...`` (issue 18, part 2): a real solve-mocap folder -> edit -> ``simulate
--controls-from`` is a pipeline; gains reach the simulation; every option has help; user mistakes
exit 2 with one line and no traceback.

The ``edit`` parsers are registered on a root parser built here (as ``facesim.cli`` will), and the
commands are run the way ``facesim.cli.main`` runs them. The solve: 3 frames of the synthetic box
model (sliding-condyle jaw, lip and teeth contact as solve-mocap defaults), direct solvers, one
numba thread.
"""

import argparse
import json

import numpy as np
import pytest

from tests.conftest import one_numba_thread

from facesim.anim.cli import OPERATIONS, add_parsers
from facesim.anim.sequence import read_sequence
from facesim.cli import EXIT_USAGE, _Parser, main
from facesim.controls_io import read_replay
from facesim.errors import FacesimError
from facesim.mocap.io import read_markers_csv
from facesim._files import MESHES

one_thread = pytest.fixture(scope="module", autouse=True)(one_numba_thread)


def parser() -> argparse.ArgumentParser:
    root = _Parser(prog="facesim")
    add_parsers(root.add_subparsers(dest="command", metavar="COMMAND", required=True))
    return root


def edit(*argv) -> int:
    """``facesim edit ARGV``, with the error handling of ``facesim.cli.main``."""
    import sys

    try:
        args = parser().parse_args(["edit", *map(str, argv)])
        return int(args.func(args) or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else EXIT_USAGE)
    except FacesimError as exc:
        print(f"facesim: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_USAGE


def states(folder):
    return [np.load(p) for p in sorted((folder / "state").glob("frame_*.npz"))]


@pytest.fixture(scope="module")
def solved(box_model, tmp_path_factory):
    """The model file and a solve-mocap folder of 3 frames of the box model (do not modify)."""
    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.fem.newton import NewtonOptions
    from facesim.mocap.io import write_trc

    folder = tmp_path_factory.mktemp("edit_inputs")
    model = box_model.save(folder / "model.npz")
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct")),
                        jaw_model="sliding-condyle")
    t = np.linspace(0.0, 1.0, 3)
    A, jaw = np.stack([0.6 * t, 0.3 * t], axis=1), np.stack([0.05 * t, 0 * t, 0 * t], axis=1)
    P = np.array([box_model.marker_positions(sim.equilibrium(Controls(a, jaw=q)).x) for a, q in zip(A, jaw)])
    write_trc(folder / "capture.trc", np.arange(3), box_model.markers.names, P, fps=30.0)
    out = folder / "solve"
    assert main(["solve-mocap", "--model", str(model), "--markers", str(folder / "capture.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.05", "--solver", "direct", "-q"]) == 0
    return model, out


@pytest.fixture(scope="module")
def saved(solved):
    """The box model as read back from its file (what the solve's run.json fingerprints)."""
    from facesim.model import load_model

    return load_model(solved[0])


def test_solve_mocap_edit_scale_simulate_controls_from_is_a_pipeline(solved, saved, tmp_path, capsys):
    model, solve = solved
    assert edit("scale", solve, "--factor", "0.5", "--model", model, "-o", tmp_path / "half") == 0
    assert "edit scale: 3 frames (0..2) at 30 Hz" in capsys.readouterr().out
    source, half = read_sequence(solve, saved), read_sequence(tmp_path / "half", saved)
    assert source.A[2].min() > 0.1 and np.array_equal(half.A, 0.5 * source.A)
    assert np.array_equal(half.jaw, source.jaw) and half.setup == source.setup   # the solve's contact kept
    record = json.loads((tmp_path / "half" / "run.json").read_text())
    assert record["command"] == "edit" and record["inputs"]["simulator"]["lip_contact"] is True
    assert main(["simulate", "--model", str(model), "--controls-from", str(tmp_path / "half"), "-o",
                 str(tmp_path / "sim"), "--solver", "direct", "-q"]) == 0
    done = states(tmp_path / "sim")
    assert len(done) == 3 and all(bool(z["converged"]) for z in done)
    assert np.array_equal(np.array([z["a"] for z in done]), half.A)
    assert np.array_equal(np.array([z["jaw"] for z in done]), half.jaw)
    report = json.loads((tmp_path / "sim" / "report.json").read_text())
    assert report["options"]["lip_contact"] and report["options"]["teeth_contact"]   # as solved
    # --simulate writes the same simulation into OUT/sim
    assert edit("scale", solve, "--factor", "0.5", "--model", model, "-o", tmp_path / "half2", "--simulate",
                "--solver", "direct", "-q") == 0
    assert (tmp_path / "half2" / "sim" / "markers.csv").read_text() == (tmp_path / "sim" / "markers.csv").read_text()


def test_gain_reaches_the_simulation(solved, saved, tmp_path):
    model, solve = solved
    assert edit("gain", solve, "--factor", "3", "--muscles", "zygomaticus_major", "--model", model, "-o",
                tmp_path / "g", "--simulate", "--solver", "direct", "-q") == 0
    assert (tmp_path / "g" / "gain.csv").read_text() == "muscle,gain\nzygomaticus_major_L,3.0\norbicularis_oris,1.0\n"
    assert np.array_equal(read_replay(tmp_path / "g", saved).gain, [3.0, 1.0])   # simulate --controls-from's reader
    report = json.loads((tmp_path / "g" / "sim" / "report.json").read_text())
    assert report["gain"] == {"zygomaticus_major_L": 3.0} and report["converged"] == 3
    assert edit("scale", solve, "--factor", "1", "--model", model, "-o", tmp_path / "plain", "--simulate",
                "--solver", "direct", "-q") == 0
    rest = saved.marker_positions()
    moved = {name: np.linalg.norm(read_markers_csv(tmp_path / name / "sim" / "markers.csv").P[2] - rest, axis=1)
             for name in ("g", "plain")}                                  # mm, frame 2, per marker
    left = [saved.markers.names.index(n) for n in ("mouth_L", "cheek_L")]   # over the zygomaticus
    assert (moved["plain"][left] > 5.0).all()
    assert (moved["g"][left] > 1.15 * moved["plain"][left]).all()          # 7.4 -> 9.2 mm, 7.3 -> 8.9 mm
    assert (moved["g"] >= moved["plain"]).all()


def test_resume_and_overwrite(solved, saved, tmp_path, capsys):
    model, solve = solved
    args = ["scale", solve, "--factor", "0.5", "--model", model, "-o", tmp_path / "out"]
    assert edit(*args) == 0
    assert edit(*args) == EXIT_USAGE
    assert "not empty; use --overwrite" in capsys.readouterr().err
    assert edit(*args, "--resume") == 0                                   # the same edit again
    assert edit("scale", solve, "--factor", "0.6", "--model", model, "-o", tmp_path / "out", "--resume") == EXIT_USAGE
    assert "other inputs: controls differ" in capsys.readouterr().err
    assert edit("scale", solve, "--factor", "0.6", "--model", model, "-o", tmp_path / "out", "--overwrite") == 0
    assert np.array_equal(read_sequence(tmp_path / "out", saved).A, 0.6 * read_sequence(solve, saved).A)


def test_every_operation_and_option_has_help(capsys):
    root = parser()
    edit_parser = next(a for a in root._subparsers._group_actions[0].choices.values())
    ops = edit_parser._subparsers._group_actions[0].choices
    assert set(ops) == set(OPERATIONS)
    for name, p in ops.items():
        assert edit(name, "--help") == 0
        assert capsys.readouterr().out.startswith(f"usage: facesim edit {name}")
        for action in p._actions:
            assert action.help and action.help.strip(), f"edit {name}: {action.option_strings or action.dest}"
    assert edit("--help") == 0 and "blend" in capsys.readouterr().out


def test_keyframe_splice_retime_and_mirror_commands(solved, saved, tmp_path):
    model, solve = solved
    source = read_sequence(solve, saved)
    assert edit("keyframe", "--key", solve, 0, 0, "--key", solve, 2, 8, "--method", "linear", "--model", model,
                "-o", tmp_path / "k") == 0
    k = read_sequence(tmp_path / "k", saved)
    assert np.array_equal(k.frames, np.arange(9)) and np.array_equal(k.A[8], source.A[2])
    np.testing.assert_allclose(k.A[4], 0.5 * (source.A[0] + source.A[2]), atol=1e-15)
    assert edit("splice", solve, f"{solve}@1:2", "--crossfade", 1, "--model", model, "-o", tmp_path / "s") == 0
    s = read_sequence(tmp_path / "s", saved)
    assert np.array_equal(s.frames, np.arange(4)) and np.array_equal(s.A[3], source.A[2])
    np.testing.assert_allclose(s.A[2], 0.5 * (source.A[2] + source.A[1]), atol=1e-15)
    assert edit("retime", solve, "--fps", 60, "--model", model, "-o", tmp_path / "r") == 0
    r = read_sequence(tmp_path / "r", saved)
    assert r.fps == 60.0 and np.array_equal(r.frames, np.arange(5)) and np.array_equal(r.A[::2], source.A)
    assert json.loads((tmp_path / "r" / "report.json").read_text())["fps"] == 60.0
    assert edit("blend", solve, tmp_path / "s@0:2", "--t", "0:1", "--model", model, "-o", tmp_path / "b") == 0
    b = read_sequence(tmp_path / "b", saved)
    assert np.array_equal(b.A[0], source.A[0]) and np.array_equal(b.A[2], s.A[2])
    # mirror on the coarse face's L/R pairs, from an activations CSV
    face = MESHES / "face_coarse.npz"
    (tmp_path / "a.csv").write_text("frame,zygomaticus_major_L,frontalis_R\n0,0.6,0.1\n1,0.3,0.2\n")
    assert edit("mirror", tmp_path / "a.csv", "--model", face, "-o", tmp_path / "m") == 0
    header, *rows = (tmp_path / "m" / "activations.csv").read_text().splitlines()
    values = dict(zip(header.split(","), rows[0].split(",")))
    assert float(values["zygomaticus_major_R"]) == 0.6 and float(values["zygomaticus_major_L"]) == 0.0
    assert float(values["frontalis_L"]) == 0.1 and float(values["frontalis_R"]) == 0.0


def test_user_mistakes_exit_2_with_one_line(solved, tmp_path, capsys):
    model, solve = solved
    (tmp_path / "empty").mkdir()
    (tmp_path / "a.csv").write_text("frame,orbicularis_oris\n0,0.5\n1,0.25\n2,0\n")
    out = ["--model", model, "-o", tmp_path / "out"]
    cases = [
        (["scale", solve, "--factor", "1", "--muscles", "zygomaticus", *out], "muscle 'zygomaticus': unknown muscle"),
        (["blend", solve, tmp_path / "a.csv", "--t", "0.5", *out], "b is for the 'rigid' jaw model, a for the "
                                                                   "'sliding-condyle' one"),
        (["scale", solve, "--factor", "-2", *out], "scale: expected 0 <= factor <= 100, got -2"),
        (["gain", solve, "--factor", "0", *out], "gain: expected 0 < factor <= 100"),
        (["blend", solve, solve, "--t", "1.5", *out], "blend: t = 1.5 outside [0, 1]"),
        (["blend", solve, solve, "--t", "a:b", *out], "expected a number, got 'a'"),
        (["scale", tmp_path / "empty", "--factor", "1", *out], "an empty folder; expected a solve-mocap"),
        (["scale", f"{solve}@5:2", "--factor", "1", *out], "the range 5:2 is empty"),
        (["scale", f"{solve}@7:9", "--factor", "1", *out], "frames 7:9: no frame of the sequence"),
        (["scale", solve, "--factor", "1", "--jaw", tmp_path / "a.csv", *out], "--jaw: 1 given for 0 activations CSV"),
        (["splice", solve, solve, solve, "--at", "1", *out], "splice --at: expected two sources, got 3"),
        (["retime", solve, "--fps", "0", *out], "retime: expected a frame rate > 0 Hz"),
        (["keyframe", "--key", solve, "x", "0", *out], "FRAME 'x'; expected a frame number"),
        (["mirror", solve, *out], "mirror: muscle 'zygomaticus_major_L' (side L) has no right partner"),
        (["scale", solve, "--factor", "1", "--model", model, "-o", solve], "also a source"),
        (["scale", solve, *out], "the following arguments are required: --factor"),
    ]
    for argv, message in cases:
        assert edit(*argv) == EXIT_USAGE, argv
        err = capsys.readouterr().err
        assert message in err, (argv, err)
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()
