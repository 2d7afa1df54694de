"""Depth metrics on batched panoramas ``(..., H, W)`` with validity masks, plus LRCE (on depth, against the reference).

Per-image values are returned (shape ``(...)``); images without a single valid pixel give NaN so
that a dataset mean can skip them explicitly (``torch.nanmean``) instead of silently averaging 0.
Default validity: ``0.45 m < d* < 10 m`` on the reference depth (PanSplat's evaluation range).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from jaxtyping import Bool, Float
from torch import Tensor

__all__ = ["DepthRange", "valid_depth_mask", "abs_rel", "rmse", "delta1", "pcc", "lrce", "depth_metrics"]


@dataclass(frozen=True)
class DepthRange:
    """Open interval of reference depths (metres) that count as valid."""

    near: float = 0.45
    far: float = 10.0


def _check_pair(pred: Tensor, target: Tensor, name: str) -> None:
    if pred.shape != target.shape:
        raise ValueError(f"{name}: prediction {tuple(pred.shape)} and target {tuple(target.shape)} differ in shape")
    if pred.ndim < 2:
        raise ValueError(f"{name}: expected depth maps (..., H, W), got {tuple(pred.shape)}")


def valid_depth_mask(
    target: Float[Tensor, "*b H W"], depth_range: DepthRange = DepthRange(), pred: Tensor | None = None
) -> Bool[Tensor, "*b H W"]:
    """Pixels with ``near < target < far`` (and a finite prediction when ``pred`` is given)."""
    mask = (target > depth_range.near) & (target < depth_range.far) & torch.isfinite(target)
    if pred is not None:
        mask &= torch.isfinite(pred)
    return mask


def _masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    values = torch.where(mask, values, torch.zeros_like(values))
    count = mask.sum(dim=(-2, -1))
    total = values.sum(dim=(-2, -1))
    return torch.where(count > 0, total / count.clamp(min=1), torch.full_like(total, float("nan")))


def _prepare(pred, target, mask, depth_range, name):
    _check_pair(pred, target, name)
    valid = valid_depth_mask(target, depth_range, pred)
    if mask is not None:
        valid &= mask.bool()
    return pred.double(), target.double(), valid


def abs_rel(pred, target, mask=None, depth_range: DepthRange = DepthRange()) -> Tensor:
    """Mean of ``|d - d*| / d*`` over valid pixels, per image."""
    p, t, m = _prepare(pred, target, mask, depth_range, "abs_rel")
    return _masked_mean((p - t).abs() / t.clamp(min=1e-12), m).to(pred.dtype)


def rmse(pred, target, mask=None, depth_range: DepthRange = DepthRange()) -> Tensor:
    """Root of the mean squared depth error over valid pixels, per image."""
    p, t, m = _prepare(pred, target, mask, depth_range, "rmse")
    return _masked_mean((p - t) ** 2, m).sqrt().to(pred.dtype)


def delta1(pred, target, mask=None, depth_range: DepthRange = DepthRange(), threshold: float = 1.25) -> Tensor:
    """Fraction of valid pixels with ``max(d/d*, d*/d) < threshold``; non-positive predictions fail."""
    p, t, m = _prepare(pred, target, mask, depth_range, "delta1")
    safe_p = p.clamp(min=1e-12)
    ratio = torch.maximum(safe_p / t, t / safe_p)
    good = (ratio < threshold) & (p > 0)
    return _masked_mean(good.double(), m).to(pred.dtype)


def pcc(pred, target, mask=None, depth_range: DepthRange | None = DepthRange()) -> Tensor:
    """Pearson correlation of predicted vs reference depth per image over masked pixels.

    ``depth_range=None`` uses every finite pixel (for reference depths from a network).
    Constant inputs (zero variance) give NaN.
    """
    _check_pair(pred, target, "pcc")
    if depth_range is None:
        m = torch.isfinite(pred) & torch.isfinite(target)
    else:
        m = valid_depth_mask(target, depth_range, pred)
    if mask is not None:
        m &= mask.bool()
    p, t = pred.double(), target.double()
    mp = _masked_mean(p, m)[..., None, None]
    mt = _masked_mean(t, m)[..., None, None]
    dp = torch.where(m, p - mp, torch.zeros_like(p))
    dt = torch.where(m, t - mt, torch.zeros_like(t))
    cov = (dp * dt).sum(dim=(-2, -1))
    denom = torch.sqrt((dp * dp).sum(dim=(-2, -1)) * (dt * dt).sum(dim=(-2, -1)))
    return torch.where(denom > 0, cov / denom.clamp(min=1e-300), torch.full_like(cov, float("nan"))).to(pred.dtype)


def lrce(pred: Float[Tensor, "*b H W"] | Float[Tensor, "*b C H W"], target: Tensor, channel_dim: bool = False,
         depth_range: DepthRange | None = DepthRange()) -> Tensor:
    """Left-right consistency error, the paper's LRCE: how much worse than the reference the seam is.

    ``mean_rows |(p[:, 0] - p[:, -1]) - (t[:, 0] - t[:, -1])|`` per image: the difference between the
    first and last pixel columns of the prediction, against the same difference in the reference (the
    released CylinderSplat evaluation's ``continuity``, on metric depth). A render whose seam matches the
    truth scores 0, whatever the scene has at the seam; a blurred one does not win (the earlier
    reference-free variant, ``mean |x[:, 0] - x[:, -1]|`` of the render alone, rewarded blur).

    Depth maps ``(..., H, W)`` (default): only rows where both reference end pixels are valid depths
    in ``depth_range`` count (the released code has no mask: a hole in the reference would score as
    an error); NaN when no row does. ``channel_dim=True``: images ``(..., C, H, W)`` (the mean runs over
    channels too; pass ``depth_range=None``), the RGB variant, also relative to the reference.
    """
    if pred.shape != target.shape:
        raise ValueError(f"lrce: prediction {tuple(pred.shape)} and reference {tuple(target.shape)} differ in shape")
    p, t = pred.double(), target.double()
    diff = ((p[..., 0] - p[..., -1]) - (t[..., 0] - t[..., -1])).abs()  # (..., [C,] H)
    if channel_dim:
        diff = diff.mean(dim=-2)
    if depth_range is None:
        return diff.mean(dim=-1).to(pred.dtype)
    ends = torch.stack([t[..., 0], t[..., -1]])
    rows = ((ends > depth_range.near) & (ends < depth_range.far) & torch.isfinite(ends)).all(dim=0)
    if channel_dim:
        rows = rows.all(dim=-2)
    count = rows.sum(dim=-1)
    mean = (diff * rows).sum(dim=-1) / count.clamp(min=1)
    return torch.where(count > 0, mean, torch.full_like(mean, float("nan"))).to(pred.dtype)


def depth_metrics(pred, target, mask=None, depth_range: DepthRange = DepthRange()) -> dict[str, Tensor]:
    """All per-image depth metrics at once: ``abs_rel``, ``rmse``, ``delta1``, ``pcc``."""
    return {
        "abs_rel": abs_rel(pred, target, mask, depth_range),
        "rmse": rmse(pred, target, mask, depth_range),
        "delta1": delta1(pred, target, mask, depth_range),
        "pcc": pcc(pred, target, mask, depth_range),
    }
