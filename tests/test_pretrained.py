"""The shipped weights: found by name, loaded like any checkpoint, trained (not a placeholder), and used by
the commands when no --checkpoint is given."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data import SyntheticDataset
from cylindersplat.data.synth import profile_config, write_synthetic_dataset
from cylindersplat.evaluation import evaluate, model_method
from cylindersplat.metrics import DepthRange
from cylindersplat.model import from_config
from cylindersplat.model.pretrained import DEFAULT_PRETRAINED, PRETRAINED, from_pretrained, pretrained_path


def test_every_listed_model_ships_and_loads():
    for name in PRETRAINED:
        model = from_pretrained(name)
        assert model.config.name == "tiny" and model.mode == "both"
        assert all(torch.isfinite(p).all() for p in model.parameters())


def test_shipped_weights_have_the_tiny_sharp_recipes_model():
    """The shipped file is the tiny training preset's model (issue 23's recipe: surface colour, pixel clearing,
    rescaled priors, 8x32x16 cells), as scripts/train_pretrained.sh trains it, drawn with recipes/tiny_sharp (issue
    34: switches that change no parameter)."""
    from cylindersplat.training import load_config

    shipped = from_pretrained(DEFAULT_PRETRAINED).config
    assert shipped == load_config("recipes/tiny_sharp").model
    sharp = {"render_dilation": 0.0, "pixel.footprint": "surface", "pixel.footprint_px": 0.7,
             "fusion.pixel_footprint": "covisible",
             "pixel.opacity": "opaque", "pixel.refine_depth": "where_missing", "fusion.surface_clearance": 0.2,
             "fusion.pixel_clearing": "at_depth_edges", "render_pixel_blending": "surface"}
    assert load_config("tiny").model.replace(**sharp) == shipped


def test_the_shipped_weights_recipes_are_the_runs_settings():
    """scripts/train_pretrained.sh trains with two recipes (presets): the tiny preset's stages 1-2 at lr 2e-3, then
    its stage 3 at lr 5e-4 without the volume loss; they give exactly the settings the former shell arguments gave."""
    from cylindersplat.training import load_config
    from cylindersplat.training.config import config_as_dict

    runs = {"recipes/tiny_synth_stages12": ["train.stages=[1,2]", "train.steps_per_stage=[1200,400]", "train.lr=2e-3"],
            "recipes/tiny_synth_stage3": ["train.stages=[3]", "train.steps_per_stage=[400]", "train.lr=5e-4",
                                          "loss.volume_weight=0"]}
    for recipe, overrides in runs.items():
        assert config_as_dict(load_config(recipe)) == config_as_dict(load_config("tiny", overrides)), recipe
    script = (Path(__file__).resolve().parents[1] / "scripts" / "train_pretrained.sh").read_text()
    assert all(f"--config {recipe}" in script for recipe in runs)


def test_another_seed_leaves_the_shipped_weights_alone(tmp_path):
    """TRAIN_SEED=N trains the same recipe with another seed into OUT, never over the shipped file; a seed that is not
    a whole number is refused before anything is written."""
    import subprocess

    script = Path(__file__).resolve().parents[1] / "scripts" / "train_pretrained.sh"
    text = script.read_text()
    assert 'TARGET="$OUT/tiny_synth_seed$SEED.safetensors"' in text and '"train.seed=$SEED"' in text
    shipped = pretrained_path().read_bytes()
    done = subprocess.run(["bash", str(script), str(tmp_path / "out")], env={**os.environ, "TRAIN_SEED": "1x"},
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "TRAIN_SEED must be a whole number, got '1x'" in done.stderr
    assert not (tmp_path / "out").exists() and pretrained_path().read_bytes() == shipped


def test_from_pretrained_takes_a_file_or_a_run_folder(tmp_path):
    shutil.copy(pretrained_path(), tmp_path / "model.safetensors")
    a, b = from_pretrained(tmp_path), from_pretrained(tmp_path / "model.safetensors")
    for (name, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), name
    with pytest.raises(FileNotFoundError, match="weights file not found"):
        from_pretrained(tmp_path / "missing.safetensors")
    with pytest.raises(ValueError, match="folder"):
        from_pretrained(tmp_path.parent)


@pytest.mark.slow  # 56 s at load 10 (2 shared cores)
def test_shipped_weights_are_trained(tmp_path):
    """On scenes it never saw (another dataset seed), the shipped model renders far better than the same
    architecture untrained: the file holds the documented training run, not a placeholder."""
    write_synthetic_dataset(tmp_path, 2, (64, 128), profile_config("occlusion"), seed=7)
    dataset = SyntheticDataset(tmp_path, views="two_view")
    torch.manual_seed(0)
    # both drawn as the paper draws them: with the shipped drawing an untrained pixel branch is already a sharp warp
    paper = {"render_dilation": 0.3, "pixel.footprint": "learned", "pixel.opacity": "learned",
             "pixel.refine_depth": "everywhere", "fusion.surface_clearance": 0.0}
    shipped = from_pretrained(DEFAULT_PRETRAINED).with_config(**paper)
    methods = [model_method(shipped, "shipped"), model_method(from_config(shipped.config).eval(), "untrained")]
    means = evaluate(dataset, methods, depth_range=DepthRange(0.05, 1000.0), progress=False).means
    # An untrained pixel branch already splats the input pixels at the prior's depth (a forward warp, 18.8 dB
    # here); training adds 1.7 dB on the images and cuts the depth error (AbsRel) by 40 %.
    assert means["shipped"]["ws_psnr"] > means["untrained"]["ws_psnr"] + 1.0
    assert means["shipped"]["abs_rel"] < 0.75 * means["untrained"]["abs_rel"]


def test_render_and_export_default_to_the_shipped_weights(tmp_path, capsys, panorama_folder):
    out = tmp_path / "out"
    assert main(["export", "--input", str(panorama_folder[0]), "--out", str(out / "scene.ply"), "--resolution", "16x32",
                 "--device", "cpu"]) == 0
    assert f"using the shipped {DEFAULT_PRETRAINED} weights" in capsys.readouterr().out
    assert (out / "scene.ply").is_file()
    assert main(["export", "--input", str(panorama_folder[0]), "--checkpoint", "no-such-model", "--out",
                 str(out / "x.ply")]) == 1
    assert "weights file not found: no-such-model" in capsys.readouterr().err
