"""The valid inputs the fuzz cases start from, written into one folder (run in a subprocess)::

    python -m tests.fuzz.bases DIR

Writes the box model of ``tests/conftest.py`` (``box.npz``), 2-frame controls for it
(``a.csv``; rigid, sliding-condyle and Posselt jaw files ``j_*.csv``), a collider path and mesh
(``ball.csv``, ``ball.obj``), a 2-frame capture of its markers (``markers.csv/.trc/.c3d`` and
``capture.npz``, the arrays the C3D mutations rewrite), jaw poses (``ext.npz``: the five
extremes; ``ses.npz``: a session of border movements) and rigs (``r3.npz`` 3-DOF, ``rp.npz``
Posselt, ``rn.npz`` NLPCA, ``box_posselt.npz`` the box model's own Posselt rig).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

#: file names of the bases (the cases refer to them by these names)
FILES = ("box.npz", "a.csv", "j_open.csv", "j_full.csv", "j_slide.csv", "j_posselt.csv", "ball.csv", "ball.obj",
         "markers.csv", "markers.trc", "markers.c3d", "capture.npz", "ext.npz", "ses.npz", "r3.npz", "rp.npz",
         "rn.npz", "box_posselt.npz")


def _write(path: Path, text: str) -> None:
    path.write_text(text)


def _obj(vertices, faces) -> str:
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def write_bases(folder) -> Path:
    """Write every base file into ``folder``; returns it."""
    import trimesh

    from facesim.cli import main
    from facesim.kinematics.jaw_models import make_jaw_model
    from facesim.mocap.io import write_c3d, write_markers_csv, write_trc
    from tests.conftest import make_box_model

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    model = make_box_model()
    model.save(out / "box.npz")
    names = model.muscles.names
    _write(out / "a.csv", f"frame,{names[0]},{names[1]}\n0,0,0\n1,0.5,0.2\n")
    _write(out / "j_open.csv", "frame,opening\n0,0\n1,0.05\n")
    _write(out / "j_full.csv", "frame,rx,ry,rz,tx,ty,tz\n0,0,0,0,0,0,0\n1,0.05,0,0,0,-0.2,0.1\n")
    _write(out / "j_slide.csv", "frame,opening,right_slide,left_slide\n0,0,0,0\n1,0.05,0.5,0.5\n")
    _write(out / "ball.csv", "frame,x,y,z\n0,0,0,80\n1,0,2,81\n")
    ball = trimesh.creation.icosphere(1, 5.0)
    _write(out / "ball.obj", _obj(ball.vertices, ball.faces))

    # the box model's own Posselt rig, and the sliders of its rest pose
    assert main(["jaw", "fit-model", "--model", str(out / "box.npz"), "-o", str(out / "box_posselt.npz")]) == 0
    rest = make_jaw_model(model, f"posselt:{out / 'box_posselt.npz'}").rest
    moved = np.clip(rest + [0.0, 0.1, 0.0], 0.0, 1.0)
    _write(out / "j_posselt.csv", "frame,sx,sy,sz\n" + "\n".join(
        f"{k}," + ",".join(f"{v:.6f}" for v in q) for k, q in enumerate((rest, moved))) + "\n")

    # a capture of the markers: rest, then the face markers moved 0.3 mm forward
    P0 = model.marker_positions()
    P1 = P0 + np.where(model.markers.head[:, None], 0.0, [0.0, 0.0, 0.3])
    P = np.stack([P0, P1])
    frames = np.arange(2)
    write_markers_csv(out / "markers.csv", frames, model.markers.names, P)
    write_trc(out / "markers.trc", frames, model.markers.names, P, fps=30.0)
    write_c3d(out / "markers.c3d", frames, model.markers.names, P, fps=30.0)
    np.savez(out / "capture.npz", frames=frames, names=np.array(model.markers.names), P=P)

    # poses and rigs
    for argv in (["jaw", "generate", "--extremes", "-o", str(out / "ext.npz")],
                 ["jaw", "generate", "--kinds", "border", "-o", str(out / "ses.npz")],
                 ["jaw", "fit", "--rig", "3dof", "--poses", str(out / "ext.npz"), "-o", str(out / "r3.npz")],
                 ["jaw", "fit", "--rig", "posselt", "--poses", str(out / "ses.npz"), "-o", str(out / "rp.npz")],
                 ["jaw", "fit", "--rig", "nlpca", "--poses", str(out / "ses.npz"), "-o", str(out / "rn.npz"),
                  "--iterations", "5"]):
        assert main(argv) == 0, argv
    # a finished simulate run (the input of export-cache)
    assert main(["simulate", "--model", str(out / "box.npz"), "--activations", str(out / "a.csv"), "-o",
                 str(out / "run"), "--solver", "direct", "-q"]) == 0
    missing = [f for f in FILES if not (out / f).is_file()]
    assert not missing, missing
    return out


if __name__ == "__main__":
    write_bases(sys.argv[1])
