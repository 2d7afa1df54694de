"""Multi-view consistency check of posed panoramas with depth (the proof that poses are right).

Every pixel of a source view is lifted to 3D with its radial depth, moved into a destination
view with the two ``c2w`` poses, and the destination's colour and depth are read there. With
correct poses, colours agree (up to occlusions and shading) and the projected distance matches the
destination's depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from ..geometry import camera_to_world, equirect_rays, ray_to_uv, world_to_camera
from ..metrics.image import ws_weights

__all__ = ["ConsistencyResult", "reprojection_consistency", "sample_equirect", "reproject", "lift_to_world"]


@dataclass
class ConsistencyResult:
    weighted_l1: float  # latitude-weighted mean |colour difference| over pixels valid in both views
    consistent_fraction: float  # share of those pixels whose depths agree within the tolerance
    valid_fraction: float  # share of source pixels that landed on a valid destination depth


def sample_equirect(image: Float[Tensor, "C H W"], u: Tensor, v: Tensor, mode: str = "bilinear") -> Tensor:
    """Sample ``image`` at continuous pixel coordinates ``(u, v)`` with horizontal wrap-around.

    Returns ``(C, *u.shape)``. Columns are padded circularly by one pixel so the seam interpolates.
    """
    c, h, w = image.shape
    padded = torch.cat([image[..., -1:], image, image[..., :1]], dim=-1)
    # Continuous coordinate x (pixel centre at j + 0.5) -> grid_sample's [-1, 1] (align_corners=False).
    gx = 2.0 * (u % w + 1.0) / (w + 2) - 1.0
    gy = 2.0 * v / h - 1.0
    grid = torch.stack((gx, gy), dim=-1).reshape(1, -1, 1, 2).to(image.dtype)
    out = F.grid_sample(padded[None], grid, mode=mode, padding_mode="border", align_corners=False)
    return out.reshape(c, *u.shape)


def lift_to_world(depth: Float[Tensor, "H W"], c2w: Float[Tensor, "4 4"]) -> Float[Tensor, "HW 3"]:
    """World points (float64, row-major pixels) of every pixel of an equirect depth map."""
    h, w = depth.shape
    rays = equirect_rays(h, w, device=depth.device, dtype=torch.float64)
    return camera_to_world((rays * depth.double()[..., None]).reshape(-1, 3), c2w.double().to(depth.device))


def reproject(
    src_depth: Float[Tensor, "H W"], src_c2w: Float[Tensor, "4 4"], dst_c2w: Float[Tensor, "4 4"],
    dst_size: tuple[int, int]
) -> tuple[Tensor, Tensor, Tensor]:
    """Where every source pixel's 3D point lands in a destination panorama of ``dst_size``: pixel
    coordinates ``u, v`` and its distance from the destination camera, each ``(H*W,)``."""
    in_dst = world_to_camera(lift_to_world(src_depth, src_c2w), dst_c2w.double().to(src_depth.device))
    u, v = ray_to_uv(in_dst, *dst_size)
    return u, v, torch.linalg.vector_norm(in_dst, dim=-1)


@torch.no_grad()
def reprojection_consistency(
    src_image: Float[Tensor, "3 H W"],
    src_depth: Float[Tensor, "H W"],
    src_c2w: Float[Tensor, "4 4"],
    dst_image: Float[Tensor, "3 H W"],
    dst_depth: Float[Tensor, "H W"],
    dst_c2w: Float[Tensor, "4 4"],
    rel_tol: float = 0.05,
    min_depth: float = 1e-3,
) -> ConsistencyResult:
    """Reproject ``src`` into ``dst``; depths agree when ``|d_proj - d_dst| <= rel_tol * d_dst``."""
    h, w = src_depth.shape
    u, v, proj_depth = reproject(src_depth, src_c2w, dst_c2w, (h, w))
    colour = sample_equirect(dst_image.double(), u, v).reshape(3, h, w)
    depth_there = sample_equirect(dst_depth.double()[None], u, v, mode="nearest").reshape(h, w)
    proj_depth = proj_depth.reshape(h, w)
    valid = (src_depth > min_depth) & (depth_there > min_depth)
    weight = ws_weights(h)[:, None].expand(h, w)
    wv = weight * valid
    err = (colour - src_image.double()).abs().mean(dim=0)
    consistent = (proj_depth - depth_there).abs() <= rel_tol * depth_there
    return ConsistencyResult(
        weighted_l1=float((err * wv).sum() / wv.sum().clamp(min=1e-12)),
        consistent_fraction=float((consistent & valid).sum() / valid.sum().clamp(min=1)),
        valid_fraction=float(valid.sum() / (src_depth > min_depth).sum().clamp(min=1)),
    )
