"""CylinderSplat network: pixel branch, cylindrical-triplane volume branch, fusion.

Typical use::

    from cylindersplat.model import from_config
    model = from_config("paper")               # or "tiny_paper", or a ModelConfig
    model.configure_stage(3)                   # curriculum: 1 pixel, 2 volume, 3 both
    out = model(images, depth_prior, c2w)      # (B, V, 3, H, W), (B, V, H, W), (B, V, 4, 4)
    out.gaussians                              # batched Gaussians (B, N, ...)
"""

from .checkpoint import load_model, save_model
from .config import (
    AttentionConfig,
    BackboneConfig,
    FusionConfig,
    ModelConfig,
    PixelBranchConfig,
    VolumeBranchConfig,
    get_config,
)
from .cylindersplat import CylinderSplat, ModelOutput, from_config

__all__ = [
    "CylinderSplat",
    "ModelOutput",
    "from_config",
    "get_config",
    "save_model",
    "load_model",
    "ModelConfig",
    "BackboneConfig",
    "AttentionConfig",
    "PixelBranchConfig",
    "VolumeBranchConfig",
    "FusionConfig",
]
