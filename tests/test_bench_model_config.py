"""`cylindersplat bench model --config`: model presets, and the model of a training preset or recipe (the shipped
weights' drawing), with a one-line error for a name that is neither."""

import argparse

import pytest

from cylindersplat.benchmarks.model import main, model_config, run_single
from cylindersplat.model import get_config
from cylindersplat.training import load_config


def test_presets_and_recipes_name_their_models():
    assert model_config("tiny_paper") == get_config("tiny_paper")
    shipped = model_config("recipes/tiny_sharp")
    assert shipped == load_config("recipes/tiny_sharp").model
    assert shipped.fusion.pixel_footprint == "covisible" and shipped.render_pixel_blending == "surface"


def test_an_unknown_config_is_one_line_naming_both_kinds(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--config", "nope"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1
    assert "'nope' is neither a model preset (paper, paper_cartesian, paper_spherical, tiny_paper)" in err


def test_a_recipe_runs():
    args = argparse.Namespace(device="cpu", config="recipes/tiny_sharp", mode="both", views=2, height=16, render=False,
                              amp="off", warmup=0, repeats=1)
    result = run_single(args)
    assert result["gaussians"] > 2 * 16 * 32 and result["median_s"] > 0


@pytest.mark.parametrize("device, message", [("tpu", "not a torch device: 'tpu'"),
                                             ("cuda:7", "cuda:7")])
def test_a_device_that_is_not_there_is_one_line(device, message, capsys):
    # (it was a traceback from the timed subprocess; 'cuda:7' is refused with or without a GPU here)
    with pytest.raises(SystemExit) as stop:
        main(["--device", device])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and message in err and len(err.splitlines()) == 1, err
