"""Contact sheet of a dataset: one row per example, RGB next to colourised depth, per view."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from ..utils.colormap import colorize_depth
from .io import to_uint8
from .base import PanoramaDataset
from .depth_prior.base import NoPrior
from .pano_grf import PanoGRFDataset
from .synthetic import SyntheticDataset

__all__ = ["open_dataset", "contact_sheet", "write_contact_sheet"]


def open_dataset(path: str | Path, resolution: tuple[int, int] | None = None) -> PanoramaDataset:
    """A synthetic folder (has ``meta.json``) or a ``png_render_*`` PanoGRF folder, in n-view order."""
    path = Path(path)
    if (path / "meta.json").is_file():
        return SyntheticDataset(path, views="n_view", resolution=resolution, depth_prior=NoPrior())
    if path.name.startswith("png_render_"):
        return PanoGRFDataset(path, views="n_view", resolution=resolution)
    raise ValueError(f"{path}: neither a synthetic dataset (meta.json) nor a png_render_* folder")


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
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(out)
    return out
