"""Result tables shaped like the paper's: one row per method, metric columns per protocol."""

from __future__ import annotations

from .masked import MIN_OCCLUDED_PIXELS

__all__ = ["METRIC_COLUMNS", "OCCLUDED_COLUMNS", "VIEW_COUNTS", "results_to_markdown", "background_note"]

# (key, header, higher is better (None: no best value), format)
METRIC_COLUMNS = [
    ("pcc", "PCC ↑", True, "{:.3f}"),
    ("ws_psnr", "WS-PSNR ↑", True, "{:.2f}"),
    ("psnr", "PSNR ↑", True, "{:.2f}"),
    ("ssim", "SSIM ↑", True, "{:.3f}"),
    ("lpips", "LPIPS ↓", False, "{:.3f}"),
    ("abs_rel", "AbsRel ↓", False, "{:.3f}"),
    ("rmse", "RMSE ↓", False, "{:.3f}"),
    ("delta1", "δ1 ↑", True, "{:.3f}"),
    # the paper's LRCE: the depth seam |d(col 0) - d(col W-1)| against the ground truth's, in metres
    # (metrics.depth.lrce)
    ("lrce", "LRCE ↓", False, "{:.4f}"),
    ("time_s", "Time (s) ↓", False, "{:.2f}"),
    # On the occluded pixels only: target pixels no input view sees (docs/evaluation.md, "Occluded pixels").
    ("ws_psnr_occluded", "WS-PSNR (occ.) ↑", True, "{:.2f}"),
    ("psnr_occluded", "PSNR (occ.) ↑", True, "{:.2f}"),
    ("l1_occluded", "L1 (occ.) ↓", False, "{:.4f}"),
    ("abs_rel_occluded", "AbsRel (occ.) ↓", False, "{:.3f}"),
    ("occluded_share", "occ. share", None, "{:.1%}"),
]
OCCLUDED_COLUMNS = [c for c in METRIC_COLUMNS if c[0].endswith("_occluded") or c[0] == "occluded_share"]
# Per-method counts carried with the means (not columns): target views scored, views with occluded metrics.
VIEW_COUNTS = ("views", "occluded_views")


def results_to_markdown(results: dict[str, dict[str, dict[str, float | None]]], title: str | None = None,
                        backgrounds: dict[str, str] | None = None) -> str:
    """``results[protocol][method][metric]`` -> one Markdown table per protocol; best value in bold.

    ``backgrounds`` (method -> what it shows where it covers no pixel, :attr:`Method.background`): said
    under every table, since a method that leaves holes scores against that.

    Metrics a method could not compute (no LPIPS weights, no reference depth) show ``n/a``. The
    occluded-pixel columns ("occ.") average only the views with enough occluded pixels; when the
    means carry :data:`VIEW_COUNTS`, a line under the table says how many views that was.
    """
    lines = [f"# {title}", ""] if title else []
    for protocol, by_method in results.items():
        present = [c for c in METRIC_COLUMNS if any(m.get(c[0]) is not None for m in by_method.values())]
        missing = [c[1].split()[0] for c in METRIC_COLUMNS if c not in present and c not in OCCLUDED_COLUMNS]
        lines += [f"## {protocol}", "", "| Method | " + " | ".join(c[1] for c in present) + " |",
                  "|---|" + "---|" * len(present)]
        best = {}
        for key, _, higher, _ in present:
            values = [m[key] for m in by_method.values() if m.get(key) is not None]
            best[key] = (max if higher else min)(values) if values and higher is not None else None
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
            if set(missing) & {"PCC", "AbsRel", "RMSE", "δ1", "LRCE"}:
                why.append("depth metrics need reference depth")
            lines += ["", f"Not available here: {', '.join(missing)}" + (f" ({'; '.join(why)})." if why else ".")]
        lines += _occluded_note(by_method, [c for c in OCCLUDED_COLUMNS if c in present])
        if backgrounds:
            lines += ["", background_note({name: backgrounds[name] for name in by_method if name in backgrounds})]
        lines.append("")
    return "\n".join(lines)


def _occluded_note(by_method: dict[str, dict], shown: list) -> list[str]:
    """One line on the occluded-pixel columns: how many views they average, or why they are absent."""
    if not shown:
        if any(m.get(k) is not None for m in by_method.values() for k in ("pcc", "abs_rel")):
            return ["", "occ. columns not available here (they need ground-truth depth of the input views too)."]
        return []
    share = "occ. share is their latitude-weighted share of the panorama"
    counts = {(m.get("occluded_views"), m.get("views")) for m in by_method.values()}
    if all(used == 0 for used, _ in counts):
        return ["", f"occ.: no target view has {MIN_OCCLUDED_PIXELS} or more pixels that no input view sees; {share}."]
    if len(counts) == 1:
        used, total = next(iter(counts))
        scope = f"the {used} of {total} target views" if used is not None and total is not None else "the target views"
    else:
        scope = "the target views (" + "; ".join(
            f"{name}: {m.get('occluded_views', '?')} of {m.get('views', '?')}" for name, m in by_method.items()) + ")"
    note = (f"occ.: on the target pixels no input view sees (docs/evaluation.md, \"Occluded pixels\"); means over "
            f"{scope} with at least {MIN_OCCLUDED_PIXELS} such pixels; {share}.")
    return ["", note]


def background_note(backgrounds: dict[str, str]) -> str:
    """One line: what the methods show where they cover no pixel, each background once with its methods."""
    groups: dict[str, list[str]] = {}
    for name, text in backgrounds.items():
        groups.setdefault(text, []).append(name)
    if len(groups) == 1:
        return f"Background where a render covers no pixel: {next(iter(groups))} (every method)."
    parts = [f"{text} ({', '.join(names)})" for text, names in groups.items()]
    return "Background where a render covers no pixel: " + "; ".join(parts) + "."
