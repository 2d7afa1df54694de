"""The main job end to end at toy size, its reuse of a trained checkpoint, and the bench command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.gaussians import load_ply
from cylindersplat.scenes import demo_room
from cylindersplat.utils.picture_grid import LABEL_HEIGHT

# the model, its pixel branch and the forward warp, the last two also with each trivial fill behind
DEMO_ROWS = {"CylinderSplat (tiny)", "its pixel branch alone", "its pixel branch alone + mean fill",
             "its pixel branch alone + inpaint fill", "Forward warp", "Forward warp + mean fill",
             "Forward warp + inpaint fill"}


@pytest.mark.slow  # 141 s at load 4.5 (2 shared cores)
def test_demo_end_to_end_and_reuse(tmp_path, capsys):
    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--scenes", "3", "--held-out", "1", "--resolution", "16x32",
            "--steps", "3,2,2", "--frames", "3", "--train"]
    assert main(args) == 0
    for name in ("comparison.png", "novel_view_rgb.png", "novel_view_depth.png", "flythrough.gif",
                 "gaussians.ply", "results.md", "results.json", "input/poses.json", "train/model.safetensors"):
        assert (out / name).is_file(), name
    table = (out / "results.md").read_text()
    assert "| CylinderSplat (tiny) |" in table and "| Forward warp |" in table
    means = next(iter(json.loads((out / "results.json").read_text())["means"].values()))
    assert set(means) == DEMO_ROWS
    assert all(m["lrce"] is not None and m["lrce"] >= 0 for m in means.values())  # the depth LRCE, vs the truth
    assert "Background where a render covers no pixel: black (CylinderSplat (tiny), its pixel branch alone" in table
    # comparison: 3 rows (ground truth, ours, baseline) x (RGB | depth), each with its caption, titles on top, at 2x
    assert Image.open(out / "comparison.png").size == (2 * (2 * 32 + 4),
                                                       2 * (LABEL_HEIGHT + 3 * (4 + LABEL_HEIGHT + 16)))
    assert Image.open(out / "flythrough.gif").n_frames == 3
    assert len(load_ply(out / "gaussians.ply")) > 0
    assert "training the tiny model" in capsys.readouterr().out
    # A second run reuses the trained weights instead of training again.
    assert main(args) == 0
    assert "reusing" in capsys.readouterr().out


@pytest.mark.slow  # 19 s at load 4.5 (2 shared cores)
def test_demo_uses_the_shipped_weights_by_default(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--scenes", "2", "--held-out", "1", "--resolution", "16x32", "--frames",
                 "0"]) == 0
    printed = capsys.readouterr().out
    assert "using the shipped tiny-synth weights" in printed and "training the tiny model" not in printed
    assert not (out / "train").exists()
    means = next(iter(json.loads((out / "results.json").read_text())["means"].values()))
    assert set(means) == DEMO_ROWS


def test_demo_rejects_bad_options(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--scenes", "2", "--held-out", "2"]) == 1
    assert "held-out" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path), "--scenes", "2", "--held-out", "1", "--resolution", "16x32",
                 "--steps", "5"]) == 1
    assert "--steps" in capsys.readouterr().err


def test_demo_room(tmp_path):
    assert main(["demo", "--room", "--out", str(tmp_path)]) == 0
    rgb = np.asarray(Image.open(tmp_path / "room_rgb_00.png"))
    assert rgb.shape == (256, 512, 3)
    # The room fills the view: hardly any white background shows, and the walls are not one flat colour.
    assert (rgb == 255).all(-1).mean() < 0.05 and rgb.std() > 10
    depth = np.asarray(Image.open(tmp_path / "room_depth_00.png"))
    assert depth.shape == (256, 512, 3) and len(np.unique(depth.reshape(-1, 3), axis=0)) > 20
    assert len(load_ply(tmp_path / "demo_room.ply")) == len(demo_room())


def test_bench_command(capsys):
    assert main(["bench", "synth", "--scenes", "1", "--resolution", "16x32", "--threads", "1", "--repeats", "1"]) == 0
    assert "pano" in capsys.readouterr().out.lower()
