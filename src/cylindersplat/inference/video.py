"""Writing fly-through videos: GIF with Pillow (always there), MP4 when an imageio backend exists."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..utils.atomic import atomic_path

__all__ = ["write_video", "check_video_format"]

VIDEO_SUFFIXES = (".gif", ".mp4", ".webm", ".mkv")


def check_video_format(path: str | Path) -> None:
    """Raise ``ValueError`` (before any rendering) when ``path``'s format cannot be written here."""
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: video must be .gif, .mp4, .webm or .mkv")
    if suffix == ".gif":
        return
    try:
        import imageio_ffmpeg  # noqa: F401  (the backend imageio uses for mp4/webm/mkv)
    except ImportError:
        raise ValueError(f"cannot write {suffix} videos: no ffmpeg backend; install it with "
                         "`pip install imageio[ffmpeg]` (or `pip install cylindersplat[video]`), or write a .gif") from None


def write_video(path: str | Path, frames: list[np.ndarray], fps: int = 12) -> Path:
    """Save uint8 ``(H, W, 3)`` frames as ``.gif`` or ``.mp4``/``.webm`` (needs ``pip install imageio[ffmpeg]``)."""
    path = Path(path)
    if not frames:
        raise ValueError("no frames to write")
    check_video_format(path)
    suffix = path.suffix.lower()
    with atomic_path(path) as tmp:  # a failed write leaves no truncated video (and an earlier one intact)
        if suffix == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0,
                           optimize=False)
            return path
        import imageio.v3 as iio

        try:
            iio.imwrite(tmp, np.stack(frames), fps=fps, codec="libx264" if suffix == ".mp4" else None)
        except Exception as exc:  # noqa: BLE001 - which backend fails varies; say what to do
            raise ValueError(f"cannot write {path} ({type(exc).__name__}: {exc}); install a video backend with "
                             "`pip install imageio[ffmpeg]` or write a .gif") from exc
    return path
