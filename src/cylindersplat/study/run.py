"""Run a study: train every variant x seed with one schedule, score each on the same held-out scenes, and write
``ablation.json`` (per variant: every metric's per-seed values, mean and spread, plus training time, skipped
steps and Gaussian counts) and ``ablation.md`` (:func:`~.table.study_table`).

All variants get the same number of optimizer steps (``Schedule.total``): the full model runs stages 1-2-3, the
pixel-only model spends them all in stage 1, volume-only models run stage 1 (the pixel branch provides the volume
branch's features and depth) then stage 2. Runs are resumable: a variant/seed whose ``model.safetensors`` exists
is scored, not retrained.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, replace
from pathlib import Path

from ..evaluation.fills import FILL_DESCRIPTIONS
from ..utils.atomic import atomic_write_text
from ..utils.jsonfile import json_text
from .aggregate import RunResult, aggregate
from .schedule import STUDY_THREADS, Schedule, Variant, torch_threads
from .table import study_table

__all__ = ["run_study", "check_variants"]

# the held-out scenes are scored with these valid reference depths (metres)
STUDY_DEPTH_RANGE = (0.05, 1000.0)


def _train(variant: Variant, seed: int, schedule: Schedule, data_root: Path, train_ids: list[str], run_dir: Path,
           resolution: tuple[int, int], device: str) -> tuple[Path, float, int]:
    import torch

    from ..training import Trainer, load_config

    weights = run_dir / "model.safetensors"
    meta = run_dir / "study_run.json"
    if weights.is_file() and meta.is_file():
        info = json.loads(meta.read_text())
        if info.get("overrides", list(variant.overrides)) != list(variant.overrides):
            raise ValueError(f"{run_dir} holds a finished run of {variant.name} with other settings "
                             f"({info['overrides']}, not {list(variant.overrides)}); choose another output folder")
        return weights, info["train_s"], info["skipped_steps"]
    stages, steps = variant.stages(schedule)
    # the variant's own switches are command-line overrides; the study's settings are typed changes
    config = load_config("tiny", variant.overrides, changes={
        "data.root": data_root, "output_dir": run_dir, "data.resolution": list(resolution),
        "data.options": {"scenes": list(train_ids)}, "train.stages": list(stages), "train.steps_per_stage": list(steps),
        "train.lr": schedule.lr, "train.warmup_steps": 10, "train.seed": seed, "train.device": str(device),
        "train.progress": False, "train.image_every": 0, "train.tensorboard": False,
        "train.checkpoint_every": schedule.total + 1, "train.log_every": 25,
    })
    start = time.perf_counter()
    resume = run_dir if (run_dir / "checkpoints").is_dir() else None  # a killed study continues its run
    summary = Trainer(config, resume=resume).fit()
    train_s = time.perf_counter() - start
    atomic_write_text(meta, json.dumps({"train_s": train_s, "skipped_steps": summary.get("skipped_steps", 0),
                                        "stages": stages, "steps": steps, "seed": seed,
                                        "overrides": list(variant.overrides), "threads": torch.get_num_threads()}))
    return Path(summary["weights"]), train_s, int(summary.get("skipped_steps", 0))


def _held_out(data_root: Path, held_out: list[str], depth_prior: str):
    from ..data.datasets import make_dataset

    return make_dataset("synthetic", data_root, views="two_view", depth_prior=depth_prior, scenes=held_out)


def _score(weights: Path, data_root: Path, held_out: list[str], device: str, depth_prior: str = "default",
           fills: tuple[str, ...] = ()) -> tuple[dict, int, int, dict[str, dict]]:
    """The run's means on the held-out scenes, its Gaussian counts, and the means with each of ``fills`` behind
    its renders (``fill -> means``; the fill rows of pixel-only variants)."""
    from ..evaluation import evaluate, fill_methods, model_method
    from ..evaluation.methods import reconstruct
    from ..metrics import DepthRange
    from ..model import load_model

    # scored with the input depth prior it was trained with (a variant may change data.depth_prior)
    dataset = _held_out(data_root, held_out, depth_prior)
    model = load_model(weights, map_location=device)
    methods = fill_methods(model_method(model, "model", device=device), fills)
    result = evaluate(dataset, methods, depth_range=DepthRange(*STUDY_DEPTH_RANGE), progress=False)
    gaussians = reconstruct(model, dataset[0], device)
    visible = int((gaussians.opacities > 0.005).sum())
    filled = {fill: result.means[m.name] for fill, m in zip(fills, methods[1:])}
    return result.means["model"], len(gaussians), visible, filled


def _score_forward_warp(data_root: Path, held_out: list[str], depth_prior: str, fills: tuple[str, ...]
                        ) -> dict[str | None, dict]:
    """The forward warp of the nearest input on the held-out scenes: ``fill -> means``, ``None`` on black."""
    from ..evaluation import evaluate, fill_methods, forward_warp_method
    from ..metrics import DepthRange

    dataset = _held_out(data_root, held_out, depth_prior)
    methods = fill_methods(forward_warp_method(), fills)
    result = evaluate(dataset, methods, depth_range=DepthRange(*STUDY_DEPTH_RANGE), progress=False)
    return {fill: result.means[m.name] for fill, m in zip((None,) + tuple(fills), methods)}


def run_study(
    data_root: str | Path,
    out_dir: str | Path,
    variants: list[Variant] | None = None,
    seeds: tuple[int, ...] = (0, 1),
    schedule: Schedule = Schedule(),
    held_out: int = 8,
    resolution: tuple[int, int] = (64, 128),
    device: str = "cpu",
    log=None,
    depth_prior: str = "default",
    fills: tuple[str, ...] = ("mean", "inpaint"),
    threads: int | None = STUDY_THREADS,
) -> dict:
    """Train and score every variant x seed; write ``ablation.json`` / ``ablation.md`` to ``out_dir``.
    ``variants``: the default study (:func:`~.variants.default_variants`) when ``None``.
    ``depth_prior`` (a ``data.depth_prior`` spec) is every variant's input prior unless the variant sets its own.
    ``fills``: the fill rows (:mod:`cylindersplat.evaluation.fills`) of every pixel-only variant and of the forward
    warp, which the study scores too (the cheapest alternatives any completion must beat); ``()`` for none.
    ``threads``: torch's intra-op threads during the study (``None``: leave them as they are). The thread count
    sets the order of float sums, so it is part of a run's recipe: with the same count, a rerun on the same
    machine kind is bit-identical; with another, 600 steps drift by about the seed spread."""
    with torch_threads(threads):
        return _run_study(data_root, out_dir, variants, seeds, schedule, held_out, resolution, device, log,
                          depth_prior, fills)


def _fill_row(variant: Variant, fill: str) -> Variant:
    return replace(variant, name=f"{variant.name} + {fill} fill",
                   description=f"{variant.description}, {FILL_DESCRIPTIONS[fill]} behind its renders")


def _forward_warp_row(fill: str | None) -> Variant:
    what = "the nearest input panorama forward-warped with its depth prior (no training)"
    if fill is None:
        return Variant("forward_warp", what, kind="baseline")
    return Variant(f"forward_warp + {fill} fill", f"{what}, {FILL_DESCRIPTIONS[fill]} behind", kind="baseline")


def _run_study(data_root, out_dir, variants, seeds, schedule, held_out, resolution, device, log, depth_prior,
               fills) -> dict:
    import torch

    from ..data import SyntheticDataset
    from .variants import default_variants

    log = log or (lambda text: print(text, flush=True))  # progress lines reach a log file as they happen
    data_root, out_dir = Path(data_root), Path(out_dir)
    variants = variants or default_variants()
    if depth_prior != "default":  # first, so that a variant's own data.depth_prior (a later override) wins
        from ..data.depth_prior import parse_depth_prior

        parse_depth_prior(depth_prior)  # a bad spec fails before any training
        variants = [replace(v, overrides=(f"data.depth_prior={depth_prior}",) + v.overrides) for v in variants]
    scenes = SyntheticDataset(data_root).scenes
    if held_out < 1 or len(scenes) - held_out < 1:
        raise ValueError(f"need at least one training and one held-out scene ({len(scenes)} scenes, "
                         f"held out {held_out})")
    train_ids, test_ids = scenes[:-held_out], scenes[-held_out:]
    check_variants(variants)
    report: dict = {"schedule": asdict(schedule), "seeds": list(seeds), "resolution": list(resolution),
                    "data": str(data_root), "train_scenes": len(train_ids), "held_out_scenes": test_ids,
                    "depth_prior": depth_prior, "threads": torch.get_num_threads(), "variants": {}}
    report["fills"] = list(fills)
    start = time.perf_counter()
    for vi, variant in enumerate(variants):
        runs: list[RunResult] = []
        # a pixel-only model leaves holes: its fill rows (the same weights, a trivial fill behind) beside it
        variant_fills = tuple(fills) if variant.kind == "pixel" else ()
        filled_runs: dict[str, list[RunResult]] = {fill: [] for fill in variant_fills}
        for seed in seeds:
            run_dir = out_dir / "runs" / variant.name / f"seed{seed}"
            run_dir.mkdir(parents=True, exist_ok=True)
            t0 = time.perf_counter()
            weights, train_s, skipped = _train(variant, seed, schedule, data_root, train_ids, run_dir, resolution,
                                               device)
            metrics, count, visible, filled = _score(weights, data_root, test_ids, device, variant.depth_prior,
                                                     variant_fills)
            runs.append(RunResult(metrics, train_s, skipped, count, visible, str(weights)))
            for fill, means in filled.items():
                filled_runs[fill].append(RunResult(means, train_s, skipped, count, visible, str(weights)))
            occluded = _fmt(metrics.get("ws_psnr_occluded"))
            log(f"[{vi + 1}/{len(variants)}] {variant.name} seed {seed}: "
                f"WS-PSNR {metrics.get('ws_psnr', float('nan')):.2f} (occluded {occluded}), trained {train_s:.0f} s, "
                f"skipped {skipped}; {time.perf_counter() - t0:.0f} s, study {time.perf_counter() - start:.0f} s")
        report["variants"][variant.name] = aggregate(variant, runs)
        for fill, fill_runs in filled_runs.items():
            row = _fill_row(variant, fill)
            report["variants"][row.name] = aggregate(row, fill_runs)
    if fills:  # the cheapest alternative of all: no model, the nearest input warped, with and without the fills
        for fill, means in _score_forward_warp(data_root, test_ids, depth_prior, tuple(fills)).items():
            row = _forward_warp_row(fill)
            report["variants"][row.name] = aggregate(row, [RunResult(means, 0.0, 0, 0, 0, "")])
    report["study_s"] = time.perf_counter() - start
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "ablation.json", json_text(report))
    atomic_write_text(out_dir / "ablation.md", study_table(report))
    return report


def _fmt(value) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.2f}"


def check_variants(variants: list[Variant]) -> None:
    """Fail before hours of training if a variant's overrides are not valid configs."""
    from ..training import load_config

    names = [v.name for v in variants]
    if len(set(names)) != len(names):
        raise ValueError(f"variant names must be unique, got {names}")
    for v in variants:
        try:
            load_config("tiny", list(v.overrides)).model.validate()
        except (ValueError, TypeError) as exc:
            raise ValueError(f"ablation variant {v.name!r} is not available: {exc}") from exc
