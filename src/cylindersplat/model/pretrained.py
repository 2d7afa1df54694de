"""Weights that ship with the package, and a ``from_pretrained`` that takes a name, a file or a folder.

The shipped model (``tiny-synth``) is the ``tiny`` architecture trained on procedural scenes by
``bash scripts/train_pretrained.sh`` (its log and held-out table: ``benchmarks/RESULTS.md``,
"Shipped weights"). It is a starting point and a smoke-test model, not a model for real captures:
train or fine-tune on your data for that.

A checkpoint is one ``.safetensors`` file with its config in the metadata (``save_model``), or a
folder holding ``model.safetensors`` — the same layout a model hub repository would have, so larger
weights can be published the same way later.
"""

from __future__ import annotations

import warnings
from importlib import resources
from pathlib import Path

import torch

from ..utils.notices import Notice
from .checkpoint import check_weights_file, load_model, read_model_config
from .config import ModelConfig
from .cylindersplat import CylinderSplat

__all__ = ["PRETRAINED", "DEFAULT_PRETRAINED", "pretrained_path", "resolve_weights", "weights_config",
           "from_pretrained"]

# name -> (file inside cylindersplat/weights, what it is)
PRETRAINED: dict[str, tuple[str, str]] = {
    "tiny-synth": ("tiny_synth.safetensors",
                   "tiny model, 3-stage curriculum on procedural indoor/outdoor scenes at 64x128 (CPU-trained)"),
}
DEFAULT_PRETRAINED = "tiny-synth"


def pretrained_path(name: str = DEFAULT_PRETRAINED) -> Path:
    """The file of a shipped model; ``ValueError`` for an unknown name, ``FileNotFoundError`` when the
    installation lacks it (e.g. a source tree without the weights)."""
    if name not in PRETRAINED:
        raise ValueError(f"unknown pretrained model {name!r}; shipped: {', '.join(sorted(PRETRAINED))}")
    path = Path(str(resources.files("cylindersplat") / "weights" / PRETRAINED[name][0]))
    if not path.is_file():
        raise FileNotFoundError(f"the shipped weights {name!r} are missing from this installation ({path}); "
                                "reinstall cylindersplat or give --checkpoint")
    return path


def resolve_weights(name_or_path: str | Path = DEFAULT_PRETRAINED) -> Path:
    """The weights file of a shipped model's name (``"tiny-synth"``), a ``.safetensors`` file, or a folder
    holding ``model.safetensors`` (a training run's output or a downloaded hub repository); checked
    (missing, folder, pickle: a one-line error) without loading it."""
    if isinstance(name_or_path, str) and name_or_path in PRETRAINED:
        return pretrained_path(name_or_path)
    if not isinstance(name_or_path, (str, Path)) or not str(name_or_path):
        from ..errors import InputError

        raise InputError(f"weights must be a shipped model name ({', '.join(PRETRAINED)}), a .safetensors file "
                         f"or a run folder, got {name_or_path!r}")
    path = Path(name_or_path)
    if path.is_dir() and (path / "model.safetensors").is_file():
        path = path / "model.safetensors"
    else:
        path = _checkpoint_weights(path) or path
    check_weights_file(path)
    return path


def _checkpoint_weights(path: Path) -> Path | None:
    """The weights a training run's ``checkpoints/latest`` pointer names, for ``path`` = that pointer file, the
    ``checkpoints`` folder, or a run folder without final weights (an unfinished run); else None."""
    for pointer in (path, path / "latest", path / "checkpoints" / "latest"):
        if pointer.name == "latest" and pointer.is_file() and pointer.stat().st_size < 256:
            target = pointer.parent / pointer.read_text().strip() / "model.safetensors"
            if pointer != path:  # a folder was given: say which weights it stands for
                warnings.warn(f"{path} has no final model.safetensors: using its latest checkpoint {target}", Notice,
                              stacklevel=3)
            return target
    return None


def weights_config(name_or_path: str | Path = DEFAULT_PRETRAINED) -> ModelConfig:
    """The model config of :func:`resolve_weights`' file, without loading the weights."""
    return read_model_config(resolve_weights(name_or_path))


def from_pretrained(
    name_or_path: str | Path = DEFAULT_PRETRAINED, map_location: str | torch.device = "cpu"
) -> CylinderSplat:
    """The model of :func:`resolve_weights`' file."""
    return load_model(resolve_weights(name_or_path), map_location=map_location)
