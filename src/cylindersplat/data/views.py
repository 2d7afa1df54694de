"""Which frames of a sequence are context (input) and which are target (rendered) views.

Protocols (paper Sec. 4 and its peers), for a sequence of ``n`` frames on a line:

* ``"two_view"``: first and last frame in, the middle frame ``(n-1)//2`` out (PanoGRF/PanSplat
  test: frames 00, 02 -> 01; Residential: 0, 8 -> 4);
* ``"one_view"``: the middle frame in, the first and last frames out;
* ``"n_view"``: every frame but the middle one in, the middle one out;
* ``"released"``: the authors' released scoring (``data/mp3d_dataloader_double_256.py`` of
  wangqww/CylinderSplat: ``context_indices = [0, 2]``, ``target_indices = [0, 1, 2]``): first and last
  frame in, and the first, middle and last frame out -- the two inputs are scored as well as the novel
  view, which lifts every number; the paper's Table 1 matches this at 256x512 (``cylindersplat eval
  --protocols released`` defaults to that size);
* ``"all_between"``: two contexts ``gap`` frames apart starting at ``start``, every frame between
  them *including the contexts* out (PanSplat's 360Loc test protocol, ``gap = 3``). With more
  context views (the paper's Table 5: 3 and 4 views on 360Loc) see :func:`all_between`'s layouts.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ViewSplit", "PROTOCOLS", "ALL_BETWEEN_LAYOUTS", "select_views", "all_between", "all_between_span",
           "all_between_starts"]

PROTOCOLS = ("two_view", "one_view", "n_view", "released")


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
    if protocol == "released":
        if num_frames < 3:
            raise ValueError("released needs >= 3 frames (first/last in; first, middle and last out)")
        return ViewSplit((0, num_frames - 1), (0, mid, num_frames - 1))
    if protocol == "n_view":
        if num_frames < 3:
            raise ValueError("n_view needs >= 3 frames")
        return ViewSplit(tuple(i for i in range(num_frames) if i != mid), (mid,))
    raise ValueError(f"unknown view protocol {protocol!r}; choose from {PROTOCOLS} or pass a ViewSplit")


ALL_BETWEEN_LAYOUTS = ("spaced", "released")


def all_between_starts(num_frames: int, gap: int, times: int) -> list[int]:
    """Left-context indices of PanSplat's 360Loc test sampler: ``times`` evenly spaced starts.

    ``gap`` is the span between the outermost contexts (:func:`all_between_span`); a sequence of
    ``num_frames <= gap`` frames gives none.
    """
    if num_frames <= gap:
        return []
    return [int((num_frames - gap - 1) * i / max(times - 1, 1)) for i in range(times)]


def _check_all_between(gap: int, views: int, layout: str) -> None:
    if layout not in ALL_BETWEEN_LAYOUTS:
        raise ValueError(f"unknown all_between layout {layout!r}; choose from {', '.join(ALL_BETWEEN_LAYOUTS)}")
    if isinstance(gap, bool) or not isinstance(gap, int) or gap < 1:
        raise ValueError(f"the gap between context frames must be an integer >= 1, got {gap!r}")
    if isinstance(views, bool) or not isinstance(views, int) or views < 2:
        raise ValueError(f"all_between needs an integer number of context views >= 2, got {views!r}")
    if layout == "released" and views > 4:
        raise ValueError(f"the released layout exists for 2, 3 and 4 context views only, not {views}; use layout "
                         "spaced")


def all_between_span(gap: int, views: int = 2, layout: str = "spaced") -> int:
    """Frames from the first to the last context of :func:`all_between` (what a sequence must exceed)."""
    _check_all_between(gap, views, layout)
    if layout == "spaced":
        return (views - 1) * gap
    return gap + {2: 0, 3: 1, 4: 2}[views]


def all_between(start: int, gap: int, views: int = 2, layout: str = "spaced") -> ViewSplit:
    """360Loc's context/target frames for ``views`` contexts, the first at ``start``.

    ``views=2`` (both layouts): contexts ``start`` and ``start + gap``, every frame from one to the
    other a target, the contexts included (PanSplat's protocol and the paper's two-view 360Loc rows;
    ``gap=3`` is the 1.4 m baseline). More views, as ``layout``:

    * ``"spaced"`` (default): contexts every ``gap`` frames, ``start + k * gap`` for ``k < views``,
      every frame from the first to the last context a target, contexts included -- the two-view rule
      repeated, so every pair of neighbouring contexts keeps the two-view baseline (the generic
      ``sample(gap, step)`` of the released CylinderSplat 360Loc loaders,
      ``data/loc360_dataloader_double_all.py`` and ``_double_random.py``, ``step`` = our ``gap``);
    * ``"released"``: exactly ``three_sample`` / ``four_sample`` of the released
      ``data/loc360_dataloader_double_all.py`` (repository wangqww/CylinderSplat) when ``gap=3``: the
      two-view pair ``gap`` apart plus contexts on the adjacent frames -- 3 views ``(s, s+gap, s+gap+1)``,
      4 views ``(s, s+1, s+gap+1, s+gap+2)`` -- and as targets every frame strictly between the
      outermost contexts (3 views: ``s+1 .. s+gap``; 4 views: ``s+1 .. s+gap+1``).

    The paper (Table 5) names only the view counts; it does not say which layout its rows used.
    """
    span = all_between_span(gap, views, layout)
    if views == 2 or layout == "spaced":
        return ViewSplit(tuple(start + k * gap for k in range(views)), tuple(range(start, start + span + 1)))
    if views == 3:
        context = (start, start + gap, start + gap + 1)
    else:
        context = (start, start + 1, start + gap + 1, start + gap + 2)
    return ViewSplit(context, tuple(range(start + 1, start + span)))
