"""Cubemap ("indirect") panorama rendering: six 90-degree pinhole faces resampled to equirect.

This is how prior feed-forward panoramic methods render; it is kept as the baseline the direct
rasterizer is compared against (paper appendix, "Comparison of 3DGS Rendering Methods").
Resampling is bilinear inside each face; every equirect pixel reads from the face its ray
leaves the cube through.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.cubemap import cubemap_face_c2w, cubemap_rotations
from ..geometry.equirect import check_equirect_shape, equirect_rays
from .api import RenderOutput, render
from .cameras import cubemap_face
from .projection import RasterSettings

__all__ = ["render_cubemap", "cubemap_to_equirect"]


def cubemap_to_equirect(faces: Tensor, height: int, width: int) -> Tensor:
    """Resample cube faces ``(..., 6, C, S, S)`` (order of :data:`CUBEMAP_FACES`) to ``(..., C, H, W)``."""
    *lead, six, ch, s, _ = faces.shape
    rays = equirect_rays(height, width, device=faces.device, dtype=faces.dtype)  # (H, W, 3)
    rot = cubemap_rotations(device=faces.device, dtype=faces.dtype)  # (6, 3, 3) face -> camera
    local = torch.einsum("kji,hwj->khwi", rot, rays)  # ray in each face's frame
    forward = local[..., 2]
    face = torch.argmax(forward, dim=0)  # (H, W) face whose forward axis is closest to the ray
    z = forward.clamp_min(1e-6)
    # Pixel x = f * x / z + S/2 with f = S/2  ->  normalised [-1, 1] coordinate = x / z.
    grid = torch.stack((local[..., 0] / z, local[..., 1] / z), dim=-1)  # (6, H, W, 2)
    flat = faces.reshape(-1, 6, ch, s, s)
    out = []
    for k in range(6):
        g = grid[k].expand(flat.shape[0], -1, -1, -1)
        out.append(F.grid_sample(flat[:, k], g, mode="bilinear", padding_mode="border", align_corners=False))
    stacked = torch.stack(out, dim=1)  # (N, 6, C, H, W)
    picked = torch.gather(stacked, 1, face.view(1, 1, 1, height, width).expand(stacked.shape[0], 1, ch, -1, -1))
    return picked[:, 0].reshape(*lead, ch, height, width)


def _face_background(background, face_c2w: Tensor):
    """A per-panorama background ``(..., 3)`` becomes one per face (each panorama's six faces share it)."""
    if background is None:
        return None
    background = torch.as_tensor(background, device=face_c2w.device)
    if background.numel() == 3:
        return background.reshape(3)
    return background.reshape(-1, 3).repeat_interleave(6, dim=0)


def render_cubemap(
    gaussians: Gaussians,
    c2w: Tensor,
    height: int,
    width: int,
    face_size: int | None = None,
    background: Tensor | None = None,
    settings: RasterSettings | None = None,
    backend: str = "auto",
) -> RenderOutput:
    """Render six faces of ``face_size`` (default ``H // 2``) and stitch them into an equirect panorama.

    Same output as :func:`cylindersplat.render.render_equirect`; the faces go through the same
    backends (``backend``) as the direct route.
    """
    check_equirect_shape(height, width)
    face_size = face_size or max(height // 2, 1)
    out_shape = tuple(c2w.shape[:-2])  # (*B, V); render() checks it against the Gaussians
    face_c2w = cubemap_face_c2w(c2w.to(gaussians.device))  # (..., 6, 4, 4)
    if gaussians.batch_shape:
        face_c2w = face_c2w.flatten(1, 2)  # (B, V*6, 4, 4)
    else:
        face_c2w = face_c2w.reshape(-1, 4, 4)
    faces = render(gaussians, face_c2w, cubemap_face(face_size), _face_background(background, face_c2w), backend,
                   settings)
    packed = torch.cat((faces.rgb, faces.depth.unsqueeze(-3), faces.alpha.unsqueeze(-3)), dim=-3)
    packed = packed.reshape(*out_shape, 6, 5, face_size, face_size)
    pano = cubemap_to_equirect(packed, height, width)
    return RenderOutput(rgb=pano[..., :3, :, :], depth=pano[..., 3, :, :], alpha=pano[..., 4, :, :])
