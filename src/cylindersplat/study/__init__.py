"""Studies built on the library (``cylindersplat ablate``): train model variants with one schedule and several
seeds, score them on the same held-out scenes, and tabulate mean and spread (paper Table "Ablation Study").

* :mod:`.schedule` - :class:`Schedule`, :class:`Variant`, the thread count that is part of a run's recipe;
* :mod:`.variants` - the variant catalogue, read from ``configs/studies/ablation_variants.yaml``;
* :mod:`.run` - :func:`run_study` (schedule, train, score, resume); :mod:`.aggregate` - per-seed values to mean
  and spread; :mod:`.table` - the Markdown table.

The study scripts built on it, and their results, live outside the package in ``studies/``.
"""

from .aggregate import RunResult, aggregate
from .run import check_variants, run_study
from .schedule import STUDY_THREADS, Schedule, Variant, torch_threads
from .table import TABLE_METRICS, study_table
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
