"""Issue 37: the inputs a new user gets wrong end in one line that says what is wrong, and nothing is silent.

A depth file that is an ``.npz`` archive, a panorama that is a symlink loop, ``--input`` naming a file, an unknown
option, one panorama where the photometric search needs two, panoramas resized for the model, a synthetic
dataset's own ``depth_scale``.
"""

import json
import os
import shutil

import numpy as np
import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data.io import read_depth_npy, read_depth_png


def _error(capsys) -> str:
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and err.strip().endswith(errors[0]) and "Traceback" not in err, err
    return errors[0]


def test_an_npz_named_npy_is_named(tmp_path):
    np.savez(tmp_path / "d.npz", depth=np.ones((4, 8), np.float32))
    os.replace(tmp_path / "d.npz", tmp_path / "pano_depth.npy")
    with pytest.raises(ValueError) as failure:
        read_depth_npy(tmp_path / "pano_depth.npy")
    assert str(failure.value) == (f"{tmp_path}/pano_depth.npy: a .npz archive, not a .npy array; save the depth map "
                                  "alone with numpy.save (float32 metres, H x W)")


def _export(folder, checkpoint, tmp_path, *more):
    return ["export", "--input", str(folder), "--checkpoint", str(checkpoint), "--resolution", "16x32", "--out",
            str(tmp_path / "out" / "g.ply"), "--device", "cpu", *more]


def test_a_panorama_that_is_a_symlink_loop_is_one_line(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    folder = panorama_folder[0]
    (folder / "pano_00.png").unlink()
    os.symlink("pano_00.png", folder / "pano_00.png")
    assert main(_export(folder, tiny_checkpoint, tmp_path)) == 1
    assert _error(capsys) == (f'cylindersplat export: error: {folder}/poses.json frame 0 "image": pano_00.png is a '
                              "symlink loop (a link that leads back to itself); replace it with the file or a link "
                              "to it")
    assert main(_export(folder, tiny_checkpoint, tmp_path, "--allow-outside-paths")) == 1  # not confined: read
    assert _error(capsys) == (f"cylindersplat export: error: {folder}/pano_00.png is a symlink that leads to no file "
                              "(a loop, or its target is missing); replace it with the file")


def test_input_that_is_a_file_says_so(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    poses = panorama_folder[0] / "poses.json"
    assert main(_export(poses, tiny_checkpoint, tmp_path)) == 1
    assert _error(capsys) == (f"cylindersplat export: error: input {poses} is a file, not a folder: give the folder "
                              f"that holds the panoramas and their poses file (here perhaps {panorama_folder[0]})")


def test_an_unknown_option_points_at_the_subcommands_help_with_the_nearest_one(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["render", "--input", "x", "--frame-count", "3"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == ("cylindersplat render: error: unrecognized arguments: --frame-count 3 (did you "
                                       "mean --frames?) (see cylindersplat render --help)\n")
    with pytest.raises(SystemExit):
        main(["export", "--input", "x", "zzz"])
    assert capsys.readouterr().err == ("cylindersplat export: error: unrecognized arguments: zzz "
                                       "(see cylindersplat export --help)\n")


def test_one_panorama_gets_no_photometric_search_and_is_counted_right(panorama_folder, tiny_checkpoint, tmp_path,
                                                                      capsys):
    from cylindersplat.inference import write_panorama_folder

    _, images, depths, poses = panorama_folder
    one = write_panorama_folder(tmp_path / "one", images[:1], poses[:1], depths[:1])
    assert main(_export(one, tiny_checkpoint, tmp_path, "--prior-scale", "photometric")) == 0
    out = capsys.readouterr().out
    assert "depth used as given: the photometric depth-scale search needs 2 or more panoramas, this is 1" in out
    assert "x1.000" not in out and "Gaussians from 1 panorama at 16x32" in out, out


def test_panoramas_resized_for_the_model_are_said(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    argv = _export(panorama_folder[0], tiny_checkpoint, tmp_path)
    argv[argv.index("--resolution") + 1] = "32x64"
    assert main(argv) == 0
    assert "the panoramas (16x32) are resized to 32x64 for the model" in capsys.readouterr().out.splitlines()


def test_a_synthetic_datasets_own_depth_scale_is_used(synth_dataset, tmp_path):
    from cylindersplat.data import SyntheticDataset

    root = tmp_path / "synth"
    shutil.copytree(synth_dataset(1, seed=0), root)
    meta = json.loads((root / "meta.json").read_text())
    (root / "meta.json").write_text(json.dumps({**meta, "depth_scale": 500}))
    scene = root / meta["scenes"][0]
    scene_meta = json.loads((scene / "meta.json").read_text())
    del scene_meta["depth_scale"]  # the dataset's declaration is the only one
    (scene / "meta.json").write_text(json.dumps(scene_meta))
    frame = SyntheticDataset(root).example(0).frames[0]
    assert frame.depth_scale == 500
    stored = read_depth_png(scene / "00" / "depth.png", scale=1.0)
    torch.testing.assert_close(read_depth_png(frame.depth, scale=frame.depth_scale), stored / 500)


def test_views_that_barely_show_the_scene_are_warned_about(tmp_path, capsys):
    """A scene far smaller than the cameras' distances (millimetres read as metres): a few % of each panorama."""
    from cylindersplat.gaussians import Gaussians, save_ply

    g = torch.Generator().manual_seed(0)
    means = torch.randn(50, 3, generator=g) * 0.05 + torch.tensor([0.0, 0.0, 2.0])
    scene = Gaussians.from_rgb(means, torch.full((50, 3), 0.05), torch.tensor([[1.0, 0, 0, 0]]).repeat(50, 1),
                               torch.full((50,), 0.99), torch.rand(50, 3, generator=g))
    save_ply(scene, tmp_path / "small.ply")
    (tmp_path / "views.json").write_text(json.dumps({"convention": "opencv_c2w",
                                                     "frames": [{"c2w": torch.eye(4).tolist()}]}))
    argv = ["render", "--ply", str(tmp_path / "small.ply"), "--views", str(tmp_path / "views.json"),
            "--output-resolution", "32x64", "--frames", "0", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "note:" in line]
    assert len(notes) == 1 and notes[0].startswith("cylindersplat render: note: the rendered views show the scene in "
                                                   "only "), notes
    assert notes[0].endswith(" % of their pixels: is the scene (or the poses) in other units than metres, or are the "
                             "cameras outside it? Gaussians closer than 1 cm to a camera are not drawn")
    torch.manual_seed(0)
    from cylindersplat.scenes import demo_room

    save_ply(demo_room(), tmp_path / "room.ply")  # a room around the camera: no note
    assert main([*argv[:2], str(tmp_path / "room.ply"), *argv[3:]]) == 0
    assert "note:" not in capsys.readouterr().err


def test_demo_refuses_a_height_the_model_cannot_take_before_any_work(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--scenes", "2", "--held-out", "1", "--resolution", "40x80"]) == 1
    assert _error(capsys) == ("cylindersplat demo: error: --resolution 40x80: the tiny model needs a height divisible "
                              "by 16, e.g. 32x64 or 48x96")
    assert not out.exists()  # no scenes generated for nothing
