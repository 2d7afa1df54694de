"""Triton kernels of the fast backend's tile binning (:mod:`.triton_binning`): per-Gaussian pair counts, (Gaussian,
tile) pair emission with tile keys, and the pair fields written in sorted order.

Imported lazily by :mod:`.triton_binning` (``TRITON_INTERPRET=1`` must be set before the first import to select
Triton's CPU interpreter). One lane per projected Gaussian (in depth order) recomputes its tile spans from its centre
and extent with the rules of :class:`.rasterize.TileSpans` (:func:`_spans_strided`) and writes its pairs at its
offset (the exclusive prefix sum of the counts), Gaussian-major like the reference emission
(:func:`.rasterize._emit_pairs`); after the sort by tile, one lane per sorted place writes that pair's fields.
"""

from __future__ import annotations

import triton
import triton.language as tl


@triton.jit
def _store_pair_rect(rows_ptr, cols_ptr, at, i0, i1, a0, b0, a1, b1, ty, tx, second, mask, TILE: tl.constexpr):
    """A pair's pixel rectangle (its footprint's rows and columns inside its tile; ``second``: the part of a
    footprint wrapped across the seam) at place ``at``, in the fields' own integer type."""
    lo = tl.where(second, a1, a0)
    hi = tl.where(second, b1, b0)
    kind = rows_ptr.dtype.element_ty
    tl.store(rows_ptr + 2 * at, tl.maximum(i0, ty * TILE).to(kind), mask=mask)
    tl.store(rows_ptr + 2 * at + 1, tl.minimum(i1, ty * TILE + TILE - 1).to(kind), mask=mask)
    tl.store(cols_ptr + 2 * at, tl.maximum(lo, tx * TILE).to(kind), mask=mask)
    tl.store(cols_ptr + 2 * at + 1, tl.minimum(hi, tx * TILE + TILE - 1).to(kind), mask=mask)


@triton.jit
def _pair_tile(k, camera, i0, a0, a1, nx0, nx1, tiles_x, tiles_per_camera, TILE: tl.constexpr):
    """Tile row, tile column, second-interval flag and global tile id of a Gaussian's ``k``-th pair."""
    nx = nx0 + nx1
    nx_safe = tl.where(nx > 0, nx, 1).to(tl.int32)
    # Every value divided below is >= 0 (Triton's // truncates, torch's floors: they agree there). k and nx are
    # below 2**31 (a pair count): int32, whose division is far cheaper than int64's.
    k32 = (k + tl.zeros_like(nx_safe)).to(tl.int32)  # (k: a Python int in the interpreter's loops)
    ty = (k32 // nx_safe).to(tl.int64) + i0 // TILE
    col = (k32 % nx_safe).to(tl.int64)
    second = col >= nx0
    tx = tl.where(second, a1 // TILE + col - nx0, a0 // TILE + col)
    return ty, tx, second, camera * tiles_per_camera + ty * tiles_x + tx


@triton.jit
def _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask, height, width, TILE: tl.constexpr,
                   WRAP_U: tl.constexpr):
    """:func:`tile_spans` of Gaussians ``g`` whose centres and extents are ``uv_stride`` / ``ext_stride`` elements
    apart (e.g. the projection's ``(M, 8)`` rows, read in place)."""
    u = tl.load(uv_ptr + uv_stride * g, mask=mask, other=0.0)
    v = tl.load(uv_ptr + uv_stride * g + 1, mask=mask, other=0.0)
    eu = tl.load(ext_ptr + ext_stride * g, mask=mask, other=0.0)
    ev = tl.load(ext_ptr + ext_stride * g + 1, mask=mask, other=0.0)
    return tile_spans(u, v, eu, ev, height, width, TILE, WRAP_U)


@triton.jit
def tile_spans(u, v, eu, ev, height, width, TILE: tl.constexpr, WRAP_U: tl.constexpr):
    """:func:`.rasterize.tile_spans` of a Gaussian centred at pixel ``(u, v)`` with half-widths ``(eu, ev)``, the
    same arithmetic in the same float type: ``(i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1)`` (its pixel rows, first
    column, columns ``a0..b0`` and, wrapped across the seam, ``a1..b1``; its tile rows and the tile columns of each
    interval). Also the compositing's (:mod:`.triton_kernels`), where the pairs carry no pixel rectangle."""
    i0 = tl.maximum(tl.ceil(v - ev - 0.5), 0.0).to(tl.int64)
    i1 = tl.minimum(tl.floor(v + ev - 0.5), height - 1.0).to(tl.int64)
    j0 = tl.ceil(u - eu - 0.5).to(tl.int64)
    j1 = tl.floor(u + eu - 0.5).to(tl.int64)
    if WRAP_U:
        j1 = tl.minimum(j1, j0 + width - 1)
        rem = j0 % width  # Triton's % keeps the dividend's sign; torch.remainder the divisor's
        a0 = tl.where(rem < 0, rem + width, rem)
        end = a0 + (j1 - j0)
        b0 = tl.minimum(end, width - 1)
        a1 = tl.zeros_like(a0)
        b1 = end - width
        second = end >= width
    else:
        j0 = tl.maximum(j0, 0)
        j1 = tl.minimum(j1, width - 1)
        a0 = j0
        b0 = j1
        a1 = tl.zeros_like(a0)
        b1 = a1 - 1
        second = a1 != 0
    ok = (i1 >= i0) & (j1 >= j0)
    # Every value divided below is >= 0 where it is used (ok).
    ny = tl.where(ok, i1 // TILE - i0 // TILE + 1, 0)
    nx0 = tl.where(ok, b0 // TILE - a0 // TILE + 1, 0)
    nx1 = tl.where(ok & second, b1 // TILE - a1 // TILE + 1, 0)
    return i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1


@triton.jit
def _sorted_pair(uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, rank_ptr, at, mask, height, width, uv_stride,
                 ext_stride, tiles_x, tiles_per_camera, TILE: tl.constexpr, WRAP_U: tl.constexpr):
    """The pair emitted at place ``at`` (the ``k``-th of the Gaussian of depth rank ``rank[at]``): its Gaussian's
    row, pixel rows ``i0, i1``, first column ``j0``, column intervals ``a0..b0`` / ``a1..b1``, tile row and column,
    second-interval flag and tile id."""
    i = tl.load(rank_ptr + at, mask=mask, other=0)
    g = tl.load(by_depth_ptr + i, mask=mask, other=0)
    camera = tl.load(camera_ptr + g, mask=mask, other=0)
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask,
                                                              height, width, TILE, WRAP_U)
    k = at - (tl.load(end_ptr + i, mask=mask, other=0) - ny * (nx0 + nx1))
    ty, tx, second, tile = _pair_tile(k, camera, i0, a0, a1, nx0, nx1, tiles_x, tiles_per_camera, TILE)
    return g, i0, i1, j0, a0, b0, a1, b1, ty, tx, second, tile


@triton.jit
def count_pairs_kernel(
    uv_ptr, ext_ptr, by_depth_ptr, count_ptr, num_gaussians, height, width, uv_stride, ext_stride,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr,
):
    """The binning's first pass: the pair count of the Gaussian of depth rank ``i`` (centres and extents
    ``uv_stride`` / ``ext_stride`` elements apart: read in place)."""
    i = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    mask = i < num_gaussians
    g = tl.load(by_depth_ptr + i, mask=mask, other=0)
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask,
                                                              height, width, TILE, WRAP_U)
    tl.store(count_ptr + i, ny * (nx0 + nx1), mask=mask)


@triton.jit
def emit_fused_keys_kernel(
    uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, key_ptr, rank_ptr,
    num_gaussians, height, width, uv_stride, ext_stride, tiles_x, tiles_per_camera,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr, ROW_IDS: tl.constexpr = False,
):
    """The emission: lane ``i`` takes the Gaussian of depth rank ``i`` and writes its pairs' tile ids (the sort
    keys, int16 or int32) and ``i`` at its offset (``end``: the inclusive prefix sum of the counts in depth
    order); with ``ROW_IDS``, the Gaussian's row instead of ``i`` (pairs that carry only their Gaussian)."""
    i = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    mask = i < num_gaussians
    g = tl.load(by_depth_ptr + i, mask=mask, other=0)
    camera = tl.load(camera_ptr + g, mask=mask, other=0)
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask,
                                                              height, width, TILE, WRAP_U)
    count = ny * (nx0 + nx1)
    start = tl.load(end_ptr + i, mask=mask, other=0) - count
    for k in range(0, tl.max(count, axis=0)):
        on = mask & (k < count)
        ty, tx, second, tile = _pair_tile(k, camera, i0, a0, a1, nx0, nx1, tiles_x, tiles_per_camera, TILE)
        tl.store(key_ptr + start + k, tile.to(key_ptr.dtype.element_ty), mask=on)
        tl.store(rank_ptr + start + k, (g if ROW_IDS else i).to(tl.int32), mask=on)


@triton.jit
def write_fused_pairs_kernel(
    uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, order_ptr, rank_ptr,
    gaussian_ptr, tile_ptr, rows_ptr, cols_ptr, shift_ptr,
    num_pairs, height, width, uv_stride, ext_stride, tiles_x, tiles_per_camera,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr,
):
    """The pair fields, one lane per sorted place ``q``: the pair emitted at ``order[q]`` is the ``k``-th of the
    Gaussian of depth rank ``rank[order[q]]``."""
    q = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    mask = q < num_pairs
    at = tl.load(order_ptr + q, mask=mask, other=0)
    g, i0, i1, j0, a0, b0, a1, b1, ty, tx, second, tile = _sorted_pair(
        uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, rank_ptr, at, mask, height, width, uv_stride, ext_stride,
        tiles_x, tiles_per_camera, TILE, WRAP_U)
    tl.store(gaussian_ptr + q, g.to(tl.int64), mask=mask)
    tl.store(tile_ptr + q, tile.to(tl.int64), mask=mask)
    _store_pair_rect(rows_ptr, cols_ptr, q, i0, i1, a0, b0, a1, b1, ty, tx, second, mask, TILE)
    tl.store(shift_ptr + q, a0 - j0 - tl.where(second, width, 0), mask=mask)


# The lean binning (:func:`.triton_binning.bin_lean`): the binning's three kernels into buffers of a cached capacity
# that the device-side pair count may exceed (nothing is written past it: the caller reruns with a larger one), with
# int32 pair fields and the tiles' first places written by the last kernel (no tile ids, no column shifts, no
# searchsorted).


@triton.jit
def count_lean_kernel(
    uv_ptr, ext_ptr, by_depth_ptr, count_ptr, key_ptr, num_gaussians, capacity, pad, height, width, uv_stride,
    ext_stride, TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr,
):
    """:func:`count_pairs_kernel` on strided centres and extents, and the key buffer's fill: ``pad`` (past every
    tile id: places the emission leaves unwritten sort last) at its ``capacity`` places. Launch with at least
    ``max(num_gaussians, capacity)`` lanes."""
    i = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    tl.store(key_ptr + i, tl.full([BLOCK], pad, tl.int32).to(key_ptr.dtype.element_ty), mask=i < capacity)
    mask = i < num_gaussians
    g = tl.load(by_depth_ptr + i, mask=mask, other=0)
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask,
                                                              height, width, TILE, WRAP_U)
    tl.store(count_ptr + i, ny * (nx0 + nx1), mask=mask)


@triton.jit
def emit_lean_keys_kernel(
    uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, key_ptr, rank_ptr,
    num_gaussians, capacity, height, width, uv_stride, ext_stride, tiles_x, tiles_per_camera,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr, ROW_IDS: tl.constexpr = False,
):
    """:func:`emit_fused_keys_kernel` on strided centres and extents; places at or past ``capacity`` are not
    written (the pair count, ``end[-1]``, tells the caller to rerun with more)."""
    i = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    mask = i < num_gaussians
    g = tl.load(by_depth_ptr + i, mask=mask, other=0)
    camera = tl.load(camera_ptr + g, mask=mask, other=0)
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = _spans_strided(uv_ptr, ext_ptr, uv_stride, ext_stride, g, mask,
                                                              height, width, TILE, WRAP_U)
    count = ny * (nx0 + nx1)
    start = tl.load(end_ptr + i, mask=mask, other=0) - count
    for k in range(0, tl.max(count, axis=0)):
        on = mask & (k < count) & (start + k < capacity)
        ty, tx, second, tile = _pair_tile(k, camera, i0, a0, a1, nx0, nx1, tiles_x, tiles_per_camera, TILE)
        tl.store(key_ptr + start + k, tile.to(key_ptr.dtype.element_ty), mask=on)
        tl.store(rank_ptr + start + k, (g if ROW_IDS else i).to(tl.int32), mask=on)


@triton.jit
def write_lean_pairs_kernel(
    uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, total_ptr, order_ptr, sorted_key_ptr, rank_ptr,
    gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr,
    capacity, num_tiles, height, width, uv_stride, ext_stride, tiles_x, tiles_per_camera,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, BLOCK: tl.constexpr, RECTS: tl.constexpr = True,
):
    """:func:`write_fused_pairs_kernel` on strided centres and extents, int32 fields (Gaussian row, pixel rows
    and columns) for the ``used = min(total, capacity)`` sorted places, and the tiles' first places: lane
    ``q <= used`` writes ``tile_start[t] = q`` for the tiles ``t`` after the previous place's and up to its own
    (a place ``>= used`` counts as past every tile, so ``tile_start[num_tiles] = used``). Launch with at least
    ``capacity + 1`` lanes. ``RECTS=False``: the pairs carry only their Gaussian's row, which the emission wrote in
    ``rank`` (``ROW_IDS``); no pixel rectangle (``rows``, ``cols``, and the spans' inputs are not read)."""
    q = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    used = tl.minimum(tl.load(total_ptr), capacity)
    mask = q < used
    at = tl.load(order_ptr + q, mask=mask, other=0)
    if RECTS:
        g, i0, i1, j0, a0, b0, a1, b1, ty, tx, second, tile = _sorted_pair(
            uv_ptr, ext_ptr, camera_ptr, by_depth_ptr, end_ptr, rank_ptr, at, mask, height, width, uv_stride,
            ext_stride, tiles_x, tiles_per_camera, TILE, WRAP_U)
        tl.store(gaussian_ptr + q, g.to(tl.int32), mask=mask)
        _store_pair_rect(rows_ptr, cols_ptr, q, i0, i1, a0, b0, a1, b1, ty, tx, second, mask, TILE)
    else:
        tl.store(gaussian_ptr + q, tl.load(rank_ptr + at, mask=mask, other=0).to(tl.int32), mask=mask)
    # The tiles' first places, from the sorted keys (every key < num_tiles).
    key = tl.load(sorted_key_ptr + q, mask=mask, other=0).to(tl.int32)
    key = tl.where(mask, key, num_tiles)
    before = (q > 0) & (q <= used)  # lanes with a previous place
    prev = tl.load(sorted_key_ptr + q - 1, mask=before, other=0).to(tl.int32)
    prev = tl.where(before, prev, -1)
    active = q <= used
    gap = tl.where(active, key - prev, 0)
    for t in range(1, tl.max(gap, axis=0) + 1):
        tl.store(tile_start_ptr + prev + t, q.to(tl.int64), mask=active & (t <= gap))
