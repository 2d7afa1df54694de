"""Which pixels of a target panorama no context panorama sees (the "occluded" pixels).

A target pixel with depth is lifted to its 3D point, projected into every context view and
depth-tested against that context's depth map. A pixel is *occluded* when no context sees its point.
These are the pixels only completion (the volume branch) can get right; ``cylindersplat eval``
reports metrics on them separately (docs/evaluation.md, "Occluded pixels").

The test is made robust to the resolution it runs at, because a naive one marks 1-pixel lines along
every object silhouette as hidden (a point just beside an occluder projects onto the occluder's rim in
the context, and depth maps resized by area averaging put "floating" depths on silhouettes):

* **decide at the highest resolution there is**: the caller passes the depth maps as stored (e.g.
  512x1024) and ``out_size`` the evaluation size; an evaluation pixel takes the decision of the stored
  pixel at its centre, i.e. on the ray the renderer draws it with. (Majority pooling of the stored
  pixels under it was tried and rejected: it drops thin hidden strips at coarse sizes. On the real
  Matterport3D fixture, one view in, it gave 0.81 % hidden at 64x128 against 1.39 % at 256x512; centre
  sampling gives 1.29 % and 1.23 %, the stored resolution 1.22 %.)
* **at a fixed angular footprint**: depth maps stored smaller than ``decision_height`` rows (512, the
  real datasets' stored size) are upsampled by nearest neighbour to at least that, so that the one-pixel
  tolerances below mean about 0.35 degrees on every dataset (on the procedural study data, stored at
  64x128, one-pixel tolerances at the stored size would drop two thirds of the truly hidden pixels);
* **tolerant in the context**: the point counts as seen when any context pixel within
  ``context_window`` pixels of where it projects is at least as far as the point (``d_ctx >= (1 -
  rel_tol) * d_proj``), so a point beside a silhouette is not hidden by the silhouette's own pixel;
* **no decision at depth edges**: target pixels within ``edge_band`` pixels of a depth discontinuity
  (a second difference of the depth larger than ``edge_tol`` times the depth, which smooth slanted
  floors and walls do not reach) are never marked occluded; their depth belongs to two surfaces.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float
from torch import Tensor

from .consistency import reproject, sample_equirect

__all__ = ["occluded_mask", "occluded_fraction", "depth_edges", "sample_mask"]


def _pad_equirect(image: Tensor, k: int, mode: str) -> Tensor:
    """Pad ``(N, C, H, W)`` by ``k`` pixels: circularly in longitude, by ``mode`` in latitude."""
    image = torch.cat([image[..., -k:], image, image[..., :k]], dim=-1)
    return F.pad(image, (0, 0, k, k), mode=mode)


def depth_edges(depth: Float[Tensor, "H W"], edge_tol: float = 0.1, band: int = 1, min_depth: float = 1e-3
                ) -> Bool[Tensor, "H W"]:
    """Pixels within ``band`` pixels of a depth discontinuity (or of a pixel without depth).

    A discontinuity is where the second difference along a row or column, ``|d[i-1] - 2 d[i] + d[i+1]|``,
    exceeds ``edge_tol * d[i]``: a step between two surfaces does, a slanted plane (whose depth changes
    steadily) does not. Rows wrap around in longitude; beyond the top and bottom rows the depth is
    extrapolated linearly. ``band = 0``: no pixel.
    """
    if band <= 0:
        return torch.zeros_like(depth, dtype=torch.bool)
    d = depth.double()
    d = torch.cat([2 * d[:1] - d[1:2], d, 2 * d[-1:] - d[-2:-1]])  # linear beyond the poles: no step there
    padded = torch.cat([d[:, -1:], d, d[:, :1]], dim=1)
    centre = padded[1:-1, 1:-1]
    horizontal = (padded[1:-1, :-2] - 2 * centre + padded[1:-1, 2:]).abs()
    vertical = (padded[:-2, 1:-1] - 2 * centre + padded[2:, 1:-1]).abs()
    edge = (torch.maximum(horizontal, vertical) > edge_tol * centre) | (centre <= min_depth)
    # Band: a pixel whose (2 band - 1)-wide neighbourhood holds an edge pixel (the second difference
    # already flags both sides of a step, so band 1 is the test itself).
    if band > 1:
        k = band - 1
        edge = F.max_pool2d(_pad_equirect(edge.double()[None, None], k, "replicate"), 2 * k + 1, stride=1)[0, 0] > 0
    return edge


def sample_mask(mask: Bool[Tensor, "H W"], out_size: tuple[int, int]) -> Bool[Tensor, "h w"]:
    """``mask`` at the pixel centres of an ``out_size`` grid over the same panorama (nearest pixel; a centre
    on a boundary between two pixels takes the later one)."""
    if tuple(mask.shape) == tuple(out_size):
        return mask
    (h, w), (oh, ow) = mask.shape, out_size
    rows = ((torch.arange(oh, dtype=torch.float64) + 0.5) * h / oh).floor().long().clamp(max=h - 1)
    cols = ((torch.arange(ow, dtype=torch.float64) + 0.5) * w / ow).floor().long().clamp(max=w - 1)
    return mask[rows.to(mask.device)][:, cols.to(mask.device)]


@torch.no_grad()
def occluded_mask(
    target_depth: Float[Tensor, "H W"],
    target_c2w: Float[Tensor, "4 4"],
    context_depths: Float[Tensor, "V Hc Wc"],
    context_c2w: Float[Tensor, "V 4 4"],
    rel_tol: float = 0.05,
    min_depth: float = 1e-3,
    context_window: int = 1,
    edge_tol: float = 0.1,
    edge_band: int = 1,
    out_size: tuple[int, int] | None = None,
    decision_height: int = 512,
) -> Bool[Tensor, "h w"]:
    """``True`` where the target pixel has a valid depth and no context view sees its 3D point.

    Decided at the resolution of ``target_depth`` (pass the stored, full-resolution depth maps; upsampled
    to ``decision_height`` rows when smaller, 0 = never) and sampled at the pixel centres of ``out_size``
    (default: the size of ``target_depth``); see the module docstring for ``context_window``, ``edge_tol``
    and ``edge_band`` (0 each, with ``decision_height=0``: the plain nearest-pixel test at every pixel). Context depths
    of 0 (invalid) count as "sees nothing there"; context maps may have another resolution than the
    target.
    """
    if target_depth.ndim != 2 or context_depths.ndim != 3 or context_c2w.shape != (len(context_depths), 4, 4):
        raise ValueError(f"occluded_mask needs target depth (H, W), context depths (V, H, W) and poses (V, 4, 4); got "
                         f"{tuple(target_depth.shape)}, {tuple(context_depths.shape)}, {tuple(context_c2w.shape)}")
    if min(context_window, edge_band) < 0 or rel_tol < 0 or edge_tol <= 0:
        raise ValueError("occluded_mask: context_window and edge_band must be >= 0, rel_tol >= 0 and edge_tol > 0; "
                         f"got {context_window}, {edge_band}, {rel_tol}, {edge_tol}")
    size = tuple(out_size) if out_size is not None else tuple(target_depth.shape)
    if target_depth.shape[0] < decision_height:  # nearest upsampling: the tolerances become sub-pixel
        factor = -(-decision_height // target_depth.shape[0])
        target_depth = F.interpolate(target_depth[None, None], scale_factor=factor, mode="nearest")[0, 0]
        context_depths = F.interpolate(context_depths[None], scale_factor=factor, mode="nearest")[0]
    h, w = target_depth.shape
    valid = target_depth > min_depth
    seen = torch.zeros(h * w, dtype=torch.bool, device=target_depth.device)
    for ctx_depth, c2w in zip(context_depths.to(target_depth.device), context_c2w):
        u, v, d_proj = reproject(target_depth, target_c2w, c2w, tuple(ctx_depth.shape))
        farthest = ctx_depth.double()
        if context_window > 0:  # the farthest surface near the projected pixel: a rim pixel does not hide
            k = context_window
            farthest = F.max_pool2d(_pad_equirect(farthest[None, None], k, "replicate"), 2 * k + 1, stride=1)[0, 0]
        d_ctx = sample_equirect(farthest[None], u, v, mode="nearest").reshape(-1)
        seen |= (d_ctx > min_depth) & (d_ctx >= (1.0 - rel_tol) * d_proj)
    hidden = valid & ~seen.reshape(h, w) & ~depth_edges(target_depth, edge_tol, edge_band, min_depth)
    return sample_mask(hidden, size)


def occluded_fraction(mask: Bool[Tensor, "H W"]) -> float:
    """Latitude-weighted share of occluded pixels (the weighting WS-PSNR uses)."""
    from ..metrics.image import ws_weights

    weight = ws_weights(mask.shape[0]).to(mask.device)[:, None].expand_as(mask)
    return float((weight * mask).sum() / weight.sum())
