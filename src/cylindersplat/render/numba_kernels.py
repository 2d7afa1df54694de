"""Numba kernels of the CPU backend: tile binning, per-tile compositing and its backward pass.

Imported lazily by :mod:`.numba_backend` (the first CPU render compiles them, or loads them from
numba's on-disk cache). The rules are the reference's (:mod:`.rasterize`), stage by stage:

* **Spans** (:func:`tile_spans`): the support's bounding box in pixels, columns as up to two intervals in
  ``[0, W)`` (the second where the box wraps past the seam), as :func:`.rasterize.tile_spans`.
* **Binning** (:func:`bin_pairs`): a counting sort of (Gaussian, tile) pairs by tile, fed in depth order
  (:func:`depth_order`, a radix sort; ties by row, as the reference's stable ranking): every tile's pairs end up
  front to back. Runs of the depth order are counted and emitted in parallel, each run's pairs placed after the
  earlier runs' in every tile. A pair is ``2 * row + interval`` (int64), which names its pixel rectangle without
  storing it.
* **Compositing** (:func:`composite_forward`, one tile per parallel iteration): each pair visits only the
  pixels of its rectangle that can be inside its ellipse (per-row column ranges); ``du`` wraps into
  ``[-W/2, W/2)``; fragments outside the ``sigma_extent`` ellipse or with ``alpha < alpha_min`` are skipped;
  the fragment that would bring ``T`` below ``transmittance_min`` and all later ones are dropped; a tile stops
  once every pixel has. The pairs' rows are first copied into pair order (:func:`gather_pairs`), so the loop
  reads memory in order.
* **Backward** (:func:`composite_backward`): the same walk, front to back, with
  ``dL/dalpha_i = T_i s_i - (S - P_i) / (1 - alpha_i)`` (``s_i = g . f_i``, ``S = g . out``, ``P_i`` the
  running sum of ``s_k w_k``), per-pair gradients summed over the pair's pixels without races (a pair
  belongs to one tile), then added per Gaussian (:func:`reduce_pair_grads`).

The support test (offsets, Mahalanobis distance) runs in the dtype of the packed rows, in the
reference's order, so both backends test the same fragments; ``exp(-m/2)`` comes from a float64
recurrence along each row (:func:`_row_exponentials`), and transmittance, sums and gradients are float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _clamp_to_int(x):
    """``int(x)`` for an already rounded float, saturated far outside any image (no overflow)."""
    if x > 1e15:
        return np.int64(10**15)
    if x < -1e15:
        return np.int64(-10**15)
    return np.int64(x)


@njit(parallel=True, cache=True)
def tile_spans(uv, extent, height, width, tile, wrap_u, half):
    """Per projected Gaussian ``(M, 7)`` int64 ``i0, i1, a0, b0, a1, b1, shift`` (inclusive rows and up to two
    column intervals, ``b < a`` marks an empty one; ``shift``: wrapped minus unwrapped column in the first
    interval, ``shift - W`` in the second) and ``(M,)`` pair counts. ``half`` is 0.5 in the dtype of ``uv``."""
    m = uv.shape[0]
    spans = np.zeros((m, 7), np.int64)
    counts = np.zeros(m, np.int64)
    for k in prange(m):
        spans[k, 1] = spans[k, 3] = spans[k, 5] = -1
        u, v, eu, ev = uv[k, 0], uv[k, 1], extent[k, 0], extent[k, 1]
        if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(eu) and np.isfinite(ev)):
            continue
        i0 = max(_clamp_to_int(math.ceil(v - ev - half)), 0)
        i1 = min(_clamp_to_int(math.floor(v + ev - half)), height - 1)
        j0 = _clamp_to_int(math.ceil(u - eu - half))
        j1 = _clamp_to_int(math.floor(u + eu - half))
        if wrap_u:
            j1 = min(j1, j0 + width - 1)
        else:
            j0 = max(j0, 0)
            j1 = min(j1, width - 1)
        if i1 < i0 or j1 < j0:
            continue
        a1, b1 = 0, -1
        if wrap_u:
            a0 = j0 % width  # Python's modulo: in [0, W)
            end = a0 + (j1 - j0)
            b0 = min(end, width - 1)
            if end >= width:  # the box wraps past the seam
                b1 = end - width
        else:
            a0, b0 = j0, j1
        spans[k, 0] = i0
        spans[k, 1] = i1
        spans[k, 2] = a0
        spans[k, 3] = b0
        spans[k, 4] = a1
        spans[k, 5] = b1
        spans[k, 6] = a0 - j0
        nx = b0 // tile - a0 // tile + 1
        if b1 >= a1:
            nx += b1 // tile - a1 // tile + 1
        counts[k] = (i1 // tile - i0 // tile + 1) * nx
    return spans, counts


@njit(cache=True)
def _visit_pairs(spans, camera, per_camera, tiles_x, tile, lo, hi, counts, pairs, fill, order, emit):
    """Walk every pair of the Gaussians ``lo .. hi - 1`` of ``spans``/``camera`` (in depth order): count them per
    tile into ``counts`` (``emit`` False) or write them as ``2 * order[idx] + interval`` at ``fill`` (``emit``
    True)."""
    for idx in range(lo, hi):
        i0, i1 = spans[idx, 0], spans[idx, 1]
        if i1 < i0:
            continue
        base = camera[idx] * per_camera
        for ty in range(i0 // tile, i1 // tile + 1):
            for interval in range(2):
                a, b = spans[idx, 2 + 2 * interval], spans[idx, 3 + 2 * interval]
                if b < a:
                    continue
                for tx in range(a // tile, b // tile + 1):
                    t = base + ty * tiles_x + tx
                    if emit:
                        pairs[fill[t]] = 2 * order[idx] + interval
                        fill[t] += 1
                    else:
                        counts[t] += 1


# The depth sort's digits (four passes of 256 buckets: fewer write streams than 11-bit digits, faster here at 0.1 and
# 1 M) and its runs of the input, counted and placed in parallel.
_RADIX_RUNS = 8
_RADIX_BITS = 8
_RADIX_DIGITS = 1 << _RADIX_BITS


@njit(parallel=True, cache=True)
def depth_order(depth):
    """Rows of float32 ``depth`` in the order of ``(bits of depth as int32, row)``: a stable LSD radix sort of the
    32-bit patterns (positive depths sort by value), four passes, each counted and placed by runs in parallel.
    3-5x faster than ``np.sort`` of 64-bit ``bits << 32 | row`` keys (one thread), which it equals."""
    n = len(depth)
    bits = depth.view(np.uint32)
    keys, rows = np.empty(n, np.uint32), np.empty(n, np.int64)
    for i in prange(n):
        keys[i] = bits[i] ^ np.uint32(0x80000000)  # the int32 order as an unsigned one
        rows[i] = i
    next_keys, next_rows = np.empty(n, np.uint32), np.empty(n, np.int64)
    run = (n + _RADIX_RUNS - 1) // _RADIX_RUNS
    for shift in range(0, 32, _RADIX_BITS):
        place = np.zeros((_RADIX_RUNS, _RADIX_DIGITS), np.int64)
        for r in prange(_RADIX_RUNS):
            for i in range(r * run, min(n, r * run + run)):
                place[r, (keys[i] >> shift) & (_RADIX_DIGITS - 1)] += 1
        total = 0
        for d in range(_RADIX_DIGITS):  # counts -> each run's first place per digit (after the earlier runs')
            for r in range(_RADIX_RUNS):
                count = place[r, d]
                place[r, d] = total
                total += count
        for r in prange(_RADIX_RUNS):
            for i in range(r * run, min(n, r * run + run)):
                d = (keys[i] >> shift) & (_RADIX_DIGITS - 1)
                next_keys[place[r, d]] = keys[i]
                next_rows[place[r, d]] = rows[i]
                place[r, d] += 1
        keys, next_keys = next_keys, keys
        rows, next_rows = next_rows, rows
    return rows


# Runs of the depth order counted and emitted in parallel (each run's pairs go after the previous runs' in every
# tile, so the pairs come out as the serial counting sort puts them).
_BIN_RUNS = 8


@njit(parallel=True, cache=True)
def bin_pairs(order, spans, camera, num_cameras, tiles_x, tiles_y, tile):
    """Pairs sorted by (tile, depth): ``tile_start (T + 1,)`` and ``pairs (P,)`` = ``2 * row + interval``.

    ``order``: rows by depth (ties by row). A counting sort by tile keeps that order within each tile."""
    per_camera = tiles_x * tiles_y
    num_tiles = num_cameras * per_camera
    num = len(order)
    # Both passes read the Gaussians in depth order: gather them into that order once (independent loads)
    # rather than jumping through memory twice.
    sorted_spans = np.empty((num, spans.shape[1]), np.int64)
    sorted_camera = np.empty(num, np.int64)
    for idx in prange(num):
        for j in range(spans.shape[1]):  # (element loops: row slices cost more than their copies, gather_pairs)
            sorted_spans[idx, j] = spans[order[idx], j]
        sorted_camera[idx] = camera[order[idx]]
    run = (num + _BIN_RUNS - 1) // _BIN_RUNS
    counts = np.zeros((_BIN_RUNS, num_tiles), np.int64)
    none = np.empty(0, np.int64)
    for r in prange(_BIN_RUNS):
        _visit_pairs(sorted_spans, sorted_camera, per_camera, tiles_x, tile, r * run, min(num, r * run + run),
                     counts[r], none, none, order, False)
    # Each tile's first place, and each run's first place in each tile (after the earlier runs').
    start = np.empty(num_tiles + 1, np.int64)
    fill = np.empty((_BIN_RUNS, num_tiles), np.int64)
    placed = 0
    for t in range(num_tiles):
        start[t] = placed
        for r in range(_BIN_RUNS):
            fill[r, t] = placed
            placed += counts[r, t]
    start[num_tiles] = placed
    pairs = np.empty(placed, np.int64)
    for r in prange(_BIN_RUNS):
        _visit_pairs(sorted_spans, sorted_camera, per_camera, tiles_x, tile, r * run, min(num, r * run + run),
                     none, pairs, fill[r], order, True)
    return start, pairs


@njit(cache=True)
def _offsets(u, v, a, b, c, row_center, col_center, consts, wrap_u):
    """Offsets and Mahalanobis distance at one pixel (packed dtype, the reference's order of operations)."""
    du = col_center - u
    if wrap_u:
        x = du + consts[1]
        if x < 0 or x >= consts[0]:  # the reference's remainder (exact, and the identity inside [0, W))
            x = x % consts[0]
        du = x - consts[1]
    dv = row_center - v
    return du, dv, a * du * du + consts[2] * b * du * dv + c * dv * dv


@njit(cache=True)
def _pair_reach(spans, g, interval, u, a, b, c, o, sigma2, alpha_min, width):
    """What the per-row column ranges of a pair need: its Gaussian's centre in the interval's (wrapped)
    columns and the squared Mahalanobis radius beyond which no fragment passes (``sigma_extent^2``, or
    less where the opacity cannot reach ``alpha_min`` there: ``o exp(-m / 2) < alpha_min``)."""
    centre = np.float64(u) + spans[g, 6] - interval * width
    reach = np.float64(sigma2)
    if o > 0 and alpha_min > 0:
        reach = min(reach, 2.0 * math.log(np.float64(o) / np.float64(alpha_min)))
    return centre, reach


@njit(cache=True)
def _row_columns(row_center, v, a, b, c, centre, reach, j0, j1):
    """Columns of row ``row_center`` inside ``[j0, j1]`` that can lie inside the ellipse ``m <= reach`` (the
    quadratic in ``du`` solved in float64 and widened by a pixel each side: every fragment is still tested)."""
    a64, b64, c64 = np.float64(a), np.float64(b), np.float64(c)
    if not a64 > 0:
        return j0, j1
    dv = np.float64(row_center) - np.float64(v)
    disc = (b64 * b64 - a64 * c64) * dv * dv + reach * a64
    if disc < 0:
        return j0, j0 - 1
    if not disc < 1e300:  # inf or NaN: no bound
        return j0, j1
    root = math.sqrt(disc)
    lo = centre + (-b64 * dv - root) / a64
    hi = centre + (-b64 * dv + root) / a64
    if lo - 1.5 > j0:
        j0 = np.int64(math.ceil(lo - 0.5)) - 1
    if hi + 1.5 < j1:
        j1 = np.int64(math.floor(hi - 0.5)) + 1
    return j0, j1


@njit(cache=True)
def _row_exponentials(row_center, first_center, v, a, b, c, centre):
    """``exp(-m/2)`` at a row's first column and its ratio to the next column's, in float64.

    Along a row ``m`` is quadratic in ``du``, so ``exp(-m/2)`` steps by a factor that itself steps by
    ``exp(-A)`` (exact to float64 rounding over a tile's width): two exponentials per row instead of one
    per fragment, which dominated the loop."""
    a64, b64, c64 = np.float64(a), np.float64(b), np.float64(c)
    du = np.float64(first_center) - centre
    dv = np.float64(row_center) - np.float64(v)
    gauss = math.exp(-0.5 * (a64 * du * du + 2.0 * b64 * du * dv + c64 * dv * dv))
    step = math.exp(-0.5 * (a64 * (2.0 * du + 1.0) + 2.0 * b64 * dv))
    return gauss, step


@njit(cache=True)
def _tile_box(t, per_camera, tiles_x, tile, height, width):
    cam, local = t // per_camera, t % per_camera
    r_lo, c_lo = (local // tiles_x) * tile, (local % tiles_x) * tile
    return cam, r_lo, min(r_lo + tile, height) - 1, c_lo, min(c_lo + tile, width) - 1


@njit(cache=True)
def _rectangle(spans, g, interval, r_lo, r_hi, c_lo, c_hi):
    """Pixel rectangle of a pair: its Gaussian's rows / column interval inside the tile."""
    return (max(spans[g, 0], r_lo), min(spans[g, 1], r_hi),
            max(spans[g, 2 + 2 * interval], c_lo), min(spans[g, 3 + 2 * interval], c_hi))


@njit(parallel=True, cache=True)
def composite_forward(packed, pairs, tile_start, spans, centers, consts, height, width, tiles_x, tile, wrap_u, t_min):
    """``out (C * H * W, 5)`` float64: ``[r, g, b, depth, alpha]`` per pixel (no background).

    ``centers``: pixel centres ``i + 0.5``; ``consts``: ``W, W / 2, 2, -1/2, sigma_extent^2, alpha_max,
    alpha_min``, both in the packed dtype."""
    num_tiles = len(tile_start) - 1
    per_camera = tiles_x * ((height + tile - 1) // tile)
    out = np.zeros((num_tiles // per_camera * height * width, 5), np.float64)
    sigma2, alpha_max, alpha_min = consts[4], consts[5], consts[6]
    for t in prange(num_tiles):
        cam, r_lo, r_hi, c_lo, c_hi = _tile_box(t, per_camera, tiles_x, tile, height, width)
        trans = np.ones(tile * tile, np.float64)
        alive = np.ones(tile * tile, np.bool_)
        acc = np.zeros((tile * tile, 5), np.float64)
        n_alive = (r_hi - r_lo + 1) * (c_hi - c_lo + 1)
        for p in range(tile_start[t], tile_start[t + 1]):
            if n_alive == 0:
                break
            g, interval = pairs[p] >> 1, pairs[p] & 1
            i0, i1, j0, j1 = _rectangle(spans, g, interval, r_lo, r_hi, c_lo, c_hi)
            u, v, a, b, c, o = packed[g, 0], packed[g, 1], packed[g, 2], packed[g, 3], packed[g, 4], packed[g, 5]
            cr, cg, cb, cd = packed[g, 6], packed[g, 7], packed[g, 8], packed[g, 9]
            centre, reach = _pair_reach(spans, g, interval, u, a, b, c, o, sigma2, alpha_min, width)
            decay = math.exp(-np.float64(a))
            for row in range(i0, i1 + 1):
                k0, k1 = _row_columns(centers[row], v, a, b, c, centre, reach, j0, j1)
                gauss, step = _row_exponentials(centers[row], centers[k0], v, a, b, c, centre)
                for col in range(k0, k1 + 1):
                    k = (row - r_lo) * tile + (col - c_lo)
                    value = gauss
                    gauss *= step
                    step *= decay
                    if not alive[k]:
                        continue
                    du, dv, mahal = _offsets(u, v, a, b, c, centers[row], centers[col], consts, wrap_u)
                    if not mahal <= sigma2:
                        continue
                    raw = o * value
                    alpha = min(raw, alpha_max)
                    if not alpha >= alpha_min:
                        continue
                    after = trans[k] * (1.0 - alpha)
                    if after < t_min:
                        alive[k] = False
                        n_alive -= 1
                        continue
                    w = alpha * trans[k]
                    acc[k, 0] += w * cr
                    acc[k, 1] += w * cg
                    acc[k, 2] += w * cb
                    acc[k, 3] += w * cd
                    acc[k, 4] += w
                    trans[k] = after
        for row in range(r_lo, r_hi + 1):
            for col in range(c_lo, c_hi + 1):
                k = (row - r_lo) * tile + (col - c_lo)
                pixel = (cam * height + row) * width + col
                for ch in range(5):
                    out[pixel, ch] = acc[k, ch]
    return out


@njit(parallel=True, cache=True)
def composite_backward(packed, pairs, tile_start, spans, centers, consts, height, width, tiles_x, tile, wrap_u, t_min,
                       out, grad_out):
    """Per-pair gradients ``(P, 10)`` w.r.t. packed columns ``u, v, A, B, C, opacity, r, g, b, depth``.

    ``out``: the forward's float64 sums; ``grad_out``: ``dL/dout (C * H * W, 5)``; the rest as the forward's."""
    num_tiles = len(tile_start) - 1
    per_camera = tiles_x * ((height + tile - 1) // tile)
    pair_grads = np.zeros((len(pairs), 10), packed.dtype)
    sigma2, alpha_max, alpha_min = consts[4], consts[5], consts[6]
    for t in prange(num_tiles):
        cam, r_lo, r_hi, c_lo, c_hi = _tile_box(t, per_camera, tiles_x, tile, height, width)
        trans = np.ones(tile * tile, np.float64)
        alive = np.ones(tile * tile, np.bool_)
        grad = np.zeros((tile * tile, 5), np.float64)
        total = np.zeros(tile * tile, np.float64)  # S = g . out
        prefix = np.zeros(tile * tile, np.float64)  # P_i
        for row in range(r_lo, r_hi + 1):
            for col in range(c_lo, c_hi + 1):
                k = (row - r_lo) * tile + (col - c_lo)
                pixel = (cam * height + row) * width + col
                for ch in range(5):
                    grad[k, ch] = grad_out[pixel, ch]
                    total[k] += grad_out[pixel, ch] * out[pixel, ch]
        n_alive = (r_hi - r_lo + 1) * (c_hi - c_lo + 1)
        for p in range(tile_start[t], tile_start[t + 1]):
            if n_alive == 0:
                break
            g, interval = pairs[p] >> 1, pairs[p] & 1
            i0, i1, j0, j1 = _rectangle(spans, g, interval, r_lo, r_hi, c_lo, c_hi)
            u, v, a, b, c, o = packed[g, 0], packed[g, 1], packed[g, 2], packed[g, 3], packed[g, 4], packed[g, 5]
            cr, cg, cb, cd = packed[g, 6], packed[g, 7], packed[g, 8], packed[g, 9]
            a64, b64, c64 = np.float64(a), np.float64(b), np.float64(c)
            g_u, g_v, g_a, g_b, g_c, g_o = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            g_r, g_g, g_bl, g_d = 0.0, 0.0, 0.0, 0.0
            centre, reach = _pair_reach(spans, g, interval, u, a, b, c, o, sigma2, alpha_min, width)
            decay = math.exp(-np.float64(a))
            for row in range(i0, i1 + 1):
                k0, k1 = _row_columns(centers[row], v, a, b, c, centre, reach, j0, j1)
                gauss, step = _row_exponentials(centers[row], centers[k0], v, a, b, c, centre)
                for col in range(k0, k1 + 1):
                    k = (row - r_lo) * tile + (col - c_lo)
                    value = gauss
                    gauss *= step
                    step *= decay
                    if not alive[k]:
                        continue
                    du, dv, mahal = _offsets(u, v, a, b, c, centers[row], centers[col], consts, wrap_u)
                    if not mahal <= sigma2:
                        continue
                    raw = o * value
                    alpha = min(raw, alpha_max)
                    if not alpha >= alpha_min:
                        continue
                    after = trans[k] * (1.0 - alpha)
                    if after < t_min:
                        alive[k] = False
                        n_alive -= 1
                        continue
                    w = alpha * trans[k]
                    s = grad[k, 0] * cr + grad[k, 1] * cg + grad[k, 2] * cb + grad[k, 3] * cd + grad[k, 4]
                    prefix[k] += s * w
                    g_r += grad[k, 0] * w
                    g_g += grad[k, 1] * w
                    g_bl += grad[k, 2] * w
                    g_d += grad[k, 3] * w
                    if raw < alpha_max:  # a capped alpha passes no gradient to opacity or shape
                        d_alpha = trans[k] * s - (total[k] - prefix[k]) / (1.0 - alpha)
                        d_mahal = -0.5 * alpha * d_alpha
                        du64, dv64 = np.float64(du), np.float64(dv)
                        g_u -= 2.0 * d_mahal * (a64 * du64 + b64 * dv64)
                        g_v -= 2.0 * d_mahal * (b64 * du64 + c64 * dv64)
                        g_a += d_mahal * du64 * du64
                        g_b += 2.0 * d_mahal * du64 * dv64
                        g_c += d_mahal * dv64 * dv64
                        g_o += d_alpha * alpha
                    trans[k] = after
            pair_grads[p, 0] = g_u
            pair_grads[p, 1] = g_v
            pair_grads[p, 2] = g_a
            pair_grads[p, 3] = g_b
            pair_grads[p, 4] = g_c
            pair_grads[p, 5] = g_o / max(np.float64(o), 1e-30)
            pair_grads[p, 6] = g_r
            pair_grads[p, 7] = g_g
            pair_grads[p, 8] = g_bl
            pair_grads[p, 9] = g_d
    return pair_grads


@njit(parallel=True, cache=True)
def gather_pairs(packed, spans, pairs):
    """Each pair's packed row and spans in pair order, and pairs renumbered to them (``2 * p + interval``): the
    compositing loops then read memory in order instead of jumping between Gaussians (about a fifth faster)."""
    num, columns, span_columns = len(pairs), packed.shape[1], spans.shape[1]
    pair_packed = np.empty((num, columns), packed.dtype)
    pair_spans = np.empty((num, span_columns), np.int64)
    local = np.empty(num, np.int64)
    for p in prange(num):
        g = pairs[p] >> 1
        # Element loops, not row slices (``pair_packed[p] = packed[g]``): 4x faster here (1.9 against 8 ms for 0.2 M
        # pairs of 11 columns), the slices' views cost more than their copies.
        for j in range(columns):
            pair_packed[p, j] = packed[g, j]
        for j in range(span_columns):
            pair_spans[p, j] = spans[g, j]
        local[p] = 2 * p + (pairs[p] & 1)
    return pair_packed, pair_spans, local


@njit(cache=True)
def reduce_pair_grads(pairs, pair_grads, num_rows):
    """Per-Gaussian gradients ``(M, 11)`` (the constant last column gets none) from per-pair ones."""
    grads = np.zeros((num_rows, 11), np.float64)
    for p in range(len(pairs)):
        g = pairs[p] >> 1
        for c in range(10):
            grads[g, c] += pair_grads[p, c]
    return grads
