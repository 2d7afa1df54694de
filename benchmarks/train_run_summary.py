"""Print, per curriculum stage, how a run's training loss moved: first -> last logged value.

    python benchmarks/train_run_summary.py outputs/train/run/metrics.jsonl
"""

import json
import statistics
import sys


def main(path: str) -> None:
    rows = [json.loads(line) for line in open(path)]
    rows = [r for r in rows if "train/total" in r]
    if not rows:
        sys.exit(f"{path}: no training losses logged")
    for stage in sorted({r["stage"] for r in rows}):
        s = [r for r in rows if r["stage"] == stage]
        first, last = s[0]["train/total"], s[-1]["train/total"]
        head = statistics.mean(r["train/total"] for r in s[:3])
        tail = statistics.mean(r["train/total"] for r in s[-3:])
        step = statistics.median(r["train/step_time"] for r in s)
        print(f"training run: stage {stage}, steps {s[0]['step']}-{s[-1]['step']} ({len(s)} logged), loss {first:.4f} -> "
              f"{last:.4f} (mean of first/last 3 logs {head:.4f} -> {tail:.4f}), median step {step:.3f} s")


if __name__ == "__main__":
    main(sys.argv[1])
