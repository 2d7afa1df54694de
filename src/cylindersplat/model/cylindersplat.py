"""The CylinderSplat model: pixel branch + volume branch + fusion, with curriculum switches.

``mode`` selects which Gaussians the model outputs (paper Sec. 3.3 curriculum):

* ``"pixel"`` (stage 1): pixel Gaussians only; the volume branch is not run.
* ``"volume"`` (stage 2): volume Gaussians only; the pixel branch still provides depth, F_pano
  and the feature cloud (run without autograd when all its parameters are frozen), but not its
  Gaussians.
* ``"both"`` (stage 3 and inference): fused ``G_pixel + G_volume``.

:meth:`CylinderSplat.configure_stage` sets the mode and the matching freezing in one call.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..gaussians import Gaussians
from ..render import FrontLayer
from .config import CHOICES, ModelConfig, get_config
from .curriculum import stage_policy
from .fusion import fuse
from .pixel_branch import PixelBranch
from .prior_alignment import ScaleMemo
from .volume_branch import VolumeBranch

__all__ = ["ModelOutput", "CylinderSplat", "from_config", "MODES"]

MODES = CHOICES["mode"]


@dataclass
class ModelOutput:
    gaussians: Gaussians  # what the current mode outputs, batched (B, N, ...)
    keep_mask: Tensor  # (B, N) False for Gaussians pruned by depth-guided fusion
    refined_depth: Float[Tensor, "B V H W"]
    features: Float[Tensor, "B V C H W"]  # F_pano
    pixel_gaussians: Gaussians | None  # (B, V*H*W, ...), view-major then row-major pixels
    volume_gaussians: Gaussians | None  # (B, V*G, ...) camera-major then (q0, q1, q2) cells; (B, G) central
    prior_scales: Tensor | None = None  # (B, V) factors applied to the depth priors (prior_alignment), else None


class CylinderSplat(nn.Module):
    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config.validate()
        self._prior_scales = ScaleMemo()  # each distinct input's depth scale searched once (training repeats them)
        self.pixel_branch = PixelBranch(config)
        self.volume_branch = VolumeBranch(config)
        self.mode = config.mode

    # -- curriculum ---------------------------------------------------------------------------
    @property
    def mode(self) -> str:
        return self._mode

    @mode.setter
    def mode(self, value: str) -> None:
        if value not in MODES:
            raise ValueError(f"unknown branch mode {value!r}; expected one of {MODES}")
        self._mode = value

    def set_mode(self, mode: str) -> "CylinderSplat":
        self.mode = mode
        return self

    def _set_trainable(self, module: nn.Module, trainable: bool) -> "CylinderSplat":
        for p in module.parameters():
            p.requires_grad_(trainable)
        return self

    def configure_stage(self, stage: int, stage2_render: str = "volume") -> "CylinderSplat":
        """Mode and freezing of curriculum stage 1 (pixel only), 2 (volume, pixel frozen; rendered alone or, with
        ``stage2_render="fused"``, over the frozen pixel Gaussians) or 3 (joint): :func:`~.curriculum.stage_policy`."""
        policy = stage_policy(stage, stage2_render)
        self.set_mode(policy.mode)
        self._set_trainable(self.pixel_branch, policy.train_pixel)
        return self._set_trainable(self.volume_branch, policy.train_volume)

    def with_config(self, **changes) -> "CylinderSplat":
        """The same weights under this config with fields replaced (:meth:`ModelConfig.replace`, dotted keys): the
        switches that keep every parameter's shape, e.g. ``render_dilation`` or ``**{"pixel.footprint": "pixel"}``;
        a change of shape raises ``ValueError``."""
        model = CylinderSplat(self.config.replace(**changes)).to(next(self.parameters()).device)
        try:
            model.load_state_dict(self.state_dict())
        except RuntimeError as error:
            raise ValueError(f"config changes {sorted(changes)} change the model's parameters: {error}") from None
        return model.set_mode(self.mode).train(self.training)

    def branch_parameters(self, branch: str) -> list[nn.Parameter]:
        return list({"pixel": self.pixel_branch, "volume": self.volume_branch}[branch].parameters())

    def parameter_counts(self) -> dict[str, int]:
        count = lambda m: sum(p.numel() for p in m.parameters())  # noqa: E731
        pb = self.pixel_branch
        return {
            "backbone": count(pb.backbone),
            "attention": count(pb.attention) + count(pb.to_tokens) + count(pb.ray_embedding),
            "decoder": count(pb.decoder) + count(pb.full_res) + count(pb.out),
            "pixel_head": count(pb.gaussian_head),
            "volume_branch": count(self.volume_branch),
            "total": count(self),
        }

    # -- forward ------------------------------------------------------------------------------
    def forward(
        self,
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
    ) -> ModelOutput:
        if images.ndim != 5 or images.shape[2] != 3:
            raise ValueError(f"images must be (B, V, 3, H, W), got {tuple(images.shape)}")
        b, v, _, h, w = images.shape
        if depth_prior.shape != (b, v, h, w) or c2w.shape != (b, v, 4, 4):
            raise ValueError(
                f"depth_prior must be {(b, v, h, w)} and c2w {(b, v, 4, 4)}, "
                f"got {tuple(depth_prior.shape)} and {tuple(c2w.shape)}"
            )
        c2w = c2w.to(images.dtype)
        prior_scales = None
        if self.config.prior_alignment == "photometric":
            prior_scales = self._prior_scales(images, depth_prior, c2w)
            depth_prior = depth_prior * prior_scales[..., None, None]
        frozen = not any(p.requires_grad for p in self.pixel_branch.parameters())
        no_grad = torch.no_grad() if self.mode == "volume" and frozen else contextlib.nullcontext()
        with no_grad:
            pixel_out = self.pixel_branch(images, depth_prior, c2w, predict_gaussians=self.mode != "volume")

        pixel = pixel_out.gaussians
        volume = None
        if self.mode != "pixel":
            volume = self.volume_branch(
                images, depth_prior, c2w, pixel_out.features, pixel_out.points_world, pixel_out.point_features
            )
        fused, keep = fuse(pixel, volume, pixel_out.refined_depth, c2w, self.config.fusion)
        return ModelOutput(
            gaussians=fused,
            keep_mask=keep,
            refined_depth=pixel_out.refined_depth,
            features=pixel_out.features,
            pixel_gaussians=pixel,
            volume_gaussians=None if volume is None else volume.gaussians,
            prior_scales=prior_scales,
        )

    def front_layer(self, out: ModelOutput) -> FrontLayer | None:
        """How ``out.gaussians`` are drawn, as the model's config says (``render_layering``,
        ``render_pixel_blending``): the leading pixel Gaussians as a front layer
        (:func:`~cylindersplat.render.layered.render_layered`), or ``None`` for one depth-sorted pass. A pixel-only
        output is all one blended layer under ``render_pixel_blending="surface"``."""
        opaque = self.config.render_layering == "pixel_over_volume"
        blend = self.config.render_pixel_blending == "surface"
        if (opaque or blend) and out.pixel_gaussians is not None and out.volume_gaussians is not None:
            return FrontLayer(out.pixel_gaussians.num_gaussians, blend=blend, opaque=opaque)  # fused: pixel first
        if blend and out.volume_gaussians is None and out.pixel_gaussians is not None:
            return FrontLayer(out.gaussians.num_gaussians, blend=True)
        return None


def from_config(config: ModelConfig | str = "paper", **changes) -> CylinderSplat:
    """Build a model from a :class:`ModelConfig` or a preset name (with optional field changes)."""
    if isinstance(config, str):
        config = get_config(config, **changes)
    elif changes:
        config = config.replace(**changes)
    return CylinderSplat(config)
