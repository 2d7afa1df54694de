"""Pinhole rendering (same rasterizer and backends, perspective projection); the cubemap route uses it."""

from __future__ import annotations

from torch import Tensor

from ..gaussians import Gaussians
from .api import RenderOutput, render
from .cameras import Pinhole
from .projection import RasterSettings

__all__ = ["render_pinhole"]


def render_pinhole(
    gaussians: Gaussians,
    c2w: Tensor,
    intrinsics: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    settings: RasterSettings | None = None,
    backend: str = "auto",
) -> RenderOutput:
    """Render pinhole images (OpenCV intrinsics ``K`` 3x3, pixel centres at +0.5):
    ``render(gaussians, c2w, Pinhole(K, height, width), ...)``.

    Shapes as :func:`cylindersplat.render.render_equirect`. ``depth`` is the radial distance of the
    Gaussian means (alpha-weighted), so it is comparable with equirect depth.
    """
    return render(gaussians, c2w, Pinhole(intrinsics, height, width), background, backend, settings)
