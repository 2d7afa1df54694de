"""The fast backend's tile binning: per-Gaussian tile counts, prefix sum, key emission, one sort.

The arrangement gsplat uses: :func:`.rasterize.tile_spans` counts each Gaussian's tiles, an exclusive
prefix sum gives every Gaussian its place, a Triton kernel (:mod:`.triton_binning_kernels`) writes
each pair with the 64-bit key ``tile << 32 | bits(float32 depth)``, and one stable sort of the keys
(a radix sort on CUDA) orders the pairs by (tile, depth) - no depth ranking, no second sort. Ties in
float32 depth keep the emission order (by Gaussian row), as the reference's ranking does, so the
result equals :func:`.rasterize.bin_to_tiles` wherever the depths are float32 (the Triton
projection's are).
"""

from __future__ import annotations

import torch

from .projection import ProjectedGaussians
from .rasterize import TileBins, tile_spans

__all__ = ["bin_to_tiles_by_key"]

_BLOCK = 128


def bin_to_tiles_by_key(proj: ProjectedGaussians, tile_size: int = 16) -> TileBins:
    """:func:`.rasterize.bin_to_tiles` by per-Gaussian counts, a prefix sum, key emission and one sort."""
    from . import triton_binning_kernels as kernels

    spans = tile_spans(proj, tile_size)
    counts = spans.count
    offsets = torch.cumsum(counts, 0) - counts
    total = int(counts.sum()) if len(counts) else 0  # the one host synchronisation: the output size
    device = proj.camera.device
    keys = torch.empty(total, dtype=torch.int64, device=device)
    gaussian = torch.empty(total, dtype=torch.int64, device=device)
    rows = torch.empty(total, 2, dtype=torch.int64, device=device)
    cols = torch.empty(total, 2, dtype=torch.int64, device=device)
    shift = torch.empty(total, dtype=torch.int64, device=device)
    if total > 0:
        depth_bits = proj.depth.detach().float().contiguous().view(torch.int32)
        num = len(counts)
        kernels.emit_pairs_kernel[((num + _BLOCK - 1) // _BLOCK,)](
            proj.camera, depth_bits, spans.i0, spans.i1, spans.j0, spans.a0, spans.b0, spans.a1, spans.b1, spans.ny,
            spans.nx0, spans.nx1, offsets, keys, gaussian, rows, cols, shift, num, proj.width, spans.tiles_x,
            spans.tiles_x * spans.tiles_y, TILE=tile_size, BLOCK=_BLOCK)
    keys, order = torch.sort(keys, stable=True)
    return TileBins(gaussian[order], keys >> 32, rows[order], cols[order], shift[order], spans.tiles_x, spans.tiles_y)
