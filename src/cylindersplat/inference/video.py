"""Writing fly-through videos: GIF with Pillow (always there), MP4 when an imageio backend exists."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_video"]


def write_video(path: str | Path, frames: list[np.ndarray], fps: int = 12) -> Path:
    """Save uint8 ``(H, W, 3)`` frames as ``.gif`` or ``.mp4``/``.webm`` (needs ``pip install imageio[ffmpeg]``)."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0, optimize=False)
        return path
    if suffix not in (".mp4", ".webm", ".mkv"):
        raise ValueError(f"{path}: video must be .gif, .mp4, .webm or .mkv")
    import imageio.v3 as iio

    try:
        iio.imwrite(path, np.stack(frames), fps=fps, codec="libx264" if suffix == ".mp4" else None)
    except Exception as exc:  # noqa: BLE001 - which backend is missing varies; say what to do
        raise RuntimeError(
            f"cannot write {path} ({exc}); install a video backend with `pip install imageio[ffmpeg]` or use a .gif"
        ) from exc
    return path
