"""A study report as a paper-shaped Markdown table: one row per variant, ``mean ± half the seed range``."""

from __future__ import annotations

from ..evaluation.fills import FILL_DESCRIPTIONS

__all__ = ["TABLE_METRICS", "study_table"]

# metric key -> (table header, higher is better, format); occluded-pixel metrics appear when eval reports them
TABLE_METRICS = [
    ("ws_psnr", "WS-PSNR ↑", True, "{:.2f}"),
    ("ssim", "SSIM ↑", True, "{:.3f}"),
    ("pcc", "PCC ↑", True, "{:.3f}"),
    ("abs_rel", "AbsRel ↓", False, "{:.3f}"),
    ("ws_psnr_occluded", "WS-PSNR occ. ↑", True, "{:.2f}"),
    ("abs_rel_occluded", "AbsRel occ. ↓", False, "{:.3f}"),
    ("occluded_share", "occ. share", None, "{:.3f}"),
    ("gaussians", "Gaussians", None, "{:,.0f}"),
    ("train_s", "Train (s)", None, "{:.0f}"),
    ("time_s", "Time / scene (s)", None, "{:.2f}"),
]


def _mean(variant: dict, key: str):
    return variant["metrics"].get(key, {}).get("mean")


def study_table(report: dict) -> str:
    """Markdown: one row per variant, ``mean ± half the seed range`` per metric; best mean in bold."""
    variants = report["variants"]
    present = [m for m in TABLE_METRICS if any(_mean(v, m[0]) is not None for v in variants.values())]
    best = {}
    for key, _, higher, _ in present:
        if higher is None:
            continue
        means = [_mean(v, key) for v in variants.values() if _mean(v, key) is not None]
        best[key] = (max if higher else min)(means) if means else None
    sched = report["schedule"]
    chosen = report.get("depth_prior", "default")
    prior = "" if chosen == "default" else f"; input depth prior {chosen}"
    total = sched["stage1"] + sched["stage2"] + sched["stage3"]
    fills = ""
    if report.get("fills"):
        fills = (", except the fill rows (" + "; ".join(f"+ {fill} fill: {FILL_DESCRIPTIONS[fill]}"
                                                        for fill in report["fills"])
                 + "; forward_warp rows: no training, one value)")
    lines = [
        f"Ablation study: {report['train_scenes']} training / {len(report['held_out_scenes'])} held-out procedural "
        f"scenes, {report['resolution'][0]}x{report['resolution'][1]}, two_view; seeds {report['seeds']}; "
        f"{total} steps per variant (full: {sched['stage1']}/{sched['stage2']}/{sched['stage3']}), "
        f"lr {sched['lr']}{prior}. Cells: mean ± half the range over seeds. \"occ.\": pixels no input view sees.",
        "",
        "Background where a render covers no pixel: black" + fills + ".",
        "",
        "| Variant | " + " | ".join(h for _, h, _, _ in present) + " |",
        "|---|" + "---|" * len(present),
    ]
    for name, v in variants.items():
        cells = []
        for key, _, higher, fmt in present:
            stat = v["metrics"].get(key, {})
            mean, spread = stat.get("mean"), stat.get("spread")
            if mean is None:
                cells.append("n/a")
                continue
            text = fmt.format(mean) + (f" ± {fmt.format(spread)}" if spread and higher is not None else "")
            cells.append(f"**{text}**" if higher is not None and mean == best.get(key) else text)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", f"Study time: {report.get('study_s', float('nan')) / 60:.1f} min."]
    return "\n".join(lines) + "\n"
