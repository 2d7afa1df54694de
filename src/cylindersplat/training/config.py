"""Typed experiment configuration: YAML presets + ``key=value`` overrides.

One mechanism for every experiment: a preset (``cylindersplat/configs/<name>.yaml`` or any YAML path) is read into
a nested dict, each ``dotted.key=value`` override is written into that dict (values parsed as YAML,
so ``train.lr=3e-4``, ``train.stages=[3]``, ``model.volume.init=isolated`` all work), and the
result is turned into :class:`ExperimentConfig`. Unknown keys are errors (typos must not be
silently ignored). The model section names a preset of :mod:`cylindersplat.model.config` plus
field changes: ``model: {preset: tiny_paper, attention: {depth: 4}}``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from ..data.augment import CaptureAugment
from ..data.datasets import check_reference_spec
from ..dataset_layouts import DATASET_SPECS
from ..model.config import CHOICES, ModelConfig, config_to_dict, get_config, set_dotted
from .losses import LossConfig

__all__ = [
    "DataConfig",
    "TrainConfig",
    "EvalConfig",
    "ExperimentConfig",
    "CONFIG_DIR",
    "available_presets",
    "load_config",
    "parse_overrides",
    "config_as_dict",
    "config_from_dict",
]

# YAML presets ship inside the package (cylindersplat/configs/*.yaml).
CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


@dataclass
class DataConfig:
    format: str = "synthetic"  # a layout of the dataset registry (cylindersplat.dataset_layouts)
    root: str | None = None  # dataset folder (see docs/data.md)
    resolution: tuple[int, int] | None = None  # (H, W) resize on load; None = stored size
    split: str = "train"  # pano_grf / loc360 split
    views: str = "two_view"  # protocol of cylindersplat.data.select_views
    # The model's input prior: "default" (the dataset's own: simulated for synthetic data, else an error asking for a
    # choice), file:NAME (from `cylindersplat data priors`), simulated, gt, constant:M, none, or a network spec
    # (unik3d:DIR, exported:NET.pt2, depth_anything_v2:MODEL)
    depth_prior: str = "default"
    options: dict[str, Any] = field(default_factory=dict)  # extra loader kwargs, e.g. {dist: 1.0}
    # false: read frames outside the plausibility bounds (depth median 1 cm-1 km, cameras within 10 km)
    check_plausibility: bool = True
    batch_size: int = 1  # per process
    num_workers: int = 0
    # Training samples that look like captures (cylindersplat.data.augment; never applied to evaluation): "captures"
    # gives each context view its own exposure, white balance, sensor noise, JPEG and a small pose error (the targets
    # stay clean); data.captures.* sets the magnitudes (docs/training.md, "Capture-like training data")
    augment: Literal["none", "captures"] = "none"
    captures: CaptureAugment = field(default_factory=CaptureAugment)


@dataclass
class TrainConfig:
    stages: tuple[int, ...] = (1, 2, 3)  # curriculum stages run in order (1 pixel, 2 volume, 3 joint)
    steps_per_stage: tuple[int, ...] = (1000, 1000, 1000)  # one entry per stage in `stages`, or one for all
    epochs_per_stage: float | None = None  # if set, overrides steps_per_stage (paper: 10 epochs)
    lr: float = 1e-4
    weight_decay: float = 0.01
    betas: tuple[float, float] = (0.9, 0.999)
    warmup_steps: int = 0  # linear warm-up before the cosine decay
    min_lr_ratio: float = 0.0  # cosine decays to lr * min_lr_ratio
    grad_clip: float = 1.0  # max global grad norm; 0 disables
    max_nonfinite_steps: int = 20  # consecutive skipped (NaN/inf loss or grads) steps before giving up; 0 = never
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    amp: Literal["auto", "bf16", "off"] = "auto"  # auto: bf16 network forward on CUDA, fp32 on CPU
    device: str = "auto"  # auto: cuda when available
    # Stage 2 renders the volume Gaussians alone ("volume", the paper) or together with the frozen pixel
    # branch's ("fused"): then the volume branch is supervised only where the pixel branch leaves errors.
    stage2_render: Literal["volume", "fused"] = "volume"
    # How training draws the targets: "one_pass" (the paper: every Gaussian in one depth-sorted pass) or "model"
    # (the drawing eval and render use, from the model's render_layering / render_pixel_blending: the pixel
    # Gaussians as a front layer, blended by surface splatting, the volume behind), so that the volume branch is
    # supervised only where it shows at inference (issue 34). "model" costs two more renders per step with blending.
    render_drawing: Literal["one_pass", "model"] = "one_pass"
    volume_lr_scale: float = 1.0  # volume-branch learning rate = lr x this (a per-branch rate for the joint stage)
    render_backend: str = "auto"  # render_equirect backend: auto, torch (reference) or triton
    seed: int = 0
    log_every: int = 10
    image_every: int = 100  # steps between logged image grids (render | target, rgb and depth); 0 = never
    init: str | None = None  # model.safetensors to start from (fine-tuning); ignored when resuming
    checkpoint_every: int = 500  # steps; a checkpoint is also written at the end of every stage
    keep_checkpoints: int = 3  # older step checkpoints are deleted (0 keeps all)
    tensorboard: bool = True  # used only if the tensorboard package is importable
    progress: bool = True  # a tqdm bar on a terminal; ten lines per stage in a log file or pipe


@dataclass
class EvalConfig:
    # Reference depth of the PCC column (`cylindersplat eval --config PRESET` / --pcc-reference): gt (the dataset's
    # ground truth) or file:NAME (e.g. file:depth_anywhere, the paper's reference, from `cylindersplat data priors`)
    pcc_reference: str = "gt"


@dataclass
class ExperimentConfig:
    name: str = "experiment"
    output_dir: str = "outputs/train"
    model: ModelConfig = field(default_factory=lambda: get_config("tiny_paper"))
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def steps_for(self, stage: int, batches_per_epoch: int | None = None) -> int:
        """Optimizer steps of curriculum ``stage``."""
        if self.train.epochs_per_stage is not None:
            if not batches_per_epoch:
                raise ValueError("train.epochs_per_stage needs a non-empty dataset")
            return max(1, round(self.train.epochs_per_stage * batches_per_epoch))
        steps = self.train.steps_per_stage
        if len(steps) == 1:
            return int(steps[0])
        if len(steps) != len(self.train.stages):
            raise ValueError(f"train.steps_per_stage {steps} needs one entry per stage in {self.train.stages} (or one)")
        return int(steps[list(self.train.stages).index(stage)])


def available_presets() -> list[str]:
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")) if CONFIG_DIR.is_dir() else []


def _read_preset(preset: str | Path, _bases: tuple[str, ...] = ()) -> dict[str, Any]:
    """A preset's nested dict. A recipe (``configs/recipes/*.yaml``: ``base: PRESET`` and ``changes:`` of dotted
    keys) is its base preset with those changes, so ``--config recipes/tiny_earlier`` trains it."""
    path = Path(preset)
    if not path.suffix:
        path = CONFIG_DIR / f"{preset}.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"config {preset!r} not found (presets: {available_presets()}; or give a YAML path)")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: malformed YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: top level must be a mapping")
    if "base" in data:  # a recipe: a change set on another preset
        base, changes = str(data.pop("base")), data.pop("changes", None) or {}
        if base in _bases or not isinstance(changes, dict):
            raise ValueError(f"{path}: a recipe needs a base preset other than itself and a mapping of changes")
        data = _merge(_merge(_read_preset(base, (*_bases, base)), nest_changes(changes)), data)
    return data


def parse_overrides(overrides: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``["train.lr=3e-4", "model.preset=paper"]`` -> nested dict (values parsed as YAML)."""
    nested: dict[str, Any] = {}
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"override {item!r} must look like section.key=value")
        try:
            value = yaml.safe_load(raw) if raw.strip() else None
        except yaml.YAMLError:
            raise ValueError(f"override {item!r}: the value is not valid YAML") from None
        set_dotted(nested, key.strip(), value, what="override")
    return nested


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _coerce(value: Any, current: Any, where: str) -> Any:
    """Match YAML scalars/lists to the type of the field's current value."""
    if value is None:
        return None
    if isinstance(current, str) and isinstance(value, bool):
        return "on" if value else "off"  # YAML 1.1 reads on/off as booleans
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true/false, got {value!r}")
        return value
    if isinstance(current, float) and isinstance(value, str):
        try:  # YAML 1.1 reads "1e-4" (no dot) as a string
            number = float(value)
        except ValueError:
            raise ValueError(f"{where} must be a number, got {value!r}") from None
        if not math.isfinite(number):
            raise ValueError(f"{where} must be a finite number, got {value!r}")
        return number
    if isinstance(current, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ValueError(f"{where} must be a finite number, got {value!r}")
        return float(value)
    if isinstance(current, int) and isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(current, int) and (isinstance(value, bool) or not isinstance(value, int)):
        raise ValueError(f"{where} must be an integer, got {value!r}")
    if isinstance(current, float) and not isinstance(value, (int, float)):
        raise ValueError(f"{where} must be a number, got {value!r}")
    if isinstance(current, tuple) and not isinstance(value, (list, tuple)):
        raise ValueError(f"{where} must be a list like [1, 2], got {value!r}")
    if isinstance(current, tuple) and current:  # elements of the defaults' kind: [abc] is not a list of counts
        kind = type(current[0])
        if kind in (int, float) and not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise ValueError(f"{where} must be a list of numbers like {list(current)}, got {value!r}")
        if kind is int and not all(float(v).is_integer() for v in value):
            raise ValueError(f"{where} must be a list of whole numbers like {list(current)}, got {value!r}")
        if kind is int:
            value = [int(v) for v in value]
        if kind is float and not all(math.isfinite(v) for v in value):
            raise ValueError(f"{where} must be a list of finite numbers, got {value!r}")
    if isinstance(current, str) and not isinstance(value, str):
        raise ValueError(f"{where} must be a string, got {value!r}")
    if isinstance(value, list):
        return tuple(value)
    return value


def _update(obj: Any, values: dict[str, Any], prefix: str) -> None:
    names = {f.name for f in dataclasses.fields(obj)}
    for key, value in values.items():
        where = f"{prefix}{key}"
        if key not in names:
            raise ValueError(_unknown_key(where, names))
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ValueError(f"{where} is a section; set its fields, e.g. {where}.<field>=...")
            _update(current, value, f"{where}.")
        else:
            setattr(obj, key, _check_choice(_coerce(value, current, where), where))


def _check_choice(value: Any, where: str) -> Any:
    """``value`` if the key has no named choices or is one of them: the model's and the training run's string choices
    are one table, :data:`~cylindersplat.model.config.CHOICES` (``model.volume.color`` is its ``volume.color``)."""
    choices = CHOICES.get(where.removeprefix("model."), ())
    if choices and value not in choices:
        raise ValueError(f"{where} must be one of {', '.join(map(str, choices))}; got {value!r}")
    return value


def _all_keys(obj: Any, prefix: str = "") -> list[str]:
    """Every dotted key of a config (sections included), e.g. ``train.epochs_per_stage``."""
    keys = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        keys.append(f"{prefix}{f.name}")
        if dataclasses.is_dataclass(value):
            keys += _all_keys(value, f"{prefix}{f.name}.")
    return keys


def _unknown_key(where: str, names: set[str]) -> str:
    """One line for a key that is not in the config: the close names anywhere in it, else the section's keys."""
    every = _all_keys(ExperimentConfig())
    last = where.rsplit(".", 1)[-1]
    close = [k for k in every if k.rsplit(".", 1)[-1] == last]  # the right name in another section
    close += [k for k in difflib.get_close_matches(where, every, n=3, cutoff=0.75) if k not in close]
    if close:
        return f"unknown config key {where!r}; did you mean {' or '.join(close[:3])}?"
    return f"unknown config key {where!r}; known: {sorted(names)}"


def _from_dict(data: dict[str, Any]) -> ExperimentConfig:
    data = dict(data)
    model_data = dict(data.pop("model", None) or {})
    cfg = ExperimentConfig(model=get_config(model_data.pop("preset", "tiny_paper")))
    _update(cfg.model, model_data, "model.")
    _update(cfg, data, "")
    if cfg.data.resolution is not None:
        cfg.data.resolution = tuple(int(x) for x in cfg.data.resolution)
    bad = [s for s in cfg.train.stages if s not in (1, 2, 3)]
    if bad or not cfg.train.stages:
        raise ValueError(f"train.stages must be a non-empty list of 1, 2, 3; got {cfg.train.stages}")
    if cfg.data.format not in DATASET_SPECS:  # the registry's layouts (a dataset added there is trainable)
        raise ValueError(f"data.format must be one of {', '.join(DATASET_SPECS)}; got {cfg.data.format!r}")
    check_reference_spec(cfg.loss.depth_reference, "loss.depth_reference")
    check_reference_spec(cfg.eval.pcc_reference, "eval.pcc_reference", allowed=("gt",))
    if cfg.loss.occluded_weight < 0:
        raise ValueError(f"loss.occluded_weight must be >= 0, got {cfg.loss.occluded_weight}")
    if cfg.loss.volume_weight < 0:
        raise ValueError(f"loss.volume_weight must be >= 0, got {cfg.loss.volume_weight}")
    if not cfg.train.volume_lr_scale > 0:
        raise ValueError(f"train.volume_lr_scale must be > 0, got {cfg.train.volume_lr_scale}")
    cfg.data.captures.validate()
    if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", str(cfg.train.device)):  # (torch.device would say so mid-setup)
        raise ValueError(f"train.device must be auto, cpu, cuda or cuda:N; got {cfg.train.device!r}")
    if cfg.train.max_nonfinite_steps < 0:
        raise ValueError("train.max_nonfinite_steps must be >= 0 (0 = never give up), got "
                         f"{cfg.train.max_nonfinite_steps}")
    t, d = cfg.train, cfg.data
    limits = [
        ("data.batch_size", d.batch_size, 1), ("data.num_workers", d.num_workers, 0),
        ("train.log_every", t.log_every, 1),
        ("train.checkpoint_every", t.checkpoint_every, 1), ("train.keep_checkpoints", t.keep_checkpoints, 0),
        ("train.image_every", t.image_every, 0), ("train.warmup_steps", t.warmup_steps, 0),
    ] + [("train.steps_per_stage", n, 0) for n in t.steps_per_stage]
    for name, value, low in limits:
        if value < low:
            raise ValueError(f"{name} must be >= {low}, got {value}")
    if not t.lr > 0 or t.grad_clip < 0 or t.weight_decay < 0:
        raise ValueError(f"train.lr must be > 0 and train.grad_clip, train.weight_decay >= 0 "
                         f"(got {t.lr}, {t.grad_clip}, {t.weight_decay})")
    _check_ranges(cfg)
    return cfg



def _check_ranges(cfg: ExperimentConfig) -> None:
    """Ranges the types alone do not give: loss weights >= 0, epochs > 0, a 2:1 resolution,
    a model whose sizes are positive (:meth:`ModelConfig.validate`)."""
    for f in dataclasses.fields(cfg.loss):
        value = getattr(cfg.loss, f.name)
        if isinstance(value, float) and value < 0:  # every number of the loss is a weight or a margin
            raise ValueError(f"loss.{f.name} must be >= 0, got {value:g}")
    epochs = cfg.train.epochs_per_stage
    if epochs is not None and (isinstance(epochs, bool) or not isinstance(epochs, (int, float)) or not epochs > 0):
        raise ValueError("train.epochs_per_stage must be a number > 0 (or null to use steps_per_stage), got "
                         f"{epochs!r}")
    size = cfg.data.resolution
    if size is not None and (len(size) != 2 or size[1] != 2 * size[0] or size[0] < 8):
        raise ValueError(f"data.resolution must be [H, W] with W == 2H and H >= 8, e.g. [128, 256]; got {list(size)}")
    cfg.model.validate()


def nest_changes(changes: dict[str, Any]) -> dict[str, Any]:
    """``{"train.lr": 3e-4, "data.root": path}`` -> nested dict (values as given: Paths become strings)."""
    nested: dict[str, Any] = {}
    for key, value in changes.items():
        set_dotted(nested, key, str(value) if isinstance(value, Path) else value, what="change")
    return nested


def load_config(preset: str | Path | None = None, overrides: list[str] | tuple[str, ...] = (),
                changes: dict[str, Any] | None = None) -> ExperimentConfig:
    """Preset name (``cylindersplat/configs/<name>.yaml``), YAML path or None (defaults), then the
    command line's ``key=value`` ``overrides``, then ``changes`` from code (``{"train.lr": 3e-4}``, Python
    values). All three merge into one nested dict that is type-checked and validated the same way."""
    data = _read_preset(preset) if preset is not None else {}
    data = _merge(data, parse_overrides(overrides))
    return _from_dict(_merge(data, nest_changes(changes or {})))


def config_from_dict(data: dict[str, Any], overrides: list[str] | tuple[str, ...] = (),
                     changes: dict[str, Any] | None = None) -> ExperimentConfig:
    """A config saved with :func:`config_as_dict` (a run's ``config.yaml``), then ``key=value`` ``overrides``, then
    ``changes`` from code (Python values, as :func:`load_config` takes them)."""
    return _from_dict(_merge(_merge(data, parse_overrides(overrides)), nest_changes(changes or {})))


def config_as_dict(cfg: ExperimentConfig) -> dict[str, Any]:
    """Plain dict (YAML/JSON-safe) that :func:`load_config` turns back into an equal config."""
    out = dataclasses.asdict(cfg)
    out["model"] = config_to_dict(cfg.model)  # every field explicit, so the base preset is irrelevant

    def plain(x):
        if isinstance(x, dict):
            return {k: plain(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [plain(v) for v in x]
        return x

    return plain(out)
