"""Pinhole renderer (same rasterizer, perspective projection); used for the cubemap baseline."""

from __future__ import annotations

from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.poses import validate_c2w
from .api import RenderOutput, _output_shape
from .projection import RasterSettings, project_pinhole_gaussians
from .rasterize import rasterize

__all__ = ["render_pinhole"]


def render_pinhole(
    gaussians: Gaussians,
    c2w: Tensor,
    intrinsics: Tensor,
    height: int,
    width: int,
    background: Tensor | None = None,
    settings: RasterSettings | None = None,
) -> RenderOutput:
    """Render pinhole images (OpenCV intrinsics ``K`` 3x3, pixel centres at +0.5).

    Shapes as :func:`cylindersplat.render.render_equirect`. ``depth`` is the radial distance of the
    Gaussian means (alpha-weighted), so it is comparable with equirect depth.
    """
    if height <= 0 or width <= 0:
        raise ValueError(f"image size must be positive, got {height}x{width}")
    if intrinsics.shape != (3, 3):
        raise ValueError(f"intrinsics must be a 3x3 matrix, got {tuple(intrinsics.shape)}")
    gaussians.validate()
    validate_c2w(c2w)
    settings = settings or RasterSettings()
    out_shape = _output_shape(gaussians, c2w)
    proj, _ = project_pinhole_gaussians(gaussians, c2w.to(gaussians.device), intrinsics.to(gaussians.device), height, width, settings)
    if background is not None:
        background = background.to(gaussians.device, gaussians.dtype)
    rgb, depth, alpha = rasterize(proj, settings, background)
    return RenderOutput(
        rgb=rgb.reshape(*out_shape, 3, height, width),
        depth=depth.reshape(*out_shape, height, width),
        alpha=alpha.reshape(*out_shape, height, width),
    )
