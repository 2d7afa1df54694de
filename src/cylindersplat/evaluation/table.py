"""Result tables shaped like the paper's: one row per method, metric columns per protocol."""

from __future__ import annotations

__all__ = ["METRIC_COLUMNS", "results_to_markdown"]

# (key, header, higher is better, format)
METRIC_COLUMNS = [
    ("pcc", "PCC ↑", True, "{:.3f}"),
    ("ws_psnr", "WS-PSNR ↑", True, "{:.2f}"),
    ("ssim", "SSIM ↑", True, "{:.3f}"),
    ("lpips", "LPIPS ↓", False, "{:.3f}"),
    ("abs_rel", "AbsRel ↓", False, "{:.3f}"),
    ("rmse", "RMSE ↓", False, "{:.3f}"),
    ("delta1", "δ1 ↑", True, "{:.3f}"),
    ("lrce", "LRCE ↓", False, "{:.4f}"),
    ("time_s", "Time (s) ↓", False, "{:.2f}"),
]


def results_to_markdown(results: dict[str, dict[str, dict[str, float | None]]], title: str | None = None) -> str:
    """``results[protocol][method][metric]`` -> one Markdown table per protocol; best value in bold.

    Metrics a method could not compute (no LPIPS weights, no reference depth) show ``n/a``.
    """
    lines = [f"# {title}", ""] if title else []
    for protocol, by_method in results.items():
        present = [c for c in METRIC_COLUMNS if any(m.get(c[0]) is not None for m in by_method.values())]
        missing = [c[1].split()[0] for c in METRIC_COLUMNS if c not in present]
        lines += [f"## {protocol}", "", "| Method | " + " | ".join(c[1] for c in present) + " |",
                  "|---|" + "---|" * len(present)]
        best = {}
        for key, _, higher, _ in present:
            values = [m[key] for m in by_method.values() if m.get(key) is not None]
            best[key] = (max if higher else min)(values) if values else None
        for name, metrics in by_method.items():
            cells = []
            for key, _, _, fmt in present:
                value = metrics.get(key)
                text = "n/a" if value is None else fmt.format(value)
                cells.append(f"**{text}**" if value is not None and value == best[key] and len(by_method) > 1 else text)
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        if missing:
            why = []
            if "LPIPS" in missing:
                why.append("LPIPS needs local VGG weights")
            if set(missing) & {"PCC", "AbsRel", "RMSE", "δ1"}:
                why.append("depth metrics need reference depth")
            lines += ["", f"Not available here: {', '.join(missing)}" + (f" ({'; '.join(why)})." if why else ".")]
        lines.append("")
    return "\n".join(lines)
