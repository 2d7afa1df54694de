"""Time and peak memory of one training step of each curriculum stage.

    cylindersplat bench train --config paper --height 512          # the paper's setting (GPU)
    cylindersplat bench train --config tiny_paper --height 64 --steps 3  # CPU smoke numbers

A step is what :meth:`cylindersplat.training.Trainer.train_step` does: network forward (bf16
autocast on CUDA), fp32 render of every target view, L1 + LPIPS + depth-L1 loss, backward, gradient
clipping, AdamW. The data are procedural scenes generated into a temporary folder at the requested
size (two context views, one target, batch 1). Without local LPIPS weights the LPIPS term runs on
an untrained network of the same architecture (``--lpips random``; same cost, meaningless value),
so the timing includes it as the paper's recipe does; ``--lpips off`` drops it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import warnings

import torch

from cylindersplat.model.config import PRESETS, RENAMED_PRESETS
from cylindersplat.utils.arguments import OneLineErrorParser, nonnegative_int, positive_int
from cylindersplat.utils.arguments import device as device_name

from .render import _peak_mb


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def bench_stages(args) -> list[dict]:
    from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset
    from cylindersplat.metrics.lpips import LPIPS
    from cylindersplat.training import Trainer, load_config
    from cylindersplat.training.data import build_dataset

    device = torch.device(args.device)
    height = args.height
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        write_synthetic_dataset(tmp, 2, (height, 2 * height), SequenceConfig(), seed=0, progress=False)
        preset = RENAMED_PRESETS.get(args.config, args.config)  # (tiny: tiny_paper, without the rename's warning)
        overrides = [f"model.preset={preset}", "data.format=synthetic", f"data.root={tmp}",
                     f"data.resolution=[{height},{2 * height}]", f"train.device={args.device}",
                     f"train.steps_per_stage=[{args.steps + args.warmup}]", "train.progress=false",
                     "model.fusion.strategy=concat", "train.stage2_render=volume",  # the paper's recipe
                     "train.tensorboard=false", f"output_dir={tmp}/run", "loss.use_lpips=off"]
        cfg = load_config("tiny", overrides)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            trainer = Trainer(cfg, dataset=build_dataset(cfg.data))
        if args.lpips == "random":
            trainer.loss_fn.lpips_net = LPIPS().to(device).requires_grad_(False).eval()
        batch = next(iter(torch.utils.data.DataLoader(trainer.dataset, batch_size=1, collate_fn=_collate)))
        for index, stage in enumerate(cfg.train.stages):
            trainer.stage_index = index
            trainer._begin_stage()
            for _ in range(args.warmup):
                trainer.train_step(batch)
            if device.type == "cuda":
                _sync(device)
                torch.cuda.reset_peak_memory_stats()
            times, losses = [], []
            for _ in range(args.steps):
                _sync(device)
                t0 = time.perf_counter()
                parts = trainer.train_step(batch)
                _sync(device)
                times.append(time.perf_counter() - t0)
                losses.append(parts["total"])
            row = {"stage": stage, "median_s": statistics.median(times), "min_s": min(times),
                   "peak_mb": _peak_mb(device),
                   "gaussians": _num_gaussians(trainer, batch),
                   "loss_first": losses[0], "loss_last": losses[-1]}
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def _collate(samples):
    from cylindersplat.data import collate_samples

    return collate_samples(samples)


def _num_gaussians(trainer, batch) -> int:
    from cylindersplat.training.trainer import batch_to_device

    b = batch_to_device(batch, trainer.device)
    with torch.no_grad(), torch.autocast(trainer.device.type, dtype=torch.bfloat16, enabled=trainer.use_bf16):
        out = trainer.model(b.context_images, b.context_priors, b.context_poses)
    return int(out.gaussians.means.shape[-2])


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(prog="cylindersplat bench train", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="paper", choices=sorted(PRESETS) + sorted(RENAMED_PRESETS),
                        metavar="PRESET", help="model preset: %(choices)s (default %(default)s)")
    parser.add_argument("--height", type=positive_int, default=512, help="panorama height (width = 2 x height)")
    parser.add_argument("--device", type=device_name, default="auto", help="auto (CUDA when present), cpu, cuda[:N]")
    parser.add_argument("--steps", type=positive_int, default=5, help="timed steps per stage")
    parser.add_argument("--warmup", type=nonnegative_int, default=2)
    parser.add_argument("--lpips", choices=["random", "off"], default="random")
    parser.add_argument("--compile", action="store_true", help="projection through torch.compile "
                                                               "(render.projection.compile_projection)")
    args = parser.parse_args(argv)
    if args.compile:
        from cylindersplat.render.projection import compile_projection

        compile_projection(True)
    name = torch.cuda.get_device_name() if args.device.startswith("cuda") else "CPU"
    print(f"# training step per curriculum stage: config={args.config} {args.height}x{2 * args.height}, batch 1, "
          f"2 context + 1 target, LPIPS {args.lpips}; {name}, torch {torch.__version__}", flush=True)
    rows = bench_stages(args)
    print("| stage | median step (s) | min (s) | peak memory (MiB) | Gaussians |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['stage']} | {r['median_s']:.3f} | {r['min_s']:.3f} | {r['peak_mb']:.0f} | {r['gaussians']:,} |")
    if not args.device.startswith("cuda"):
        print("(CPU memory: the process's peak resident memory up to that stage, model and data included; on CUDA, "
              "torch.cuda.max_memory_allocated of the stage's steps)")


if __name__ == "__main__":
    main()
