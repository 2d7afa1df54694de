"""``cylindersplat bench {render,model,synth} [options]``: run a benchmark (options: ``... --help``)."""

from __future__ import annotations

import argparse
import importlib


def run(args: argparse.Namespace) -> int:
    module = importlib.import_module(f"cylindersplat.benchmarks.{args.benchmark}")
    module.main(args.options)
    return 0


def register(subparsers) -> None:
    from ..benchmarks import BENCHMARKS

    parser = subparsers.add_parser(
        "bench", help="benchmarks: renderer speed/memory, model forward, data generation",
        description="Run a benchmark and print its figures (with the machine that produced them). render: the "
        "equirect rasterizer, forward and forward+backward (median ms, peak MB), --cubemap compares with the "
        "6-face route, --stages splits the time; model: forward/backward per preset and view count; synth: "
        "procedural panoramas per second. Options after the name go to the benchmark: "
        "`cylindersplat bench render --help`. Results: benchmarks/RESULTS.md.",
    )
    parser.add_argument("benchmark", choices=BENCHMARKS, help="which benchmark")
    parser.add_argument("options", nargs=argparse.REMAINDER, help="options of that benchmark (see its --help)")
    parser.set_defaults(func=run)
