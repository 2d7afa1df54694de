"""Issue 34: what a retraining changed, seed by seed: per setting, the change of a row between results files of the
runs before and after (WS-PSNR on all pixels / on the hidden ones / SSIM), and how many seeds gained.

    python studies/finetune_delta.py \\
        --before studies/results/sharp_fixture.json studies/results/seed1_fixture.json \\
                 studies/results/seed2_fixture.json \\
        --after studies/results/finetune_drawn_seed0_fixture.json studies/results/finetune_drawn_seed1_fixture.json \\
                studies/results/finetune_drawn_seed2_fixture.json

``--before`` and ``--after`` name one ``studies/sharp_variants.py`` results file per seed, in the same seed order.
Each cell: the after-minus-before changes of seeds 0 / 1 / 2 ...; the last rows count, per metric, the cells where
every seed gained, every seed lost, or the seeds disagree. ``--against ROW`` compares the after run's ``--row``
with another row of the same after file instead (e.g. ``"FW + inpaint"``, ``"tiny_sharp: pixel branch + inpaint"``).
"""

from __future__ import annotations

import argparse
import json

METRICS = (("ws_psnr", "all", 2), ("ws_psnr_occluded", "hidden", 2), ("ssim", "SSIM", 3))


def deltas(before: list[dict], after: list[dict], row: str, against: str | None = None) -> dict[str, dict]:
    """Per setting and metric, the list of per-seed changes (None where a file lacks the value)."""
    keys = [key for key in after[0] if all(key in run for run in after + before)]
    table: dict[str, dict] = {}
    for key in keys:
        table[key] = {}
        for metric, _, _ in METRICS:
            changes = []
            for old, new in zip(before, after):
                reference = (new if against else old)[key].get(against or row, {}).get(metric)
                value = new[key].get(row, {}).get(metric)
                changes.append(None if value is None or reference is None else value - reference)
            table[key][metric] = changes
    return table


def render(table: dict[str, dict]) -> str:
    lines = ["| setting | " + " | ".join(name for _, name, _ in METRICS) + " |", "|---|" + "---|" * len(METRICS)]
    tally = {metric: {"all seeds up": 0, "all seeds down": 0, "mixed": 0} for metric, _, _ in METRICS}
    for key, cells in table.items():
        shown = []
        for metric, _, digits in METRICS:
            changes = cells[metric]
            if any(c is None for c in changes):
                shown.append("-")
                continue
            shown.append(" / ".join(f"{c:+.{digits}f}" for c in changes))
            kind = "all seeds up" if all(c > 0 for c in changes) else (
                "all seeds down" if all(c < 0 for c in changes) else "mixed")
            tally[metric][kind] += 1
        lines.append(f"| {key} | " + " | ".join(shown) + " |")
    for kind in ("all seeds up", "all seeds down", "mixed"):
        lines.append(f"| *{kind}* | " + " | ".join(str(tally[m][kind]) for m, _, _ in METRICS) + " |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", nargs="+", required=True, help="results files of the runs before, one per seed")
    p.add_argument("--after", nargs="+", required=True, help="results files of the runs after, same seed order")
    p.add_argument("--row", default="tiny_sharp")
    p.add_argument("--against", default=None, help="compare with this row of the after files instead")
    args = p.parse_args()
    if len(args.before) != len(args.after):
        p.error(f"--before has {len(args.before)} files and --after {len(args.after)}: give one per seed in each")
    runs = []
    for path in args.before + args.after:
        try:
            with open(path) as f:
                runs.append(json.load(f))
        except (OSError, json.JSONDecodeError) as error:
            p.error(f"cannot read results file {path}: {error}")
    before, after = runs[:len(args.before)], runs[len(args.before):]
    print(render(deltas(before, after, args.row, args.against)))


if __name__ == "__main__":
    main()
