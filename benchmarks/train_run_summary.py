"""Print, per curriculum stage, how a run's training loss moved, and a verdict.

    python benchmarks/train_run_summary.py outputs/train/run/metrics.jsonl [--require-fall]

Each logged loss is one batch of one random scene, and scenes differ far more than steps do (on procedural
rooms the depth term of a single batch jumps from 0.05 to 0.9 with the scene drawn). So a stage is judged on
its photometric term (``train/rgb_l1``, the total where that is not logged) by the **median of the first
quarter of its logs against the median of its last quarter**; it "falls" when the second is lower. A stage
with fewer than 8 logs is too short to tell (log more often: ``train.log_every``). ``--require-fall`` exits
with status 1 unless every stage that can tell fell (benchmarks/gpu_check.sh: "a training run that
converges").
"""

import json
import statistics
import sys

MIN_LOGS = 8  # two quarters of at least two batches each


def _term(row: dict) -> float:
    return row.get("train/rgb_l1", row["train/total"])


def stage_verdict(rows: list[dict]) -> tuple[float, float, bool | None]:
    """Median photometric loss of the first and last quarter of a stage's logs, and whether it fell."""
    quarter = max(len(rows) // 4, 1)
    head = statistics.median(_term(r) for r in rows[:quarter])
    tail = statistics.median(_term(r) for r in rows[-quarter:])
    return head, tail, (None if len(rows) < MIN_LOGS else tail < head)


def main(path: str, require_fall: bool = False) -> int:
    rows = [json.loads(line) for line in open(path)]
    rows = [r for r in rows if "train/total" in r]
    if not rows:
        sys.exit(f"{path}: no training losses logged")
    verdicts = []
    for stage in sorted({r["stage"] for r in rows}):
        s = [r for r in rows if r["stage"] == stage]
        head, tail, fell = stage_verdict(s)
        term = "rgb L1" if "train/rgb_l1" in s[0] else "total loss"
        step = statistics.median(r["train/step_time"] for r in s)
        skipped = sum(r.get("train/skipped", 0) for r in s)
        print(f"training run: stage {stage}, steps {s[0]['step']}-{s[-1]['step']} ({len(s)} logged), {term} median of "
              f"first/last quarter {head:.4f} -> {tail:.4f} ({100 * (tail / head - 1):+.0f} %), "
              f"median step {step:.3f} s, {skipped:g} skipped")
        verdicts.append((stage, fell))
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
