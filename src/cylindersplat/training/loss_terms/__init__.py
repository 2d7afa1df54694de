"""The training loss's terms, one module each; :class:`cylindersplat.training.losses.RenderLoss` weighs them
(Eq. 7) and :class:`cylindersplat.training.objective.Objective` composes the step's loss from them.

* :mod:`.photometric` - RGB L1 (optionally per-pixel weighted) and RGB L2;
* :mod:`.perceptual` - LPIPS;
* :mod:`.depth` - depth L1 against the reference depth (``loss.depth_reference``);
* :mod:`.hidden_pixels` - the per-pixel weights of pixels no context view sees (``loss.occluded_weight``,
  ``loss.pixel_stage_hidden``);
* :mod:`.volume` - what the volume branch's own render is scored with (``loss.volume_loss``).
"""
