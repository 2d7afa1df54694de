"""Methods under evaluation: a callable ``Sample -> RenderOutput`` of the sample's target views.

Every method sees the same inputs (context images, depth priors, poses) and returns the target
renders as :class:`~cylindersplat.render.RenderOutput` with rgb ``(T, 3, H, W)``, depth and alpha
``(T, H, W)`` (depth alpha-weighted, as the renderer gives it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from ..baselines import forward_warp
from ..data import Sample
from ..inference.pipeline import reconstruct_gaussians, render_views
from ..render.api import RenderOutput

__all__ = ["Method", "model_method", "forward_warp_method", "reconstruct"]


@dataclass
class Method:
    name: str
    run: Callable[[Sample], RenderOutput]


def reconstruct(model, sample: Sample, device: torch.device | str = "cpu"):
    """Gaussians (world frame, unbatched) of a sample's context views."""
    return reconstruct_gaussians(model, sample.context_images, sample.context_priors, sample.context_poses, device)


def model_method(model, name: str = "CylinderSplat", device: torch.device | str = "cpu", background=(0.0, 0.0, 0.0)) -> Method:
    model = model.to(device)

    def run(sample: Sample) -> RenderOutput:
        gaussians = reconstruct(model, sample, device)
        h, w = sample.target_images.shape[-2:]
        return render_views(gaussians, sample.target_poses, h, w, background)

    return Method(name, run)


def forward_warp_method(name: str = "Forward warp", background=(0.0, 0.0, 0.0)) -> Method:
    """Nearest input panorama warped with its depth prior (the prior, not ground truth)."""

    def run(sample: Sample) -> RenderOutput:
        h, w = sample.target_images.shape[-2:]
        return forward_warp(sample.context_images, sample.context_priors, sample.context_poses, sample.target_poses,
                            h, w, background=background)

    return Method(name, run)
