"""Per-seed results of one variant -> per metric: the seeds' values, their mean and half their range."""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

from .schedule import Variant

__all__ = ["RunResult", "aggregate"]


@dataclass
class RunResult:
    """One trained and scored run (a variant and a seed): held-out means and what the run cost."""

    metrics: dict[str, float | None]
    train_s: float
    skipped_steps: int
    gaussians: int
    visible_gaussians: int
    weights: str


def aggregate(variant: Variant, runs: list[RunResult]) -> dict:
    """The report's entry of ``variant``: description, overrides, kind and, per metric, ``seeds`` / ``mean`` /
    ``spread`` (half the range; ``None`` where no seed has a finite value)."""
    keys = list(dict.fromkeys(k for r in runs for k in r.metrics))
    per_metric = {k: [r.metrics.get(k) for r in runs] for k in keys}
    per_metric["gaussians"] = [r.visible_gaussians for r in runs]
    per_metric["gaussians_total"] = [r.gaussians for r in runs]
    per_metric["train_s"] = [r.train_s for r in runs]
    per_metric["skipped_steps"] = [r.skipped_steps for r in runs]
    metrics = {}
    for key, values in per_metric.items():
        finite = [float(x) for x in values if x is not None and math.isfinite(float(x))]
        metrics[key] = {
            "seeds": [None if x is None else float(x) for x in values],
            "mean": statistics.fmean(finite) if finite else None,
            "spread": (max(finite) - min(finite)) / 2 if len(finite) > 1 else 0.0 if finite else None,
        }
    return {"description": variant.description, "overrides": list(variant.overrides), "kind": variant.kind,
            "metrics": metrics}
