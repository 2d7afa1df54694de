"""Where a model loses detail against a forward warp (issue 34): regions, Gaussian sources and an oracle ladder.

A forward warp of the nearest input with its depth is one opaque, pixel-sized splat per input pixel, coloured by
that pixel. The pixel branch starts there (colour = pixel + residual, footprint = depth x pixel angle x factor,
opacity), so the gap between the two can be walked one step at a time. :func:`ladder` builds Gaussians that
change one thing per rung, from the splatted warp to the full model:

1. ``splat warp``: the nearest input's pixels at the *prior's* depth, the pixel's colour, each a flat Gaussian on
   the pixel's own patch of surface (:func:`~cylindersplat.model.gaussian_heads.surface_footprints`, ``pixel_sigma``
   times its extent), opacity 1: the forward warp, drawn by the Gaussian rasterizer;
2. ``+ refined depth``: the same at the model's refined depth;
3. ``+ all views``: every input's pixels (where two views see a surface, both are drawn);
4. ``+ learned colour``: the pixel head's colours;
5. ``+ learned footprint``: its scales and rotations;
6. ``+ learned opacity``: its opacities (edge fading included): the pixel branch's Gaussians as stage 1 draws them;
7. ``full model``: pixel and volume Gaussians as the model fuses them (pixel clearing included).

Every rung is scored with the inpaint fill behind it (:mod:`.fills`), as the warp is, on the target regions of
:func:`target_regions`: pixels the nearest input sees, pixels only another input sees, pixels no input sees
(decided on ground-truth depth at the stored resolution, :func:`~cylindersplat.data.occlusion.occluded_mask`),
and a band around the target's depth edges (kept out of the other three). :func:`source_shares` says which
Gaussians draw each region (the nearest input's pixel Gaussians, the other inputs', the volume branch's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..baselines.forward_warp import forward_warp, nearest_source
from ..data.occlusion import depth_edges, occluded_mask
from ..gaussians import Gaussians
from ..geometry import camera_to_world, equirect_rays
from ..geometry.rotations import matrix_to_quaternion, quaternion_multiply
from ..metrics import ssim, ws_psnr
from ..model.gaussian_heads import surface_footprints
from ..render import Equirect, RasterSettings, render
from ..render.api import RenderOutput
from .fills import fill_uncovered
from .masked import MIN_OCCLUDED_PIXELS, masked_ws_psnr

__all__ = ["REGIONS", "RUNGS", "target_regions", "ladder", "source_shares", "pixel_statistics", "diagnose_sample",
           "DiagnosisRow"]

REGIONS = ("all", "seen_nearest", "seen_other_only", "hidden", "edge_band")
RUNGS = ("FW + inpaint", "splat warp", "+ refined depth", "+ all views", "+ learned colour", "+ learned footprint",
         "+ learned opacity", "full model")
SOURCES = ("nearest view", "other views", "volume")


def target_regions(
    sample,
    stored_targets: Tensor | None = None,
    stored_contexts: Tensor | None = None,
    edge_band: int = 2,
) -> dict[str, Bool[Tensor, "T H W"]]:
    """Disjoint masks ``(T, H, W)`` of each target's pixels (plus ``all``), from ground-truth depth.

    ``edge_band``: target pixels within this many pixels (at the evaluation size) of a depth discontinuity of the
    target's ground truth; they are left out of the three visibility regions (their depth belongs to two surfaces).
    ``stored_*``: the full-resolution depth maps, on which visibility is decided (see :func:`occluded_mask`)."""
    if sample.target_depths is None or sample.context_gt_depths is None:
        raise ValueError("the diagnosis needs ground-truth depth of the targets and of the inputs")
    targets = sample.target_depths if stored_targets is None else stored_targets
    contexts = sample.context_gt_depths if stored_contexts is None else stored_contexts
    size = tuple(sample.target_depths.shape[-2:])
    nearest = nearest_source(sample.context_poses, sample.target_poses)
    regions = {name: [] for name in REGIONS}
    for t in range(len(sample.target_poses)):
        n = int(nearest[t])
        hidden = occluded_mask(targets[t], sample.target_poses[t], contexts, sample.context_poses, out_size=size)
        unseen_nearest = occluded_mask(targets[t], sample.target_poses[t], contexts[n:n + 1],
                                       sample.context_poses[n:n + 1], out_size=size)
        valid = sample.target_depths[t] > 1e-3
        edge = depth_edges(sample.target_depths[t], band=edge_band) & valid
        regions["all"].append(torch.ones(size, dtype=torch.bool))
        regions["seen_nearest"].append(valid & ~unseen_nearest & ~edge)
        regions["seen_other_only"].append(unseen_nearest & ~hidden & ~edge)
        regions["hidden"].append(hidden & ~edge)
        regions["edge_band"].append(edge)
    return {name: torch.stack(masks) for name, masks in regions.items()}


def _pixel_means(depth: Float[Tensor, "V H W"], c2w: Float[Tensor, "V 4 4"]) -> Float[Tensor, "V*H*W 3"]:
    """World points of every input pixel at ``depth`` along its ray
    (view-major, row-major: the pixel branch's order)."""
    v, h, w = depth.shape
    rays = equirect_rays(h, w, device=depth.device, dtype=depth.dtype).reshape(1, h * w, 3)
    return camera_to_world(rays * depth.reshape(v, h * w, 1), c2w).reshape(v * h * w, 3)


def ladder(
    output,
    images: Float[Tensor, "V 3 H W"],
    prior: Float[Tensor, "V H W"],
    c2w: Float[Tensor, "V 4 4"],
    nearest: int,
    pixel_sigma: float = 0.5,
) -> dict[str, Gaussians]:
    """Gaussians (unbatched, world frame) of rungs 1-7 (see the module docstring) for a target whose nearest input
    is ``nearest``. ``output``: the model's :class:`~cylindersplat.model.ModelOutput` of these inputs (batch 1, mode
    ``both``); ``prior``: the depth the model was given (after its own rescaling, if any, for a fair first rung)."""
    v, _, h, w = images.shape
    pixel = output.pixel_gaussians.batch(0)
    refined = output.refined_depth[0]
    view_of = torch.arange(v, device=images.device).repeat_interleave(h * w)
    rgb = images.permute(0, 2, 3, 1).reshape(-1, 3).clamp(0, 1)
    camera_rotation = matrix_to_quaternion(c2w[:, :3, :3]).repeat_interleave(h * w, dim=0)

    def gaussians(depth, colours, scales=None, rotations=None, opacities=None) -> Gaussians:
        if scales is None:  # the pixel's own patch of surface, turned from the camera into the world frame
            scales, local = surface_footprints(depth, pixel_sigma)
            scales, rotations = scales.reshape(-1, 3), quaternion_multiply(camera_rotation, local.reshape(-1, 4))
        return Gaussians.from_rgb(
            _pixel_means(depth, c2w), scales, rotations,
            torch.ones(v * h * w, dtype=images.dtype, device=images.device) if opacities is None else opacities,
            colours,
        )

    own = view_of == nearest
    rungs = {
        "splat warp": gaussians(prior, rgb)[own],
        "+ refined depth": gaussians(refined, rgb)[own],
        "+ all views": gaussians(refined, rgb),
        "+ learned colour": gaussians(refined, pixel.rgb),
        "+ learned footprint": gaussians(refined, pixel.rgb, pixel.scales, pixel.rotations),
        "+ learned opacity": gaussians(refined, pixel.rgb, pixel.scales, pixel.rotations, pixel.opacities),
    }
    fused = output.gaussians.batch(0)
    rungs["full model"] = fused[output.keep_mask[0]]
    return rungs


def source_shares(
    output, c2w_target: Float[Tensor, "4 4"], height: int, width: int, nearest: int, num_views: int,
    settings: RasterSettings | None = None,
) -> Float[Tensor, "3 H W"]:
    """Per target pixel, the rendered weight of each source (:data:`SOURCES`): the model's fused Gaussians drawn
    with a one-hot colour per source (the nearest input's pixel Gaussians, the other inputs', the volume's)."""
    fused = output.gaussians.batch(0)
    keep = output.keep_mask[0]
    n_pixel = 0 if output.pixel_gaussians is None else output.pixel_gaussians.num_gaussians
    per_view = n_pixel // num_views
    source = torch.full((fused.num_gaussians,), 2, dtype=torch.long, device=fused.means.device)
    if n_pixel:
        view_of = torch.arange(n_pixel, device=source.device) // per_view
        source[:n_pixel] = torch.where(view_of == nearest, 0, 1)
    onehot = torch.nn.functional.one_hot(source, 3).to(fused.means.dtype)
    tagged = replace(fused, sh=((onehot - 0.5) / 0.28209479177387814).unsqueeze(-2))[keep]
    out = render(tagged, c2w_target, Equirect(height, width), settings=settings)
    return out.rgb


@torch.no_grad()
def pixel_statistics(output, prior: Float[Tensor, "V H W"]) -> dict[str, float]:
    """Summary of the pixel head's Gaussians: footprint in input pixels (largest std-dev / (depth x pi/H)), opacity,
    and how far refinement moved the depth (mean |log(refined / prior)|)."""
    pixel = output.pixel_gaussians.batch(0)
    refined = output.refined_depth[0]
    h = refined.shape[-2]
    sigma_px = pixel.scales.max(dim=-1).values / (refined.reshape(-1) * math.pi / h)
    moved = (refined.clamp_min(1e-6) / prior.clamp_min(1e-6)).log().abs()
    return {
        "footprint_px_median": float(sigma_px.median()),
        "footprint_px_p90": float(sigma_px.quantile(0.9)),
        "opacity_mean": float(pixel.opacities.mean()),
        "opacity_below_0.9": float((pixel.opacities < 0.9).double().mean()),
        "depth_moved_mean_abs_log": float(moved[prior > 0].mean()),
    }


@dataclass
class DiagnosisRow:
    """One rung's scores on one target: WS-PSNR per region (``None`` for a region of too few pixels) and SSIM."""

    rung: str
    ws_psnr: dict[str, float | None]
    ssim: float


def _scores(rgb: Float[Tensor, "3 H W"], target: Float[Tensor, "3 H W"], masks: dict[str, Tensor], t: int):
    values = {}
    for name, mask in masks.items():
        m = mask[t]
        if name == "all":
            values[name] = float(ws_psnr(rgb[None].clamp(0, 1), target[None]))
        elif int(m.sum()) >= MIN_OCCLUDED_PIXELS:
            values[name] = float(masked_ws_psnr(rgb[None], target[None], m[None]))
        else:
            values[name] = None
    return values


@torch.no_grad()
def diagnose_sample(model, sample, stored=(None, None), pixel_sigma: float = 0.5,
                    settings: RasterSettings | None = None) -> dict:
    """Ladder scores, source shares and pixel statistics of one sample (every target view).

    Returns ``{"rows": [DiagnosisRow per (target, rung)], "shares": {region: {source: share}} per target,
    "pixel": pixel_statistics, "pixels": {region: count} per target}``."""
    model.eval()
    images, prior, c2w = sample.context_images, sample.context_priors, sample.context_poses
    output = model(images[None], prior[None], c2w[None])
    given = prior if output.prior_scales is None else prior * output.prior_scales[0, :, None, None]
    masks = target_regions(sample, *stored)
    nearest = nearest_source(c2w, sample.target_poses)
    h, w = sample.target_images.shape[-2:]
    warp = forward_warp(images, prior, c2w, sample.target_poses, h, w)
    warp = fill_uncovered(warp, images, "inpaint")
    rows, shares, pixels = [], [], []
    for t in range(len(sample.target_poses)):
        target = sample.target_images[t]
        rows.append(DiagnosisRow("FW + inpaint", _scores(warp.rgb[t], target, masks, t),
                                 float(ssim(warp.rgb[t:t + 1].clamp(0, 1), target[None]))))
        for name, gaussians in ladder(output, images, given, c2w, int(nearest[t]), pixel_sigma).items():
            out = render(gaussians, sample.target_poses[t:t + 1], Equirect(h, w), settings=settings)
            filled = fill_uncovered(RenderOutput(out.rgb, out.depth, out.alpha), images, "inpaint")
            rows.append(DiagnosisRow(name, _scores(filled.rgb[0], target, masks, t),
                                     float(ssim(filled.rgb[:1].clamp(0, 1), target[None]))))
        weights = source_shares(output, sample.target_poses[t], h, w, int(nearest[t]), len(images), settings)
        share = {}
        for region, mask in masks.items():
            m = mask[t]
            total = weights[:, m].sum()
            share[region] = {s: (float(weights[i, m].sum() / total) if total > 0 else None)
                             for i, s in enumerate(SOURCES)}
            share[region]["coverage"] = float(weights[:, m].sum(0).mean()) if int(m.sum()) else None
        shares.append(share)
        pixels.append({region: int(mask[t].sum()) for region, mask in masks.items()})
    return {"rows": rows, "shares": shares, "pixel": pixel_statistics(output, given), "pixels": pixels}
