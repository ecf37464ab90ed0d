"""Pictures and videos: ``render`` (off-screen pictures of a model), ``solve`` (side-by-side video of
a solved capture), ``plots`` (matplotlib plots of a track), ``video`` (MP4 or GIF of rendered frames)."""
