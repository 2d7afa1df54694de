"""How many (Gaussian, tile) pairs the Triton compositing kernels walk (issue 35: why the backward of 0.1 M Gaussians
took longer than that of 1.3 M). A tile's program walks its pairs front to back until every pixel's transmittance is
below ``transmittance_min``: the forward counts the live pixels after each run of
:data:`cylindersplat.render.triton_kernels._ALIVE_EVERY` pairs, the backward after each pair. Its work is the pairs it
walks - a block of pixels, block-wide sums and atomics each - not the pairs it has. A sparse scene leaves pixels
alive, so its tiles walk nearly all their pairs; a dense one stops early.

:func:`tile_walk` replays the kernels' termination rule on the reference binning (:func:`.rasterize.bin_to_tiles`),
compiled with numba on the CPU, whatever device renders; ``bench render --tile-walk`` prints it per size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import torch

from cylindersplat.render import RasterSettings
from cylindersplat.render.projection import ProjectedGaussians
from cylindersplat.render.rasterize import bin_to_tiles

__all__ = ["TileWalk", "tile_walk", "tile_walk_line", "FORWARD_RUN"]

FORWARD_RUN = 8  # pairs between two counts of the live pixels in the forward kernel (triton_kernels._ALIVE_EVERY)


@dataclass
class TileWalk:
    """pairs: (tiles,) pairs each tile has; forward / backward: (tiles,) pairs each kernel walks; used: (tiles,)
    fragments composited (a pixel's, before its transmittance fell below the cut-off); alpha: (cameras, H, W) the
    alpha the walked fragments give (the render's own, to check the walk against)."""

    pairs: np.ndarray
    forward: np.ndarray
    backward: np.ndarray
    used: np.ndarray
    alpha: np.ndarray


@numba.njit(parallel=True, cache=True)
def _walk(starts, pair_gaussian, rows, cols, col_shift, uv, conic, opacity, tiles_x, tiles_per_camera, tile, height,
          width, sigma2, alpha_max, alpha_min, t_min, run):  # pragma: no cover - compiled (tested through tile_walk)
    tiles = len(starts) - 1
    forward = np.zeros(tiles, np.int64)
    backward = np.zeros(tiles, np.int64)
    used = np.zeros(tiles, np.int64)
    alpha = np.zeros((tiles // tiles_per_camera, height, width))
    for t in numba.prange(tiles):
        cam, local = t // tiles_per_camera, t % tiles_per_camera
        ty, tx = local // tiles_x, local % tiles_x
        trans = np.ones(tile * tile)
        alive = np.zeros(tile * tile, np.bool_)
        for k in range(tile * tile):
            alive[k] = ty * tile + k // tile < height and tx * tile + k % tile < width
        n_alive = alive.sum()
        p, end = starts[t], starts[t + 1]
        while p < end and n_alive > 0:
            g = pair_gaussian[p]
            for k in range(tile * tile):
                r, c = ty * tile + k // tile, tx * tile + k % tile
                if not alive[k] or r < rows[p, 0] or r > rows[p, 1] or c < cols[p, 0] or c > cols[p, 1]:
                    continue  # (the pair's pixel ranges, in the image's columns)
                du, dv = c - col_shift[p] + 0.5 - uv[g, 0], r + 0.5 - uv[g, 1]  # (from the unwrapped column)
                mahal = conic[g, 0] * du * du + 2.0 * conic[g, 1] * du * dv + conic[g, 2] * dv * dv
                a = min(opacity[g] * np.exp(-0.5 * mahal), alpha_max)
                if mahal > sigma2 or a < alpha_min:
                    continue
                after = trans[k] * (1.0 - a)
                if after < t_min:  # this fragment and the pixel's later ones are dropped
                    alive[k] = False
                    n_alive -= 1
                else:
                    trans[k] = after
                    used[t] += 1
            p += 1
        backward[t] = p - starts[t]  # (up to the pair that left no pixel alive, or all of them)
        forward[t] = min(starts[t] + -(-backward[t] // run) * run, end) - starts[t]  # up to the end of its run
        for k in range(tile * tile):
            r, c = ty * tile + k // tile, tx * tile + k % tile
            if r < height and c < width:
                alpha[cam, r, c] = 1.0 - trans[k]
    return forward, backward, used, alpha


def tile_walk(proj: ProjectedGaussians, settings: RasterSettings | None = None) -> TileWalk:
    """The pairs each tile of ``proj`` has and those the forward and backward kernels walk (see the module)."""
    settings = settings or RasterSettings()
    tile = settings.tile_size
    bins = bin_to_tiles(proj, tile)
    tiles_per_camera = bins.tiles_x * bins.tiles_y
    starts = np.searchsorted(bins.tile.cpu().numpy(), np.arange(proj.num_cameras * tiles_per_camera + 1))
    as64 = lambda t: np.ascontiguousarray(t.detach().cpu().double().numpy())  # noqa: E731
    forward, backward, used, alpha = _walk(
        starts, bins.gaussian.cpu().numpy(), bins.rows.cpu().numpy(), bins.cols.cpu().numpy(),
        bins.col_shift.cpu().numpy(), as64(proj.uv), as64(proj.conic), as64(proj.opacity), bins.tiles_x,
        tiles_per_camera, tile, proj.height, proj.width, float(settings.sigma_extent) ** 2, float(settings.alpha_max),
        float(settings.alpha_min), float(settings.transmittance_min), FORWARD_RUN)
    return TileWalk(np.diff(starts), forward, backward, used, alpha)


def tile_walk_line(num: int, height: int, camera: str = "equirect") -> str:
    """``# tile walk`` of the benchmarks' scene (:func:`cylindersplat.scenes.random_indoor` from its centre) at
    ``height x 2 height``: its pairs, and those the kernels walk, in all and per tile."""
    from cylindersplat.scenes import random_indoor

    from .views import view_camera

    model = view_camera(camera, height)
    walk = tile_walk(model.project(random_indoor(num), torch.eye(4)[None], RasterSettings()))
    pairs, tiles = int(walk.pairs.sum()), len(walk.pairs)
    share = lambda walked: f"{int(walked.sum()):,} ({walked.sum() / max(pairs, 1):.1%}, {walked.mean():.0f} a tile)"  # noqa: E731
    return (f"# tile walk ({num} Gaussians, {height}x{2 * height}, {camera}): {pairs:,} pairs ({pairs / tiles:.0f} a "
            f"tile), the forward walks {share(walk.forward)}, the backward {share(walk.backward)}; "
            f"{int(walk.used.sum()) / walk.alpha.size:.1f} fragments composited a pixel")
