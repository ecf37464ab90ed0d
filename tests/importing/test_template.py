"""The template transfer (facesim.importing.template): landmarks of the procedural head, the
landmark warp, and the template's muscles and markers carried onto other meshes.

Figures measured when these tests were written (coarse template, 20 samples per tet):

* identity (coarse -> coarse): the same 1,409 entries, fractions and fibres to round-off,
  markers at the same positions (4e-14 mm).
* coarse -> medium mesh (same anatomy, a finer mesh of its own), identity landmarks: per-muscle
  volumes within 24 % of the medium model's own embedding (their sum within 4 %), which is the
  coarse embedding's own disagreement with the medium one (the transfer keeps the coarse
  volumes within 5 %); centroids within 4.2 mm of the medium model's own (the coarse model's
  own are 4.1 mm off); fibres 1.5 deg apart (fraction-weighted mean); markers 0.5 mm off the
  medium skin.
* a known affine map (scale 1.1 / 0.95 / 1.05 and a shear): exact -- fibres rotate by the map
  (2.6 deg on average) to 1e-6 deg, volumes scale by det A, centroids move by the map.
* the same plus a small bend (z -= 0.001 x^2, y += 0.00025 z^2): the landmark warp itself is
  up to 3.7 mm off the map on the face (no landmark near the temples or the orbits); fibres
  within 1 deg (mean) of the map's rotation (3.2 deg), centroids 0.6 mm (mean, 4.6 max),
  markers 0.6 mm (mean, 0.4 median; 3.5 mm at the temples, 58 mm from any landmark, where the
  warp itself is 3.6 mm off; under 1 mm within 25 mm of a landmark).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.interpolate import RBFInterpolator

from facesim._kernels import locate as kernels
from facesim.errors import FacesimError
from facesim.fem.meshes import TetLocator
from facesim.importing.template import (LANDMARK_NAMES, MIN_LANDMARKS, barycentric_samples, landmark_warp,
                                        template_landmarks, transfer_markers, transfer_muscles)
from facesim.model import load_model, signed_volumes
from tests.conftest import box_tets, boundary_triangles

MESHES = Path(__file__).resolve().parents[2] / "meshes"


@pytest.fixture(scope="module")
def coarse():
    return load_model(MESHES / "face_coarse.npz")


@pytest.fixture(scope="module")
def medium():
    return load_model(MESHES / "face_medium.npz")


@pytest.fixture(scope="module")
def landmarks(coarse):
    return template_landmarks(coarse)


def _centroids(muscles, X, tets):
    """(n_muscles, 3) fraction-volume weighted centroids, mm (NaN for an empty muscle)."""
    vol = signed_volumes(X, tets)
    cen = X[tets].mean(axis=1)
    w = muscles.fraction * vol[muscles.tet]
    out = np.full((muscles.n_muscles, 3), np.nan)
    for m in range(muscles.n_muscles):
        e = muscles.entries(m)
        if w[e].sum() > 0:
            out[m] = np.average(cen[muscles.tet[e]], axis=0, weights=w[e])
    return out


def _pairs(a, b):
    """Indices (i into a, j into b) of the (muscle, tet) entries both muscle sets hold."""
    key_a = a.muscle.astype(np.int64) * 10**7 + a.tet
    key_b = b.muscle.astype(np.int64) * 10**7 + b.tet
    common, i, j = np.intersect1d(key_a, key_b, return_indices=True)
    return i, j


def _angle_deg(u, v):
    """Angles between the directions ``u (k, 3)`` and ``v (k, 3)`` up to sign, degrees."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.abs(np.einsum("ij,ij->i", u, v))))


# ------------------------------------------------------------------------------- landmarks
#: where the rules land on the procedural head (mm); docs/physics.md section 6 values where the
#: phantom's profile follows them (the phantom symphysis is nearly vertical: its most forward
#: point is 14 mm above the textbook pogonion)
EXPECTED = {"condyle_left": (50, 0, 0), "condyle_right": (-50, 0, 0), "incisor": (0, -40, 79.7),
            "upper_incisor": (0, -38, 81), "menton": (0, -88, 70), "pogonion": (0, -64, 81),
            "gonion_left": (47, -59, -6), "gonion_right": (-47, -59, -6), "pronasale": (0, -2, 115),
            "subnasale": (0, -17, 95), "nasion": (0, 38, 84), "stomion": (0, -39, 94),
            "cheilion_left": (25, -38, 83), "cheilion_right": (-25, -38, 83), "labiale_superius": (0, -36, 95),
            "labiale_inferius": (0, -43, 93), "soft_pogonion": (0, -65, 91)}


def test_template_landmarks_on_the_procedural_head(coarse, medium, landmarks):
    assert set(landmarks) == set(LANDMARK_NAMES)
    np.testing.assert_array_equal(landmarks["condyle_left"], coarse.jaw.condyle_left)
    np.testing.assert_array_equal(landmarks["incisor"], coarse.jaw.incisor)
    for name, where in EXPECTED.items():
        assert np.linalg.norm(landmarks[name] - where) < 5.0, (name, landmarks[name])
    # left/right mirror images, and the same rules find the same points on the finer mesh
    for side in ("gonion", "cheilion"):
        left, right = landmarks[f"{side}_left"], landmarks[f"{side}_right"]
        assert np.linalg.norm(left * [-1, 1, 1] - right) < 2.0
    other = template_landmarks(medium)
    far = {n: round(float(np.linalg.norm(other[n] - landmarks[n])), 2) for n in LANDMARK_NAMES}
    assert max(far.values()) < 3.0, far


# ------------------------------------------------------------------------------------ warp
def test_warp_is_scipys_thin_plate_spline_with_its_jacobian_and_inverse(coarse, landmarks):
    rng = np.random.default_rng(1)
    dst = {n: p * [1.05, 0.97, 1.02] + rng.normal(0.0, 0.5, 3) for n, p in landmarks.items()}
    P = coarse.X[::13]
    for smoothing in (0.0, 5.0):
        warp = landmark_warp(landmarks, dst, smoothing=smoothing)
        oracle = RBFInterpolator(warp.src, warp.dst, kernel="thin_plate_spline", degree=1, smoothing=smoothing)
        moved = warp(P)
        assert np.abs(moved - P).max() > 1.0                             # not a trivial map
        np.testing.assert_allclose(moved, oracle(P), atol=1e-8)
        h = 1e-4
        fd = np.stack([(warp(P[:40] + h * e) - warp(P[:40] - h * e)) / (2 * h) for e in np.eye(3)], axis=2)
        np.testing.assert_allclose(warp.jacobian(P[:40]), fd, atol=1e-6)
        back, res = warp.inverse(moved, return_residual=True)
        assert np.abs(back - P).max() < 1e-6 and res.max() < 1e-6
        err = warp.landmark_error().max()
        assert (err < 1e-9) if smoothing == 0 else (0.05 < err < 2.0)


def test_warp_errors_are_one_line(coarse, landmarks):
    few = {n: landmarks[n] for n in LANDMARK_NAMES[:MIN_LANDMARKS - 2]}
    few_dst = dict(few, nasion=landmarks["nasion"])
    with pytest.raises(FacesimError, match=r"6 landmarks in common, need at least 8") as e:
        landmark_warp(dict(few, pronasale=landmarks["pronasale"]), few_dst)
    msg = str(e.value)
    assert "\n" not in msg
    assert "missing from the subject: pronasale;" in msg and "missing from the template: nasion;" in msg
    assert "stomion" in msg.split("missing from both:")[1]
    # a NaN position is a missing landmark
    nan = dict(landmarks, **{n: np.full(3, np.nan) for n in LANDMARK_NAMES[2:12]})
    with pytest.raises(FacesimError, match="7 landmarks in common"):
        landmark_warp(landmarks, nan)
    midline = {n: p for n, p in landmarks.items() if abs(p[0]) < 1e-6}
    assert len(midline) >= MIN_LANDMARKS
    with pytest.raises(FacesimError, match=r"11 template landmarks lie within ~\S+ mm of a plane"):
        landmark_warp(midline, midline)
    twin = dict(landmarks, pronasale=landmarks["nasion"])
    with pytest.raises(FacesimError, match="'pronasale' and 'nasion' coincide|'nasion' and 'pronasale' coincide"):
        landmark_warp(twin, landmarks)
    with pytest.raises(FacesimError, match=r"landmark 'menton': expected a \(3,\) position"):
        landmark_warp(landmarks, dict(landmarks, menton=[1.0, 2.0]))
    with pytest.raises(FacesimError, match="smoothing must be a finite number >= 0"):
        landmark_warp(landmarks, landmarks, smoothing=-1.0)
    # folding: gonions swapped folds at the landmarks; a lip pushed 12 mm back folds between them
    swapped = dict(landmarks, gonion_left=landmarks["gonion_right"], gonion_right=landmarks["gonion_left"])
    with pytest.raises(FacesimError, match="folds over the landmarks: det J = -"):
        landmark_warp(landmarks, swapped)
    pushed = dict(landmarks, labiale_superius=landmarks["labiale_superius"] - [0, 0, 12])
    warp = landmark_warp(landmarks, pushed)                          # fine at the landmarks ...
    with pytest.raises(FacesimError, match="folds over the domain"):
        landmark_warp(landmarks, pushed, domain=coarse.X)
    for call in (lambda: transfer_muscles(coarse, warp, coarse.X, coarse.tets),
                 lambda: transfer_markers(coarse, warp, coarse.X, coarse.skin)):
        with pytest.raises(FacesimError, match=r"folds over the template (mesh|skin)") as e:
            call()
        assert "\n" not in str(e.value)


# ---------------------------------------------------------------------------------- kernels
def test_samples_and_point_location_against_brute_force():
    for n in (1, 4, 10, 20, 35):
        lam = barycentric_samples(n)
        assert lam.shape == (n, 4) and lam.min() > 0
        np.testing.assert_allclose(lam.sum(axis=1), 1.0)
        np.testing.assert_allclose(lam.mean(axis=0), 0.25)          # the centroid: exact for linear fields
    with pytest.raises(FacesimError, match="samples_per_tet"):
        barycentric_samples(11)
    X, tets = box_tets((4, 3, 3), spacing=10.0)
    rng = np.random.default_rng(2)
    X = X + rng.normal(0.0, 1.0, X.shape) * (np.abs(X) < 14.9)      # jiggle the inner nodes
    P = rng.uniform(-1.0, 1.0, (4000, 3)) * [23.0, 18.0, 18.0]
    loc = TetLocator(X, tets, snap=0.0)
    tet, bary = loc.locate(P)
    # oracle: barycentric coordinates in every tet
    E = np.transpose(X[tets[:, 1:]] - X[tets[:, :1]], (0, 2, 1))
    lam = np.einsum("mij,pmj->pmi", np.linalg.inv(E), P[:, None] - X[tets[:, 0]][None])
    lam = np.concatenate([1 - lam.sum(axis=2, keepdims=True), lam], axis=2)
    inside = (lam.min(axis=2) >= -1e-10)
    assert 0.3 < inside.any(axis=1).mean() < 0.8                    # points both inside and out
    assert np.array_equal(tet >= 0, inside.any(axis=1))
    hit = tet >= 0
    assert inside[np.flatnonzero(hit), tet[hit]].all()
    np.testing.assert_allclose(np.einsum("pk,pkj->pj", bary[hit], X[tets[tet[hit]]]), P[hit], atol=1e-9)
    # with a snap distance, a point outside goes to the nearest tet iff the flesh is within reach
    out = P[~hit] * 1.0
    _, depth, _ = trimesh.proximity.closest_point(trimesh.Trimesh(X, boundary_triangles(tets), process=False), out)
    assert (depth < 1.0).sum() > 100 and (depth > 1.0).sum() > 100
    t2, b2 = TetLocator(X, tets, snap=1.0).locate(out)
    clear = np.abs(depth - 1.0) > 1e-6
    assert np.array_equal((t2 >= 0)[clear], (depth <= 1.0)[clear])
    snapped = t2 >= 0
    near = np.einsum("pk,pkj->pj", b2[snapped], X[tets[t2[snapped]]])
    np.testing.assert_allclose(np.linalg.norm(near - out[snapped], axis=1), depth[snapped], atol=1e-9)
    assert b2[snapped].min() >= 0 and np.allclose(b2[snapped].sum(axis=1), 1.0)


def test_closest_skin_point_against_trimesh(coarse):
    rng = np.random.default_rng(3)
    X, F = coarse.X, coarse.skin
    P = X[np.unique(F)][rng.choice(len(np.unique(F)), 60)] + rng.normal(0.0, 3.0, (60, 3))
    Fn = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    Fn /= np.linalg.norm(Fn, axis=1, keepdims=True)
    tri, bary = np.empty(60, np.int32), np.empty((60, 3))
    region, dist = np.empty(60, np.int64), np.empty(60)
    kernels.closest_on_triangles(X, F, Fn, P, np.zeros((60, 3)), -2.0, tri, bary, region, dist)  # any normal
    _, d, _ = trimesh.proximity.closest_point(trimesh.Trimesh(X, F, process=False), P)
    assert d.max() > 1.0
    np.testing.assert_allclose(dist, d, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(np.einsum("pk,pkj->pj", bary, X[F[tri]]) - P, axis=1), d, atol=1e-9)


# ----------------------------------------------------------------------- muscles and markers
def test_identity_reproduces_the_template(coarse, landmarks):
    warp = landmark_warp(landmarks, landmarks)
    muscles, report = transfer_muscles(coarse, warp, coarse.X, coarse.tets)
    ref = coarse.muscles
    assert muscles.names == ref.names and muscles.sides == ref.sides
    np.testing.assert_array_equal(muscles.sigma_max, ref.sigma_max)
    np.testing.assert_array_equal(muscles.tet, ref.tet)
    np.testing.assert_array_equal(muscles.muscle, ref.muscle)
    np.testing.assert_allclose(muscles.fraction, ref.fraction, atol=1e-12)
    assert _angle_deg(muscles.fibre, ref.fibre).max() < 1e-6
    assert report["flagged"] == {} and report["min_jacobian_det"] == 1.0
    assert all(abs(m["volume_ratio"] - 1) < 1e-9 and m["outside_target"] == 0 for m in report["muscles"].values())
    assert report["tets_over_full"] == {"template": 111, "target": 111}   # interlacing muscles kept as they are
    json.dumps(report)
    markers, mreport = transfer_markers(coarse, warp, coarse.X, coarse.skin)
    assert markers.names == coarse.markers.names and mreport["dropped"] == {}
    np.testing.assert_array_equal(markers.head, coarse.markers.head)
    json.dumps(mreport)
    moved = coarse.with_(markers=markers).marker_positions() - coarse.marker_positions()
    assert np.abs(moved).max() < 1e-6
    # a marker on an edge may bind to the neighbouring triangle at the same point
    assert (markers.triangle == coarse.markers.triangle).mean() > 0.8


def test_cap_total(coarse, landmarks):
    warp = landmark_warp(landmarks, landmarks)
    muscles, report = transfer_muscles(coarse, warp, coarse.X, coarse.tets, samples_per_tet=4, cap_total=True)
    total = muscles.total_fraction(coarse.n_tets)
    assert report["tets_over_full"]["target"] == 111 and report["capped"]
    assert total.max() <= 1 + 1e-12 and np.isclose(total.max(), 1.0)


def test_onto_the_medium_mesh(coarse, medium, landmarks):
    """Same anatomy, an independent finer mesh: the transfer agrees with the medium model's own
    embedding as well as the coarse embedding does (the ribbons are the same, meshed apart)."""
    warp = landmark_warp(landmarks, landmarks)
    muscles, report = transfer_muscles(coarse, warp, medium.X, medium.tets)
    vol = medium.tet_volumes()
    got = muscles.volume_per_muscle(vol)
    own = medium.muscles.volume_per_muscle(vol)
    template = coarse.muscles.volume_per_muscle(coarse.tet_volumes())
    assert np.abs(got / template - 1).max() < 0.06           # the transfer keeps the template's volumes
    assert np.abs(got / own - 1).max() < 0.30                # ... which differ from the medium's own by <= 25 %
    assert abs(got.sum() / own.sum() - 1) < 0.06
    ratio = np.array([m["volume_ratio"] for m in report["muscles"].values()])
    assert np.abs(ratio - 1).max() < 0.06 and report["flagged"] == {}
    dist = np.linalg.norm(_centroids(muscles, medium.X, medium.tets) - _centroids(medium.muscles, medium.X,
                                                                                 medium.tets), axis=1)
    assert dist.max() < 5.0 and np.median(dist) < 1.5
    i, j = _pairs(muscles, medium.muscles)
    weight = muscles.fraction[i] * vol[muscles.tet[i]]
    assert weight.sum() > 0.5 * got.sum()
    assert np.average(_angle_deg(muscles.fibre[i], medium.muscles.fibre[j]), weights=weight) < 4.0
    markers, mreport = transfer_markers(coarse, warp, medium.X, medium.skin)
    assert mreport["dropped"] == {} and mreport["max_distance_mm"] < 1.0
    bound = medium.with_(markers=markers).marker_positions()
    assert np.linalg.norm(bound - coarse.marker_positions(), axis=1).max() < 1.0
    # the medium model's own bindings project the canonical layout onto its own skin: most agree,
    # a few (the nasolabial fold) project 9 mm apart on the two meshes
    assert np.median(np.linalg.norm(bound - medium.marker_positions(), axis=1)) < 1.0


def _affine(P):
    A = np.array([[1.10, 0.00, 0.05], [0.00, 0.95, 0.00], [-0.04, 0.00, 1.05]])
    return np.atleast_2d(P) @ A.T + [2.0, -1.0, 3.0], A


def _bent(P):
    x, y, z = np.atleast_2d(P).T
    return np.stack([1.1 * x, 0.95 * y + 0.00025 * z**2, 1.05 * z - 0.001 * x**2], axis=1)


def _bent_jacobian(P):
    x, y, z = np.atleast_2d(P).T
    J = np.zeros((len(x), 3, 3))
    J[:, 0, 0], J[:, 1, 1], J[:, 2, 2] = 1.1, 0.95, 1.05
    J[:, 1, 2], J[:, 2, 0] = 0.0005 * z, -0.002 * x
    return J


def _known_map_transfer(coarse, landmarks, g, jacobian):
    """The template transferred onto its own mesh moved by ``g``, with the landmarks moved by ``g``.
    Returns (muscles, report, markers, marker report, target X, fibre rotation by g per template
    entry (deg), angle between transferred and expected fibres on common entries (deg), their weights)."""
    Xt = g(coarse.X)
    warp = landmark_warp(landmarks, {n: g(p)[0] for n, p in landmarks.items()})
    muscles, report = transfer_muscles(coarse, warp, Xt, coarse.tets)
    markers, mreport = transfer_markers(coarse, warp, Xt, coarse.skin)
    ref = coarse.muscles
    cen = coarse.X[coarse.tets[ref.tet]].mean(axis=1)
    expected = np.einsum("kij,kj->ki", jacobian(cen), ref.fibre)
    i, j = _pairs(ref, muscles)
    weight = ref.fraction[i] * signed_volumes(Xt, coarse.tets)[ref.tet[i]]
    return (muscles, report, markers, mreport, Xt, _angle_deg(ref.fibre, expected),
            _angle_deg(muscles.fibre[j], expected[i]), weight)


def test_known_affine_map_is_carried_exactly(coarse, landmarks):
    A = _affine(np.zeros(3))[1]
    muscles, report, markers, mreport, Xt, rotation, error, _ = _known_map_transfer(
        coarse, landmarks, lambda P: _affine(P)[0], lambda P: np.broadcast_to(A, (len(P), 3, 3)))
    assert rotation.mean() > 2.0                              # the fibres do turn ...
    assert error.max() < 1e-6 and len(error) == len(coarse.muscles.tet)   # ... exactly as the map says
    np.testing.assert_allclose(muscles.fraction, coarse.muscles.fraction, atol=1e-9)
    np.testing.assert_allclose(muscles.volume_per_muscle(signed_volumes(Xt, coarse.tets)),
                               np.linalg.det(A) * coarse.muscles.volume_per_muscle(coarse.tet_volumes()), rtol=1e-9)
    np.testing.assert_allclose(_centroids(muscles, Xt, coarse.tets),
                               _affine(_centroids(coarse.muscles, coarse.X, coarse.tets))[0], atol=1e-6)
    assert abs(report["min_jacobian_det"] - np.linalg.det(A)) < 1e-3
    got = coarse.with_(X=Xt, markers=markers).marker_positions()
    np.testing.assert_allclose(got, _affine(coarse.marker_positions())[0], atol=1e-6)


def test_known_bent_map(coarse, landmarks):
    muscles, report, markers, mreport, Xt, rotation, error, weight = _known_map_transfer(
        coarse, landmarks, _bent, _bent_jacobian)
    assert np.average(rotation, weights=weight) > 2.5
    assert np.average(error, weights=weight) < 1.5 and np.percentile(error, 90) < 3.5
    target = _centroids(muscles, Xt, coarse.tets)
    mapped = _centroids(coarse.muscles, Xt, coarse.tets)      # the template's entries on the bent mesh
    dist = np.linalg.norm(target - mapped, axis=1)
    assert dist.mean() < 1.2 and dist.max() < 6.0
    ratio = np.array([m["volume_ratio"] for m in report["muscles"].values()])
    assert np.median(np.abs(ratio - 1)) < 0.05 and report["flagged"] == {}
    # the markers on the bent skin, against the template's bindings on the bent mesh
    assert mreport["dropped"] == {}
    got = coarse.with_(X=Xt, markers=markers).marker_positions()
    true = coarse.with_(X=Xt).marker_positions()
    err = np.linalg.norm(got - true, axis=1)
    # binding adds nothing to the warp's own error (largest at the temples, 58 mm from any landmark)
    warp = landmark_warp(landmarks, {n: _bent(p)[0] for n, p in landmarks.items()})
    own = np.linalg.norm(warp(coarse.marker_positions()) - true, axis=1)
    assert (err <= own + 0.25).all()
    lm = np.array([_bent(p)[0] for p in landmarks.values()])
    near = np.linalg.norm(true[:, None] - lm[None], axis=2).min(axis=1) < 25.0
    assert near.sum() > 30 and err[near].max() < 1.0
    assert np.median(err) < 0.5 and err.max() < 4.5


def test_cropped_target_flags_and_drops(coarse, landmarks):
    """A face mask: flesh and skin below the brows only. The muscles above are reported by name
    (they fall outside the target flesh), and so are the markers, which are dropped."""
    warp = landmark_warp(landmarks, landmarks)
    cen = coarse.X[coarse.tets].mean(axis=1)
    tets = coarse.tets[(cen[:, 1] < 40) & (cen[:, 2] > 20)]
    muscles, report = transfer_muscles(coarse, warp, coarse.X, tets, samples_per_tet=10)
    flagged = report["flagged"]
    assert {"frontalis_L", "frontalis_R"} <= set(flagged)
    assert "outside the target flesh" in flagged["frontalis_L"]
    assert report["muscles"]["frontalis_L"]["outside_target"] > 0.9
    assert "zygomaticus_major_L" not in flagged and "orbicularis_oris_upper_R" not in flagged
    assert report["muscles"]["zygomaticus_major_L"]["volume_ratio"] > 0.95
    assert muscles.tet.max() < len(tets)
    scen = coarse.X[coarse.skin].mean(axis=1)
    mask = coarse.skin[(scen[:, 1] < 40) & (scen[:, 2] > 20)]
    markers, mreport = transfer_markers(coarse, warp, coarse.X, mask)
    dropped = mreport["dropped"]
    assert {"head_forehead_C", "forehead_low_L", "brow_inner_L"} <= set(dropped)
    assert "mm away" in dropped["head_forehead_C"] and "open edge" in dropped["brow_inner_L"]
    assert "nose_tip" not in dropped and "lip_upper_C" not in dropped and "chin_C" not in dropped
    assert set(markers.names) == set(coarse.markers.names) - set(dropped)
    assert mreport["head_markers"] == 1 and "head stabilisation needs 3" in mreport["warnings"][0]
    kept = [coarse.markers.names.index(n) for n in markers.names]
    tri = mask[markers.triangle]
    got = np.einsum("rk,rkj->rj", markers.bary, coarse.X[tri])
    assert np.abs(got - coarse.marker_positions()[kept]).max() < 1e-6


def test_bad_meshes(coarse, landmarks):
    warp = landmark_warp(landmarks, landmarks)
    flipped = coarse.tets[:, [0, 2, 1, 3]]
    with pytest.raises(FacesimError, match="target mesh: expected positively oriented tets"):
        transfer_muscles(coarse, warp, coarse.X, flipped)
    with pytest.raises(FacesimError, match=r"target mesh: expected tets \(m, 4\)"):
        transfer_muscles(coarse, warp, coarse.X[:10], coarse.tets)
    with pytest.raises(FacesimError, match="none of the template's 81 markers lands within 10 mm"):
        transfer_markers(coarse, warp, coarse.X * 1000.0, coarse.skin)    # a skin in micrometres
