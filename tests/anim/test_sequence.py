"""Controls sequences and their edits (issue 18, parts 1 and 3): blends are equilibria between their
ends, scale 0 / 1 are the rest and the original, gain moves the face beyond activation 1, files
round-trip, mirror swaps sides, retime keeps shared times, curves clamp, bad input is one line.

Simulations run on the synthetic box model (2 muscles, sliding-condyle jaw) with the direct solver
on one numba thread; names and mirroring on the shipped coarse face (32 muscles in L/R pairs)
without simulating.
"""

import json

import numpy as np
import pytest

from tests.conftest import one_numba_thread

from facesim import se3
from facesim.anim import (ControlsSequence, blend, concatenate, gain, keyframes, mirror, read_sequence, retime, scale,
                          splice, write_sequence)
from facesim.anim.curves import interpolate_values
from facesim.anim.symmetry import mirror_matrix
from facesim.controls import Controls
from facesim.errors import FacesimError
from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
from facesim.fem.newton import NewtonOptions
from facesim.kinematics.condyle import SlidingCondyleJaw
from facesim.mocap.io import read_markers_csv
from facesim.model import load_model
from facesim.simulate import SimulateOptions, simulate
from facesim._files import MESHES

one_thread = pytest.fixture(scope="module", autouse=True)(one_numba_thread)
DIRECT = SimulateOptions(newton=NewtonOptions(linear_solver="direct"))


@pytest.fixture(scope="module")
def face():
    """The shipped coarse face (32 muscles in _L/_R pairs, sliding-condyle TMJ symmetric about x = 0)."""
    return load_model(MESHES / "face_coarse.npz")


def expression(model, a, jaw=(0.0, 0.0, 0.0), **kw):
    return ControlsSequence.of(model, [a], jaw=[jaw], jaw_model="sliding-condyle", **kw)


def run(model, seq, out, gain=None, **kw):
    return simulate(model, seq.A, out, frames=seq.frames, jaw=seq.jaw, jaw_model="sliding-condyle", options=DIRECT,
                    progress=False, gain=gain, **kw)


def frame_log(out):
    lines = (out / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    return [dict(zip(header, line.split(","))) for line in lines[1:]]


# ------------------------------------------------------------------ blends are equilibria between their ends
@pytest.fixture(scope="module")
def blended(box_model, tmp_path_factory):
    """Five in-betweens of two expressions (activations and jaw opening and slide), simulated."""
    e0 = expression(box_model, [0.2, 0.1], (0.02, 0.0, 0.0))
    e1 = expression(box_model, [0.9, 0.6], (0.12, 2.0, 2.0))
    seq = blend(e0, e1, np.linspace(0.0, 1.0, 5))
    out = tmp_path_factory.mktemp("blend")
    run(box_model, seq, out)
    return seq, out


def test_blend_of_two_expressions_interpolates_the_controls_and_hits_both_ends_bit_for_bit(box_model, blended):
    seq, _ = blended
    assert np.array_equal(seq.frames, np.arange(5))
    np.testing.assert_allclose(seq.A[2], [0.55, 0.35], atol=1e-15)
    np.testing.assert_allclose(seq.jaw[1], [0.045, 0.5, 0.5], atol=1e-15)
    assert np.array_equal(seq.A[0], [0.2, 0.1]) and np.array_equal(seq.A[-1], [0.9, 0.6])
    assert np.array_equal(seq.jaw[-1], [0.12, 2.0, 2.0])


def test_every_frame_of_a_blend_is_an_equilibrium(box_model, blended):
    seq, out = blended
    log = frame_log(out)
    assert [int(r["converged"]) for r in log] == [1] * 5
    rtol = NewtonOptions().rtol
    assert all(float(r["relative_residual"]) <= rtol for r in log)
    # independently of the solver's report: the flesh and muscle forces balance at the free nodes
    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct")),
                        jaw_model="sliding-condyle")
    free = ~sim.fixed
    for k in (1, 2, 3):
        x = np.load(out / "state" / f"frame_{k:05d}.npz")["x"]
        scale_N = sim.force_scale(Controls(seq.A[k], jaw=seq.jaw[k]))
        assert scale_N > 1.0
        residual = np.linalg.norm(sim.internal_force(x, seq.A[k])[free])
        assert residual <= 10 * rtol * scale_N
        # the same positions are far from the equilibrium of other activations: the check can fail
        assert np.linalg.norm(sim.internal_force(x, seq.A[k] + 0.05)[free]) > 1e3 * residual


def test_the_markers_of_a_blend_lie_between_those_of_its_ends(blended):
    _, out = blended
    P = read_markers_csv(out / "markers.csv").P                  # (5, 6, 3) mm
    change = P[-1] - P[0]
    moving = np.abs(change) > 0.1                                # coordinates that move over 0.1 mm
    assert moving.sum() >= 6 and np.abs(change).max() > 3.0
    lo, hi = np.minimum(P[0], P[-1]), np.maximum(P[0], P[-1])
    inner = P[1:-1][:, moving]
    assert (inner > lo[moving]).all() and (inner < hi[moving]).all()
    # monotone from one end to the other, along every moving coordinate
    steps = np.diff(P, axis=0)[:, moving] * np.sign(change[moving])
    assert (steps > 0).all()


# ------------------------------------------------------------------ scale and gain
def test_scale_one_is_the_original_bit_for_bit_and_zero_the_rest_face(box_model, tmp_path):
    seq = ControlsSequence.of(box_model, [[0.3, 0.7], [0.75, 0.2]], jaw=[[0.05, 1.0, 2.0], [0.1, 0.5, 0.5]],
                              jaw_model="sliding-condyle")
    one = scale(seq, 1.0)
    assert one == seq and np.array_equal(one.A, seq.A) and np.array_equal(one.jaw, seq.jaw)
    assert scale(seq, 1.0, jaw=True) == seq
    double = scale(seq, 2.0)
    assert np.array_equal(double.A, [[0.6, 1.0], [1.0, 0.4]])          # clamped to 1
    only = scale(seq, 0.5, muscles=["orbicularis_oris"])
    assert np.array_equal(only.A, [[0.3, 0.35], [0.75, 0.1]])
    zero = scale(seq, 0.0, jaw=True)
    assert not zero.A.any() and not zero.jaw.any()
    run(box_model, zero, tmp_path / "zero")
    P = read_markers_csv(tmp_path / "zero" / "markers.csv").P
    np.testing.assert_allclose(P, np.broadcast_to(box_model.marker_positions(), P.shape), atol=1e-9)
    run(box_model, seq, tmp_path / "seq")
    moved = read_markers_csv(tmp_path / "seq" / "markers.csv").P - box_model.marker_positions()
    assert np.abs(moved).max() > 1.0                                   # the unscaled face does move


def test_gain_moves_the_markers_beyond_activation_one_monotonically(box_model, tmp_path):
    full = expression(box_model, [1.0, 0.0])
    assert full.A.max() == 1.0                                         # no activation can go further
    reach = {}
    for g in (1.0, 2.0, 4.0):
        seq = gain(full, g, muscles="zygomaticus_major")
        assert np.array_equal(seq.gain, [g, 1.0]) and np.array_equal(seq.A, full.A)
        s = run(box_model, seq, tmp_path / f"g{g:g}", gain=seq.gain)
        assert s["converged"] == 1 and s["gain"] == (None if g == 1.0 else {"zygomaticus_major_L": g})
        P = read_markers_csv(tmp_path / f"g{g:g}" / "markers.csv").P[0]
        reach[g] = P - box_model.marker_positions()
    far = {g: np.linalg.norm(d, axis=1).max() for g, d in reach.items()}    # mm: 9.3, 10.4, 11.4
    assert far[1.0] > 5.0
    assert far[2.0] > 1.08 * far[1.0] and far[4.0] > 1.08 * far[2.0]      # the flesh stiffens: sublinear
    # the same expression, further: the displacement field keeps its direction
    cos = (reach[4.0] * reach[1.0]).sum() / (np.linalg.norm(reach[4.0]) * np.linalg.norm(reach[1.0]))
    assert cos > 0.95
    # a gain of ones is no gain: the same equilibria, bit for bit
    run(box_model, full, tmp_path / "ones", gain=np.ones(2))
    assert (tmp_path / "ones" / "markers.csv").read_text() == (tmp_path / "g1" / "markers.csv").read_text()


def test_a_resume_with_another_gain_is_refused(box_model, tmp_path):
    seq = expression(box_model, [0.5, 0.2])
    run(box_model, seq, tmp_path / "out", gain=[2.0, 1.0])
    assert "gain" in json.loads((tmp_path / "out" / "run.json").read_text())["inputs"]
    run(box_model, seq, tmp_path / "out", gain=[2.0, 1.0], resume=True)     # the same gain resumes
    with pytest.raises(FacesimError, match=r"other inputs: gain differ"):
        run(box_model, seq, tmp_path / "out", gain=[3.0, 1.0], resume=True)
    with pytest.raises(FacesimError, match=r"gain: expected 2 finite .* > 0, got values down to -1"):
        run(box_model, seq, tmp_path / "bad", gain=[-1.0, 1.0])


# ------------------------------------------------------------------ files
def performance(model, F=6, seed=0, **kw):
    rng = np.random.default_rng(seed)
    jaw = SlidingCondyleJaw(model.jaw)
    q = np.stack([np.linspace(0.0, 0.3, F), rng.uniform(0, 8, F), rng.uniform(0, 8, F)], axis=1)
    q = np.clip(q, *jaw.bounds.T)
    return ControlsSequence.of(model, rng.uniform(0.0, 1.0, (F, model.n_muscles)), frames=np.arange(10, 10 + F),
                               jaw=q, jaw_model="sliding-condyle", **kw)


def test_write_then_read_gives_the_same_sequence(face, tmp_path):
    rng = np.random.default_rng(1)
    head = se3.exp(np.c_[rng.normal(0, 0.1, (6, 3)), rng.normal(0, 5.0, (6, 3))])
    g = np.ones(face.n_muscles)
    g[[3, 14]] = [2.0, 0.25]
    seq = performance(face, head=head, gain=g).replace(fps=60.0)
    write_sequence(tmp_path / "out", seq, face)
    back = read_sequence(tmp_path / "out", face)
    assert back == seq                                                 # every field, arrays bit for bit
    assert back.fps == 60.0 and back.gain[14] == 0.25 and np.array_equal(back.head, seq.head)
    header = (tmp_path / "out" / "gain.csv").read_text().splitlines()
    assert header[0] == "muscle,gain" and len(header) == face.n_muscles + 1
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["jaw_model_used"]["spec"] == "sliding-condyle" and report["gain"] == {
        face.muscles.names[3]: 2.0, face.muscles.names[14]: 0.25}
    # without gains and head: no gain.csv and head.csv, and the sequence again
    plain = performance(face, seed=2)
    write_sequence(tmp_path / "plain", plain, face)
    assert not (tmp_path / "plain" / "gain.csv").exists() and not (tmp_path / "plain" / "head.csv").exists()
    assert read_sequence(tmp_path / "plain", face) == plain
    # a folder is not written over without overwrite
    with pytest.raises(FacesimError, match="not empty; use --overwrite"):
        write_sequence(tmp_path / "plain", seq, face)
    write_sequence(tmp_path / "plain", seq, face, overwrite=True)
    assert read_sequence(tmp_path / "plain", face) == seq


def test_rigid_jaw_poses_and_csv_sources_round_trip(box_model, tmp_path):
    T = np.array([se3.exp([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), se3.exp([0.1, 0.02, -0.03, 0.5, -1.0, 0.2])])
    seq = ControlsSequence.of(box_model, [[0.1, 0.2], [0.3, 0.4]], jaw=T, jaw_model="rigid")
    write_sequence(tmp_path / "rigid", seq, box_model)
    assert (tmp_path / "rigid" / "jaw.csv").read_text().startswith("frame,rx,ry,rz,tx,ty,tz\n")
    back = read_sequence(tmp_path / "rigid", box_model)
    np.testing.assert_allclose(back.jaw, T, atol=1e-14)
    assert np.array_equal(back.A, seq.A) and back.jaw_model == seq.jaw_model
    # a bare activations CSV with its jaw CSV
    (tmp_path / "a.csv").write_text("frame,orbicularis_oris\n0,0.5\n1,0.25\n")
    (tmp_path / "j.csv").write_text("frame,opening,right_slide,left_slide\n0,0.1,0,0\n1,0.2,1,2\n")
    csv = read_sequence(tmp_path / "a.csv", box_model, jaw=tmp_path / "j.csv", jaw_model="sliding-condyle", fps=24)
    assert np.array_equal(csv.A, [[0.0, 0.5], [0.0, 0.25]]) and np.array_equal(csv.jaw[1], [0.2, 1.0, 2.0])
    assert csv.fps == 24.0 and csv.jaw_model.name == "sliding-condyle" and csv.setup == ""
    # without a jaw file: rest (rigid, None)
    assert read_sequence(tmp_path / "a.csv", box_model).jaw is None


# ------------------------------------------------------------------ mirror
def test_mirror_swaps_left_and_right_muscles_and_slides(face):
    names = face.muscles.names
    a = np.zeros(face.n_muscles)
    a[names.index("zygomaticus_major_L")] = 0.7
    a[names.index("frontalis_R")] = 0.2
    g = np.ones(face.n_muscles)
    g[names.index("risorius_L")] = 3.0
    seq = expression(face, a, (0.2, 3.0, 7.0), gain=g)
    m = mirror(seq, face)
    assert m.A[0, names.index("zygomaticus_major_R")] == 0.7 and m.A[0, names.index("zygomaticus_major_L")] == 0.0
    assert m.A[0, names.index("frontalis_L")] == 0.2 and m.A[0].sum() == pytest.approx(0.9)
    assert m.gain[names.index("risorius_R")] == 3.0 and m.gain[names.index("risorius_L")] == 1.0
    assert np.array_equal(m.jaw, [[0.2, 7.0, 3.0]])
    # the slide swap is the pose mirrored across the midsagittal plane (the TMJ is symmetric)
    jaw = SlidingCondyleJaw(face.jaw)
    S = mirror_matrix(face)
    np.testing.assert_allclose(S @ jaw.transform([0.2, 3.0, 7.0]) @ S, jaw.transform([0.2, 7.0, 3.0]), atol=1e-12)
    assert np.abs(jaw.transform([0.2, 3.0, 7.0]) - jaw.transform([0.2, 7.0, 3.0])).max() > 0.05


def test_mirror_twice_is_the_identity(face):
    rng = np.random.default_rng(4)
    head = se3.exp(np.c_[rng.normal(0, 0.1, (6, 3)), rng.normal(0, 5.0, (6, 3))])
    seq = performance(face, head=head, gain=rng.uniform(0.5, 3.0, face.n_muscles))
    once = mirror(seq, face)
    assert not np.array_equal(once.A, seq.A) and np.abs(once.head - seq.head).max() > 1e-3
    twice = mirror(once, face)
    assert np.array_equal(twice.A, seq.A) and np.array_equal(twice.jaw, seq.jaw)
    assert np.array_equal(twice.gain, seq.gain)
    np.testing.assert_allclose(twice.head, seq.head, atol=1e-12)
    assert np.array_equal(once.head[0], seq.head[0])                   # mirrored about the first frame's head


def test_mirror_of_other_jaw_models_mirrors_the_pose(face):
    """The affine-condyle jaw (12 frame coefficients) through parameters(S T S): the frames of the
    sliding-condyle poses with the slides swapped; the rigid jaw: S T S."""
    jaw = SlidingCondyleJaw(face.jaw)
    q = [[0.1, 2.0, 6.0], [0.3, 8.0, 1.0]]
    T = np.array([jaw.transform(p) for p in q])
    affine = ControlsSequence.of(face, np.zeros((2, face.n_muscles)), jaw=[jaw.frame(p) for p in q],
                                 jaw_model="affine-condyle")
    swapped = np.array([jaw.transform([p[0], p[2], p[1]]) for p in q])
    np.testing.assert_allclose(mirror(affine, face).jaw, [jaw.frame([p[0], p[2], p[1]]) for p in q], atol=1e-12)
    rigid = ControlsSequence.of(face, np.zeros((2, face.n_muscles)), jaw=T, jaw_model="rigid")
    np.testing.assert_allclose(mirror(rigid, face).jaw, swapped, atol=1e-12)


def test_mirror_needs_muscles_in_pairs(box_model):
    with pytest.raises(FacesimError, match=r"mirror: muscle 'zygomaticus_major_L' \(side L\) has no right partner"):
        mirror(expression(box_model, [0.5, 0.5]), box_model)


# ------------------------------------------------------------------ retime, keyframes, splice
def ramp(model, F, fps=30.0):
    """Activations and opening rising, the slides falling, over frames 0..F-1."""
    t = np.linspace(0.0, 1.0, F)
    return ControlsSequence.of(model, np.stack([t, t**2], axis=1), fps=fps,
                               jaw=np.stack([0.4 * t, 5 - 5 * t, 3 * t], axis=1), jaw_model="sliding-condyle")


def test_retime_keeps_the_start_the_end_and_the_values_at_common_times(box_model):
    seq = ramp(box_model, 31)                                          # 1 s at 30 Hz
    r24 = retime(seq, 24.0)
    assert r24.fps == 24.0 and np.array_equal(r24.frames, np.arange(25))
    assert np.array_equal(r24.A[::4], seq.A[::5]) and np.array_equal(r24.jaw[::4], seq.jaw[::5])   # every 1/6 s
    assert not np.array_equal(r24.A[1], seq.A[1])
    r60 = retime(seq, 60.0)
    assert np.array_equal(r60.frames, np.arange(61)) and np.array_equal(r60.A[::2], seq.A)
    np.testing.assert_allclose(r60.A[1::2], 0.5 * (seq.A[:-1] + seq.A[1:]), atol=1e-15)   # linear in between
    assert retime(r60, 30.0) == seq and retime(seq, 30.0) == seq
    # an end between two new frames: the last one holds the source's end
    short = ramp(box_model, 10)                                        # 0.3 s
    r = retime(short, 24.0, method="catmull-rom")
    assert np.array_equal(r.frames, np.arange(9))                      # 8/24 s >= 0.3 s
    assert np.array_equal(r.A[0], short.A[0]) and np.array_equal(r.A[-1], short.A[-1])
    assert np.array_equal(r.jaw[-1], short.jaw[-1])


def test_keyframes_linear_smoothstep_and_catmull_rom(box_model):
    e = [expression(box_model, a, q) for a, q in (([0.0, 0.2], (0.0, 0, 0)), ([1.0, 0.6], (0.5, 10, 10)),
                                                   ([1.0, 0.6], (0.5, 10, 10)), ([0.0, 0.2], (0.0, 0, 0)))]
    lin = keyframes(e[:2], [0, 10], "linear")
    assert np.array_equal(lin.frames, np.arange(11))
    np.testing.assert_allclose(lin.A[5], [0.5, 0.4], atol=1e-15)
    smooth = keyframes(e[:2], [0, 8], "smoothstep")
    np.testing.assert_allclose(smooth.A[2], [0.15625, 0.2 + 0.4 * 0.15625], atol=1e-15)   # 3s^2 - 2s^3 at 1/4
    cr = keyframes(e, [0, 10, 20, 30], "catmull-rom")
    for i, k in enumerate((0, 10, 20, 30)):
        assert np.array_equal(cr.A[k], e[i].A[0]) and np.array_equal(cr.jaw[k], e[i].jaw[0])
    # Catmull-Rom overshoots between the two equal keys; the edit clamps to [0, 1] and the jaw's bounds
    raw = interpolate_values([0, 10, 20, 30], [0.0, 1.0, 1.0, 0.0], [15.0], "catmull-rom")
    assert raw[0, 0] == pytest.approx(1.125)
    assert cr.A[15, 0] == 1.0 and cr.A.max() == 1.0 and cr.A[15, 1] > 0.6
    assert cr.jaw[15, 0] == 0.5 and cr.jaw[15, 1] == 10.0                          # max opening, track end
    # head poses on SE(3): the midpoint of a turn is half the turn, and rigid
    xi = np.array([0.0, 0.4, 0.0, 5.0, 0.0, 0.0])
    k0 = expression(box_model, [0, 0], head=[np.eye(4)])
    k1 = expression(box_model, [0, 0], head=[se3.exp(xi)])
    mid = keyframes([k0, k1], [0, 2], "linear").head[1]
    np.testing.assert_allclose(mid, se3.exp(0.5 * xi), atol=1e-14)
    assert np.linalg.norm(se3.so3_log(mid[:3, :3])) == pytest.approx(0.2)


def test_splice_and_concatenate_with_a_crossfade(box_model):
    a, b = ramp(box_model, 10), scale(ramp(box_model, 4), 0.5)
    s = splice(a, b, at=5, crossfade=2)
    assert np.array_equal(s.frames, np.arange(9))
    assert np.array_equal(s.A[:5], a.A[:5]) and np.array_equal(s.A[7:], b.A[2:])
    np.testing.assert_allclose(s.A[5], (2 * a.A[5] + b.A[0]) / 3, atol=1e-15)     # b weighs 1/3, then 2/3
    np.testing.assert_allclose(s.A[6], (a.A[6] + 2 * b.A[1]) / 3, atol=1e-15)
    cut = splice(a, b, at=5)
    assert np.array_equal(cut.A, np.concatenate([a.A[:5], b.A])) and np.array_equal(cut.frames, np.arange(9))
    c = concatenate([a, b, a], crossfade=1)
    assert np.array_equal(c.frames, np.arange(10 + 4 + 10 - 2))
    assert np.array_equal(c.A[:9], a.A[:9]) and np.array_equal(c.A[-9:], a.A[1:])
    np.testing.assert_allclose(c.A[9], 0.5 * (a.A[9] + b.A[0]), atol=1e-15)
    plain = concatenate([a, b])
    assert np.array_equal(plain.frames, np.arange(14)) and np.array_equal(plain.jaw[10:], b.jaw)


# ------------------------------------------------------------------ one-line errors
def one_line(excinfo) -> str:
    text = str(excinfo.value)
    assert "\n" not in text
    return text


def test_bad_inputs_are_one_line_errors(box_model, tmp_path):
    seq = ramp(box_model, 5)
    rigid = ControlsSequence.of(box_model, seq.A)
    cases = [
        (lambda: scale(seq, 1.5, muscles=["zygomatic_major_L"]), r"unknown muscle; closest: zygomaticus_major_L"),
        (lambda: blend(seq, rigid, 0.5), r"blend: b is for the 'rigid' jaw model, a for the 'sliding-condyle' one"),
        (lambda: scale(seq, -0.5), r"scale: expected 0 <= factor <= 100, got -0.5"),
        (lambda: gain(seq, 0.0), r"gain: expected 0 < factor <= 100, got 0"),
        (lambda: blend(seq, seq, 1.5), r"blend: t = 1.5 outside \[0, 1\]"),
        (lambda: blend(seq, seq, [0.1, 0.2]), r"blend: t: 2 values for 5 frames"),
        (lambda: blend(seq, retime(seq, 60), 0.5), r"blend: b is at 60 Hz, a at 30 Hz"),
        (lambda: concatenate([seq, gain(seq, 2.0)]), r"sequence 2 has gain 2 on zygomaticus_major_L"),
        (lambda: splice(seq, seq, at=3, crossfade=4), r"a crossfade of 4 frames from frame 3 needs 4 frames of a"),
        (lambda: splice(seq, seq, at=0), r"splice: no frame of a before frame 0"),
        (lambda: keyframes([seq, seq.at(2)], [0, 5]), r"keyframes: key 1 has 5 frames"),
        (lambda: keyframes([seq.at(0), seq.at(2)], [5, 5]), r"expected increasing integers"),
        (lambda: keyframes([seq.at(0), seq.at(2)], [0, 5], "cubic"), r"expected one of linear, smoothstep"),
        (lambda: seq.segment(7, 9), r"frames 7:9: no frame of the sequence in this range"),
        (lambda: seq.at(12), r"frame 12: not in the sequence"),
        (lambda: retime(seq, -24), r"retime: expected a frame rate > 0 Hz"),
        (lambda: ControlsSequence.of(box_model, [[1.5, 0.0]]),
         r"activations: expected \(1, 2\) finite values in \[0, 1\]"),
    ]
    for call, message in cases:
        with pytest.raises(FacesimError, match=message) as excinfo:
            call()
        one_line(excinfo)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FacesimError, match=r"empty: an empty folder; expected a solve-mocap") as excinfo:
        read_sequence(tmp_path / "empty", box_model)
    one_line(excinfo)
    with pytest.raises(FacesimError, match=r"no such folder or file"):
        read_sequence(tmp_path / "nowhere", box_model)
    # a folder of another model
    write_sequence(tmp_path / "face", seq, box_model)
    other = load_model(MESHES / "face_coarse.npz")
    with pytest.raises(FacesimError, match=r"solved with another model") as excinfo:
        read_sequence(tmp_path / "face", other)
    one_line(excinfo)


def test_a_bad_gain_file_is_a_one_line_error(box_model, tmp_path):
    write_sequence(tmp_path / "g", gain(ramp(box_model, 3), 2.0), box_model)
    assert np.array_equal(read_sequence(tmp_path / "g", box_model).gain, [2.0, 2.0])
    for text, message in (("muscle,gain\nzygomaticus_major_L,-1\n", r"line 2, column 'gain': gain -1 of "
                                                                     r"zygomaticus_major_L; expected a number > 0"),
                          ("muscle,gain\nzygomaticus_L,2\n",
                           r"unknown muscle 'zygomaticus_L'; closest: zygomaticus_major_L"),
                          ("muscle,gain\norbicularis_oris,2\norbicularis_oris,3\n", r"line 3.*again"),
                          ("muscle,scale\norbicularis_oris,2\n", r"expected 'muscle,gain'")):
        (tmp_path / "g" / "gain.csv").write_text(text)
        with pytest.raises(FacesimError, match=message) as excinfo:
            read_sequence(tmp_path / "g", box_model)
        one_line(excinfo)
    (tmp_path / "g" / "gain.csv").write_text("muscle,gain\norbicularis_oris,0.5\n")   # unlisted muscles keep 1
    assert np.array_equal(read_sequence(tmp_path / "g", box_model).gain, [1.0, 0.5])
