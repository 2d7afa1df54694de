"""`render --ply` reads every splat format `view` reads, through the one loader (`load_gaussians`)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.gaussians import Gaussians, load_gaussians, save_ply, save_splat
from cylindersplat.gaussians.formats import SPLAT_TRANSFORM_ENV
from cylindersplat.inference.pipeline import render_views
from cylindersplat.scenes import demo_room


def _scene(n: int = 200, seed: int = 3) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians.from_rgb(torch.rand(n, 3, generator=g) * 4 - 2, torch.rand(n, 3, generator=g) * 0.05 + 0.01,
                              torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
                              torch.rand(n, generator=g), torch.rand(n, 3, generator=g))


def test_splat_files_read_back_within_their_quantisation(tmp_path):
    g = _scene()
    back = load_gaussians(save_splat(g, tmp_path / "s.splat"))
    order = torch.argsort(-(g.opacities * g.scales.prod(dim=-1)), stable=True)  # the writer's order
    torch.testing.assert_close(back.means, g.means[order], atol=0, rtol=0)
    torch.testing.assert_close(back.scales, g.scales[order], atol=0, rtol=0)
    assert (back.rgb - g.rgb[order]).abs().max() <= 0.5 / 255 + 1e-6
    assert (back.opacities - g.opacities[order]).abs().max() <= 0.5 / 255 + 1e-6
    same_rotation = torch.minimum((back.rotations - g.rotations[order]).norm(dim=-1),
                                  (back.rotations + g.rotations[order]).norm(dim=-1))  # q and -q are one rotation
    assert same_rotation.max() < 0.02
    (tmp_path / "bad.splat").write_bytes(b"x" * 33)
    with pytest.raises(ValueError, match="not a whole number of 32-byte"):
        load_gaussians(tmp_path / "bad.splat")


def _views(tmp_path):
    poses = torch.eye(4).repeat(2, 1, 1)
    poses[1, 0, 3] = 0.4
    (tmp_path / "views.json").write_text(json.dumps({"poses": poses.tolist()}))
    return poses


def _rendered(folder) -> np.ndarray:
    return np.stack([np.asarray(Image.open(p)) for p in sorted((folder / "views").glob("view_*_rgb.png"))])


def test_render_reads_splat_files(tmp_path, capsys):
    poses = _views(tmp_path)
    splat = save_splat(demo_room(4.0), tmp_path / "room.splat")  # before: a raw 'ascii' codec error
    assert main(["render", "--ply", str(splat), "--views", str(tmp_path / "views.json"), "--output-resolution", "8x16",
                 "--frames", "0", "--out", str(tmp_path / "out")]) == 0
    reference = render_views(load_gaussians(splat), poses, 8, 16)
    expected = (reference.rgb.clamp(0, 1) * 255 + 0.5).floor().permute(0, 2, 3, 1).numpy()
    assert np.abs(_rendered(tmp_path / "out").astype(int) - expected).max() <= 1
    capsys.readouterr()
    (tmp_path / "room.obj").write_text("v 0 0 0\n")
    assert main(["render", "--ply", str(tmp_path / "room.obj"), "--views", str(tmp_path / "views.json"),
                 "--out", str(tmp_path / "obj")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown splat format" in err[0]
    (tmp_path / "scene.ply").mkdir()  # a folder (e.g. of posed panoramas) given as the splat file
    assert main(["render", "--ply", str(tmp_path / "scene.ply"), "--views", str(tmp_path / "views.json"),
                 "--out", str(tmp_path / "folder")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "scene.ply is a folder: give a splat file" in err[0] and "--input" in err[0], err
    assert not (tmp_path / "folder").exists()
    with pytest.raises(ValueError, match="is a folder, not a splat file"):
        load_gaussians(tmp_path / "scene.ply")


@pytest.mark.parametrize("name", ["room.spz", "room.sog", "room.compressed.ply"])
def test_render_reads_the_converted_formats_through_splat_transform(tmp_path, monkeypatch, name):
    # A stand-in converter (the real one needs Node.js): "splat-transform --quiet IN OUT" writes the scene as a PLY.
    ply = save_ply(demo_room(4.0), tmp_path / "truth.ply")
    tool = tmp_path / "fake_splat_transform.py"
    tool.write_text(f"import shutil, sys\nshutil.copyfile({str(ply)!r}, sys.argv[-1])\n")
    monkeypatch.setenv(SPLAT_TRANSFORM_ENV, f"{sys.executable} {tool}")
    (tmp_path / name).write_bytes(b"compressed bytes")
    _views(tmp_path)
    common = ["--views", str(tmp_path / "views.json"), "--output-resolution", "8x16", "--frames", "0"]
    assert main(["render", "--ply", str(tmp_path / name), *common, "--out", str(tmp_path / "a")]) == 0
    assert main(["render", "--ply", str(ply), *common, "--out", str(tmp_path / "b")]) == 0
    np.testing.assert_array_equal(_rendered(tmp_path / "a"), _rendered(tmp_path / "b"))
