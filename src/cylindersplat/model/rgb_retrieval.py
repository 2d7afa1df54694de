"""Visibility-aware RGB retrieval for volume Gaussians (paper Eq. 6).

Every Gaussian centre is projected into all ``V`` input panoramas; the colour ``C_v`` and the
depth prior ``d_o`` are read there (bilinear, wrapping in ``u``). The visibility score is
``s_v = d_g - d_o`` with ``d_g`` the radial distance to camera ``v``; ``w = softmax_v(-s_v / T)``
(``T = 1`` m is the paper). A view whose prior surface lies in front of the Gaussian
(occluded, ``s_v >> 0``) gets a small weight; an invalid prior (0) counts as "occluded by
``d_g``". An MLP maps ``sum_v w_v C_v`` (and a per-Gaussian feature from the triplane, our
addition so the colour can depend on the Gaussian) to the final colour, as a logit-space
residual on the retrieved colour so that it starts at the retrieval itself.

The colour rules (``volume.color``; :data:`COLOR_RULES`, built by :func:`build_color_module`):

* ``"retrieval"`` - Eq. 6 as above (the ``paper`` preset). For a point hidden behind an occluder in
  every view, ``d_g - d_o > 0`` in all of them and the softmax still returns a blend of the views'
  colours *at the projection*: the occluder's. At the true geometry of the study's scenes it colours
  hidden pixels no better than copying the nearest visible pixel
  (``studies/colour_rule_oracle.py``).
* ``"surface"`` (our departure): every view is read at the ``(2 window + 1)^2`` pixels around the
  projection (``volume.surface_window``), each read lifted to its observed surface point
  ``d_o * ray``, and ``w = softmax_{v, k}(-|p_g - d_o ray_k| / T)`` over views and taps with a sharp
  ``T`` in metres (``volume.surface_temperature``, learnable with ``volume.learn_temperature``): the
  colour of the *observed surface points nearest the Gaussian*. For a Gaussian behind an occluder
  the nearest observed points are the hidden surface's visible continuation beside the occluder; on
  a seen surface the centre tap is nearest.
* ``"released_mlp"`` (the authors' released code, ``VolumeGaussianDecoderCylinder``): no softmax;
  an MLP (128-128-3, LeakyReLU, sigmoid) maps every view's 3x3 colour taps, each with the view's
  ``d_g - d_o`` at the projection, concatenated over views (zero-padded to
  ``volume.color_views`` views), to the colour.
* ``"decoded"`` - :class:`DecodedColor` below (no image lookup).

:class:`DecodedColor` is the ``volume.color="decoded"`` ablation (Table "Ablation Study", row
"Only Cylindrical Volume Branch (w/o RGB)", OmniScene's colour): the colour is decoded from the
triplane alone, ``sigmoid(MLP(color_feature))``, without reading the input images.
"""

from __future__ import annotations

import math

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..geometry import project_equirect, uv_to_ray, world_to_camera
from .config import COLOR_RULES
from .sampling import sample_panorama

__all__ = ["project_to_views", "visibility_weights", "retrieve_colors", "retrieve_colors_window", "tap_features",
           "RGBRetrieval", "ReleasedColorMLP", "DecodedColor", "COLOR_RULES", "build_color_module"]


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


def _taps(uv: Float[Tensor, "B V N 2"], window: int, height: int) -> Float[Tensor, "B V K N 2"]:
    """The ``K = (2 window + 1)^2`` pixel positions around every projection (rows clamped, columns wrap later)."""
    steps = torch.arange(-window, window + 1, device=uv.device, dtype=uv.dtype)
    offsets = torch.stack(torch.meshgrid(steps, steps, indexing="xy"), dim=-1).reshape(-1, 2)  # (K, 2)
    taps = uv[:, :, None] + offsets[:, None]
    return torch.stack((taps[..., 0], taps[..., 1].clamp(0.5, height - 0.5)), dim=-1)


def _read_taps(images: Tensor, depth_prior: Tensor, taps: Tensor) -> tuple[Tensor, Tensor]:
    """Colours ``(B, V, K, N, 3)`` and prior depths ``(B, V, K, N)`` of every view at its taps ``(B, V, K, N, 2)``."""
    b, v, _, h, w = images.shape
    k = taps.shape[2]
    flat = taps.reshape(b * v, -1, 2)
    colors = sample_panorama(images.reshape(b * v, 3, h, w), flat).view(b, v, k, -1, 3)
    prior = sample_panorama(depth_prior.reshape(b * v, 1, h, w), flat).view(b, v, k, -1)
    return colors, prior


def retrieve_colors_window(
    points_world: Float[Tensor, "B N 3"],
    images: Float[Tensor, "B V 3 H W"],
    depth_prior: Float[Tensor, "B V H W"],
    c2w: Float[Tensor, "B V 4 4"],
    window: int,
    temperature: float | Tensor = 1.0,
) -> tuple[Float[Tensor, "B N 3"], Float[Tensor, "B V K N"]]:
    """Colour of the observed surface points nearest each point (module docstring, ``"surface"``):
    ``sum_{v,k} w_{vk} C_{vk}`` with ``w = softmax_{v,k}(-|p - d_o(u_k) ray(u_k)| / T)`` over the
    ``K = (2 window + 1)^2`` pixel offsets ``u_k`` around the projection ``u`` in every view ``v``
    (rows clamped to the image, columns wrapped). Returns the colours and the weights ``(B, V, K, N)``."""
    b, v, _, h, w = images.shape
    points_cam = world_to_camera(points_world[:, None], c2w)  # (B, V, N, 3)
    uv, _ = project_equirect(points_cam, h, w)
    taps = _taps(uv, window, h)
    colors, prior = _read_taps(images, depth_prior, taps)
    observed = prior[..., None] * uv_to_ray(taps[..., 0], taps[..., 1], h, w)  # surface points (B, V, K, N, 3)
    distance = (points_cam[:, :, None] - observed).norm(dim=-1)
    k = taps.shape[2]
    weights = torch.softmax(-distance.flatten(1, 2) / temperature, dim=1).view(b, v, k, -1)
    return (weights[..., None] * colors).sum(dim=(1, 2)), weights


def tap_features(
    points_world: Float[Tensor, "B N 3"],
    images: Float[Tensor, "B V 3 H W"],
    depth_prior: Float[Tensor, "B V H W"],
    c2w: Float[Tensor, "B V 4 4"],
    window: int = 1,
) -> Float[Tensor, "B N V K 4"]:
    """The released colour MLP's input: per view and tap, the colour and ``d_g - d_o`` at the projection
    (the same for every tap of a view; an invalid prior reads as 0, i.e. ``d_g``)."""
    b, v, _, h, w = images.shape
    uv, distance = project_to_views(points_world, c2w, h, w)  # (B, V, N, 2), (B, V, N)
    prior = sample_panorama(depth_prior.reshape(b * v, 1, h, w), uv.reshape(b * v, -1, 2)).view(b, v, -1)
    colors, _ = _read_taps(images, depth_prior, _taps(uv, window, h))  # (B, V, K, N, 3)
    visibility = (distance - prior)[:, :, None, :, None].expand(-1, -1, colors.shape[2], -1, 1)
    return torch.cat((colors, visibility), dim=-1).permute(0, 3, 1, 2, 4)


class RGBRetrieval(nn.Module):
    """Eq. 6 (``window = 0``) or the nearest-observed-surface rule (``window > 0``), then a residual MLP on the
    retrieved colour and the Gaussian's triplane feature (logit space, so it starts at the retrieval).
    ``learn_temperature``: ``T`` is a parameter (``log T``, so it stays positive)."""

    def __init__(self, feature_dim: int, hidden: int, temperature: float = 1.0, window: int = 0,
                 learn_temperature: bool = False):
        super().__init__()
        self.window = window
        if learn_temperature:
            self.log_temperature = nn.Parameter(torch.tensor(math.log(temperature)))
        else:
            self.register_buffer("log_temperature", torch.tensor(math.log(temperature)), persistent=False)
        self.mlp = nn.Sequential(nn.Linear(3 + feature_dim, hidden), nn.GELU(), nn.Linear(hidden, 3))

    @property
    def temperature(self) -> Tensor:
        return self.log_temperature.exp()

    def forward(
        self,
        points_world: Float[Tensor, "B N 3"],
        features: Float[Tensor, "B N F"],
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
    ) -> Float[Tensor, "B N 3"]:
        temperature = self.temperature.to(images.dtype)
        if self.window > 0:
            retrieved, _ = retrieve_colors_window(points_world, images, depth_prior, c2w, self.window, temperature)
        else:
            retrieved, _ = retrieve_colors(points_world, images, depth_prior, c2w, temperature)
        residual = self.mlp(torch.cat((retrieved, features), dim=-1))
        return torch.sigmoid(torch.logit(retrieved.clamp(0.01, 0.99)) + residual)


class ReleasedColorMLP(nn.Module):
    """The released code's colour rule (module docstring, ``"released_mlp"``): an MLP over every view's 3x3 colour
    taps and ``d_g - d_o``, views concatenated in input order and zero-padded to ``max_views``."""

    def __init__(self, max_views: int, hidden: int = 128, window: int = 1):
        super().__init__()
        self.max_views, self.window = max_views, window
        taps = (2 * window + 1) ** 2
        self.mlp = nn.Sequential(nn.Linear(max_views * taps * 4, hidden), nn.LeakyReLU(), nn.Linear(hidden, hidden),
                                 nn.LeakyReLU(), nn.Linear(hidden, 3), nn.Sigmoid())

    def forward(self, points_world, features, images, depth_prior, c2w) -> Float[Tensor, "B N 3"]:
        views = images.shape[1]
        if views > self.max_views:
            raise ValueError(f"volume.color=released_mlp takes at most volume.color_views={self.max_views} "
                             f"input views, got {views}; raise volume.color_views (and retrain)")
        taps = tap_features(points_world, images, depth_prior, c2w, self.window).flatten(2)  # (B, N, V*K*4)
        padded = torch.nn.functional.pad(taps, (0, (self.max_views - views) * taps.shape[-1] // views))
        return self.mlp(padded)


class DecodedColor(nn.Module):
    """Colour decoded directly from the triplane (``volume.color="decoded"``; paper ablation row
    "Only Cylindrical Volume Branch (w/o RGB)"): ``sigmoid(MLP(f))`` on the volume head's colour
    feature ``f``. No projection into the input images: the colour depends on the images only
    through the triplane features (``F_pano`` via init and triplane-to-image attention).
    """

    def __init__(self, feature_dim: int, hidden: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(feature_dim, hidden), nn.GELU(), nn.Linear(hidden, 3))

    def forward(self, points_world, features: Float[Tensor, "B N F"], images=None, depth_prior=None, c2w=None
                ) -> Float[Tensor, "B N 3"]:
        return torch.sigmoid(self.mlp(features))  # the same call as the other rules; the images are not read


def build_color_module(vc) -> nn.Module:
    """The colour module of a ``VolumeBranchConfig`` (``vc.color`` one of :data:`COLOR_RULES`)."""
    if vc.color == "retrieval":
        return RGBRetrieval(vc.color_hidden, vc.color_hidden, vc.visibility_temperature)
    if vc.color == "surface":
        return RGBRetrieval(vc.color_hidden, vc.color_hidden, vc.surface_temperature, vc.surface_window,
                            vc.learn_temperature)
    if vc.color == "released_mlp":
        return ReleasedColorMLP(vc.color_views)
    if vc.color == "decoded":
        return DecodedColor(vc.color_hidden, vc.color_hidden)
    raise ValueError(f"unknown volume.color {vc.color!r}; expected one of {sorted(COLOR_RULES)}")
