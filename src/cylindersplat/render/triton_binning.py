"""The fast backend's tile binning: a depth sort, per-Gaussian tile counts, a prefix sum, key emission, one sort.

The arrangement gsplat uses (counts, an exclusive prefix sum that gives every Gaussian its place, key emission,
one radix sort), with the Gaussians sorted by depth first so that the keys need only the tile: the Gaussians are
sorted once by depth (a stable sort of ``M`` float32 keys: ties by row), their pairs emitted in that order with the
tile id as key, in the narrowest integer type that holds the tile count (int16 below 32768 tiles, else int32), and
one *stable* sort of those keys puts a pair's place in its tile at its Gaussian's depth rank (ties by row; a
Gaussian that meets one tile twice across the seam keeps its emission order) - the reference's order
(:func:`.rasterize.bin_to_tiles`, field by field wherever the depths are float32, as the Triton projection's are),
from 16 (or 32) key bits instead of 64. Three kernels (:mod:`.triton_binning_kernels`) each recompute a Gaussian's
tile spans from its centre and extent (:func:`.rasterize.tile_spans`' arithmetic in the same float type): the
counts, the emission (the key and the Gaussian's depth rank) and the pair fields, written once straight into their
sorted places (no gathers). On an H100 (benchmarks/RESULTS.md, 2026-11-26) this took 1.4 ms for 1.3 M Gaussians
(4.9 M tile pairs) against 9.1 ms for one radix sort of 64-bit ``tile << 32 | depth`` keys and 3.6 ms with
:func:`.rasterize.tile_spans`' thirty small PyTorch operations instead of the recomputation, variants removed since.
:func:`bin_ids` gives the same pairs carrying only their Gaussian's row (the compositing computes their pixel
rectangles: ``triton_backend.PAIR_FIELD = "ids"``).

:func:`bin_to_tiles_by_key` makes one host synchronisation: the pair count that sizes the buffers, read with the
render's deferred input checks (:func:`.projection.read_count`). :func:`bin_lean` (the lean forward) makes none
before the compositing is queued.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .projection import ProjectedGaussians, read_count
from .rasterize import TileBins

__all__ = ["bin_to_tiles_by_key", "bin_ids", "bin_lean", "PairBins", "tile_key_dtype"]

_BLOCK = 128


def bin_to_tiles_by_key(proj: ProjectedGaussians, tile_size: int = 16) -> TileBins:
    """:func:`.rasterize.bin_to_tiles` by a depth sort, per-Gaussian counts, a prefix sum, key emission and one
    sort by tile."""
    by_depth, centres, ends, total = _counted(proj, tile_size)
    tiles_x, tiles_y = math.ceil(proj.width / tile_size), math.ceil(proj.height / tile_size)
    if total == 0:
        return TileBins(*_pair_fields(0, proj.camera.device), tiles_x, tiles_y)
    return _write_bins(proj, centres, by_depth, ends, total, tile_size)


def _counted(proj: ProjectedGaussians, tile_size: int):
    """The first half of :func:`bin_to_tiles_by_key` and :func:`bin_ids`: the Gaussians' depth order (None for
    none), their centres and extents as the kernels read them, the inclusive prefix sum of their pair counts in
    depth order, and the pair count (the one host synchronisation)."""
    by_depth = None
    if len(proj.depth):
        # Gaussians in depth order (ties by row): their counts and places in that order.
        by_depth = torch.sort(proj.depth.detach().float(), stable=True).indices
    centres = _centres_and_extents(proj)  # once for the binning's three kernels (read in place)
    counts = _depth_order_counts(centres, by_depth, tile_size, proj)
    ends = torch.cumsum(counts, 0)
    total = read_count(proj, ends[-1:]) if len(counts) else 0  # the one host synchronisation: the output size
    return by_depth, centres, ends, total


def tile_key_dtype(num_tiles: int) -> torch.dtype:
    """The narrowest signed integer type that holds every tile id ``0 .. num_tiles - 1``."""
    return torch.int16 if num_tiles <= 2**15 else torch.int32


def _pair_fields(total: int, device) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Empty int64 pair fields of :class:`.rasterize.TileBins`: Gaussian, tile, rows (2), columns (2), column shift."""
    def empty(*shape):
        return torch.empty(total, *shape, dtype=torch.int64, device=device)

    return empty(), empty(), empty(2), empty(2), empty()


def _key_buffers(proj, total, num_tiles):
    keys = torch.empty(total, dtype=tile_key_dtype(num_tiles), device=proj.camera.device)
    return keys, torch.empty(total, dtype=torch.int32, device=proj.camera.device)


def _centres_and_extents(proj) -> tuple[Tensor, Tensor, int, int]:
    """``uv`` and ``extent`` in the float type :func:`.rasterize.tile_spans` computes in (their promotion), and their
    row strides: read in place where they have that type and side-by-side columns (the Triton projection's rows)."""
    uv, ext = proj.uv.detach(), proj.extent.detach()
    dtype = torch.promote_types(uv.dtype, ext.dtype)
    if uv.dtype == ext.dtype == dtype and uv.stride(-1) == ext.stride(-1) == 1 and len(uv) > 1:
        return uv, ext, uv.stride(0), ext.stride(0)
    return uv.to(dtype).contiguous(), ext.to(dtype).contiguous(), 2, 2


def _depth_order_counts(centres, by_depth, tile_size, proj):
    """Pair counts of the Gaussians in depth order, from their ``centres`` and extents (one kernel)."""
    from . import triton_binning_kernels as kernels

    num = len(proj.depth)
    counts = torch.empty(num, dtype=torch.int64, device=proj.camera.device)
    uv, ext, uv_stride, ext_stride = centres
    if num:
        kernels.count_pairs_kernel[((num + _BLOCK - 1) // _BLOCK,)](
            uv, ext, by_depth, counts, num, proj.height, proj.width, uv_stride, ext_stride, TILE=tile_size,
            WRAP_U=bool(proj.wrap_u), BLOCK=_BLOCK)
    return counts


def _write_bins(proj, centres, by_depth, ends, total, tile_size) -> TileBins:
    from . import triton_binning_kernels as kernels

    device = proj.camera.device
    num = len(by_depth)
    tiles_x, tiles_y = math.ceil(proj.width / tile_size), math.ceil(proj.height / tile_size)
    tiles_per_camera = tiles_x * tiles_y
    keys, rank = _key_buffers(proj, total, proj.num_cameras * tiles_per_camera)
    uv, ext, uv_stride, ext_stride = centres
    head = (uv, ext, proj.camera, by_depth, ends)
    constants = dict(TILE=tile_size, WRAP_U=bool(proj.wrap_u), BLOCK=_BLOCK)
    kernels.emit_fused_keys_kernel[((num + _BLOCK - 1) // _BLOCK,)](
        *head, keys, rank, num, proj.height, proj.width, uv_stride, ext_stride, tiles_x, tiles_per_camera,
        **constants)
    order = torch.sort(keys, stable=True).indices  # by tile; within a tile, emission (= depth) order
    gaussian, tile, rows, cols, shift = _pair_fields(total, device)
    kernels.write_fused_pairs_kernel[((total + _BLOCK - 1) // _BLOCK,)](
        *head, order, rank, gaussian, tile, rows, cols, shift, total, proj.height, proj.width, uv_stride, ext_stride,
        tiles_x, tiles_per_camera, **constants)
    return TileBins(gaussian, tile, rows, cols, shift, tiles_x, tiles_y)


# The lean binning's pair capacity per kind of render (device, cameras, height, width, tile size and the number of
# visible Gaussians to a power of two): it grows (with headroom) when a render needs more, so that after the first
# renders of a kind the buffers are sized without reading the pair count on the host (:func:`bin_lean`). Scenes of
# other sizes keep their own (a small scene does not sort the padding of a large one's capacity).
_CAPACITY: dict = {}
CAPACITY_HEADROOM = 1.25


@dataclass
class PairBins:
    """Pairs sorted by (tile, depth) in buffers of ``capacity`` places, with int32 fields and the tiles' first
    places (:func:`bin_lean`, :func:`bin_ids`).

    gaussian: (capacity,) int32 row of the ProjectedGaussians; rows/cols: (capacity, 2) int32 inclusive pixel
    ranges (:class:`.rasterize.TileBins`), or None where the pairs carry only their Gaussian (the compositing
    computes them); tile_start: (num_tiles + 1,) int64 first place of each tile (the last: the number of places
    used); total: (1,) int64 on the device, the pair count, which may exceed ``capacity`` (then the bins are
    incomplete: :func:`bin_lean` with a larger capacity)."""

    gaussian: torch.Tensor
    rows: torch.Tensor | None
    cols: torch.Tensor | None
    tile_start: torch.Tensor
    total: torch.Tensor
    capacity: int
    tiles_x: int
    tiles_y: int


_PINNED: list[int] = []  # pinned_capacity(): the innermost's capacity last


@contextlib.contextmanager
def pinned_capacity(capacity: int):
    """Within: every lean binning uses buffers of ``capacity`` pairs, whatever the cache says (a CUDA graph's
    capture: its buffers are sized for its own renders, :mod:`.graphs`)."""
    _PINNED.append(int(capacity))
    try:
        yield
    finally:
        _PINNED.pop()


def lean_capacity(proj: ProjectedGaussians, tile_size: int) -> tuple[tuple, int]:
    """The cache key of ``proj``'s kind of render and its current pair capacity (first guess: 4 per Gaussian; a
    :func:`pinned_capacity` where one holds)."""
    key = (str(proj.camera.device), proj.num_cameras, proj.height, proj.width, tile_size, len(proj.depth).bit_length())
    return key, (_PINNED[-1] if _PINNED else _CAPACITY.get(key, 4 * len(proj.depth) + 1024))


def grow_capacity(key: tuple, needed: int) -> int:
    """Record that ``needed`` pairs did not fit: the new capacity for ``key`` (with headroom)."""
    _CAPACITY[key] = max(_CAPACITY.get(key, 0), int(needed * CAPACITY_HEADROOM) + 1024)
    return _CAPACITY[key]


def settle_capacity(key: tuple, needed: int) -> None:
    """Record the pairs of the first render of ``key``'s kind: its capacity becomes theirs with headroom, below the
    first guess where they are fewer (every place is sorted and written: a pinhole view of 1.3 M Gaussians made 3.2 M
    pairs, where the guess keeps 5.2 M places). Later renders only grow it (:func:`grow_capacity`)."""
    if key not in _CAPACITY and not _PINNED:
        _CAPACITY[key] = int(needed * CAPACITY_HEADROOM) + 1024


def _strided_rows(x: torch.Tensor) -> tuple[torch.Tensor, int]:
    """``x (M, k)`` float with unit column stride, and its row stride (a copy only where the columns are apart)."""
    if x.stride(-1) != 1 or x.dtype not in (torch.float32, torch.float64):
        x = x.float().contiguous()
    return x, (x.stride(0) if len(x) > 1 else x.shape[1])


def bin_lean(proj: ProjectedGaussians, tile_size: int, capacity: int, rects: bool = True) -> PairBins:
    """:func:`bin_to_tiles_by_key` without a host synchronisation: the centres and extents read in place, buffers of
    ``capacity`` pairs (the padding sorts last), int32 pair fields and the tiles' first places written by the last
    kernel. Two sorts and four launches: depth sort, count (and the key buffer's fill), prefix sum, emission, tile
    sort, writing. ``rects=False``: the pairs carry only their Gaussian's row (no pixel rectangles)."""
    from . import triton_binning_kernels as kernels

    device = proj.camera.device
    num = len(proj.depth)
    tiles_x, tiles_y = math.ceil(proj.width / tile_size), math.ceil(proj.height / tile_size)
    tiles_per_camera = tiles_x * tiles_y
    num_tiles = proj.num_cameras * tiles_per_camera
    uv, uv_stride = _strided_rows(proj.uv.detach())
    ext, ext_stride = _strided_rows(proj.extent.detach())
    if ext.dtype != uv.dtype:  # tile_spans computes in the promoted type
        uv, ext = uv.to(torch.float64).contiguous(), ext.to(torch.float64).contiguous()
        uv_stride = ext_stride = 2
    constants = dict(TILE=tile_size, WRAP_U=bool(proj.wrap_u), BLOCK=_BLOCK)
    key_dtype = tile_key_dtype(num_tiles)
    keys = torch.empty(capacity, dtype=key_dtype, device=device)  # filled by the count kernel: padding sorts last
    rank = torch.empty(capacity, dtype=torch.int32, device=device)
    by_depth = (torch.sort(proj.depth.detach().float(), stable=True).indices if num
                else torch.zeros(1, dtype=torch.int64, device=device))
    counts = (torch.empty if num else torch.zeros)(max(num, 1), dtype=torch.int64, device=device)  # none: total 0
    lanes = max(num, capacity, 1)
    kernels.count_lean_kernel[((lanes + _BLOCK - 1) // _BLOCK,)](
        uv, ext, by_depth, counts, keys, num, capacity, torch.iinfo(key_dtype).max, proj.height, proj.width,
        uv_stride, ext_stride, **constants)
    ends = torch.cumsum(counts, 0)
    total = ends[-1:]
    head = (uv, ext, proj.camera, by_depth, ends)
    if num:
        kernels.emit_lean_keys_kernel[((num + _BLOCK - 1) // _BLOCK,)](
            *head, keys, rank, num, capacity, proj.height, proj.width, uv_stride, ext_stride, tiles_x,
            tiles_per_camera, ROW_IDS=not rects, **constants)
    return _write_pair_bins(head, keys, rank, total, capacity, num_tiles, tiles_x, tiles_y, proj, uv_stride,
                            ext_stride, rects, constants)


def bin_ids(proj: ProjectedGaussians, tile_size: int) -> PairBins:
    """:func:`bin_to_tiles_by_key`'s pairs (the same order, after the same one host synchronisation) carrying only
    their Gaussian's row, in int32, with the tiles' first places: no pixel rectangles, tile ids or column shifts
    (the compositing computes a pair's rectangle from its Gaussian's centre and extents: ``rects=False`` in
    :mod:`.triton_kernels`). 4 bytes a pair written once after the sort, against 56 (``PAIR_FIELD = "rects"``)."""
    from . import triton_binning_kernels as kernels

    by_depth, centres, ends, total = _counted(proj, tile_size)
    tiles_x, tiles_y = math.ceil(proj.width / tile_size), math.ceil(proj.height / tile_size)
    num_tiles = proj.num_cameras * tiles_x * tiles_y
    device = proj.camera.device
    if total == 0:
        return PairBins(torch.empty(0, dtype=torch.int32, device=device), None, None,
                        torch.zeros(num_tiles + 1, dtype=torch.int64, device=device),
                        torch.zeros(1, dtype=torch.int64, device=device), 0, tiles_x, tiles_y)
    uv, ext, uv_stride, ext_stride = centres
    keys, rank = _key_buffers(proj, total, num_tiles)
    head = (uv, ext, proj.camera, by_depth, ends)
    constants = dict(TILE=tile_size, WRAP_U=bool(proj.wrap_u), BLOCK=_BLOCK)
    kernels.emit_fused_keys_kernel[((len(by_depth) + _BLOCK - 1) // _BLOCK,)](
        *head, keys, rank, len(by_depth), proj.height, proj.width, uv_stride, ext_stride, tiles_x, tiles_x * tiles_y,
        ROW_IDS=True, **constants)
    return _write_pair_bins(head, keys, rank, ends[-1:], total, num_tiles, tiles_x, tiles_y, proj, uv_stride,
                            ext_stride, False, constants)


def _write_pair_bins(head, keys, rank, total, capacity, num_tiles, tiles_x, tiles_y, proj, uv_stride, ext_stride,
                     rects, constants) -> PairBins:
    """The sort by tile and the last kernel of :func:`bin_lean` and :func:`bin_ids`: the pairs' int32 fields in
    sorted order and the tiles' first places."""
    from . import triton_binning_kernels as kernels

    device = proj.camera.device
    sorted_keys, order = torch.sort(keys, stable=True)  # by tile; within a tile, emission (= depth) order
    gaussian = torch.empty(capacity, dtype=torch.int32, device=device)
    rows = cols = None
    if rects:
        rows = torch.empty(capacity, 2, dtype=torch.int32, device=device)
        cols = torch.empty(capacity, 2, dtype=torch.int32, device=device)
    tile_start = torch.empty(num_tiles + 1, dtype=torch.int64, device=device)
    kernels.write_lean_pairs_kernel[(capacity // _BLOCK + 1,)](
        *head, total, order, sorted_keys, rank, gaussian, gaussian if rows is None else rows,
        gaussian if cols is None else cols, tile_start, capacity, num_tiles, proj.height, proj.width, uv_stride,
        ext_stride, tiles_x, num_tiles // proj.num_cameras, RECTS=rects, **constants)
    return PairBins(gaussian, rows, cols, tile_start, total, capacity, tiles_x, tiles_y)
