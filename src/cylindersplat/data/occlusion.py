"""Which pixels of a target panorama no context panorama sees (the "occluded" pixels).

A target pixel with depth is lifted to its 3D point, projected into every context view and
depth-tested against that context's depth map: the context sees the point when nothing lies in
front of it there, i.e. ``d_ctx >= (1 - rel_tol) * d_proj`` (``d_proj`` the point's distance from
the context camera, ``d_ctx`` the context depth at the projected pixel, nearest sample; a tolerance
covers resampling and discretisation). A pixel is *occluded* when no context sees its point. These
are the pixels only completion (the volume branch) can get right; ``cylindersplat eval`` reports
metrics on them separately (docs/evaluation.md).
"""

from __future__ import annotations

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from .consistency import reproject, sample_equirect

__all__ = ["occluded_mask", "occluded_fraction"]


@torch.no_grad()
def occluded_mask(
    target_depth: Float[Tensor, "H W"],
    target_c2w: Float[Tensor, "4 4"],
    context_depths: Float[Tensor, "V Hc Wc"],
    context_c2w: Float[Tensor, "V 4 4"],
    rel_tol: float = 0.05,
    min_depth: float = 1e-3,
) -> Bool[Tensor, "H W"]:
    """``True`` where the target pixel has a valid depth and no context view sees its 3D point.

    Context depths of 0 (invalid) count as "sees nothing there" (the point counts as hidden from
    that context). Context maps may have another resolution than the target.
    """
    if target_depth.ndim != 2 or context_depths.ndim != 3 or context_c2w.shape != (len(context_depths), 4, 4):
        raise ValueError(f"occluded_mask needs target depth (H, W), context depths (V, H, W) and poses (V, 4, 4); got "
                         f"{tuple(target_depth.shape)}, {tuple(context_depths.shape)}, {tuple(context_c2w.shape)}")
    h, w = target_depth.shape
    valid = target_depth > min_depth
    seen = torch.zeros(h * w, dtype=torch.bool, device=target_depth.device)
    for ctx_depth, c2w in zip(context_depths.to(target_depth.device), context_c2w):
        u, v, d_proj = reproject(target_depth, target_c2w, c2w, tuple(ctx_depth.shape))
        d_ctx = sample_equirect(ctx_depth.double()[None], u, v, mode="nearest").reshape(-1)
        seen |= (d_ctx > min_depth) & (d_ctx >= (1.0 - rel_tol) * d_proj)
    return valid & ~seen.reshape(h, w)


def occluded_fraction(mask: Bool[Tensor, "H W"]) -> float:
    """Latitude-weighted share of occluded pixels (the weighting WS-PSNR uses)."""
    from ..metrics.image import ws_weights

    weight = ws_weights(mask.shape[0]).to(mask.device)[:, None].expand_as(mask)
    return float((weight * mask).sum() / weight.sum())
