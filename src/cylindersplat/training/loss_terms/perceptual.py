"""The perceptual term: LPIPS between render and target (the network is built by
:class:`~cylindersplat.training.losses.RenderLoss`, which knows where its weights are)."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor, nn

__all__ = ["lpips_term"]


def lpips_term(net: nn.Module, rgb: Float[Tensor, "*B V 3 H W"], target: Float[Tensor, "*B V 3 H W"]) -> Tensor:
    """Mean LPIPS; the network expects ``(B, 3, H, W)``, so every leading dim is folded into the batch."""
    return net(rgb.flatten(0, -4), target.flatten(0, -4)).mean()
