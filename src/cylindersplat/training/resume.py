"""What ``train --resume RUN`` continues with: the run's own saved config, changed only where asked.

A resumed run must not fall back to a preset's defaults (no ``data.root``, another schedule): its checkpoint
holds the full config it was trained with (``state.pt``'s ``config``; ``config.yaml`` of the run folder for
checkpoints without one). Command-line settings are applied on top and every difference is reported, so
changing the schedule on resume is explicit and said.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .checkpoint import read_state, resolve_checkpoint
from .config import ExperimentConfig, config_as_dict, config_from_dict

__all__ = ["ResumePoint", "find_resume_point", "config_changes"]


class ResumePoint:
    """A checkpoint to continue: its folder, its run folder, the saved config and the curriculum position.

    Attributes:
        checkpoint: ``RUN/checkpoints/step_NNNNNNN``.
        run_folder: ``RUN`` (where the resumed run keeps writing unless ``--out`` says otherwise).
        saved: the run's config as a plain dict (``config_as_dict`` layout).
        global_step: optimizer steps done.
        stage_index, stage_step: the curriculum position (index into ``train.stages``, steps done in that stage).
    """

    def __init__(self, checkpoint: Path, saved: dict[str, Any], state: dict[str, Any]) -> None:
        self.checkpoint, self.saved = checkpoint, saved
        self.run_folder = checkpoint.parent.parent
        self.global_step, self.stage_index, self.stage_step = (int(state[k]) for k in ("global_step", "stage_index", "stage_step"))

    def finished(self, config: ExperimentConfig) -> bool:
        """Nothing is left to train under ``config``'s schedule (the end-of-stage checkpoint of the last stage, or
        later). A schedule in epochs needs the dataset's size to tell: then only a run past its last stage is."""
        stages = config.train.stages
        if self.stage_index >= len(stages):
            return True
        if self.stage_index < len(stages) - 1 or config.train.epochs_per_stage is not None:
            return False
        return self.stage_step >= config.steps_for(stages[-1])

    def config(self, overrides: list[str] | tuple[str, ...] = ()) -> ExperimentConfig:
        """The saved config with the command line's ``key=value`` ``overrides`` applied."""
        return config_from_dict(self.saved, overrides)


def find_resume_point(path: str | Path) -> ResumePoint:
    """``path``: a run folder, its ``checkpoints/`` folder, a ``step_*`` folder or its ``state.pt``."""
    checkpoint = resolve_checkpoint(path)
    state = read_state(checkpoint)
    saved = state.get("config")
    if saved is None:  # checkpoints of early versions: the run folder's config.yaml
        config_file = checkpoint.parent.parent / "config.yaml"
        if not config_file.is_file():
            raise FileNotFoundError(f"{checkpoint} holds no config and {config_file} is missing: "
                                    "start anew with --overwrite, or from its weights with --init")
        saved = yaml.safe_load(config_file.read_text())
    return ResumePoint(checkpoint, saved, state)


def config_changes(before: dict[str, Any], after: ExperimentConfig) -> list[str]:
    """``["train.steps_per_stage [4] -> [8]", ...]``: every setting of ``after`` that differs from ``before``."""
    changes: list[str] = []

    def walk(old: Any, new: Any, prefix: str) -> None:
        if isinstance(old, dict) and isinstance(new, dict):
            for key in sorted(set(old) | set(new)):
                walk(old.get(key), new.get(key), f"{prefix}{key}.")
        elif old != new:
            changes.append(f"{prefix[:-1]} {old} -> {new}")

    walk(before, config_as_dict(after), "")
    return changes
