"""``--output-frame input`` (issue 16, item 1): meshes and markers written back in the frame and
units of the meshes an imported model was made from, the exact inverse of the import transform.

No importer run: the synthetic box model is given the ``input_frame`` meta the importer writes
(from :meth:`facesim.importing.frame.FrameFit.meta`, so the format is the real one) for a user
whose meshes are in metres, rotated and translated against facesim's frame. Every file written in
the input frame is compared by value with the same run's (or export's) facesim-frame file mapped
through the inverse of the stored transform, computed here independently of the code under test
(``np.linalg.solve`` on the stored 4x4). Tolerances are the files' own precision: PLY and VTU hold
float64 (1e-9 relative), marker CSV and TRC 1e-6 mm (6 decimals in mm, 9 in m), C3D float32.
The same on a real import (the Badin mandible written back onto its own file) is in
tests/importing/test_build.py, which shares its imported model.
"""

import json
import shutil

import meshio
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import one_numba_thread

from facesim.cli import main
from facesim.errors import FacesimError
from facesim.importing.frame import FrameFit
from facesim.mocap.io import read_c3d, read_markers_csv, read_trc
from facesim.output_frame import output_frame

one_thread = pytest.fixture(scope="module", autouse=True)(one_numba_thread)

ACTIVATIONS = "frame,zygomaticus_major_L,orbicularis_oris\n0,0,0\n1,1,0.3\n"
JAW = "frame,opening\n0,0\n1,0.05\n"
#: the user's frame: metres, turned by an arbitrary proper rotation and moved (mm, after scaling)
R_USER = Rotation.from_rotvec([0.4, -1.3, 0.8]).as_matrix()
T_USER = np.array([120.0, -45.0, 65.0])
MARKER_FILE_MM = 1.5e-6   # the marker CSV and TRC resolution: 1e-6 mm, rounded on both sides


def _fit() -> FrameFit:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_USER, T_USER
    return FrameFit(T=T, scale_to_mm=1000.0, units="m", how="spec: test")


def _imported(model):
    """``model`` with the meta ``facesim model import`` writes (facesim/importing/build.py)."""
    fit = _fit()
    return model.with_(meta={**model.meta, "builder": "import", "units": "mm",
                             "import": {"builder": "import", "input_frame": fit.meta(),
                                        "units": {"name": "m", "scale_to_mm": 1000.0, "how": "given: metres"}},
                             "input_frame": {"T_facesim_from_input_mm": fit.meta()["T_facesim_from_input_mm"],
                                             "scale_to_mm": 1000.0, "units": "m"}})


def to_input(model, P) -> np.ndarray:
    """The oracle: ``P (..., 3)`` facesim mm -> the user's metres, by the stored transform inverted."""
    T = np.array(model.meta["import"]["input_frame"]["T_facesim_from_input_mm"])
    scale = model.meta["import"]["input_frame"]["scale_to_mm"]
    Q = np.linalg.solve(T[:3, :3], (np.asarray(P) - T[:3, 3]).reshape(-1, 3).T).T
    return Q.reshape(np.shape(P)) / scale


def close(got, want, atol=None):
    want = np.asarray(want)
    atol = 1e-9 * np.nanmax(np.abs(want)) if atol is None else atol
    np.testing.assert_allclose(got, want, rtol=0, atol=atol)


def signed_volume(V, F) -> float:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.fixture(scope="module")
def imported(box_model, tmp_path_factory):
    model = _imported(box_model)
    return model, model.save(tmp_path_factory.mktemp("imported") / "imported.npz")


def simulate_cli(model_path, folder, out, *extra):
    (folder / "a.csv").write_text(ACTIVATIONS)
    (folder / "j.csv").write_text(JAW)
    return main(["simulate", "--model", str(model_path), "--activations", str(folder / "a.csv"), "--jaw",
                 str(folder / "j.csv"), "-o", str(out), "--solver", "direct", "-q", "--fps", "25", *extra])


@pytest.fixture(scope="module")
def runs(imported, tmp_path_factory):
    """The same two-frame simulate run of the imported model, in facesim's frame and in the input
    frame: (facesim folder, input folder)."""
    _, path = imported
    folder = tmp_path_factory.mktemp("sim")
    assert simulate_cli(path, folder, folder / "facesim") == 0
    assert simulate_cli(path, folder, folder / "input", "--output-frame", "input") == 0
    return folder / "facesim", folder / "input"


# ------------------------------------------------------------------ the helper
def test_the_helper_inverts_the_import_exactly_and_keeps_orientation(imported):
    model, _ = imported
    frame = output_frame(model, "input")
    assert (frame.name, frame.units, frame.mm_per_unit) == ("input", "m", 1000.0)
    P = model.X[:50] + 3.0
    close(frame.points(P), to_input(model, P))
    assert np.abs(frame.points(P) - P).max() > 10.0                      # not the identity
    # the importer's own map back (its T unrounded: the model stores it to 9 decimals, ~1e-7 mm here)
    close(_fit().to_facesim(frame.points(P)), P, 5e-7)
    close(frame.to_facesim(frame.points(P)), P)
    close(frame.points_mm(P), 1000.0 * to_input(model, P))
    assert np.linalg.det(frame.rotation) == pytest.approx(1.0)            # proper: winding kept
    D = np.array([[0.0, 0.0, 1.0]])
    close(frame.directions(D), D @ R_USER)                                # rows: R^T d
    assert output_frame(model, "facesim").points(P) is not P and np.array_equal(output_frame(model).points(P), P)
    assert np.isnan(frame.points(np.full((2, 3), np.nan))).all()


def test_input_frame_of_a_model_that_was_not_imported_is_one_line(box_model, box_model_path, tmp_path, capsys):
    from facesim._files import MESHES
    from facesim.model import load_model

    with pytest.raises(FacesimError, match=r"^--output-frame input: M.npz was built by facesim model build, not "
                                           r"imported; it has no input frame$"):
        output_frame(box_model, "input", "M.npz")
    shipped = MESHES / "face_coarse.npz"
    if shipped.is_file():
        with pytest.raises(FacesimError, match="face_coarse.npz was built by facesim model build"):
            output_frame(load_model(shipped), "input", shipped)
    for argv in (["model", "export", str(box_model_path), "-o", str(tmp_path / "s.ply"), "--output-frame", "input"],
                 ["simulate", "--model", str(box_model_path), "--activations", str(tmp_path / "a.csv"), "-o",
                  str(tmp_path / "out"), "--output-frame", "input"]):
        (tmp_path / "a.csv").write_text(ACTIVATIONS)
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.strip() == f"facesim: error: --output-frame input: {box_model_path} was built by facesim model " \
                              "build, not imported; it has no input frame", err
    assert not (tmp_path / "s.ply").exists() and not (tmp_path / "out").exists()


def test_a_stored_transform_that_is_not_rigid_is_refused(box_model):
    fit = _fit()
    bad = fit.meta()
    bad["T_facesim_from_input_mm"] = (np.diag([-1.0, 1.0, 1.0, 1.0]) @ fit.T).tolist()   # mirrored
    mirrored = box_model.with_(meta={"builder": "import", "import": {"input_frame": bad}})
    with pytest.raises(FacesimError, match="not a 4x4 proper rigid transform"):
        output_frame(mirrored, "input", "M.npz")


# ------------------------------------------------------------------ simulate
def test_simulate_writes_skin_and_markers_in_the_input_frame(runs, imported):
    model, _ = imported
    fs, inp = runs
    skins = sorted(p.name for p in (inp / "skin").iterdir())
    assert skins == ["frame_00000.ply", "frame_00001.ply"]
    for name in skins:
        want, got = meshio.read(fs / "skin" / name), meshio.read(inp / "skin" / name)
        np.testing.assert_array_equal(got.cells_dict["triangle"], want.cells_dict["triangle"])
        close(got.points, to_input(model, want.points))
        F = got.cells_dict["triangle"]   # winding kept: the closed skin still encloses positive volume
        volume = signed_volume(got.points, F)
        assert volume > 0 and volume == pytest.approx(signed_volume(want.points, F) / 1e9, rel=1e-9)
    # the state files stay in facesim's frame
    for k in (0, 1):
        with np.load(fs / "state" / f"frame_{k:05d}.npz") as a, np.load(inp / "state" / f"frame_{k:05d}.npz") as b:
            np.testing.assert_allclose(b["x"], a["x"], rtol=0, atol=1e-9)
    with np.load(fs / "state" / "frame_00001.npz") as z:
        assert np.abs(z["x"] - model.X).max() > 0.5   # frame 1 moved: the comparison can fail
    # markers.csv: the user's metres (the CSV itself says no unit; read it as m)
    want, got = read_markers_csv(fs / "markers.csv"), read_markers_csv(inp / "markers.csv", "m")
    assert got.names == want.names and np.array_equal(got.frames, want.frames)
    close(got.P, 1000.0 * to_input(model, want.P), MARKER_FILE_MM)
    raw = read_markers_csv(inp / "markers.csv")   # the numbers as written: metres
    close(raw.P, to_input(model, want.P), MARKER_FILE_MM / 1000.0)
    # TRC: Units m in its header, values in m
    header = (inp / "markers.trc").read_text().splitlines()[1:3]
    assert dict(zip(header[0].split("\t"), header[1].split("\t")))["Units"] == "m"
    trc = read_trc(inp / "markers.trc")
    assert trc.units == "m" and trc.rate == 25.0
    close(trc.P, 1000.0 * to_input(model, want.P), MARKER_FILE_MM)
    c3d = read_c3d(inp / "markers.c3d")
    assert c3d.units == "m"
    np.testing.assert_allclose(c3d.P, 1000.0 * to_input(model, want.P), rtol=1e-6, atol=1e-3)   # float32
    # report.json says which frame the files are in
    report = json.loads((inp / "report.json").read_text())
    assert report["output_frame"]["name"] == "input" and report["output_frame"]["units"] == "m"
    M = np.array(report["output_frame"]["matrix_from_facesim_mm"])
    close(model.X @ M[:3, :3].T + M[:3, 3], to_input(model, model.X))
    assert json.loads((fs / "report.json").read_text())["output_frame"] == {
        "name": "facesim", "units": "mm", "files": report["output_frame"]["files"]}
    assert json.loads((inp / "run.json").read_text())["inputs"]["output_frame"] == "input"
    assert "output_frame" not in json.loads((fs / "run.json").read_text())["inputs"]   # older records still resume


def test_resume_with_another_output_frame_is_refused(runs, imported, tmp_path, capsys):
    _, path = imported
    for name, other in ((0, "input"), (1, "facesim")):
        out = shutil.copytree(runs[name], tmp_path / f"out{name}")
        before = (out / "markers.csv").read_text()
        assert simulate_cli(path, tmp_path, out, "--resume", "--output-frame", other) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "--resume" in err and "output_frame" in err, err
        assert (out / "markers.csv").read_text() == before
    # the same frame resumes (nothing left to do) and rewrites the TRC from markers.csv alike
    out = tmp_path / "out1"
    trc = (out / "markers.trc").read_text()
    (out / "skin" / "frame_00001.ply").unlink()   # a lost skin is drawn again, in the run's frame
    assert simulate_cli(path, tmp_path, out, "--resume", "--output-frame", "input") == 0
    assert (out / "markers.trc").read_text() == trc
    redrawn, written = (meshio.read(o / "skin" / "frame_00001.ply").points for o in (out, runs[1]))
    close(redrawn, written)


# ------------------------------------------------------------------ model export
def test_model_export_in_the_input_frame(imported, tmp_path, capsys):
    model, path = imported
    assert main(["model", "export", str(path), "-o", str(tmp_path / "skin.ply"), "--surfaces",
                 str(tmp_path / "bones"), "--output-frame", "input"]) == 0
    assert "in the input frame (m)" in capsys.readouterr().out
    assert main(["model", "export", str(path), "-o", str(tmp_path / "volume.vtu"), "--output-frame", "input"]) == 0
    skin = meshio.read(tmp_path / "skin.ply")
    used = np.unique(model.skin)
    close(skin.points, to_input(model, model.X[used]))
    assert signed_volume(skin.points, skin.cells_dict["triangle"]) > 0   # outward, as in facesim's frame
    vol = meshio.read(tmp_path / "volume.vtu")
    close(vol.points, to_input(model, model.X))
    np.testing.assert_array_equal(vol.cells_dict["tetra"], model.tets)
    e = vol.points[model.tets[:, 1:]] - vol.points[model.tets[:, :1]]
    assert (np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2])) > 0).all()   # tets stay positive
    _, _, fibre = model.muscles.dominant(model.n_tets)
    close(vol.cell_data["fibre"][0], fibre @ R_USER, 1e-9)   # rotated, still unit (or zero)
    for s in model.bones + model.colliders:
        got = meshio.read(tmp_path / "bones" / f"{s.name}.ply")
        close(got.points, to_input(model, s.vertices[np.unique(s.faces)]))


# ------------------------------------------------------------------ export-cache
def test_export_cache_in_the_input_frame_from_either_run(runs, imported, tmp_path):
    model, path = imported
    fs, inp = runs
    assert main(["export-cache", str(fs), "--model", str(path), "--pvd", str(tmp_path / "a.pvd"), "--c3d",
                 str(tmp_path / "a.c3d"), "--output-frame", "input"]) == 0
    with np.load(fs / "state" / "frame_00001.npz") as z:
        x = z["x"]
    grid = meshio.read(tmp_path / "a" / "frame_00001.vtu")
    close(grid.points, to_input(model, x))
    close(grid.point_data["displacement"], to_input(model, x) - to_input(model, model.X), 1e-9 * 0.2)
    want = read_markers_csv(fs / "markers.csv")
    c3d = read_c3d(tmp_path / "a.c3d")
    assert c3d.units == "m"
    np.testing.assert_allclose(c3d.P, 1000.0 * to_input(model, want.P), rtol=1e-6, atol=1e-3)
    # from the run written in the input frame: its markers.csv is read in the frame it recorded
    assert main(["export-cache", str(inp), "--model", str(path), "--c3d", str(tmp_path / "b.c3d")]) == 0
    b = read_c3d(tmp_path / "b.c3d")
    assert b.units == "mm"
    np.testing.assert_allclose(b.P, want.P, rtol=0, atol=1e-4)
    assert main(["export-cache", str(inp), "--model", str(path), "--c3d", str(tmp_path / "c.c3d"),
                 "--output-frame", "input"]) == 0
    np.testing.assert_allclose(read_c3d(tmp_path / "c.c3d").P, c3d.P, rtol=1e-6, atol=1e-3)


def test_usd_cache_in_the_input_frame(runs, imported, tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    from facesim.caches import bone_transforms

    model, path = imported
    fs, _ = runs
    assert main(["export-cache", str(fs), "--model", str(path), "--usd", str(tmp_path / "f.usda"),
                 "--output-frame", "input"]) == 0
    stage = Usd.Stage.Open(str(tmp_path / "f.usda"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    up = output_frame(model, "input").directions([0.0, 1.0, 0.0])
    assert UsdGeom.GetStageUpAxis(stage) == ("Z" if abs(up[2]) > abs(up[1]) else "Y")
    with np.load(fs / "state" / "frame_00001.npz") as z:
        x = z["x"]
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/skin"))
    nodes = np.array(skin.GetPrim().GetAttribute("facesim:node").Get())
    close(np.array(skin.GetPointsAttr().Get(1.0)), to_input(model, x[nodes]), 1e-7)   # float32, m
    # the jaw's surfaces, posed by their time-sampled transform, land where the facesim-frame pose puts them
    T = bone_transforms(model, x)["jaw"]
    teeth = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/jaw/teeth_lower"))
    M = np.array(UsdGeom.Xformable(teeth.GetPrim()).ComputeLocalToWorldTransform(1.0)).T
    V = np.array(teeth.GetPointsAttr().Get())
    posed = V @ M[:3, :3].T + M[:3, 3]
    V0 = model.surface("teeth_lower").vertices
    close(posed, to_input(model, V0 @ T[:3, :3].T + T[:3, 3]), 1e-7)
    markers = UsdGeom.Points(stage.GetPrimAtPath("/Face/markers"))
    close(np.array(markers.GetPointsAttr().Get(1.0)), to_input(model, model.marker_positions(x)), 1e-7)
    assert stage.GetRootLayer().customLayerData["facesim"]["units"] == "m"


# ------------------------------------------------------------------ solve-mocap --write-meshes
def test_solve_mocap_write_meshes_in_the_input_frame(runs, imported, tmp_path, capsys):
    model, path = imported
    fs, _ = runs
    argv = ["solve-mocap", "--model", str(path), "--markers", str(fs / "markers.trc"), "--head", "none",
            "--solver", "direct", "--max-steps", "2", "--write-meshes", "-q"]
    assert main([*argv, "-o", str(tmp_path / "s"), "--output-frame", "input"]) == 0
    out = tmp_path / "s"
    with np.load(out / "state" / "frame_00001.npz") as z:
        x = z["x"]
    close(meshio.read(out / "skin" / "frame_00001.ply").points, to_input(model, x[np.unique(model.skin)]))
    trc = read_trc(out / "markers.trc")
    assert trc.units == "m"
    close(trc.P[1], 1000.0 * to_input(model, model.marker_positions(x)), MARKER_FILE_MM)
    assert json.loads((out / "report.json").read_text())["output_frame"]["units"] == "m"
    capsys.readouterr()
    assert main([*argv, "-o", str(out), "--resume"]) == 2   # the run's files are in the input frame
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "output_frame" in err, err
    # without --write-meshes the option has nothing to write: a warning, not an error
    assert main([*argv[:-2], "-q", "-o", str(tmp_path / "t"), "--output-frame", "input", "--frames", "0"]) == 0
    assert "--output-frame is ignored without --write-meshes" in capsys.readouterr().err


# ------------------------------------------------------------------ edit --simulate
def test_edit_simulate_in_the_input_frame(imported, tmp_path, capsys):
    model, path = imported
    (tmp_path / "a.csv").write_text(ACTIVATIONS)
    argv = ["edit", "scale", str(tmp_path / "a.csv"), "--factor", "0.5", "--model", str(path), "--solver", "direct",
            "-q"]
    assert main([*argv, "-o", str(tmp_path / "e"), "--simulate", "--output-frame", "input"]) == 0
    sim = tmp_path / "e" / "sim"
    with np.load(sim / "state" / "frame_00001.npz") as z:
        x = z["x"]
    close(meshio.read(sim / "skin" / "frame_00001.ply").points, to_input(model, x[np.unique(model.skin)]))
    trc = read_trc(sim / "markers.trc")
    assert trc.units == "m"
    close(trc.P[1], 1000.0 * to_input(model, model.marker_positions(x)), MARKER_FILE_MM)
    capsys.readouterr()
    assert main([*argv, "-o", str(tmp_path / "f"), "--output-frame", "input"]) == 0   # nothing simulated
    assert "--output-frame is ignored without --simulate" in capsys.readouterr().err
