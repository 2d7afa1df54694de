"""What the volume branch's own render (its Gaussians before fusion) is scored with, ``loss.volume_loss``, times
``loss.volume_weight``:

* ``scaled`` - the render loss itself (Eq. 7, with the same per-pixel weights);
* ``released`` - the authors' released code's stage-3 volume loss: 0.1 L2 + 0.005 LPIPS + 0.1 depth L1
  (``volume_weight=1`` gives exactly their weights).

A new mode is one function here and one entry in :data:`VOLUME_LOSS_MODES`.
"""

from __future__ import annotations

from typing import Callable

from torch import Tensor

__all__ = ["VOLUME_LOSS_MODES", "scaled", "released"]


def scaled(loss_fn, render, target: Tensor, reference: Tensor | None, pixel_weight: Tensor | None):
    return loss_fn(render.rgb, render.depth, render.alpha, target, reference, pixel_weight=pixel_weight)


def released(loss_fn, render, target: Tensor, reference: Tensor | None, pixel_weight: Tensor | None):
    return loss_fn.released_volume(render.rgb, render.depth, target, reference)


#: loss.volume_loss -> ``f(loss_fn, own render, target images, reference depth, pixel weights) -> LossTerms``
VOLUME_LOSS_MODES: dict[str, Callable] = {"scaled": scaled, "released": released}
