"""PanoGRF's renders (Matterport3D, Replica, Residential): a ``png_render_{split}_{W}x{H}_seq_len_3_{name}_dist_{d}``
folder of 3-frame sequences with ground-truth depth (:mod:`cylindersplat.data.pano_grf`). Evaluated, as PanoGRF
does, over reference depths of 0.45-10 m."""

from __future__ import annotations

from pathlib import Path

from ...dataset_layouts import IS_ONE, DatasetSpec


def _detect(path: Path) -> int:
    return IS_ONE if path.name.startswith("png_render_") else 0


def _open(root, *, views="two_view", split="test", **options):
    from ..pano_grf import PanoGRFDataset

    return PanoGRFDataset(root, split=split, views=views, **options)


def _frames(root, split: str = "all"):
    from ..depth_prior.base import NoPrior
    from ..pano_grf import PanoGRFDataset

    return PanoGRFDataset(root, depth_prior=NoPrior())


def _inspect(root, *, views, resolution=None):
    from ..depth_prior.base import NoPrior
    from ..pano_grf import PanoGRFDataset

    return PanoGRFDataset(root, views=views, resolution=resolution, depth_prior=NoPrior())  # pictures need no prior


SPEC = DatasetSpec("pano_grf", "a png_render_* PanoGRF folder", _detect, _open, _frames, _inspect,
                   views="two_view",
                   info_views="two_view", preview_views="n_view",
                   options=("stored_size", "name", "dist", "depth_resize"), depth_range=(0.45, 10.0))
