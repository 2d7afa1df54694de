"""Image-quality metrics on batched panoramas: PSNR, WS-PSNR, SSIM.

All functions take tensors laid out ``(..., 3, H, W)`` with values in ``[0, 1]`` and return one
value per image (shape ``(...)``). Inputs are compared in float64 internally so that results match
the numpy/skimage references to ~1e-6 whatever the input dtype.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

__all__ = ["check_image_pair", "psnr", "ws_psnr", "ws_weights", "ssim", "gaussian_kernel1d"]


def check_image_pair(pred: Tensor, target: Tensor, *, equirect: bool = False, name: str = "images") -> None:
    """Refuse ambiguous layouts: require ``(..., 3, H, W)`` (and ``W == 2H`` for panoramas).

    Why so strict: a channel-last tensor ``(..., H, W, 3)`` silently gives wrong WS-PSNR values
    (weights applied over the wrong axis), a bug one peer shipped for months.
    """
    if pred.shape != target.shape:
        raise ValueError(f"{name}: prediction {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if pred.ndim < 3 or pred.shape[-3] != 3:
        hint = " (looks channel-last; permute to (..., 3, H, W))" if pred.ndim >= 3 and pred.shape[-1] == 3 else ""
        raise ValueError(f"{name}: expected layout (..., 3, H, W), got {tuple(pred.shape)}{hint}")
    if equirect and pred.shape[-1] != 2 * pred.shape[-2]:
        raise ValueError(
            f"{name}: equirectangular images need W == 2H, got H={pred.shape[-2]}, W={pred.shape[-1]}"
        )


def _mse_to_psnr(mse: Tensor, data_range: float = 1.0) -> Tensor:
    # Identical images give +inf, as skimage does.
    return 10.0 * torch.log10(data_range**2 / mse)


def psnr(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"]) -> Float[Tensor, "*b"]:
    """PSNR in dB of images clipped to ``[0, 1]`` (per image, MSE pooled over RGB and pixels)."""
    check_image_pair(pred, target, name="psnr")
    err = (pred.double().clamp(0, 1) - target.double().clamp(0, 1)) ** 2
    return _mse_to_psnr(err.mean(dim=(-3, -2, -1))).to(pred.dtype)


def ws_weights(height: int, device=None) -> Float[Tensor, " H"]:
    """Per-row WS-PSNR weight ``cos(latitude) = sin(pi * (i + 0.5) / H)``."""
    rows = torch.arange(height, device=device, dtype=torch.float64) + 0.5
    return torch.sin(math.pi * rows / height)


def ws_psnr(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"]) -> Float[Tensor, "*b"]:
    """Weighted-to-spherically-uniform PSNR of equirect panoramas in ``[0, 1]`` (clipped).

    ``WMSE = sum_{c,i,j} w_i e_{cij}^2 / sum_{c,i,j} w_i`` with ``w_i = sin(pi (i + 1/2) / H)``,
    i.e. the error is pooled over the three channels (PanSplat's convention).
    """
    check_image_pair(pred, target, equirect=True, name="ws_psnr")
    w = ws_weights(pred.shape[-2], device=pred.device)[:, None]
    err = (pred.double().clamp(0, 1) - target.double().clamp(0, 1)) ** 2
    wmse = (err * w).sum(dim=(-3, -2, -1)) / (w.sum() * pred.shape[-1] * 3)
    return _mse_to_psnr(wmse).to(pred.dtype)


def gaussian_kernel1d(sigma: float, truncate: float = 3.5, dtype=torch.float64, device=None) -> Tensor:
    """Normalised 1-D Gaussian of radius ``int(truncate * sigma + 0.5)`` (scipy.ndimage's kernel)."""
    radius = int(truncate * sigma + 0.5)
    x = torch.arange(-radius, radius + 1, dtype=dtype, device=device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def _blur_valid(x: Tensor, kernel: Tensor) -> Tensor:
    """Separable 'valid' Gaussian filter of ``(N, 1, H, W)`` -> ``(N, 1, H-2r, W-2r)``."""
    k = kernel.shape[0]
    x = F.conv2d(x, kernel.view(1, 1, k, 1))
    return F.conv2d(x, kernel.view(1, 1, 1, k))


def ssim(
    pred: Float[Tensor, "*b 3 H W"],
    target: Float[Tensor, "*b 3 H W"],
    *,
    sigma: float = 1.5,
    data_range: float = 1.0,
    use_sample_covariance: bool = True,
) -> Float[Tensor, "*b"]:
    """Mean SSIM per image, equal to ``skimage.metrics.structural_similarity(..., gaussian_weights=True,
    sigma=1.5, data_range=1, channel_axis=0)`` with skimage's default sample covariance, as the
    pixelSplat/PanSplat evaluation code calls it (so tables compare with their published numbers).

    skimage averages the SSIM map over the interior only (a border of the window radius is cropped),
    so a 'valid' convolution gives the same numbers without caring about its padding mode.
    ``use_sample_covariance=False`` gives the population-covariance variant (third decimal differs).
    """
    check_image_pair(pred, target, name="ssim")
    kernel = gaussian_kernel1d(sigma, device=pred.device)
    radius = kernel.shape[0] // 2
    height, width = pred.shape[-2:]
    if height <= 2 * radius or width <= 2 * radius:
        raise ValueError(f"ssim: images of {height}x{width} are smaller than the {2 * radius + 1}px window")
    batch = pred.shape[:-3]
    x = pred.double().reshape(-1, 1, height, width)
    y = target.double().reshape(-1, 1, height, width)
    stats = _blur_valid(torch.cat((x, y, x * x, y * y, x * y), dim=1).view(-1, 1, height, width), kernel)
    stats = stats.view(x.shape[0], 5, *stats.shape[-2:])
    mx, my, mxx, myy, mxy = stats.unbind(1)
    n = float(kernel.shape[0] ** 2)
    cov_norm = n / (n - 1.0) if use_sample_covariance else 1.0
    vx = cov_norm * (mxx - mx * mx)
    vy = cov_norm * (myy - my * my)
    vxy = cov_norm * (mxy - mx * my)
    c1 = (0.01 * data_range) ** 2
    c2 = (0.03 * data_range) ** 2
    s = ((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    per_channel = s.mean(dim=(-2, -1)).view(*batch, 3)
    return per_channel.mean(dim=-1).to(pred.dtype)
