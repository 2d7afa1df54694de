"""The curriculum's per-stage policy (paper Sec. 3.3), in one place.

Stage 1 trains the pixel branch alone; stage 2 the volume branch beside the frozen pixel branch (its render:
the volume Gaussians alone, the paper's, or fused with the frozen pixel Gaussians, ``train.stage2_render=fused``);
stage 3 both, jointly. :class:`~.cylindersplat.CylinderSplat` applies a :class:`StagePolicy` (mode and freezing),
the trainer asks it what a stage renders and whether later stages complete hidden space, and the ablation study
maps its variant kinds to stages through :data:`KIND_STAGES`.
"""

from __future__ import annotations

from dataclasses import dataclass

from .config import CHOICES

__all__ = ["StagePolicy", "stage_policy", "STAGE2_RENDERS", "KIND_STAGES", "volume_stage_follows"]

STAGE2_RENDERS = CHOICES["train.stage2_render"]  # ("volume", "fused"), from the one choice table
# ablation variant kind -> the curriculum stages it runs
KIND_STAGES = {"full": (1, 2, 3), "pixel": (1,), "volume": (1, 2)}


@dataclass(frozen=True)
class StagePolicy:
    stage: int
    mode: str  # which Gaussians the model outputs: "pixel", "volume" or "both"
    train_pixel: bool
    train_volume: bool


def stage_policy(stage: int, stage2_render: str = "volume") -> StagePolicy:
    """What curriculum ``stage`` (1, 2, 3) renders and trains."""
    if stage not in (1, 2, 3):
        raise ValueError(f"curriculum stage must be 1, 2 or 3, got {stage}")
    if stage2_render not in STAGE2_RENDERS:
        raise ValueError(f"train.stage2_render must be one of {', '.join(STAGE2_RENDERS)}, got {stage2_render!r}")
    if stage == 1:
        return StagePolicy(1, "pixel", train_pixel=True, train_volume=False)
    if stage == 2:
        return StagePolicy(2, "both" if stage2_render == "fused" else "volume", train_pixel=False, train_volume=True)
    return StagePolicy(3, "both", train_pixel=True, train_volume=True)


def volume_stage_follows(stage: int, stages: tuple[int, ...] | list[int]) -> bool:
    """Whether ``stage`` is the pixel stage of a curriculum whose later stages train the volume branch (so that
    ``loss.pixel_stage_hidden=leave`` may leave hidden pixels to it)."""
    return stage == 1 and any(s in (2, 3) for s in stages)
