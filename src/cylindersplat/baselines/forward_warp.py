"""Forward warping of an input panorama with its depth: the simplest novel-view baseline.

Every source pixel becomes a 3-D point at its depth along its ray; the points are projected into
the target panorama and splatted with a z-buffer (the nearest point wins a pixel). Pixels that no
point falls into then take the nearest point among those whose 2x2 neighbourhood covers them,
which closes the one-pixel cracks of magnification; larger disocclusions stay holes and get the
background colour (alpha 0, depth 0). The output is a :class:`~cylindersplat.render.RenderOutput`,
so evaluation treats the baseline exactly like a method that renders Gaussians.
"""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

from ..geometry import (
    camera_centers,
    camera_to_world,
    check_equirect_shape,
    equirect_rays,
    project_equirect,
    world_to_camera,
)
from ..render.api import RenderOutput

__all__ = ["forward_warp", "nearest_source"]


def nearest_source(source_c2w: Float[Tensor, "V 4 4"], target_c2w: Float[Tensor, "T 4 4"]) -> Tensor:
    """Index ``(T,)`` of the source camera closest to each target camera."""
    return torch.cdist(camera_centers(target_c2w), camera_centers(source_c2w)).argmin(dim=-1)


def _splat_one(
    image: Tensor, depth: Tensor, src_c2w: Tensor, tgt_c2w: Tensor, height: int, width: int
) -> tuple[Tensor, Tensor]:
    """Z-buffered 2x2 splat of one source ``(3, h, w)`` + ``(h, w)`` into one ``height x width`` target."""
    h, w = depth.shape
    valid = (depth > 0) & torch.isfinite(depth)
    points = equirect_rays(h, w, device=depth.device, dtype=torch.float64)[valid] * depth[valid, None].double()
    colors = image.permute(1, 2, 0)[valid]
    uv, dist = project_equirect(world_to_camera(camera_to_world(points, src_c2w.double()), tgt_c2w.double()), height,
                                width)
    out_depth = torch.full((height * width,), float("inf"), dtype=torch.float64, device=depth.device)
    out_rgb = torch.zeros(height * width, 3, dtype=image.dtype, device=image.device)
    in_front = dist > 1e-6
    # Pass 1: each point to the pixel containing it. Pass 2: pixels still empty take the nearest of
    # the points whose 2x2 neighbourhood of pixel centres covers them (closes 1-px cracks).
    own_u, own_v = torch.floor(uv[:, 0]).long() % width, torch.floor(uv[:, 1]).long().clamp(0, height - 1)
    base_u, base_v = torch.floor(uv[:, 0] - 0.5).long(), torch.floor(uv[:, 1] - 0.5).long()
    passes = [[(own_v, own_u)], [(base_v + dv, torch.remainder(base_u + du, width)) for du in (0, 1) for dv in (0, 1)]]
    for candidates in passes:
        empty_before = torch.isinf(out_depth)
        targets, sources = [], []
        for row, col in candidates:
            pixel = row * width + col
            ok = in_front & (row >= 0) & (row < height)
            ok[ok.clone()] &= empty_before[pixel[ok]]
            targets.append(pixel[ok])
            sources.append(ok.nonzero().squeeze(1))
        target, source = torch.cat(targets), torch.cat(sources)
        best = torch.full_like(out_depth, float("inf")).scatter_reduce_(0, target, dist[source], reduce="amin")
        winner = dist[source] <= best[target]
        out_rgb[target[winner]] = colors[source[winner]]
        out_depth = torch.where(empty_before, best, out_depth)
    hit = torch.isfinite(out_depth)
    out_depth = torch.where(hit, out_depth, torch.zeros_like(out_depth))
    return out_rgb.T.reshape(3, height, width), out_depth.to(depth.dtype).reshape(height, width)


def forward_warp(
    images: Float[Tensor, "V 3 h w"],
    depths: Float[Tensor, "V h w"],
    source_c2w: Float[Tensor, "V 4 4"],
    target_c2w: Float[Tensor, "T 4 4"],
    height: int | None = None,
    width: int | None = None,
    background: tuple[float, float, float] | Tensor = (0.0, 0.0, 0.0),
    sources: str = "nearest",
) -> RenderOutput:
    """Warp input panoramas into target poses. Returns rgb ``(T, 3, H, W)``, depth and alpha ``(T, H, W)``.

    ``sources="nearest"`` warps, per target, the input camera closest to it (the usual baseline);
    ``"all"`` splats every input into one z-buffer. Depth ``<= 0`` marks unknown source pixels.
    """
    if images.ndim != 4 or images.shape[1] != 3 or depths.shape != (images.shape[0], *images.shape[2:]):
        raise ValueError(f"forward_warp: images (V, 3, h, w) and depths (V, h, w) expected, got {tuple(images.shape)} "
                         f"and {tuple(depths.shape)}")
    if sources not in ("nearest", "all"):
        raise ValueError(f"sources must be 'nearest' or 'all', got {sources!r}")
    height = height or images.shape[-2]
    width = width or 2 * height
    check_equirect_shape(height, width)
    bg = torch.as_tensor(background, dtype=images.dtype, device=images.device).view(3, 1, 1)
    nearest = nearest_source(source_c2w, target_c2w)
    rgbs, out_depths, alphas = [], [], []
    for t in range(target_c2w.shape[0]):
        chosen = [int(nearest[t])] if sources == "nearest" else range(images.shape[0])
        best_rgb = best_depth = None
        for v in chosen:
            rgb, depth = _splat_one(images[v], depths[v], source_c2w[v], target_c2w[t], height, width)
            if best_rgb is None:
                best_rgb, best_depth = rgb, depth
                continue
            closer = (depth > 0) & ((best_depth == 0) | (depth < best_depth))
            best_rgb = torch.where(closer, rgb, best_rgb)
            best_depth = torch.where(closer, depth, best_depth)
        alpha = (best_depth > 0).to(images.dtype)
        rgbs.append(best_rgb * alpha + bg * (1 - alpha))
        out_depths.append(best_depth)
        alphas.append(alpha)
    return RenderOutput(torch.stack(rgbs), torch.stack(out_depths), torch.stack(alphas))
