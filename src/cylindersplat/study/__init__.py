"""Studies built on the library (``cylindersplat ablate``): train model variants with one schedule and several
seeds, score them on the same held-out scenes, and tabulate mean and spread (paper Table "Ablation Study").

* :mod:`.schedule` - :class:`Schedule`, :class:`Variant`, the thread count that is part of a run's recipe;
* :mod:`.variants` - the variant catalogue, read from ``configs/studies/ablation_variants.yaml``;
* :mod:`.run` - :func:`run_study` (schedule, train, score, resume); :mod:`.aggregate` - per-seed values to mean
  and spread; :mod:`.table` - the Markdown table.

The study scripts built on it, and their results, live outside the package in ``studies/``.
"""

from ..utils.lazy import lazy_exports
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

# The runner and the table import the evaluation (and so torch): loaded at their first use, so that reading the
# variant catalogue (``cylindersplat ablate``'s parser) does not wait for them.
__all__ = ["RunResult", "aggregate", "STUDY_THREADS", "Schedule", "Variant", "torch_threads", "all_variants",
           "change_set", "default_variants", "extra_variants", "pinned_to_earlier_tiny", "recipe", "variant_names",
           *lazy_exports(__name__, globals(), {".run": ("check_variants", "run_study"),
                                               ".table": ("TABLE_METRICS", "study_table")})]
