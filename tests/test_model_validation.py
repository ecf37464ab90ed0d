"""Bad content is refused when read (issue 14): models, poses files and jaw rigs.

Each case corrupts one field of a good file written by the code itself (the synthetic box model
of ``conftest.py``, generated poses, fitted rigs) and expects a one-line
:class:`~facesim.errors.ModelFileError` naming the file, the field and what was expected; the
commands that read such files exit with status 2 and one line on stderr, no traceback.
"""

import dataclasses
import json

import numpy as np
import pytest

from facesim import se3
from facesim._files import MESHES
from facesim.cli import main
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw.classic import ClassicRig
from facesim.jaw.cli import read_poses
from facesim.jaw.frame import JawFrame
from facesim.jaw.nlpca import Autoencoder, NlpcaRig, Se3Chart
from facesim.jaw.posselt import PosseltRig
from facesim.kinematics.rig_jaw import RigJaw
from facesim.model import Tissue, load_model
from tests.test_model import _rewrite


# ---------------------------------------------------------------- models
def _arrays(path) -> dict:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def _meta(path) -> dict:
    return json.loads(str(_arrays(path)["meta"]))


def _tissues(good, i, **change) -> dict:
    """meta update replacing fields of tissue ``i``."""
    tissues = _meta(good)["tissues"]
    tissues[i] = {**tissues[i], **change}
    return {"tissues": tissues}


def _empty(good) -> dict:
    """Every array field of the model emptied (right trailing shapes, no muscles, no markers)."""
    a = _arrays(good)
    return {k: np.zeros((0,) + v.shape[1:], v.dtype) for k, v in a.items()
            if k != "meta" and not k.startswith(("jaw_condyle", "jaw_track", "jaw_incisor", "bone", "collider"))}


def model_cases(good):
    """{case: (replace, meta update, file field, words the message must hold)}."""
    a = _arrays(good)
    X, tets = a["X"], a["tets"]
    n, m = len(X), len(tets)
    nan_X = X.copy()
    nan_X[[3, 17]] = np.nan
    inf_X = X.copy()
    inf_X[5, 2] = np.inf
    flipped = tets[:, [1, 0, 2, 3]]
    one_flipped = tets.copy()
    one_flipped[5] = tets[5, [1, 0, 2, 3]]
    far = tets.copy()
    far[7, 2] = 10 ** 6
    wrapped = tets.astype(np.int64)
    wrapped[0, 0] += 2 ** 32                     # cast to int32 this would wrap back to a valid index
    fibre = a["muscle_entry_fibre"].copy()
    fibre[4] = 0.0
    nan_fibre = a["muscle_entry_fibre"].copy()
    nan_fibre[2, 1] = np.nan
    long_fibre = a["muscle_entry_fibre"] * 2.0
    sigma = a["muscle_sigma_max"].copy()
    sigma[1] = -0.1
    # a simulated tet with free nodes marked as moving with the cranium
    free_tet = int(np.flatnonzero(a["simulated"] & ~np.isin(tets, a["cranium_nodes"]).all(axis=1))[0])
    loose = a["simulated"].copy()
    loose[free_tet] = False
    bary = a["marker_bary"].copy()
    bary[2] = np.nan
    bone = a["bone0_vertices"].copy()
    bone[0] = np.nan
    no_tets = {"tets": tets[:0], "tissue": a["tissue"][:0], "simulated": a["simulated"][:0],
               "muscle_entry_muscle": a["muscle_entry_muscle"][:0], "muscle_entry_tet": a["muscle_entry_tet"][:0],
               "muscle_entry_fraction": a["muscle_entry_fraction"][:0], "muscle_entry_fibre": fibre[:0]}
    no_markers = {"marker_triangle": a["marker_triangle"][:0], "marker_bary": bary[:0],
                  "marker_offset": a["marker_offset"][:0], "marker_head": a["marker_head"][:0]}
    M = {"muscle_names": [], "muscle_sides": [], "marker_names": []}
    return {
        "X_nan": ({"X": nan_X}, None, "X", f"expected finite node coordinates (mm), 2 of {n:,} nodes (first: node 3) "
                                          f"are NaN or inf"),
        "X_inf": ({"X": inf_X}, None, "X", f"1 of {n:,} nodes (first: node 5) are NaN or inf"),
        "all_empty": (_empty(good), M, "X",
                      "expected at least one node, got none"),
        "no_tets": (no_tets, None, "tets", "expected at least one tet"),
        "no_skin": ({"skin": a["skin"][:0], **no_markers}, {"marker_names": []}, "skin",
                    "expected at least one skin triangle"),
        "c10_negative": ({}, _tissues(good, 0, c10=-1e-3), "meta.tissues[0].c10",
                         "expected c10 > 0 MPa, <= 10000 MPa and finite for tissue 'fat', got -0.001"),
        "c10_zero": ({}, _tissues(good, 1, c10=0.0), "meta.tissues[1].c10", "expected c10 > 0 MPa"),
        "c10_nan": ({}, _tissues(good, 0, c10=float("nan")), "meta.tissues[0].c10", "got nan"),
        "c01_negative": ({}, _tissues(good, 0, c01=-1e-4), "meta.tissues[0].c01", "expected c01 >= 0 MPa"),
        "kappa_negative": ({}, _tissues(good, 1, kappa=-0.1), "meta.tissues[1].kappa",
                           "expected kappa > 0 MPa, <= 1e+07 MPa and finite for tissue 'muscle', got -0.1"),
        "kappa_zero": ({}, _tissues(good, 0, kappa=0), "meta.tissues[0].kappa", "expected kappa > 0 MPa"),
        "kappa_inf": ({}, _tissues(good, 0, kappa=float("inf")), "meta.tissues[0].kappa", "got inf"),
        "kappa_text": ({}, _tissues(good, 0, kappa="stiff"), "meta.tissues[0].kappa", "got 'stiff'"),
        "sigma_negative": ({"muscle_sigma_max": sigma}, None, "muscle_sigma_max",
                           "expected finite peak stresses 0 <= sigma_max <= 100 MPa, 1 of 2 muscles (first: muscle 1) "
                           "are not ('orbicularis_oris': -0.1)"),
        "sigma_huge": ({"muscle_sigma_max": np.array([0.3, 1e30])}, None, "muscle_sigma_max", "<= 100 MPa"),
        "c10_huge": ({}, _tissues(good, 0, c10=1e30), "meta.tissues[0].c10", "<= 10000 MPa"),
        "collider_without_faces": ({"collider0_faces": a["collider0_faces"][:0]}, None, "collider0_faces",
                                   "expected a closed surface of at least 4 triangles, got 0"),
        "sigma_nan": ({"muscle_sigma_max": np.array([np.nan, 0.2])}, None, "muscle_sigma_max", "(first: muscle 0)"),
        "fibre_zero": ({"muscle_entry_fibre": fibre}, None, "muscle_entry_fibre",
                       "expected unit fibre directions, 1 of"),
        "fibre_nan": ({"muscle_entry_fibre": nan_fibre}, None, "muscle_entry_fibre", "(first: entry 2)"),
        "fibre_long": ({"muscle_entry_fibre": long_fibre}, None, "muscle_entry_fibre", "(length 2)"),
        "tets_float": ({"tets": tets.astype(np.float64)}, None, "tets",
                       "expected integer indices, stored as dtype float64"),
        "cranium_float": ({"cranium_nodes": a["cranium_nodes"].astype(np.float32)}, None, "cranium_nodes",
                          "expected integer indices, stored as dtype float32"),
        "simulated_int": ({"simulated": a["simulated"].astype(np.int8)}, None, "simulated", "expected a bool mask"),
        "X_text": ({"X": X.astype(str)}, None, "X", "expected real numbers"),
        "tets_wrapped": ({"tets": wrapped}, None, "tets", "expected integers in [-2147483648, 2147483647]"),
        "no_cranium": ({"cranium_nodes": a["cranium_nodes"][:0]}, None, "cranium_nodes",
                       "expected at least one node attached to the cranium"),
        "no_jaw": ({"jaw_nodes": a["jaw_nodes"][:0]}, None, "jaw_nodes",
                   "expected at least one node attached to the mandible"),
        "all_inverted": ({"tets": flipped}, None, "tets", f"every one of the {m:,} tets is inverted"),
        "one_inverted": ({"tets": one_flipped}, None, "tets",
                         f"expected positive rest volumes, 1 of {m:,} tets (first: tet 5) are inverted or flat"),
        "none_simulated": ({"simulated": np.zeros(m, bool)}, None, "simulated",
                           f"expected at least one simulated tet, got none of {m:,}"),
        "loose_tet": ({"simulated": loose}, None, "simulated", f"(first: tet {free_tet}) have free nodes"),
        "tets_range": ({"tets": far}, None, "tets", f"indices must lie in [0, {n}), got [0, 1000000]"),
        "muscle_tet_range": ({"muscle_entry_tet": a["muscle_entry_tet"] + m}, None, "muscle_entry_tet",
                             f"indices must lie in [0, {m})"),
        "jaw_negative": ({"jaw_nodes": a["jaw_nodes"] - 1000}, None, "jaw_nodes", "indices must lie in"),
        "bary_nan": ({"marker_bary": bary}, None, "marker_bary", "1 of 6 markers (first: marker 2) are not"),
        "condyle_nan": ({"jaw_condyle_left": np.array([np.nan, 0.0, 0.0])}, None, "jaw_condyle_left",
                        "expected 3 finite numbers, got [nan, 0.0, 0.0]"),
        "track_nan": ({}, {"jaw_track_length": float("nan")}, "meta.jaw_track_length", "expected a finite length"),
        "bone_nan": ({"bone0_vertices": bone}, None, "bone0_vertices", "expected finite vertex coordinates"),
    }


@pytest.fixture(scope="module")
def good(box_model, tmp_path_factory):
    return box_model.save(tmp_path_factory.mktemp("valid") / "good.npz")


@pytest.fixture(scope="module")
def bad_models(good):
    folder = good.parent
    out = {}
    for case, (replace, meta, key, words) in model_cases(good).items():
        out[case] = (_rewrite(good, folder / f"{case}.npz", replace=replace, meta_update=meta), key, words)
    return out


CASES = [
    "X_nan", "X_inf", "all_empty", "no_tets", "no_skin", "c10_negative", "c10_zero", "c10_nan", "c01_negative",
    "kappa_negative", "kappa_zero", "kappa_inf", "kappa_text", "sigma_negative", "sigma_nan", "fibre_zero",
    "fibre_nan", "fibre_long", "tets_float", "cranium_float", "simulated_int", "X_text", "tets_wrapped", "no_cranium",
    "no_jaw", "all_inverted", "one_inverted", "none_simulated", "loose_tet", "tets_range", "muscle_tet_range",
    "jaw_negative", "bary_nan", "condyle_nan", "track_nan", "bone_nan", "sigma_huge", "c10_huge",
    "collider_without_faces"]


def test_the_good_file_loads(good, box_model):
    loaded = load_model(good)
    assert loaded.n_tets == box_model.n_tets == 720
    np.testing.assert_array_equal(loaded.tets, box_model.tets)


def test_every_case_is_listed(good):
    assert sorted(model_cases(good)) == sorted(CASES)


@pytest.mark.parametrize("case", CASES)
def test_bad_model_content_is_refused(bad_models, case):
    path, key, words = bad_models[case]
    with pytest.raises(ModelFileError) as info:
        load_model(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: field '{key}': "), message
    assert words in message, message
    assert info.value.path == str(path)


@pytest.mark.parametrize("case", ["X_nan", "kappa_negative", "tets_float", "none_simulated", "fibre_zero",
                                  "all_inverted"])
def test_model_info_exits_2_with_one_line(bad_models, case, capsys):
    path, key, words = bad_models[case]
    capsys.readouterr()
    assert main(["model", "info", str(path)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{path}: field '{key}': " in err and words in err, err
    assert captured.out == ""


def test_model_info_of_the_good_file(good, capsys):
    assert main(["model", "info", str(good)]) == 0
    assert "720" in capsys.readouterr().out


@pytest.mark.parametrize("command", [["jaw", "generate", "--kinds", "speech", "--model"],
                                     ["jaw", "fit-model", "--model"]])
def test_jaw_commands_refuse_a_nan_model(bad_models, tmp_path, command, capsys):
    nan_model = tmp_path / "nan.npz"
    a = _arrays(bad_models["X_nan"][0])
    a["X"] = np.full_like(a["X"], np.nan)
    np.savez(nan_model, **a)
    out = tmp_path / "out.npz"
    capsys.readouterr()
    assert main([*command, str(nan_model), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{nan_model}: field 'X': expected finite node coordinates" in err
    assert not out.exists()


def test_in_memory_models_are_checked_too(box_model):
    fat, muscle = box_model.tissues
    with pytest.raises(FacesimError, match=r"^tissues\[1\]\.kappa: expected kappa > 0 MPa"):
        box_model.with_tissues([fat, Tissue("muscle", muscle.c10, 0.0, -0.2)])
    with pytest.raises(FacesimError, match=r"^muscles\.sigma_max: expected finite peak stresses"):
        box_model.with_muscle_strength([0.3, np.nan])
    X = np.array(box_model.X)
    X[0] = np.inf
    with pytest.raises(FacesimError, match=r"^X: expected finite node coordinates \(mm\), 1 of 210 nodes"):
        box_model.with_(X=X)
    with pytest.raises(FacesimError, match="expected integers in"):
        box_model.with_(cranium_nodes=np.asarray(box_model.cranium_nodes) + 0.5)
    # the legitimate edge of each range passes: c01 = 0, sigma_max = 0, integral float indices
    ok = box_model.with_(tissues=(Tissue("fat", 1e-3, 0.0, 0.1), muscle), cranium_nodes=box_model.cranium_nodes * 1.0)
    np.testing.assert_array_equal(ok.cranium_nodes, box_model.cranium_nodes)
    assert box_model.with_muscle_strength([0.0, 0.0]).muscles.sigma_max.sum() == 0.0


def test_shipped_models_still_load():
    paths = sorted(p for p in MESHES.glob("face_*.npz") if not p.stem.endswith("_posselt"))
    assert paths, "no shipped models found"
    for path in paths:
        model = load_model(path)
        assert model.n_simulated > 0 and (model.tet_volumes() > 0).all()


# ---------------------------------------------------------------- poses
def _rotation(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def test_check_rigid_accepts_rigid_motions_and_refuses_the_rest():
    T = se3.from_rt(np.stack([_rotation(a) for a in (0.0, 0.2, -0.4)]), np.array([[0, 0, 0], [1, 2, 3], [4, 5, 6.]]))
    np.testing.assert_array_equal(se3.check_rigid(T), T)
    near = T.copy()
    near[1, 0, 0] += 1e-8                        # float32-like rounding: still rigid
    se3.check_rigid(near)
    cases = {
        "a reflection (det R = -1) in pose 1 (1 of 3 poses)": np.diag([-1.0, 1.0, 1.0, 1.0]),
        "NaN or inf entries in pose 1": np.full((4, 4), np.nan),
        "|R^T R - I| = 3 in pose 1": np.diag([2.0, 1.0, 1.0, 1.0]),
        "last row 0 0 0.5 1 in pose 1": np.r_[np.eye(4)[:3], [[0.0, 0.0, 0.5, 1.0]]],
    }
    for words, bad in cases.items():
        P = T.copy()
        P[1] = bad
        with pytest.raises(FacesimError) as info:
            se3.check_rigid(P, "P.npz: field 'poses'")
        assert str(info.value).startswith("P.npz: field 'poses': expected ") and words in str(info.value)
    skew = T[2].copy()
    skew[:3, :3] += 1e-5                          # beyond the tolerance
    with pytest.raises(FacesimError, match=r"^jaw pose: expected rigid transforms with an orthonormal rotation"):
        se3.check_rigid(skew, "jaw pose")


def _poses_file(path, **fields):
    np.savez(path, **fields)
    return path


@pytest.fixture(scope="module")
def poses(tmp_path_factory):
    """A good poses file of 40 rigid poses (rotation about x, translation) and its arrays."""
    angles = np.linspace(0.0, 0.3, 40)
    P = se3.from_rt(np.stack([_rotation(a) for a in angles]), np.c_[np.zeros(40), -angles, angles])
    return tmp_path_factory.mktemp("poses"), P


@pytest.mark.parametrize("case", ["reflection", "nan", "scaled", "last_row", "float_bounds"])
def test_bad_poses_files_are_refused(poses, case):
    folder, P = poses
    bad = P.copy()
    extra = {}
    if case == "reflection":
        bad[7, :3, :3] = bad[7, :3, :3] @ np.diag([1.0, 1.0, -1.0])
        field, words = "poses", "got a reflection (det R = -1) in pose 7 (1 of 40 poses)"
    elif case == "nan":
        bad[3, 1, 2] = np.nan
        field, words = "poses", "expected finite values, got NaN or inf in 1 of 40 rows (first: row 3)"
    elif case == "scaled":
        bad[11, :3, :3] *= 1.01
        field, words = "poses", "orthonormal rotation (|R^T R - I| <= 1e-06), got |R^T R - I| = 0.0201 in pose 11"
    elif case == "last_row":
        bad[0, 3, 0] = 0.1
        field, words = "poses", "last row 0 0 0 1"
    else:
        extra = {"segment_names": np.array(["opening"]), "segment_bounds": np.array([[0.0, 10.0]])}
        field, words = "segment_bounds", "got dtype float64"
    path = _poses_file(folder / f"{case}.npz", poses=bad, **extra)
    with pytest.raises(ModelFileError) as info:
        read_poses(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: field '{field}': expected "), message
    assert words in message, message
    assert len(read_poses(_poses_file(folder / "good.npz", poses=P)).poses) == 40


@pytest.mark.parametrize("rig", ["6dof", "1dof", "nlpca", "posselt"])
def test_jaw_fit_on_a_reflection_exits_2(poses, rig, tmp_path, capsys):
    folder, P = poses
    bad = P.copy()
    bad[5, :3, :3] = -bad[5, :3, :3]              # det -1: a point reflection
    path = _poses_file(tmp_path / "reflect.npz", poses=bad)
    out = tmp_path / "rig.npz"
    capsys.readouterr()
    assert main(["jaw", "fit", "--rig", rig, "--poses", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{path}: field 'poses': expected rigid transforms with a rotation (det R = +1)" in err, err
    assert not out.exists()


def test_rigs_refuse_non_rigid_poses():
    frame = JawFrame(np.zeros(3), np.eye(3))
    rig = ClassicRig("1dof", frame, np.zeros(3), [[-1.0, 1.0]])
    flipped = np.diag([1.0, -1.0, 1.0, 1.0])[None]
    with pytest.raises(FacesimError, match=r"^poses: expected rigid transforms with a rotation \(det R = \+1\)"):
        rig.fit_parameters(flipped, np.eye(3) * 10)
    with pytest.raises(FacesimError, match=r"^jaw pose: expected rigid transforms with a rotation"):
        RigJaw(rig).parameters(flipped[0])


# ---------------------------------------------------------------- rigs
def _corrupt(src, dst, **replace):
    a = _arrays(src)
    meta = json.loads(str(a["meta"]))
    for k, v in list(replace.items()):
        if k.startswith("meta_"):
            meta[k[len("meta_"):]] = replace.pop(k)
    a.update(replace)
    a["meta"] = np.array(json.dumps(meta))
    np.savez(dst, **a)
    return dst


def _nlpca_rig() -> NlpcaRig:
    """A small NLPCA rig with fixed weights (its content matters here, not its fit)."""
    rng = np.random.default_rng(0)
    h = 4
    shapes = {"A": (3, 6), "W1": (h, 6), "b1": (h,), "W2": (3, h), "b2": (3,), "B": (6, 3), "W3": (h, 3),
              "b3": (h,), "W4": (6, h), "b4": (6,)}
    net = Autoencoder({k: 0.1 * rng.standard_normal(s) for k, s in shapes.items()}, np.zeros(6), 1.0)
    chart = Se3Chart.of(JawFrame(np.array([0.0, -40.0, 80.0]), np.eye(3)), rng.standard_normal((20, 3)) * 30)
    return NlpcaRig(chart, net, np.zeros(3), np.ones(3), np.arange(4.0), np.zeros((4, 2)) - 1, np.ones((4, 2)))


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rigs")
    frame = JawFrame(np.array([0.0, -40.0, 80.0]), np.eye(3))
    return {"classic": (ClassicRig("3dof", frame, np.zeros(3), np.tile([-1.0, 1.0], (3, 1))).save(folder / "c.npz"),
                        ClassicRig.load),
            "nlpca": (_nlpca_rig().save(folder / "n.npz"), NlpcaRig.load),
            "posselt": (MESHES / "face_coarse_posselt.npz", PosseltRig.load),
            "folder": folder}


def rig_cases(rigs):
    """{case: (kind, replacements, words)}."""
    posselt = _arrays(rigs["posselt"][0])
    tmj = _meta(rigs["posselt"][0])["tmj"]
    centres = posselt["centres"].copy()
    centres[3] = np.nan
    return {
        "classic_origin": ("classic", {"frame_origin": np.array([np.nan, 0.0, 0.0])},
                           "classic rig: jaw frame (fields 'frame_origin', 'frame_axes'): expected finite rigid"),
        "classic_axes": ("classic", {"frame_axes": np.diag([1.0, 1.0, -1.0])}, "jaw frame: expected orthonormal right"),
        "nlpca_grid": ("nlpca", {"grid": np.array([0.0, np.nan, 2.0, 3.0])},
                       "nlpca rig: field 'grid': expected finite numbers, got NaN or inf"),
        "nlpca_weights": ("nlpca", {"net_W3": np.full((4, 3), np.inf)}, "nlpca rig: field 'net_W3': expected finite"),
        "nlpca_text": ("nlpca", {"gain": np.array(["a", "b", "c"])}, "field 'gain': expected real numbers"),
        "nlpca_metric": ("nlpca", {"metric": np.zeros((6, 6))}, "field 'metric': expected an invertible"),
        "posselt_centres": ("posselt", {"centres": centres},
                            "posselt rig: field 'centres': expected finite numbers (the RBF map), got NaN or inf"),
        "posselt_scale": ("posselt", {"meta_scale": -1.0},
                          "posselt rig: field 'meta.scale': expected a finite RBF length unit > 0 mm, got -1.0"),
        "posselt_origin": ("posselt", {"frame_origin": np.array([0.0, np.inf, 0.0])}, "(fields 'frame_origin'"),
        "posselt_tmj": ("posselt", {"meta_tmj": {**tmj, "incisor": [0.0, float("nan"), 79.7]}},
                        "field 'meta.tmj': expected the jaw geometry's fields"),
    }


def test_good_rigs_load(rigs):
    for kind in ("classic", "nlpca", "posselt"):
        path, load = rigs[kind]
        assert load(path).frame.origin[1] == pytest.approx(-40.0)


@pytest.mark.parametrize("case", ["classic_origin", "classic_axes", "nlpca_grid", "nlpca_weights", "nlpca_text",
                                  "nlpca_metric", "posselt_centres", "posselt_scale", "posselt_origin",
                                  "posselt_tmj"])
def test_bad_rig_content_is_refused(rigs, case, capsys):
    kind, replace, words = rig_cases(rigs)[case]
    src, load = rigs[kind]
    path = _corrupt(src, rigs["folder"] / f"{case}.npz", **replace)
    with pytest.raises(ModelFileError) as info:
        load(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and words in message, message
    capsys.readouterr()
    assert main(["jaw", "pose", "--rig", str(path), "--sliders", "0.5", "0.5", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and words in err, err


def test_tmj_with_nan_is_refused_on_its_own(box_model):
    with pytest.raises(FacesimError, match=r"^jaw\.incisor: expected 3 finite numbers"):
        dataclasses.replace(box_model.jaw, incisor=np.array([0.0, np.nan, 1.0]))
    with pytest.raises(FacesimError, match=r"^jaw\.track_direction: expected a unit vector"):
        dataclasses.replace(box_model.jaw, track_direction=np.array([2.0, 0.0, 0.0]))
    with pytest.raises(FacesimError, match=r"^jaw\.condyle_left: expected two distinct condyles"):
        dataclasses.replace(box_model.jaw, condyle_left=box_model.jaw.condyle_right)
