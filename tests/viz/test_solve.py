"""The side-by-side render of a solve (facesim.viz.solve), through solve-mocap --render."""

import numpy as np

from facesim.cli import main


def test_solve_mocap_render_writes_a_side_by_side_video(box_model, box_model_path, tmp_path, capsys):
    from PIL import Image

    from facesim.controls import Controls
    from facesim.fem.equilibrium import EquilibriumOptions, FaceSimulator
    from facesim.fem.newton import NewtonOptions
    from facesim.kinematics.condyle import SlidingCondyleJaw
    from facesim.mocap.io import write_trc

    sim = FaceSimulator(box_model, EquilibriumOptions(newton=NewtonOptions(linear_solver="direct")),
                        jaw_model=SlidingCondyleJaw(box_model.jaw))
    P = np.array([box_model.marker_positions(sim.equilibrium(Controls([0.3 * k, 0.2 * k], jaw=[0.04 * k, 0, 0])).x)
                  for k in range(2)])
    write_trc(tmp_path / "m.trc", np.arange(2), box_model.markers.names, P, fps=10.0)
    out = tmp_path / "out"
    assert main(["solve-mocap", "--model", str(box_model_path), "--markers", str(tmp_path / "m.trc"), "-o", str(out),
                 "--head", "none", "--noise", "0.01", "--solver", "direct", "--render", "-q"]) == 0
    assert "video: " in capsys.readouterr().out
    videos = [p for p in (out / "render").iterdir() if p.name in ("video.mp4", "video.gif")]
    assert len(videos) == 1 and videos[0].stat().st_size > 1000
    frame = np.asarray(Image.open(out / "render" / "frame_00001.png").convert("RGB"))
    assert frame.shape == (640, 1280, 3)
    left, right = frame[:, :640], frame[:, 640:]
    assert left.std() > 5 and right.std() > 5 and np.abs(left.astype(int) - right).mean() > 1
