"""Contact sheet of a dataset (one row per example, RGB next to colourised depth, per view) and the
per-example figures ``cylindersplat data info`` prints (baseline, occluded share of each target)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from ..dataset_layouts import DATASET_SPECS, dataset_spec, detect_layout  # the rule of every command
from ..utils.atomic import atomic_path
from ..utils.colormap import colorize_depth
from .base import FrameRef, PanoramaDataset, _baseline
from .io import read_depth_npy, read_depth_png, to_uint8
from .occlusion import occluded_fraction, occluded_mask

__all__ = ["open_dataset", "default_views", "contact_sheet", "write_contact_sheet", "ExampleOcclusion",
           "example_occlusion", "occlusion_summary"]


def _layout_spec(path: Path):
    """The spec of the layout ``path`` holds, ``None`` for none the registry knows (a missing folder keeps its
    ``FileNotFoundError``)."""
    try:
        return dataset_spec(detect_layout(path))
    except ValueError:
        return None


def default_views(path: str | Path, purpose: str = "preview") -> str | None:
    """The views ``data preview`` (``purpose="preview"``) or ``data info`` (``"info"``) shows of the dataset at
    ``path`` unless told otherwise (its spec's); ``None`` for a folder that is no dataset."""
    spec = _layout_spec(Path(path))
    return None if spec is None else getattr(spec, f"{purpose}_views")


def open_dataset(path: str | Path, resolution: tuple[int, int] | None = None, views: str | None = None,
                 targets: list[str] | None = None, allow_outside_paths: bool = False) -> PanoramaDataset:
    """Any dataset the registry knows (:func:`~cylindersplat.dataset_layouts.detect_layout`), without a depth
    prior (pictures and occlusion need none). ``views`` defaults to the layout's preview views (``n_view``, every
    frame of a 3-frame sequence; for a folder of panoramas ``all_inputs``, every frame in poses-file order whatever
    their number; 360Loc's ``all_between``); ``targets`` (folders only) holds those frames out, as ``eval
    --targets`` does; ``allow_outside_paths`` (folders only) reads files their poses files name outside them."""
    path = Path(path)
    spec = _layout_spec(path)
    if targets and (spec is None or not spec.accepts("targets")):
        raise ValueError(f"{path}: targets hold out frames of a folder of posed panoramas (poses.json), "
                         "not of a synthetic or png_render_* dataset; choose views (--views) there")
    if spec is None:
        known = [dataset_spec(name).what for name in DATASET_SPECS]
        raise ValueError(f"{path}: not a dataset: neither {', '.join(known[:-1])} nor {known[-1]}")
    chosen = {"targets": targets, "allow_outside_paths": allow_outside_paths}
    options = {key: value for key, value in chosen.items() if spec.accepts(key)}
    return spec.inspect(path, views=views or spec.preview_views, resolution=resolution, **options)


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
    depth = {i: _stored_depth(ref.frames[i], expected) for i in ctx + tgt}
    sizes = {tuple(d.shape) for d in depth.values()}
    if len(sizes) > 1:  # folders fix no size
        files = ", ".join(str(ref.frames[i].depth) for i in ctx + tgt)
        raise ValueError(f"depth maps of one example differ in size {sorted(sizes)}: {files}")
    context_gt = torch.stack([depth[i] for i in ctx])  # ground truth (what the context cameras saw), not the prior
    shares = [occluded_fraction(occluded_mask(depth[t], poses[t], context_gt, poses[ctx])) for t in tgt]
    return ExampleOcclusion(ref.scene, baseline, shares)


def _stored_depth(frame: FrameRef, expected: tuple[int, int] | None) -> torch.Tensor:
    """A frame's depth file in metres at its stored size (folders: ``.npy`` files, their own ``depth_scale``)."""
    if Path(frame.depth).suffix.lower() == ".npy":
        depth = read_depth_npy(frame.depth)
        return depth if frame.depth_scale is None else depth / frame.depth_scale
    return read_depth_png(frame.depth, expected=expected,
                          **({} if frame.depth_scale is None else {"scale": frame.depth_scale}))


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
        depths = _frame_depths(dataset, index, s)
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


def _frame_depths(dataset: PanoramaDataset, index: int, sample) -> list[torch.Tensor | None]:
    """Each frame's depth (contexts, then targets), ``None`` where it has no depth file. A :class:`Sample`
    holds a group's depths only when every frame of it has one; a folder may give only some frames one."""
    depths: list[torch.Tensor | None] = []
    for group, indices in ((sample.context_gt_depths, sample.metadata["context_indices"]),
                           (sample.target_depths, sample.metadata["target_indices"])):
        if group is not None:
            depths += list(group)
            continue
        frames = dataset.example(index).frames
        depths += [dataset.load_frame(frames[i])[1] if frames[i].depth is not None else None for i in indices]
    return depths


def write_contact_sheet(data: str | Path, out: str | Path, count: int = 4, height: int = 128,
                        allow_outside_paths: bool = False) -> Path:
    sheet = contact_sheet(open_dataset(data, resolution=(height, 2 * height), allow_outside_paths=allow_outside_paths),
                          count)
    out = Path(out)
    with atomic_path(out) as tmp:  # a failed write keeps an earlier sheet; the temporary keeps the suffix (format)
        Image.fromarray(sheet).save(tmp)
    return out
