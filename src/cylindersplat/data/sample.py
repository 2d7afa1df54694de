"""The one sample schema every dataset yields, and its batched collate."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields
from typing import Any

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["Sample", "collate_samples"]


@dataclass
class Sample:
    """One multi-view panoramic example (unbatched shapes; :func:`collate_samples` adds ``B``).

    Images are float in ``[0, 1]``; depths are radial distances in metres (0 = invalid); poses are
    OpenCV camera-to-world 4x4 (world +y gravity-down where the data is gravity-aligned).

    * ``context_images`` ``(V, 3, H, W)``, ``context_priors`` ``(V, H, W)``: the depth *prior* fed
      to the model (see :mod:`cylindersplat.data.depth_prior`; all zeros only for the prior ``none``),
      ``context_poses`` ``(V, 4, 4)``. (``context_depths``, its old name, still reads it, with a
      ``DeprecationWarning``.)
    * ``target_images`` ``(T, 3, H, W)``, ``target_depths`` ``(T, H, W)`` ground truth or ``None``,
      ``target_poses`` ``(T, 4, 4)``.
    * ``context_gt_depths``: ground-truth depth of the context views when the dataset has it.
    * ``target_reference_depths`` ``(T, H, W)`` or ``None``: the chosen reference depth of the
      targets (the depth loss's ``D_ref`` for ``loss.depth_reference`` = ``prior`` / ``file:NAME``,
      or the PCC reference of the evaluation); ``None`` unless the dataset was asked for one.
    * ``metadata``: ``dataset``, ``scene``, ``baseline`` (metres between the outermost contexts),
      ``context_indices``, ``target_indices`` and dataset-specific extras.
    """

    context_images: Float[Tensor, "V 3 H W"]
    context_priors: Float[Tensor, "V H W"]
    context_poses: Float[Tensor, "V 4 4"]
    target_images: Float[Tensor, "T 3 H W"]
    target_depths: Float[Tensor, "T H W"] | None
    target_poses: Float[Tensor, "T 4 4"]
    metadata: dict[str, Any] = field(default_factory=dict)
    context_gt_depths: Float[Tensor, "V H W"] | None = None
    target_reference_depths: Float[Tensor, "T H W"] | None = None

    def __post_init__(self) -> None:
        v, _, h, w = self.context_images.shape
        t = self.target_images.shape[0]
        checks = {
            "context_priors": (self.context_priors, (v, h, w)),
            "context_poses": (self.context_poses, (v, 4, 4)),
            "target_images": (self.target_images, (t, 3, h, w)),
            "target_depths": (self.target_depths, (t, h, w)),
            "target_poses": (self.target_poses, (t, 4, 4)),
            "context_gt_depths": (self.context_gt_depths, (v, h, w)),
            "target_reference_depths": (self.target_reference_depths, (t, h, w)),
        }
        if self.context_images.shape[1] != 3:
            raise ValueError(f"context_images must be (V, 3, H, W), got {tuple(self.context_images.shape)}")
        for name, (value, shape) in checks.items():
            if value is not None and tuple(value.shape) != shape:
                raise ValueError(f"Sample.{name} must have shape {shape}, got {tuple(value.shape)}")

    @property
    def context_depths(self) -> Tensor:
        """Deprecated name of :attr:`context_priors` (the depth prior, not ground truth; read-only)."""
        warnings.warn("Sample.context_depths is deprecated: it is the depth prior fed to the model, now named "
                      "Sample.context_priors (ground-truth depth of the contexts is Sample.context_gt_depths)",
                      DeprecationWarning, stacklevel=2)
        return self.context_priors

    @property
    def num_context(self) -> int:
        return self.context_images.shape[0]

    @property
    def num_target(self) -> int:
        return self.target_images.shape[0]

    def to(self, device) -> "Sample":
        """Copy with every tensor moved to ``device``."""
        moved = {f.name: getattr(self, f.name) for f in fields(self)}
        for key, value in moved.items():
            if isinstance(value, Tensor):
                moved[key] = value.to(device)
        return Sample(**moved)


def collate_samples(samples: list[Sample]) -> Sample:
    """Stack samples into a batched :class:`Sample` (tensors gain a leading ``B``).

    All samples must share V, T and the resolution. Optional tensors stay ``None`` unless every
    sample has them. ``metadata`` becomes a dict of lists. Note: the batched object skips the
    per-sample shape validation (its shapes have the extra ``B``).
    """
    if not samples:
        raise ValueError("collate_samples needs at least one sample")
    out: dict[str, Any] = {}
    for f in fields(Sample):
        values = [getattr(s, f.name) for s in samples]
        if f.name == "metadata":
            keys = dict.fromkeys(k for v in values for k in v)
            out[f.name] = {k: [v.get(k) for v in values] for k in keys}
        elif any(v is None for v in values):
            out[f.name] = None
        else:
            shapes = {tuple(v.shape) for v in values}
            if len(shapes) > 1:
                raise ValueError(f"cannot collate {f.name} of different shapes {sorted(shapes)}")
            out[f.name] = torch.stack(values)
    batch = object.__new__(Sample)
    batch.__dict__.update(out)
    return batch
