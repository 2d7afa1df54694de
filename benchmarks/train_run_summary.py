"""Print, per curriculum stage, how a run's training loss moved: first -> last logged value, and a verdict.

    python benchmarks/train_run_summary.py outputs/train/run/metrics.jsonl [--require-fall]

A stage "falls" when the mean of its last three logged losses is below the mean of its first three
(stages with fewer than six logs are too short to tell). ``--require-fall`` exits with status 1 unless
every stage that can tell fell (benchmarks/gpu_check.sh: "a training run that converges").
"""

import json
import statistics
import sys


def main(path: str, require_fall: bool = False) -> int:
    rows = [json.loads(line) for line in open(path)]
    rows = [r for r in rows if "train/total" in r]
    if not rows:
        sys.exit(f"{path}: no training losses logged")
    verdicts = []
    for stage in sorted({r["stage"] for r in rows}):
        s = [r for r in rows if r["stage"] == stage]
        first, last = s[0]["train/total"], s[-1]["train/total"]
        head = statistics.mean(r["train/total"] for r in s[:3])
        tail = statistics.mean(r["train/total"] for r in s[-3:])
        step = statistics.median(r["train/step_time"] for r in s)
        print(f"training run: stage {stage}, steps {s[0]['step']}-{s[-1]['step']} ({len(s)} logged), loss {first:.4f} "
              f"-> {last:.4f} (mean of first/last 3 logs {head:.4f} -> {tail:.4f}), median step {step:.3f} s")
        verdicts.append((stage, None if len(s) < 6 else tail < head))
    fell = [f"stage {st}: " + ("too short to tell" if v is None else "fell" if v else "did NOT fall")
            for st, v in verdicts]
    if all(v is None for _, v in verdicts):
        verdict, ok = "too short to tell", False
    else:
        ok = all(v is not False for _, v in verdicts)
        verdict = "loss falls" if ok else "NOT converging"
    print(f"training run verdict: {verdict} ({'; '.join(fell)})")
    return 0 if ok or not require_fall else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], "--require-fall" in sys.argv[2:]))
