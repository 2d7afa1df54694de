"""Reconstruct Gaussians from posed panoramas with a trained model and render them anywhere."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor
from tqdm.auto import tqdm

from ..data.io import to_uint8, write_rgb
from ..gaussians import Gaussians
from ..render import render_equirect
from ..render.api import RenderOutput
from ..utils.colormap import colorize_depth
from .camera_path import flythrough_path
from .video import write_video

__all__ = ["reconstruct_gaussians", "render_views", "normalized_depth", "depth_limits", "view_picture", "write_view",
           "write_flythrough"]


@torch.no_grad()
def reconstruct_gaussians(
    model,
    images: Float[Tensor, "V 3 H W"],
    depths: Float[Tensor, "V H W"],
    c2w: Float[Tensor, "V 4 4"],
    device: torch.device | str = "cpu",
    min_opacity: float = 0.0,
    amp: str = "auto",
) -> Gaussians:
    """World-frame Gaussians (unbatched, float32, on ``device``) of one scene; drops those with opacity <=
    ``min_opacity``. ``amp``: ``"auto"`` runs the network under bf16 autocast on CUDA (as training
    does; the Gaussians come out in float32), ``"off"`` in float32 everywhere."""
    if amp not in ("auto", "off"):
        raise ValueError(f"amp must be 'auto' or 'off', got {amp!r}")
    model.eval()
    device = torch.device(device)
    use_bf16 = amp == "auto" and device.type == "cuda"
    with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_bf16):
        out = model(images[None].to(device), depths[None].to(device), c2w[None].to(device))
    gaussians = out.gaussians.detach().to(torch.float32).batch(0)
    if min_opacity > 0:
        gaussians = gaussians[gaussians.opacities > min_opacity]
    return gaussians


@torch.no_grad()
def render_views(
    gaussians: Gaussians,
    c2w: Float[Tensor, "K 4 4"],
    height: int,
    width: int,
    background=(0.0, 0.0, 0.0),
    chunk: int = 4,
    progress: bool = False,
    desc: str = "render",
) -> RenderOutput:
    """Render ``K`` panoramas in chunks of ``chunk`` cameras (bounded memory); results on the CPU."""
    device = gaussians.device
    parts = []
    for start in tqdm(range(0, len(c2w), chunk), desc=desc, unit="chunk", disable=None if progress else True):  # None: no bar when output is not a terminal
        out = render_equirect(gaussians, c2w[start:start + chunk].to(device), height, width, background=background)
        parts.append(RenderOutput(out.rgb.cpu(), out.depth.cpu(), out.alpha.cpu()))
    return RenderOutput(*(torch.cat([getattr(p, k) for p in parts]) for k in ("rgb", "depth", "alpha")))


def normalized_depth(depth: Tensor, alpha: Tensor, min_alpha: float = 0.5) -> Tensor:
    """Expected depth divided by coverage; 0 where the render is (nearly) empty."""
    return torch.where(alpha > min_alpha, depth / alpha.clamp_min(1e-6), torch.zeros_like(depth))


def depth_limits(depths: Tensor, low: float = 0.02, high: float = 0.98) -> tuple[float | None, float | None]:
    """Robust colormap range (quantiles of the valid depths) so every picture of a scene shares colours."""
    valid = depths[depths > 0].float()
    if valid.numel() == 0:
        return None, None
    if valid.numel() > 1_000_000:  # quantile() has an input size limit; a strided subset is plenty
        valid = valid[:: valid.numel() // 1_000_000 + 1]
    return float(valid.quantile(low)), float(valid.quantile(high))


def view_picture(rgb: Tensor, depth: Tensor, alpha: Tensor, near=None, far=None, gap: int = 4) -> np.ndarray:
    """RGB above its depth colormap (uint8 ``(2H + gap, W, 3)``)."""
    top = to_uint8(rgb)
    bottom = colorize_depth(normalized_depth(depth, alpha), near, far, as_uint8=True)
    return np.concatenate((top, np.full((gap, top.shape[1], 3), 255, np.uint8), bottom), axis=0)


def write_view(rgb_path: str | Path, depth_path: str | Path, rgb: Tensor, depth: Tensor, alpha: Tensor,
               near: float | None = None, far: float | None = None) -> None:
    """One rendered view as two PNGs: its RGB and its depth colormap (``near``/``far``: colour range)."""
    write_rgb(rgb_path, rgb)
    write_rgb(depth_path, colorize_depth(normalized_depth(depth, alpha), near, far, as_uint8=True))


def write_flythrough(
    path: str | Path,
    gaussians: Gaussians,
    c2w: Float[Tensor, "V 4 4"],
    height: int,
    width: int,
    frames: int = 48,
    fps: int = 12,
    near: float | None = None,
    far: float | None = None,
    background=(0.0, 0.0, 0.0),
) -> Path:
    """Render a looped path through the cameras ``c2w`` (RGB above depth per frame) and save it as a video."""
    poses = flythrough_path(c2w, frames, loop=True)
    out = render_views(gaussians, poses, height, width, background, progress=True, desc="fly-through")
    pictures = [view_picture(out.rgb[i], out.depth[i], out.alpha[i], near, far) for i in range(len(poses))]
    return write_video(path, pictures, fps=fps)
