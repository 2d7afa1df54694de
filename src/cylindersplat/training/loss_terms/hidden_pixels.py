"""Per-pixel weights of the target pixels no context view sees ("hidden": found from the reference depths of
targets and contexts, :func:`cylindersplat.data.occlusion.occluded_mask`).

Two settings give them another weight than 1 (the RGB term becomes a weighted mean, and pixels of weight 0 also
drop out of the depth term):

* ``loss.occluded_weight = w`` (> 0): ``1 + w`` on hidden pixels, so completion is supervised where only it can
  be right;
* ``loss.pixel_stage_hidden = leave``: weight 0 on hidden pixels in stage 1 when later stages train the volume
  branch, so the pixel branch is not taught to stretch foreground Gaussians over disocclusions. It wins over
  ``occluded_weight`` in that stage.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from ...model.curriculum import volume_stage_follows

__all__ = ["HiddenPixelWeights", "Weighting"]


@dataclass(frozen=True)
class Weighting:
    """Hidden pixels weigh ``1 + gain`` (``gain = -1``: 0, left out); ``setting`` names the option that asks."""

    gain: float
    setting: str


class HiddenPixelWeights:
    """``weights(batch, stage)`` -> ``(B, T, H, W)`` weights of the target pixels, or ``None`` (all weigh 1)."""

    def __init__(self, occluded_weight: float, pixel_stage_hidden: str, stages: list[int] | tuple[int, ...]) -> None:
        self.occluded_weight = occluded_weight
        self.pixel_stage_hidden = pixel_stage_hidden
        self.stages = tuple(stages)
        self.warned = False  # the "needs reference depths" warning is said once per run

    def weighting(self, stage: int) -> Weighting | None:
        """What hidden pixels weigh in ``stage``; ``None`` when they weigh 1 like every other pixel."""
        if self.pixel_stage_hidden == "leave" and volume_stage_follows(stage, self.stages):
            return Weighting(-1.0, "loss.pixel_stage_hidden=leave")
        if self.occluded_weight == 0:
            return None
        return Weighting(self.occluded_weight, "loss.occluded_weight")

    def __call__(self, batch, stage: int) -> Float[Tensor, "B T H W"] | None:
        weighting = self.weighting(stage)
        if weighting is None:
            return None
        if batch.target_depths is None or batch.context_gt_depths is None:
            if not self.warned:
                warnings.warn(f"{weighting.setting} needs reference depths of targets and contexts; not applied",
                              stacklevel=4)
                self.warned = True
            return None
        from ...data.occlusion import occluded_mask

        masks = torch.stack([
            torch.stack([occluded_mask(batch.target_depths[b, t], batch.target_poses[b, t], batch.context_gt_depths[b],
                                       batch.context_poses[b]) for t in range(batch.target_depths.shape[1])])
            for b in range(batch.target_depths.shape[0])
        ])
        return 1.0 + weighting.gain * masks.to(batch.target_images.dtype)
