"""A 360Loc root: ``ROOT/<location>/{mapping,query_360}/<sequence>/`` (:mod:`cylindersplat.data.loc360`). Its own
protocol (``all_between``: contexts ``gap`` frames apart, every frame between them a target); no ground-truth
depth, so an input prior must be chosen."""

from __future__ import annotations

from pathlib import Path

from ...dataset_layouts import HOLDS_SOME, DatasetSpec


def _detect(path: Path) -> int:
    holds = any((d / "mapping").is_dir() or (d / "query_360").is_dir() for d in path.iterdir() if d.is_dir())
    return HOLDS_SOME if holds else 0


def _open(root, *, views="all_between", split="test", **options):
    from ..loc360 import Loc360Dataset

    # options: gap (frames between neighbouring contexts, default 3 = 1.4 m), context_views (2, 3, 4, ...),
    # context_layout ("spaced" / "released"), times_per_sequence; see cylindersplat.data.views.all_between
    if views != "all_between":
        raise ValueError(f"360Loc has its own protocol: use views all_between (data.views / eval --protocols), "
                         f"not {views!r}")
    dataset = Loc360Dataset(root, split=split, **options)
    dataset.require_examples()
    return dataset


def _all_locations(root, split: str, **options):
    from ..loc360 import LOC360_SPLITS, Loc360Dataset

    if split == "all":
        return Loc360Dataset(root, locations=tuple(x for s in LOC360_SPLITS.values() for x in s), **options)
    return Loc360Dataset(root, split=split, **options)


def _frames(root, split: str = "all"):
    return _all_locations(root, split)


def _inspect(root, *, views, resolution=None):
    from ..depth_prior.base import NoPrior

    if views != "all_between":
        raise ValueError(f"{root}: 360Loc has its own protocol: use views all_between, not {views!r}")
    return _all_locations(root, "all", resolution=resolution, depth_prior=NoPrior())  # every location


SPEC = DatasetSpec("loc360", "a 360Loc root (<location>/mapping or query_360)", _detect, _open, _frames, _inspect,
                   views="all_between",
                   info_views="all_between", preview_views="all_between",
                   options=("locations", "gap", "context_views", "context_layout", "times_per_sequence"),
                   depth_range=(0.05, 1000.0))
