"""`cylindersplat data synth / preview / info` end to end on tiny datasets (synthetic, a folder of posed
panoramas), and their input errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data import SyntheticDataset
from cylindersplat.data.depth_prior import NoPrior
from cylindersplat.data.preview import example_occlusion, open_dataset
from cylindersplat.inference import write_panorama_folder


def test_synth_preview_info_roundtrip(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["data", "synth", "--out", str(out), "--scenes", "2", "--resolution", "32x64",
                 "--frames", "3", "--spacing", "0.25:0.5", "--seed", "3"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta  # the loader's marker file exists and is JSON

    ds = SyntheticDataset(out, views="two_view", depth_prior=NoPrior())
    assert len(ds) == 2
    sample = ds[0]
    assert sample.context_images.shape == (2, 3, 32, 64)
    assert sample.target_images.shape == (1, 3, 32, 64)
    # Frames lie on a line: the target camera sits between the two contexts.
    centres = [sample.context_poses[0, :3, 3], sample.target_poses[0, :3, 3], sample.context_poses[1, :3, 3]]
    a, m, b = (c.double().numpy() for c in centres)
    assert np.allclose(np.linalg.norm(a - m) + np.linalg.norm(m - b), np.linalg.norm(a - b), atol=1e-5)
    assert 0.25 - 1e-6 <= np.linalg.norm(a - m) <= 0.5 + 1e-6

    sheet = tmp_path / "sheet.png"
    assert main(["data", "preview", "--data", str(out), "--out", str(sheet), "--count", "2", "--height", "16"]) == 0
    image = np.asarray(Image.open(sheet))
    # 2 rows of 3 frames x (RGB, depth) tiles of 16x32 with 4-pixel gaps.
    assert image.shape == (2 * 16 + 4, 6 * 32 + 5 * 4, 3)

    assert main(["data", "info", "--data", str(out), "--count", "1"]) == 0
    assert "2 examples" in capsys.readouterr().out


@pytest.mark.parametrize("args, fragment", [
    (["--resolution", "64x64"], "W == 2H"),
    (["--spacing", "1:0.5"], "MIN <= MAX"),
    (["--target-offset", "1:0.5"], "MIN <= MAX"),  # the disocclusion options (test_data_synth_occlusion.py)
    (["--layouts", "room,castle"], "unknown layout"),
    (["--profile", "nope"], "invalid choice"),
])
def test_synth_rejects_bad_arguments(tmp_path, capsys, args, fragment):
    with pytest.raises(SystemExit):
        main(["data", "synth", "--out", str(tmp_path), "--scenes", "1", *args])
    assert fragment in capsys.readouterr().err


def test_preview_of_unknown_folder_is_a_clear_error(tmp_path, capsys):
    for command in (["preview", "--out", str(tmp_path / "x.png")], ["info"]):
        assert main(["data", *command, "--data", str(tmp_path)]) == 1
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "neither a synthetic dataset" in err  # one line naming the three formats
        assert all(part in err for part in ("meta.json", "png_render_*", "posed panoramas (poses.json"))
    assert not (tmp_path / "x.png").exists()


def _posed_folder(folder, frames=3, depth=True, seed=0):
    """``frames`` posed 32x64 panoramas 0.5 m apart on x (input format; depth PNGs when ``depth``)."""
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(frames, 3, 32, 64, generator=g)
    depths = torch.rand(frames, 32, 64, generator=g) * 3 + 0.5
    poses = torch.eye(4).repeat(frames, 1, 1)
    poses[:, 0, 3] = 0.5 * torch.arange(frames)
    return write_panorama_folder(folder, images, poses, depths if depth else None)


def _tiles(sheet, rows, cols, h=32, w=64, gap=4):
    """The tiles of a contact sheet, ``[row][col]``."""
    return [[sheet[r * (h + gap):r * (h + gap) + h, c * (w + gap):c * (w + gap) + w] for c in range(cols)]
            for r in range(rows)]


def test_info_and_preview_of_a_folder_of_panoramas(tmp_path, capsys):
    path = _posed_folder(tmp_path / "scene")
    assert main(["data", "info", "--data", str(path)]) == 0  # two_view over the frames, as eval's default
    out = capsys.readouterr().out
    assert "FolderDataset: 1 examples, stored size (32, 64) (HxW, first panorama), views two_view" in out
    assert "scene: 3 frames, context [0, 2] -> target [1]" in out and "baseline 1.000 m, occluded " in out
    assert "over 1 of 1 examples (1 targets)" in out  # the ground-truth depth files give the occluded share
    assert main(["data", "info", "--data", str(path), "--targets", "pano_00.png"]) == 0
    out = capsys.readouterr().out
    assert "views held_out (pano_00.png)" in out and "context [1, 2] -> target [0]" in out

    sheet = tmp_path / "sheet.png"
    assert main(["data", "preview", "--data", str(path), "--out", str(sheet), "--height", "32"]) == 0
    image = np.asarray(Image.open(sheet))
    assert image.shape == (32, 6 * 64 + 5 * 4, 3)  # every frame (poses-file order): RGB, depth
    assert all(tile.any() for tile in _tiles(image, 1, 6)[0][1::2])  # depth tiles coloured

    # .npy depth files (metres) give the same figures as the 16-bit millimetre PNGs they hold
    png = example_occlusion(open_dataset(path, views="two_view"), 0).occluded
    data = json.loads((path / "poses.json").read_text())
    for frame in data["frames"]:
        depth = path / frame["depth"]
        np.save(depth.with_suffix(".npy"), np.asarray(Image.open(depth)).astype(np.float32) / 1000)
        frame["depth"] = depth.with_suffix(".npy").name
        depth.unlink()
    (path / "poses.json").write_text(json.dumps(data))
    assert example_occlusion(open_dataset(path, views="two_view"), 0).occluded == pytest.approx(png)

    # one frame without a depth file: its tile is black, the others keep theirs; no occluded share
    (path / data["frames"][1].pop("depth")).unlink()
    (path / "poses.json").write_text(json.dumps(data))
    assert main(["data", "preview", "--data", str(path), "--out", str(sheet), "--height", "32"]) == 0
    depth_tiles = _tiles(np.asarray(Image.open(sheet)), 1, 6)[0][1::2]
    assert [bool(tile.any()) for tile in depth_tiles] == [True, False, True]
    assert main(["data", "info", "--data", str(path)]) == 0
    assert "occluded n/a (no depth)" in capsys.readouterr().out


def test_a_folder_without_depth_files(tmp_path, capsys):
    path = _posed_folder(tmp_path / "scenes" / "b", frames=2, depth=False)
    _posed_folder(tmp_path / "scenes" / "a", seed=1)
    assert main(["data", "info", "--data", str(path), "--targets", "pano_01"]) == 0
    out = capsys.readouterr().out
    assert "b: 2 frames, context [0] -> target [1]" in out and "occluded n/a (no depth)" in out
    assert "occluded share: n/a (no ground-truth depth)" in out
    assert main(["data", "info", "--data", str(path)]) == 1  # two_view needs three frames: the error says what to do
    err = capsys.readouterr().err
    assert "two_view needs >= 3 frames" in err and str(path) in err and "--targets" in err

    sheet = tmp_path / "sheet.png"
    assert main(["data", "preview", "--data", str(path), "--out", str(sheet), "--height", "32"]) == 0
    tiles = _tiles(np.asarray(Image.open(sheet)), 1, 4)[0]
    assert np.asarray(Image.open(sheet)).shape == (32, 4 * 64 + 3 * 4, 3)
    assert all(t.any() for t in tiles[0::2]) and not any(t.any() for t in tiles[1::2])  # no depth: black tiles

    # a folder of such folders: one example each, in name order; the summary counts those with depth
    scenes = tmp_path / "scenes"
    assert main(["data", "info", "--data", str(scenes), "--views", "one_view"]) == 0
    out = capsys.readouterr().out
    assert "FolderDataset: 2 examples" in out and "over 1 of 2 examples (2 targets)" in out
    assert main(["data", "preview", "--data", str(scenes), "--out", str(sheet), "--height", "32"]) == 0
    assert np.asarray(Image.open(sheet)).shape == (2 * 32 + 4, 6 * 64 + 5 * 4, 3)
