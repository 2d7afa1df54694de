"""Issue 34: the spread between trainings of the shipped recipe with different seeds, per drawing and setting.

    python studies/seed_spread.py studies/results/sharp_fixture.json studies/results/seed1_fixture.json \\
        studies/results/seed2_fixture.json --rows "tiny_sharp,tiny_sharp + over,tiny (the paper's drawing)"

Each cell: WS-PSNR on all pixels (``--metric``) of each run in the order given, then their range; the last column the
largest range of the row. Every file comes from ``studies/sharp_variants.py`` (the first with the shipped weights,
the others with ``--checkpoint`` of another seed's run: ``TRAIN_SEED=N bash scripts/train_pretrained.sh OUT``).
"""

from __future__ import annotations

import argparse
import json


def spread_table(runs: list[dict], rows: list[str], metric: str = "ws_psnr") -> str:
    keys = [key for key in runs[0] if all(key in run for run in runs[1:])]
    lines = ["| drawing | " + " | ".join(keys) + " | largest range |", "|---|" + "---|" * (len(keys) + 1)]
    for row in rows:
        cells, largest = [], 0.0
        for key in keys:
            values = [run[key].get(row, {}).get(metric) for run in runs]
            if any(v is None for v in values):
                cells.append("-")
                continue
            spread = max(values) - min(values)
            cells.append(" / ".join(f"{v:.2f}" for v in values) + f" ({spread:.2f})")
            largest = max(largest, spread)
        lines.append(f"| {row} | " + " | ".join(cells) + f" | {largest:.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", nargs="+", help="two or more sharp_variants.py results files, one per seed")
    p.add_argument("--rows", default="tiny_sharp,tiny_sharp + over,tiny (the paper's drawing)")
    p.add_argument("--metric", default="ws_psnr")
    args = p.parse_args()
    if len(args.results) < 2:
        p.error("give two or more results files (one per seed)")
    runs = [json.loads(open(path).read()) for path in args.results]
    print(spread_table(runs, args.rows.split(","), args.metric))


if __name__ == "__main__":
    main()
