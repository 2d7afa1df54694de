"""Datasets from :class:`DataConfig` and a batch order that can be resumed mid-epoch.

The batch order is a pure function of ``(seed, stage, epoch)``, so resuming at step ``k`` of a
stage replays exactly the batches an uninterrupted run would have seen from step ``k`` on, with no
sampler state in the checkpoint. Under DDP each rank takes every ``world_size``-th index of the
same permutation (the tail that does not fill a global batch is dropped).
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from ..data import collate_samples
from ..data.augment import CaptureAugmentedDataset
from ..data.datasets import make_dataset
from .config import DataConfig
from .losses import LossConfig

__all__ = ["build_dataset", "ResumableBatchSampler", "build_loader"]


def build_dataset(cfg: DataConfig, loss: LossConfig | None = None) -> Dataset:
    """The dataset of ``data.*`` (layouts: :data:`cylindersplat.data.DATASETS`), delivering the depth loss's
    reference (``loss.depth_reference``) when ``loss`` is given and its depth term is on, its context views changed as
    a capture's (:mod:`cylindersplat.data.augment`) when ``data.augment=captures``. Missing priors,
    prior files or reference depths fail here, before any step."""
    if not cfg.root:
        raise ValueError("data.root is not set: give a dataset folder (e.g. from `cylindersplat data synth`)")
    reference = loss.depth_reference if loss is not None and loss.depth_l1 > 0 else "none"
    dataset = make_dataset(cfg.format, cfg.root, views=cfg.views, split=cfg.split, resolution=cfg.resolution,
                           depth_prior=cfg.depth_prior, reference=reference, check_plausibility=cfg.check_plausibility,
                           **cfg.options)
    if cfg.augment == "captures":  # training samples only: evaluation opens its datasets with make_dataset
        return CaptureAugmentedDataset(dataset, cfg.captures)
    return dataset


class ResumableBatchSampler(Sampler[list[int]]):
    """Index batches for steps ``start_step .. start_step + num_steps - 1`` of one curriculum stage."""

    def __init__(
        self,
        dataset_size: int,
        batch_size: int,
        *,
        seed: int,
        stage: int,
        start_step: int,
        num_steps: int,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        self.global_batch = batch_size * world_size
        if dataset_size < self.global_batch:
            raise ValueError(f"dataset has {dataset_size} samples, fewer than one global batch ({self.global_batch})")
        self.dataset_size, self.batch_size = dataset_size, batch_size
        self.seed, self.stage = seed, stage
        self.start_step, self.num_steps = start_step, num_steps
        self.rank, self.world_size = rank, world_size

    @property
    def batches_per_epoch(self) -> int:
        return self.dataset_size // self.global_batch

    def _permutation(self, epoch: int) -> torch.Tensor:
        generator = torch.Generator().manual_seed(self.seed * 1_000_003 + self.stage * 10_007 + epoch)
        return torch.randperm(self.dataset_size, generator=generator)

    def __len__(self) -> int:
        return self.num_steps

    def __iter__(self) -> Iterator[list[int]]:
        per_epoch = self.batches_per_epoch
        for step in range(self.start_step, self.start_step + self.num_steps):
            epoch, slot = divmod(step, per_epoch)
            order = self._permutation(epoch)
            chunk = order[slot * self.global_batch : (slot + 1) * self.global_batch]
            yield chunk[self.rank :: self.world_size].tolist()


def build_loader(dataset: Dataset, sampler: ResumableBatchSampler, num_workers: int = 0) -> DataLoader:
    return DataLoader(dataset, batch_sampler=sampler, collate_fn=collate_samples, num_workers=num_workers)
