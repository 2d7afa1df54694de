"""The training objective: what one step's loss is, given the rendered targets (``compute_loss`` is forward ->
render -> objective).

``loss = L_render(render of the model's Gaussians)`` (Eq. 7, :class:`~.losses.RenderLoss`), with per-pixel
weights on the target pixels no context view sees (:mod:`.loss_terms.hidden_pixels`), plus, with
``loss.volume_weight > 0`` whenever the model outputs fused Gaussians, ``volume_weight x`` the volume loss of the
volume branch's own render (:mod:`.loss_terms.volume`). ``LossTerms.parts`` logs every unweighted term and, for
the volume render, ``volume_total``.
"""

from __future__ import annotations

from typing import Callable

from .loss_terms.depth import reference_depths
from .loss_terms.hidden_pixels import HiddenPixelWeights
from .loss_terms.volume import VOLUME_LOSS_MODES
from .losses import LossConfig, LossTerms, RenderLoss

__all__ = ["Objective"]


class Objective:
    """``objective(batch, render, stage, volume_render)`` -> :class:`LossTerms` of one step.

    Args:
        config: the ``loss`` section.
        loss_fn: the render loss (its LPIPS network is loaded once, by the trainer).
        stages: the curriculum's stages (``train.stages``): stage 1 leaves hidden pixels to later volume stages
            under ``loss.pixel_stage_hidden=leave``.
    """

    def __init__(self, config: LossConfig, loss_fn: RenderLoss, stages: list[int] | tuple[int, ...]) -> None:
        self.config = config
        self.loss_fn = loss_fn
        self.pixel_weights = HiddenPixelWeights(config.occluded_weight, config.pixel_stage_hidden, stages)
        self.volume_loss = VOLUME_LOSS_MODES[config.volume_loss]

    def __call__(self, batch, render, stage: int, volume_render: Callable[[], object] | None = None) -> LossTerms:
        """``render``: the targets rendered from the model's Gaussians (``rgb``, ``depth``, ``alpha``);
        ``volume_render``: renders the volume branch's own Gaussians when asked (``None`` where the model outputs
        no fused set); it is called only when ``loss.volume_weight > 0``."""
        cfg = self.config
        reference = reference_depths(batch, cfg.depth_reference) if cfg.depth_l1 > 0 else None
        pixel_weight = self.pixel_weights(batch, stage)
        terms = self.loss_fn(render.rgb, render.depth, render.alpha, batch.target_images, reference,
                             pixel_weight=pixel_weight)
        weight = cfg.volume_weight
        if weight > 0 and volume_render is not None:
            # loss.volume_weight: the volume Gaussians rendered alone, before fusion, count too
            own = self.volume_loss(self.loss_fn, volume_render(), batch.target_images, reference, pixel_weight)
            parts = dict(terms.parts, volume_total=own.parts["total"],
                         total=terms.parts["total"] + weight * own.parts["total"])
            terms = LossTerms(terms.total + weight * own.total, parts)
        return terms
