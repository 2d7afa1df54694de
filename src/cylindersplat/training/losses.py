"""The paper's rendering loss (Sec. 3.4, Eq. 7)::

    L_render = |I_hat - I_gt|_1 + 0.05 * LPIPS(I_hat, I_gt) + 0.1 * |D_hat - D_ref|_1

``D_hat`` is the rendered radial depth, ``D_ref`` the reference depth of the target view, chosen by
``loss.depth_reference`` (:func:`reference_depths`): ``prior`` (the input prior computed for the
target views -- UniK3D in the paper), ``gt`` (the dataset's ground truth), ``file:NAME`` (files from
``cylindersplat data priors``) or ``none`` (no depth term). The depth term is averaged over pixels
where the reference is valid (> 0). The LPIPS term needs VGG/LPIPS weights on disk
(:func:`cylindersplat.metrics.load_lpips`); ``lpips="auto"`` uses it only when they are found.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..utils.notices import Notice
from .loss_terms.depth import depth_l1 as depth_l1_term
from .loss_terms.depth import reference_depths
from .loss_terms.perceptual import lpips_term
from .loss_terms.photometric import rgb_l1 as rgb_l1_term
from .loss_terms.photometric import rgb_l2 as rgb_l2_term
from .loss_terms.volume import VOLUME_LOSS_MODES

__all__ = ["LossConfig", "RenderLoss", "LossTerms", "reference_depths", "VOLUME_LOSSES", "RELEASED_VOLUME_WEIGHTS"]

VOLUME_LOSSES = tuple(VOLUME_LOSS_MODES)  # "scaled", "released" (loss_terms/volume.py)
RELEASED_VOLUME_WEIGHTS = {"rgb_l2": 0.1, "lpips": 0.005, "depth_l1": 0.1}  # the released code's stage-3 volume loss


@dataclass
class LossConfig:
    rgb_l1: float = 1.0
    lpips: float = 0.05
    depth_l1: float = 0.1
    use_lpips: Literal["auto", "on", "off"] = "auto"  # on: fail when weights are missing
    lpips_weights: str | None = None  # file; None = $CYLINDERSPLAT_LPIPS_WEIGHTS
    # Rendered depth is alpha-composited (sum_i w_i d_i, not divided by alpha) so the depth term
    # also pushes coverage up where the reference sees a surface; True divides by alpha first.
    normalize_depth: bool = False
    # Extra weight of the RGB L1 on target pixels no context view sees (1 + w there): completion is
    # supervised where only it can be right; 0 = off. Needs ground-truth depths of targets and contexts.
    occluded_weight: float = 0.0
    # Weight of the same loss on the volume branch's own render (its Gaussians before fusion) whenever
    # the model outputs fused Gaussians (stage 3, and stage 2 with train.stage2_render=fused). Keeps the
    # volume branch a whole-scene reconstruction, so the Gaussians fusion leaves in hidden space carry
    # its colours rather than a hole-filler's; 0 = off (the paper's loss).
    volume_weight: float = 0.0
    # What the volume branch's own render is scored with (times volume_weight): "scaled", this loss (Eq. 7);
    # "released", the authors' released code's stage-3 volume loss: 0.1 L2 + 0.005 LPIPS + 0.1 depth L1
    # (volume_weight=1 gives exactly their weights).
    volume_loss: str = "scaled"
    # Stage 1 (the pixel branch alone) of a curriculum that goes on to train the volume branch: "fill" scores
    # every target pixel (the paper's); "leave" leaves the pixels no context view sees out of its RGB and depth
    # terms, so the pixel branch is not taught to stretch foreground Gaussians over disocclusions the volume
    # branch is there to fill. Needs ground-truth depths of targets and contexts.
    pixel_stage_hidden: str = "fill"
    # D_ref of the depth term: gt (dataset ground truth), prior (the input prior of the target views,
    # the paper's UniK3D), file:NAME (precomputed files) or none. Unavailable -> error at start-up.
    depth_reference: str = "gt"


@dataclass
class LossTerms:
    total: Tensor  # scalar, differentiable
    parts: dict[str, float]  # unweighted terms, detached, for logging


class RenderLoss(nn.Module):
    """``forward(rgb, depth, alpha, target_rgb, reference_depth)`` on ``(*B, V, ...)`` renders: Eq. 7's weighted
    sum of the terms in :mod:`.loss_terms` (and :meth:`released_volume`, the released code's volume loss)."""

    def __init__(self, config: LossConfig | None = None, device: torch.device | str = "cpu") -> None:
        super().__init__()
        self.config = config or LossConfig()
        self.lpips_net = self._build_lpips(device)

    @property
    def uses_lpips(self) -> bool:
        return self.lpips_net is not None

    def _build_lpips(self, device) -> nn.Module | None:
        cfg = self.config
        if cfg.use_lpips == "off" or cfg.lpips == 0:
            return None
        if cfg.use_lpips not in ("auto", "on"):
            raise ValueError(f"loss.use_lpips must be 'auto', 'on' or 'off', got {cfg.use_lpips!r}")
        from ..metrics import LPIPS_WEIGHTS_ENV, load_lpips, lpips_weights_available

        available = lpips_weights_available(cfg.lpips_weights)  # a file, or the lpips package + torchvision's cache
        if not available and cfg.use_lpips == "auto":
            warnings.warn(
                f"LPIPS loss term disabled: no weights (set loss.lpips_weights=... or ${LPIPS_WEIGHTS_ENV}, or install "
                "the lpips package with torchvision's VGG16 weights cached; docs/evaluation.md); "
                "training with L1 + depth only",
                Notice, stacklevel=3,
            )
            return None
        try:
            net = load_lpips(cfg.lpips_weights, device=device)
        except FileNotFoundError as exc:
            raise FileNotFoundError(
                f"loss.use_lpips=on but the LPIPS weights could not be loaded: {exc}. "
                "Point loss.lpips_weights (or the environment variable) at the file, or set loss.use_lpips=off."
            ) from exc
        return net.requires_grad_(False).eval()

    def forward(
        self,
        rgb: Float[Tensor, "*B V 3 H W"],
        depth: Float[Tensor, "*B V H W"],
        alpha: Float[Tensor, "*B V H W"],
        target_rgb: Float[Tensor, "*B V 3 H W"],
        reference_depth: Float[Tensor, "*B V H W"] | None,
        pixel_weight: Float[Tensor, "*B V H W"] | None = None,
    ) -> LossTerms:
        """``pixel_weight`` (optional) weights the RGB L1 per pixel (a weighted mean); pixels it gives weight 0
        are left out of the depth term too."""
        cfg = self.config
        rgb_l1 = rgb_l1_term(rgb, target_rgb, pixel_weight)
        total = cfg.rgb_l1 * rgb_l1
        parts = {"rgb_l1": float(rgb_l1.detach())}
        if self.lpips_net is not None:
            perceptual = lpips_term(self.lpips_net, rgb, target_rgb)
            total = total + cfg.lpips * perceptual
            parts["lpips"] = float(perceptual.detach())
        if reference_depth is not None and cfg.depth_l1 > 0:
            depth_l1 = depth_l1_term(depth, reference_depth, alpha, pixel_weight, cfg.normalize_depth)
            total = total + cfg.depth_l1 * depth_l1
            parts["depth_l1"] = float(depth_l1.detach())
        parts["total"] = float(total.detach())
        return LossTerms(total, parts)

    def released_volume(
        self,
        rgb: Float[Tensor, "*B V 3 H W"],
        depth: Float[Tensor, "*B V H W"],
        target_rgb: Float[Tensor, "*B V 3 H W"],
        reference_depth: Float[Tensor, "*B V H W"] | None,
    ) -> LossTerms:
        """``loss.volume_loss=released``: :data:`RELEASED_VOLUME_WEIGHTS` on the volume branch's own render (MSE,
        LPIPS when its weights are loaded, depth L1 over valid reference pixels)."""
        weights = RELEASED_VOLUME_WEIGHTS
        rgb_l2 = rgb_l2_term(rgb, target_rgb)
        total, parts = weights["rgb_l2"] * rgb_l2, {"rgb_l2": float(rgb_l2.detach())}
        if self.lpips_net is not None:
            perceptual = lpips_term(self.lpips_net, rgb, target_rgb)
            total = total + weights["lpips"] * perceptual
            parts["lpips"] = float(perceptual.detach())
        if reference_depth is not None:
            depth_l1 = depth_l1_term(depth, reference_depth)
            total = total + weights["depth_l1"] * depth_l1
            parts["depth_l1"] = float(depth_l1.detach())
        parts["total"] = float(total.detach())
        return LossTerms(total, parts)
