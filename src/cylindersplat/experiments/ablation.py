"""The ablation study: train model variants with one schedule and several seeds, score them on the
same held-out scenes, and tabulate mean and spread (paper Table "Ablation Study").

A variant is a name, a list of config overrides on the ``tiny`` preset and the curriculum stages it
trains. All variants get the same number of optimizer steps (``Schedule.total``): the full model runs
stages 1-2-3, the pixel-only model spends them all in stage 1, volume-only models run stage 1 (the
pixel branch provides the volume branch's features and depth) then stage 2. Runs are resumable: a
variant/seed whose ``model.safetensors`` exists is scored, not retrained.

Outputs: ``ablation.json`` (per variant: every metric's per-seed values, mean and spread, plus
training time, skipped steps and Gaussian counts) and ``ablation.md`` (a paper-shaped table).
"""

from __future__ import annotations

import contextlib
import json
import math
import statistics
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from ..evaluation.fills import FILL_DESCRIPTIONS
from ..utils.atomic import atomic_write_text
from ..utils.jsonfile import json_text


__all__ = ["EARLIER_TINY", "pinned_to_earlier_tiny", "SURFACE_RECIPE", "PRIOR_ALIGNMENT", "FINE_GRID", "Schedule", "Variant", "default_variants",
           "extra_variants", "all_variants", "VARIANT_NAMES", "run_study", "study_table", "study_sequence_config"]


@dataclass(frozen=True)
class Schedule:
    """Optimizer steps of the full curriculum's stages 1, 2, 3 (other variants get the same total)."""

    stage1: int = 300
    stage2: int = 150
    stage3: int = 150
    lr: float = 2e-3

    @property
    def total(self) -> int:
        return self.stage1 + self.stage2 + self.stage3


@dataclass(frozen=True)
class Variant:
    name: str
    description: str
    overrides: tuple[str, ...] = ()
    kind: str = "full"  # "full" (stages 1-2-3), "pixel" (stage 1 only), "volume" (stages 1-2)

    def stages(self, schedule: Schedule) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """(stages, steps per stage) of this variant under ``schedule``."""
        from ..model.curriculum import KIND_STAGES

        if self.kind not in KIND_STAGES:
            raise ValueError(f"unknown variant kind {self.kind!r}; expected one of {', '.join(KIND_STAGES)}")
        # the same total for every kind: a kind's last stage takes the steps of the stages it skips
        steps = [schedule.stage1, schedule.stage2, schedule.stage3][: len(KIND_STAGES[self.kind])]
        steps[-1] += schedule.total - sum(steps)
        stages = list(zip(KIND_STAGES[self.kind], steps))
        stages = [(s, n) for s, n in stages if n > 0]
        return tuple(s for s, _ in stages), tuple(n for _, n in stages)

    @property
    def depth_prior(self) -> str:
        """The input depth prior the variant trains and is scored with (``data.depth_prior``; the preset's by default)."""
        chosen = [o.split("=", 1)[1] for o in self.overrides if o.startswith("data.depth_prior=")]
        return chosen[-1] if chosen else "default"


# torch intra-op threads of the study's runs (run_study's default): fixed, so that reruns are bit-identical
# whatever OMP_NUM_THREADS the shell has (benchmarks/rerun_check.py)
STUDY_THREADS = 2

# The paper's volume-only rows: the volume branch alone renders every pixel (no fusion, no pruning).
VOLUME_ONLY = ("model.fusion.strategy=concat", "train.stage2_render=volume")
# Issue 23's recipe on top of the tiny preset: nearest-surface colour, the released volume loss, pixel clearing.
SURFACE_RECIPE = ("model.volume.color=surface", "loss.volume_loss=released", "loss.volume_weight=1",
                  "model.fusion.pixel_clearing=seen_through")
# Session 12's additions to it: depth priors rescaled to the poses' scale, and a triplane fine enough for hidden strips.
PRIOR_ALIGNMENT = ("model.prior_alignment=photometric",)
FINE_GRID = ("model.volume.grid=[8,32,16]", "model.volume.image_grid=[4,16,8]")
# The tiny preset before the recipe above (all of it) became its default (2026-11-26): Eq. 6 colour, no volume loss,
# no clearing, the priors as given, 4x16x8 cells. The studies run before then pin it, so that they keep their meaning.
EARLIER_TINY = ("model.volume.color=retrieval", "loss.volume_loss=scaled", "loss.volume_weight=0",
                "model.fusion.pixel_clearing=none", "model.prior_alignment=none",
                "model.volume.grid=[4,16,8]", "model.volume.image_grid=[2,8,4]")


def pinned_to_earlier_tiny(variants: list[Variant]) -> list[Variant]:
    """``variants`` with :data:`EARLIER_TINY` before their own switches (theirs win)."""
    return [replace(v, overrides=EARLIER_TINY + v.overrides) for v in variants]


def default_variants() -> list[Variant]:
    """The paper's ablation rows (and the switches issue 11 asks for), in table order."""
    return [
        Variant("full", "pixel + cylindrical volume branch, curriculum 1-2-3 (the tiny preset's recipe: stage 2 "
                "beside the frozen pixel branch, volume Gaussians only where no input view saw empty space, issue "
                "23's nearest-surface colour, volume loss, pixel clearing, rescaled priors and 8x32x16 cells)"),
        Variant("full_paper_recipe", "full, the paper's recipe: volume-only stage 2, concatenated Gaussians",
                ("model.fusion.strategy=concat", "train.stage2_render=volume")),
        Variant("pixel_only", "pixel branch only", kind="pixel"),
        # Edge fading leaves holes a pixel-only model cannot fill; without it the pixel branch is the stronger
        # baseline on occluded pixels, so the study scores both.
        Variant("pixel_only_no_edge_fading", "pixel branch only, without edge-aware opacity",
                ("model.pixel.edge_sigma=0",), kind="pixel"),
        Variant("volume_only_cylindrical", "volume branch only, cylindrical triplanes", VOLUME_ONLY, kind="volume"),
        Variant("volume_only_spherical", "volume branch only, spherical triplanes",
                VOLUME_ONLY + ("model.volume.coordinates=spherical",), kind="volume"),
        Variant("volume_only_cartesian", "volume branch only, Cartesian triplanes",
                VOLUME_ONLY + ("model.volume.coordinates=cartesian",), kind="volume"),
        Variant("wo_rgb_retrieval", "full, colour decoded from triplane features (no RGB retrieval)",
                ("model.volume.color=decoded",)),
        Variant("central_triplane", "full, one triplane at the centre of all views (not per camera)",
                ("model.volume.placement=central",)),
        Variant("cartesian_scale", "full, Cartesian scales instead of the Jacobian transform",
                ("model.volume.scale_transform=cartesian",)),
        Variant("full_res_query", "full, Eq. 2 with full-resolution queries",
                ("model.volume.image_query=full",)),
        Variant("isolated_init", "full, isolated triplane init (own view's points only)",
                ("model.volume.init=isolated",)),
        Variant("no_edge_fading", "full, without edge-aware pixel opacity (model.pixel.edge_sigma=0)",
                ("model.pixel.edge_sigma=0",)),
    ]


def extra_variants() -> list[Variant]:
    """Named variants outside the default study (it must fit 75 minutes on a 2-core CPU); run them with
    ``cylindersplat ablate --variants NAME ...``."""
    return [
        Variant("full_earlier_recipe", "full, the tiny preset before issue 23's recipe (Eq. 6 colour, no volume loss, "
                "no clearing, priors as given, 4x16x8 cells)", EARLIER_TINY),
        Variant("full_priors_as_given_coarse_grid", "full, issue 23's recipe without its session-12 parts (priors as "
                "given, 4x16x8 cells)", ("model.prior_alignment=none", "model.volume.grid=[4,16,8]",
                                         "model.volume.image_grid=[2,8,4]")),
        Variant("depth_fusion_own_view", "full, depth-guided fusion against each Gaussian's own view only",
                ("model.fusion.strategy=depth_prune", "model.fusion.side=front")),
        # two switches measured against the earlier preset (benchmarks/NOTEBOOK.md), pinned to it
        Variant("retrieval_window_2", "the earlier preset, volume colours from the nearest observed surface points "
                "in 5x5 pixels", EARLIER_TINY + ("model.volume.color=surface", "model.volume.surface_window=2",
                                                 "model.volume.surface_temperature=1")),
        Variant("volume_weight_1", "the earlier preset, the volume branch's own render in the loss "
                "(loss.volume_weight=1)", EARLIER_TINY + ("loss.volume_weight=1",)),
        Variant("pixel_stage_leaves_hidden", "full, stage 1 leaves pixels no input view sees out of the loss",
                ("loss.pixel_stage_hidden=leave",)),
    ]


def all_variants() -> list[Variant]:
    return default_variants() + extra_variants()


VARIANT_NAMES = tuple(v.name for v in all_variants())


def study_sequence_config():
    """Procedural sequences the study trains and scores on: the ``occlusion`` profile (targets off the
    contexts' line, occluders, doorways), so that a real share of every target is hidden from both inputs."""
    from ..data.synth import profile_config

    return profile_config("occlusion")

# metric key -> (table header, higher is better, format); occluded-pixel metrics appear when eval reports them
TABLE_METRICS = [
    ("ws_psnr", "WS-PSNR ↑", True, "{:.2f}"),
    ("ssim", "SSIM ↑", True, "{:.3f}"),
    ("pcc", "PCC ↑", True, "{:.3f}"),
    ("abs_rel", "AbsRel ↓", False, "{:.3f}"),
    ("ws_psnr_occluded", "WS-PSNR occ. ↑", True, "{:.2f}"),
    ("abs_rel_occluded", "AbsRel occ. ↓", False, "{:.3f}"),
    ("occluded_share", "occ. share", None, "{:.3f}"),
    ("gaussians", "Gaussians", None, "{:,.0f}"),
    ("train_s", "Train (s)", None, "{:.0f}"),
    ("time_s", "Time / scene (s)", None, "{:.2f}"),
]


@dataclass
class RunResult:
    metrics: dict[str, float | None]
    train_s: float
    skipped_steps: int
    gaussians: int
    visible_gaussians: int
    weights: str


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
                                "stages": stages, "steps": steps, "seed": seed, "overrides": list(variant.overrides),
                                "threads": torch.get_num_threads()}))
    return Path(summary["weights"]), train_s, int(summary.get("skipped_steps", 0))


def _score(weights: Path, data_root: Path, held_out: list[str], device: str, depth_prior: str = "default",
           fills: tuple[str, ...] = ()) -> tuple[dict, int, int, dict[str, dict]]:
    """The run's means on the held-out scenes, its Gaussian counts, and the means with each of ``fills`` behind
    its renders (``fill -> means``; the fill rows of pixel-only variants)."""
    from ..data.datasets import make_dataset
    from ..evaluation import evaluate, fill_methods, model_method
    from ..evaluation.methods import reconstruct
    from ..metrics import DepthRange
    from ..model import load_model

    # scored with the input depth prior it was trained with (a variant may change data.depth_prior)
    dataset = make_dataset("synthetic", data_root, views="two_view", depth_prior=depth_prior, scenes=held_out)
    model = load_model(weights, map_location=device)
    methods = fill_methods(model_method(model, "model", device=device), fills)
    result = evaluate(dataset, methods, depth_range=DepthRange(0.05, 1000.0), progress=False)
    gaussians = reconstruct(model, dataset[0], device)
    visible = int((gaussians.opacities > 0.005).sum())
    filled = {fill: result.means[m.name] for fill, m in zip(fills, methods[1:])}
    return result.means["model"], len(gaussians), visible, filled


def _score_forward_warp(data_root: Path, held_out: list[str], depth_prior: str, fills: tuple[str, ...]
                        ) -> dict[str | None, dict]:
    """The forward warp of the nearest input on the held-out scenes: ``fill -> means``, ``None`` on black."""
    from ..data.datasets import make_dataset
    from ..evaluation import evaluate, fill_methods, forward_warp_method
    from ..metrics import DepthRange

    dataset = make_dataset("synthetic", data_root, views="two_view", depth_prior=depth_prior, scenes=held_out)
    methods = fill_methods(forward_warp_method(), fills)
    result = evaluate(dataset, methods, depth_range=DepthRange(0.05, 1000.0), progress=False)
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
    ``depth_prior`` (a ``data.depth_prior`` spec) is every variant's input prior unless the variant sets its own.
    ``fills``: the fill rows (:mod:`cylindersplat.evaluation.fills`) of every pixel-only variant and of the forward
    warp, which the study scores too (the cheapest alternatives any completion must beat); ``()`` for none.
    ``threads``: torch's intra-op threads during the study (``None``: leave them as they are). The thread count
    sets the order of float sums, so it is part of a run's recipe: with the same count, a rerun on the same
    machine kind is bit-identical; with another, 600 steps drift by about the seed spread."""
    with torch_threads(threads):
        return _run_study(data_root, out_dir, variants, seeds, schedule, held_out, resolution, device, log,
                          depth_prior, fills)


@contextlib.contextmanager
def torch_threads(threads: int | None):
    """Within the block torch uses ``threads`` intra-op threads (``None``: unchanged)."""
    import torch

    if threads is None:
        yield
        return
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be an integer >= 1 (torch intra-op threads), got {threads!r}")
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _run_study(data_root, out_dir, variants, seeds, schedule, held_out, resolution, device, log, depth_prior,
               fills) -> dict:
    import torch

    from ..data import SyntheticDataset

    log = log or (lambda text: print(text, flush=True))  # progress lines reach a log file as they happen
    data_root, out_dir = Path(data_root), Path(out_dir)
    variants = variants or default_variants()
    if depth_prior != "default":  # first, so that a variant's own data.depth_prior (a later override) wins
        from ..data.depth_prior import parse_depth_prior

        parse_depth_prior(depth_prior)  # a bad spec fails before any training
        variants = [replace(v, overrides=(f"data.depth_prior={depth_prior}",) + v.overrides) for v in variants]
    scenes = SyntheticDataset(data_root).scenes
    if held_out < 1 or len(scenes) - held_out < 1:
        raise ValueError(f"need at least one training and one held-out scene ({len(scenes)} scenes, held out {held_out})")
    train_ids, test_ids = scenes[:-held_out], scenes[-held_out:]
    _check_variants(variants)
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
            weights, train_s, skipped = _train(variant, seed, schedule, data_root, train_ids, run_dir, resolution, device)
            metrics, count, visible, filled = _score(weights, data_root, test_ids, device, variant.depth_prior,
                                                     variant_fills)
            runs.append(RunResult(metrics, train_s, skipped, count, visible, str(weights)))
            for fill, means in filled.items():
                filled_runs[fill].append(RunResult(means, train_s, skipped, count, visible, str(weights)))
            log(f"[{vi + 1}/{len(variants)}] {variant.name} seed {seed}: WS-PSNR {metrics.get('ws_psnr', float('nan')):.2f}"
                f" (occluded {_fmt(metrics.get('ws_psnr_occluded'))}), trained {train_s:.0f} s, skipped {skipped}; "
                f"{time.perf_counter() - t0:.0f} s, study {time.perf_counter() - start:.0f} s")
        report["variants"][variant.name] = _aggregate(variant, runs)
        for fill, fill_runs in filled_runs.items():
            row = replace(variant, name=f"{variant.name} + {fill} fill",
                          description=f"{variant.description}, {FILL_DESCRIPTIONS[fill]} behind its renders")
            report["variants"][row.name] = _aggregate(row, fill_runs)
    if fills:  # the cheapest alternative of all: no model, the nearest input warped, with and without the fills
        for fill, means in _score_forward_warp(data_root, test_ids, depth_prior, tuple(fills)).items():
            what = "the nearest input panorama forward-warped with its depth prior (no training)"
            row = (Variant("forward_warp", what, kind="baseline") if fill is None else
                   Variant(f"forward_warp + {fill} fill", f"{what}, {FILL_DESCRIPTIONS[fill]} behind", kind="baseline"))
            report["variants"][row.name] = _aggregate(row, [RunResult(means, 0.0, 0, 0, 0, "")])
    report["study_s"] = time.perf_counter() - start
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "ablation.json", json_text(report))
    atomic_write_text(out_dir / "ablation.md", study_table(report))
    return report


def _fmt(value) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.2f}"


def _check_variants(variants: list[Variant]) -> None:
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


def _aggregate(variant: Variant, runs: list[RunResult]) -> dict:
    keys = list(dict.fromkeys(k for r in runs for k in r.metrics))
    per_metric = {k: [r.metrics.get(k) for r in runs] for k in keys}
    per_metric["gaussians"] = [r.visible_gaussians for r in runs]
    per_metric["gaussians_total"] = [r.gaussians for r in runs]
    per_metric["train_s"] = [r.train_s for r in runs]
    per_metric["skipped_steps"] = [r.skipped_steps for r in runs]
    metrics = {}
    for key, values in per_metric.items():
        finite = [float(x) for x in values if x is not None and math.isfinite(float(x))]
        metrics[key] = {
            "seeds": [None if x is None else float(x) for x in values],
            "mean": statistics.fmean(finite) if finite else None,
            "spread": (max(finite) - min(finite)) / 2 if len(finite) > 1 else 0.0 if finite else None,
        }
    return {"description": variant.description, "overrides": list(variant.overrides), "kind": variant.kind,
            "metrics": metrics}


def study_table(report: dict) -> str:
    """Markdown: one row per variant, ``mean ± half the seed range`` per metric; best mean in bold."""
    variants = report["variants"]
    present = [m for m in TABLE_METRICS if any(v["metrics"].get(m[0], {}).get("mean") is not None for v in variants.values())]
    best = {}
    for key, _, higher, _ in present:
        if higher is None:
            continue
        means = [v["metrics"][key]["mean"] for v in variants.values() if v["metrics"].get(key, {}).get("mean") is not None]
        best[key] = (max if higher else min)(means) if means else None
    sched = report["schedule"]
    chosen = report.get("depth_prior", "default")
    prior = "" if chosen == "default" else f"; input depth prior {chosen}"
    lines = [
        f"Ablation study: {report['train_scenes']} training / {len(report['held_out_scenes'])} held-out procedural scenes, "
        f"{report['resolution'][0]}x{report['resolution'][1]}, two_view; seeds {report['seeds']}; "
        f"{sched['stage1'] + sched['stage2'] + sched['stage3']} steps per variant (full: {sched['stage1']}/{sched['stage2']}/"
        f"{sched['stage3']}), lr {sched['lr']}{prior}. Cells: mean ± half the range over seeds. \"occ.\": pixels no input view sees.",
        "",
        "Background where a render covers no pixel: black" + (", except the fill rows (" + "; ".join(
            f"+ {fill} fill: {FILL_DESCRIPTIONS[fill]}" for fill in report["fills"]) + "; forward_warp rows: no training, "
            "one value)" if report.get("fills") else "") + ".",
        "",
        "| Variant | " + " | ".join(h for _, h, _, _ in present) + " |",
        "|---|" + "---|" * len(present),
    ]
    for name, v in variants.items():
        cells = []
        for key, _, higher, fmt in present:
            stat = v["metrics"].get(key, {})
            mean, spread = stat.get("mean"), stat.get("spread")
            if mean is None:
                cells.append("n/a")
                continue
            text = fmt.format(mean) + (f" ± {fmt.format(spread)}" if spread and higher is not None else "")
            cells.append(f"**{text}**" if higher is not None and mean == best.get(key) else text)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", f"Study time: {report.get('study_s', float('nan')) / 60:.1f} min."]
    return "\n".join(lines) + "\n"
