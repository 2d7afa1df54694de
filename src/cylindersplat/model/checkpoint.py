"""Weights-only save/load of a model with its configuration (safetensors + JSON metadata).

Full training resume state (optimiser, schedule, step) is the training module's business.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from safetensors import safe_open

from .config import config_from_dict, config_to_dict
from .cylindersplat import CylinderSplat

__all__ = ["save_model", "load_model"]

CONFIG_KEY = "cylindersplat_config"


def save_model(model: CylinderSplat, path: str | Path) -> None:
    state = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    # The branch mode in use (e.g. "pixel" after curriculum stage 1) travels with the weights.
    config = model.config.replace(mode=model.mode)
    save_file(state, str(path), metadata={CONFIG_KEY: json.dumps(config_to_dict(config))})


def load_model(path: str | Path, map_location: str | torch.device = "cpu") -> CylinderSplat:
    with safe_open(str(path), framework="pt") as f:
        metadata = f.metadata() or {}
    if CONFIG_KEY not in metadata:
        raise ValueError(f"{path} has no {CONFIG_KEY!r} metadata; was it written by save_model?")
    model = CylinderSplat(config_from_dict(json.loads(metadata[CONFIG_KEY])))
    state = load_file(str(path), device=str(map_location))
    bad = [name for name, tensor in state.items() if tensor.is_floating_point() and not torch.isfinite(tensor).all()]
    if bad:  # what a diverged run leaves; it would render nothing without a word
        raise ValueError(f"{path}: {len(bad)} weight tensors contain NaN/inf (e.g. {bad[0]}); the training run "
                         "diverged: use an earlier checkpoint or retrain with a lower learning rate")
    model.load_state_dict(state)
    return model.to(map_location)
