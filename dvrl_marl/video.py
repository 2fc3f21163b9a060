"""Writing rendered frames to a video file (MP4 through imageio-ffmpeg, GIF otherwise)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_video"]


def write_video(path, frames, fps: int = 50) -> Path:
    """Write RGB frames (each (H, W, 3) uint8) to ``path``; the suffix picks the format (.mp4 or .gif)."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = [np.asarray(frame, dtype=np.uint8) for frame in frames]
    if not frames:
        raise ValueError("no frames to write")
    if path.suffix.lower() == ".gif":
        imageio.mimsave(path, frames, duration=1.0 / fps)
        return path
    # libx264 wants even dimensions; macro_block_size=1 keeps the frame size as rendered.
    with imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=1) as writer:
        for frame in frames:
            writer.append_data(frame)
    return path
