"""Fusion of pixel and volume Gaussians (paper Sec. 3 and App. "Advanced Gaussian Fusion").

* ``"concat"`` (default, the paper's main results): ``G_pixel`` followed by ``G_volume``.
* ``"depth_prune"``: each volume Gaussian is checked against the *refined* depth of its own
  camera (the one whose triplane produced it; its centre lies inside that camera's volume). With
  ``e = (d_g - d_pred) / d_pred`` the relative deviation along its ray, its opacity is multiplied
  by ``exp(-e^2 / (2 sigma^2))`` (``side="front"``: only for ``e < 0``, i.e. Gaussians floating in
  front of the observed surface; those behind it are the occluded regions the volume branch
  completes). Gaussians whose attenuated opacity falls below ``prune_threshold`` are marked in
  ``keep_mask`` (batched outputs keep a fixed ``N``; ``gaussians.batch(i)[keep_mask[i]]`` drops them).
  Pixel Gaussians lie on the refined depth by construction and are never attenuated.
  ``side="hidden"``: the ``front`` attenuation against *every* input view's refined depth
  (multiplied), so volume Gaussians survive only in space no input view saw: where completion is
  needed, and where they cannot cover surfaces the pixel branch reconstructs.

``pixel_clearing="seen_through"`` (our addition, issue 23) applies the same ``hidden`` rule to the
*pixel* Gaussians when volume Gaussians are fused with them: a pixel Gaussian in front of another
input view's refined surface sits in space that view saw empty (a "flying pixel" a smooth depth map
strings across an occlusion boundary), and there it would cover the hidden surface the volume branch
completes; it fades. Pixel Gaussians on a surface another view also sees, or behind it, keep their
opacity (``e >= 0``); against their own view ``e = 0`` by construction.

:func:`fuse` is the one fusion rule :class:`~.cylindersplat.CylinderSplat` applies.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from jaxtyping import Float
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry import project_equirect, world_to_camera
from .config import FusionConfig
from .pixel_branch import depth_edge_confidence
from .sampling import sample_panorama

__all__ = ["covisibility", "depth_confidence", "depth_edginess", "hidden_confidence", "fuse", "fuse_gaussians"]


def depth_confidence(
    points_cam: Float[Tensor, "B V G 3"],
    refined_depth: Float[Tensor, "B V H W"],
    sigma: float,
    side: str = "both",
    clearance: float = 0.0,
) -> Float[Tensor, "B V G"]:
    """Agreement in ``(0, 1]`` of camera-frame points with their own view's predicted depth; with ``side="front"``
    and ``clearance > 0`` also ``1 - exp(-e^2 / (2 clearance^2))`` for points a relative depth ``e`` behind it."""
    b, v, h, w = refined_depth.shape
    uv, distance = project_equirect(points_cam, h, w)
    predicted = sample_panorama(refined_depth.reshape(b * v, 1, h, w), uv.reshape(b * v, -1, 2)).view(b, v, -1)
    error = (distance - predicted) / predicted.clamp_min(1e-6)
    behind = error.clamp_min(0.0)
    if side == "front":
        error = error.clamp_max(0.0)
    elif side != "both":
        raise ValueError(f"unknown pruning side {side!r}; expected 'both' or 'front'")
    confidence = torch.exp(-0.5 * (error / sigma) ** 2)
    if side == "front" and clearance > 0:
        confidence = confidence * -torch.expm1(-0.5 * (behind / clearance) ** 2)
    return confidence


def hidden_confidence(
    means_world: Float[Tensor, "B N 3"],
    c2w: Float[Tensor, "B V 4 4"],
    refined_depth: Float[Tensor, "B V H W"],
    sigma: float,
    clearance: float = 0.0,
) -> Float[Tensor, "B N"]:
    """How hidden world points are from every input view: the product over views of the ``front``
    attenuation, so a point in front of *any* view's predicted surface (space that view saw empty)
    fades, and only space no input view observed keeps full opacity."""
    points = world_to_camera(means_world[:, None], c2w)  # (B, V, N, 3): every point in every view
    return depth_confidence(points, refined_depth, sigma, "front", clearance).prod(dim=1)


def covisibility(
    means_world: Float[Tensor, "B N 3"],
    c2w: Float[Tensor, "B V 4 4"],
    refined_depth: Float[Tensor, "B V H W"],
    sigma: float,
) -> Float[Tensor, "B N"]:
    """How many input views see each world point: the sum over views of its agreement with that view's refined
    depth (``exp(-e^2 / (2 sigma^2))``, ``e`` the relative depth deviation along the view's ray; a point hidden
    behind another view's surface or in front of it counts ~0 there). A pixel Gaussian counts ~1 in its own view."""
    points = world_to_camera(means_world[:, None], c2w)  # (B, V, N, 3)
    return depth_confidence(points, refined_depth, sigma, "both").sum(dim=1)


def depth_edginess(depth: Float[Tensor, "B V H W"], step: float) -> Float[Tensor, "B VHW"]:
    """Per pixel Gaussian (view-major, row-major pixels), how much its pixel lies on a depth edge of its own view:
    ``1 - exp(-g^2 / (2 step^2))``, ``g`` the largest ``|log depth|`` step to one of its 8 neighbours."""
    b, v, h, w = depth.shape
    return 1 - depth_edge_confidence(depth.reshape(b * v, h, w), step).reshape(b, v * h * w)


def fuse_gaussians(
    pixel: Gaussians | None,
    volume: Gaussians | None,
    cfg: FusionConfig,
    volume_points_cam: Tensor | None = None,
    refined_depth: Tensor | None = None,
    c2w: Tensor | None = None,
) -> tuple[Gaussians, Float[Tensor, "B N"]]:
    """Combined Gaussians ``(B, N, ...)`` and a keep mask ``(B, N)``.

    ``side="hidden"`` needs the input poses ``c2w (B, V, 4, 4)`` and every view's refined depth."""
    if volume is not None and cfg.strategy == "depth_prune":
        if volume_points_cam is None or refined_depth is None:
            raise ValueError("depth_prune fusion needs the volume Gaussians' camera-frame points and the refined depth")
        if cfg.side == "hidden":
            if c2w is None:
                raise ValueError("fusion.side=hidden needs the input poses")
            confidence = hidden_confidence(volume.means, c2w, refined_depth, cfg.sigma, cfg.surface_clearance)
        else:
            confidence = depth_confidence(volume_points_cam, refined_depth, cfg.sigma, cfg.side).flatten(1)
        volume = replace(volume, opacities=volume.opacities * confidence)
    elif cfg.strategy not in ("concat", "depth_prune"):
        raise ValueError(f"unknown fusion strategy {cfg.strategy!r}; expected 'concat' or 'depth_prune'")
    parts = [g for g in (pixel, volume) if g is not None]
    fused = Gaussians.cat(parts) if len(parts) > 1 else parts[0]
    keep = torch.ones_like(fused.opacities, dtype=torch.bool)
    if volume is not None and cfg.strategy == "depth_prune":
        keep[..., fused.num_gaussians - volume.num_gaussians :] = volume.opacities >= cfg.prune_threshold
    return fused, keep


def fuse(
    pixel: Gaussians | None,
    volume,  # VolumeBranchOutput | None
    refined_depth: Float[Tensor, "B V H W"],
    c2w: Float[Tensor, "B V 4 4"],
    cfg: FusionConfig,
) -> tuple[Gaussians, Float[Tensor, "B N"]]:
    """The model's output Gaussians ``(B, N, ...)`` (pixel then volume) and keep mask from the branches' outputs
    (either may be ``None``: curriculum stages 1 and 2) and every input view's refined depth."""
    if cfg.pixel_clearing not in ("none", "seen_through", "at_depth_edges"):
        raise ValueError(f"unknown fusion.pixel_clearing {cfg.pixel_clearing!r}; "
                         "expected 'none', 'seen_through' or 'at_depth_edges'")
    if cfg.pixel_footprint not in ("per_view", "covisible"):
        raise ValueError(f"unknown fusion.pixel_footprint {cfg.pixel_footprint!r}; expected 'per_view' or 'covisible'")
    if pixel is not None and cfg.pixel_footprint == "covisible" and refined_depth.shape[1] > 1:
        # c views' splats tile a surface they all see: each keeps 1/sqrt(c) of its footprint for the same coverage
        count = covisibility(pixel.means.detach(), c2w, refined_depth.detach(), cfg.sigma).clamp_min(1.0)
        pixel = replace(pixel, scales=pixel.scales * count.rsqrt().unsqueeze(-1))
    volume_gaussians = points = check_depth = None
    if volume is not None:
        volume_gaussians, points, check_depth = volume.gaussians, volume.points_cam, refined_depth
        # side="hidden" checks every Gaussian against every view's depth; a central triplane's only against one view
        if cfg.side != "hidden" and volume.depth_view is not None:
            check_depth = refined_depth[:, volume.depth_view : volume.depth_view + 1]
        if pixel is not None and cfg.pixel_clearing != "none":
            confidence = hidden_confidence(pixel.means, c2w, refined_depth, cfg.sigma)
            if cfg.pixel_clearing == "at_depth_edges":
                confidence = 1 - depth_edginess(refined_depth, cfg.clearing_edge_step) * (1 - confidence)
            pixel = replace(pixel, opacities=pixel.opacities * confidence)
    return fuse_gaussians(pixel, volume_gaussians, cfg, points, check_depth, c2w)

