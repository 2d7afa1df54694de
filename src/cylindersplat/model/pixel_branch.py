"""Pixel branch (paper Sec. 3.1): ResNet + alternating attention -> refined depth, F_pano, Gaussians.

Pipeline for ``V`` posed views ``(B, V, 3, H, W)`` with depth priors ``(B, V, H, W)``:

1. :func:`encode_inputs` - RGB, normalised log prior depth and a prior-valid mask (5 channels);
2. :class:`~.backbone.ResNetBackbone` - multi-scale features; the coarsest map (stride 16 by
   default) becomes the tokens;
3. :class:`RayEmbedding` - each token gets an embedding of its viewing ray *relative to the first
   view* (Fourier features of the direction + Pluecker moment). It is the only place where poses
   enter the attention, tells global attention where each view is, depends on no fixed ``V``,
   and is continuous across the panorama seam;
4. :class:`~.attention.AlternatingAttention` - L blocks of frame / global attention;
5. :class:`PanoDecoder` - DPT-style: the outputs of all global blocks are concatenated and
   upsampled with the ResNet skips (U-Net style) back to full resolution; predicts a bounded
   log-depth residual (``D = prior * exp(m * tanh(.))``) and F_pano;
6. unprojection along the equirect rays -> feature point cloud, and per-pixel Gaussians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from ..gaussians import Gaussians
from ..geometry import camera_to_world, equirect_rays, invert_rigid
from ..geometry.rotations import matrix_to_quaternion, quaternion_multiply
from .attention import AlternatingAttention, Mlp
from .backbone import ConvNormAct, PanoConv2d, ResNetBackbone, pano_pad
from .config import ModelConfig
from .gaussian_heads import PixelGaussianHead

__all__ = ["PixelBranchOutput", "depth_edge_confidence", "fill_depth_prior", "encode_inputs", "RayEmbedding",
           "PanoDecoder", "PixelBranch"]


def depth_edge_confidence(depth: Float[Tensor, "N H W"], sigma: float) -> Float[Tensor, "N H W"]:
    """``exp(-g^2 / (2 sigma^2))`` with ``g`` the largest ``|log d - log d_n|`` over the 8 neighbours
    (columns wrap around the seam; the top and bottom rows compare with themselves).

    A depth map that is smooth across an occlusion boundary puts pixels between the foreground and
    the background; their Gaussians, seen from another viewpoint, string across the disoccluded
    region. This factor fades exactly them (flat or slanted surfaces have small steps)."""
    log_depth = depth.clamp_min(1e-6).log()[:, None]
    padded = F.pad(F.pad(log_depth, (1, 1, 0, 0), mode="circular"), (0, 0, 1, 1), mode="replicate")
    h, w = depth.shape[-2:]
    step = torch.zeros_like(log_depth)
    for dy in range(3):
        for dx in range(3):
            step = torch.maximum(step, (padded[..., dy : dy + h, dx : dx + w] - log_depth).abs())
    return torch.exp(-0.5 * (step[:, 0] / sigma) ** 2)


def fill_depth_prior(prior: Float[Tensor, "N H W"], min_depth: float) -> tuple[Tensor, Tensor]:
    """Replace invalid prior pixels (<= 0 or non-finite) by the view's median valid depth.

    Returns ``(filled depth >= min_depth, valid mask)``.
    """
    valid = torch.isfinite(prior) & (prior > 0)
    masked = torch.where(valid, prior, torch.full_like(prior, float("nan")))
    median = torch.nanmedian(masked.flatten(1), dim=1).values.nan_to_num(min_depth)
    filled = torch.where(valid, prior, median[:, None, None].expand_as(prior))
    return filled.clamp_min(min_depth), valid


def encode_inputs(images: Float[Tensor, "N 3 H W"], depth: Float[Tensor, "N H W"], valid: Tensor) -> Tensor:
    """Network input: RGB in [-1, 1], log depth (m), valid mask -> ``(N, 5, H, W)``."""
    return torch.cat((images * 2 - 1, torch.log(depth)[:, None], valid[:, None].to(images.dtype)), dim=1)


def pano_upsample2x(x: Tensor) -> Tensor:
    """Bilinear 2x upsampling that interpolates across the panorama seam (circular in W)."""
    up = F.interpolate(pano_pad(x, 1), scale_factor=2, mode="bilinear", align_corners=False)
    return up[..., 2:-2, 2:-2]


class RayEmbedding(nn.Module):
    """Embed the token rays of every view, expressed in the first view's camera frame."""

    def __init__(self, dim: int, frequencies: int):
        super().__init__()
        self.frequencies = frequencies
        in_dim = 3 + 6 * frequencies + 3
        self.mlp = Mlp(in_dim, dim, dim)

    def forward(self, c2w: Float[Tensor, "B V 4 4"], height: int, width: int) -> Float[Tensor, "B V T D"]:
        # poses relative to view 0: the embedding is invariant to the choice of world frame
        rel = invert_rigid(c2w[:, :1]) @ c2w  # (B, V, 4, 4)
        rays = equirect_rays(height, width, device=c2w.device, dtype=c2w.dtype).reshape(1, 1, -1, 3)
        directions = rays @ rel[..., :3, :3].transpose(-1, -2)  # (B, V, T, 3)
        origins = rel[..., None, :3, 3].expand_as(directions)
        moment = torch.cross(origins, directions, dim=-1)
        scales = (2.0 ** torch.arange(self.frequencies, device=c2w.device, dtype=c2w.dtype)) * math.pi
        angles = (directions[..., None] * scales).flatten(-2)
        features = torch.cat((directions, torch.sin(angles), torch.cos(angles), moment), dim=-1)
        return self.mlp(features)


class PanoDecoder(nn.Module):
    """Upsample tokens to full resolution with skip connections (coarse to fine).

    Step ``k`` doubles the resolution, convolves, adds a 1x1 projection of the skip feature of
    that stride, and refines with a conv-norm-act.
    """

    def __init__(self, token_dim: int, skip_channels: list[int], widths: tuple[int, ...], groups: int):
        super().__init__()
        if len(widths) != len(skip_channels):
            raise ValueError(f"need one decoder width per upsampling step ({len(skip_channels)}), got {len(widths)}")
        self.inp = nn.Conv2d(token_dim, widths[0], 1)
        prev = widths[0]
        self.ups, self.skips, self.refines = nn.ModuleList(), nn.ModuleList(), nn.ModuleList()
        for width, skip in zip(widths, skip_channels):
            self.ups.append(PanoConv2d(prev, width, 3))
            self.skips.append(nn.Conv2d(skip, width, 1))
            self.refines.append(ConvNormAct(width, width, 3, groups=groups))
            prev = width

    def forward(self, tokens: Float[Tensor, "N D h w"], skips: list[Tensor]) -> Tensor:
        x = self.inp(tokens)
        for up, skip_proj, refine, skip in zip(self.ups, self.skips, self.refines, skips):
            x = up(pano_upsample2x(x)) + skip_proj(skip)
            x = refine(x)
        return x


@dataclass
class PixelBranchOutput:
    refined_depth: Float[Tensor, "B V H W"]
    features: Float[Tensor, "B V C H W"]  # F_pano
    points_world: Float[Tensor, "B V HW 3"]  # feature point cloud P_feat (world frame)
    point_features: Float[Tensor, "B V HW C"]
    gaussians: Gaussians | None  # (B, V*H*W, ...) world frame, view-major then row-major pixels; None if not asked


class PixelBranch(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg.pixel
        bb, att = cfg.backbone, cfg.attention
        self.backbone = ResNetBackbone(bb)
        self.to_tokens = nn.Linear(bb.widths[-1], att.dim)
        self.ray_embedding = RayEmbedding(att.dim, att.ray_frequencies)
        self.attention = AlternatingAttention(att)
        # skips coarse-to-fine: backbone features below the token map, then a full-res input conv
        skip_channels = list(reversed(self.backbone.out_channels[:-1])) + [cfg.pixel.decoder_widths[-1]]
        self.full_res = ConvNormAct(bb.in_channels, cfg.pixel.decoder_widths[-1], 3, groups=bb.groups)
        token_channels = att.dim * self.attention.num_outputs()
        self.decoder = PanoDecoder(token_channels, skip_channels, cfg.pixel.decoder_widths, bb.groups)
        self.out = PanoConv2d(cfg.pixel.decoder_widths[-1], 1 + cfg.pixel.feature_dim, 3)
        self.gaussian_head = PixelGaussianHead(cfg.pixel.feature_dim, cfg.pixel.head_hidden, cfg.pixel.scale_range,
                                               cfg.pixel.footprint, cfg.pixel.footprint_px, cfg.pixel.opacity)
        self.token_stride = bb.token_stride

    def forward(
        self,
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
        predict_gaussians: bool = True,
    ) -> PixelBranchOutput:
        b, v, _, h, w = images.shape
        if h % self.token_stride or w % self.token_stride:
            raise ValueError(f"image size {h}x{w} must be divisible by the token stride {self.token_stride}")
        flat_images = images.reshape(b * v, 3, h, w)
        prior, valid = fill_depth_prior(depth_prior.reshape(b * v, h, w), self.cfg.min_depth)
        x = encode_inputs(flat_images, prior, valid)
        feats = self.backbone(x)
        token_map = feats[-1]
        th, tw = token_map.shape[-2:]
        tokens = self.to_tokens(token_map.flatten(2).transpose(1, 2)).view(b, v, th * tw, -1)
        layers = self.attention(tokens + self.ray_embedding(c2w, th, tw))
        token_map = torch.cat(layers, dim=-1).reshape(b * v, th, tw, -1).permute(0, 3, 1, 2)
        skips = list(reversed(feats[:-1])) + [self.full_res(x)]
        out = self.out(self.decoder(token_map, skips))
        log_offset = self.cfg.max_log_depth_offset * torch.tanh(out[:, 0])
        if self.cfg.refine_depth == "where_missing":  # measured depth is kept; only the prior's holes are inferred
            log_offset = log_offset * (~valid).to(log_offset.dtype)
        depth = prior * torch.exp(log_offset)  # (BV, H, W)
        features = out[:, 1:]

        rays = equirect_rays(h, w, device=images.device, dtype=images.dtype).reshape(1, h * w, 3)
        points_cam = rays * depth.reshape(b * v, h * w, 1)
        points_world = camera_to_world(points_cam.view(b, v, h * w, 3), c2w)
        point_features = features.flatten(2).transpose(1, 2).reshape(b, v, h * w, -1)
        gaussians = None
        if predict_gaussians:
            params = self.gaussian_head(features, flat_images, depth)
            if self.cfg.edge_sigma > 0:  # fade flying pixels at depth discontinuities (config docstring)
                edge = depth_edge_confidence(depth.detach(), self.cfg.edge_sigma)
                params["opacities"] = params["opacities"] * edge.flatten(1)
            gaussians = self._world_gaussians(params, points_world, c2w)
        return PixelBranchOutput(
            refined_depth=depth.view(b, v, h, w),
            features=features.view(b, v, -1, h, w),
            points_world=points_world,
            point_features=point_features,
            gaussians=gaussians,
        )

    @staticmethod
    def _world_gaussians(params: dict[str, Tensor], points_world: Float[Tensor, "B V HW 3"], c2w: Tensor) -> Gaussians:
        """The head's per-pixel camera-frame parameters ``(B*V, HW, .)`` as world-frame Gaussians ``(B, V*HW, .)``."""
        b, v, n = points_world.shape[:3]
        params = {k: t.reshape(b, v, n, -1) for k, t in params.items()}
        camera_rotation = matrix_to_quaternion(c2w[..., :3, :3])[:, :, None]
        rotations = quaternion_multiply(camera_rotation, params["rotations"])
        return Gaussians.from_rgb(
            points_world.flatten(1, 2),
            params["scales"].flatten(1, 2),
            rotations.flatten(1, 2),
            params["opacities"].squeeze(-1).flatten(1, 2),
            params["colors"].flatten(1, 2),
        )
