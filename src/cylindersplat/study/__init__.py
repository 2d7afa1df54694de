"""Studies built on the library (``cylindersplat ablate``): train model variants with one schedule and several
seeds, score them on the same held-out scenes, and tabulate mean and spread (paper Table "Ablation Study").

* :mod:`.schedule` - :class:`Schedule`, :class:`Variant`, the thread count that is part of a run's recipe;
* :mod:`.variants` - the variant catalogue, read from ``configs/studies/ablation_variants.yaml``;
* :mod:`.run` - :func:`run_study` (schedule, train, score, resume); :mod:`.aggregate` - per-seed values to mean
  and spread; :mod:`.table` - the Markdown table.

The study scripts built on it, and their results, live outside the package in ``studies/``.
"""

from .aggregate import RunResult, aggregate
from .schedule import STUDY_THREADS, Schedule, Variant, torch_threads
from .variants import (
    all_variants,
    change_set,
    default_variants,
    extra_variants,
    pinned_to_earlier_tiny,
    recipe,
    variant_names,
)

__all__ = ["RunResult", "aggregate", "check_variants", "run_study", "STUDY_THREADS", "Schedule", "Variant",
           "torch_threads", "TABLE_METRICS", "study_table", "all_variants", "change_set", "default_variants",
           "extra_variants", "pinned_to_earlier_tiny", "recipe", "variant_names"]


# The runner and the table import the evaluation (and so torch): loaded at their first use, so that reading the
# variant catalogue (``cylindersplat ablate``'s parser) does not wait for them.
_LAZY = {"check_variants": "run", "run_study": "run", "TABLE_METRICS": "table", "study_table": "table"}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value
    return value
