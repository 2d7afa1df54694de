"""What one study run trains: the :class:`Schedule` shared by every variant, the :class:`Variant` (a name, its
config changes on the ``tiny`` preset and its kind), and the torch thread count that is part of the recipe."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

__all__ = ["Schedule", "Variant", "STUDY_THREADS", "torch_threads"]

# torch intra-op threads of the study's runs (run_study's default): fixed, so that reruns are bit-identical
# whatever OMP_NUM_THREADS the shell has (studies/rerun_check.py)
STUDY_THREADS = 2


@dataclass(frozen=True)
class Schedule:
    """Optimizer steps of the full curriculum's stages 1, 2, 3 (other variants get the same total)."""

    stage1: int = 300
    stage2: int = 150
    stage3: int = 150
    lr: float = 2e-3

    @property
    def total(self) -> int:
        return self.stage1 + self.stage2 + self.stage3


@dataclass(frozen=True)
class Variant:
    """A model variant of a study: ``overrides`` are ``key=value`` changes on the ``tiny`` preset (the variant
    catalogue, :mod:`.variants`, writes them from typed values); ``kind`` picks the curriculum stages."""

    name: str
    description: str
    overrides: tuple[str, ...] = ()
    kind: str = "full"  # "full" (stages 1-2-3), "pixel" (stage 1 only), "volume" (stages 1-2), "baseline" (no model)

    def stages(self, schedule: Schedule) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """(stages, steps per stage) of this variant under ``schedule``."""
        from ..model.curriculum import KIND_STAGES

        if self.kind not in KIND_STAGES:
            raise ValueError(f"unknown variant kind {self.kind!r}; expected one of {', '.join(KIND_STAGES)}")
        # the same total for every kind: a kind's last stage takes the steps of the stages it skips
        steps = [schedule.stage1, schedule.stage2, schedule.stage3][: len(KIND_STAGES[self.kind])]
        steps[-1] += schedule.total - sum(steps)
        stages = list(zip(KIND_STAGES[self.kind], steps))
        stages = [(s, n) for s, n in stages if n > 0]
        return tuple(s for s, _ in stages), tuple(n for _, n in stages)

    @property
    def depth_prior(self) -> str:
        """The input depth prior the variant trains and is scored with (``data.depth_prior``; by default the
        preset's)."""
        chosen = [o.split("=", 1)[1] for o in self.overrides if o.startswith("data.depth_prior=")]
        return chosen[-1] if chosen else "default"


@contextlib.contextmanager
def torch_threads(threads: int | None):
    """Within the block torch uses ``threads`` intra-op threads (``None``: unchanged)."""
    import torch

    if threads is None:
        yield
        return
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ValueError(f"threads must be an integer >= 1 (torch intra-op threads), got {threads!r}")
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
