"""How much memory a reconstruction takes, checked before the model runs.

The forward pass of :class:`~cylindersplat.model.CylinderSplat` holds two kinds of large tensors:

* per input pixel: the full-resolution maps of the pixel branch (the encoded input, the last decoder
  stage and its refinement, ``F_pano`` with its depth channel, the Gaussian head's hidden layer) and one
  Gaussian (14 floats);
* per triplane cell (volume branch): the features sampled from the three planes, the decoder's hidden
  layers, the colour head and one Gaussian.

:func:`forward_memory` counts these floats from the model's config and doubles them (tensors that are
alive at the same time, allocator slack). Measured process peak RSS above the loaded model, CPU, float32
(``benchmarks/RESULTS.md``, "Reconstruction memory"): ``tiny``
2 views at 256x512 179 MiB (estimate 233 MiB), 1 view at 512x1024 309 MiB (estimate 401 MiB); ``paper`` 1
view at 256x512 517 MiB (estimate 994 MiB), at 512x1024 964 MiB (estimate 1.6 GiB): the measured peaks are
0.45-0.8x of the estimate. On CUDA the network runs in bf16, so the estimate is more cautious still.
:func:`check_forward_memory` refuses a reconstruction whose estimate exceeds the free memory of its
device (the same measure as the reference rasterizer's check:
:func:`cylindersplat.render.rasterize.available_memory`).
"""

from __future__ import annotations

import math

import torch

__all__ = ["ReconstructionMemoryError", "forward_memory", "check_forward_memory"]

FLOAT_BYTES = 4
GAUSSIAN_FLOATS = 14  # means 3, scales 3, rotation 4, opacity 1, colour 3
MARGIN = 2.0  # tensors alive at once, allocator slack (measured peaks are 0.45-0.8x of the estimate)
BASE_BYTES = 64 * 2**20  # workspaces, the ray embedding, the attention tokens of a small input


class ReconstructionMemoryError(MemoryError):
    """A reconstruction would need more memory than the device has free."""


def forward_memory(config, views: int, height: int, width: int, mode: str | None = None) -> int:
    """Estimated peak bytes of one forward pass (no gradients) of a model with ``config`` on ``views``
    panoramas of ``height`` x ``width`` (``mode``: the branches that run, default ``config.mode``)."""
    mode = mode or config.mode
    pix, vol = config.pixel, config.volume
    per_pixel = (config.backbone.in_channels + 2 * pix.decoder_widths[-1] + (1 + pix.feature_dim) + pix.head_hidden
                 + GAUSSIAN_FLOATS)
    total = views * height * width * per_pixel  # the pixel branch also feeds the volume branch: always runs
    if mode != "pixel":
        triplanes = views if vol.placement == "per_camera" else 1
        per_cell = 3 * vol.channels + 2 * vol.decoder_hidden + vol.color_hidden + GAUSSIAN_FLOATS
        total += triplanes * math.prod(vol.grid) * per_cell
    return BASE_BYTES + int(MARGIN * FLOAT_BYTES * total)


def check_forward_memory(config, views: int, height: int, width: int, device: torch.device | str,
                         mode: str | None = None) -> int:
    """Raise :class:`ReconstructionMemoryError` (resolution, estimate, free memory, what to do) when the
    forward pass would not fit in ``device``'s free memory; returns the estimate in bytes."""
    from ..render.rasterize import available_memory

    device = torch.device(device)
    need = forward_memory(config, views, height, width, mode)
    free = available_memory(device)
    if free is None or need <= free:
        return need
    stride = config.backbone.token_stride
    smaller, fits = height, None
    while smaller // 2 >= stride and smaller // 2 % stride == 0:
        smaller //= 2
        if forward_memory(config, views, smaller, 2 * smaller, mode) <= free:
            fits = smaller
            break
    advice = f"use a smaller --resolution (e.g. {fits}x{2 * fits})" if fits else "use a smaller --resolution"
    other = "--device cuda" if device.type == "cpu" and torch.cuda.is_available() else "a machine with more memory"
    raise ReconstructionMemoryError(
        f"reconstructing {views} panorama(s) at {height}x{width} needs about {_amount(need)} (estimate) but "
        f"{_amount(free)} are free on {device}; {advice}, fewer panoramas, or {other}")


def _amount(size: int) -> str:
    return f"{size / 2**30:.1f} GiB" if size >= 2**30 else f"{size / 2**20:.0f} MiB"
