"""Visibility-aware RGB retrieval for volume Gaussians (paper Eq. 6).

Every Gaussian centre is projected into all ``V`` input panoramas; the colour ``C_v`` and the
depth prior ``d_o`` are read there (bilinear, wrapping in ``u``). The visibility score is
``s_v = d_g - d_o`` with ``d_g`` the radial distance to camera ``v``; ``w = softmax_v(-s_v / T)``
(``T = 1`` m is the paper). A view whose prior surface lies in front of the Gaussian
(occluded, ``s_v >> 0``) gets a small weight; an invalid prior (0) counts as "occluded by
``d_g``". An MLP maps ``sum_v w_v C_v`` (and a per-Gaussian feature from the triplane, our
addition so the colour can depend on the Gaussian) to the final colour, as a logit-space
residual on the retrieved colour so that it starts at the retrieval itself.

``window > 0`` (``volume.retrieval_window``, our extension; 0 is Eq. 6): every view is read at the
``(2 window + 1)^2`` pixels around the projection, each read lifted to its observed surface point
``d_o * ray``, and ``w = softmax_{v, k}(-|p_g - d_o ray_k| / T)`` over views and taps: the colour of
the *observed surface points nearest the Gaussian*. For a Gaussian behind an occluder in every view
the nearest observed points are the hidden surface's visible continuation beside the occluder (Eq. 6
returns the occluder's colour there); for a Gaussian on a seen surface the centre tap is nearest.

:class:`DecodedColor` is the ``volume.color="decoded"`` ablation (Table "Ablation Study", row
"Only Cylindrical Volume Branch (w/o RGB)", OmniScene's colour): the colour is decoded from the
triplane alone, ``sigmoid(MLP(color_feature))``, without reading the input images.
"""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..geometry import project_equirect, uv_to_ray, world_to_camera
from .sampling import sample_panorama

__all__ = ["project_to_views", "visibility_weights", "retrieve_colors", "retrieve_colors_window", "RGBRetrieval",
           "DecodedColor"]


def project_to_views(
    points_world: Float[Tensor, "B N 3"], c2w: Float[Tensor, "B V 4 4"], height: int, width: int
) -> tuple[Float[Tensor, "B V N 2"], Float[Tensor, "B V N"]]:
    """Pixel coordinates and radial distances of world points in every view."""
    points_cam = world_to_camera(points_world[:, None], c2w)  # (B, V, N, 3)
    return project_equirect(points_cam, height, width)


def visibility_weights(
    distances: Float[Tensor, "B V N"], prior_depth: Float[Tensor, "B V N"], temperature: float = 1.0
) -> Float[Tensor, "B V N"]:
    """``softmax_v(-(d_g - d_o) / T)``."""
    return torch.softmax(-(distances - prior_depth) / temperature, dim=1)


def retrieve_colors(
    points_world: Float[Tensor, "B N 3"],
    images: Float[Tensor, "B V 3 H W"],
    depth_prior: Float[Tensor, "B V H W"],
    c2w: Float[Tensor, "B V 4 4"],
    temperature: float = 1.0,
) -> tuple[Float[Tensor, "B N 3"], Float[Tensor, "B V N"]]:
    """Visibility-weighted colour ``sum_v w_v C_v`` and the weights."""
    b, v, _, h, w = images.shape
    uv, distances = project_to_views(points_world, c2w, h, w)
    flat_uv = uv.reshape(b * v, -1, 2)
    colors = sample_panorama(images.reshape(b * v, 3, h, w), flat_uv).view(b, v, -1, 3)
    prior = sample_panorama(depth_prior.reshape(b * v, 1, h, w), flat_uv).view(b, v, -1)
    weights = visibility_weights(distances, prior, temperature)
    return (weights[..., None] * colors).sum(dim=1), weights


def retrieve_colors_window(
    points_world: Float[Tensor, "B N 3"],
    images: Float[Tensor, "B V 3 H W"],
    depth_prior: Float[Tensor, "B V H W"],
    c2w: Float[Tensor, "B V 4 4"],
    window: int,
    temperature: float = 1.0,
) -> tuple[Float[Tensor, "B N 3"], Float[Tensor, "B V K N"]]:
    """Colour of the observed surface points nearest each point (module docstring, ``window > 0``):
    ``sum_{v,k} w_{vk} C_{vk}`` with ``w = softmax_{v,k}(-|p - d_o(u_k) ray(u_k)| / T)`` over the
    ``K = (2 window + 1)^2`` pixel offsets ``u_k`` around the projection ``u`` in every view ``v``
    (rows clamped to the image, columns wrapped). Returns the colours and the weights ``(B, V, K, N)``."""
    b, v, _, h, w = images.shape
    points_cam = world_to_camera(points_world[:, None], c2w)  # (B, V, N, 3)
    uv, _ = project_equirect(points_cam, h, w)
    steps = torch.arange(-window, window + 1, device=images.device, dtype=uv.dtype)
    offsets = torch.stack(torch.meshgrid(steps, steps, indexing="xy"), dim=-1).reshape(-1, 2)  # (K, 2)
    taps = uv[:, :, None] + offsets[:, None]  # (B, V, K, N, 2)
    taps = torch.stack((taps[..., 0], taps[..., 1].clamp(0.5, h - 0.5)), dim=-1)
    k = offsets.shape[0]
    flat = taps.reshape(b * v, -1, 2)
    colors = sample_panorama(images.reshape(b * v, 3, h, w), flat).view(b, v, k, -1, 3)
    prior = sample_panorama(depth_prior.reshape(b * v, 1, h, w), flat).view(b, v, k, -1)
    observed = prior[..., None] * uv_to_ray(taps[..., 0], taps[..., 1], h, w)  # surface points (B, V, K, N, 3)
    distance = (points_cam[:, :, None] - observed).norm(dim=-1)
    weights = torch.softmax(-distance.flatten(1, 2) / temperature, dim=1).view(b, v, k, -1)
    return (weights[..., None] * colors).sum(dim=(1, 2)), weights


class RGBRetrieval(nn.Module):
    def __init__(self, feature_dim: int, hidden: int, temperature: float = 1.0, window: int = 0):
        super().__init__()
        self.temperature = temperature
        self.window = window
        self.mlp = nn.Sequential(nn.Linear(3 + feature_dim, hidden), nn.GELU(), nn.Linear(hidden, 3))

    def forward(
        self,
        points_world: Float[Tensor, "B N 3"],
        features: Float[Tensor, "B N F"],
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
    ) -> Float[Tensor, "B N 3"]:
        if self.window > 0:
            retrieved, _ = retrieve_colors_window(points_world, images, depth_prior, c2w, self.window, self.temperature)
        else:
            retrieved, _ = retrieve_colors(points_world, images, depth_prior, c2w, self.temperature)
        residual = self.mlp(torch.cat((retrieved, features), dim=-1))
        return torch.sigmoid(torch.logit(retrieved.clamp(0.01, 0.99)) + residual)


class DecodedColor(nn.Module):
    """Colour decoded directly from the triplane (``volume.color="decoded"``; paper ablation row
    "Only Cylindrical Volume Branch (w/o RGB)"): ``sigmoid(MLP(f))`` on the volume head's colour
    feature ``f``. No projection into the input images: the colour depends on the images only
    through the triplane features (``F_pano`` via init and triplane-to-image attention).
    """

    def __init__(self, feature_dim: int, hidden: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(feature_dim, hidden), nn.GELU(), nn.Linear(hidden, 3))

    def forward(self, features: Float[Tensor, "B N F"]) -> Float[Tensor, "B N 3"]:
        return torch.sigmoid(self.mlp(features))
