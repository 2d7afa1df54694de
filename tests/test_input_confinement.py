"""Issue 27, item 2: files named by a poses file stay inside the input folder; prior names stay in priors/."""

import json
import os
import shutil

import pytest

from cylindersplat.cli import main
from cylindersplat.data.depth_prior.precompute import write_priors
from cylindersplat.errors import InputError, OutsideFolderError
from cylindersplat.inference import load_panorama_folder


def _retarget(folder, frame, key, value):
    """Point ``key`` ("image" or "depth") of frame ``frame`` of ``folder/poses.json`` at ``value``."""
    poses = json.loads((folder / "poses.json").read_text())
    poses["frames"][frame][key] = value
    (folder / "poses.json").write_text(json.dumps(poses))


def _move_out(folder, name):
    """Move ``folder/name`` to a sibling folder ``outside``; -> its new path."""
    outside = folder.parent / "outside"
    outside.mkdir(exist_ok=True)
    return shutil.move(str(folder / name), str(outside / name))


def test_an_image_outside_the_folder_is_refused_with_its_name(panorama_folder):
    folder = panorama_folder[0]
    _move_out(folder, "pano_01.png")
    _retarget(folder, 1, "image", "../outside/pano_01.png")
    with pytest.raises(OutsideFolderError) as info:
        load_panorama_folder(folder, (16, 32))
    assert str(info.value) == (f'{folder / "poses.json"} frame 1 "image": ../outside/pano_01.png is outside the input '
                               f"folder {folder}; move the file into it (or pass "
                               "--allow-outside-paths to read it anyway)")
    assert len(load_panorama_folder(folder, (16, 32), allow_outside_paths=True).names) == 2  # the explicit way


def test_an_absolute_depth_path_is_refused(panorama_folder):
    folder = panorama_folder[0]
    depth = _move_out(folder, "pano_00_depth.png")
    _retarget(folder, 0, "depth", depth)
    with pytest.raises(OutsideFolderError,
                       match=r'frame 0 "depth": .*pano_00_depth.png is an absolute path; name files '
                                                 r"relative to .*--allow-outside-paths"):
        load_panorama_folder(folder, (16, 32))


def test_a_symlink_leading_out_is_refused_one_pointing_inside_is_read(panorama_folder):
    folder = panorama_folder[0]
    outside = _move_out(folder, "pano_00_depth.png")
    os.symlink(outside, folder / "pano_00_depth.png")  # same name, but the file lives outside
    with pytest.raises(OutsideFolderError, match="pano_00_depth.png is outside the input folder"):
        load_panorama_folder(folder, (16, 32))
    (folder / "pano_00_depth.png").unlink()
    shutil.move(outside, folder / "real_depth.png")
    os.symlink("real_depth.png", folder / "pano_00_depth.png")  # inside: fine
    assert load_panorama_folder(folder, (16, 32)).depths.shape == (2, 16, 32)


def test_export_refuses_an_escaping_frame_in_one_line(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    folder = panorama_folder[0]
    _move_out(folder, "pano_01.png")
    _retarget(folder, 1, "image", "../outside/pano_01.png")
    out = tmp_path / "g.ply"
    assert main(["export", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--resolution", "16x32",
                 "--out", str(out), "--device", "cpu"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f'cylindersplat export: error: {folder / "poses.json"} frame 1 "image": ../outside/pano_01.png is '
                   f"outside the input folder {folder}; move the file into it (or pass --allow-outside-paths to read "
                   "it anyway)"]
    assert not out.exists()


@pytest.mark.parametrize("name,message", [
    ("../../escape", "--name ../../escape: a prior name is one folder name (no '/', '..' or absolute path), e.g. "
                     "depth_anything; use --out DIR to write the files elsewhere"),
    ("/tmp/abs", "--name /tmp/abs: a prior name is one folder name (no '/', '..' or absolute path), e.g. "
                 "depth_anything; use --out DIR to write the files elsewhere"),
    ("..", "--name ..: a prior name is one folder name (no '/', '..' or absolute path), e.g. depth_anything; use "
           "--out DIR to write the files elsewhere"),
    ("", "--name '': a prior needs a non-empty name (files go to DATA/priors/NAME)"),
])
def test_prior_names_stay_in_the_priors_folder(panorama_folder, name, message):
    with pytest.raises(InputError) as info:
        write_priors(panorama_folder[0], "exported:missing.pt2", name=name, progress=False)
    assert str(info.value) == message


def test_data_info_refuses_then_reads_with_the_option(panorama_folder, capsys):
    folder = panorama_folder[0]
    _move_out(folder, "pano_01.png")
    _retarget(folder, 1, "image", "../outside/pano_01.png")
    assert main(["data", "info", "--data", str(folder), "--occlusion", "0"]) == 1
    assert capsys.readouterr().err.strip().endswith("(or pass --allow-outside-paths to read it anyway)")
    assert main(["data", "info", "--data", str(folder), "--occlusion", "0", "--targets", "pano_00",
                 "--allow-outside-paths"]) == 0


def test_data_priors_refuses_an_escaping_frame_without_offering_the_override(panorama_folder):
    folder = panorama_folder[0]
    _move_out(folder, "pano_01.png")
    _retarget(folder, 1, "image", "../outside/pano_01.png")
    with pytest.raises(OutsideFolderError) as info:
        write_priors(folder, "exported:missing.pt2", name="mono", progress=False)
    assert str(info.value) == (f'{folder / "poses.json"} frame 1 "image": ../outside/pano_01.png is outside the input '
                               f"folder {folder}; move the file into it (prior files mirror the panoramas' paths "
                               "inside the dataset)")


def test_view_shows_no_panorama_from_outside_the_poses_folder(panorama_folder, tmp_path, capsys):
    import torch

    from cylindersplat.gaussians import Gaussians, save_ply

    folder = panorama_folder[0]
    _move_out(folder, "pano_01.png")
    _retarget(folder, 1, "image", "../outside/pano_01.png")
    splats = save_ply(Gaussians.from_rgb(torch.tensor([[0.0, 0.0, 2.0]]), torch.full((1, 3), 0.1),
                                         torch.tensor([[1.0, 0, 0, 0]]), torch.tensor([0.9]),
                                         torch.tensor([[1.0, 0.5, 0.2]])), tmp_path / "scene.ply")
    shot = tmp_path / "shot.png"
    argv = ["view", str(splats), "--poses-file", str(folder / "poses.json"), "--screenshot", str(shot),
            "--screenshot-size", "8x16", "--device", "cpu"]
    assert main(argv) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        f'cylindersplat view: error: {folder / "poses.json"} frame 1 "image": ../outside/pano_01.png is outside the '
        f"input folder {folder}; move the file into it (or pass --allow-outside-paths to read it anyway)"]
    assert not shot.exists()
    assert main(argv + ["--allow-outside-paths"]) == 0 and shot.is_file()
