"""Weights-only save/load of a model with its configuration (safetensors + JSON metadata).

Full training resume state (optimiser, schedule, step) is the training module's business.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save

from .config import ModelConfig, config_from_dict, config_to_dict
from .cylindersplat import CylinderSplat

__all__ = ["save_model", "load_model", "read_model_config"]

CONFIG_KEY = "cylindersplat_config"


def save_model(model: CylinderSplat, path: str | Path) -> None:
    """Weights + config as one ``.safetensors``, written atomically (a failure keeps an earlier file)."""
    from ..utils.atomic import atomic_write_bytes

    state = {k: v.detach().contiguous().cpu() for k, v in model.state_dict().items()}
    # The branch mode in use (e.g. "pixel" after curriculum stage 1) travels with the weights.
    config = model.config.replace(mode=model.mode)
    atomic_write_bytes(path, save(state, metadata={CONFIG_KEY: json.dumps(config_to_dict(config))}))


WEIGHTS_HINT = "give the model.safetensors written by `cylindersplat train` or the demo"


def check_weights_file(path: str | Path) -> None:
    """Refuse, by name and with what to give instead, a folder, a missing file or a PyTorch pickle."""
    path = Path(path)
    if path.is_dir():
        inside = sorted(path.glob("model.safetensors")) or sorted(path.glob("*/model.safetensors"))
        hint = f"e.g. {inside[-1]}" if inside else WEIGHTS_HINT
        raise ValueError(f"{path} is a folder, not a weights file: {hint}")
    if not path.is_file():
        raise FileNotFoundError(f"weights file not found: {path} ({WEIGHTS_HINT})")
    with open(path, "rb") as f:
        head = f.read(9)  # safetensors: 8 bytes of header length, then the JSON header
    if head[8:9] != b"{" and (head[:2] == b"PK" or head[:1] == b"\x80"):  # torch.save's zip archive / a raw pickle
        raise ValueError(f"{path} is a PyTorch pickle (torch.save), not a .safetensors file; cylindersplat never "
                         f"unpickles weights: {WEIGHTS_HINT}")
    if len(head) < 9:
        raise ValueError(f"{path} is not a .safetensors weights file ({path.stat().st_size} bytes): {WEIGHTS_HINT}")


def read_model_config(path: str | Path) -> ModelConfig:
    """The model config stored with the weights of :func:`save_model` (the header only: no tensor is read)."""
    path = Path(path)
    check_weights_file(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            metadata = f.metadata() or {}
    except Exception as exc:  # noqa: BLE001 - SafetensorError and its kin: truncated, random bytes, ...
        raise ValueError(
            f"{path} is not a readable .safetensors file ({exc}); is it complete? {WEIGHTS_HINT}"
        ) from None
    if CONFIG_KEY not in metadata:
        raise ValueError(f"{path} has no {CONFIG_KEY!r} metadata; was it written by save_model? ({WEIGHTS_HINT})")
    try:
        return config_from_dict(json.loads(metadata[CONFIG_KEY])).validate()
    except (ValueError, TypeError, AttributeError, RecursionError) as exc:  # JSON errors are ValueErrors
        raise ValueError(f"{path}: its model config cannot be read by this version of cylindersplat ({exc})") from None


def _check_model_size(config: ModelConfig, path: Path, device) -> None:
    """Refuse a stored config whose weights alone would not fit in free memory (a hand-edited or hostile
    config asking for terabytes), before allocating: the parameters are counted on the meta device."""
    from ..utils.memory import available_memory

    with torch.device("meta"):
        model = CylinderSplat(config)
    need = sum(p.numel() * p.element_size() for p in model.parameters())
    free = available_memory(torch.device(device))
    if free is not None and need > free:
        raise MemoryError(f"{path}: its model config asks for {need / 2**30:.3g} GiB of weights but {free / 2**30:.3g} "
                          f"GiB are free; is it the right file? {WEIGHTS_HINT}")


MAX_WEIGHT = 1e8  # no trained layer holds weights this large; beyond it the file was scaled or corrupted


def _check_weights(state: dict, path: Path) -> None:
    """Finite floating-point weights of plausible size (NaN/inf: a diverged run; ints or 1e30: not trained weights)."""
    not_float = [name for name, tensor in state.items() if not tensor.is_floating_point()]
    if not_float:
        raise ValueError(f"{path}: weight {not_float[0]} is {state[not_float[0]].dtype}, not floating point; "
                         f"the file was not written by save_model: {WEIGHTS_HINT}")
    bad = [name for name, tensor in state.items() if not torch.isfinite(tensor).all()]
    if bad:  # what a diverged run leaves; it would render nothing without a word
        raise ValueError(f"{path}: {len(bad)} weight tensors contain NaN/inf (e.g. {bad[0]}); the training run "
                         "diverged: use an earlier checkpoint or retrain with a lower learning rate")
    largest = {name: float(t.abs().max()) for name, t in state.items() if t.numel()}
    huge = [(name, value) for name, value in largest.items() if value > MAX_WEIGHT]
    if huge:
        raise ValueError(f"{path}: weight {huge[0][0]} reaches {huge[0][1]:.3g} (more than {MAX_WEIGHT:g}); no trained "
                         f"model holds such values: the file is scaled or corrupted: {WEIGHTS_HINT}")


def load_model(path: str | Path, map_location: str | torch.device = "cpu") -> CylinderSplat:
    """The model saved by :func:`save_model`. A folder, a missing, truncated, foreign or diverged file, or
    weights that do not fit their stored config raise ``ValueError``/``FileNotFoundError`` naming ``path``."""
    path = Path(path)
    config = read_model_config(path)
    _check_model_size(config, path, map_location)
    try:
        model = CylinderSplat(config)
    except (ValueError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: its model config cannot be read by this version of cylindersplat ({exc})") from None
    try:
        state = load_file(str(path), device=str(map_location))
    except Exception as exc:  # noqa: BLE001 - truncated tensor data
        raise ValueError(f"{path}: cannot read its tensors ({exc}); is the file complete? {WEIGHTS_HINT}") from None
    _check_weights(state, path)
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:  # missing/unexpected keys, shapes: weights of another architecture
        first = " ".join(str(exc).split())[:160]
        raise ValueError(f"{path}: the weights do not match the model config stored with them ({first}...); "
                         f"was the file assembled by hand? {WEIGHTS_HINT}") from None
    return model.to(map_location)
