"""The CPU backend: tile binning and per-tile compositing (forward and backward) compiled by numba.

The reference (:mod:`.rasterize`) expands every fragment into tensors and sorts them; on a CPU that
memory traffic is the cost. Here the work is three loops compiled by numba (:mod:`.numba_kernels`):
a counting sort of (Gaussian, tile) pairs by tile in depth order, a parallel loop over tiles whose
pixels walk their pairs front to back, and the same walk backwards for gradients. The projection has its own
numba kernels (:mod:`.numba_projection`, forward and analytic backward); gradients reach it through the
compositing's analytic backward. The rules, and so the images and gradients, are the reference's.

The kernels compile at the first CPU render after an install (16 s forward + 8 s backward on the 2-core machine
at load 0.5, 22 + 11 s at load 10), then numba loads them from its on-disk cache (about a second); a first call
that takes over :data:`COMPILE_NOTICE_AFTER_S` says so (:func:`compile_notice`). Numba's thread count follows
``torch.get_num_threads()``.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import threading
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch
from torch import Tensor

from ..utils.notices import notice_once
from . import rasterize
from .projection import ProjectedGaussians, RasterSettings, UnsupportedSettings
from .rasterize import pack_projected, unpack_composited

__all__ = ["numba_available", "numba_backend", "NumbaBins", "bin_pairs_numba", "composite_numba", "compile_notice",
           "COMPILE_NOTICE_AFTER_S"]

# A first call of a stage's kernels that lasts longer than this (seconds) is compiling them: a Notice says so, once
# per process, while it waits (None: never). Loading them from numba's cache takes about a second.
COMPILE_NOTICE_AFTER_S: float | None = 3.0
COMPILE_NOTICE = ("compiling the CPU renderer's kernels (numba): once after an install, about 15-30 s; later runs "
                  "load them from numba's cache in about a second")
_CALLED_STAGES: set[str] = set()


def numba_available() -> bool:
    return importlib.util.find_spec("numba") is not None


@dataclass
class NumbaBins:
    """(Gaussian, tile) pairs in (tile, depth) order, as the kernels read them.

    spans ``(M, 6)`` int64 per projected Gaussian: rows ``i0..i1`` and column intervals ``a0..b0``,
    ``a1..b1`` (``b < a``: none); pairs ``(P,)`` int64 ``2 * row + interval``; tile_start ``(T + 1,)``.
    """

    spans: np.ndarray
    pairs: np.ndarray
    tile_start: np.ndarray
    tiles_x: int
    tiles_y: int


@contextlib.contextmanager
def compile_notice(stage: str) -> Iterator[None]:
    """Around a call of ``stage``'s kernels (e.g. ``"project"``, ``"composite backward"``): where it is the stage's
    first in this process and lasts over :data:`COMPILE_NOTICE_AFTER_S`, numba is compiling them, and a
    :class:`~cylindersplat.utils.notices.Notice` says so from a timer while the call goes on (one per process)."""
    if stage in _CALLED_STAGES or COMPILE_NOTICE_AFTER_S is None:
        _CALLED_STAGES.add(stage)
        yield
        return
    timer = threading.Timer(COMPILE_NOTICE_AFTER_S, _say_compiling)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        _CALLED_STAGES.add(stage)


def _say_compiling() -> None:
    notice_once("numba compile", COMPILE_NOTICE, stacklevel=2)  # shown at this line, not in threading.py


def _kernels():
    import numba

    from . import numba_kernels

    threads = torch.get_num_threads()
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    if torch.get_num_threads() != threads:  # launching numba's OpenMP pool resets the count torch shares with it
        torch.set_num_threads(threads)
    return numba_kernels


def _work_dtype(dtype: torch.dtype) -> torch.dtype:
    return dtype if dtype in (torch.float32, torch.float64) else torch.float32


def _numpy(t: Tensor, dtype: torch.dtype | None = None) -> np.ndarray:
    return t.detach().to(dtype or t.dtype).contiguous().numpy()


def _depth_order(depth: np.ndarray) -> np.ndarray:
    """Rows by depth, ties by row (the reference's stable ranking). float32: a radix sort of the depths' bits
    (:func:`.numba_kernels.depth_order`; depths are positive, so their bits sort as the values do)."""
    if depth.dtype == np.float32:
        return _kernels().depth_order(depth)
    return np.argsort(depth, kind="stable")


def bin_pairs_numba(proj: ProjectedGaussians, tile_size: int) -> NumbaBins:
    """Stage 2 of the reference (:func:`.rasterize.bin_to_tiles`): pairs sorted by (camera, tile, depth).

    Refuses (:class:`.rasterize.RenderMemoryError`) a render whose pairs would not fit in free memory."""
    kernels = _kernels()
    dtype = _work_dtype(proj.uv.dtype)
    half = np.dtype(str(dtype).removeprefix("torch.")).type(0.5)
    tiles_x, tiles_y = math.ceil(proj.width / tile_size), math.ceil(proj.height / tile_size)
    with compile_notice("bin"):
        spans, counts = kernels.tile_spans(_numpy(proj.uv, dtype), _numpy(proj.extent, dtype), proj.height,
                                           proj.width, tile_size, proj.wrap_u, half)
        rasterize.check_pair_memory(int(counts.sum()), proj.uv.device, proj.num_cameras)
        order = _depth_order(_numpy(proj.depth, dtype))
        tile_start, pairs = kernels.bin_pairs(order, spans, _numpy(proj.camera, torch.int64), proj.num_cameras,
                                              tiles_x, tiles_y, tile_size)
    return NumbaBins(spans, pairs, tile_start, tiles_x, tiles_y)


class _NumbaComposite(torch.autograd.Function):
    """Per-tile compositing of packed rows ``(M, 11)`` (:func:`.rasterize.pack_projected`) -> ``(C*H*W, 5)``."""

    @staticmethod
    def forward(ctx, packed: Tensor, bins: NumbaBins, proj_shape: tuple[int, int, bool], settings: RasterSettings):
        kernels = _kernels()
        height, width, wrap_u = proj_shape
        work = _numpy(packed, _work_dtype(packed.dtype))
        with compile_notice("composite"):
            pair_packed, pair_spans, local = kernels.gather_pairs(work, bins.spans, bins.pairs)
            args = _kernel_args(bins, local, pair_spans, work.dtype, height, width, wrap_u, settings)
            out = kernels.composite_forward(pair_packed, *args)
        ctx.save_for_backward(packed)  # (its length; and autograd refuses a backward after an in-place change)
        ctx.bins, ctx.args, ctx.out, ctx.pair_packed = bins, args, out, pair_packed  # the backward walks the same rows
        return torch.from_numpy(out).to(packed.dtype)

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        kernels = _kernels()
        (packed,) = ctx.saved_tensors
        with compile_notice("composite backward"):
            pair_grads = kernels.composite_backward(ctx.pair_packed, *ctx.args, ctx.out,
                                                    _numpy(grad_out, torch.float64))
            grads = kernels.reduce_pair_grads(ctx.bins.pairs, pair_grads, len(packed))
        return torch.from_numpy(grads).to(packed.dtype), None, None, None


def _kernel_args(bins: NumbaBins, pairs: np.ndarray, spans: np.ndarray, dtype: np.dtype, height: int, width: int,
                 wrap_u: bool, settings: RasterSettings):
    """The kernels' arguments after the (pair-ordered) packed rows: pairs and spans in pair order
    (:func:`.numba_kernels.gather_pairs`), per-fragment constants in the packed dtype (as the reference's)."""
    size = max(height, width)
    centers = np.arange(size, dtype=dtype) + dtype.type(0.5)
    consts = np.array([width, width / 2, 2, -0.5, settings.sigma_extent**2, settings.alpha_max, settings.alpha_min],
                      dtype=dtype)
    return (pairs, bins.tile_start, spans, centers, consts, height, width, bins.tiles_x,
            settings.tile_size, bool(wrap_u), float(settings.transmittance_min))


def composite_numba(proj: ProjectedGaussians, bins: NumbaBins, settings: RasterSettings,
                    background: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Stage 4 on the CPU. Returns ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``."""
    out = _NumbaComposite.apply(pack_projected(proj), bins, (proj.height, proj.width, proj.wrap_u), settings)
    return unpack_composited(out, proj, background)


def numba_backend(proj: ProjectedGaussians, settings: RasterSettings, background: Tensor | None = None):
    """The backend function (:func:`cylindersplat.render.register_backend`): projected Gaussians of any
    camera model on the CPU -> ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``."""
    if proj.uv.device.type != "cpu":
        raise UnsupportedSettings(f"the numba backend renders on the CPU, not on {proj.uv.device.type}")
    return composite_numba(proj, bin_pairs_numba(proj, settings.tile_size), settings, background)
