"""Reconstruct Gaussians from posed panoramas with a trained model and render them anywhere."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from ..data.io import DEPTH_PNG_SCALE, to_uint8, write_depth_png, write_rgb
from ..errors import InputError
from ..gaussians import Gaussians
from ..render import Equirect, RasterSettings, render
from ..render.api import RenderOutput
from ..render.cameras import CameraModel
from ..render.layered import FrontLayer, render_layered
from ..render.rasterize import RenderMemoryError
from ..utils.atomic import atomic_path
from ..utils.colormap import colorize_depth
from ..utils.notices import Notice
from ..utils.progress import Progress
from ..validation import (
    check_c2w,
    check_depth_plausible,
    check_depths,
    check_images,
    check_opacity_threshold,
    check_scene_scale,
)
from .camera_path import flythrough_path
from .memory import check_forward_memory
from .video import VideoWriter

__all__ = ["reconstruct_gaussians", "raster_settings", "iter_views", "render_views", "normalized_depth", "depth_limits",
           "sampled_depth_limits", "view_picture", "write_view", "write_metric_depth", "pinhole_intrinsics",
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
    check_plausibility: bool = True,
    layers: bool = False,
) -> Gaussians | tuple[Gaussians, int | None]:
    """World-frame Gaussians (unbatched, float32, on ``device``) of one scene; drops those with opacity <=
    ``min_opacity``. ``amp``: ``"auto"`` runs the network under bf16 autocast on CUDA (as training
    does; the Gaussians come out in float32), ``"off"`` in float32 everywhere. A resolution whose
    forward pass would not fit in the device's free memory is refused first
    (:class:`~cylindersplat.inference.memory.ReconstructionMemoryError`).

    Inputs are checked first (:mod:`cylindersplat.validation`, one-line
    :class:`~cylindersplat.errors.InputError`): ``images`` float RGB in [0, 1], finite, W == 2H, H divisible
    by the model's token stride; ``depths`` finite, >= 0 (0 = unknown), the images' size; ``c2w`` finite rigid
    poses (no reflection) within 10 km of the origin; ``min_opacity`` in [0, 1). With ``check_plausibility``
    each view's median positive depth must lie in 1 cm to 1 km (a unit mistake otherwise), and a scene whose
    size suggests one (:func:`~cylindersplat.validation.check_scene_scale`) is warned about. A ``min_opacity``
    that leaves no Gaussian is an error naming it.

    ``layers``: also return the leading Gaussians to draw as a front layer, a
    :class:`~cylindersplat.render.layered.FrontLayer` (:func:`~cylindersplat.render.layered.render_layered`; pass it
    on as ``front=`` to :func:`render_views`, :func:`iter_views` or :func:`write_flythrough`): the pixel Gaussians
    when the model outputs both branches and its ``render_layering`` is ``"pixel_over_volume"`` or its
    ``render_pixel_blending`` is ``"surface"`` (a pixel-only model's Gaussians are then all one blended layer), else
    ``None`` (one pass)."""
    if amp not in ("auto", "off"):
        raise InputError(f"amp must be 'auto' or 'off', got {amp!r}")
    check_opacity_threshold(min_opacity)
    check_images(images, model.config.backbone.token_stride)
    check_depths(depths, images)
    check_c2w(c2w, images.shape[0])
    if check_plausibility:
        for i, depth in enumerate(depths):
            check_depth_plausible(depth, f"depths[{i}]")
        check_scene_scale(depths, c2w, "the input views")
    model.eval()
    device = torch.device(device)
    check_forward_memory(model.config, images.shape[0], images.shape[-2], images.shape[-1], device, model.mode)
    use_bf16 = amp == "auto" and device.type == "cuda"
    with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_bf16):
        out = model(images[None].to(device), depths[None].to(device), c2w[None].to(device))
    gaussians = out.gaussians.detach().to(torch.float32).batch(0)
    front = model.front_layer(out)
    if min_opacity > 0:
        keep = gaussians.opacities > min_opacity
        kept = gaussians[keep]
        if len(kept) == 0 and len(gaussians):  # an empty scene is never what was asked for
            raise InputError(f"min_opacity (--min-opacity) {min_opacity:g} leaves 0 of {len(gaussians):,} Gaussians "
                             f"(the most opaque has {float(gaussians.opacities.max()):.3g}); choose a lower value")
        gaussians = kept
        if front is not None:
            front = replace(front, count=int(keep[:front.count].sum()))
    return (gaussians, front) if layers else gaussians


def raster_settings(model_config) -> RasterSettings:
    """The rasterizer's constants a model's Gaussians are drawn with (its ``render_dilation``; 3DGS's otherwise)."""
    return RasterSettings(dilation=getattr(model_config, "render_dilation", RasterSettings.dilation))


AUTO_VIEWS_AT_ONCE = 4  # the first batch size of automatic batching (halved while a batch does not fit)


@torch.no_grad()
def iter_views(
    gaussians: Gaussians,
    c2w: Float[Tensor, "K 4 4"],
    height: int,
    width: int,
    background=(0.0, 0.0, 0.0),
    chunk: int | None = None,
    progress: bool = False,
    desc: str = "render",
    camera: CameraModel | None = None,
    unit: str = "view",
    settings: RasterSettings | None = None,
    front: FrontLayer | int | None = None,
) -> Iterator[RenderOutput]:
    """Render ``K`` views ``chunk`` cameras at a time, yielding each chunk (on the CPU) as soon as it is
    done: a caller that writes and drops them holds at most ``chunk`` views. ``camera``: any camera
    model (default ``Equirect(height, width)``; e.g. ``Pinhole(K, height, width)``); ``settings``: the rasterizer's
    constants (a model's Gaussians are drawn with :func:`raster_settings` of its config); ``front``: the leading
    Gaussians drawn as a layer over the others (a :class:`~cylindersplat.render.layered.FrontLayer`, or their count;
    :func:`~cylindersplat.render.layered.render_layered`; :func:`reconstruct_gaussians` with ``layers=True`` gives
    it), None: one depth-sorted pass.

    ``chunk=None`` batches automatically: :data:`AUTO_VIEWS_AT_ONCE` views at a time, halved (down to one, with
    a :class:`~cylindersplat.utils.notices.Notice`) whenever the renderer refuses a batch for memory
    (:class:`~cylindersplat.render.rasterize.RenderMemoryError`, raised before it allocates). A fixed ``chunk``
    is kept: its refusal is raised."""
    if chunk is not None and chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    camera = camera if camera is not None else Equirect(height, width)
    if (camera.height, camera.width) != (height, width):
        raise ValueError(f"camera is {camera.height}x{camera.width} but {height}x{width} was asked for")
    device = gaussians.device
    bar = Progress(len(c2w), desc, unit, progress)
    front = FrontLayer.of(front)
    layers = None if front is None else (gaussians[:front.count], gaussians[front.count:])  # split once, per chunk
    at_once, start = chunk or AUTO_VIEWS_AT_ONCE, 0
    try:
        while start < len(c2w):
            try:
                poses = c2w[start:start + at_once].to(device)
                if layers is None:
                    out = render(gaussians, poses, camera, background=background, settings=settings)
                else:
                    out = render_layered(*layers, poses, camera, background=background, settings=settings,
                                         cover=front.cover, blend=front.blend)
            except RenderMemoryError:
                if chunk is not None or at_once == 1 or len(c2w) - start == 1:
                    raise
                at_once = min(at_once, len(c2w) - start) // 2
                warnings.warn(f"{desc}: {at_once} {unit}(s) at a time to fit in free memory", Notice, stacklevel=2)
                continue
            start += len(out.rgb)
            bar.update(len(out.rgb))
            yield RenderOutput(out.rgb.cpu(), out.depth.cpu(), out.alpha.cpu())
    finally:
        bar.close()


def render_views(
    gaussians: Gaussians,
    c2w: Float[Tensor, "K 4 4"],
    height: int,
    width: int,
    background=(0.0, 0.0, 0.0),
    chunk: int | None = None,
    progress: bool = False,
    desc: str = "render",
    camera: CameraModel | None = None,
    settings: RasterSettings | None = None,
    front: FrontLayer | int | None = None,
) -> RenderOutput:
    """Render ``K`` views (default panoramas; ``camera`` any camera model) in chunks of ``chunk`` cameras
    (bounded render memory; None: automatic, see :func:`iter_views`; ``front``: as there); all results on the
    CPU, stacked."""
    parts = list(iter_views(gaussians, c2w, height, width, background, chunk, progress, desc, camera,
                            settings=settings, front=front))
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


def write_metric_depth(npy_path: str | Path | None, png_path: str | Path | None, depth: Tensor, alpha: Tensor,
                       min_alpha: float = 0.5) -> Tensor:
    """A rendered view's depth in metres (radial distance along each pixel's ray; 0 where the view is less than
    ``min_alpha`` covered) as float32 ``.npy`` and/or a 16-bit PNG in millimetres (0 also beyond 65.535 m).
    Returns the metric depth ``(H, W)``."""
    metric = normalized_depth(depth, alpha, min_alpha).float()
    if npy_path is not None:
        with atomic_path(npy_path) as tmp:
            with open(tmp, "wb") as f:
                np.save(f, metric.numpy().astype(np.float32))
    if png_path is not None:
        write_depth_png(png_path, metric, scale=DEPTH_PNG_SCALE)
    return metric


def pinhole_intrinsics(height: int, width: int, fov_deg: float = 90.0) -> Tensor:
    """OpenCV ``K`` (3x3) of a centred pinhole camera with a horizontal field of view of ``fov_deg``
    (square pixels; pixel centres at ``+0.5``, so the principal point is ``(W/2, H/2)``)."""
    if not 0 < fov_deg < 180:
        raise ValueError(f"a pinhole field of view must be between 0 and 180 degrees, got {fov_deg}")
    f = width / 2 / math.tan(math.radians(fov_deg) / 2)
    return torch.tensor([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])


@torch.no_grad()
def sampled_depth_limits(gaussians: Gaussians, c2w: Float[Tensor, "K 4 4"], samples: int = 4,
                         size: tuple[int, int] = (32, 64)) -> tuple[float | None, float | None]:
    """:func:`depth_limits` of small panoramas at up to ``samples`` poses spread over ``c2w``: a colormap
    range known before the views themselves are rendered (so they can be written as they come)."""
    index = torch.linspace(0, len(c2w) - 1, min(samples, len(c2w))).round().long().unique()
    out = render_views(gaussians, c2w[index], *size)  # batched to fit memory, as the views themselves
    return depth_limits(normalized_depth(out.depth, out.alpha))


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
    camera: CameraModel | None = None,
    poses: Float[Tensor, "K 4 4"] | None = None,
    chunk: int | None = 2,
    progress: bool = True,
    settings: RasterSettings | None = None,
    front: FrontLayer | int | None = None,
) -> Path:
    """Render a looped path of ``frames`` poses through the cameras ``c2w`` (or exactly the poses ``poses``,
    one frame each) as RGB above depth and stream the frames into a video (``.gif``, or ``.mp4``/``.webm``
    with ffmpeg): ``chunk`` frames are rendered at a time (None: automatic, see :func:`iter_views`) and written
    at once, so memory never holds the whole video. ``camera``: default panoramas, or e.g.
    ``Pinhole(K, height, width)`` for a perspective fly-through; ``settings``: the rasterizer's constants (a model's
    :func:`raster_settings`; ``front``: as :func:`iter_views`). Returns the video's path; nothing is left at ``path``
    if rendering or writing fails."""
    if poses is None:
        poses = flythrough_path(c2w, frames, loop=True)
    with VideoWriter(path, fps) as video:
        for out in iter_views(gaussians, poses, height, width, background, chunk, progress, "fly-through", camera,
                              "frame", settings, front):
            for i in range(len(out.rgb)):
                video.append(view_picture(out.rgb[i], out.depth[i], out.alpha[i], near, far))
    return video.path
