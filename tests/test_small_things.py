"""Small things a user hits (issue 15, part 6): colliders without a position, exported surfaces as
colliders, warnings for options a command ignores."""

import numpy as np
import pytest

from facesim.cli import main
from facesim.contact.scene import parse_collider_spec
from facesim.errors import FacesimError


def warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("facesim: warning:")]


# ------------------------------------------------------------------ colliders
@pytest.mark.parametrize("spec", ["sphere:radius=12", "sphere:radius=12,bone=jaw", "sphere:radius=12,name=ball"])
def test_a_sphere_without_a_position_is_refused(spec):
    with pytest.raises(FacesimError) as info:
        parse_collider_spec(spec)
    message = str(info.value)
    assert "needs a position" in message and "centre=" in message and "path=" in message and "\n" not in message


def test_a_sphere_with_a_position_is_accepted(tmp_path):
    assert parse_collider_spec("sphere:radius=12,centre=55:-30:70").at(0).evaluate(np.array([[55.0, -30, 70]]))[0][0] < 0
    (tmp_path / "ball.csv").write_text("frame,x,y,z\n0,55,-30,70\n")
    parse_collider_spec("sphere:radius=12,path=ball.csv", base=tmp_path)


def test_simulate_refuses_a_sphere_without_a_position_in_one_line(box_model_path, tmp_path, capsys):
    (tmp_path / "a.csv").write_text("frame,orbicularis_oris\n0,0.1\n")
    code = main(["simulate", "--model", str(box_model_path), "--activations", str(tmp_path / "a.csv"),
                 "-o", str(tmp_path / "out"), "--collider", "sphere:radius=12", "-q"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "needs a position" in err
    assert not (tmp_path / "out").exists()


def test_exported_surfaces_are_accepted_as_mesh_colliders(tmp_path, capsys):
    """The shipped model's teeth and cranium are closed surfaces whose sheets touch at points (coincident
    vertices): welded on reading they were not closed any more."""
    from facesim._files import MESHES

    assert main(["model", "export", str(MESHES / "face_coarse.npz"), "--surfaces", str(tmp_path)]) == 0
    written = {p.stem for p in tmp_path.glob("*.ply")}
    assert {"upper_teeth", "lower_teeth", "cranium", "eye_L"} <= written
    for name in ("upper_teeth", "lower_teeth", "eye_L"):
        c = parse_collider_spec(f"mesh:file={name}.ply,spacing=1", base=tmp_path).at(0)
        lo, hi = c.surface()[0].min(axis=0), c.surface()[0].max(axis=0)
        assert np.all(hi - lo > 1.0), name


def test_a_triangle_soup_is_welded(tmp_path):
    """An STL stores every triangle's corners apart: still accepted (its corners are merged)."""
    import trimesh

    trimesh.creation.icosphere(2, 8.0).apply_translation((0, 0, 90)).export(tmp_path / "ball.stl")
    c = parse_collider_spec("mesh:file=ball.stl,spacing=1", base=tmp_path).at(0)
    assert c.evaluate(np.array([[0.0, 0.0, 90.0]]))[0][0] < -7.0


# ------------------------------------------------------------------ ignored options warn
@pytest.mark.parametrize("extra, flags", [
    (["--view", "side"], ["--view"]),
    (["--view", "side", "--size", "100x100", "--color-by", "displacement"], ["--view", "--size", "--color-by"]),
    (["--contact-stiffness", "5"], ["--contact-stiffness"]),
    (["--fps", "24"], []),                               # the TRC's time column: never ignored
    (["--render", "--view", "side", "--color-by", "activation"], []),
    (["--lip-contact", "--contact-stiffness", "5"], []),
])
def test_simulate_warns_once_per_ignored_option(box_model_path, tmp_path, capsys, extra, flags):
    # a missing activations file stops the command right after the warnings: nothing is solved
    main(["simulate", "--model", str(box_model_path), "--activations", str(tmp_path / "missing.csv"),
          "-o", str(tmp_path / "out"), *extra])
    lines = warnings(capsys.readouterr().err)
    assert len(lines) == len(flags)
    for flag, line in zip(flags, lines):
        assert line.startswith(f"facesim: warning: {flag} is ignored ")
    if flags == ["--view"]:
        assert lines == ["facesim: warning: --view is ignored without --render or --video"]


@pytest.mark.parametrize("extra, flags", [
    (["--loss-scale", "2"], ["--loss-scale"]),
    (["--loss", "huber", "--loss-scale", "2"], []),
    (["--head", "none", "--head-smoothing", "5"], ["--head-smoothing"]),
    (["--head-smoothing", "5"], []),
    (["--color-by", "activation"], ["--color-by"]),
    (["--no-contact", "--contact-stiffness", "3"], ["--contact-stiffness"]),
    (["--chunk-size", "4"], []),                         # chunks still start cold on one process
])
def test_solve_mocap_warns_once_per_ignored_option(box_model_path, tmp_path, capsys, extra, flags):
    main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "missing.trc"),
          "-o", str(tmp_path / "out"), *extra])
    lines = warnings(capsys.readouterr().err)
    assert [line.split()[2] for line in lines] == flags


def test_model_render_warns_about_opacity_without_skin_and_refuses_colouring_at_rest(box_model_path, tmp_path,
                                                                                      capsys):
    out = tmp_path / "x.png"
    assert main(["model", "render", str(box_model_path), "-o", str(out), "--hide", "skin", "--opacity", "0.5",
                 "--size", "160x160"]) == 0
    assert warnings(capsys.readouterr().err) == ["facesim: warning: --opacity is ignored with --hide skin"]
    for kind in ("activation", "displacement"):
        assert main(["model", "render", str(box_model_path), "-o", str(out), "--color-by", kind]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "at rest" in err and "simulate --render" in err


@pytest.mark.parametrize("values", [np.zeros(0, np.int64), np.array([7]), np.array([3, 3, 3]),
                                    np.random.default_rng(0).integers(-50, 50, 1000),
                                    np.random.default_rng(1).integers(0, 2 ** 40, 100_000)])
def test_unique_ints_is_numpys_unique(values):
    from facesim._arrays import unique_ints

    out = unique_ints(values)
    np.testing.assert_array_equal(out, np.unique(values))
    assert out.dtype == values.dtype
