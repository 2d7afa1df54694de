"""A poses file that lists the same frame several times: each is read and reconstructed once (issue 37: `export`
with two frames each listed ten times ran the model on all twenty)."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data.base import FrameRef
from cylindersplat.data.io import write_depth_png
from cylindersplat.data.repeated_frames import repeated_frames
from cylindersplat.gaussians import load_ply
from cylindersplat.inference import load_panorama_folder, write_panorama_folder
from cylindersplat.utils.notices import Notice


def _two_panoramas(folder):
    """Two textured 32x64 panoramas 0.4 m apart with a 2 m depth each, in the input format."""
    generator = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, 32, 64, generator=generator)
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 0.4
    return write_panorama_folder(folder, images, c2w, torch.full((2, 32, 64), 2.0))


def _listed_three_times(two, folder):
    """``two``'s folder with its poses.json listing each frame three times (interleaved)."""
    shutil.copytree(two, folder)
    data = json.loads((two / "poses.json").read_text())
    data["frames"] = data["frames"] * 3
    (folder / "poses.json").write_text(json.dumps(data))
    return folder


@pytest.mark.slow  # two exports, ~20 s on 2 shared cores
def test_export_of_repeated_frames_equals_export_of_the_frames_once(tmp_path, capsys):
    two = _two_panoramas(tmp_path / "two")
    six = _listed_three_times(two, tmp_path / "six")
    assert main(["export", "--input", str(two), "--out", str(tmp_path / "two.ply")]) == 0
    once = capsys.readouterr()
    assert main(["export", "--input", str(six), "--out", str(tmp_path / "six.ply")]) == 0
    repeated = capsys.readouterr()
    assert "repeat" not in once.err
    assert f"cylindersplat export: note: 4 frames of {six / 'poses.json'} repeat another (same image, pose and " \
           "depth): used once" in repeated.err.splitlines()
    assert "from 2 panoramas" in repeated.out  # the model ran on two views, not six
    expected, got = load_ply(tmp_path / "two.ply"), load_ply(tmp_path / "six.ply")
    for name in ("means", "scales", "rotations", "opacities", "sh"):
        torch.testing.assert_close(getattr(got, name), getattr(expected, name), rtol=0, atol=0)


def test_a_copy_under_another_name_is_a_repeat_a_new_pose_or_depth_is_not(tmp_path):
    folder = _two_panoramas(tmp_path / "scene")
    shutil.copy(folder / "pano_00.png", folder / "copy_of_00.png")  # the same bytes under another name
    write_depth_png(folder / "other_depth.png", torch.full((32, 64), 2.5))
    data = json.loads((folder / "poses.json").read_text())
    first, second = data["frames"]
    moved = json.loads(json.dumps(first))
    moved["c2w"][2][3] = 0.1
    data["frames"] = [first, second, {**first, "image": "copy_of_00.png"}, moved,
                      {**second, "depth": "other_depth.png"}]  # same image and pose as `second`, other depth bytes
    (folder / "poses.json").write_text(json.dumps(data))
    with pytest.warns(Notice, match="1 frame of .* repeats another"):
        inputs = load_panorama_folder(folder, (32, 64))
    assert inputs.names == ["pano_00.png", "pano_01.png", "pano_00.png", "pano_01.png"]
    torch.testing.assert_close(inputs.c2w[3][:3, 3], torch.tensor([0.4, 0.0, 0.0]))


def test_repeated_frames_compares_file_bytes_pose_and_depth_scale(tmp_path):
    for name, content in (("a.png", b"A"), ("b.png", b"A"), ("c.png", b"C"), ("d.png", b"D"), ("e.png", b"D")):
        (tmp_path / name).write_bytes(content)
    eye, moved = torch.eye(4), torch.eye(4)
    moved[0, 3] = 1.0
    frames = [FrameRef("a", tmp_path / "a.png", eye, tmp_path / "d.png", 1000.0),
              FrameRef("a again", tmp_path / "a.png", eye, tmp_path / "d.png", 1000.0),  # same files: repeat
              FrameRef("b", tmp_path / "b.png", eye, tmp_path / "e.png", 1000.0),  # equal bytes: repeat
              FrameRef("c", tmp_path / "c.png", eye, tmp_path / "d.png", 1000.0),  # other image
              FrameRef("a moved", tmp_path / "a.png", moved, tmp_path / "d.png", 1000.0),  # other pose
              FrameRef("a in metres", tmp_path / "a.png", eye, tmp_path / "d.png", 1.0),  # other depth scale
              FrameRef("a no depth", tmp_path / "a.png", eye, None, 1000.0),  # no depth file
              FrameRef("a no depth again", tmp_path / "a.png", eye, None, 1000.0)]  # repeat of the one before
    assert repeated_frames(frames) == [1, 2, 7]
