"""Markerless jaw tracking, the learning half (facesim.jaw.markerless; Zoss et al. 2019 sections
5.2-7): SVR regression, rigid fit, Procrustes baseline, retargeting, multi-subject mapping, files.

The subjects are made here from a known smooth ground truth, independent of the code under test:
a U-shaped mandible of 5 bone points turning about a condyle axis (up to 0.4 rad) with small
lateral rotations, protrusion and side shift; ~40 skin feature points on a shell 8-14 mm outside
it whose displacement is a nonlinear blend of the jaw's rigid motion (the skin follows the bone
less far from the chin and slides back as the mouth opens wide), plus expression-like smooth
fields independent of the jaw, plus noise.
"""

import numpy as np
import pytest

from facesim import se3
from facesim.errors import FacesimError, ModelFileError
from facesim.jaw.markerless import (
    alignment,
    baseline_poses,
    evaluate,
    load_predictor,
    pose_error,
    predict_bone_points,
    predict_poses,
    retarget,
    rigid_poses,
    save_predictor,
    train,
)
from facesim.jaw.markerless_data import MarkerlessData

# a small grid keeps the file quick; the default grid is exercised once (test_recovers_smooth_map)
GRID = {"C": (10.0, 100.0), "epsilon": (0.02,), "gamma": (0.1, 0.3)}


def mandible(scale=1.0):
    """5 bone points (chin, two on the body, two at the angles) of a U-shaped mandible, mm; skull
    frame: x to the subject's left, y up, z forward, condyles on the x axis."""
    return scale * np.array([[0.0, -70, 85], [32, -62, 60], [-32, -62, 60], [46, -52, 18], [-46, -52, 18]])


def skin_shell(n=40, scale=1.0, thickness=1.0, seed=0):
    """``n`` skin points (mm) on a shell outside the mandible's U: along the U (angle phi) and down
    from the lip line, pushed outwards by 8-14 mm (times ``thickness``)."""
    rng = np.random.default_rng(seed)
    phi = rng.uniform(-1.1, 1.1, n)
    h = rng.uniform(0, 1, n)
    u = np.stack([np.sin(phi), np.zeros(n), np.cos(phi)], 1)          # outward in the horizontal plane
    base = np.stack([48 * np.sin(phi), -45 - 28 * h - 6 * np.cos(phi), 15 + 72 * np.cos(phi)], 1)
    return scale * base + thickness * (8 + 6 * h)[:, None] * u


def jaw_poses(n, seed):
    """``n`` random jaw poses (4, 4): opening about the condyle axis 0-0.4 rad, lateral rotation
    +-0.05 rad, protrusion -1..4 mm, side shift +-1.5 mm."""
    rng = np.random.default_rng(seed)
    opening = 0.4 * rng.uniform(0, 1, n) ** 1.3
    omega = np.stack([opening, rng.uniform(-0.05, 0.05, n), rng.uniform(-0.02, 0.02, n)], 1)
    T = se3.from_rt(se3.so3_exp(omega), np.stack([rng.uniform(-1.5, 1.5, n), np.zeros(n),
                                                  rng.uniform(-1, 4, n)], 1))
    return T


def skin_motion(rest, poses, chin, *, expressions=1.0, seed=0, noise=0.05, follow=1.0):
    """Skin positions ``(N, P, 3)``: rest points moved by a smooth nonlinear function of the jaw pose
    (a fraction of the rigid jaw motion, largest near the chin, shrinking as the mouth opens),
    plus two expression fields with random amplitudes, plus noise (mm)."""
    rng = np.random.default_rng(seed)
    N = len(poses)
    moved = se3.transform_points(poses, rest)                              # (N, P, 3)
    opening = np.linalg.norm(se3.so3_log(poses[:, :3, :3]), axis=1)
    w = follow * (0.45 + 0.45 * np.exp(-np.sum((rest - chin) ** 2, 1) / (2 * 35.0**2)))   # (P,)
    blend = w[None, :, None] * (1 - 0.6 * opening[:, None, None])
    fields = np.stack([np.stack([np.sin(rest[:, 0] / 30), 0.5 * np.cos(rest[:, 2] / 40), 0 * rest[:, 0]], 1),
                       np.stack([0 * rest[:, 0], np.sin(rest[:, 1] / 25), np.cos(rest[:, 0] / 20)], 1)])
    amp = expressions * rng.uniform(-1.5, 1.5, (N, 2))
    return rest + blend * (moved - rest) + np.einsum("nm,mpi->npi", amp, fields) + noise * rng.normal(size=moved.shape)


def subject(n, *, seed, scale=1.0, thickness=1.0, follow=1.0, placement=None, expressions=1.0, name=None):
    """One synthetic subject's MarkerlessData with ``n`` frames; ``placement`` (4, 4) moves the whole
    head (rest points, poses) to another skull frame."""
    bone = mandible(scale)
    rest = skin_shell(scale=scale, thickness=thickness)
    poses = jaw_poses(n, seed)
    skin = skin_motion(rest, poses, bone[0], seed=seed + 100, follow=follow, expressions=expressions)
    if placement is not None:
        G = placement
        bone, rest, skin = (x @ G[:3, :3].T + G[:3, 3] for x in (bone, rest, skin))
        poses = G @ poses @ se3.inverse(G)
    P = len(rest)
    return MarkerlessData(skin, rest, bone, poses, np.ones(n, bool), np.zeros(P, np.int64), np.full((P, 3), 1 / 3),
                          meta={"subject": name or f"s{seed}"})


def _mean_error(pred, data):
    return pose_error(predict_poses(pred, data), data.poses, data.bone_rest).mean()


def _baseline_error(data):
    return pose_error(baseline_poses(data), data.poses, data.bone_rest).mean()


@pytest.fixture(scope="module")
def source():
    """A subject with 400 frames (the first 300 to train on, the rest to test) and its predictor."""
    data = subject(400, seed=1)
    return data, train(data.subset(np.arange(300)), grid=GRID)


# ---------------------------------------------------------------------------------------------


def test_kabsch_recovers_a_rigid_transform_with_a_proper_rotation():
    rng = np.random.default_rng(3)
    rest = rng.normal(scale=20, size=(5, 3))
    T = se3.exp(np.r_[rng.normal(scale=0.5, size=3), rng.normal(scale=10, size=3)])
    assert np.allclose(rigid_poses(rest, se3.transform_points(T, rest)[None])[0], T, atol=1e-12)
    # a mirror image (x -> -x) plus noise: the unconstrained least-squares fit is a reflection;
    # the fit must be the best proper rotation, scipy's align_vectors being the oracle
    from scipy.spatial.transform import Rotation

    mirrored = rest * np.array([-1.0, 1.0, 1.0]) + rng.normal(scale=0.5, size=rest.shape)
    A, B = rest - rest.mean(0), mirrored - mirrored.mean(0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    assert np.linalg.det(Vt.T @ U.T) < 0          # the data does ask for a reflection
    pose = rigid_poses(rest, mirrored[None])[0]
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0, abs=1e-12)
    oracle, _ = Rotation.align_vectors(B, A)
    assert np.allclose(pose[:3, :3], oracle.as_matrix(), atol=1e-9)
    assert np.allclose(pose[:3, 3], mirrored.mean(0) - pose[:3, :3] @ rest.mean(0), atol=1e-9)


def test_baseline_is_exact_for_skin_that_moves_with_the_jaw():
    data = subject(30, seed=2)
    rigid = MarkerlessData(se3.transform_points(data.poses, data.skin_rest), data.skin_rest, data.bone_rest,
                           data.poses, data.ok, data.feature_tri, data.feature_bary)
    assert pose_error(baseline_poses(rigid), rigid.poses, rigid.bone_rest).max() < 1e-9
    # the synthetic skin does not: the baseline is off by millimetres there
    assert _baseline_error(data) > 2.0


def test_own_rbf_equals_sklearn():
    from sklearn.svm import SVR

    data = subject(120, seed=4)
    pred = train(data, grid={"C": (10.0,), "epsilon": (0.02,), "gamma": (0.3,)})
    X = data.skin_displacement.reshape(data.n_frames, -1)
    Z = (X - pred.x_mean) / pred.x_scale
    Y = (data.bone_points() - data.bone_rest).reshape(data.n_frames, -1)
    V = (Y - pred.y_mean) / pred.y_scale
    ref = np.stack([SVR(C=10.0, epsilon=0.02, gamma=pred.gamma).fit(Z, V[:, k]).predict(Z)
                    for k in range(V.shape[1])], 1) * pred.y_scale + pred.y_mean
    new = subject(50, seed=5)
    Zn = (new.skin_displacement.reshape(50, -1) - pred.x_mean) / pred.x_scale
    ref_new = np.stack([SVR(C=10.0, epsilon=0.02, gamma=pred.gamma).fit(Z, V[:, k]).predict(Zn)
                        for k in range(V.shape[1])], 1) * pred.y_scale + pred.y_mean
    assert np.abs(pred.regress(data.skin_displacement).reshape(len(ref), -1) - ref).max() < 1e-9
    assert np.abs(pred.regress(new.skin_displacement).reshape(50, -1) - ref_new).max() < 1e-9
    assert pred.meta["hyper"]["gamma"] == pytest.approx(0.3 / X.shape[1])


def test_recovers_smooth_map(source):
    data, pred = source
    test = data.subset(np.arange(300, 400))
    e_pred, e_base = _mean_error(pred, test), _baseline_error(test)
    print(f"\nheld-out frames: predictor {e_pred:.3f} mm, baseline {e_base:.3f} mm")
    assert e_pred < 0.6 and e_pred < e_base / 5
    # the default grid chooses among 18 points by CV; it must do no worse than the small grid
    default = train(data.subset(np.arange(300)))
    hyper = default.meta["hyper"]
    assert len(hyper["grid"]) == 18 and hyper["cv_mm"] == min(s["cv_mm"] for s in hyper["grid"])
    assert _mean_error(default, test) < 0.6


def test_evaluate_report_and_excluded_frames(source):
    data, pred = source
    test = data.subset(np.arange(300, 400))
    ok = test.ok.copy()
    ok[[3, 7]] = False
    bad = MarkerlessData(test.skin.copy(), test.skin_rest, test.bone_rest, test.poses, ok, test.feature_tri,
                         test.feature_bary)
    bad.skin[[3, 7]] += 50.0                        # garbage in the failed frames must not count
    report = evaluate(pred, bad)
    assert report["frames"] == 98 and report["excluded"] == [3, 7]
    assert set(report["predictor"]) == {"mean_mm", "p95_mm", "max_mm"}
    assert report["predictor"]["mean_mm"] < report["predictor"]["p95_mm"] <= report["predictor"]["max_mm"]
    assert report["predictor"]["mean_mm"] < report["baseline"]["mean_mm"] / 5
    # frames with ok False are not learned either
    poisoned = MarkerlessData(data.skin.copy(), data.skin_rest, data.bone_rest, data.poses, data.ok.copy(),
                              data.feature_tri, data.feature_bary)
    poisoned.skin[:60] += 40.0
    poisoned.ok[:60] = False
    p2 = train(poisoned.subset(np.arange(300)), grid=GRID)
    assert p2.meta["subjects"][0]["frames"] == 240 and p2.meta["subjects"][0]["excluded"] == 60
    assert _mean_error(p2, test) < 0.7


def test_predicts_from_bare_skin_and_checks_the_layout(source):
    data, pred = source
    test = data.subset(np.arange(300, 320))
    assert np.allclose(predict_poses(pred, test.skin), predict_poses(pred, test), atol=1e-10)
    with pytest.raises(FacesimError, match="^predictor expects 40 skin features, data has 39$"):
        predict_poses(pred, test.skin[:, :39])
    with pytest.raises(FacesimError, match="no jaw poses"):
        evaluate(pred, MarkerlessData(test.skin, test.skin_rest, test.bone_rest, None, test.ok, test.feature_tri,
                                      test.feature_bary))


def test_a_new_placement_of_the_head_is_aligned(source):
    """The same subject in another skull frame (rotated 20 degrees, shifted): the rest-point
    alignment undoes it, so the predictor is as good as in the subject's own frame."""
    data, pred = source
    G = se3.exp(np.r_[0.35 * np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2]), 5.0, -8.0, 3.0])
    moved = subject(400, seed=1, placement=G).subset(np.arange(300, 400))
    assert np.allclose(alignment(moved.skin_rest, moved.bone_rest, data.skin_rest, data.bone_rest), G[:3, :3].T,
                       atol=1e-9)
    assert abs(_mean_error(pred, moved) - _mean_error(pred, data.subset(np.arange(300, 400)))) < 1e-6


def _tissue_variant(data, attenuation=0.7, degrees=10.0):
    """The same jaw motion seen through thicker tissue: every displacement attenuated and turned."""
    Rt = se3.so3_exp(np.radians(degrees) * np.array([1.0, 0.4, 0.2]) / np.linalg.norm([1.0, 0.4, 0.2]))
    disp = attenuation * data.skin_displacement @ Rt.T
    return MarkerlessData(data.skin_rest + disp, data.skin_rest, data.bone_rest, data.poses, data.ok,
                          data.feature_tri, data.feature_bary, meta={"subject": "thick"})


def test_rotation_jacobian_and_retarget_gradient(source):
    """The analytic Jacobians of retargeting (rotation of a displacement; the whole least-squares
    problem through the RBF expansion) against central differences, at a random non-zero state."""
    from facesim.jaw.markerless import _Calibration, _neighbour_edges, _rotation_jacobian

    rng = np.random.default_rng(0)
    w, d = rng.normal(scale=0.4, size=3), rng.normal(size=3)
    h = 1e-6
    fd = np.stack([(se3.so3_exp(w + h * e) @ d - se3.so3_exp(w - h * e) @ d) / (2 * h) for e in np.eye(3)], 1)
    J = _rotation_jacobian(w, se3.so3_exp(w) @ d)
    assert np.abs(J).max() > 0.1 and np.abs(J - fd).max() < 1e-8

    _, pred = source
    cal = _tissue_variant(subject(5, seed=9))
    target = (cal.bone_points() - cal.bone_rest).reshape(5, -1)
    problem = _Calibration(pred, cal.skin_displacement, target, _neighbour_edges(cal.skin_rest, 4), 1.0, 0.1, True)
    x = rng.normal(scale=0.1, size=problem.n_params)
    J = problem.jacobian(x).toarray()
    h = 1e-5
    cols = rng.choice(problem.n_params, 12, replace=False)
    fd = np.stack([(problem.residuals(x + h * e) - problem.residuals(x - h * e)) / (2 * h)
                   for e in np.eye(problem.n_params)[cols]], 1)
    fit_rows = 5 * 15
    assert np.abs(J[:fit_rows, cols]).max() > 0.1
    assert np.abs(J[:, cols] - fd).max() < 1e-6 * np.abs(fd).max()


def test_retargeting_from_five_poses_beats_none(source):
    data, pred = source
    thick = _tissue_variant(subject(400, seed=7))
    calibration = thick.subset(np.array([10, 20, 30, 40, 50]))
    test = thick.subset(np.arange(100, 400))
    e_none = _mean_error(pred, test)
    adapted = retarget(pred, calibration)
    e_ret = _mean_error(adapted, test)
    info = adapted.meta["retarget"]
    print(f"\nthicker tissue (x0.7, 10 deg): no retargeting {e_none:.3f} mm, retargeted from 5 poses "
          f"{e_ret:.3f} mm, own-subject error {_mean_error(pred, data.subset(np.arange(300, 400))):.3f} mm; "
          f"calibration {info['calibration_mm_before']:.3f} -> {info['calibration_mm_after']:.3f} mm, "
          f"mean scale {info['mean_scale']:.3f}, mean rotation {info['mean_rotation_deg']:.2f} deg")
    assert e_ret < 0.5 * e_none
    assert info["frames"] == 5 and info["calibration_mm_after"] < info["calibration_mm_before"]
    # the regularisers matter: without them five frames overfit
    loose = retarget(pred, calibration, smoothness=0.0, identity=1e-6)
    assert _mean_error(loose, test) > 2 * e_ret
    # and so does the scale: rotations alone cannot undo the attenuation
    assert _mean_error(retarget(pred, calibration, scale=False), test) > 5 * e_ret
    assert adapted.retargeted and not pred.retargeted
    with pytest.raises(FacesimError, match="already retargeted"):
        retarget(adapted, calibration)


def test_multi_subject_predicts_a_held_out_subject_better():
    """Three subjects of different proportions, tissue response and head placement in one
    predictor against one of them alone, on a fourth subject never seen."""
    def placement(seed):
        rng = np.random.default_rng(seed)
        return se3.exp(np.r_[rng.normal(scale=0.15, size=3), rng.normal(scale=5, size=3)])

    train_subjects = [subject(200, seed=11, scale=1.0, follow=1.0, placement=placement(1)),
                      subject(200, seed=12, scale=0.92, follow=0.75, placement=placement(2)),
                      subject(200, seed=13, scale=1.07, follow=1.25, placement=placement(3))]
    held_out = subject(200, seed=14, scale=0.96, follow=0.85, placement=placement(4))
    single = train(train_subjects[0], grid=GRID)
    multi = train(train_subjects, grid=GRID)
    e_single, e_multi = _mean_error(single, held_out), _mean_error(multi, held_out)
    print(f"\nheld-out subject: single-subject {e_single:.3f} mm, three subjects {e_multi:.3f} mm, "
          f"baseline {_baseline_error(held_out):.3f} mm")
    assert e_multi < 0.7 * e_single
    assert [s["frames"] for s in multi.meta["subjects"]] == [200, 200, 200]
    # every training subject's own frames stay well predicted: the placements were undone
    for s in train_subjects:
        assert _mean_error(multi, s) < 0.6


def test_save_load_round_trip(source, tmp_path):
    data, pred = source
    thick = _tissue_variant(subject(60, seed=8))
    adapted = retarget(pred, thick.subset(np.arange(5)))
    for p, d, name in ((pred, data, "pred.npz"), (adapted, thick, "adapted.npz")):
        path = save_predictor(p, tmp_path / name)
        back = load_predictor(path)
        assert np.array_equal(predict_bone_points(back, d), predict_bone_points(p, d))
        assert back.meta == p.meta and back.gamma == p.gamma
    assert load_predictor(tmp_path / "adapted.npz").retargeted
    # single precision (the shipped predictor): a smaller file, the same jaw to ~1e-5 mm
    small = save_predictor(pred, tmp_path / "small.npz", single=True)
    assert small.stat().st_size < 0.7 * (tmp_path / "pred.npz").stat().st_size
    moved = np.abs(predict_bone_points(pred, data) - data.bone_rest).max()
    assert np.abs(predict_bone_points(load_predictor(small), data) - predict_bone_points(pred, data)).max() < 1e-5 * moved


def test_bad_predictor_files(source, tmp_path):
    data, pred = source
    dataset = data.save(tmp_path / "data.npz")
    with pytest.raises(ModelFileError) as err:
        load_predictor(dataset)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(str(dataset)) and "facesim-markerless-predictor" in msg
    with pytest.raises(ModelFileError, match="no such file"):
        load_predictor(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ModelFileError, match="junk.npz: not a readable"):
        load_predictor(tmp_path / "junk.npz")
    # a damaged predictor: wrong field shape, and a field missing
    good = np.load(save_predictor(pred, tmp_path / "p.npz"))
    fields = dict(good)
    fields["dual"] = fields["dual"][:, :-1]
    np.savez(tmp_path / "shape.npz", **fields)
    with pytest.raises(ModelFileError, match=r"shape.npz: field 'dual': expected shape"):
        load_predictor(tmp_path / "shape.npz")
    del fields["support"]
    np.savez(tmp_path / "missing_field.npz", **fields)
    with pytest.raises(ModelFileError, match=r"missing_field.npz: field 'support' missing"):
        load_predictor(tmp_path / "missing_field.npz")
