"""Forward latency and peak memory of the CylinderSplat model for 1-4 input views.

Examples::

    cylindersplat bench model --config tiny_paper                 # CPU smoke numbers
    cylindersplat bench model --config recipes/tiny_sharp --height 256 --views 2   # the shipped model and drawing
    cylindersplat bench model --config paper --height 128          # paper widths/grids, small input
    cylindersplat bench model --config paper --height 512 --render # GPU: the paper's setting

Every view count runs in a fresh subprocess so that the CPU peak (max RSS of the process) is
per-configuration; on CUDA the peak is ``torch.cuda.max_memory_allocated``. With ``--render``
the timing includes one ``render_equirect`` of the fused Gaussians at the input resolution
(the paper's "0.29 s" is forward + one 512x1024 render, 2 views, RTX 4090).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

import torch

from cylindersplat.utils.arguments import OneLineErrorParser, nonnegative_int, positive_int
from cylindersplat.utils.arguments import device as device_name


def synthetic_inputs(views: int, height: int, device: torch.device, seed: int = 0):
    from cylindersplat.geometry import make_c2w

    g = torch.Generator().manual_seed(seed)
    images = torch.rand(1, views, 3, height, 2 * height, generator=g)
    depth = 1.0 + 4.0 * torch.rand(1, views, height, 2 * height, generator=g)
    c2w = torch.stack([make_c2w(translation=torch.tensor([0.75 * v, 0.0, 0.0])) for v in range(views)])[None]
    return images.to(device), depth.to(device), c2w.to(device)


def model_config(name: str):
    """The model config ``--config`` names: a model preset (``tiny_paper``, ``paper``, ...) or the model of a training
    preset, recipe or YAML file (``tiny``, ``recipes/tiny_sharp``: the shipped weights' model and drawing). A name that
    is neither raises a ``ValueError`` listing both kinds."""
    from cylindersplat.model.config import PRESETS, RENAMED_PRESETS, get_config
    from cylindersplat.training import load_config

    if name in PRESETS or name in RENAMED_PRESETS:
        return get_config(name)
    try:
        return load_config(name).model
    except FileNotFoundError:
        raise ValueError(f"--config {name!r} is neither a model preset ({', '.join(sorted(PRESETS))}) nor a training "
                         "preset, recipe (recipes/NAME) or YAML file") from None


def run_single(args) -> dict:
    from cylindersplat.model import from_config

    device = torch.device(args.device)
    torch.manual_seed(0)
    model = from_config(model_config(args.config), mode=args.mode).to(device).eval()
    images, depth, c2w = synthetic_inputs(args.views, args.height, device)
    render = None
    if args.render:
        from cylindersplat.render import render_equirect

        render = render_equirect

    use_bf16 = args.amp == "bf16" and device.type == "cuda"

    def step():
        with torch.no_grad():
            with torch.autocast("cuda", dtype=torch.bfloat16, enabled=use_bf16):
                out = model(images, depth, c2w)
            if render is not None:
                render(out.gaussians.to(torch.float32), c2w[:, :1], args.height, 2 * args.height)
        return out

    for _ in range(args.warmup):
        out = step()
    if device.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        out = step()
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    if device.type == "cuda":
        peak_mb = torch.cuda.max_memory_allocated() / 2**20
        memory_kind = "cuda max_memory_allocated"
    else:
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
        memory_kind = "process max RSS"
    return {
        "views": args.views,
        "height": args.height,
        "gaussians": out.gaussians.num_gaussians,
        "median_s": sorted(times)[len(times) // 2],
        "min_s": min(times),
        "peak_mb": peak_mb,
        "memory_kind": memory_kind,
        "parameters": sum(p.numel() for p in model.parameters()),
    }


def describe_device(device: str) -> str:
    if device.startswith("cuda"):
        return torch.cuda.get_device_name(0)
    return (f"CPU {platform.processor() or platform.machine()}, {os.cpu_count()} logical cores, "
            f"torch threads {torch.get_num_threads()}")


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(prog="cylindersplat bench model", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="tiny_paper",
                        help="model preset (tiny_paper, paper, ...), or a training preset or recipe whose model to "
                             "time (tiny, recipes/tiny_sharp: the shipped weights' model and drawing)")
    parser.add_argument("--height", type=positive_int, default=None, help="input panorama height (width = 2 x height)")
    parser.add_argument("--views", type=positive_int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--mode", default="both", choices=["pixel", "volume", "both"])
    parser.add_argument("--device", type=device_name, default="auto", help="auto (CUDA when present), cpu, cuda[:N]")
    parser.add_argument("--render", action="store_true", help="include one render_equirect per forward")
    parser.add_argument("--amp", choices=["bf16", "off"], default="bf16",
                        help="network forward under bf16 autocast on CUDA (as inference and training do)")
    parser.add_argument("--warmup", type=nonnegative_int, default=1)
    parser.add_argument("--compile", action="store_true", help="projection through torch.compile "
                                                               "(render.projection.compile_projection)")
    parser.add_argument("--repeats", type=positive_int, default=3)
    parser.add_argument("--single", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.compile:
        from cylindersplat.render.projection import compile_projection

        compile_projection(True)
    try:
        config = model_config(args.config)
    except ValueError as error:
        parser.error(str(error))
    if args.height is None:
        args.height = config.image_height

    if args.single:
        args.views = args.views[0]
        print(json.dumps(run_single(args)))
        return

    print(f"# CylinderSplat forward benchmark: config={args.config} mode={args.mode} input "
          f"{args.height}x{2 * args.height}{' + 1 render' if args.render else ''}, amp "
          f"{args.amp if args.device.startswith('cuda') else 'off'}; {describe_device(args.device)}")
    print("| views | Gaussians | median latency (s) | min (s) | peak memory (MiB) |")
    print("|---|---|---|---|---|")
    for views in args.views:
        cmd = [sys.executable, __file__, "--single", "--config", args.config, "--height", str(args.height),
               "--views", str(views), "--mode", args.mode, "--device", args.device,
               "--warmup", str(args.warmup), "--repeats", str(args.repeats), "--amp", args.amp]
        cmd += (["--compile"] if args.compile else []) + (["--render"] if args.render else [])
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"benchmark with {views} views failed:\n{proc.stderr}")
        result = json.loads(proc.stdout.strip().splitlines()[-1])
        print(f"| {views} | {result['gaussians']:,} | {result['median_s']:.3f} | {result['min_s']:.3f} | "
              f"{result['peak_mb']:.0f} |", flush=True)
    print(f"(memory: {result['memory_kind']}; parameters: {result['parameters']:,})")


if __name__ == "__main__":
    main()
