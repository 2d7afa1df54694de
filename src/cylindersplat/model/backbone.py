"""ResNet feature extractor for equirectangular panoramas (plain torch, no torchvision).

Every convolution pads the panorama *circularly* along its width (longitude wraps at the seam)
and with zeros along its height, so features are continuous across ``u = 0 = W``.
Normalisation is GroupNorm: feed-forward batches are 1-2 scenes, too few for batch statistics.
"""

from __future__ import annotations

import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from .config import BackboneConfig

__all__ = ["pano_pad", "PanoConv2d", "ConvNormAct", "BasicBlock", "ResNetBackbone"]


def pano_pad(x: Tensor, pad: int) -> Tensor:
    """Pad ``(..., H, W)`` by ``pad``: circular along W, zeros along H."""
    if pad == 0:
        return x
    x = F.pad(x, (pad, pad, 0, 0), mode="circular")
    return F.pad(x, (0, 0, pad, pad))


class PanoConv2d(nn.Conv2d):
    """``nn.Conv2d`` with "same" panoramic padding (odd kernels)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3, stride: int = 1, bias: bool = True):
        super().__init__(in_channels, out_channels, kernel_size, stride=stride, padding=0, bias=bias)
        self.pano_padding = kernel_size // 2

    def forward(self, x: Tensor) -> Tensor:
        return super().forward(pano_pad(x, self.pano_padding))


def _norm(channels: int, groups: int) -> nn.GroupNorm:
    g = groups
    while channels % g:
        g -= 1
    return nn.GroupNorm(g, channels)


class ConvNormAct(nn.Sequential):
    def __init__(self, cin: int, cout: int, kernel_size: int = 3, stride: int = 1, groups: int = 8):
        super().__init__(
            PanoConv2d(cin, cout, kernel_size, stride, bias=False), _norm(cout, groups), nn.ReLU(inplace=True)
        )


class BasicBlock(nn.Module):
    """ResNet basic block (two 3x3 convs + identity / 1x1 projection shortcut)."""

    def __init__(self, cin: int, cout: int, stride: int, groups: int):
        super().__init__()
        self.conv1 = PanoConv2d(cin, cout, 3, stride, bias=False)
        self.norm1 = _norm(cout, groups)
        self.conv2 = PanoConv2d(cout, cout, 3, 1, bias=False)
        self.norm2 = _norm(cout, groups)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or cin != cout:
            self.shortcut = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), _norm(cout, groups))

    def forward(self, x: Tensor) -> Tensor:
        out = F.relu(self.norm1(self.conv1(x)), inplace=True)
        out = self.norm2(self.conv2(out))
        return F.relu(out + self.shortcut(x), inplace=True)


class ResNetBackbone(nn.Module):
    """Stem (7x7/2 conv + 3x3/2 max-pool) and stages of BasicBlocks.

    ``forward`` returns the multi-scale features, finest first:
    ``[stem (stride 2), stage 0 (stride 4), stage 1 (stride 8), ...]``; the last one is the
    token map of stride :attr:`BackboneConfig.token_stride`.
    """

    def __init__(self, cfg: BackboneConfig):
        super().__init__()
        self.stem = nn.Sequential(
            PanoConv2d(cfg.in_channels, cfg.stem_width, 7, stride=2, bias=False),
            _norm(cfg.stem_width, cfg.groups),
            nn.ReLU(inplace=True),
        )
        stages = []
        cin = cfg.stem_width
        for index, (width, count) in enumerate(zip(cfg.widths, cfg.blocks)):
            stride = 1 if index == 0 else 2
            blocks = [BasicBlock(cin, width, stride, cfg.groups)]
            blocks += [BasicBlock(width, width, 1, cfg.groups) for _ in range(count - 1)]
            stages.append(nn.Sequential(*blocks))
            cin = width
        self.stages = nn.ModuleList(stages)
        self.out_channels = [cfg.stem_width, *cfg.widths]

    def forward(self, x: Float[Tensor, "N C H W"]) -> list[Tensor]:
        stem = self.stem(x)
        out = F.max_pool2d(pano_pad(stem, 1), 3, stride=2)
        features = [stem]
        for stage in self.stages:
            out = stage(out)
            features.append(out)
        return features
