"""Photometric terms: the RGB L1 of Eq. 7 (a weighted mean when pixels carry weights) and the released code's L2."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

__all__ = ["rgb_l1", "rgb_l2"]


def rgb_l1(rgb: Float[Tensor, "*B V 3 H W"], target: Float[Tensor, "*B V 3 H W"],
           pixel_weight: Float[Tensor, "*B V H W"] | None = None) -> Tensor:
    """Mean ``|rgb - target|`` over pixels and channels; with ``pixel_weight`` the weighted mean."""
    if pixel_weight is None:
        return (rgb - target).abs().mean()
    w = pixel_weight.unsqueeze(-3).to(rgb.dtype)
    return (w * (rgb - target).abs()).sum() / (3 * w.sum()).clamp_min(1e-12)


def rgb_l2(rgb: Float[Tensor, "*B V 3 H W"], target: Float[Tensor, "*B V 3 H W"]) -> Tensor:
    """Mean squared error over pixels and channels."""
    return ((rgb - target) ** 2).mean()
