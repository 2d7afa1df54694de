"""Image metrics restricted to a pixel mask (the occluded pixels of a target view).

Same conventions as :mod:`cylindersplat.metrics.image`: images ``(..., 3, H, W)`` in ``[0, 1]``
(clipped), float64 internally, one value per image; masks ``(..., H, W)`` shared by the three
channels. An image whose mask selects no pixel gives NaN (callers turn it into ``None``).

* :func:`masked_ws_psnr`: ``WMSE = sum_{c, (i,j) in M} w_i e_cij^2 / (3 sum_{(i,j) in M} w_i)``
  with the WS-PSNR row weight ``w_i = sin(pi (i + 1/2) / H)``, then ``10 log10(1 / WMSE)``.
* :func:`masked_psnr`: plain mean of ``e^2`` over the masked pixels and the channels.
* :func:`masked_l1`: plain mean of ``|e|`` over the masked pixels and the channels.
"""

from __future__ import annotations

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..metrics import check_image_pair, ws_weights

__all__ = ["masked_ws_psnr", "masked_psnr", "masked_l1", "MIN_OCCLUDED_PIXELS"]

# A view with fewer occluded pixels than this gets no occluded metrics (None): a handful of pixels
# would give a meaningless, noisy number.
MIN_OCCLUDED_PIXELS = 16


def _prepare(pred: Tensor, target: Tensor, mask: Tensor, name: str) -> tuple[Tensor, Tensor]:
    check_image_pair(pred, target, name=name)
    if mask.shape != pred.shape[:-3] + pred.shape[-2:]:
        raise ValueError(f"{name}: mask {tuple(mask.shape)} does not match images {tuple(pred.shape)} "
                         "(expected (..., H, W))")
    err = pred.double().clamp(0, 1) - target.double().clamp(0, 1)
    return err, mask.bool()[..., None, :, :].double()


def _weighted_mean(values: Tensor, weight: Tensor) -> Tensor:
    """``sum(values * weight) / (3 * sum(weight))`` per image; NaN where the weight is all zero."""
    total = (values * weight).sum(dim=(-3, -2, -1))
    norm = weight.sum(dim=(-3, -2, -1)) * values.shape[-3]
    return torch.where(norm > 0, total / norm.clamp(min=1e-300), torch.full_like(total, float("nan")))


def _to_psnr(mse: Tensor) -> Tensor:
    return 10.0 * torch.log10(1.0 / mse)  # identical pixels: +inf, as the all-pixel metrics do


def masked_ws_psnr(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"],
                   mask: Bool[Tensor, "*b H W"]) -> Float[Tensor, "*b"]:
    """WS-PSNR (dB) over the masked pixels only (latitude-weighted MSE, pooled over RGB)."""
    err, m = _prepare(pred, target, mask, "masked_ws_psnr")
    w = ws_weights(pred.shape[-2], device=pred.device)[:, None]
    return _to_psnr(_weighted_mean(err**2, m * w)).to(pred.dtype)


def masked_psnr(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"],
                mask: Bool[Tensor, "*b H W"]) -> Float[Tensor, "*b"]:
    """PSNR (dB) over the masked pixels only (MSE pooled over RGB and masked pixels)."""
    err, m = _prepare(pred, target, mask, "masked_psnr")
    return _to_psnr(_weighted_mean(err**2, m)).to(pred.dtype)


def masked_l1(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"],
              mask: Bool[Tensor, "*b H W"]) -> Float[Tensor, "*b"]:
    """Mean absolute error over the masked pixels and the three channels (images in [0, 1])."""
    err, m = _prepare(pred, target, mask, "masked_l1")
    return _weighted_mean(err.abs(), m).to(pred.dtype)
