"""Markdown tables of issue 34's results files (studies/results/sharp_*.json), as benchmarks/RESULTS.md shows them.

    python studies/sharp_tables.py studies/results/sharp_fixture.json --priors gt,degraded:mono
    python studies/sharp_tables.py studies/results/sharp_synthetic_64.json --priors default,gt,degraded:mono

Each cell: WS-PSNR on all pixels / on the hidden ones (no input sees them; "-" where a view has too few) / SSIM.
Rows: the shipped weights as they draw (``tiny_sharp``), FW + inpaint, the shipped pixel branch with the better of
the two fills, the same weights drawn with one footprint for every pixel Gaussian (session 16's drawing), with the
front-most pixel splat winning (``tiny_sharp + over``, the drawing before session 16) and drawn the paper's way,
each with its pixel branch's best fill row, and options.
"""

from __future__ import annotations

import argparse
import json

SHIPPED, PAPER = "tiny_sharp", "tiny (the paper's drawing)"


def cell(scores: dict | None) -> str:
    if scores is None:
        return "-"
    hidden = scores.get("ws_psnr_occluded")
    return f"{scores['ws_psnr']:.2f} / {'-' if hidden is None else f'{hidden:.2f}'} / {scores['ssim']:.3f}"


def best_fill(block: dict, name: str) -> dict | None:
    rows = [block.get(f"{name}: pixel branch + {fill}") for fill in ("inpaint", "mean")]
    rows = [row for row in rows if row]
    return max(rows, key=lambda row: row["ws_psnr"]) if rows else None


ROWS = (
    ("CylinderSplat, shipped weights (`recipes/tiny_sharp` drawing)", lambda b: b.get(SHIPPED)),
    ("FW + inpaint", lambda b: b.get("FW + inpaint")),
    ("its pixel branch + best fill", lambda b: best_fill(b, SHIPPED)),
    ("shipped, one footprint for all (`fusion.pixel_footprint=per_view`, 0.5 px: session 16's drawing)",
     lambda b: b.get(f"{SHIPPED} (per-view footprint)")),
    ("that pixel branch + best fill", lambda b: best_fill(b, f"{SHIPPED} (per-view footprint)")),
    ("shipped, front-most splat (`render_pixel_blending=over`: session 15's drawing)",
     lambda b: b.get(f"{SHIPPED} + over")),
    ("that pixel branch + best fill", lambda b: best_fill(b, f"{SHIPPED} + over")),
    ("same weights, the paper's drawing", lambda b: b.get(PAPER)),
    ("that pixel branch + best fill", lambda b: best_fill(b, PAPER)),
    ("shipped, drawn as opaque layers (option `render_layering=pixel_over_volume`)",
     lambda b: b.get(f"{SHIPPED} + layers")),
    ("session 16's drawing, pixel clearing everywhere (`fusion.pixel_clearing=seen_through`)",
     lambda b: b.get(f"{SHIPPED} + blending + clearing seen_through")),
)


def tables(results: dict, priors: list[str]) -> str:
    lines = []
    for prior in priors:
        keys = [key for key in results if key.endswith(f" {prior}")]
        if not keys:
            continue
        lines += [f"\nDepth prior `{prior}`:\n", "| method | " + " | ".join(k.rsplit(" ", 1)[0] for k in keys) + " |",
                  "|---|" + "---|" * len(keys)]
        for name, get in ROWS:
            cells = [cell(get(results[key])) for key in keys]
            if any(c != "-" for c in cells):
                lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results")
    p.add_argument("--priors", default="gt,degraded:mono")
    args = p.parse_args()
    print(tables(json.loads(open(args.results).read()), args.priors.split(",")))


if __name__ == "__main__":
    main()
