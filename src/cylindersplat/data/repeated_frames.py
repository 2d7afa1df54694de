"""Frames that repeat an earlier one of the same list: the same image, pose and depth (issue 37).

A poses file that lists one panorama several times (a copy-paste, a tool writing keyframes twice) gives the model
nothing new: each repeat is one more view for every stage to run on, the same pixels at the same place. Files are
the same when they are one file or their bytes are equal; only frames whose poses are equal are read to compare.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Sequence

from .base import FrameRef

__all__ = ["repeated_frames"]


def _file_key(path: Path | None, digests: dict[Path, tuple[int, str]]) -> tuple[int, str] | None:
    """(size, sha256) of a file's bytes (cached by resolved path); None for no file."""
    if path is None:
        return None
    resolved = Path(path).resolve()
    if resolved not in digests:
        try:
            digests[resolved] = (resolved.stat().st_size, hashlib.sha256(resolved.read_bytes()).hexdigest())
        except OSError:  # unreadable: never equal to another file; loading it says what is wrong
            digests[resolved] = (-1, str(resolved))
    return digests[resolved]


def repeated_frames(frames: Sequence[FrameRef]) -> list[int]:
    """Indices of the frames equal to an earlier frame of ``frames`` (same image file content, same ``c2w``, same
    depth file content and ``depth_scale``), in order; the first of each group is not among them."""
    by_pose: dict[tuple, list[int]] = {}
    for i, frame in enumerate(frames):
        by_pose.setdefault((frame.c2w.detach().cpu().numpy().tobytes(), frame.depth_scale), []).append(i)
    digests: dict[Path, tuple[int, str]] = {}
    repeats = []
    for group in by_pose.values():
        seen = set()
        for i in group:
            if len(group) == 1:
                break
            key = (_file_key(frames[i].rgb, digests), _file_key(frames[i].depth, digests))
            if key in seen:
                repeats.append(i)
            seen.add(key)
    return sorted(repeats)
