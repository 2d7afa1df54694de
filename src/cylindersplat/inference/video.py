"""Writing fly-through videos frame by frame: GIF with Pillow (always there), MP4/WebM/MKV through ffmpeg.

:class:`VideoWriter` sends every appended frame straight to the file (a GIF is encoded frame by
frame, an MP4 is piped to an ``ffmpeg`` process from ``imageio-ffmpeg``), so a fly-through of any
length holds one frame in memory, not all of them. The video is written under a temporary name in
the same folder and renamed when complete: an interrupted or failed write leaves no half-written
file (and an earlier video at the path intact).
"""

from __future__ import annotations

import contextlib
import math
import struct
import sys
from pathlib import Path
from typing import Iterable

import numpy as np

from ..utils.atomic import atomic_path

__all__ = ["VideoWriter", "write_video", "check_video_format", "ffmpeg_available", "video_path_with_fallback"]

VIDEO_SUFFIXES = (".gif", ".mp4", ".webm", ".mkv")
FFMPEG_HINT = "`pip install imageio-ffmpeg` (the `video` extra: `pip install cylindersplat[video]`)"


def ffmpeg_available() -> bool:
    """Whether ``imageio-ffmpeg`` and its ffmpeg binary are there (needed for .mp4/.webm/.mkv)."""
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError, OSError):
        return False
    return True


def check_video_format(path: str | Path) -> None:
    """Raise ``ValueError`` (before any rendering) when ``path``'s format cannot be written here."""
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_SUFFIXES:
        raise ValueError(f"{path}: video must be .gif, .mp4, .webm or .mkv")
    if suffix != ".gif" and not ffmpeg_available():
        raise ValueError(f"cannot write {suffix} videos: no ffmpeg backend; install it with {FFMPEG_HINT}, or write a "
                         ".gif")


def video_path_with_fallback(path: str | Path) -> tuple[Path, str | None]:
    """``(path, None)`` when its format can be written here, else ``(path with .gif, one-line reason)``.

    Unknown suffixes are still an error (:func:`check_video_format`).
    """
    path = Path(path)
    try:
        check_video_format(path)
    except ValueError:
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise
        gif = path.with_suffix(".gif")
        return gif, f"no ffmpeg for {path.suffix} videos, writing {gif.name} instead; for {path.suffix}: {FFMPEG_HINT}"
    return path, None


# Pixels the palette of a GIF frame is chosen from (a frame with more is sampled on a regular grid).
PALETTE_SAMPLE = 1 << 16


def _indexed(image):
    """``image`` (RGB) with a 256-colour palette of its own: the median cut of Pillow's GIF saver, chosen from at
    most :data:`PALETTE_SAMPLE` pixels (every k-th of every k-th row) and applied to every pixel. The whole frame's
    median cut was most of a fly-through's time: a 1024x1024 frame (two photos) takes 41 ms instead of 193, a
    512x1024 photo 43 instead of 110-140 (a smooth gradient, whose many colours make the mapping slow, 70-110 instead
    of 113-350), within 0.2-1.2 dB of the whole frame's palette; Pillow's fast octree takes 3-4 ms but loses 2-5 dB
    on smooth gradients (banding). benchmarks/RESULTS.md, "GIF frames"."""
    from PIL import Image

    step = max(1, math.ceil((image.width * image.height / PALETTE_SAMPLE) ** 0.5))
    if step == 1:
        return image.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    sample = image.resize((image.width // step, image.height // step), Image.Resampling.NEAREST)
    return image.quantize(palette=sample.quantize(colors=256, method=Image.Quantize.MEDIANCUT),
                          dither=Image.Dither.NONE)


class _GifStream:
    """An animated GIF written one frame at a time (each frame with its own 256-colour palette)."""

    def __init__(self, path: Path, fps: float) -> None:
        self._file = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._duration = max(1, round(1000 / fps))  # GIF delays are in 1/100 s; Pillow rounds
        self._size: tuple[int, int] | None = None

    def append(self, frame: np.ndarray) -> None:
        from PIL import GifImagePlugin, Image

        h, w = frame.shape[:2]
        if self._size is None:
            self._size = (h, w)
            # Header, logical screen (no global colour table: every frame brings its own), loop forever.
            self._file.write(b"GIF89a" + struct.pack("<HHBBB", w, h, 0, 0, 0))
            self._file.write(b"!\xff\x0bNETSCAPE2.0\x03\x01" + struct.pack("<H", 0) + b"\x00")
        image = _indexed(Image.fromarray(frame))
        for chunk in GifImagePlugin.getdata(image, (0, 0), duration=self._duration, include_color_table=True):
            self._file.write(chunk)

    def close(self) -> None:
        if self._size is not None:
            self._file.write(b";")  # trailer
        self._file.close()

    def abort(self) -> None:
        self._file.close()


class _FfmpegStream:
    """Frames piped to an ffmpeg process (imageio-ffmpeg): H.264 for .mp4/.mkv, VP9 for .webm."""

    def __init__(self, path: Path, fps: float) -> None:
        self._path, self._fps = path, fps
        self._writer = None
        self._size: tuple[int, int] | None = None

    def append(self, frame: np.ndarray) -> None:
        import imageio_ffmpeg

        if frame.shape[0] % 2 or frame.shape[1] % 2:  # yuv420p needs even sizes: repeat the last row/column
            frame = np.pad(frame, ((0, frame.shape[0] % 2), (0, frame.shape[1] % 2), (0, 0)), mode="edge")
        if self._writer is None:
            self._size = frame.shape[:2]
            codec = "libvpx-vp9" if self._path.suffix.lower() == ".webm" else "libx264"
            self._writer = imageio_ffmpeg.write_frames(str(self._path), (frame.shape[1], frame.shape[0]), fps=self._fps,
                                                       codec=codec, macro_block_size=1, quality=8,
                                                       ffmpeg_log_level="error")
            self._writer.send(None)  # start ffmpeg
        try:
            self._writer.send(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
        except (BrokenPipeError, RuntimeError) as exc:  # ffmpeg stopped (codec missing, bad size, ...)
            raise ValueError(f"ffmpeg could not write {self._path.suffix} video ({type(exc).__name__}: {exc}); "
                             "write a .gif instead") from exc
        except OSError as exc:
            if exc.errno is not None:  # disk full, permissions: reported as such by the CLI
                raise
            raise ValueError(f"ffmpeg could not write {self._path.suffix} video ({exc}); write a .gif instead") from exc

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()  # waits for ffmpeg to finish the file

    def abort(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


class VideoWriter:
    """``with VideoWriter("fly.gif", fps=12) as video: video.append(frame)`` for uint8 ``(H, W, 3)`` frames.

    Frames go to the file as they come (memory holds one frame); the file appears under ``path``
    only when the block ends without an error. ``.gif`` always works; ``.mp4``/``.webm``/``.mkv``
    need ``imageio-ffmpeg`` (:func:`video_path_with_fallback` picks a GIF when it is missing).
    """

    def __init__(self, path: str | Path, fps: float = 12) -> None:
        self.path = Path(path)
        check_video_format(self.path)
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.fps = fps
        self.frames = 0
        self._stack: contextlib.ExitStack | None = None
        self._stream = None
        self._size: tuple[int, ...] | None = None

    def __enter__(self) -> "VideoWriter":
        self._stack = contextlib.ExitStack()
        tmp = self._stack.enter_context(atomic_path(self.path))
        try:
            self._stream = (_GifStream if self.path.suffix.lower() == ".gif" else _FfmpegStream)(tmp, self.fps)
        except BaseException:
            self._stack.__exit__(*sys.exc_info())
            raise
        return self

    def append(self, frame: np.ndarray) -> None:
        if self._stream is None:
            raise RuntimeError("use VideoWriter in a `with` block")
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"video frames must be uint8 (H, W, 3), got {frame.dtype} {frame.shape}")
        if self._size is None:
            self._size = frame.shape
        elif frame.shape != self._size:
            raise ValueError(f"every video frame must have the same size; frame {self.frames} is {frame.shape[:2]}, "
                             f"the first was {self._size[:2]}")
        self._stream.append(frame)
        self.frames += 1

    def __exit__(self, exc_type, exc, tb) -> bool:
        stream, stack = self._stream, self._stack
        self._stream = self._stack = None
        if exc_type is None and self.frames == 0:
            exc_type, exc = ValueError, ValueError(f"no frames to write to {self.path}")
            stream.abort()
            stack.__exit__(exc_type, exc, None)
            raise exc
        if exc_type is None:
            try:
                stream.close()
            except BaseException as error:  # noqa: BLE001 - ffmpeg failed: drop the temporary file, report
                stack.__exit__(type(error), error, error.__traceback__)
                if isinstance(error, (RuntimeError, BrokenPipeError)):  # ffmpeg gave up
                    raise ValueError(f"cannot write {self.path} ({type(error).__name__}: {error})") from error
                raise
            stack.close()  # rename the finished file into place
            return False
        stream.abort()
        stack.__exit__(exc_type, exc, tb)  # removes the temporary file
        return False


def write_video(path: str | Path, frames: Iterable[np.ndarray], fps: int = 12) -> Path:
    """Save uint8 ``(H, W, 3)`` frames (a list or any iterable, consumed one at a time) as ``.gif`` or
    ``.mp4``/``.webm``/``.mkv`` (needs ``imageio-ffmpeg``)."""
    with VideoWriter(path, fps) as video:
        for frame in frames:
            video.append(frame)
    return video.path
