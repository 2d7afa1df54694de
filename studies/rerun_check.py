"""Is a study run reproducible? Train one ablation variant/seed several times on the same data and compare.

    python studies/rerun_check.py --data outputs/ablation/data --out outputs/rerun --threads 2 2 1 --steps 30 15 15

Each run trains ``--variant`` (default ``full``) with ``--seed`` from scratch into its own folder, with the
given torch intra-op thread count, exactly as ``cylindersplat ablate`` does (same schedule, same held-out
scenes), then scores it. The report (``--json``, default ``studies/results/rerun_check.json``) lists every
run's weights hash and scores and says which runs are bit-identical.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cpu_name() -> str:
    """The CPU's model name (kernels of the math libraries, hence float results, may differ between CPU models)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def one_run(data: str, out: str, variant: str, seed: int, threads: int, steps: tuple[int, int, int]) -> dict:
    """Train and score one run in a fresh process (thread count and RNG state start clean)."""
    code = f"""
import hashlib, json, torch
torch.set_num_threads({threads})
from cylindersplat.study import Schedule, all_variants, run_study
variant = [v for v in all_variants() if v.name == {variant!r}]
report = run_study({data!r}, {out!r}, variant, seeds=({seed},), schedule=Schedule(*{tuple(steps)!r}), fills=(),
                   log=lambda *_: None)
metrics = report["variants"][{variant!r}]["metrics"]
weights = open({out!r} + "/runs/{variant}/seed{seed}/model.safetensors", "rb").read()
print(json.dumps({{"sha256": hashlib.sha256(weights).hexdigest(),
                  **{{k: metrics[k]["seeds"][0]
                     for k in ("ws_psnr", "ssim", "abs_rel", "ws_psnr_occluded", "train_s")}}}}))
"""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    return {"threads": threads, "out": out, "wall_s": time.perf_counter() - start, **result}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", required=True, help="the study's synthetic dataset (cylindersplat ablate's OUT/data)")
    parser.add_argument("--out", type=Path, default=Path("outputs/rerun_check"))
    parser.add_argument("--variant", default="full")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, nargs="+", default=[2, 2, 1], help="torch threads of each run")
    parser.add_argument("--steps", type=int, nargs=3, default=[300, 150, 150], metavar=("S1", "S2", "S3"),
                        help="curriculum steps (default the study's 300 150 150)")
    parser.add_argument("--json", type=Path, default=ROOT / "studies/results/rerun_check.json")
    args = parser.parse_args()
    runs = []
    for i, threads in enumerate(args.threads):
        runs.append(one_run(args.data, str(args.out / f"run{i}"), args.variant, args.seed, threads, tuple(args.steps)))
        print(json.dumps(runs[-1]), flush=True)
    groups: dict[str, list[int]] = {}
    for i, run in enumerate(runs):
        groups.setdefault(run["sha256"], []).append(i)
    report = {"variant": args.variant, "seed": args.seed, "steps": args.steps, "data": args.data, "machine": cpu_name(),
              "date": time.strftime("%Y-%m-%d"), "runs": runs,
              "identical_groups": list(groups.values())}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1) + "\n")
    print(f"bit-identical groups of runs: {list(groups.values())} -> {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
