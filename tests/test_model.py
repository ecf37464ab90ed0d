"""FaceModel: npz round trip, immutability, with_() copies, one-line errors for bad files."""

import dataclasses
import json
import shutil
import zipfile

import numpy as np
import pytest

from facesim.errors import FacesimError, ModelFileError
from facesim.model import FORMAT_VERSION, FaceModel, load_model

# stored as float32 by the file format, so equal to about 1e-7 relative after a round trip
FLOAT32_FIELDS = {"fraction", "fibre"}


def assert_same(a, b, path="model"):
    """Recursively compare two models (dataclasses, tuples, arrays, scalars, dicts)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), path
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert a.shape == b.shape and a.dtype == b.dtype, f"{path}: {a.shape} {a.dtype} vs {b.shape} {b.dtype}"
        if path.rsplit(".", 1)[-1] in FLOAT32_FIELDS:
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7, err_msg=path)
        else:
            np.testing.assert_array_equal(a, b, err_msg=path)
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def test_save_load_round_trip(box_model, tmp_path):
    path = box_model.save(tmp_path / "sub" / "m.npz")
    loaded = load_model(path)
    assert_same(box_model, loaded)
    assert loaded.muscles.names == ("zygomaticus_major_L", "orbicularis_oris")
    assert loaded.markers.names[-2:] == ("head_L", "head_R")
    assert [s.name for s in loaded.colliders] == ["teeth_lower", "eye_L"]
    assert loaded.meta == {"resolution": "synthetic", "seed": 0}
    assert FaceModel.load(path).n_tets == box_model.n_tets == 720
    assert not list(path.parent.glob("*.tmp*"))  # the atomic save left no temporary file


def test_second_round_trip_is_exact(box_model, tmp_path):
    once = load_model(box_model.save(tmp_path / "a.npz"))
    twice = load_model(once.save(tmp_path / "b.npz"))
    np.testing.assert_array_equal(once.muscles.fraction, twice.muscles.fraction)
    np.testing.assert_allclose(once.muscles.fibre, twice.muscles.fibre, rtol=0, atol=1e-15)


def test_arrays_are_read_only(box_model):
    with pytest.raises(ValueError):
        box_model.X[0, 0] = 1.0
    with pytest.raises(ValueError):
        box_model.muscles.fraction[0] = 0.1
    with pytest.raises(dataclasses.FrozenInstanceError):
        box_model.X = np.zeros((3, 3))


def test_with_returns_validated_copy_and_leaves_original(box_model):
    before = box_model.simulated.copy()
    changed = box_model.with_(simulated=np.ones(box_model.n_tets, dtype=bool))
    assert changed is not box_model
    assert changed.n_simulated == box_model.n_tets != box_model.n_simulated
    np.testing.assert_array_equal(box_model.simulated, before)
    assert not changed.simulated.flags.writeable
    assert changed.muscles is box_model.muscles  # unchanged parts are shared, not copied

    stronger = box_model.with_muscle_strength([1.0, 2.0])
    np.testing.assert_array_equal(stronger.muscles.sigma_max, [1.0, 2.0])
    np.testing.assert_array_equal(box_model.muscles.sigma_max, [0.3, 0.25])

    with pytest.raises(FacesimError, match="tissue: indices must lie in"):
        box_model.with_(tissue=np.full(box_model.n_tets, 7))
    with pytest.raises(FacesimError, match="simulated: expected one entry per tet"):
        box_model.with_(simulated=np.ones(3, dtype=bool))


# ---------------------------------------------------------------- bad files
def _rewrite(src, dst, drop=(), replace=None, meta_update=None, meta_drop=()):
    """Copy a model npz, dropping or replacing array keys or changing its JSON meta."""
    with np.load(src) as data:
        arrays = {k: data[k] for k in data.files if k not in drop}
    arrays.update(replace or {})
    meta = json.loads(str(arrays["meta"]))
    meta.update(meta_update or {})
    for k in meta_drop:
        del meta[k]
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(dst, **arrays)
    return dst


def bad_model_files(good, folder):
    """{case: (path, words the one-line message must contain)} for every refused kind of file."""
    text = folder / "text.npz"
    text.write_text("this is not a model\n")
    no_meta = folder / "no_meta.npz"
    np.savez(no_meta, X=np.zeros((3, 3)))
    return {
        "missing": (folder / "nope.npz", "no such file"),
        "text": (text, "not a readable .npz"),
        "no_meta": (no_meta, "field 'meta' missing"),
        "version": (_rewrite(good, folder / "v999.npz", meta_update={"version": 999}), "field 'meta.version'"),
        "format": (_rewrite(good, folder / "fmt.npz", meta_update={"format": "other"}), "field 'meta.format'"),
        "field": (_rewrite(good, folder / "noskin.npz", drop=("skin",)), "field 'skin' missing"),
        "meta_field": (_rewrite(good, folder / "nonames.npz", meta_drop=("muscle_names",)),
                       "field 'meta.muscle_names' missing"),
        "inconsistent": (_rewrite(good, folder / "short.npz", replace={"simulated": np.ones(3, dtype=bool)}),
                         "inconsistent model data: simulated: expected one entry per tet"),
    }


@pytest.fixture(scope="module")
def bad_files(box_model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("bad")
    return bad_model_files(box_model.save(folder / "good.npz"), folder)


@pytest.mark.parametrize("case", ["missing", "text", "no_meta", "version", "format", "field", "meta_field",
                                  "inconsistent"])
def test_bad_files_raise_one_line_model_file_error(bad_files, case):
    path, words = bad_files[case]
    with pytest.raises(ModelFileError) as info:
        load_model(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path) + ": ")
    assert words in message
    assert info.value.path == str(path)
    if case == "version":
        assert "999" in message and str(FORMAT_VERSION) in message


@pytest.mark.parametrize("case", ["npy", "corrupt"])
def test_npy_and_corrupt_files_raise_model_file_error(box_model, tmp_path, case):
    path = tmp_path / f"{case}.npz"
    if case == "npy":
        np.save(tmp_path / "a.npy", np.zeros(3))
        shutil.copy(tmp_path / "a.npy", path)
    else:
        data = bytearray(box_model.save(tmp_path / "good.npz").read_bytes())
        with zipfile.ZipFile(tmp_path / "good.npz") as z:
            info = z.getinfo("X.npy")
        for i in range(info.header_offset + 100, info.header_offset + 200):
            data[i] ^= 0xFF
        path.write_bytes(bytes(data))
    with pytest.raises(ModelFileError):
        load_model(path)
