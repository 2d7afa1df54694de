"""Run methods over a dataset and score every target view with the paper's metrics."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from tqdm.auto import tqdm

from ..data.io import to_uint8
from ..inference.pipeline import depth_limits, normalized_depth
from ..metrics import DepthRange, abs_rel, delta1, lrce, pcc, psnr, rmse, ssim, ws_psnr
from ..utils.colormap import colorize_depth
from .methods import Method

__all__ = ["EvalResult", "evaluate", "score_views", "comparison_image"]


@dataclass
class EvalResult:
    """``means[method][metric]`` over all target views; ``rows``: one dict per (example, view, method)."""

    means: dict[str, dict[str, float | None]]
    rows: list[dict] = field(default_factory=list)
    num_examples: int = 0


def score_views(render, target_images, target_depths, lpips_net=None, depth_range: DepthRange = DepthRange()) -> list[dict]:
    """Per-view metrics. ``render``: RenderOutput ``(T, ...)``; targets ``(T, 3, H, W)`` / ``(T, H, W)`` or None."""
    rgb = render.rgb.clamp(0, 1).float()
    target = target_images.float()
    scores = {
        "ws_psnr": ws_psnr(rgb, target),
        "psnr": psnr(rgb, target),
        "ssim": ssim(rgb, target),
        "lrce": lrce(rgb),
    }
    if lpips_net is not None:
        with torch.no_grad():
            scores["lpips"] = lpips_net(rgb, target).reshape(-1)
    if target_depths is not None:
        depth = normalized_depth(render.depth.float(), render.alpha.float())
        # PCC over every reference pixel in range; pixels the method left empty count with depth 0.
        scores["pcc"] = pcc(depth, target_depths.float(), depth_range=depth_range)
        scores["abs_rel"] = abs_rel(depth, target_depths.float(), depth_range=depth_range)
        scores["rmse"] = rmse(depth, target_depths.float(), depth_range=depth_range)
        scores["delta1"] = delta1(depth, target_depths.float(), depth_range=depth_range)
    return [{k: float(v[i]) for k, v in scores.items()} for i in range(rgb.shape[0])]


def comparison_image(target_rgb, target_depth, renders: dict, labels: bool = True) -> np.ndarray:
    """uint8 grid, one row per source (ground truth first, then each method): RGB | depth colormap."""
    near, far = depth_limits(target_depth) if target_depth is not None else (None, None)
    rows = []
    blank = np.zeros_like(to_uint8(target_rgb))
    gt_depth = colorize_depth(target_depth, near, far, as_uint8=True) if target_depth is not None else blank
    rows.append(("ground truth", to_uint8(target_rgb), gt_depth))
    for name, (rgb, depth, alpha) in renders.items():
        d = normalized_depth(depth, alpha)
        rows.append((name, to_uint8(rgb), colorize_depth(d, near, far, as_uint8=True)))
    gap = 4
    h, w = rows[0][1].shape[:2]
    sheet = np.full((len(rows) * (h + gap) - gap, 2 * w + gap, 3), 255, np.uint8)
    for r, (_, rgb, depth) in enumerate(rows):
        sheet[r * (h + gap): r * (h + gap) + h, :w] = rgb
        sheet[r * (h + gap): r * (h + gap) + h, w + gap:] = depth
    return sheet


def evaluate(
    dataset,
    methods: list[Method],
    lpips_net=None,
    max_examples: int | None = None,
    example_dir: str | Path | None = None,
    num_pictures: int = 4,
    depth_range: DepthRange = DepthRange(),
    progress: bool = True,
) -> EvalResult:
    """Score ``methods`` on the first ``max_examples`` examples of ``dataset``.

    ``time_s`` is the wall time of a method on one example (all its targets). Comparison pictures
    (ground truth, then each method; RGB | depth) of the first ``num_pictures`` targets go to
    ``example_dir`` when given.
    """
    count = len(dataset) if max_examples is None else min(max_examples, len(dataset))
    if count == 0:
        raise ValueError("evaluate: the dataset is empty")
    rows: list[dict] = []
    pictures = 0
    for index in tqdm(range(count), desc="evaluate", unit="example", disable=not progress):
        sample = dataset[index]
        renders = {}
        for method in methods:
            start = time.perf_counter()
            out = method.run(sample)
            seconds = time.perf_counter() - start
            renders[method.name] = out
            for view, scores in enumerate(score_views(out, sample.target_images, sample.target_depths, lpips_net, depth_range)):
                rows.append({"example": index, "scene": sample.metadata.get("scene", str(index)), "view": view,
                             "method": method.name, "time_s": seconds, **scores})
        if example_dir is not None:
            for view in range(sample.target_images.shape[0]):
                if pictures >= num_pictures:
                    break
                depth = sample.target_depths[view] if sample.target_depths is not None else None
                sheet = comparison_image(sample.target_images[view], depth,
                                         {k: (o.rgb[view], o.depth[view], o.alpha[view]) for k, o in renders.items()})
                Path(example_dir).mkdir(parents=True, exist_ok=True)
                Image.fromarray(sheet).save(Path(example_dir) / f"example_{index:04d}_view{view}.png")
                pictures += 1
    means: dict[str, dict[str, float | None]] = {}
    for method in methods:
        mine = [r for r in rows if r["method"] == method.name]
        keys = [k for k in mine[0] if k not in ("example", "scene", "view", "method")]
        means[method.name] = {k: float(np.mean([r[k] for r in mine])) for k in keys}
        # time is per example, not per view
        means[method.name]["time_s"] = float(np.mean([r["time_s"] for r in mine if r["view"] == 0]))
    return EvalResult(means, rows, count)
