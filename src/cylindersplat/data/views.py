"""Which frames of a sequence are context (input) and which are target (rendered) views.

Protocols (paper Sec. 4 and its peers), for a sequence of ``n`` frames on a line:

* ``"two_view"``: first and last frame in, the middle frame ``(n-1)//2`` out (PanoGRF/PanSplat
  test: frames 00, 02 -> 01; Residential: 0, 8 -> 4);
* ``"one_view"``: the middle frame in, the first and last frames out;
* ``"n_view"``: every frame but the middle one in, the middle one out;
* ``"all_between"``: two contexts ``gap`` frames apart starting at ``start``, every frame between
  them *including the contexts* out (PanSplat's 360Loc test protocol, ``gap = 3``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ViewSplit", "PROTOCOLS", "select_views", "all_between", "all_between_starts"]

PROTOCOLS = ("two_view", "one_view", "n_view")


@dataclass(frozen=True)
class ViewSplit:
    context: tuple[int, ...]
    target: tuple[int, ...]


def select_views(num_frames: int, protocol: str | ViewSplit = "two_view") -> ViewSplit:
    """Context/target frame indices of a ``num_frames`` sequence under ``protocol``."""
    if isinstance(protocol, ViewSplit):
        bad = [i for i in protocol.context + protocol.target if not 0 <= i < num_frames]
        if bad:
            raise ValueError(f"view indices {bad} out of range for a sequence of {num_frames} frames")
        return protocol
    if num_frames < 2:
        raise ValueError(f"protocol {protocol!r} needs at least 2 frames, the sequence has {num_frames}")
    mid = (num_frames - 1) // 2
    if protocol == "two_view":
        if num_frames < 3:
            raise ValueError("two_view needs >= 3 frames (first/last in, middle out)")
        return ViewSplit((0, num_frames - 1), (mid,))
    if protocol == "one_view":
        return ViewSplit((mid,), tuple(sorted({0, num_frames - 1} - {mid})))
    if protocol == "n_view":
        if num_frames < 3:
            raise ValueError("n_view needs >= 3 frames")
        return ViewSplit(tuple(i for i in range(num_frames) if i != mid), (mid,))
    raise ValueError(f"unknown view protocol {protocol!r}; choose from {PROTOCOLS} or pass a ViewSplit")


def all_between_starts(num_frames: int, gap: int, times: int) -> list[int]:
    """Left-context indices of PanSplat's 360Loc test sampler: ``times`` evenly spaced starts."""
    if num_frames <= gap:
        return []
    return [int((num_frames - gap - 1) * i / max(times - 1, 1)) for i in range(times)]


def all_between(start: int, gap: int) -> ViewSplit:
    """Contexts ``start`` and ``start + gap``; targets every frame from ``start`` to ``start + gap``."""
    return ViewSplit((start, start + gap), tuple(range(start, start + gap + 1)))
