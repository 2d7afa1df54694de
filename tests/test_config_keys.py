"""Issue 36 item 4: one dotted-path writer (``model.config.set_dotted``) behind presets' recipes, KEY=VALUE
overrides, typed changes and ``ModelConfig.replace``; the training run's string choices in the one choice table."""

from __future__ import annotations

import dataclasses
import typing

import pytest

from cylindersplat.model.config import (
    CHOICES,
    FusionConfig,
    ModelConfig,
    UnknownConfigKey,
    VolumeBranchConfig,
    get_config,
    get_dotted,
    set_dotted,
)
from cylindersplat.training.config import ExperimentConfig, load_config, nest_changes, parse_overrides


def test_set_dotted_builds_nested_dicts():
    tree: dict = {"train": {"lr": 1.0}}
    set_dotted(tree, "train.stages", [3])
    set_dotted(tree, "model.volume.grid", [8, 32, 16])
    set_dotted(tree, "name", "x")
    assert tree == {"train": {"lr": 1.0, "stages": [3]}, "model": {"volume": {"grid": [8, 32, 16]}}, "name": "x"}
    assert get_dotted(tree, "model.volume.grid") == [8, 32, 16]


def test_dict_writers_agree_with_set_dotted():
    """Overrides (values read as YAML) and typed changes (values as given) nest the same way."""
    from pathlib import Path

    expected = {"train": {"lr": 0.0003, "stages": [1, 2]}, "model": {"volume": {"init": "isolated"}}}
    assert parse_overrides(["train.lr=3e-4", " train.stages=[1, 2]", "model.volume.init=isolated"]) == {
        "train": {"lr": "3e-4", "stages": [1, 2]}, "model": {"volume": {"init": "isolated"}}}  # YAML 1.1: a string
    assert nest_changes({"train.lr": 3e-4, "train.stages": [1, 2], "model.volume.init": "isolated"}) == expected
    assert nest_changes({"data.root": Path("a/b")}) == {"data": {"root": "a/b"}}


@pytest.mark.parametrize("write", [lambda: parse_overrides(["train.lr=1", "train.lr.x=2"]),
                                   lambda: nest_changes({"train.lr": 1, "train.lr.x": 2})])
def test_a_key_below_a_value_is_refused(write):
    with pytest.raises(ValueError, match=r"'train.lr.x' conflicts with another (override|change): train.lr is"):
        write()


@pytest.mark.parametrize("key", ["a..b", ".a", "a.", ""])
def test_empty_names_are_refused(key):
    with pytest.raises(ValueError, match="a dotted key needs a name"):
        set_dotted({}, key, 1)


def test_set_dotted_on_a_config_writes_the_field():
    cfg = ModelConfig()
    set_dotted(cfg, "volume.grid", (8, 32, 16))
    set_dotted(cfg, "render_dilation", 0.0)
    assert cfg == ModelConfig(volume=VolumeBranchConfig(grid=(8, 32, 16)), render_dilation=0.0)
    assert get_dotted(cfg, "volume.grid") == (8, 32, 16)


def test_replace_copies_and_goes_through_the_writer():
    base = get_config("tiny_paper")
    changed = base.replace(**{"fusion.side": "hidden", "fusion.sigma": 0.2, "mode": "pixel"})
    expected = dataclasses.replace(base, mode="pixel", fusion=FusionConfig(side="hidden", sigma=0.2))
    assert changed == expected and base == get_config("tiny_paper")  # the original is untouched


@pytest.mark.parametrize("key,section,valid", [
    ("volume.gridd", "volume", "coordinates, radius, height, grid, "),
    ("volum.grid", "ModelConfig", "name, image_height, image_width, mode, "),
    ("backbone.token_stride", "backbone", "in_channels, stem_width, widths, blocks, groups"),  # a property
])
def test_unknown_config_field_names_the_key_and_the_valid_ones(key, section, valid):
    with pytest.raises(UnknownConfigKey) as caught:
        get_config("tiny_paper").replace(**{key: 1})
    message = str(caught.value)
    part = key.split(".")[1 if section != "ModelConfig" else 0]
    assert message.startswith(f"unknown config field {key!r}: {section} has no {part!r}; valid: {valid}")
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, AttributeError)


def test_a_field_below_a_value_is_refused_on_a_config():
    with pytest.raises(ValueError, match=r"'volume.grid.x': volume.grid is the value \(4, 16, 8\), not a section"):
        get_config("tiny_paper").replace(**{"volume.grid.x": 1})


# -- the one choice table --------------------------------------------------------------------------------------

TRAINING_CHOICES = [key for key in CHOICES if key.split(".")[0] in ("train", "loss", "data")]


def test_the_training_choices_are_in_the_table():
    assert set(TRAINING_CHOICES) == {"train.amp", "train.stage2_render", "train.render_drawing", "loss.use_lpips",
                                     "loss.volume_loss", "loss.pixel_stage_hidden", "data.augment"}


@pytest.mark.parametrize("key", TRAINING_CHOICES)
def test_a_wrong_training_choice_names_the_valid_ones(key):
    allowed = ", ".join(CHOICES[key])
    with pytest.raises(ValueError, match=f"^{key} must be one of {allowed}; got 'nonsense'$"):
        load_config("tiny", [f"{key}=nonsense"])
    for value in CHOICES[key]:  # and every listed one is taken
        assert get_dotted(load_config("tiny", changes={key: value}), key) == value


def test_every_literal_of_the_configs_is_a_table_entry():
    """Each string ``Literal`` field of the experiment config (model, train, loss, data, eval) has its
    choices in the table, equal, so a preset, an override and ``ModelConfig.validate`` all say the same."""

    def literals(obj, prefix):
        hints = typing.get_type_hints(type(obj))
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                yield from literals(value, f"{prefix}{f.name}.")
            elif typing.get_origin(hints[f.name]) is typing.Literal:
                yield f"{prefix}{f.name}", typing.get_args(hints[f.name])

    found = dict(literals(ExperimentConfig(), ""))
    assert {"train.amp", "train.stage2_render", "loss.use_lpips", "model.volume.color"} <= set(found)
    for key, allowed in found.items():
        assert CHOICES[key.removeprefix("model.")] == allowed, key


def test_the_registries_agree_with_the_table():
    from cylindersplat.model.curriculum import STAGE2_RENDERS
    from cylindersplat.training.loss_terms.volume import VOLUME_LOSS_MODES

    assert tuple(VOLUME_LOSS_MODES) == CHOICES["loss.volume_loss"]
    assert STAGE2_RENDERS == CHOICES["train.stage2_render"]


# -- the two tiny models ---------------------------------------------------------------------------------------

def test_the_two_tiny_models_have_distinct_names():
    """``tiny_paper`` (the paper's choices at tiny sizes, what the tests build) and ``tiny``, the training preset's
    model, which the shipped weights' stored config names (tests/test_pretrained.py: the same fields)."""
    from cylindersplat.model.checkpoint import read_model_config
    from cylindersplat.model.pretrained import pretrained_path

    small, trained = get_config("tiny_paper"), load_config("tiny").model
    assert (small.name, trained.name) == ("tiny_paper", "tiny")
    assert small.volume.grid == (4, 16, 8) and trained.volume.grid == (8, 32, 16)
    assert (small.volume.color, trained.volume.color) == ("retrieval", "surface")
    model_choices = [key for key in CHOICES if key not in TRAINING_CHOICES]
    assert all(get_dotted(small, key) == get_dotted(get_config("paper"), key) for key in model_choices)
    assert {key for key in model_choices if get_dotted(trained, key) != get_dotted(small, key)} == {
        "prior_alignment", "volume.color", "fusion.strategy", "fusion.side", "fusion.pixel_clearing"}
    assert read_model_config(pretrained_path()).name == "tiny"


def test_the_old_model_preset_name_still_works_with_a_warning():
    with pytest.warns(FutureWarning, match="model preset 'tiny' is now 'tiny_paper'") as caught:
        old = get_config("tiny", **{"volume.init": "isolated"})
    assert old == get_config("tiny_paper", **{"volume.init": "isolated"})
    assert caught[0].filename == __file__  # it points at the caller's line
    with pytest.warns(FutureWarning, match="'tiny_paper'"):
        assert load_config(None, ["model.preset=tiny"]).model == get_config("tiny_paper")


def test_no_other_module_splits_dotted_keys():
    """The one writer stays one: no module under src/ but model/config.py splits keys on dots (metrics/lpips.py
    reads a checkpoint's parameter names, not settings)."""
    from pathlib import Path

    import cylindersplat

    package = Path(cylindersplat.__file__).parent
    found = sorted(str(path.relative_to(package)) for path in package.rglob("*.py")
                   if '.split(".")' in path.read_text())
    assert found == ["metrics/lpips.py", "model/config.py"]


@pytest.mark.parametrize("device", ["tpu", "cuda:x", "gpu", "cpu:0:1"])
def test_a_device_torch_does_not_know_is_refused_when_the_config_loads(device):
    # (torch.device raised a traceback from the trainer's setup; the command line shows this message in one line)
    with pytest.raises(ValueError, match=f"^train.device must be auto, cpu, cuda or cuda:N; got '{device}'$"):
        load_config("tiny", [f"train.device={device}"])
    for good in ("auto", "cpu", "cuda", "cuda:1"):  # a missing GPU is the command's check, not the config's
        assert load_config("tiny", [f"train.device={good}"]).train.device == good
