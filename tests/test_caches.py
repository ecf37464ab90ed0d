"""Animation caches (facesim.caches, issue 15 part 4): USD, ParaView .pvd series and C3D of a
simulate run of the box model, each read back with another reader and checked by value.

One simulate run is shared: frames 0, 1, 3 (frame 2 skipped, for the C3D's gap), the zygomaticus
and orbicularis driven and the rigid jaw rotated and translated (so the jaw transform is not the
identity). Tests that need a frame that did not converge copy it and mark frame 1 so.
"""

import shutil
import sys

import meshio
import numpy as np
import pytest

from facesim.caches import Run, export_cache, read_pvd, read_run, tet_activation, write_usd
from facesim.cli import main
from facesim.controls import rotation_about
from facesim.errors import FacesimError
from facesim.fem.newton import NewtonOptions
from facesim.mocap.io import read_markers, read_markers_csv
from facesim.simulate import SimulateOptions, simulate

FRAMES = np.array([0, 1, 3])
A = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.4]])
FPS = 24.0
USD_TOLERANCE = 1e-4   # mm: USD points are float32 (~4e-6 mm at 30 mm)

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom  # noqa: E402


def _jaw(model):
    centre = (model.jaw.condyle_left + model.jaw.condyle_right) / 2
    T = [np.eye(4), rotation_about([0.03, 0.0, 0.0], centre), rotation_about([0.05, 0.01, 0.0], centre)]
    T[2][:3, 3] += [0.0, -0.3, 0.2]
    return np.array(T)


@pytest.fixture(scope="module")
def run(box_model, tmp_path_factory):
    out = tmp_path_factory.mktemp("caches") / "out"
    s = simulate(box_model, A, out, frames=FRAMES, jaw=_jaw(box_model),
                 options=SimulateOptions(newton=NewtonOptions(linear_solver="direct"), fps=FPS), progress=False)
    assert s["converged"] == 3
    return out


def states(out):
    xs = []
    for k in FRAMES:
        with np.load(out / "state" / f"frame_{k:05d}.npz") as z:
            xs.append(z["x"])
    return np.array(xs)


@pytest.fixture
def failed(run, tmp_path):
    """A copy of the run whose frame 1 did not converge (NaN positions, as a diverged solve)."""
    out = shutil.copytree(run, tmp_path / "out")
    path = out / "state" / "frame_00001.npz"
    with np.load(path) as z:
        fields = dict(z)
    fields.update(x=np.full_like(fields["x"], np.nan), converged=False)
    np.savez(path, **fields)
    return out


# ------------------------------------------------------------------ USD
def test_usd_skin_bones_and_stage_metadata(run, box_model, tmp_path):
    path = export_cache(run, box_model, usd=tmp_path / "face.usd")["usd"]
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 0.001 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert stage.GetTimeCodesPerSecond() == FPS and stage.GetFramesPerSecond() == FPS   # from report.json
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 3)
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/skin"))
    nodes = np.array(skin.GetPrim().GetAttribute("facesim:node").Get())
    faces = np.array(skin.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
    np.testing.assert_array_equal(nodes[faces], box_model.skin)   # topology once, as the model's skin
    assert set(skin.GetFaceVertexCountsAttr().Get()) == {3}
    points = skin.GetPointsAttr()
    assert points.GetTimeSamples() == list(map(float, FRAMES))
    x = states(run)
    assert np.abs(x[2] - box_model.X).max() > 1.0   # the comparison below can fail
    for i, k in enumerate(FRAMES):
        np.testing.assert_allclose(np.array(points.Get(float(k))), x[i][nodes], atol=USD_TOLERANCE, rtol=0)
    # the jaw group moves its surfaces by the jaw transform simulate was given
    jaw = UsdGeom.Xformable(stage.GetPrimAtPath("/Face/jaw"))
    cranium = UsdGeom.Xformable(stage.GetPrimAtPath("/Face/cranium"))
    for i, T in enumerate(_jaw(box_model)):
        M = np.array(jaw.ComputeLocalToWorldTransform(float(FRAMES[i])))
        np.testing.assert_allclose(M.T, T, atol=1e-9)
        np.testing.assert_allclose(np.array(cranium.ComputeLocalToWorldTransform(float(FRAMES[i]))), np.eye(4), atol=1e-9)
    teeth = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/jaw/teeth_lower"))
    np.testing.assert_allclose(np.array(teeth.GetPointsAttr().Get()), box_model.surface("teeth_lower").vertices,
                               atol=1e-5)
    a = stage.GetPrimAtPath("/Face").GetAttribute("facesim:activations")
    np.testing.assert_allclose(np.array(a.Get(3.0)), A[2], atol=1e-7)
    markers = UsdGeom.Points(stage.GetPrimAtPath("/Face/markers"))
    np.testing.assert_allclose(np.array(markers.GetPointsAttr().Get(1.0)), box_model.marker_positions(x[1]),
                               atol=USD_TOLERANCE)
    assert list(stage.GetRootLayer().customLayerData["facesim"]["unconverged_frames"]) == []


def test_usd_passes_openusd_validation(run, box_model, tmp_path):
    """The stage passes the validators OpenUSD ships (what ``usdchecker`` runs: stage metadata,
    geometry encapsulation, composition, attribute types, ...) with no error."""
    from pxr import UsdValidation

    path = export_cache(run, box_model, usd=tmp_path / "face.usda")["usd"]
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    assert len(validators) >= 10
    errors = UsdValidation.ValidationContext(validators).Validate(Usd.Stage.Open(str(path)))
    assert [f"{e.GetName()}: {e.GetMessage()}" for e in errors] == []


def test_usd_holds_the_last_converged_frame(failed, box_model, tmp_path):
    path = export_cache(failed, box_model, usd=tmp_path / "face.usda", fps=10)["usd"]
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == 10
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/skin")).GetPointsAttr()
    assert len(points.GetTimeSamples()) == 3
    np.testing.assert_array_equal(np.array(points.Get(1.0)), np.array(points.Get(0.0)))
    assert not np.array_equal(np.array(points.Get(3.0)), np.array(points.Get(0.0)))
    assert list(stage.GetRootLayer().customLayerData["facesim"]["unconverged_frames"]) == [1]


def test_usd_before_any_converged_frame_shows_the_rest_pose(box_model, tmp_path):
    x = np.stack([np.full_like(box_model.X, np.nan), box_model.X + 1.0])
    run = Run.from_arrays([4, 5], x, np.zeros((2, 2)), converged=[False, True])
    stage = Usd.Stage.Open(str(write_usd(box_model, run, tmp_path / "c.usdc")))
    skin = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/skin"))
    nodes = np.array(skin.GetPrim().GetAttribute("facesim:node").Get())
    np.testing.assert_allclose(np.array(skin.GetPointsAttr().Get(4.0)), box_model.X[nodes], atol=USD_TOLERANCE)
    np.testing.assert_allclose(np.array(skin.GetPointsAttr().Get(5.0)), box_model.X[nodes] + 1, atol=USD_TOLERANCE)
    assert stage.GetTimeCodesPerSecond() == 30   # no rate given anywhere


# ------------------------------------------------------------------ ParaView
def _activation_oracle(model, a):
    out = np.zeros(model.n_tets)
    for m, t, f in zip(model.muscles.muscle, model.muscles.tet, model.muscles.fraction):
        out[t] += f * a[m]
    return out


def test_pvd_series_arrays(run, box_model, tmp_path):
    path = export_cache(run, box_model, pvd=tmp_path / "series.pvd")["pvd"]
    entries = read_pvd(path)
    np.testing.assert_allclose([t for t, _ in entries], FRAMES / FPS)
    x = states(run)
    for i, (_, vtu) in enumerate(entries):
        assert vtu.name == f"frame_{FRAMES[i]:05d}.vtu"
        mesh = meshio.read(vtu)
        np.testing.assert_array_equal(mesh.points, x[i])
        np.testing.assert_array_equal(mesh.cells_dict["tetra"], box_model.tets)
        np.testing.assert_allclose(mesh.point_data["displacement"], x[i] - box_model.X)
        activation = mesh.cell_data["activation"][0]
        np.testing.assert_allclose(activation, _activation_oracle(box_model, A[i]), atol=1e-12)
        assert activation.shape == (box_model.n_tets,) and (i == 0 or activation.max() > 0.3)
        np.testing.assert_array_equal(mesh.cell_data["tissue"][0], box_model.tissue)
        assert mesh.field_data["muscle:orbicularis_oris"][0] == 1 and mesh.field_data["tissue:muscle"][0] == 1
        assert mesh.field_data["frame"][0] == FRAMES[i] and mesh.field_data["converged"][0] == 1
    _, stress = tet_activation(box_model, [1.0, 0.0])
    np.testing.assert_allclose(stress.max(), 0.55 * 0.3)   # fraction x sigma_max of the zygomaticus


def test_pvd_opens_in_pyvista_with_times(failed, box_model, tmp_path):
    pv = pytest.importorskip("pyvista")
    path = export_cache(failed, box_model, pvd=tmp_path / "series.pvd")["pvd"]
    entries = read_pvd(path)
    assert entries[1][1] == entries[0][1]   # frame 1 did not converge: the last converged volume again
    reader = pv.PVDReader(str(path))
    np.testing.assert_allclose(reader.time_values, FRAMES / FPS)
    reader.set_active_time_value(FRAMES[2] / FPS)
    grid = reader.read()[0]
    assert grid.n_cells == box_model.n_tets and grid.point_data["displacement"].shape == (box_model.n_nodes, 3)
    np.testing.assert_allclose(grid.points, states(failed)[2])


# ------------------------------------------------------------------ C3D
def test_c3d_round_trip_with_gap(run, box_model, tmp_path):
    path = export_cache(run, box_model, c3d=tmp_path / "markers.c3d")["c3d"]
    data, csv = read_markers(path), read_markers_csv(run / "markers.csv")
    np.testing.assert_array_equal(data.frames, [0, 1, 2, 3])
    assert data.names == box_model.markers.names and data.rate == FPS
    assert np.isnan(data.P[2]).all()   # frame 2 was not simulated: missing
    np.testing.assert_allclose(data.P[[0, 1, 3]], csv.P, atol=1e-4)   # C3D stores float32


def test_c3d_from_states_without_markers_csv(failed, box_model, tmp_path):
    (failed / "markers.csv").unlink()
    data = read_markers(export_cache(failed, box_model, c3d=tmp_path / "m.c3d")["c3d"])
    assert np.isnan(data.P[1]).all() and np.isnan(data.P[2]).all()
    np.testing.assert_allclose(data.P[3], box_model.marker_positions(states(failed)[2]), atol=1e-4)


# ------------------------------------------------------------------ errors and the CLI
def test_errors_are_one_line(run, box_model, tmp_path, monkeypatch):
    with pytest.raises(FacesimError, match="no such run folder"):
        read_run(tmp_path / "nothing", box_model)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FacesimError, match="no state files"):
        read_run(tmp_path / "empty", box_model)
    out = shutil.copytree(run, tmp_path / "out")
    (out / "state" / "frame_00003.npz").unlink()
    with pytest.raises(FacesimError, match=r"missing state files of 1 frames listed in frames.csv.*frame_00003"):
        read_run(out, box_model)
    np.savez(out / "state" / "frame_00003.npz", x=np.zeros((5, 3)), a=np.zeros(2), converged=True)
    with pytest.raises(FacesimError, match="5 nodes, the model has 210; .* another model"):
        export_cache(out, box_model, pvd=tmp_path / "p.pvd")
    monkeypatch.setitem(sys.modules, "pxr", None)   # as if usd-core were not installed
    with pytest.raises(FacesimError, match="pip install usd-core"):
        export_cache(run, box_model, usd=tmp_path / "u.usd")
    with pytest.raises(FacesimError, match="nothing to do"):
        export_cache(run, box_model)


def test_cli_export_cache(run, box_model_path, tmp_path, capsys):
    assert main(["export-cache", str(run), "--model", str(box_model_path), "--usd", str(tmp_path / "f.usd"),
                 "--pvd", str(tmp_path / "f.pvd"), "--c3d", str(tmp_path / "f.c3d")]) == 0
    printed = capsys.readouterr().out
    assert "cached 3 frames" in printed and "24 fps" in printed
    assert (tmp_path / "f.usd").is_file() and len(read_pvd(tmp_path / "f.pvd")) == 3 and (tmp_path / "f.c3d").is_file()
    assert main(["export-cache", str(tmp_path / "none"), "--model", str(box_model_path), "--usd", "x.usd"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no such run folder" in err
