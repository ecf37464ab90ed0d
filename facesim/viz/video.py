"""Videos of rendered frames: MP4 through imageio-ffmpeg when installed, else an animated GIF."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facesim._files import atomic_write
from facesim.errors import FacesimError


def write_video(pngs, out_dir, fps: float) -> tuple[Path, str]:
    """Movie of the PNG files ``pngs`` at ``fps``: ``OUT/video.mp4`` if imageio and imageio-ffmpeg
    are installed, else an animated GIF ``OUT/video.gif`` through PIL. Returns the path and a
    one-line note ("" for MP4)."""
    from PIL import Image

    pngs = list(pngs)
    if not pngs:
        raise FacesimError(f"{out_dir}: no rendered frames to make a video of")
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (imageio's MP4 backend)
    except ImportError:
        imageio = None
    out_dir = Path(out_dir)
    if imageio is not None:
        def write_mp4(tmp):
            with imageio.get_writer(tmp, fps=fps, codec="libx264", quality=8) as writer:
                for p in pngs:
                    writer.append_data(np.asarray(Image.open(p).convert("RGB")))
        return atomic_write(out_dir / "video.mp4", write_mp4), ""

    def write_gif(tmp):
        images = [Image.open(p).convert("RGB") for p in pngs]
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], loop=0,
                       duration=max(20, round(1000.0 / fps)))
    path = atomic_write(out_dir / "video.gif", write_gif)
    return path, (f"imageio-ffmpeg is not installed: wrote an animated GIF {path} instead of MP4 "
                  "(pip install imageio imageio-ffmpeg for MP4)")


__all__ = ["write_video"]
