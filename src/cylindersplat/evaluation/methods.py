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
from ..inference.pipeline import raster_settings, reconstruct_gaussians, render_views
from ..render.api import RenderOutput

__all__ = ["Method", "model_method", "forward_warp_method", "reconstruct", "with_fill", "fill_methods"]


@dataclass
class Method:
    """A named renderer of a sample's targets; ``background``: what it shows where it covers no pixel
    (said under every table, since holes scored against black lose dB that a trivial fill recovers)."""

    name: str
    run: Callable[[Sample], RenderOutput]
    background: str = "black"


def with_fill(method: Method, fill: str, name: str | None = None) -> Method:
    """``method`` with a trivial fill behind its render (:mod:`cylindersplat.evaluation.fills`)."""
    from .fills import FILL_DESCRIPTIONS, fill_uncovered

    if fill not in FILL_DESCRIPTIONS:
        raise ValueError(f"unknown fill {fill!r}; choose from {', '.join(FILL_DESCRIPTIONS)}")

    def run(sample: Sample) -> RenderOutput:
        return fill_uncovered(method.run(sample), sample.context_images, fill)

    return Method(name or f"{method.name} + {fill} fill", run, FILL_DESCRIPTIONS[fill])


def fill_methods(method: Method, fills) -> list[Method]:
    """``method`` followed by itself with each fill of ``fills`` (the fill rows of a table)."""
    return [method] + [with_fill(method, fill) for fill in fills]


def reconstruct(model, sample: Sample, device: torch.device | str = "cpu"):
    """Gaussians (world frame, unbatched) of a sample's context views."""
    return reconstruct_gaussians(model, sample.context_images, sample.context_priors, sample.context_poses, device)


def model_method(model, name: str = "CylinderSplat", device: torch.device | str = "cpu",
                 background=(0.0, 0.0, 0.0)) -> Method:
    model = model.to(device)
    settings = raster_settings(model.config)

    def run(sample: Sample) -> RenderOutput:
        gaussians, front = reconstruct_gaussians(model, sample.context_images, sample.context_priors,
                                                 sample.context_poses, device, layers=True)
        h, w = sample.target_images.shape[-2:]
        return render_views(gaussians, sample.target_poses, h, w, background, settings=settings, front=front)

    return Method(name, run)


def forward_warp_method(name: str = "Forward warp", background=(0.0, 0.0, 0.0)) -> Method:
    """Nearest input panorama warped with its depth prior (the prior, not ground truth)."""

    def run(sample: Sample) -> RenderOutput:
        h, w = sample.target_images.shape[-2:]
        return forward_warp(sample.context_images, sample.context_priors, sample.context_poses, sample.target_poses,
                            h, w, background=background)

    return Method(name, run)
