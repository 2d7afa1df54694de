"""Throughput of the procedural panorama generator (render + PNG writing), CPU.

    cylindersplat bench synth --scenes 12 --resolution 256x512 --threads 1 2

Reports panoramas per second end to end (scene generation, ray casting, shading, writing
rgb.png + 16-bit depth.png + JSON), as ``cylindersplat data synth`` does it.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time

import torch

from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset
from cylindersplat.utils.arguments import OneLineErrorParser, equirect_resolution, positive_int


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(prog="cylindersplat bench synth", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=positive_int, default=12)
    parser.add_argument("--frames", type=positive_int, default=3)
    parser.add_argument("--resolution", type=equirect_resolution, default=(256, 512), help="HxW (default 256x512)")
    parser.add_argument("--threads", type=positive_int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=positive_int, default=2, help="best of N runs (the machine is shared)")
    args = parser.parse_args(argv)
    h, w = args.resolution
    print(f"{platform.processor() or platform.machine()}, torch {torch.__version__}, {args.scenes} scenes x "
          f"{args.frames} frames at {h}x{w}")
    previous_threads = torch.get_num_threads()
    try:
        _run(args, h, w)
    finally:
        torch.set_num_threads(previous_threads)  # callers (the CLI, tests) keep their thread count


def _run(args, h: int, w: int) -> None:
    for threads in args.threads:
        torch.set_num_threads(threads)
        best = float("inf")
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                start = time.perf_counter()
                write_synthetic_dataset(tmp, args.scenes, (h, w),
                                        SequenceConfig(frames=args.frames, spacing=(0.25, 1.0)),
                                        seed=0, progress=False)
                best = min(best, time.perf_counter() - start)
        n = args.scenes * args.frames
        print(f"threads={threads}: {n} panoramas in {best:.2f} s -> {n / best:.2f} panoramas/s ({1000 * best / n:.0f} "
              "ms each)")


if __name__ == "__main__":
    main()
