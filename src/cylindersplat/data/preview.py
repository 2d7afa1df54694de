"""Contact sheet of a dataset (one row per example, RGB next to colourised depth, per view) and the
per-example figures ``cylindersplat data info`` prints (baseline, occluded share of each target)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from ..utils.atomic import atomic_path
from ..utils.colormap import colorize_depth
from .base import PanoramaDataset, _baseline
from .depth_prior.base import NoPrior
from .io import read_depth_png, to_uint8
from .occlusion import occluded_fraction, occluded_mask
from .pano_grf import PanoGRFDataset
from .synthetic import SyntheticDataset

__all__ = ["open_dataset", "contact_sheet", "write_contact_sheet", "ExampleOcclusion", "example_occlusion",
           "occlusion_summary"]


def open_dataset(path: str | Path, resolution: tuple[int, int] | None = None, views="n_view") -> PanoramaDataset:
    """A synthetic folder (has ``meta.json``) or a ``png_render_*`` PanoGRF folder (default: n-view order)."""
    path = Path(path)
    if (path / "meta.json").is_file():
        return SyntheticDataset(path, views=views, resolution=resolution, depth_prior=NoPrior())
    if path.name.startswith("png_render_"):
        return PanoGRFDataset(path, views=views, resolution=resolution, depth_prior=NoPrior())  # pictures need no prior
    raise ValueError(f"{path}: neither a synthetic dataset (meta.json) nor a png_render_* folder")


@dataclass
class ExampleOcclusion:
    """One example's context baseline (m) and, per target view, the latitude-weighted share of its
    pixels that no context view sees (``None`` without ground-truth depth)."""

    scene: str
    baseline: float
    occluded: list[float] | None


def example_occlusion(dataset: PanoramaDataset, index: int) -> ExampleOcclusion:
    """:class:`ExampleOcclusion` of example ``index`` from the stored ground-truth depth maps (stored
    resolution, no image decoding): :func:`~cylindersplat.data.occlusion.occluded_mask` per target."""
    ref = dataset.example(index)
    ctx, tgt = list(ref.views.context), list(ref.views.target)
    poses = torch.stack([f.c2w.float() for f in ref.frames])
    baseline = _baseline(poses[ctx], poses[tgt])
    if any(ref.frames[i].depth is None or not Path(ref.frames[i].depth).is_file() for i in ctx + tgt):
        return ExampleOcclusion(ref.scene, baseline, None)
    expected = getattr(dataset, "stored_size", None)
    depth = {i: read_depth_png(ref.frames[i].depth, expected=expected) for i in ctx + tgt}
    context_gt = torch.stack([depth[i] for i in ctx])  # ground truth (what the context cameras saw), not the prior
    shares = [occluded_fraction(occluded_mask(depth[t], poses[t], context_gt, poses[ctx])) for t in tgt]
    return ExampleOcclusion(ref.scene, baseline, shares)


def occlusion_summary(dataset: PanoramaDataset, count: int = 64) -> dict | None:
    """Mean / median / min / max occluded share of the targets and mean baseline over ``count``
    evenly spaced examples (all when ``count >= len``); ``None`` when the dataset has no depth."""
    if count <= 0 or len(dataset) == 0:
        return None
    indices = np.unique(np.linspace(0, len(dataset) - 1, min(count, len(dataset))).round().astype(int))
    items = [example_occlusion(dataset, int(i)) for i in indices]
    shares = np.array([s for it in items if it.occluded is not None for s in it.occluded])
    if shares.size == 0:
        return None
    per_example = np.array([np.mean(it.occluded) for it in items if it.occluded is not None])
    return {
        "examples": len(per_example), "targets": int(shares.size), "of": len(dataset),
        "mean": float(shares.mean()), "median": float(np.median(shares)), "min": float(shares.min()),
        "max": float(shares.max()), "at_least_1pct": float((per_example >= 0.01).mean()),
        "baseline": float(np.mean([it.baseline for it in items])),
    }


def contact_sheet(dataset: PanoramaDataset, count: int = 4, gap: int = 4) -> np.ndarray:
    """uint8 ``(rows*h, cols*w, 3)`` grid: for each of the first ``count`` examples, every frame's
    RGB followed by its depth (turbo, inverse depth; black = no depth)."""
    rows = []
    for index in range(min(count, len(dataset))):
        s = dataset[index]
        images = list(s.context_images) + list(s.target_images)
        depths = list(s.context_gt_depths) if s.context_gt_depths is not None else [None] * s.num_context
        depths += list(s.target_depths) if s.target_depths is not None else [None] * s.num_target
        tiles = []
        for image, depth in zip(images, depths):
            tiles.append(to_uint8(image))
            tiles.append(colorize_depth(depth, as_uint8=True) if depth is not None else np.zeros_like(tiles[-1]))
        rows.append(tiles)
    if not rows:
        raise ValueError("contact_sheet: the dataset is empty")
    h, w = rows[0][0].shape[:2]
    cols = max(len(r) for r in rows)
    sheet = np.full((len(rows) * (h + gap) - gap, cols * (w + gap) - gap, 3), 255, np.uint8)
    for r, tiles in enumerate(rows):
        for c, tile in enumerate(tiles):
            sheet[r * (h + gap) : r * (h + gap) + h, c * (w + gap) : c * (w + gap) + w] = tile
    return sheet


def write_contact_sheet(data: str | Path, out: str | Path, count: int = 4, height: int = 128) -> Path:
    sheet = contact_sheet(open_dataset(data, resolution=(height, 2 * height)), count)
    out = Path(out)
    with atomic_path(out) as tmp:  # a failed write keeps an earlier sheet; the temporary keeps the suffix (format)
        Image.fromarray(sheet).save(tmp)
    return out
