"""``cylindersplat data synth`` output: ``ROOT/meta.json``, ``ROOT/<scene>/NN/{rgb.png,depth.png}``, poses.json.
One folder, no splits (``scenes=[...]`` selects); its own input prior is the simulated one."""

from __future__ import annotations

from pathlib import Path

from ...dataset_layouts import IS_ONE, DatasetSpec


def _detect(path: Path) -> int:
    return IS_ONE if (path / "meta.json").is_file() else 0


def _open(root, *, views="two_view", split=None, **options):
    from ..synthetic import SyntheticDataset

    return SyntheticDataset(root, views=views, **options)  # one folder, no splits (scenes=[...] selects)


def _frames(root, split: str = "all"):
    from ..depth_prior.base import NoPrior
    from ..synthetic import SyntheticDataset

    return SyntheticDataset(root, depth_prior=NoPrior())


def _inspect(root, *, views, resolution=None):
    from ..depth_prior.base import NoPrior
    from ..synthetic import SyntheticDataset

    return SyntheticDataset(root, views=views, resolution=resolution, depth_prior=NoPrior())


SPEC = DatasetSpec("synthetic", "a synthetic dataset (meta.json)", _detect, _open, _frames, _inspect,
                   views="two_view",
                   info_views="two_view", preview_views="n_view", options=("scenes",), depth_range=(0.05, 1000.0))
