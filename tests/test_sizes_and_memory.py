"""eval/render pick the model's resolution by default and say so; memory refusals name the option that fixes them;
views are rendered in batches that fit (automatic, or --view-batch)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.gaussians import save_ply
from cylindersplat.inference.pipeline import iter_views
from cylindersplat.render import Equirect, rasterize, render
from cylindersplat.scenes import demo_room
from cylindersplat.utils.notices import Notice


def _memory_for(monkeypatch, cameras: int) -> list[int]:
    """The renderer's memory check passes for up to ``cameras`` views at once and refuses more; returns the sizes
    of the batches it was asked for."""
    asked: list[int] = []

    def check(num_fragments, device, cameras_at_once=1):
        asked.append(cameras_at_once)
        if cameras_at_once > cameras:
            raise rasterize.RenderMemoryError(num_fragments * 400, 1000, num_fragments, cameras_at_once, device)

    monkeypatch.setattr(rasterize, "check_fragment_memory", check)  # the PyTorch reference's check
    monkeypatch.setattr(rasterize, "check_pair_memory", check)  # the numba CPU backend's
    return asked


def _poses(count: int) -> torch.Tensor:
    poses = torch.eye(4).repeat(count, 1, 1)
    poses[:, 0, 3] = torch.linspace(-0.5, 0.5, count)
    return poses


def test_views_are_batched_to_fit_memory(monkeypatch):
    scene, poses = demo_room(4.0), _poses(3)
    reference = render(scene, poses, Equirect(8, 16))  # all at once, memory unchecked
    asked = _memory_for(monkeypatch, 1)
    with pytest.warns(Notice, match="1 view\\(s\\) at a time to fit in free memory"):
        parts = list(iter_views(scene, poses, 8, 16))
    assert asked == [3, 1, 1, 1] and [len(p.rgb) for p in parts] == [1, 1, 1]
    torch.testing.assert_close(torch.cat([p.rgb for p in parts]), reference.rgb, atol=1e-5, rtol=0)
    with pytest.raises(rasterize.RenderMemoryError, match="3 view\\(s\\) at once"):  # a fixed batch is kept
        list(iter_views(scene, poses, 8, 16, chunk=3))


@pytest.fixture()
def ply_and_views(tmp_path):
    ply = save_ply(demo_room(4.0), tmp_path / "room.ply")
    (tmp_path / "views.json").write_text(json.dumps({"poses": _poses(3).tolist()}))
    return ply, tmp_path / "views.json"


def test_render_ply_batches_views_and_names_the_options(ply_and_views, tmp_path, monkeypatch, capsys):
    ply, views = ply_and_views
    common = ["render", "--ply", str(ply), "--views", str(views), "--output-resolution", "8x16", "--frames", "0"]
    _memory_for(monkeypatch, 1)
    assert main([*common, "--out", str(tmp_path / "auto")]) == 0  # before: refused, "fewer cameras at once"
    assert len(list((tmp_path / "auto" / "views").glob("view_*_rgb.png"))) == 3
    assert "cylindersplat render: note: novel views: 1 view(s) at a time" in capsys.readouterr().err
    assert main([*common, "--view-batch", "3", "--out", str(tmp_path / "fixed")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "of 3 view(s) at once needs about" in err[0] and "use --view-batch 1" in err[0], err
    _memory_for(monkeypatch, 0)
    assert main([*common, "--out", str(tmp_path / "none")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "1 view(s) at once" in err[0] and "a smaller --output-resolution" in err[0], err
    with pytest.raises(SystemExit):
        main([*common, "--view-batch", "0"])


def test_eval_uses_the_models_resolution_and_names_the_option(synth_dataset, tiny_checkpoint, tmp_path, monkeypatch,
                                                              capsys):
    data = synth_dataset(2, seed=7)  # stored at 32x64; the tiny model's own size is 64x128
    common = ["eval", "--data", str(data), "--checkpoint", str(tiny_checkpoint), "--no-baseline", "--lpips", "off",
              "--max-examples", "1", "--pictures", "1"]
    assert main([*common, "--out", str(tmp_path / "e")]) == 0
    said = capsys.readouterr().out
    assert "running the model at 64x128, its own resolution (--resolution HxW to choose another)" in said
    (picture,) = (tmp_path / "e" / "examples" / "two_view").glob("*.png")
    assert np.asarray(Image.open(picture)).shape[1] == 2 * 128 + 4  # RGB | depth columns of 128 pixels
    _memory_for(monkeypatch, 0)
    assert main([*common, "--out", str(tmp_path / "f")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and "use a smaller --resolution" in err[0], err
