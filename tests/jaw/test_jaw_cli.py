"""``facesim jaw ...`` (facesim.jaw.cli): the quick workflow on generated data and one-line errors.

The commands run through ``facesim.cli.main`` once it registers the ``jaw`` group; until then
through a ``facesim``-style parser holding only ``add_jaw_commands`` (same parser class, same
error handling).
"""

import contextlib
import functools
import io
import json
import sys

import numpy as np
import pytest

import facesim.cli as facesim_cli
from facesim import se3
from facesim.errors import FacesimError
from facesim.jaw import load_rig
from facesim.jaw.cli import add_jaw_commands
from facesim.jaw.evaluate import pose_errors
from facesim.jaw.motion import JawMotion, Subject
from facesim.jaw.points import front_weights, mandible_points


@functools.lru_cache(maxsize=1)
def _wired() -> bool:
    with contextlib.redirect_stderr(io.StringIO()):
        try:
            facesim_cli.build_parser().parse_args(["jaw", "eval", "--rig", "r.npz", "--poses", "p.npz"])
            return True
        except SystemExit:
            return False


def run(argv) -> int:
    """Exit status of ``facesim ARGV`` (messages go to stdout/stderr as in the real command)."""
    if _wired():
        return facesim_cli.main(argv)
    parser = facesim_cli._Parser(prog="facesim")
    add_jaw_commands(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    try:
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 0
    except FacesimError as exc:
        print(f"facesim: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return facesim_cli.EXIT_USAGE


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Generated sessions of subject 7 (train, test) and five extremal poses of subject 8."""
    folder = tmp_path_factory.mktemp("jaw_cli")
    out = {"train": folder / "train.npz", "test": folder / "test.npz", "extremes": folder / "ext.npz",
           "other": folder / "other.npz", "folder": folder}
    assert run(["jaw", "generate", "--subject", "7", "--session", "1", "-o", str(out["train"])]) == 0
    assert run(["jaw", "generate", "--subject", "7", "--session", "2", "-o", str(out["test"])]) == 0
    assert run(["jaw", "generate", "--subject", "8", "--extremes", "-o", str(out["extremes"])]) == 0
    assert run(["jaw", "generate", "--subject", "8", "--session", "2", "-o", str(out["other"])]) == 0
    out["posselt"] = folder / "posselt.npz"
    assert run(["jaw", "fit", "--rig", "posselt", "--poses", str(out["train"]), "-o", str(out["posselt"])]) == 0
    return out


def _eval_json(rig, poses, capsys):
    capsys.readouterr()
    assert run(["jaw", "eval", "--rig", str(rig), "--poses", str(poses), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_generate_writes_labelled_sessions(files):
    with np.load(files["train"]) as z:
        assert z["poses"].shape[1:] == (4, 4) and len(z["poses"]) > 1000
        assert "posterior" in set(z["segment_names"]) and z["segment_bounds"].shape == (len(z["segment_names"]), 2)
    with np.load(files["extremes"]) as z:
        assert list(z["names"]) == ["rest", "open", "protrusion", "left", "right"]
        opening = JawMotion(subject=Subject.random(8)).measures(z["poses"])["opening"]
        assert opening[1] == pytest.approx(Subject.random(8).max_opening, abs=0.5)


@pytest.mark.parametrize("rig", ["posselt", "3dof", "nlpca"])
def test_fit_then_eval(files, rig, capsys):
    path = files["folder"] / f"{rig}.npz"
    if rig != "posselt":
        extra = ["--iterations", "150"] if rig == "nlpca" else []
        assert run(["jaw", "fit", "--rig", rig, "--poses", str(files["train"]), "-o", str(path), *extra]) == 0
        assert "error on the fitted poses" in capsys.readouterr().out
    report = _eval_json(path, files["test"], capsys)
    # the numbers are the rig's front-weighted mandible-vertex errors on the test poses
    fitted = load_rig(path)
    with np.load(files["test"]) as z:
        poses = z["poses"]
    points = mandible_points()
    weights = front_weights(points, fitted.frame)
    stats = pose_errors(fitted.reproduce(poses, points, weights), poses, points, weights)
    assert report["frames"] == len(poses) and report["kind"] == rig
    assert report["mean_mm"] == pytest.approx(stats.mean) and report["max_mm"] == pytest.approx(stats.max)
    assert report["mean_mm"] <= report["p95_mm"] <= report["max_mm"]
    assert report["mean_mm"] < {"posselt": 0.2, "3dof": 3.0, "nlpca": 0.3}[rig]
    assert run(["jaw", "eval", "--rig", str(path), "--poses", str(files["test"])]) == 0
    assert "95th percentile" in capsys.readouterr().out


def test_fit_posselt_on_unlabelled_poses(files, tmp_path, capsys):
    """Without segment labels the border movements are found in the poses."""
    bare = tmp_path / "bare.npz"
    with np.load(files["train"]) as z:
        np.savez(bare, poses=z["poses"], reference_point=z["reference_point"])
    capsys.readouterr()
    assert run(["jaw", "fit", "--rig", "posselt", "--poses", str(bare), "-o", str(tmp_path / "found.npz")]) == 0
    assert "finding them in the poses" in capsys.readouterr().out
    found = _eval_json(tmp_path / "found.npz", files["test"], capsys)["mean_mm"]
    labelled = _eval_json(files["posselt"], files["test"], capsys)["mean_mm"]
    assert found < labelled + 0.05


def test_retarget(files, capsys):
    source = files["posselt"]
    new = files["folder"] / "retargeted.npz"
    assert run(["jaw", "retarget", "--rig", str(source), "--poses", str(files["extremes"]), "-o", str(new)]) == 0
    before = _eval_json(source, files["other"], capsys)["mean_mm"]
    after = _eval_json(new, files["other"], capsys)["mean_mm"]
    assert after < 0.6 * before


def test_pose_and_envelope(files, capsys):
    rig = files["posselt"]
    capsys.readouterr()
    assert run(["jaw", "pose", "--rig", str(rig), "--sliders", "0.5", "1", "0"]) == 0
    out = capsys.readouterr().out.splitlines()
    T = np.array([[float(v) for v in line.split()] for line in out[1:5]])
    assert se3.rigidity_error(T) < 1e-5
    reference = load_rig(rig).reference_point
    incisor = se3.transform_points(T, reference)[0]
    assert reference[1] - incisor[1] == pytest.approx(Subject.random(7).max_opening, abs=1.0)
    assert np.allclose([float(v) for v in out[5].split(" at ")[1].split()[:3]], incisor, atol=2e-3)
    png = files["folder"] / "env.png"
    assert run(["jaw", "envelope", "--rig", str(rig), "--poses", str(files["test"]), "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_errors_are_one_line(files, tmp_path, capsys):
    rig = files["folder"] / "err_rig.npz"
    assert run(["jaw", "fit", "--rig", "1dof", "--poses", str(files["train"]), "-o", str(rig)]) == 0
    bare = tmp_path / "bare.npz"
    with np.load(files["train"]) as z:
        np.savez(bare, poses=z["poses"])
    speech = tmp_path / "speech.npz"
    assert run(["jaw", "generate", "--kinds", "speech", "-o", str(speech)]) == 0
    bad = tmp_path / "bad.npz"
    np.savez(bad, poses=np.zeros((5, 3, 3)))
    skewed = tmp_path / "skewed.npz"
    np.savez(skewed, poses=np.tile(np.diag([2.0, 1.0, 1.0, 1.0]), (3, 1, 1)))
    cases = [
        (["jaw", "fit", "--rig", "posselt", "--poses", str(speech), "-o", str(tmp_path / "r.npz")],
         "speech.npz: border detection: "),
        (["jaw", "fit", "--rig", "3dof", "--poses", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "r.npz")],
         "missing.npz: no such file"),
        (["jaw", "eval", "--rig", str(rig), "--poses", str(bad)], "bad.npz: field 'poses': expected (N, 4, 4)"),
        (["jaw", "eval", "--rig", str(rig), "--poses", str(skewed)],
         "skewed.npz: field 'poses': expected rigid transforms with an orthonormal rotation"),
        (["jaw", "eval", "--rig", str(bare), "--poses", str(files["test"])], "not a facesim jaw rig"),
        (["jaw", "pose", "--rig", str(rig), "--sliders", "0.1", "0.2"], "takes 1 finite values"),
        (["jaw", "retarget", "--rig", str(rig), "--poses", str(files["extremes"]), "-o", str(tmp_path / "n.npz")],
         "needs a posselt rig"),
        (["jaw", "envelope", "--rig", str(rig), "-o", str(tmp_path / "e.png")], "has no envelope"),
        (["jaw", "fit", "--rig", "3dof", "--poses", str(files["train"]), "-o", str(tmp_path / "r.txt")],
         "ending in .npz"),
        (["jaw", "fit", "--rig", "4dof", "--poses", str(files["train"]), "-o", str(tmp_path / "r.npz")],
         "invalid choice"),
    ]
    for argv, message in cases:
        capsys.readouterr()
        assert run(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err, (argv, err)


def test_help_everywhere(capsys):
    for command in ([], ["fit"], ["eval"], ["retarget"], ["pose"], ["envelope"], ["generate"]):
        assert run(["jaw", *command, "--help"]) == 0
        assert "usage:" in capsys.readouterr().out
