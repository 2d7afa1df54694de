"""Named, seeded degradations of ground-truth depth: priors like the ones users have (``degraded:KIND``).

Evaluation reads every table twice (DESIGN.md, section 5): with the true depth, what scanner users have, and with
a prior like a monocular network's, what most users have. ``--depth-prior degraded:KIND`` gives every method
(the model and the forward warp alike) the same degraded depth. Sizes are angular, so a kind means the same at
64x128 and at 512x1024. Kinds (``degraded:KIND`` or ``degraded:KIND,seed=N``; seed 0 by default):

* ``noise``: multiplicative per-pixel noise ``1 + N(0, 0.05)``;
* ``edge_blur``: a Gaussian blur of 0.6 % of the panorama's height (3 px at 512 rows) on valid pixels, which
  smears depth across occlusion edges, as networks do;
* ``scale``: one global scale error of 30 % per view, ``x1.3`` or ``/1.3`` by a seeded coin;
* ``mono``: a monocular network's mix: a global scale error ``exp(N(0, 0.15))`` per view, the ``edge_blur``
  blur, a smooth low-frequency bias of a few percent (planes bent: ``exp(0.05 * f)`` with ``f`` a random
  combination of the first spherical harmonics of the viewing direction), and 1 % noise.

Every kind keeps invalid (0) ground truth at 0 and is reproducible from ``(kind, seed, query key)``.
"""

from __future__ import annotations

import hashlib
import math

import torch
from torch import Tensor

from ...geometry import equirect_rays
from .base import DepthPrior, PriorQuery
from .simulated import _gaussian_blur_wrap

__all__ = ["DEGRADATIONS", "DegradedPrior", "degrade"]

DEGRADATIONS = {
    "noise": "per-pixel noise of 5 %",
    "edge_blur": "blur across depth edges (0.6 % of the height)",
    "scale": "a 30 % global scale error per view",
    "mono": "monocular-style: scale error, edge blur, low-frequency bias, 1 % noise",
}
BLUR_FRACTION = 0.006  # blur std-dev as a share of the panorama's height
SCALE_ERROR = 1.3


def _low_frequency_field(h: int, w: int, generator: torch.Generator) -> Tensor:
    """A smooth field on the sphere in about [-1, 1]: random weights on the degree-1 and degree-2 real spherical
    harmonics of the viewing direction (continuous across the seam and at the poles)."""
    x, y, z = equirect_rays(h, w, dtype=torch.float64).unbind(-1)
    basis = torch.stack([x, y, z, x * y, y * z, x * z, 3 * y * y - 1, x * x - z * z])
    weights = torch.randn(len(basis), generator=generator, dtype=torch.float64)
    field = (weights[:, None, None] * basis).sum(0)
    return (field / field.abs().max().clamp_min(1e-9)).float()


def degrade(depth: Tensor, kind: str, generator: torch.Generator) -> Tensor:
    """Degrade one ``(H, W)`` depth map (0 = invalid, kept) as ``kind`` (:data:`DEGRADATIONS`)."""
    if kind not in DEGRADATIONS:
        raise ValueError(f"unknown depth degradation {kind!r}; choose from {', '.join(DEGRADATIONS)}")
    h, w = depth.shape
    valid = depth > 0
    blur = BLUR_FRACTION * h
    out = depth.float()
    if kind == "noise":
        out = out * (1 + 0.05 * torch.randn(h, w, generator=generator))
    elif kind == "edge_blur":
        out = _gaussian_blur_wrap(out, valid, blur)
    elif kind == "scale":
        out = out * (SCALE_ERROR if torch.rand((), generator=generator) < 0.5 else 1 / SCALE_ERROR)
    else:  # mono
        out = out * math.exp(0.15 * float(torch.randn((), generator=generator)))
        out = _gaussian_blur_wrap(out, valid, blur)
        out = out * torch.exp(0.05 * _low_frequency_field(h, w, generator))
        out = out * (1 + 0.01 * torch.randn(h, w, generator=generator))
    return torch.where(valid, out.clamp_min(1e-3), torch.zeros_like(out))


def seed_setting(text: str, prior: str) -> int:
    """The seed of a spec's optional ``seed=N`` tail (``""``: 0); anything else is a one-line ``ValueError``."""
    if not text:
        return 0
    key, _, value = text.partition("=")
    if key.strip() != "seed":
        raise ValueError(f"{prior}: unknown setting {key.strip()!r}; only seed=N")
    try:
        return int(value)
    except ValueError:
        raise ValueError(f"{prior}: seed={value!r} is not an integer") from None


class DegradedPrior(DepthPrior):
    """Ground truth degraded by a named kind (:data:`DEGRADATIONS`), seeded per view; needs ``gt_depth``."""

    name = "degraded"

    def __init__(self, kind: str = "mono", seed: int = 0) -> None:
        if kind not in DEGRADATIONS:
            raise ValueError(f"unknown depth degradation {kind!r}; choose from {', '.join(DEGRADATIONS)} "
                             "(degraded:KIND or degraded:KIND,seed=N)")
        self.kind, self.seed = kind, int(seed)

    @staticmethod
    def spec_arguments(text: str) -> dict:
        """``KIND`` or ``KIND,seed=N`` -> keyword arguments."""
        kind, _, rest = text.partition(",")
        return {"kind": kind.strip(), "seed": seed_setting(rest, "degraded prior")}

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.gt_depth is None:
            raise ValueError(f"{query.key}: the degraded depth prior needs ground-truth depth")
        digest = hashlib.sha256(f"degraded:{self.kind}:{self.seed}:{query.key}".encode()).digest()
        generator = torch.Generator().manual_seed(int.from_bytes(digest[:8], "little") & (2**63 - 1))
        return degrade(query.gt_depth, self.kind, generator)
