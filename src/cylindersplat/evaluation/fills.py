"""Trivial hole fills: what a method scores once the pixels it leaves uncovered get a cheap colour.

A method that leaves holes (the forward warp, a pixel-only model) loses dB against black that any fill
recovers; a component that claims to complete hidden space must beat the same method *with* a fill.
Two fills, each applied behind the render (``rgb + (1 - alpha) * fill``, the render's own colours and
depth unchanged):

* ``"mean"``: one colour, the latitude-weighted mean of the input panoramas (what a user could paint
  behind any render without looking at it);
* ``"inpaint"``: a 2-D harmonic (Laplace) inpaint of the pixels the render leaves uncovered
  (``alpha < 0.5``) from the colours of those it covers, on the image grid with the longitude wrapping
  around and no flux across the poles. Solved exactly (conjugate gradients on the 5-point Laplacian
  with the covered pixels as Dirichlet values; tested against a direct sparse solve).
"""

from __future__ import annotations

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..metrics.image import ws_weights
from ..render.api import RenderOutput

__all__ = ["FILLS", "FILL_DESCRIPTIONS", "mean_input_colour", "harmonic_inpaint", "fill_uncovered"]

FILL_DESCRIPTIONS = {
    "mean": "the inputs' mean colour",
    "inpaint": "a 2-D inpaint from the covered pixels",
}
FILLS = tuple(FILL_DESCRIPTIONS)
COVERED_ALPHA = 0.5  # a pixel the render covers at least this much is a known colour of the inpaint


def mean_input_colour(images: Float[Tensor, "V 3 H W"]) -> Float[Tensor, "3"]:
    """Mean colour of panoramas, each pixel weighted by its solid angle (the WS-PSNR row weight)."""
    weight = ws_weights(images.shape[-2], device=images.device).to(images.dtype)[:, None]
    return (images * weight).sum(dim=(0, 2, 3)) / (weight.sum() * images.shape[-1] * images.shape[0])


def _neighbour_sum(x: Tensor, interior_up: Tensor, interior_down: Tensor) -> Tensor:
    """Sum of the 4-neighbours of ``(..., H, W)``: longitude wraps, no neighbour beyond the top/bottom row."""
    up = torch.cat([torch.zeros_like(x[..., :1, :]), x[..., :-1, :]], dim=-2)
    down = torch.cat([x[..., 1:, :], torch.zeros_like(x[..., :1, :])], dim=-2)
    return x.roll(1, dims=-1) + x.roll(-1, dims=-1) + up * interior_up + down * interior_down


@torch.no_grad()
def harmonic_inpaint(image: Float[Tensor, "C H W"], known: Bool[Tensor, "H W"], tol: float = 1e-7,
                     max_iter: int = 5000) -> Float[Tensor, "C H W"]:
    """Fill the pixels outside ``known`` with the discrete harmonic interpolant of the known ones.

    Each unknown pixel equals the mean of its neighbours (4 of them; 3 on the top and bottom rows, whose
    outer neighbour does not exist), columns wrapping around; known pixels keep their values. Without
    any known pixel the image's mean is returned everywhere.
    """
    c, h, w = image.shape
    x_known = image.double() * known
    unknown = ~known
    if not unknown.any():
        return image.clone()
    if not known.any():
        return image.double().mean(dim=(-2, -1), keepdim=True).expand(c, h, w).to(image.dtype).clone()
    rows = torch.arange(h, device=image.device)[:, None]
    interior_up, interior_down = (rows > 0).double(), (rows < h - 1).double()
    degree = (2 + interior_up + interior_down).expand(h, w)
    mask = unknown.double()

    def apply(x):  # the Laplacian restricted to the unknown pixels (x is 0 on known ones)
        return (degree * x - _neighbour_sum(x, interior_up, interior_down)) * mask

    b = _neighbour_sum(x_known, interior_up, interior_down) * mask
    fill = (x_known.sum(dim=(-2, -1)) / known.sum()).view(c, 1, 1)
    x = fill * mask  # start at the known pixels' mean colour
    r = b - apply(x)
    p = r.clone()
    rr = (r * r).sum(dim=(-2, -1), keepdim=True)
    scale = (b * b).sum(dim=(-2, -1), keepdim=True).clamp(min=1e-30)
    for _ in range(max_iter):
        if bool((rr <= tol * tol * scale).all()):
            break
        ap = apply(p)
        step = rr / (p * ap).sum(dim=(-2, -1), keepdim=True).clamp(min=1e-300)
        x = x + step * p
        r = r - step * ap
        rr_new = (r * r).sum(dim=(-2, -1), keepdim=True)
        p = r + (rr_new / rr.clamp(min=1e-300)) * p
        rr = rr_new
    return (x_known + x * mask).to(image.dtype)


def fill_uncovered(render: RenderOutput, context_images: Float[Tensor, "V 3 H W"], fill: str) -> RenderOutput:
    """``render`` (rgb ``(T, 3, H, W)`` on a black background, alpha ``(T, H, W)``) with ``fill`` behind it."""
    if fill not in FILL_DESCRIPTIONS:
        raise ValueError(f"unknown fill {fill!r}; choose from {', '.join(FILLS)}")
    rgb, alpha = render.rgb, render.alpha.to(render.rgb.dtype)
    if fill == "mean":
        behind = mean_input_colour(context_images.to(rgb)).view(1, 3, 1, 1).expand_as(rgb)
    else:
        covered = alpha >= COVERED_ALPHA
        colour = rgb / alpha.clamp(min=1e-6)[:, None]  # the render's own colour where it covers the pixel
        behind = torch.stack([harmonic_inpaint(colour[t], covered[t]) for t in range(rgb.shape[0])])
    return RenderOutput(rgb + (1 - alpha)[:, None] * behind, render.depth, render.alpha)
