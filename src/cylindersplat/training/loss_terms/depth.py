"""The depth term: L1 between rendered and reference radial depth, over pixels where the reference is valid."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

__all__ = ["depth_l1", "reference_depths"]


def depth_l1(depth: Float[Tensor, "*B V H W"], reference: Float[Tensor, "*B V H W"],
             alpha: Float[Tensor, "*B V H W"] | None = None, pixel_weight: Float[Tensor, "*B V H W"] | None = None,
             normalize: bool = False) -> Tensor:
    """Mean ``|depth - reference|`` over pixels with a reference (> 0) and, with ``pixel_weight``, a non-zero
    weight. ``normalize`` divides the (alpha-composited) rendered depth by ``alpha`` first."""
    valid = reference > 0
    if pixel_weight is not None:
        valid = valid & (pixel_weight > 0)
    rendered = depth / alpha.clamp_min(1e-4) if normalize else depth
    error = (rendered - reference).abs() * valid
    return error.sum() / valid.sum().clamp_min(1)


def reference_depths(batch, depth_reference: str) -> Tensor | None:
    """The depth loss's ``D_ref`` of a (batched) Sample for ``loss.depth_reference``; ``None`` for ``none``."""
    if depth_reference == "none":
        return None
    if depth_reference == "gt":
        depth, what = batch.target_depths, "ground-truth depth of the targets"
    else:
        depth, what = getattr(batch, "target_reference_depths", None), f"{depth_reference} reference depth"
    if depth is None:
        raise ValueError(f"loss.depth_reference={depth_reference}: this batch has no {what}; build the dataset with "
                         "cylindersplat.training.data.build_dataset(data, loss) (or choose loss.depth_reference=none)")
    return depth
