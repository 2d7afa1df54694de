"""The fast backend: tile binning and per-tile compositing (fwd + bwd) as Triton kernels, any camera model.

Needs no compile step from the user: Triton ships with CUDA builds of PyTorch and compiles the
kernels (:mod:`.triton_kernels`) at first use. The backend also brings its own projection, a fused
float32 kernel with an analytic backward (:mod:`.triton_projection`, registered beside it in
:mod:`.api`) for the equirect and pinhole camera models; other camera models are projected by the
reference. Tile binning is a depth sort, per-Gaussian counts, a prefix sum, key emission and one stable sort by
tile (:mod:`.triton_binning`). Compositing follows the reference's rules; gradients reach the projected Gaussians
through the compositing kernels' backward. The forward path, the projection's compaction, the input checks, what a
pair carries and how far ahead the compositing loads come in variants that give the same results (:data:`FORWARDS`,
:data:`COMPACTIONS`, :data:`CHECKS`, :data:`PAIR_FIELDS`, :data:`LOOKAHEADS`; by name :data:`VARIANT_FIELDS`), timed
side by side by ``bench render --variants`` until one is made the default. (The binning and the backward had
variants too until an H100 chose between them on 2026-11-26: benchmarks/RESULTS.md.)

On a CPU, ``TRITON_INTERPRET=1`` (set before the first render) runs the same kernels in Triton's
interpreter; that is how the test suite checks them on machines without a GPU.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

import torch
from torch import Tensor

from .projection import ProjectedGaussians, RasterSettings, UnsupportedSettings, is_recording, read_count
from .rasterize import TileBins, over_background, pack_projected
from .triton_binning import bin_to_tiles_by_key

__all__ = ["triton_available", "triton_backend", "composite_triton", "composite_bins", "FORWARDS", "FORWARD",
           "COMPACTIONS", "COMPACTION", "CHECKS", "CHECK", "PAIR_FIELDS", "PAIR_FIELD", "LOOKAHEADS", "LOOKAHEAD",
           "VARIANT_FIELDS", "takes_every_pair", "queue_checks", "pairs_carry_rects"]

# The forward path's variant: "default" (:func:`.triton_binning.bin_to_tiles_by_key`, which reads the pair count on
# the host before sizing its buffers, then compositing) or "lean" (:func:`_lean_backend`: the binning's
# kernels in buffers of a cached, growing capacity, no host synchronisation before the compositing is queued; the
# pair count is read once after it, and the binning and compositing rerun with a larger capacity where the pairs
# did not fit). The same images and gradients; on an H100 (2026-11-27) the same speed within the calls' noise.
# Module-level: the benchmark switches it.
FORWARDS = ("default", "lean")
FORWARD = "default"

# The rows the backend gets from the projection (issue 35): "none" (every (camera, Gaussian) pair, the invisible ones
# inert - outside the image, no extent - so no host synchronisation sizes them; the binning's sort and counts run
# over all B * V * N pairs) or "nonzero" (the visible pairs only, compacted by a ``nonzero``: one more host
# synchronisation, fewer rows where many pairs are invisible, e.g. pinhole views). The same images and gradients.
# Either way the render's input checks are read with the pair count (:func:`.projection.read_count`): one host
# synchronisation per forward with "none", two with "nonzero". On an H100 (2026-11-27) neither was faster beyond the
# calls' noise, panoramas or pinhole views. Module-level: the benchmark switches it.
COMPACTIONS = ("none", "nonzero")
COMPACTION = "none"

# How a render on this backend queues its input checks (read with the pair count): "fused" (one kernel launch,
# :mod:`.triton_checks`) or "torch" (the PyTorch operations of ``api._queue_checks_torch``: some seventy launches for
# the Gaussians' and the poses' value checks). The same flags; "torch" took 1.3-2.4 ms more a forward on an H100
# (2026-11-27). Module-level: the benchmark switches it.
CHECKS = ("fused", "torch")
CHECK = "fused"

# What a (Gaussian, tile) pair carries from the binning to the compositing: "ids" (the default: its Gaussian's row
# only, 4 bytes; the compositing kernels compute the rectangle from the Gaussian's centre and extents with the
# binning's arithmetic, as gsplat's rasterizer reads only Gaussian ids) or "rects" (its Gaussian's row and its pixel
# rectangle in the tile, written by the binning's last kernel: 56 bytes a pair with the default forward, 20 with
# "lean"). The same images and gradients. "ids" needs the Triton projection's rows (float32, extents in place); other
# projections' pairs carry rectangles whatever this says. Default since three H100 calls (2026-11-27, session 26: with
# LOOKAHEAD "row", faster in 13 of 20 pinhole forward + backward timings and 5 of 8 panorama ones, within the calls'
# noise, and a quarter to a third less peak memory at 1.3 M Gaussians; benchmarks/RESULTS.md). Module-level: the
# benchmark switches it.
PAIR_FIELDS = ("ids", "rects")
PAIR_FIELD = "ids"

# How far ahead the compositing kernels load a tile's next pair (issue 35): "row" (the default: the next pair's whole
# row - centre, conic, opacity, rectangle or extents, colour, depth - loaded while the current one is composited, its
# id two pairs ahead: a load's latency hidden behind a pair's arithmetic, as gsplat hides it behind batches in shared
# memory) or "id" (its Gaussian's id one pair ahead; the pair's row is loaded when it is composited, and the pixels
# wait for it). The same arithmetic in the same order: the same images and gradients bit for bit in Triton's
# interpreter. Compiled for a GPU, pinhole views with PAIR_FIELD "ids" differed in the last bits (at most 2.4e-7 on an
# H100, 2026-11-27; the two kernels' PTX has the same arithmetic instructions in another order), both as close to the
# float64 reference. Module-level: the benchmark switches it.
LOOKAHEADS = ("row", "id")
LOOKAHEAD = "row"

# The switches above by name, for the benchmarks' variant names (every value is one field's: "lean,rects,id").
VARIANT_FIELDS = {"FORWARD": FORWARDS, "COMPACTION": COMPACTIONS, "CHECK": CHECKS, "PAIR_FIELD": PAIR_FIELDS,
                  "LOOKAHEAD": LOOKAHEADS}


def triton_available() -> bool:
    return importlib.util.find_spec("triton") is not None


def takes_every_pair() -> bool:
    """Whether the backend wants every pair from the projection (:data:`COMPACTION`), asked once per render."""
    if COMPACTION not in COMPACTIONS:
        raise ValueError(f"unknown Triton compaction {COMPACTION!r}: choose one of {', '.join(COMPACTIONS)}")
    return COMPACTION == "none"


def queue_checks(gaussians, c2w: Tensor) -> list[Tensor] | None:
    """The render's deferred input checks the :data:`CHECK` way (``register_backend``'s ``queue_checks``): the
    fused kernel's flags, or None for PyTorch's."""
    if CHECK not in CHECKS:
        raise ValueError(f"unknown Triton input check {CHECK!r}: choose one of {', '.join(CHECKS)}")
    if CHECK == "torch":
        return None
    from .triton_checks import queue_input_checks

    return queue_input_checks(gaussians, c2w)


class _TritonComposite(torch.autograd.Function):
    """Compositing on Triton: the pairs' rows (:class:`CompositeRows`) and bins -> ``rgb (C, 3, H, W)``,
    ``depth (C, H, W)``, ``alpha (C, H, W)`` (float32, each its own contiguous tensor)."""

    @staticmethod
    def forward(ctx, geo, opacity, colour, pair_gaussian, rows, cols, tile_start, num_cameras, height, width,
                tiles_x, tiles_y, wrap_u, settings, layout):
        from . import triton_kernels as kernels

        # Every pixel is written: one program per tile of every camera, empty tiles included.
        empty = dict(dtype=torch.float32, device=geo.device)
        rgb = torch.empty(num_cameras, 3, height, width, **empty)
        depth, alpha = (torch.empty(num_cameras, height, width, **empty) for _ in range(2))
        grid = (len(tile_start) - 1,)
        args = (height, width, tiles_x, tiles_x * tiles_y, settings.sigma_extent**2, settings.alpha_max,
                settings.alpha_min, settings.transmittance_min)
        pointers = layout.pointers(geo, opacity, colour)
        rects = rows is not None  # else the kernels compute each pair's rectangle (never read: the ids as pointers)
        if not rects:
            rows = cols = pair_gaussian
        if LOOKAHEAD not in LOOKAHEADS:
            raise ValueError(f"unknown Triton lookahead {LOOKAHEAD!r}: choose one of {', '.join(LOOKAHEADS)}")
        flags = dict(RECTS=rects, ROW_AHEAD=LOOKAHEAD == "row")  # the backward's too
        if grid[0] > 0:
            kernels.composite_forward_kernel[grid](*pointers, pair_gaussian, rows, cols, tile_start, rgb, depth, alpha,
                                                   *args, TILE=settings.tile_size, WRAP_U=bool(wrap_u),
                                                   **flags, **layout.strides)
        ctx.save_for_backward(geo, opacity, colour, pair_gaussian, rows, cols, tile_start, rgb, depth, alpha)
        ctx.args, ctx.tile, ctx.wrap_u, ctx.layout, ctx.flags = args, settings.tile_size, bool(wrap_u), layout, flags
        ctx.set_materialize_grads(False)  # an output without a gradient (often alpha) is read as zero, not made
        return rgb, depth, alpha

    @staticmethod
    def backward(ctx, grad_rgb, grad_depth, grad_alpha):
        from . import triton_kernels as kernels

        geo, opacity, colour, pair_gaussian, rows, cols, tile_start, rgb, depth, alpha = ctx.saved_tensors
        layout = ctx.layout
        grad_rows = torch.zeros(len(geo), layout.gradient_width, dtype=torch.float32, device=geo.device)
        grid = (len(tile_start) - 1,)
        grads = [out if grad is None else grad.float().contiguous()  # (a placeholder where None: never read)
                 for grad, out in ((grad_rgb, rgb), (grad_depth, depth), (grad_alpha, alpha))]
        has = [int(grad is not None) for grad in (grad_rgb, grad_depth, grad_alpha)]
        if grid[0] > 0 and any(has):
            kernels.composite_backward_kernel[grid](*layout.pointers(geo, opacity, colour), pair_gaussian, rows, cols,
                                                    tile_start, rgb, depth, alpha, *grads, grad_rows, *has,
                                                    *ctx.args, TILE=ctx.tile, WRAP_U=ctx.wrap_u, SPLIT=layout.split,
                                                    **ctx.flags, **layout.strides)
        return (*layout.gradients(grad_rows),) + (None,) * 12


@dataclass(frozen=True)
class CompositeRows:
    """Where the compositing kernels read a pair's parameters (:mod:`.triton_kernels`): ``split`` 1, the
    projection's ``(M, 8)`` rows, the ``(M,)`` opacities and the ``(M, 3)`` colours where they are (a gradient
    buffer ``M x 12`` whose column slices are their gradients); 0, one ``M x 11`` tensor of
    :func:`.rasterize.pack_projected` (its gradient ``M x 11``)."""

    split: int

    @property
    def strides(self) -> dict:
        if self.split:
            return dict(GEO_STRIDE=8, OPAC_STRIDE=1, COLOUR_STRIDE=3, DEPTH_COL=7)
        return dict(GEO_STRIDE=11, OPAC_STRIDE=11, COLOUR_STRIDE=11, DEPTH_COL=9)

    @property
    def gradient_width(self) -> int:
        return 11 + self.split

    def pointers(self, geo: Tensor, opacity: Tensor | None, colour: Tensor | None) -> tuple[Tensor, Tensor, Tensor]:
        """The kernels' three row pointers (views into the one packed tensor where not split)."""
        return (geo, opacity, colour) if self.split else (geo, geo[:, 5], geo[:, 6:9])

    def gradients(self, grad_rows: Tensor) -> tuple[Tensor, Tensor | None, Tensor | None]:
        """The gradients of ``geo``, ``opacity`` and ``colour`` (views of the kernel's gradient rows)."""
        if self.split:
            return grad_rows[:, :8], grad_rows[:, 8], grad_rows[:, 9:12]
        return grad_rows, None, None


def _finish(rgb: Tensor, depth: Tensor, alpha: Tensor, dtype: torch.dtype, background: Tensor | None):
    """The compositing's outputs in the render's dtype, over ``background`` (``(3,)`` or ``(C, 3)``) where given."""
    rgb, depth, alpha = rgb.to(dtype), depth.to(dtype), alpha.to(dtype)
    return over_background(rgb, alpha, background), depth, alpha


def composite_triton(
    proj: ProjectedGaussians, bins: TileBins, settings: RasterSettings, background: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Stage 4 on Triton. Returns ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``."""
    tile = settings.tile_size
    if tile & (tile - 1):
        raise UnsupportedSettings(f"the Triton backend needs a power-of-two tile size, got {tile}")
    h, w, c = proj.height, proj.width, proj.num_cameras
    num_tiles = c * bins.tiles_x * bins.tiles_y
    # Pairs are sorted by tile: each tile's first pair by a binary search (bincount would synchronise with the
    # host on CUDA to size its output).
    tile_ids = torch.arange(num_tiles + 1, dtype=bins.tile.dtype, device=bins.tile.device)
    tile_start = torch.searchsorted(bins.tile.contiguous(), tile_ids)
    rows, layout, dtype = _composite_rows(proj)
    out = _TritonComposite.apply(
        *rows, bins.gaussian.contiguous(), bins.rows.contiguous(), bins.cols.contiguous(),
        tile_start, c, h, w, bins.tiles_x, bins.tiles_y, proj.wrap_u, settings, layout,
    )
    return _finish(*out, dtype, background)


def triton_backend(proj: ProjectedGaussians, settings: RasterSettings, background: Tensor | None = None):
    """The backend function (:func:`cylindersplat.render.register_backend`): projected Gaussians of
    any camera model -> ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``."""
    if settings.tile_size & (settings.tile_size - 1):
        raise UnsupportedSettings(f"the Triton backend needs a power-of-two tile size, got {settings.tile_size}")
    if FORWARD not in FORWARDS:
        raise ValueError(f"unknown Triton forward {FORWARD!r}: choose one of {', '.join(FORWARDS)}")
    rects = pairs_carry_rects(proj)
    if FORWARD == "lean":
        return _lean_backend(proj, settings, background, rects)
    if not rects:
        from .triton_binning import bin_ids

        return composite_bins(proj, bin_ids(proj, settings.tile_size), settings, background)
    return composite_triton(proj, bin_to_tiles_by_key(proj, settings.tile_size), settings, background)


def pairs_carry_rects(proj: ProjectedGaussians) -> bool:
    """Whether the binning gives the pairs of ``proj`` their pixel rectangles (:data:`PAIR_FIELD`; always where the
    compositing cannot compute them: rows other than the Triton projection's)."""
    if PAIR_FIELD not in PAIR_FIELDS:
        raise ValueError(f"unknown Triton pair field {PAIR_FIELD!r}: choose one of {', '.join(PAIR_FIELDS)}")
    return PAIR_FIELD == "rects" or _projection_rows(proj) is None


def _lean_backend(proj: ProjectedGaussians, settings: RasterSettings, background: Tensor | None, rects: bool = True):
    """The ``"lean"`` forward: :func:`.triton_binning.bin_lean` into the cached capacity of this kind of render,
    compositing, then one read of the pair count (the GPU has the whole forward queued by then); where the pairs
    did not fit, the capacity grows to hold them and the binning and compositing run again: no pair is dropped (the
    first render of a kind sets its capacity by its pairs, :func:`.triton_binning.settle_capacity`). While
    reads are recorded (:func:`.projection.recording_reads`, a CUDA graph's capture), the count is recorded with the
    capacity and the forward returns: its recorder redoes it where the pairs did not fit."""
    from .triton_binning import bin_lean, grow_capacity, lean_capacity, settle_capacity

    key, capacity = lean_capacity(proj, settings.tile_size)
    while True:
        bins = bin_lean(proj, settings.tile_size, capacity, rects)
        out = composite_bins(proj, bins, settings, background)
        # The one host synchronisation, after the compositing is queued (recorded instead in a graph capture).
        needed = read_count(proj, bins.total, capacity)
        if not is_recording():  # (a recorded read returns 0: no count to learn from)
            settle_capacity(key, needed)
        if needed <= capacity:
            return out
        capacity = grow_capacity(key, needed)


def composite_bins(proj: ProjectedGaussians, bins, settings: RasterSettings, background: Tensor | None = None):
    """Stage 4 on :class:`.triton_binning.PairBins` (the ``"lean"`` forward's, complete only where their pair
    count fits their capacity, and :func:`.triton_binning.bin_ids`'). Returns ``rgb (C, 3, H, W), depth (C, H, W),
    alpha (C, H, W)``."""
    rows, layout, dtype = _composite_rows(proj)
    out = _TritonComposite.apply(*rows, bins.gaussian, bins.rows, bins.cols, bins.tile_start, proj.num_cameras,
                                 proj.height, proj.width, bins.tiles_x, bins.tiles_y, proj.wrap_u, settings, layout)
    return _finish(*out, dtype, background)


def _composite_rows(proj: ProjectedGaussians) -> tuple[tuple[Tensor, Tensor | None, Tensor | None], CompositeRows,
                                                      torch.dtype]:
    """The compositing kernels' inputs ``(geo, opacity, colour)``, where they read them (:class:`CompositeRows`) and
    the outputs' dtype: where ``uv``, ``conic`` and ``depth`` are columns 0-1, 2-4 and 7 of one float32 ``(M, 8)``
    tensor (the projection's rows, as :func:`.projection._pairs` makes them), those rows, the opacities and the
    colours as they are (contiguous float32; no concatenation, and the gradient reaches the projection's rows
    whole); else :func:`.rasterize.pack_projected`'s rows (``M x 11``)."""
    base = _projection_rows(proj)
    if base is not None:
        return (base, proj.opacity.contiguous(), proj.color.contiguous()), CompositeRows(1), torch.float32
    packed = pack_projected(proj)
    return (packed.float().contiguous(), None, None), CompositeRows(0), packed.dtype


def _projection_rows(proj: ProjectedGaussians) -> Tensor | None:
    """The projection's float32 ``(M, 8)`` rows ``[u, v, A, B, C, extent u, extent v, depth]`` that ``uv``,
    ``conic``, ``extent`` and ``depth`` are views of (as :func:`.projection._pairs` makes them from the Triton
    projection's), with float32 opacities and colours; else None."""
    base = proj.uv._base  # the projection's rows, (M, 8) or (B, V, N, 8)
    f32 = torch.float32
    views = (proj.uv, proj.conic, proj.extent, proj.depth)
    if (base is not None and base.dtype == f32 and base.shape[-1:] == (8,) and base.numel() == 8 * len(proj.depth)
            and base.is_contiguous() and all(t._base is base for t in views[1:])
            and proj.opacity.dtype == f32 and proj.color.dtype == f32
            and [t.storage_offset() - base.storage_offset() for t in views] == [0, 2, 5, 7]
            and [t.stride() for t in views] == [(8, 1), (8, 1), (8, 1), (8,)]):
        return base.view(-1, 8)
    return None
