"""Triton kernels of the fast backend: per-tile front-to-back compositing and its backward pass.

Imported lazily by :mod:`.triton_backend` (only when the Triton backend is used), so that
``TRITON_INTERPRET=1`` set by a test before the first call selects Triton's CPU interpreter.

One program per (camera, tile): its ``TILE x TILE`` pixels walk the tile's (Gaussian, tile) pairs in
depth order. The rules are the reference's (:mod:`.rasterize`): a pixel gets a fragment of pair
``p`` only inside the pair's pixel rectangle and the ``sigma_extent`` ellipse; ``du`` wraps into
``[-W/2, W/2)`` across the seam; ``alpha = min(alpha_max, o exp(-m/2))``, skipped below
``alpha_min``; the fragment that would bring the transmittance below ``transmittance_min`` and
all later ones are dropped. A tile stops early once all its pixels have terminated.

Packed Gaussian rows (``M x 11``, float32): ``[u, v, A, B, C, opacity, r, g, b, depth, 1]``; with the
constant ``LEAN=1`` (the lean forward, :data:`.triton_backend.FORWARD`) ``M x 12``: the projection's rows
``[u, v, A, B, C, extent u, extent v, depth]`` followed by ``[opacity, r, g, b]`` - one concatenation of the
projection's output, whose gradient goes back to it whole. :func:`_column` maps the ten parameters to their
columns.
"""

from __future__ import annotations

import triton
import triton.language as tl


@triton.jit
def _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE: tl.constexpr):
    camera = tile // tiles_per_camera
    local = tile % tiles_per_camera
    ty = local // tiles_x
    tx = local % tiles_x
    offs = tl.arange(0, TILE * TILE)
    row = ty * TILE + offs // TILE
    col = tx * TILE + offs % TILE
    inside = (row < height) & (col < width)
    pixel = (camera * height + row) * width + col
    return row, col, inside, pixel


@triton.jit
def _column(j, LEAN: tl.constexpr):
    """The packed column of parameter ``j`` (0-4: u, v, A, B, C; 5: opacity; 6-8: r, g, b; 9: depth)."""
    return tl.where(j < 5, j, tl.where(j == 9, 9 - 2 * LEAN, j + 3 * LEAN))


@triton.jit
def _fragment(packed_ptr, g, p, rows_ptr, cols_ptr, row, col, width, sigma2, alpha_max, alpha_min,
              WRAP_U: tl.constexpr, LEAN: tl.constexpr):
    """Offsets, alpha and the support mask of pair ``p`` (Gaussian ``g``) at the tile's pixels."""
    base = packed_ptr + g * (11 + LEAN)
    u = tl.load(base + 0)
    v = tl.load(base + 1)
    a = tl.load(base + 2)
    b = tl.load(base + 3)
    c = tl.load(base + 4)
    o = tl.load(base + 5 + 3 * LEAN)
    r0 = tl.load(rows_ptr + 2 * p)
    r1 = tl.load(rows_ptr + 2 * p + 1)
    c0 = tl.load(cols_ptr + 2 * p)
    c1 = tl.load(cols_ptr + 2 * p + 1)
    du = col.to(tl.float32) + 0.5 - u
    if WRAP_U:
        half = width * 0.5
        du = du + half
        du = du - width * tl.floor(du / width) - half
    dv = row.to(tl.float32) + 0.5 - v
    mahal = a * du * du + 2.0 * b * du * dv + c * dv * dv
    raw = o * tl.exp(-0.5 * mahal)
    alpha = tl.minimum(raw, alpha_max)
    support = (row >= r0) & (row <= r1) & (col >= c0) & (col <= c1) & (mahal <= sigma2) & (alpha >= alpha_min)
    return du, dv, alpha, raw, support, a, b, c, o


@triton.jit
def _colour(packed_ptr, g, LEAN: tl.constexpr):
    """Colour and radial depth of Gaussian ``g`` (columns 6-9 of its packed row; 9-11 and 7 with ``LEAN``)."""
    base = packed_ptr + g * (11 + LEAN)
    return (tl.load(base + 6 + 3 * LEAN), tl.load(base + 7 + 3 * LEAN), tl.load(base + 8 + 3 * LEAN),
            tl.load(base + 9 - 2 * LEAN))


@triton.jit
def _transmittance_step(trans, alpha, support, alive, t_min):
    """One fragment under the termination rule: ``(used, weight alpha*T, T after, alive after)``.

    The fragment that would bring ``T`` below ``t_min`` and all later ones are dropped."""
    frag = support & alive
    after = trans * (1.0 - alpha)
    use = frag & (after >= t_min)
    stop = frag & (after < t_min)
    w = tl.where(use, alpha * trans, 0.0)
    return use, w, tl.where(use, after, trans), alive & (stop == 0)


@triton.jit
def _add_gradients(gp, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, o, JOINED: tl.constexpr, LEAN: tl.constexpr):
    """``gp[j] += sum(x_j)`` over the tile's pixels (``/ max(o, 1e-30)`` for ``j = 5``, the opacity), for the
    ten packed parameters of one Gaussian.

    ``JOINED=False``: ten block-wide sums and ten scalar atomics. ``JOINED=True``: the ten per-pixel
    values joined into one ``(pixels, 2, 2, 2, 2)`` tensor (registers, no data movement), one block-wide
    sum of it (one pass through shared memory instead of ten, each with its barriers) and one vector
    atomic of the ten sums (six padding lanes masked off). ``gp``: the Gaussian's packed gradient row (columns by
    :func:`_column`)."""
    if JOINED:
        z = tl.zeros_like(x0)
        low = tl.join(tl.join(tl.join(x0, x1), tl.join(x2, x3)), tl.join(tl.join(x4, x5), tl.join(x6, x7)))
        high = tl.join(tl.join(tl.join(x8, x9), tl.join(z, z)), tl.join(tl.join(z, z), tl.join(z, z)))
        sums = tl.sum(tl.join(low, high), axis=0)  # sums[s1, s2, s3, s4] = sum of x_(s1 + 2 s2 + 4 s3 + 8 s4)
        bit = tl.arange(0, 2)
        j = (bit[:, None, None, None] + 2 * bit[None, :, None, None] + 4 * bit[None, None, :, None]
             + 8 * bit[None, None, None, :])
        tl.atomic_add(gp + _column(j, LEAN), sums / tl.where(j == 5, tl.maximum(o, 1e-30), 1.0), mask=j < 10)
    else:
        tl.atomic_add(gp + 0, tl.sum(x0, axis=0))
        tl.atomic_add(gp + 1, tl.sum(x1, axis=0))
        tl.atomic_add(gp + 2, tl.sum(x2, axis=0))
        tl.atomic_add(gp + 3, tl.sum(x3, axis=0))
        tl.atomic_add(gp + 4, tl.sum(x4, axis=0))
        tl.atomic_add(gp + 5 + 3 * LEAN, tl.sum(x5, axis=0) / tl.maximum(o, 1e-30))
        tl.atomic_add(gp + 6 + 3 * LEAN, tl.sum(x6, axis=0))
        tl.atomic_add(gp + 7 + 3 * LEAN, tl.sum(x7, axis=0))
        tl.atomic_add(gp + 8 + 3 * LEAN, tl.sum(x8, axis=0))
        tl.atomic_add(gp + 9 - 2 * LEAN, tl.sum(x9, axis=0))


@triton.jit
def _store_pixels(out_ptr, pixel, inside, acc_r, acc_g, acc_b, acc_d, acc_a):
    """A forward kernel's output per pixel: rgb, depth and alpha (= 1 - final transmittance), 5 values."""
    optr = out_ptr + pixel * 5
    tl.store(optr + 0, acc_r, mask=inside)
    tl.store(optr + 1, acc_g, mask=inside)
    tl.store(optr + 2, acc_b, mask=inside)
    tl.store(optr + 3, acc_d, mask=inside)
    tl.store(optr + 4, acc_a, mask=inside)


@triton.jit
def composite_forward_kernel(
    packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, out_ptr,
    height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, LEAN: tl.constexpr,
):
    tile = tl.program_id(0)
    row, col, inside, pixel = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    trans = tl.where(inside, 1.0, 0.0)
    alive = inside
    acc_r = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_g = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_b = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_d = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_a = tl.zeros([TILE * TILE], dtype=tl.float32)
    p = start
    n_alive = tl.sum(alive.to(tl.int32), axis=0)
    while (p < end) & (n_alive > 0):
        g = tl.load(pair_gaussian_ptr + p)
        du, dv, alpha, raw, support, a, b, c, o = _fragment(
            packed_ptr, g, p, rows_ptr, cols_ptr, row, col, width, sigma2, alpha_max, alpha_min, WRAP_U, LEAN)
        use, w, trans, alive = _transmittance_step(trans, alpha, support, alive, t_min)
        cr, cg, cb, cd = _colour(packed_ptr, g, LEAN)
        acc_r += w * cr
        acc_g += w * cg
        acc_b += w * cb
        acc_d += w * cd
        acc_a += w
        n_alive = tl.sum(alive.to(tl.int32), axis=0)
        p += 1
    _store_pixels(out_ptr, pixel, inside, acc_r, acc_g, acc_b, acc_d, acc_a)


@triton.jit
def _output_gradients(grad_out_ptr, out_ptr, pixel, inside):
    """The pixels' output gradients ``g`` (rgb, depth, alpha) and ``S = g . out`` (all contributions)."""
    gptr = grad_out_ptr + pixel * 5
    g_r = tl.load(gptr + 0, mask=inside, other=0.0)
    g_g = tl.load(gptr + 1, mask=inside, other=0.0)
    g_b = tl.load(gptr + 2, mask=inside, other=0.0)
    g_d = tl.load(gptr + 3, mask=inside, other=0.0)
    g_a = tl.load(gptr + 4, mask=inside, other=0.0)
    optr = out_ptr + pixel * 5
    total = (g_r * tl.load(optr + 0, mask=inside, other=0.0) + g_g * tl.load(optr + 1, mask=inside, other=0.0)
             + g_b * tl.load(optr + 2, mask=inside, other=0.0) + g_d * tl.load(optr + 3, mask=inside, other=0.0)
             + g_a * tl.load(optr + 4, mask=inside, other=0.0))
    return g_r, g_g, g_b, g_d, g_a, total


@triton.jit
def composite_backward_kernel(
    packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, out_ptr, grad_out_ptr, grad_packed_ptr,
    height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, JOINED: tl.constexpr, LEAN: tl.constexpr,
):
    """Front to back again: ``dL/dalpha_i = T_i s_i - (S - P_i) / (1 - alpha_i)`` with ``s_i = g . f_i``,
    ``S = g . out`` (all contributions) and ``P_i`` the running sum of ``s_k w_k`` up to ``i``.
    Per-pair gradients are summed over the tile's pixels and added atomically per Gaussian
    (:func:`_add_gradients`). ``JOINED``: fewer block-wide sums per pair (the ten gradients in one, and the
    counts of used and still-alive pixels in one), the same arithmetic per pixel."""
    tile = tl.program_id(0)
    row, col, inside, pixel = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    g_r, g_g, g_b, g_d, g_a, total = _output_gradients(grad_out_ptr, out_ptr, pixel, inside)
    trans = tl.where(inside, 1.0, 0.0)
    alive = inside
    prefix = tl.zeros([TILE * TILE], dtype=tl.float32)
    p = start
    n_alive = tl.sum(alive.to(tl.int32), axis=0)
    while (p < end) & (n_alive > 0):
        g = tl.load(pair_gaussian_ptr + p)
        du, dv, alpha, raw, support, a, b, c, o = _fragment(
            packed_ptr, g, p, rows_ptr, cols_ptr, row, col, width, sigma2, alpha_max, alpha_min, WRAP_U, LEAN)
        use, w, next_trans, next_alive = _transmittance_step(trans, alpha, support, alive, t_min)
        cr, cg, cb, cd = _colour(packed_ptr, g, LEAN)
        s = g_r * cr + g_g * cg + g_b * cb + g_d * cd + g_a
        prefix += s * w
        if JOINED:  # both counts from one block-wide sum
            n_use, n_alive_next = tl.split(tl.sum(tl.join(use.to(tl.int32), next_alive.to(tl.int32)), axis=0))
        else:
            n_use = tl.sum(use.to(tl.int32), axis=0)
            n_alive_next = tl.sum(next_alive.to(tl.int32), axis=0)
        # Pairs that touch none of the tile's pixels (bounding box only) add nothing: skip their atomics.
        if n_use > 0:
            d_alpha = trans * s - (total - prefix) / (1.0 - alpha)
            on = use & (raw < alpha_max)
            # where(), not a product with 0: alpha, du, dv are garbage (even NaN) outside the support.
            d_mahal = tl.where(on, -0.5 * alpha * d_alpha, 0.0)
            du = tl.where(on, du, 0.0)
            dv = tl.where(on, dv, 0.0)
            _add_gradients(grad_packed_ptr + g * (11 + LEAN),
                           -2.0 * d_mahal * (a * du + b * dv), -2.0 * d_mahal * (b * du + c * dv),
                           d_mahal * du * du, 2.0 * d_mahal * du * dv, d_mahal * dv * dv,
                           tl.where(on, d_alpha * alpha, 0.0), g_r * w, g_g * w, g_b * w, g_d * w, o, JOINED, LEAN)
        trans = next_trans
        alive = next_alive
        n_alive = n_alive_next
        p += 1


@triton.jit
def _chunk(packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, p0, end, row, col, width, trans, alive,
           sigma2, alpha_max, alpha_min, t_min, WRAP_U: tl.constexpr, CHUNK: tl.constexpr, LEAN: tl.constexpr):
    """Pairs ``p0 .. p0 + CHUNK - 1`` (those before ``end``) at the tile's pixels: pairs along axis 0,
    pixels along axis 1, :func:`_fragment`'s arithmetic, and the transmittance by a product scan along
    the pairs.

    The termination rule is :func:`_transmittance_step`'s: the transmittance only falls along the pairs,
    so the fragment that brings it below ``t_min`` and every later one fail ``T_after >= t_min``. The
    products are associated differently from a running product (float32 rounding: a fragment within an
    ulp of ``t_min`` may be judged differently; the chunked forward and backward judge alike).
    Returns the pairs' Gaussians and parameters, the fragments' offsets, alpha and weights, and the
    pixels' transmittance and liveness after the chunk."""
    p = p0 + tl.arange(0, CHUNK)
    valid = p < end
    g = tl.load(pair_gaussian_ptr + p, mask=valid, other=0)
    base = packed_ptr + g * (11 + LEAN)
    u = tl.load(base + 0, mask=valid, other=0.0)[:, None]
    v = tl.load(base + 1, mask=valid, other=0.0)[:, None]
    a = tl.load(base + 2, mask=valid, other=0.0)[:, None]
    b = tl.load(base + 3, mask=valid, other=0.0)[:, None]
    c = tl.load(base + 4, mask=valid, other=0.0)[:, None]
    o = tl.load(base + 5 + 3 * LEAN, mask=valid, other=0.0)
    r0 = tl.load(rows_ptr + 2 * p, mask=valid, other=1)[:, None]  # (1, 0): an empty range past the end
    r1 = tl.load(rows_ptr + 2 * p + 1, mask=valid, other=0)[:, None]
    c0 = tl.load(cols_ptr + 2 * p, mask=valid, other=0)[:, None]
    c1 = tl.load(cols_ptr + 2 * p + 1, mask=valid, other=0)[:, None]
    du = col[None, :].to(tl.float32) + 0.5 - u
    if WRAP_U:
        half = width * 0.5
        du = du + half
        du = du - width * tl.floor(du / width) - half
    dv = row[None, :].to(tl.float32) + 0.5 - v
    mahal = a * du * du + 2.0 * b * du * dv + c * dv * dv
    raw = o[:, None] * tl.exp(-0.5 * mahal)
    alpha = tl.minimum(raw, alpha_max)
    frag = ((row[None, :] >= r0) & (row[None, :] <= r1) & (col[None, :] >= c0) & (col[None, :] <= c1)
            & (mahal <= sigma2) & (alpha >= alpha_min) & alive[None, :])
    keep = tl.where(frag, 1.0 - alpha, 1.0)
    after = trans[None, :] * tl.cumprod(keep, axis=0)  # T after pair k, inclusive
    before = after / keep  # keep >= 1 - alpha_max > 0
    use = frag & (after >= t_min)
    w = tl.where(use, alpha * before, 0.0)
    # After the chunk: T after the last used fragment; alive unless a fragment was dropped.
    trans_next = tl.min(tl.where(use, after, trans[None, :]), axis=0)
    alive_next = alive & (tl.max((frag & (after < t_min)).to(tl.int32), axis=0) == 0)
    return g, valid, a, b, c, o, du, dv, alpha, raw, before, use, w, trans_next, alive_next


@triton.jit
def composite_forward_chunked_kernel(
    packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, out_ptr,
    height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, CHUNK: tl.constexpr, LEAN: tl.constexpr,
):
    """:func:`composite_forward_kernel` over ``CHUNK`` pairs at a time (:func:`_chunk`)."""
    tile = tl.program_id(0)
    row, col, inside, pixel = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    trans = tl.where(inside, 1.0, 0.0)
    alive = inside
    acc_r = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_g = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_b = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_d = tl.zeros([TILE * TILE], dtype=tl.float32)
    acc_a = tl.zeros([TILE * TILE], dtype=tl.float32)
    p0 = start
    n_alive = tl.sum(alive.to(tl.int32), axis=0)
    while (p0 < end) & (n_alive > 0):
        g, valid, a, b, c, o, du, dv, alpha, raw, before, use, w, trans, alive = _chunk(
            packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, p0, end, row, col, width, trans, alive,
            sigma2, alpha_max, alpha_min, t_min, WRAP_U, CHUNK, LEAN)
        base = packed_ptr + g * (11 + LEAN)
        acc_r += tl.sum(w * tl.load(base + 6 + 3 * LEAN, mask=valid, other=0.0)[:, None], axis=0)
        acc_g += tl.sum(w * tl.load(base + 7 + 3 * LEAN, mask=valid, other=0.0)[:, None], axis=0)
        acc_b += tl.sum(w * tl.load(base + 8 + 3 * LEAN, mask=valid, other=0.0)[:, None], axis=0)
        acc_d += tl.sum(w * tl.load(base + 9 - 2 * LEAN, mask=valid, other=0.0)[:, None], axis=0)
        acc_a += tl.sum(w, axis=0)
        n_alive = tl.sum(alive.to(tl.int32), axis=0)
        p0 += CHUNK
    _store_pixels(out_ptr, pixel, inside, acc_r, acc_g, acc_b, acc_d, acc_a)


@triton.jit
def composite_backward_chunked_kernel(
    packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, out_ptr, grad_out_ptr, grad_packed_ptr,
    height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, CHUNK: tl.constexpr, LEAN: tl.constexpr,
):
    """:func:`composite_backward_kernel` over ``CHUNK`` pairs at a time (:func:`_chunk`): the running sum
    ``P`` by a sum scan along the pairs, the per-pair gradients by sums over the pixels and ``CHUNK``-wide
    atomics - a tile's serial steps (each with its block-wide sums and memory round trips) fall
    ``CHUNK``-fold."""
    tile = tl.program_id(0)
    row, col, inside, pixel = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    g_r, g_g, g_b, g_d, g_a, total = _output_gradients(grad_out_ptr, out_ptr, pixel, inside)
    trans = tl.where(inside, 1.0, 0.0)
    alive = inside
    prefix = tl.zeros([TILE * TILE], dtype=tl.float32)
    p0 = start
    n_alive = tl.sum(alive.to(tl.int32), axis=0)
    while (p0 < end) & (n_alive > 0):
        g, valid, a, b, c, o, du, dv, alpha, raw, before, use, w, trans, alive = _chunk(
            packed_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, p0, end, row, col, width, trans, alive,
            sigma2, alpha_max, alpha_min, t_min, WRAP_U, CHUNK, LEAN)
        base = packed_ptr + g * (11 + LEAN)
        s = (g_r[None, :] * tl.load(base + 6 + 3 * LEAN, mask=valid, other=0.0)[:, None]
             + g_g[None, :] * tl.load(base + 7 + 3 * LEAN, mask=valid, other=0.0)[:, None]
             + g_b[None, :] * tl.load(base + 8 + 3 * LEAN, mask=valid, other=0.0)[:, None]
             + g_d[None, :] * tl.load(base + 9 - 2 * LEAN, mask=valid, other=0.0)[:, None] + g_a[None, :])
        sw = s * w
        running = prefix[None, :] + tl.cumsum(sw, axis=0)  # P through pair k, inclusive
        d_alpha = before * s - (total[None, :] - running) / (1.0 - alpha)
        on = use & (raw < alpha_max)
        # where(), not a product with 0: alpha, du, dv are garbage (even NaN) outside the support.
        d_mahal = tl.where(on, -0.5 * alpha * d_alpha, 0.0)
        du = tl.where(on, du, 0.0)
        dv = tl.where(on, dv, 0.0)
        used = (tl.max(use.to(tl.int32), axis=1) > 0) & valid  # pairs that touch a pixel: their atomics
        gp = grad_packed_ptr + g * (11 + LEAN)
        tl.atomic_add(gp + 0, tl.sum(-2.0 * d_mahal * (a * du + b * dv), axis=1), mask=used)
        tl.atomic_add(gp + 1, tl.sum(-2.0 * d_mahal * (b * du + c * dv), axis=1), mask=used)
        tl.atomic_add(gp + 2, tl.sum(d_mahal * du * du, axis=1), mask=used)
        tl.atomic_add(gp + 3, tl.sum(2.0 * d_mahal * du * dv, axis=1), mask=used)
        tl.atomic_add(gp + 4, tl.sum(d_mahal * dv * dv, axis=1), mask=used)
        tl.atomic_add(gp + 5 + 3 * LEAN, tl.sum(tl.where(on, d_alpha * alpha, 0.0), axis=1) / tl.maximum(o, 1e-30),
                      mask=used)
        tl.atomic_add(gp + 6 + 3 * LEAN, tl.sum(g_r[None, :] * w, axis=1), mask=used)
        tl.atomic_add(gp + 7 + 3 * LEAN, tl.sum(g_g[None, :] * w, axis=1), mask=used)
        tl.atomic_add(gp + 8 + 3 * LEAN, tl.sum(g_b[None, :] * w, axis=1), mask=used)
        tl.atomic_add(gp + 9 - 2 * LEAN, tl.sum(g_d[None, :] * w, axis=1), mask=used)
        prefix += tl.sum(sw, axis=0)
        n_alive = tl.sum(alive.to(tl.int32), axis=0)
        p0 += CHUNK
