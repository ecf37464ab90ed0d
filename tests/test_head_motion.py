"""Head motion as an input of ``simulate`` (issue 18: head and jaw motion as moving Dirichlet
conditions): the API's ``head=``, ``simulate --head H.csv`` and ``--controls-from`` with a head.csv."""

import json

import numpy as np
import pytest

from facesim.cli import main
from facesim.controls_io import HEAD_COLUMNS, read_head_csv
from facesim.errors import FacesimError
from facesim.simulate import simulate


def yaw(angle, centre):
    """4x4 rotation by ``angle`` rad about the vertical axis through ``centre`` (mm), then a shift."""
    c, s = np.cos(angle), np.sin(angle)
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = np.asarray(centre) - T[:3, :3] @ centre + [1.5 * angle, -2.0 * angle, 0.0]
    return T


def write_head_csv(path, frames, H, digits=9):
    lines = ["frame," + ",".join(HEAD_COLUMNS)]
    for k, T in zip(frames, H):
        vals = [*T[:3, :3].ravel(), *T[:3, 3], 0.0]
        lines.append(",".join([str(k), *(f"{v:.{digits}g}" for v in vals)]))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_head_motion_moves_the_rest_face_rigidly(box_model, tmp_path):
    """With no activation, the equilibrium under a moved head is the rest face moved with it:
    every node and marker follows the head's rigid transform (to the solver tolerance)."""
    m = box_model
    centre = m.X.mean(axis=0)
    H = np.array([yaw(a, centre) for a in (0.0, 0.15, -0.1)])
    s = simulate(m, np.zeros((3, m.n_muscles)), tmp_path / "run", head=H, progress=False)
    assert s["converged"] == 3
    for k, T in enumerate(H):
        with np.load(tmp_path / "run" / "state" / f"frame_{k:05d}.npz") as z:
            x = z["x"]
        moved = m.X @ T[:3, :3].T + T[:3, 3]
        assert np.abs(x - moved).max() < 1e-4 * (1 + np.abs(moved).max())
    assert np.abs(x - m.X).max() > 2.5            # the head really moved (3 mm at the box corners)
    rec = json.loads((tmp_path / "run" / "run.json").read_text())
    assert "head" in rec["inputs"]


def test_head_motion_input_checked(box_model, tmp_path):
    m = box_model
    with pytest.raises(FacesimError, match=r"head: expected 2 4x4"):
        simulate(m, np.zeros((2, m.n_muscles)), tmp_path / "a", head=np.tile(np.eye(4), (3, 1, 1)), progress=False)
    bad = np.tile(np.eye(4), (2, 1, 1))
    bad[1, :3, :3] *= 1.1                          # a scale is not a head motion
    with pytest.raises(FacesimError, match="head: expected rigid transforms"):
        simulate(m, np.zeros((2, m.n_muscles)), tmp_path / "b", head=bad, progress=False)


def test_head_csv_reader(tmp_path):
    H = np.array([yaw(a, np.zeros(3)) for a in (0.0, 0.2)])
    f, G = read_head_csv(write_head_csv(tmp_path / "h.csv", [4, 5], H, digits=5))   # few digits: re-orthonormalised
    assert list(f) == [4, 5] and np.abs(G - H).max() < 1e-4
    assert np.abs(np.einsum("nji,njk->nik", G[:, :3, :3], G[:, :3, :3]) - np.eye(3)).max() < 1e-12
    H[1, 0, 0] = 0.5
    with pytest.raises(FacesimError, match=r"h2\.csv: head: expected rigid transforms .* in pose 1"):
        read_head_csv(write_head_csv(tmp_path / "h2.csv", [4, 5], H))
    (tmp_path / "h3.csv").write_text("frame,r00,r01\n0,1,0\n")
    with pytest.raises(FacesimError, match=r"h3\.csv: line 1: column 'r02' missing"):
        read_head_csv(tmp_path / "h3.csv")


def test_simulate_cli_head(box_model, box_model_path, tmp_path, capsys):
    m = box_model
    names = m.muscles.names
    acts = tmp_path / "a.csv"
    acts.write_text(f"frame,{names[0]}\n0,0\n1,0\n")
    H = np.array([yaw(a, m.X.mean(axis=0)) for a in (0.0, 0.1)])
    head = write_head_csv(tmp_path / "head.csv", [0, 1], H)
    assert main(["simulate", "--model", str(box_model_path), "--activations", str(acts), "--head", str(head),
                 "-o", str(tmp_path / "run"), "-q"]) == 0
    with np.load(tmp_path / "run" / "state" / "frame_00001.npz") as z:
        x = z["x"]
    assert np.abs(x - (m.X @ H[1, :3, :3].T + H[1, :3, 3])).max() < 1e-3
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["head"] == str(head) and report["head_motion"] is True
    # frames that are not the activations' frames: one line naming both files
    write_head_csv(tmp_path / "h2.csv", [0, 2], H)
    assert main(["simulate", "--model", str(box_model_path), "--activations", str(acts), "--head",
                 str(tmp_path / "h2.csv"), "-o", str(tmp_path / "run2"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "h2.csv: data row 2 is frame 2" in err and "a.csv" in err and "Traceback" not in err


def test_controls_from_takes_the_head_csv(box_model, box_model_path, tmp_path, capsys):
    """A controls folder with a head.csv (what solve-mocap --head solve and facesim edit of such a
    solve write) replays with its head motion; --head rest keeps the head fixed."""
    m = box_model
    acts = tmp_path / "a.csv"
    acts.write_text(f"frame,{m.muscles.names[0]}\n0,0\n1,0.0\n")
    edit = tmp_path / "edit"
    assert main(["edit", "keyframe", "--model", str(box_model_path), "--key", str(acts), "0", "0",
                 "--key", str(acts), "1", "1", "-o", str(edit), "-q"]) == 0
    H = np.array([yaw(a, m.X.mean(axis=0)) for a in (0.05, 0.1)])
    write_head_csv(edit / "head.csv", [0, 1], H)
    for head, expected in ((None, H[1]), ("rest", np.eye(4))):
        out = tmp_path / f"run_{head}"
        assert main(["simulate", "--model", str(box_model_path), "--controls-from", str(edit), "-o", str(out), "-q",
                     *(["--head", head] if head else [])]) == 0
        with np.load(out / "state" / "frame_00001.npz") as z:
            x = z["x"]
        assert np.abs(x - (m.X @ expected[:3, :3].T + expected[:3, 3])).max() < 1e-3


def test_dynamic_head_shake_lags_the_head(box_model, box_model_path, tmp_path):
    """simulate --dynamic --head: a fast turn of the head leaves the free flesh behind (inertia),
    a slow one does not: the dynamic state's departure from the rigidly moved rest face is
    several times larger when the same turn is made 20 times faster."""
    m = box_model
    acts = tmp_path / "a.csv"
    n = 6
    acts.write_text(f"frame,{m.muscles.names[0]}\n" + "".join(f"{k},0\n" for k in range(n)))
    H = np.array([yaw(0.2 * k / (n - 1), m.X.mean(axis=0)) for k in range(n)])
    head = write_head_csv(tmp_path / "head.csv", range(n), H)
    lag = {}
    for fps in (24.0, 480.0):
        out = tmp_path / f"dyn_{fps:g}"
        assert main(["simulate", "--model", str(box_model_path), "--activations", str(acts), "--head", str(head),
                     "--dynamic", "--fps", f"{fps:g}", "-o", str(out), "-q"]) == 0
        with np.load(out / "state" / f"frame_{n - 1:05d}.npz") as z:
            x = z["x"]
        lag[fps] = np.abs(x - (m.X @ H[-1, :3, :3].T + H[-1, :3, 3])).max()
    assert lag[480.0] > 5 * lag[24.0] and lag[480.0] > 1e-3, lag
