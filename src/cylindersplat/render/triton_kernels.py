"""Triton kernels of the fast backend: per-tile front-to-back compositing and its backward pass.

Imported lazily by :mod:`.triton_backend` (only when the Triton backend is used), so that
``TRITON_INTERPRET=1`` set by a test before the first call selects Triton's CPU interpreter.

One program per (camera, tile): its ``TILE x TILE`` pixels walk the tile's (Gaussian, tile) pairs in
depth order. The rules are the reference's (:mod:`.rasterize`): a pixel gets a fragment of pair
``p`` only inside the pair's pixel rectangle (read from the pair's fields, or with ``RECTS=False`` computed from
its Gaussian's centre and extents: :func:`_pair_rect`) and the ``sigma_extent`` ellipse; ``du`` wraps into
``[-W/2, W/2)`` across the seam; ``alpha = min(alpha_max, o exp(-m/2))``, skipped below
``alpha_min``; the fragment that would bring the transmittance below ``transmittance_min`` and
all later ones are dropped. A tile stops early once all its pixels have terminated (the forward counts them after
every run of eight pairs).

The pairs' parameters are read from three row pointers with compile-time row strides: ``geo`` (``u, v, A, B, C``
in columns 0-4, the depth in column ``DEPTH_COL``), ``opac`` and ``colour`` (``r, g, b``). With ``SPLIT=1`` (the
Triton projection's rows, either forward of :data:`.triton_backend.FORWARD`) they are the projection's own
``(M, 8)`` rows ``[u, v, A, B, C, extent u, extent v, depth]``, the ``(M,)`` opacities and the ``(M, 3)`` colours,
read where they are (no concatenation: it was 8 % of the device time at 1.3 M Gaussians on an H100), and the
gradients go into one ``M x 12`` buffer laid out as ``[u, v, A, B, C, -, -, depth, opacity, r, g, b]``, whose
column slices are the three inputs' gradients; with ``SPLIT=0`` all three point into
:func:`.rasterize.pack_projected`'s ``M x 11`` rows ``[u, v, A, B, C, opacity, r, g, b, depth, 1]``, and so does
the gradient. :func:`_column` maps the ten parameters to their gradient columns. The outputs are the render's own
tensors: rgb planar ``(C, 3, H, W)``, depth and alpha ``(C, H, W)``, float32 and contiguous (no slices of an
interleaved buffer: their gradients come back as they are).
"""

from __future__ import annotations

import triton
import triton.language as tl

from .triton_binning_kernels import tile_spans

# Pairs composited between two counts of a tile's live pixels (the forward's early stop).
_ALIVE_EVERY = tl.constexpr(8)


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
    return row, col, inside, pixel, tx * TILE


@triton.jit
def _column(j, SPLIT: tl.constexpr):
    """The gradient column of parameter ``j`` (0-4: u, v, A, B, C; 5: opacity; 6-8: r, g, b; 9: depth)."""
    return tl.where(j < 5, j, tl.where(j == 9, 9 - 2 * SPLIT, j + 3 * SPLIT))


@triton.jit
def _pair_rect(u, v, eu, ev, repeated, col0, height, width, TILE: tl.constexpr, WRAP_U: tl.constexpr):
    """The pixel rows ``r0..r1`` and columns ``c0..c1`` of a pair in the tile whose first column is ``col0``, from
    its Gaussian's centre and extents (the binning's arithmetic, :func:`.triton_binning_kernels.tile_spans`): the
    rectangle the binning writes for the pair, less its clamping to the tile (the tile's pixels are inside it).
    Across the seam a footprint has two column intervals; where both meet the tile the Gaussian has two pairs
    there, next to each other (one Gaussian's pairs are emitted together, and the sort by tile is stable), the
    first interval's first: ``repeated`` (the previous pair of the tile has the same Gaussian) marks the second."""
    i0, i1, j0, a0, b0, a1, b1, ny, nx0, nx1 = tile_spans(u, v, eu, ev, height, width, TILE, WRAP_U)
    if WRAP_U:
        meets_first = (a0 <= col0 + TILE - 1) & (b0 >= col0)
        second = repeated | (meets_first == 0)
        return i0, i1, tl.where(second, a1, a0), tl.where(second, b1, b0)
    return i0, i1, a0, b0


@triton.jit
def _load_pair(geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g, p, on, GEO_STRIDE: tl.constexpr,
               OPAC_STRIDE: tl.constexpr, COLOUR_STRIDE: tl.constexpr, DEPTH_COL: tl.constexpr, RECTS: tl.constexpr):
    """What the compositing reads of pair ``p`` (Gaussian ``g``; zeros where ``on`` is false): ``u, v, A, B, C``,
    the opacity, the rectangle's four inputs (``RECTS``: its pixel rows ``r0, r1`` and columns ``c0, c1`` from the
    pair's fields; else its Gaussian's extents ``eu, ev`` from columns 5-6 of ``geo`` and two unused zeros: the
    rectangle is computed by :func:`_fragment_at`), the colour ``r, g, b`` and the radial depth."""
    base = geo_ptr + g * GEO_STRIDE
    u = tl.load(base + 0, mask=on, other=0.0)
    v = tl.load(base + 1, mask=on, other=0.0)
    a = tl.load(base + 2, mask=on, other=0.0)
    b = tl.load(base + 3, mask=on, other=0.0)
    c = tl.load(base + 4, mask=on, other=0.0)
    o = tl.load(opac_ptr + g * OPAC_STRIDE, mask=on, other=0.0)
    if RECTS:
        e0 = tl.load(rows_ptr + 2 * p, mask=on, other=0)
        e1 = tl.load(rows_ptr + 2 * p + 1, mask=on, other=0)
        e2 = tl.load(cols_ptr + 2 * p, mask=on, other=0)
        e3 = tl.load(cols_ptr + 2 * p + 1, mask=on, other=0)
    else:
        e0 = tl.load(base + 5, mask=on, other=0.0)
        e1 = tl.load(base + 6, mask=on, other=0.0)
        e2 = e0 * 0.0
        e3 = e2
    colour = colour_ptr + g * COLOUR_STRIDE
    cr = tl.load(colour + 0, mask=on, other=0.0)
    cg = tl.load(colour + 1, mask=on, other=0.0)
    cb = tl.load(colour + 2, mask=on, other=0.0)
    cd = tl.load(base + DEPTH_COL, mask=on, other=0.0)
    return u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd


@triton.jit
def _first_pairs(pair_gaussian_ptr, geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, start, end,
                 GEO_STRIDE: tl.constexpr, OPAC_STRIDE: tl.constexpr, COLOUR_STRIDE: tl.constexpr,
                 DEPTH_COL: tl.constexpr, RECTS: tl.constexpr):
    """Where a tile's walk over its pairs ``start..end`` begins: its first pair's Gaussian, ``-1`` for the pair
    before it (none), the second pair's Gaussian and the first pair's row (:func:`_load_pair`), each loaded only
    where the tile has pairs: what the kernels carry into their loop with ``ROW_AHEAD``."""
    has = start < end
    g = tl.load(pair_gaussian_ptr + start, mask=has, other=0)
    g1 = tl.load(pair_gaussian_ptr + tl.maximum(tl.minimum(start + 1, end - 1), start), mask=has, other=0)
    u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd = _load_pair(
        geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g, start, has, GEO_STRIDE, OPAC_STRIDE, COLOUR_STRIDE,
        DEPTH_COL, RECTS)
    return g, g * 0 - 1, g1, u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd


@triton.jit
def _fragment_at(u, v, a, b, c, o, e0, e1, e2, e3, repeated, col0, row, col, height, width, sigma2, alpha_max,
                 alpha_min, TILE: tl.constexpr, WRAP_U: tl.constexpr, RECTS: tl.constexpr):
    """Offsets, alpha and the support mask of a pair (:func:`_load_pair`'s values) at the tile's pixels. Without
    ``RECTS`` the pair's pixel rectangle is computed (:func:`_pair_rect`: ``repeated`` and ``col0``) from its
    Gaussian's extents ``e0, e1``."""
    if RECTS:
        r0, r1, c0, c1 = e0, e1, e2, e3
    else:
        r0, r1, c0, c1 = _pair_rect(u, v, e0, e1, repeated, col0, height, width, TILE, WRAP_U)
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
    return du, dv, alpha, raw, support


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
def _add_gradients(gp, x0, x1, x2, x3, x4, x5, x6, x7, x8, x9, o, SPLIT: tl.constexpr):
    """``gp[j] += sum(x_j)`` over the tile's pixels (``/ max(o, 1e-30)`` for ``j = 5``, the opacity), for the
    ten parameters of one Gaussian: the ten per-pixel values joined into one ``(pixels, 2, 2, 2, 2)`` tensor
    (registers, no data movement), one block-wide sum of it (one pass through shared memory instead of ten, each with
    its barriers) and one vector atomic of the ten sums (six padding lanes masked off). ``gp``: the Gaussian's
    gradient row (columns by :func:`_column`)."""
    z = tl.zeros_like(x0)
    low = tl.join(tl.join(tl.join(x0, x1), tl.join(x2, x3)), tl.join(tl.join(x4, x5), tl.join(x6, x7)))
    high = tl.join(tl.join(tl.join(x8, x9), tl.join(z, z)), tl.join(tl.join(z, z), tl.join(z, z)))
    sums = tl.sum(tl.join(low, high), axis=0)  # sums[s1, s2, s3, s4] = sum of x_(s1 + 2 s2 + 4 s3 + 8 s4)
    bit = tl.arange(0, 2)
    j = (bit[:, None, None, None] + 2 * bit[None, :, None, None] + 4 * bit[None, None, :, None]
         + 8 * bit[None, None, None, :])
    tl.atomic_add(gp + _column(j, SPLIT), sums / tl.where(j == 5, tl.maximum(o, 1e-30), 1.0), mask=j < 10)


@triton.jit
def _rgb_offset(pixel, tile, tiles_per_camera, plane):
    """Where a pixel's red value lies in the planar ``(C, 3, H, W)`` colour image (green one ``plane`` later, blue
    two): ``pixel`` counts ``(C, H, W)``."""
    return pixel + 2 * (tile // tiles_per_camera) * plane


@triton.jit
def _store_pixels(rgb_ptr, depth_ptr, alpha_ptr, pixel, rgb_at, plane, inside, acc_r, acc_g, acc_b, acc_d, acc_a):
    """A forward kernel's output per pixel: rgb (planar, ``(C, 3, H, W)``), depth and alpha (= 1 - final
    transmittance, ``(C, H, W)``)."""
    tl.store(rgb_ptr + rgb_at, acc_r, mask=inside)
    tl.store(rgb_ptr + rgb_at + plane, acc_g, mask=inside)
    tl.store(rgb_ptr + rgb_at + 2 * plane, acc_b, mask=inside)
    tl.store(depth_ptr + pixel, acc_d, mask=inside)
    tl.store(alpha_ptr + pixel, acc_a, mask=inside)


@triton.jit
def composite_forward_kernel(
    geo_ptr, opac_ptr, colour_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, rgb_ptr, depth_ptr,
    alpha_ptr, height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, GEO_STRIDE: tl.constexpr, OPAC_STRIDE: tl.constexpr,
    COLOUR_STRIDE: tl.constexpr, DEPTH_COL: tl.constexpr, RECTS: tl.constexpr = True, ROW_AHEAD: tl.constexpr = False,
):
    """Front to back: each pixel's colour, depth and alpha (:func:`_transmittance_step`). ``ROW_AHEAD``: each pair's
    parameters are loaded while the pair before it is composited (its Gaussian's id two pairs ahead), else only its
    Gaussian's id one pair ahead (the row's loads wait for it)."""
    tile = tl.program_id(0)
    row, col, inside, pixel, col0 = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    if ROW_AHEAD:  # (else nothing is carried into the loop but the Gaussian ids)
        g, g_prev, g1, u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd = _first_pairs(
            pair_gaussian_ptr, geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, start, end, GEO_STRIDE,
            OPAC_STRIDE, COLOUR_STRIDE, DEPTH_COL, RECTS)
    else:
        g = tl.load(pair_gaussian_ptr + start, mask=start < end, other=0)
        g_prev = g * 0 - 1  # (none yet: -1)
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
        # A run of pairs between two counts of the live pixels (a block-wide sum, with its barriers, per run instead
        # of per pair; a finished tile walks at most the rest of its run, adding nothing), each pair's Gaussian
        # loaded one pair ahead so that its row's loads need not wait for it (or, ROW_AHEAD, its row too).
        stop = tl.minimum(p + _ALIVE_EVERY, end)
        if not ROW_AHEAD:
            g = tl.load(pair_gaussian_ptr + p)
        while p < stop:
            if ROW_AHEAD:
                g2 = tl.load(pair_gaussian_ptr + tl.minimum(p + 2, end - 1))
                nu, nv, na, nb, nc, no, n0, n1, n2, n3, nr, ng, nbl, nd = _load_pair(
                    geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g1, tl.minimum(p + 1, end - 1), p < end,
                    GEO_STRIDE, OPAC_STRIDE, COLOUR_STRIDE, DEPTH_COL, RECTS)
            else:
                g_next = tl.load(pair_gaussian_ptr + tl.minimum(p + 1, stop - 1))
                u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd = _load_pair(
                    geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g, p, p < end, GEO_STRIDE, OPAC_STRIDE,
                    COLOUR_STRIDE, DEPTH_COL, RECTS)
            du, dv, alpha, raw, support = _fragment_at(u, v, a, b, c, o, e0, e1, e2, e3, g == g_prev, col0, row, col,
                                                       height, width, sigma2, alpha_max, alpha_min, TILE, WRAP_U,
                                                       RECTS)
            use, w, trans, alive = _transmittance_step(trans, alpha, support, alive, t_min)
            acc_r += w * cr
            acc_g += w * cg
            acc_b += w * cb
            acc_d += w * cd
            acc_a += w
            g_prev = g
            if ROW_AHEAD:
                u, v, a, b, c, o, e0, e1 = nu, nv, na, nb, nc, no, n0, n1
                e2, e3, cr, cg, cb, cd = n2, n3, nr, ng, nbl, nd
                g = g1
                g1 = g2
            else:
                g = g_next
            p += 1
        n_alive = tl.sum(alive.to(tl.int32), axis=0)
    plane = height * width
    _store_pixels(rgb_ptr, depth_ptr, alpha_ptr, pixel, _rgb_offset(pixel, tile, tiles_per_camera, plane), plane,
                  inside, acc_r, acc_g, acc_b, acc_d, acc_a)


@triton.jit
def _output_gradients(rgb_ptr, depth_ptr, alpha_ptr, grad_rgb_ptr, grad_depth_ptr, grad_alpha_ptr, has_rgb, has_depth,
                      has_alpha, pixel, rgb_at, plane, inside):
    """The pixels' output gradients ``g`` (rgb, depth, alpha; zero for an output without one: ``has_*`` 0) and
    ``S = g . out`` (all contributions). The gradients lie as the outputs do (planar rgb, contiguous)."""
    none = tl.zeros_like(pixel)  # (the flags as blocks: a scalar flag in a mask is refused by the interpreter)
    on_rgb = inside & (none + has_rgb != 0)
    g_r = tl.load(grad_rgb_ptr + rgb_at, mask=on_rgb, other=0.0)
    g_g = tl.load(grad_rgb_ptr + rgb_at + plane, mask=on_rgb, other=0.0)
    g_b = tl.load(grad_rgb_ptr + rgb_at + 2 * plane, mask=on_rgb, other=0.0)
    g_d = tl.load(grad_depth_ptr + pixel, mask=inside & (none + has_depth != 0), other=0.0)
    g_a = tl.load(grad_alpha_ptr + pixel, mask=inside & (none + has_alpha != 0), other=0.0)
    total = (g_r * tl.load(rgb_ptr + rgb_at, mask=inside, other=0.0)
             + g_g * tl.load(rgb_ptr + rgb_at + plane, mask=inside, other=0.0)
             + g_b * tl.load(rgb_ptr + rgb_at + 2 * plane, mask=inside, other=0.0)
             + g_d * tl.load(depth_ptr + pixel, mask=inside, other=0.0)
             + g_a * tl.load(alpha_ptr + pixel, mask=inside, other=0.0))
    return g_r, g_g, g_b, g_d, g_a, total


@triton.jit(do_not_specialize=["has_rgb", "has_depth", "has_alpha"])  # one compilation whichever outputs have one
def composite_backward_kernel(
    geo_ptr, opac_ptr, colour_ptr, pair_gaussian_ptr, rows_ptr, cols_ptr, tile_start_ptr, rgb_ptr, depth_ptr,
    alpha_ptr, grad_rgb_ptr, grad_depth_ptr, grad_alpha_ptr, grad_rows_ptr, has_rgb, has_depth, has_alpha,
    height, width, tiles_x, tiles_per_camera,
    sigma2, alpha_max, alpha_min, t_min,
    TILE: tl.constexpr, WRAP_U: tl.constexpr, GEO_STRIDE: tl.constexpr, OPAC_STRIDE: tl.constexpr,
    COLOUR_STRIDE: tl.constexpr, DEPTH_COL: tl.constexpr, SPLIT: tl.constexpr, RECTS: tl.constexpr = True,
    ROW_AHEAD: tl.constexpr = False,
):
    """Front to back again: ``dL/dalpha_i = T_i s_i - (S - P_i) / (1 - alpha_i)`` with ``s_i = g . f_i``,
    ``S = g . out`` (all contributions) and ``P_i`` the running sum of ``s_k w_k`` up to ``i``.
    Per-pair gradients are summed over the tile's pixels and added atomically per Gaussian
    (:func:`_add_gradients`): two block-wide sums per pair (the ten gradients in one, and the counts of used and
    still-alive pixels in one). ``ROW_AHEAD`` as in the forward."""
    tile = tl.program_id(0)
    row, col, inside, pixel, col0 = _pixel_setup(tile, tiles_x, tiles_per_camera, height, width, TILE)
    start = tl.load(tile_start_ptr + tile)
    end = tl.load(tile_start_ptr + tile + 1)
    plane = height * width
    g_r, g_g, g_b, g_d, g_a, total = _output_gradients(
        rgb_ptr, depth_ptr, alpha_ptr, grad_rgb_ptr, grad_depth_ptr, grad_alpha_ptr, has_rgb, has_depth, has_alpha,
        pixel, _rgb_offset(pixel, tile, tiles_per_camera, plane), plane, inside)
    trans = tl.where(inside, 1.0, 0.0)
    alive = inside
    prefix = tl.zeros([TILE * TILE], dtype=tl.float32)
    p = start
    n_alive = tl.sum(alive.to(tl.int32), axis=0)
    if ROW_AHEAD:  # (else nothing is carried into the loop but the Gaussian ids)
        g, g_prev, g1, u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd = _first_pairs(
            pair_gaussian_ptr, geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, start, end, GEO_STRIDE,
            OPAC_STRIDE, COLOUR_STRIDE, DEPTH_COL, RECTS)
    else:
        g = tl.load(pair_gaussian_ptr + start, mask=start < end, other=0)
        g_prev = g * 0 - 1  # (none yet: -1)
    while (p < end) & (n_alive > 0):
        if ROW_AHEAD:
            g2 = tl.load(pair_gaussian_ptr + tl.minimum(p + 2, end - 1))
            nu, nv, na, nb, nc, no, n0, n1, n2, n3, nr, ng, nbl, nd = _load_pair(
                geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g1, tl.minimum(p + 1, end - 1), p < end,
                GEO_STRIDE, OPAC_STRIDE, COLOUR_STRIDE, DEPTH_COL, RECTS)
        else:
            g_next = tl.load(pair_gaussian_ptr + tl.minimum(p + 1, end - 1))  # one pair ahead (as the forward)
            u, v, a, b, c, o, e0, e1, e2, e3, cr, cg, cb, cd = _load_pair(
                geo_ptr, opac_ptr, colour_ptr, rows_ptr, cols_ptr, g, p, p < end, GEO_STRIDE, OPAC_STRIDE,
                COLOUR_STRIDE, DEPTH_COL, RECTS)
        du, dv, alpha, raw, support = _fragment_at(u, v, a, b, c, o, e0, e1, e2, e3, g == g_prev, col0, row, col,
                                                   height, width, sigma2, alpha_max, alpha_min, TILE, WRAP_U, RECTS)
        use, w, next_trans, next_alive = _transmittance_step(trans, alpha, support, alive, t_min)
        s = g_r * cr + g_g * cg + g_b * cb + g_d * cd + g_a
        prefix += s * w
        # both counts from one block-wide sum
        n_use, n_alive_next = tl.split(tl.sum(tl.join(use.to(tl.int32), next_alive.to(tl.int32)), axis=0))
        # Pairs that touch none of the tile's pixels (bounding box only) add nothing: skip their atomics.
        if n_use > 0:
            d_alpha = trans * s - (total - prefix) / (1.0 - alpha)
            on = use & (raw < alpha_max)
            # where(), not a product with 0: alpha, du, dv are garbage (even NaN) outside the support.
            d_mahal = tl.where(on, -0.5 * alpha * d_alpha, 0.0)
            du = tl.where(on, du, 0.0)
            dv = tl.where(on, dv, 0.0)
            _add_gradients(grad_rows_ptr + g * (11 + SPLIT),
                           -2.0 * d_mahal * (a * du + b * dv), -2.0 * d_mahal * (b * du + c * dv),
                           d_mahal * du * du, 2.0 * d_mahal * du * dv, d_mahal * dv * dv,
                           tl.where(on, d_alpha * alpha, 0.0), g_r * w, g_g * w, g_b * w, g_d * w, o, SPLIT)
        trans = next_trans
        alive = next_alive
        n_alive = n_alive_next
        g_prev = g
        if ROW_AHEAD:
            u, v, a, b, c, o, e0, e1 = nu, nv, na, nb, nc, no, n0, n1
            e2, e3, cr, cg, cb, cd = n2, n3, nr, ng, nbl, nd
            g = g1
            g1 = g2
        else:
            g = g_next
        p += 1
