"""Simulated depth prior: ground truth degraded like a monocular network's output.

Applied in this order, all reproducible from ``(seed, query key)``:

1. a per-image global scale error ``exp(N(0, scale_sigma))`` (monocular scale ambiguity);
2. a Gaussian blur of ``blur_sigma`` pixels (rows; columns wrap around the 360-degree seam)
   computed on valid pixels only (normalised convolution), which smears depth edges;
3. multiplicative per-pixel noise ``1 + N(0, noise_sigma)``;
4. holes: ``hole_fraction`` of the pixels, as random discs, set to 0 (unknown);
   invalid ground truth stays 0.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from .base import DepthPrior, PriorQuery

__all__ = ["SimulatedPriorConfig", "SimulatedPrior", "degrade_depth"]


@dataclass(frozen=True)
class SimulatedPriorConfig:
    scale_sigma: float = 0.1  # std of the log global scale error
    blur_sigma: float = 1.5  # Gaussian blur, pixels at the output resolution
    noise_sigma: float = 0.02  # relative per-pixel noise
    hole_fraction: float = 0.02  # approximate share of pixels dropped, in discs
    hole_radius: float = 0.02  # disc radius as a fraction of the image height


def _gaussian_blur_wrap(x: Tensor, valid: Tensor, sigma: float) -> Tensor:
    if sigma <= 0:
        return x
    radius = max(1, int(3 * sigma + 0.5))
    k = torch.exp(-0.5 * (torch.arange(-radius, radius + 1, dtype=x.dtype) / sigma) ** 2)
    k = k / k.sum()

    def blur(img):  # img (1, 1, H, W): circular along W, replicate along H
        img = F.pad(img, (radius, radius, 0, 0), mode="circular")
        img = F.pad(img, (0, 0, radius, radius), mode="replicate")
        img = F.conv2d(img, k.view(1, 1, -1, 1))
        return F.conv2d(img, k.view(1, 1, 1, -1))

    w = valid.to(x.dtype)[None, None]
    num = blur((x * valid)[None, None])
    den = blur(w)
    return torch.where(den > 1e-6, num / den.clamp(min=1e-6), torch.zeros_like(num))[0, 0]


def degrade_depth(depth: Tensor, cfg: SimulatedPriorConfig, generator: torch.Generator) -> Tensor:
    """Degrade one ``(H, W)`` depth map; see the module docstring."""
    h, w = depth.shape
    valid = depth > 0
    out = depth * torch.exp(torch.randn((), generator=generator) * cfg.scale_sigma)
    out = _gaussian_blur_wrap(out, valid, cfg.blur_sigma)
    out = out * (1 + cfg.noise_sigma * torch.randn(h, w, generator=generator))
    radius = max(1.0, cfg.hole_radius * h)
    holes = int(round(cfg.hole_fraction * h * w / (torch.pi * radius**2)))
    if holes > 0:
        centres = torch.rand(holes, 2, generator=generator) * torch.tensor([h, w])
        rows = torch.arange(h)[:, None, None] + 0.5
        cols = torch.arange(w)[None, :, None] + 0.5
        dc = (cols - centres[:, 1]).abs()
        dc = torch.minimum(dc, w - dc)  # wrap-around distance
        hit = ((rows - centres[:, 0]) ** 2 + dc**2 <= radius**2).any(-1)
        out = torch.where(hit, torch.zeros_like(out), out)
    return torch.where(valid, out.clamp(min=0), torch.zeros_like(out))


class SimulatedPrior(DepthPrior):
    """Seeded degraded ground truth (needs ``gt_depth``); the same key always gives the same prior."""

    name = "simulated"

    def __init__(self, config: SimulatedPriorConfig = SimulatedPriorConfig(), seed: int = 0) -> None:
        self.config = config
        self.seed = seed

    @staticmethod
    def spec_arguments(text: str) -> dict:
        """Keyword arguments from a spec's value: ``SEED`` or ``key=value[,key=value...]`` with keys ``seed``
        and the :class:`SimulatedPriorConfig` fields (``simulated:blur_sigma=0.5``,
        ``simulated:seed=2,noise_sigma=0``)."""
        if "=" not in text:
            return {"seed": int(text)}
        fields = {f.name for f in dataclasses.fields(SimulatedPriorConfig)}
        seed, changes = 0, {}
        for item in text.split(","):
            key, _, value = item.partition("=")
            key = key.strip()
            if key not in fields | {"seed"}:
                raise ValueError(f"simulated prior: unknown setting {key!r}; "
                                 f"choose from seed, {', '.join(sorted(fields))}")
            try:
                number = float(value)
            except ValueError:
                raise ValueError(f"simulated prior: {key}={value!r} is not a number") from None
            if key == "seed":
                seed = int(number)
            elif not number >= 0:  # also refuses nan
                raise ValueError(f"simulated prior: {key} must be >= 0, got {value!r}")
            else:
                changes[key] = number
        return {"seed": seed, "config": SimulatedPriorConfig(**changes)}

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.gt_depth is None:
            raise ValueError(f"{query.key}: the simulated depth prior needs ground-truth depth")
        digest = hashlib.sha256(f"{self.seed}:{query.key}".encode()).digest()
        generator = torch.Generator().manual_seed(int.from_bytes(digest[:8], "little") & (2**63 - 1))
        return degrade_depth(query.gt_depth.float(), self.config, generator)
