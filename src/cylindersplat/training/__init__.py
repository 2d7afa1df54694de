"""Training: the paper's rendering loss, typed configs with YAML presets and overrides, and the
three-stage curriculum trainer with exact resume (see ``docs/training.md``)."""

from .config import (
    DataConfig,
    ExperimentConfig,
    TrainConfig,
    available_presets,
    config_as_dict,
    load_config,
    parse_overrides,
)
from .losses import LossConfig, LossTerms, RenderLoss
from .trainer import Trainer, batch_to_device, select_device

__all__ = [name for name in dir() if not name.startswith("_")]
