"""What ``train --resume RUN`` continues with: the run's own saved config, changed only where asked.

A resumed run must not fall back to a preset's defaults (no ``data.root``, another schedule): its checkpoint
holds the full config it was trained with (``state.pt``'s ``config``; ``config.yaml`` of the run folder for
checkpoints without one). Command-line settings are applied on top and every difference is reported, so
changing the schedule on resume is explicit and said.

A run folder without a checkpoint (a run killed before its first one, ``train.checkpoint_every`` steps) holds
nothing to continue: the same command starts it over (:func:`unresumable_run`), and ``--resume`` says so.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import yaml

from .checkpoint import read_state, resolve_checkpoint
from .config import ExperimentConfig, config_as_dict, config_from_dict

__all__ = ["ResumePoint", "find_resume_point", "config_changes", "curriculum_position", "RUN_OUTPUTS", "run_outputs",
           "has_checkpoint", "unresumable_run", "remove_run_outputs"]

# What a run writes into its folder (``--overwrite`` removes exactly these, nothing else of the user's).
RUN_OUTPUTS = ("checkpoints", "images", "tensorboard", "metrics.jsonl", "config.yaml", "model.safetensors",
               "model_stage1.safetensors", "model_stage2.safetensors", "model_stage3.safetensors")


def run_outputs(folder: Path) -> list[str]:
    """The names of :data:`RUN_OUTPUTS` present in ``folder``."""
    return [name for name in RUN_OUTPUTS if (Path(folder) / name).exists()]


def remove_run_outputs(folder: str | Path) -> None:
    """Delete :data:`RUN_OUTPUTS` from ``folder`` (and nothing else there)."""
    for name in run_outputs(Path(folder)):
        path = Path(folder) / name
        shutil.rmtree(path) if path.is_dir() else path.unlink()


def has_checkpoint(folder: str | Path) -> bool:
    """Whether ``folder`` (a run folder) holds a complete checkpoint to resume."""
    try:
        resolve_checkpoint(folder)
    except FileNotFoundError:
        return False
    return True


def unresumable_run(folder: str | Path) -> list[str]:
    """The run outputs of a run that stopped before its first checkpoint (no checkpoint, no weights): nothing to
    continue and nothing trained to keep, so the same command may start over. Empty for any other folder."""
    present = run_outputs(Path(folder))
    if not present or has_checkpoint(folder) or any(name.endswith(".safetensors") for name in present):
        return []
    return present


def curriculum_position(saved_stages, stage_index: int, stage_step: int, stages) -> tuple[int, int]:
    """``(stage_index, stage_step)`` under ``stages`` of a checkpoint at ``(stage_index, stage_step)`` of
    ``saved_stages``: the same position for the same stages; otherwise the first of ``stages`` the run has not
    finished (the stage it was in keeps its steps), ``(len(stages), 0)`` when it finished all of them."""
    saved_stages, stages = list(saved_stages), list(stages)
    if saved_stages == stages:
        return stage_index, stage_step
    finished = set(saved_stages[:stage_index])
    current = saved_stages[stage_index] if stage_index < len(saved_stages) else None
    for index, stage in enumerate(stages):
        if stage not in finished:
            return index, stage_step if stage == current else 0
    return len(stages), 0


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
        self.global_step, self.stage_index, self.stage_step = (int(state[k])
                                                               for k in ("global_step", "stage_index", "stage_step"))
        self.saved_stages = [int(s) for s in state["stages"]]

    def finished(self, config: ExperimentConfig) -> bool:
        """Nothing is left to train under ``config``'s schedule (the end-of-stage checkpoint of the last stage, or
        later). A schedule in epochs needs the dataset's size to tell: then only a run past its last stage is."""
        stages = config.train.stages
        stage_index, stage_step = curriculum_position(self.saved_stages, self.stage_index, self.stage_step, stages)
        if stage_index >= len(stages):
            return True
        if stage_index < len(stages) - 1 or config.train.epochs_per_stage is not None:
            return False
        return stage_step >= config.steps_for(stages[-1])

    def config(self, overrides: list[str] | tuple[str, ...] = (), changes: dict | None = None) -> ExperimentConfig:
        """The saved config with the command line's ``key=value`` ``overrides``, then its options' typed ``changes``."""
        return config_from_dict(self.saved, overrides, changes)


def find_resume_point(path: str | Path) -> ResumePoint:
    """``path``: a run folder, its ``checkpoints/`` folder, a ``step_*`` folder or its ``state.pt``."""
    try:
        checkpoint = resolve_checkpoint(path)
    except FileNotFoundError as exc:
        if unresumable_run(path):
            raise FileNotFoundError(f"no training checkpoint at {path}: its run stopped before the first one "
                                    "(train.checkpoint_every); run the same command without --resume to start it "
                                    "over") from exc
        raise
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
