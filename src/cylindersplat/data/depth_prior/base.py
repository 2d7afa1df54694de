"""Depth-prior interface: what a loader asks for each context view."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["PriorQuery", "DepthPrior", "NoPrior", "GroundTruthPrior", "ConstantPrior"]


@dataclass
class PriorQuery:
    """Everything a prior may use for one view.

    ``image`` ``(3, H, W)`` at the loader's output resolution; ``gt_depth`` ``(H, W)`` or ``None``;
    ``rgb_path`` the stored panorama (file priors look next to it); ``key`` a stable id
    ``"{dataset}/{scene}/{frame}"`` (seeds the simulated prior).
    """

    image: Float[Tensor, "3 H W"]
    gt_depth: Float[Tensor, "H W"] | None
    rgb_path: Path | None
    key: str

    @property
    def size(self) -> tuple[int, int]:
        return tuple(self.image.shape[-2:])


class DepthPrior:
    """A source of per-view radial depth priors ``(H, W)`` in metres (0 = unknown)."""

    name = "base"

    def __call__(self, query: PriorQuery) -> Float[Tensor, "H W"]:
        raise NotImplementedError


class NoPrior(DepthPrior):
    """All-zero prior (no depth information)."""

    name = "none"

    def __call__(self, query: PriorQuery) -> Tensor:
        return torch.zeros(query.size)


class GroundTruthPrior(DepthPrior):
    """Oracle prior: the ground-truth depth itself (for ablations / upper bounds)."""

    name = "gt"

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.gt_depth is None:
            raise ValueError(f"{query.key}: the 'gt' depth prior needs ground-truth depth, which this view lacks")
        return query.gt_depth.clone()


class ConstantPrior(DepthPrior):
    """Every pixel at ``depth`` metres (a sphere around the camera): a last resort for inputs with no depth."""

    name = "constant"

    def __init__(self, depth: float = 2.0) -> None:
        if not (depth > 0 and depth < float("inf")):
            raise ValueError(f"constant depth prior needs a positive finite depth, got {depth}")
        self.depth = float(depth)

    def __call__(self, query: PriorQuery) -> Tensor:
        return torch.full(query.size, self.depth)
