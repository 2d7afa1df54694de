"""Tile binning and front-to-back compositing of projected Gaussians (PyTorch reference).

Pipeline (the fast GPU backend follows the same stages and rules):

1. **Support.** Gaussian ``g`` can touch pixel centre ``p`` only inside its ``3 sigma`` ellipse
   ``d^T Sigma_2d^-1 d <= 9`` with ``d = p - uv_g``; in equirect images ``d_u`` is wrapped into
   ``[-W/2, W/2)`` so a footprint continues across the seam ``u = 0 = W``. The ellipse's bounding
   box (``extent``) gives the candidate pixels. Support is defined per pixel, independent of
   tiling, so the result does not depend on the tile size.
2. **Tile binning.** Each Gaussian is paired with every ``tile_size``-square tile its bounding box
   overlaps (column ranges wrap around the seam); pairs are sorted by (camera, tile, radial depth).
3. **Fragments.** Each pair expands to the pixels of its tile inside the bounding box; a stable sort
   by pixel keeps every pixel's fragments in front-to-back order.
4. **Compositing** per pixel, front to back: ``alpha = min(0.99, o * exp(power))``, fragments
   with ``alpha < 1/255`` or outside the ellipse are skipped, ``T_i = prod_{j<i} (1 - alpha_j)``, and
   the fragment that would bring ``T`` below ``1e-4`` and all after it are dropped (3DGS rule).
   ``rgb = sum_i alpha_i T_i c_i + T_final * background``, ``depth = sum_i alpha_i T_i r_i``
   (radial, *not* divided by alpha), ``alpha = 1 - T_final``. The segmented product is a cumulative
   sum of ``log(1 - alpha)`` in float64 (exact enough at millions of fragments).

Everything is plain differentiable PyTorch: autograd provides the backward pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..utils.memory import available_memory  # a name of this module too: tests patch rasterize.available_memory
from .projection import ProjectedGaussians, RasterSettings

__all__ = ["TileBins", "TileSpans", "tile_spans", "bin_to_tiles", "expand_fragments", "composite", "rasterize",
           "pack_projected", "unpack_composited"]


@dataclass
class TileBins:
    """(Gaussian, tile) pairs sorted by global tile id then depth.

    gaussian: (P,) row of the ProjectedGaussians;  tile: (P,) global tile id
    (``camera * tiles_per_camera + ty * tiles_x + tx``); rows/cols: (P, 2) inclusive pixel ranges
    of the pair's candidate pixels (inside the tile and the Gaussian's bounding box); col_shift:
    (P,) multiple of W with ``wrapped column = unwrapped column + col_shift`` (seam handling).
    """

    gaussian: Tensor
    tile: Tensor
    rows: Tensor
    cols: Tensor
    col_shift: Tensor
    tiles_x: int
    tiles_y: int


def _pixel_ranges(proj: ProjectedGaussians) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Inclusive candidate pixel ranges ``(i0, i1, j0, j1)``; columns unwrapped (may be < 0 or >= W)."""
    h, w = proj.height, proj.width
    uv, ext = proj.uv.detach(), proj.extent.detach()
    i0 = torch.ceil(uv[:, 1] - ext[:, 1] - 0.5).clamp(min=0).long()
    i1 = torch.floor(uv[:, 1] + ext[:, 1] - 0.5).clamp(max=h - 1).long()
    j0 = torch.ceil(uv[:, 0] - ext[:, 0] - 0.5).long()
    j1 = torch.floor(uv[:, 0] + ext[:, 0] - 0.5).long()
    if proj.wrap_u:
        j1 = torch.minimum(j1, j0 + w - 1)
    else:
        j0, j1 = j0.clamp(min=0), j1.clamp(max=w - 1)
    return i0, i1, j0, j1


def _expand(counts: Tensor) -> tuple[Tensor, Tensor]:
    """For ``counts`` per item: the item index of every output element and its rank within the item."""
    item = torch.repeat_interleave(torch.arange(counts.numel(), device=counts.device), counts)
    first = torch.cumsum(counts, 0) - counts
    rank = torch.arange(item.numel(), device=counts.device) - first[item]
    return item, rank


@dataclass
class TileSpans:
    """Per projected Gaussian ``(M,)``: which tiles its bounding box overlaps.

    Rows ``i0..i1`` (inclusive pixel range, tile rows ``i0 // T .. i1 // T``: ``ny`` of them); columns
    as up to two intervals inside ``[0, W)``: ``a0..b0`` (``nx0`` tile columns) and, where the range
    wraps past the seam, ``a1..b1`` (``nx1``); ``j0`` is the unwrapped first column. ``count = ny *
    (nx0 + nx1)`` (Gaussian, tile) pairs.
    """

    i0: Tensor
    i1: Tensor
    j0: Tensor
    a0: Tensor
    b0: Tensor
    a1: Tensor
    b1: Tensor
    ny: Tensor
    nx0: Tensor
    nx1: Tensor
    tiles_x: int
    tiles_y: int

    @property
    def count(self) -> Tensor:
        return self.ny * (self.nx0 + self.nx1)


def tile_spans(proj: ProjectedGaussians, tile_size: int) -> TileSpans:
    """Per-Gaussian tile ranges and pair counts (stage 2's first step, shared by every binning)."""
    h, w, t = proj.height, proj.width, tile_size
    i0, i1, j0, j1 = _pixel_ranges(proj)
    ok = (i1 >= i0) & (j1 >= j0)
    # Up to two column intervals in [0, W): the second exists when the range wraps past the seam.
    if proj.wrap_u:
        a0 = torch.remainder(j0, w)
        end = a0 + (j1 - j0)
        b0 = end.clamp(max=w - 1)
        has_second = end >= w
        a1, b1 = torch.zeros_like(a0), end - w
    else:
        a0, b0 = j0, j1
        has_second = torch.zeros_like(ok)
        a1, b1 = torch.zeros_like(a0), torch.full_like(a0, -1)
    ny = torch.where(ok, i1 // t - i0 // t + 1, 0)
    nx0 = torch.where(ok, b0 // t - a0 // t + 1, 0)
    nx1 = torch.where(ok & has_second, b1 // t - a1 // t + 1, 0)
    return TileSpans(i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1, math.ceil(w / t), math.ceil(h / t))


def _emit_pairs(proj: ProjectedGaussians, spans: TileSpans, tile_size: int) -> TileBins:
    """Every (Gaussian, tile) pair, Gaussian-major, unsorted (the readable emission)."""
    t, w, s = tile_size, proj.width, spans
    nx = s.nx0 + s.nx1
    g, k = _expand(s.count)
    ty = k // nx[g] + s.i0[g] // t
    col = k % nx[g]
    second = col >= s.nx0[g]
    tx = torch.where(second, s.a1[g] // t + col - s.nx0[g], s.a0[g] // t + col)
    lo = torch.where(second, s.a1[g], s.a0[g])
    hi = torch.where(second, s.b1[g], s.b0[g])
    rows = torch.stack((torch.maximum(s.i0[g], ty * t), torch.minimum(s.i1[g], ty * t + t - 1)), dim=-1)
    cols = torch.stack((torch.maximum(lo, tx * t), torch.minimum(hi, tx * t + t - 1)), dim=-1)
    tile = proj.camera[g] * (s.tiles_x * s.tiles_y) + ty * s.tiles_x + tx
    shift = s.a0[g] - s.j0[g] - torch.where(second, w, 0)
    return TileBins(g, tile, rows, cols, shift, s.tiles_x, s.tiles_y)


def _select(bins: TileBins, order: Tensor) -> TileBins:
    return TileBins(bins.gaussian[order], bins.tile[order], bins.rows[order], bins.cols[order], bins.col_shift[order],
                    bins.tiles_x, bins.tiles_y)


def bin_to_tiles(proj: ProjectedGaussians, tile_size: int = 16) -> TileBins:
    """Stage 2: pair Gaussians with the tiles their bounding boxes overlap, sorted by (tile, depth).

    The readable definition: depth ranks (ties by Gaussian row), then one stable argsort of
    ``tile * M + rank`` (a Gaussian whose columns wrap around the seam can meet one tile twice, with
    disjoint columns: emission order). The fast backend's binning
    (:func:`.triton_binning.bin_to_tiles_by_key`) gives the same order."""
    pairs = _emit_pairs(proj, tile_spans(proj, tile_size), tile_size)
    depth_rank = torch.empty_like(proj.camera)
    depth_rank[torch.argsort(proj.depth.detach(), stable=True)] = torch.arange(len(proj.depth),
                                                                               device=depth_rank.device)
    return _select(pairs, torch.argsort(pairs.tile * max(len(proj.depth), 1) + depth_rank[pairs.gaussian], stable=True))


# Peak bytes per fragment of a forward + backward through this reference (measured: 6.3 M fragments
# -> 2.3 GiB peak RSS on CPU, see benchmarks/RESULTS.md), with some margin.
BYTES_PER_FRAGMENT = 400


class RenderMemoryError(MemoryError):
    """The reference rasterizer would need more memory than the device has free.

    Attributes: ``need``/``free`` (bytes), ``cameras`` (rendered at once), ``fragments``, ``device``, and
    ``facts`` (those in words); :meth:`advise` gives the same refusal with a caller's own advice (a command
    names its options there).
    """

    GENERIC_ADVICE = ("render at a lower resolution or fewer cameras at once, prune transparent Gaussians, or use "
                      "the Triton backend on a GPU")

    def __init__(self, need: int, free: int, fragments: int, cameras: int, device, advice: str = GENERIC_ADVICE,
                 what: str = "fragments"):
        self.need, self.free, self.fragments, self.cameras, self.device = need, free, fragments, cameras, device
        self.what = what
        self.facts = (f"this render of {cameras} view(s) at once needs about {need / 2**30:.1f} GiB for {fragments:,} "
                      f"{what} but {free / 2**30:.1f} GiB are free on {device}")
        self.advice = advice
        super().__init__(f"{self.facts}; {advice}")

    def advise(self, advice: str) -> "RenderMemoryError":
        """The same refusal, ending in ``advice`` instead."""
        return RenderMemoryError(self.need, self.free, self.fragments, self.cameras, self.device, advice, self.what)


def check_fragment_memory(num_fragments: int, device: torch.device, cameras: int = 1) -> None:
    """Refuse, with numbers and what to do, a render whose fragments would not fit in free memory
    (instead of swapping the machine to a halt or failing deep in the allocator)."""
    _check_memory(num_fragments, BYTES_PER_FRAGMENT, "fragments", device, cameras)


# Bytes per (Gaussian, tile, row) span of expand_fragments' first level: about twenty int64/float tensors.
BYTES_PER_ROW_SPAN = 200


def check_span_memory(num_spans: int, device: torch.device, cameras: int = 1) -> None:
    """:func:`check_fragment_memory` for the row spans fragments are cut from: Gaussians as large as the panorama
    make billions of them before a single fragment is counted."""
    _check_memory(num_spans, BYTES_PER_ROW_SPAN, "row spans", device, cameras)


# Bytes per (Gaussian, tile) pair of the CPU backend (.numba_backend): its entries, its copy of the Gaussian's row
# and spans, and ten gradients (float64 at most), with margin.
BYTES_PER_PAIR = 320


def check_pair_memory(num_pairs: int, device: torch.device, cameras: int = 1) -> None:
    """:func:`check_fragment_memory` for the CPU backend, whose memory grows with (Gaussian, tile) pairs."""
    _check_memory(num_pairs, BYTES_PER_PAIR, "tile pairs", device, cameras)


def _check_memory(count: int, per_item: int, what: str, device: torch.device, cameras: int) -> None:
    need = count * per_item
    free = available_memory(device)
    if free is not None and need > free:
        raise RenderMemoryError(need, free, count, cameras, device, what=what)


def expand_fragments(proj: ProjectedGaussians, bins: TileBins, sigma_extent: float = 3.0) -> tuple[Tensor, Tensor]:
    """Stage 3: ``(gaussian, pixel)`` of every fragment inside a support ellipse, sorted by pixel then depth.

    Each pair is cut into its rows; per row only the columns inside the ellipse
    ``d^T Sigma^-1 d <= sigma_extent^2`` are kept (solving the quadratic in ``d_u``), which avoids
    the bounding box's empty corners. ``pixel`` is ``camera * H * W + row * W + col`` (int64).
    """
    h, w = proj.height, proj.width
    # Level 1: (pair, row) items.
    nr = bins.rows[:, 1] - bins.rows[:, 0] + 1
    # Large footprints make many spans before a fragment is counted: refuse those first, by the same rule.
    check_span_memory(int(nr.sum()), nr.device, proj.num_cameras)
    pair, k = _expand(nr)
    row = bins.rows[pair, 0] + k
    g = bins.gaussian[pair]
    uv, conic = proj.uv.detach()[g], proj.conic.detach()[g]
    a, b, c = conic.unbind(-1)
    dv = row.to(uv.dtype) + 0.5 - uv[:, 1]
    # Columns of this row inside the ellipse: a du^2 + 2 b du dv + c dv^2 <= s^2.
    disc = (b * b - a * c) * dv * dv + sigma_extent**2 * a
    root = torch.sqrt(disc.clamp_min(0))
    lo = uv[:, 0] + (-b * dv - root) / a
    hi = uv[:, 0] + (-b * dv + root) / a
    shift = bins.col_shift[pair]
    col0 = torch.maximum(torch.ceil(lo - 0.5).long() + shift, bins.cols[pair, 0])
    col1 = torch.minimum(torch.floor(hi - 0.5).long() + shift, bins.cols[pair, 1])
    nc = torch.where(disc >= 0, (col1 - col0 + 1).clamp_min(0), 0)
    check_fragment_memory(int(nc.sum()), nc.device, proj.num_cameras)
    # Level 2: fragments.
    item, j = _expand(nc)
    col = col0[item] + j
    camera = bins.tile[pair[item]] // (bins.tiles_x * bins.tiles_y)
    pixel = (camera * h + row[item]) * w + col
    # Pairs are in (tile, depth) order and a pixel lies in one tile: a stable sort by pixel
    # yields (pixel, depth) order.
    order = torch.argsort(pixel, stable=True)
    return g[item[order]], pixel[order]


class _Composite(torch.autograd.Function):
    """Per-pixel front-to-back compositing with an analytic backward pass.

    Inputs: ``packed (M, 11)`` per projected Gaussian ``[u, v, A, B, C, opacity, r, g, b, depth, 1]``;
    fragments ``(gaussian, pixel)`` sorted by (pixel, depth). Output ``(num_pixels, 5)``:
    ``[r, g, b, depth, alpha]`` (no background).

    Backward (3DGS): with ``s_i = dL/dO . f_i`` and ``f_i = (colour, depth, 1)``,
    ``dL/dalpha_i = T_i s_i - (sum_{k > i} s_k w_k) / (1 - alpha_i)`` for contributing fragments;
    ``alpha = o exp(-m/2)`` (zero gradient where capped at 0.99), ``m = A du^2 + 2 B du dv + C dv^2``.
    """

    @staticmethod
    def forward(ctx, packed, frag_gaussian, frag_pixel, num_pixels, height, width, wrap_u, settings):
        f = packed[frag_gaussian]
        alpha, _, _, _, raw = _fragment_alpha(f, frag_pixel, height, width, wrap_u, settings)
        log_t = torch.log1p(-alpha.double())
        is_start, segment = _segments(frag_pixel)
        excl = _segmented_exclusive_cumsum(log_t, is_start, segment)
        alive = (excl + log_t) >= math.log(settings.transmittance_min)
        trans = torch.exp(excl).to(alpha.dtype)
        weight = alpha * trans * alive
        out = torch.zeros(num_pixels, 5, dtype=packed.dtype, device=packed.device)
        out.index_add_(0, frag_pixel, f[:, 6:] * weight[:, None])
        # Skipped (alpha < alpha_min) and terminated fragments have zero weight and zero gradient:
        # keep only the contributing ones for backward (exact; often most fragments are dead).
        used = alive & (alpha > 0)
        used_idx = used.nonzero().squeeze(1)
        if len(used_idx) < len(used):
            frag_gaussian, frag_pixel = frag_gaussian[used_idx], frag_pixel[used_idx]
            alpha, trans, alive, raw = alpha[used_idx], trans[used_idx], alive[used_idx], raw[used_idx]
        ctx.save_for_backward(packed, frag_gaussian, frag_pixel, alpha, trans, alive, raw)
        ctx.height, ctx.width, ctx.wrap_u, ctx.settings = height, width, wrap_u, settings
        return out

    @staticmethod
    def backward(ctx, grad_out):
        packed, frag_gaussian, frag_pixel, alpha, trans, alive, raw = ctx.saved_tensors
        f = packed[frag_gaussian]
        _, du, dv, _, _ = _fragment_alpha(f, frag_pixel, ctx.height, ctx.width, ctx.wrap_u, ctx.settings,
                                          need_alpha=False)
        g = grad_out[frag_pixel]  # (F, 5)
        weight = alpha * trans * alive
        s = (g * f[:, 6:]).sum(-1)
        # Suffix sums of s_k w_k within each pixel: total minus inclusive prefix (float64).
        sw = (s * weight).double()
        is_start, segment = _segments(frag_pixel)
        incl = _segmented_exclusive_cumsum(sw, is_start, segment) + sw
        total = torch.zeros(grad_out.shape[0], dtype=torch.float64, device=sw.device).index_add_(0, frag_pixel, sw)
        suffix = (total[frag_pixel] - incl).to(alpha.dtype)
        # Zero where the fragment did not contribute (skipped, terminated) or alpha was capped.
        use = alive & (alpha > 0) & (raw < ctx.settings.alpha_max)
        d_alpha = (trans * s - suffix / (1 - alpha)) * use
        d_mahal = -0.5 * alpha * d_alpha
        a, b, c = f[:, 2], f[:, 3], f[:, 4]
        grad_f = torch.empty_like(f)
        two_dm = 2 * d_mahal
        grad_f[:, 0] = -two_dm * (a * du + b * dv)
        grad_f[:, 1] = -two_dm * (b * du + c * dv)
        dm_du = d_mahal * du
        grad_f[:, 2] = dm_du * du
        grad_f[:, 3] = 2 * dm_du * dv
        grad_f[:, 4] = d_mahal * dv * dv
        grad_f[:, 5] = d_alpha * alpha / f[:, 5].clamp_min(1e-30)
        grad_f[:, 6:] = g * weight[:, None]
        grad_packed = torch.zeros_like(packed).index_add_(0, frag_gaussian, grad_f)
        return grad_packed, None, None, None, None, None, None, None


def _fragment_alpha(f, frag_pixel, height, width, wrap_u, settings, need_alpha=True):
    """Offsets, Mahalanobis distance and alpha of fragments (``f`` = gathered packed rows)."""
    cols = torch.remainder(frag_pixel, width)
    rows = torch.div(frag_pixel, width, rounding_mode="floor") % height
    du = cols.to(f.dtype) + 0.5 - f[:, 0]
    if wrap_u:
        du = torch.remainder(du + width / 2, width) - width / 2
    dv = rows.to(f.dtype) + 0.5 - f[:, 1]
    if not need_alpha:
        return None, du, dv, None, None
    mahal = f[:, 2] * du * du + 2 * f[:, 3] * du * dv + f[:, 4] * dv * dv
    raw = f[:, 5] * torch.exp(-0.5 * mahal)
    alpha = torch.clamp(raw, max=settings.alpha_max)
    keep = (mahal <= settings.sigma_extent**2) & (alpha >= settings.alpha_min)
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    return alpha, du, dv, mahal, raw


def _segments(sorted_keys: Tensor) -> tuple[Tensor, Tensor]:
    is_start = torch.ones_like(sorted_keys, dtype=torch.bool)
    is_start[1:] = sorted_keys[1:] != sorted_keys[:-1]
    return is_start, torch.cumsum(is_start, 0) - 1


def _segmented_exclusive_cumsum(x: Tensor, is_start: Tensor, segment: Tensor) -> Tensor:
    excl = torch.cumsum(x, 0) - x
    return excl - excl[is_start][segment]


def composite(
    proj: ProjectedGaussians,
    frag_gaussian: Tensor,
    frag_pixel: Tensor,
    settings: RasterSettings,
    background: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Stage 4: front-to-back compositing. Returns ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``."""
    h, w, c = proj.height, proj.width, proj.num_cameras
    out = _Composite.apply(pack_projected(proj), frag_gaussian, frag_pixel, c * h * w, h, w, proj.wrap_u, settings)
    return unpack_composited(out, proj, background)


def pack_projected(proj: ProjectedGaussians) -> Tensor:
    """Per-Gaussian compositing inputs, one row of 11: ``u v | conic a b c | opacity | r g b | depth | 1``.

    The trailing 1 accumulates alpha alongside colour and depth; both backends read this layout.
    """
    ones = torch.ones_like(proj.depth)[:, None]
    return torch.cat((proj.uv, proj.conic, proj.opacity[:, None], proj.color, proj.depth[:, None], ones), dim=-1)


def unpack_composited(
    out: Tensor, proj: ProjectedGaussians, background: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Per-pixel sums ``(C*H*W, 5)`` (rgb, depth, alpha) -> ``rgb (C, 3, H, W)`` over ``background``, depth, alpha."""
    out = out.view(proj.num_cameras, proj.height, proj.width, 5)
    depth, acc = out[..., 3], out[..., 4]
    return over_background(out[..., :3].permute(0, 3, 1, 2), acc, background), depth, acc


def over_background(rgb: Tensor, alpha: Tensor, background: Tensor | None) -> Tensor:
    """``rgb (C, 3, H, W)`` over ``background`` (``(3,)`` or ``(C, 3)``; None: as it is) by ``alpha (C, H, W)``."""
    if background is None:
        return rgb
    return rgb + (1 - alpha)[:, None] * background.to(rgb.dtype).view(-1, 3, 1, 1)


def rasterize(
    proj: ProjectedGaussians, settings: RasterSettings, background: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Stages 2-4 for a projection. Returns ``(C, 3, H, W), (C, H, W), (C, H, W)``."""
    bins = bin_to_tiles(proj, settings.tile_size)
    frag_gaussian, frag_pixel = expand_fragments(proj, bins, settings.sigma_extent)
    return composite(proj, frag_gaussian, frag_pixel, settings, background)
