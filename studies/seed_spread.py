"""Issue 34: the spread between two trainings of the shipped recipe (seeds 0 and 1), per drawing and setting.

    python studies/seed_spread.py studies/results/sharp_fixture.json studies/results/seed1_fixture.json \\
        --rows "tiny_sharp,tiny_sharp + over,tiny (the paper's drawing)"

Each cell: WS-PSNR on all pixels, seed 0 / seed 1 (difference); the last column the largest |difference| per row.
Both files come from ``studies/sharp_variants.py`` (the second with ``--checkpoint`` of the other run).
"""

from __future__ import annotations

import argparse
import json


def spread_table(first: dict, second: dict, rows: list[str], metric: str = "ws_psnr") -> str:
    keys = [key for key in first if key in second]
    lines = ["| drawing | " + " | ".join(keys) + " | largest difference |", "|---|" + "---|" * (len(keys) + 1)]
    for row in rows:
        cells, largest = [], 0.0
        for key in keys:
            a, b = (d[key].get(row, {}).get(metric) for d in (first, second))
            if a is None or b is None:
                cells.append("-")
                continue
            cells.append(f"{a:.2f} / {b:.2f} ({b - a:+.2f})")
            largest = max(largest, abs(b - a))
        lines.append(f"| {row} | " + " | ".join(cells) + f" | {largest:.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("first")
    p.add_argument("second")
    p.add_argument("--rows", default="tiny_sharp,tiny_sharp + over,tiny (the paper's drawing)")
    p.add_argument("--metric", default="ws_psnr")
    args = p.parse_args()
    first, second = (json.loads(open(path).read()) for path in (args.first, args.second))
    print(spread_table(first, second, args.rows.split(","), args.metric))


if __name__ == "__main__":
    main()
