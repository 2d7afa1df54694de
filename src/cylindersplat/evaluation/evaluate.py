"""Run methods over a dataset and score every target view with the paper's metrics."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from ..data.io import to_uint8, write_rgb
from ..data.occlusion import occluded_fraction, occluded_mask
from ..inference.pipeline import depth_limits, normalized_depth
from ..metrics import DepthRange, abs_rel, delta1, lrce, pcc, psnr, rmse, ssim, ws_psnr
from ..utils.colormap import colorize_depth
from ..utils.picture_grid import picture_grid
from .masked import MIN_OCCLUDED_PIXELS, masked_l1, masked_psnr, masked_ws_psnr
from .methods import Method

__all__ = ["EvalResult", "evaluate", "score_views", "comparison_image", "occluded_masks", "MIN_OCCLUDED_PIXELS",
           "OCCLUDED_METRICS"]

# Per-view keys computed on the occluded pixels only (None when the view has too few of them).
OCCLUDED_METRICS = ("ws_psnr_occluded", "psnr_occluded", "l1_occluded", "abs_rel_occluded")
# Valid depth of a PCC reference that is not metric (a network's relative depth): any positive finite value.
NON_METRIC_RANGE = DepthRange(0.0, math.inf)
# Row keys that are bookkeeping, not metrics to average.
_ROW_KEYS = ("example", "scene", "view", "method", "occluded_pixels")


@dataclass
class EvalResult:
    """``means[method][metric]`` over all target views; ``rows``: one dict per (example, view, method).

    Occluded-pixel metrics (``*_occluded``) average only the views that have them; ``means`` also
    holds ``views`` (target views scored) and ``occluded_views`` (views with at least
    :data:`MIN_OCCLUDED_PIXELS` occluded pixels). ``notes``: why occluded metrics were skipped, if so.
    """

    means: dict[str, dict[str, float | None]]
    rows: list[dict] = field(default_factory=list)
    num_examples: int = 0
    notes: list[str] = field(default_factory=list)
    backgrounds: dict[str, str] = field(default_factory=dict)  # method -> what it shows where it covers nothing


def occluded_masks(sample, stored_target_depths=None, stored_context_depths=None, rel_tol: float = 0.05
                   ) -> tuple[torch.Tensor | None, str | None]:
    """``(T, H, W)`` masks of the target pixels no context view sees, or ``(None, reason)``.

    Needs the ground-truth depth of the targets (to lift their pixels) and of the contexts (to
    depth-test): the depth prior is not what the context cameras saw, so it is never used here. When
    the stored, full-resolution depth maps are given (``(T, Hs, Ws)`` / ``(V, Hs, Ws)``, e.g. from
    :meth:`~cylindersplat.data.base.PanoramaDataset.stored_depths`), visibility is decided on them and
    sampled at the sample's pixel centres, so that the mask does not depend on the evaluation size.
    """
    if sample.target_depths is None:
        return None, "the targets have no ground-truth depth"
    if sample.context_gt_depths is None:
        return None, "the context views have no ground-truth depth (the depth prior is not used for this)"
    targets, contexts = sample.target_depths, sample.context_gt_depths
    if stored_target_depths is not None and stored_context_depths is not None:
        targets, contexts = stored_target_depths, stored_context_depths
    size = tuple(sample.target_depths.shape[-2:])
    masks = [occluded_mask(depth, pose, contexts, sample.context_poses, rel_tol=rel_tol, out_size=size)
             for depth, pose in zip(targets, sample.target_poses)]
    return torch.stack(masks), None


def stored_depths_for(dataset, index: int, sample) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """The stored-resolution depths of example ``index`` when the dataset resized them for ``sample``, else Nones."""
    reader = getattr(dataset, "stored_depths", None)
    if reader is None or sample.target_depths is None or getattr(dataset, "resolution", None) is None:
        return None, None
    targets, contexts = reader(index)
    if targets is None or contexts is None or targets.shape[-2:] == sample.target_depths.shape[-2:]:
        return None, None
    return targets, contexts


def _finite_or_none(value) -> float | None:
    value = float(value)
    return None if math.isnan(value) else value


def score_views(render, target_images, target_depths, lpips_net=None, depth_range: DepthRange = DepthRange(),
                occluded=None, pcc_depths=None) -> list[dict]:
    """Per-view metrics. ``render``: RenderOutput ``(T, ...)``; targets ``(T, 3, H, W)`` / ``(T, H, W)`` or None.

    ``pcc_depths`` ``(T, H, W)``: the PCC reference when it is not ``target_depths`` (e.g. files of
    another depth network, as the paper scores PCC against Depth Anywhere); then PCC is computed even
    without ground-truth depth, on every pixel where that reference is positive (it need not be metric,
    so ``depth_range`` does not apply to it).

    ``occluded``: ``(T, H, W)`` bool masks of the pixels no context sees (:func:`occluded_masks`);
    when given, every view also gets ``occluded_share`` (latitude-weighted share of the mask),
    ``occluded_pixels`` and :data:`OCCLUDED_METRICS` on the masked pixels, those being ``None`` for
    a view with fewer than :data:`MIN_OCCLUDED_PIXELS` occluded pixels.
    """
    rgb = render.rgb.clamp(0, 1).float()
    target = target_images.float()
    scores = {
        "ws_psnr": ws_psnr(rgb, target),
        "psnr": psnr(rgb, target),
        "ssim": ssim(rgb, target),
    }
    if lpips_net is not None:
        with torch.no_grad():
            scores["lpips"] = lpips_net(rgb, target).reshape(-1)
    depth = None
    if target_depths is not None or pcc_depths is not None:
        depth = normalized_depth(render.depth.float(), render.alpha.float())
        # PCC over every reference pixel in range; pixels the method left empty count with depth 0. A reference
        # from another network (pcc_depths, e.g. Depth Anywhere) need not be metric: the metric range does not
        # apply to it, only positive finite depth.
        reference = pcc_depths if pcc_depths is not None else target_depths
        pcc_range = depth_range if pcc_depths is None else NON_METRIC_RANGE
        scores["pcc"] = pcc(depth, reference.float().to(depth.device), depth_range=pcc_range)
    if target_depths is not None:
        scores["abs_rel"] = abs_rel(depth, target_depths.float(), depth_range=depth_range)
        scores["rmse"] = rmse(depth, target_depths.float(), depth_range=depth_range)
        scores["delta1"] = delta1(depth, target_depths.float(), depth_range=depth_range)
        # the paper's LRCE: the render's depth seam against the ground truth's (metrics.depth.lrce)
        scores["lrce"] = lrce(depth, target_depths.float(), depth_range=depth_range)
    rows = [{k: _finite_or_none(v[i]) if k == "lrce" else float(v[i]) for k, v in scores.items()}
            for i in range(rgb.shape[0])]
    if occluded is not None:
        occluded = occluded.to(rgb.device).bool()
        if occluded.shape != (rgb.shape[0], *rgb.shape[-2:]):
            raise ValueError(f"score_views: occluded masks {tuple(occluded.shape)} do not match the renders "
                             f"{tuple(rgb.shape)} (expected (T, H, W))")
        masked = {
            "ws_psnr_occluded": masked_ws_psnr(rgb, target, occluded),
            "psnr_occluded": masked_psnr(rgb, target, occluded),
            "l1_occluded": masked_l1(rgb, target, occluded),
        }
        if target_depths is not None:
            masked["abs_rel_occluded"] = abs_rel(depth, target_depths.float(), mask=occluded, depth_range=depth_range)
        for i, row in enumerate(rows):
            pixels = int(occluded[i].sum())
            enough = pixels >= MIN_OCCLUDED_PIXELS
            row["occluded_share"] = occluded_fraction(occluded[i])
            row["occluded_pixels"] = pixels
            for key in OCCLUDED_METRICS:
                row[key] = _finite_or_none(masked[key][i]) if enough and key in masked else None
    return rows


def comparison_image(target_rgb, target_depth, renders: dict, labels: bool = True) -> np.ndarray:
    """uint8 grid, one row per source (ground truth first, then each method): RGB | depth colormap; with
    ``labels``, column titles on top and each row's name above it
    (:func:`~cylindersplat.utils.picture_grid.picture_grid`)."""
    near, far = depth_limits(target_depth) if target_depth is not None else (None, None)
    blank = np.zeros_like(to_uint8(target_rgb))
    gt_depth = colorize_depth(target_depth, near, far, as_uint8=True) if target_depth is not None else blank
    rows = [("ground truth", to_uint8(target_rgb), gt_depth)]
    for name, (rgb, depth, alpha) in renders.items():
        d = normalized_depth(depth, alpha)
        rows.append((name, to_uint8(rgb), colorize_depth(d, near, far, as_uint8=True)))
    return picture_grid([[rgb, depth] for _, rgb, depth in rows], [name for name, _, _ in rows] if labels else None,
                        ["RGB", "depth (near blue, far red)"] if labels else None)


def evaluate(
    dataset,
    methods: list[Method],
    lpips_net=None,
    max_examples: int | None = None,
    example_dir: str | Path | None = None,
    num_pictures: int = 4,
    depth_range: DepthRange = DepthRange(),
    progress: bool = True,
    pcc_reference: str = "gt",
) -> EvalResult:
    """Score ``methods`` on the first ``max_examples`` examples of ``dataset``.

    ``pcc_reference``: ``"gt"`` scores PCC against ``Sample.target_depths``; ``"reference"`` against
    ``Sample.target_reference_depths`` (a dataset with ``target_reference`` set, e.g. by
    :func:`cylindersplat.data.make_dataset` with ``reference="file:depth_anywhere"``).

    ``time_s`` is the wall time of a method on one example (all its targets). Comparison pictures
    (ground truth, then each method; RGB | depth) of the first ``num_pictures`` targets go to
    ``example_dir`` when given.
    """
    count = len(dataset) if max_examples is None else min(max_examples, len(dataset))
    if count == 0:
        raise ValueError("evaluate: the dataset is empty")
    rows: list[dict] = []
    notes: list[str] = []
    pictures = 0
    # None: no bar when output is not a terminal
    for index in tqdm(range(count), desc="evaluate", unit="example", disable=None if progress else True):
        sample = dataset[index]
        pcc_depths = None
        if pcc_reference != "gt":
            pcc_depths = getattr(sample, "target_reference_depths", None)
            if pcc_depths is None:
                raise ValueError("evaluate: pcc_reference='reference' but the samples have no target_reference_depths "
                                 "(open the dataset with make_dataset(..., reference='file:NAME'))")
        occluded, reason = occluded_masks(sample, *stored_depths_for(dataset, index, sample))
        if reason is not None and sample.target_depths is not None:
            # Without target depth no depth metric exists and the table says so; a missing context
            # depth is worth a word, as it silently drops only the occluded columns.
            note = f"occluded-pixel metrics skipped: {reason}"
            if note not in notes:
                notes.append(note)
                warnings.warn(f"evaluate: {note} (example {index} and possibly others)", stacklevel=2)
        renders = {}
        for method in methods:
            start = time.perf_counter()
            out = method.run(sample)
            seconds = time.perf_counter() - start
            renders[method.name] = out
            scored = score_views(out, sample.target_images, sample.target_depths, lpips_net, depth_range, occluded,
                                 pcc_depths=pcc_depths)
            for view, scores in enumerate(scored):
                rows.append({"example": index, "scene": sample.metadata.get("scene", str(index)), "view": view,
                             "method": method.name, "time_s": seconds, **scores})
        if example_dir is not None:
            for view in range(sample.target_images.shape[0]):
                if pictures >= num_pictures:
                    break
                depth = sample.target_depths[view] if sample.target_depths is not None else None
                sheet = comparison_image(sample.target_images[view], depth,
                                         {k: (o.rgb[view], o.depth[view], o.alpha[view]) for k, o in renders.items()})
                write_rgb(Path(example_dir) / f"example_{index:04d}_view{view}.png", sheet)  # atomic, makes the folder
                pictures += 1
    means: dict[str, dict[str, float | None]] = {}
    for method in methods:
        mine = [r for r in rows if r["method"] == method.name]
        keys = [k for k in dict.fromkeys(k for r in mine for k in r) if k not in _ROW_KEYS]
        means[method.name] = {}
        exact: dict[int, list[str]] = {}
        for key in keys:
            if key in ("occluded_share", "lrce") or key in OCCLUDED_METRICS:
                # only the views that have the value (enough occluded pixels, valid reference depth at the seam)
                values = [r[key] for r in mine if r.get(key) is not None]
                means[method.name][key] = float(np.mean(values)) if values else None
            else:
                values = [r[key] for r in mine]
                finite = [v for v in values if v != math.inf]  # a PSNR of a render equal to its target is inf
                if len(finite) < len(values):
                    exact.setdefault(len(values) - len(finite), []).append(key)
                means[method.name][key] = float(np.mean(finite)) if finite else math.inf
        for count_exact, keys_exact in exact.items():
            what = (f"{method.name}: {count_exact} of {len(mine)} target views rendered exactly (infinite "
                    f"{', '.join(keys_exact)}; e.g. a target that is also an input view)")
            notes.append(f"{what} are left out of those means" if count_exact < len(mine) else
                         f"{what}: those means are infinite (null in results.json)")
        # time is per example, not per view
        means[method.name]["time_s"] = float(np.mean([r["time_s"] for r in mine if r["view"] == 0]))
        means[method.name]["views"] = len(mine)
        means[method.name]["occluded_views"] = sum(r.get("ws_psnr_occluded") is not None for r in mine)
    return EvalResult(means, rows, count, notes, {m.name: m.background for m in methods})
