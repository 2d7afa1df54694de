"""Bilinear sampling of 2D feature grids with optional wrap-around per axis.

Used for everything that reads a panorama (wrap along ``u``) or a triplane plane (wrap along
``theta``). Coordinates are *continuous cell coordinates* with the pixel-centre convention of
docs/conventions.md: cell ``j`` covers ``[j, j + 1)`` and its centre is ``j + 0.5``. On a wrapped axis the
coordinate is taken modulo the size, so ``x`` and ``x + size`` read the same value and sampling
between the last and the first cell interpolates across the seam. On a clamped axis samples
outside ``[0.5, size - 0.5]`` take the border value.
"""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["bilinear_sample", "sample_panorama"]


def _corner_indices(coord: Tensor, size: int, wrap: bool) -> tuple[Tensor, Tensor, Tensor]:
    """Integer neighbours ``(i0, i1)`` and the weight of ``i1`` for continuous ``coord``."""
    pos = coord - 0.5
    lower = torch.floor(pos)
    frac = pos - lower
    i0 = lower.long()
    i1 = i0 + 1
    if wrap:
        i0, i1 = torch.remainder(i0, size), torch.remainder(i1, size)
    else:
        i0, i1 = i0.clamp(0, size - 1), i1.clamp(0, size - 1)
    return i0, i1, frac


def bilinear_sample(
    grid: Float[Tensor, "N C H W"],
    x: Float[Tensor, "N P"],
    y: Float[Tensor, "N P"],
    wrap_x: bool = False,
    wrap_y: bool = False,
) -> Float[Tensor, "N P C"]:
    """Sample ``grid`` at continuous cell coordinates ``x`` (along W) and ``y`` (along H).

    Differentiable w.r.t. ``grid`` and the coordinates (within a cell).
    """
    n, c, h, w = grid.shape
    x0, x1, fx = _corner_indices(x, w, wrap_x)
    y0, y1, fy = _corner_indices(y, h, wrap_y)
    flat = grid.flatten(2).transpose(1, 2)  # (N, H*W, C): gather rows, not columns

    def read(yi: Tensor, xi: Tensor) -> Tensor:
        index = (yi * w + xi).unsqueeze(-1).expand(-1, -1, c)
        return torch.gather(flat, 1, index)

    fx, fy = fx.unsqueeze(-1).to(grid.dtype), fy.unsqueeze(-1).to(grid.dtype)
    top = read(y0, x0) * (1 - fx) + read(y0, x1) * fx
    bottom = read(y1, x0) * (1 - fx) + read(y1, x1) * fx
    return top * (1 - fy) + bottom * fy


def sample_panorama(
    image: Float[Tensor, "N C H W"], uv: Float[Tensor, "N P 2"]
) -> Float[Tensor, "N P C"]:
    """Bilinear read of equirect images at pixel coordinates ``uv`` (wraps in ``u``, clamps ``v``)."""
    return bilinear_sample(image, uv[..., 0], uv[..., 1], wrap_x=True, wrap_y=False)
