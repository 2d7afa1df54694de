"""Inference on a user's folder: the input format round-trips, bad inputs fail clearly, paths, CLI end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data.depth_prior import ConstantPrior
from cylindersplat.gaussians import load_ply
from cylindersplat.geometry import make_c2w
from cylindersplat.inference import (
    flythrough_path,
    interpolate_poses,
    load_panorama_folder,
    midpoint_poses,
    render_views,
    slerp,
    write_panorama_folder,
)
from cylindersplat.model import from_config, save_model
from cylindersplat.render import render_equirect
from cylindersplat.scenes import demo_room


def _yaw(angle: float, t=(0.0, 0.0, 0.0)) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return make_c2w(rot, torch.tensor(t))


@pytest.fixture()
def folder(tmp_path):
    torch.manual_seed(0)
    images = torch.rand(2, 3, 16, 32)
    depths = torch.rand(2, 16, 32) * 3 + 0.5
    poses = torch.stack([_yaw(0.0), _yaw(0.3, (0.5, 0.0, 0.2))])
    return write_panorama_folder(tmp_path / "scene", images, poses, depths), images, depths, poses


def test_folder_round_trip(folder):
    path, images, depths, poses = folder
    inputs = load_panorama_folder(path, (16, 32))
    assert inputs.names == ["pano_00.png", "pano_01.png"]
    torch.testing.assert_close(inputs.images, (images * 255 + 0.5).floor() / 255, atol=1e-6, rtol=0)
    torch.testing.assert_close(inputs.depths, depths, atol=6e-4, rtol=0)  # 1 mm steps
    torch.testing.assert_close(inputs.c2w, poses)


def test_poses_only_format_matches_images_in_name_order(folder):
    path, _, _, poses = folder
    (path / "poses.json").write_text(json.dumps({"poses": [p[:3].tolist() for p in poses]}))  # 3x4 accepted
    inputs = load_panorama_folder(path, (16, 32))
    torch.testing.assert_close(inputs.c2w, poses)
    (path / "poses.json").write_text(json.dumps({"poses": [poses[0].tolist()]}))
    with pytest.raises(ValueError, match="has 1 poses but .* has 2 panoramas"):
        load_panorama_folder(path, (16, 32))


def _frames(path):
    return json.loads((path / "poses.json").read_text())


def test_bad_inputs_name_the_problem(folder):
    path, *_ = folder
    good = _frames(path)
    data = _frames(path)
    data["frames"][1]["c2w"][0][3] = float("nan")
    (path / "poses.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="frame 1.*non-finite"):
        load_panorama_folder(path, (16, 32))
    data = _frames(path)
    data["frames"][0]["c2w"] = (2 * torch.eye(4)).tolist()
    (path / "poses.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="frame 0.*orthonormal"):
        load_panorama_folder(path, (16, 32))
    (path / "poses.json").write_text(json.dumps(good))
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(path / "pano_01.png")
    with pytest.raises(ValueError, match="pano_01.png.*2:1"):
        load_panorama_folder(path, (16, 32))
    (path / "pano_01.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(ValueError, match="pano_01.png: cannot decode"):
        load_panorama_folder(path, (16, 32))
    (path / "pano_01.png").unlink()
    with pytest.raises(FileNotFoundError, match="pano_01.png"):
        load_panorama_folder(path, (16, 32))
    (path / "poses.json").write_text("{not json")
    with pytest.raises(ValueError, match="poses.json: not valid JSON"):
        load_panorama_folder(path, (16, 32))
    with pytest.raises(FileNotFoundError, match="input folder not found"):
        load_panorama_folder(path / "nope", (16, 32))


def test_missing_depth_needs_a_prior(folder):
    path, *_ = folder
    data = _frames(path)
    for frame in data["frames"]:
        del frame["depth"]
        (path / frame["image"].replace(".png", "_depth.png")).unlink()
    (path / "poses.json").write_text(json.dumps(data))
    with pytest.raises(FileNotFoundError, match="no depth prior for pano_00.png, pano_01.png.*--depth-prior"):
        load_panorama_folder(path, (16, 32))
    inputs = load_panorama_folder(path, (16, 32), depth_prior=ConstantPrior(2.5))
    assert inputs.depths.eq(2.5).all()


def test_slerp_and_paths():
    # Known value: halfway between yaw 0 and yaw 90 degrees is yaw 45 degrees, centre halfway too.
    mid = interpolate_poses(_yaw(0.0), _yaw(math.pi / 2, (2.0, 0.0, 0.0)), torch.tensor([0.5]))[0]
    torch.testing.assert_close(mid, _yaw(math.pi / 4, (1.0, 0.0, 0.0)), atol=1e-6, rtol=0)
    q = torch.tensor([1.0, 0.0, 0.0, 0.0])
    torch.testing.assert_close(slerp(q, -q, torch.tensor([0.3])), q[None])  # same rotation, no spin
    cams = torch.stack([_yaw(0.0), _yaw(0.4, (1.0, 0.0, 0.0)), _yaw(-0.2, (1.0, 0.0, 1.0))])
    path = flythrough_path(cams, frames=16, loop=True)
    assert path.shape == (16, 4, 4)
    torch.testing.assert_close(path[0], cams[0])
    torch.testing.assert_close(path[4], cams[1], atol=1e-6, rtol=0)  # 4 segments x 4 frames
    torch.testing.assert_close(path[8], cams[2], atol=1e-6, rtol=0)
    rot = path[:, :3, :3]
    torch.testing.assert_close(rot @ rot.transpose(1, 2), torch.eye(3).expand(16, 3, 3), atol=1e-5, rtol=0)
    open_path = flythrough_path(cams, frames=10, loop=False)
    torch.testing.assert_close(open_path[-1], cams[-1])
    spin = flythrough_path(cams[:1], frames=8)
    torch.testing.assert_close(spin[:, :3, 3], cams[0, :3, 3].expand(8, 3))
    torch.testing.assert_close(spin[2], cams[0] @ _yaw(math.pi / 2), atol=1e-6, rtol=0)
    torch.testing.assert_close(midpoint_poses(cams)[0], interpolate_poses(cams[0], cams[1], torch.tensor([0.5]))[0])


def test_chunked_rendering_equals_one_call():
    g = demo_room(4.0)
    poses = torch.stack([_yaw(0.1 * i, (0.1 * i, 0.0, 0.0)) for i in range(3)])
    chunked = render_views(g, poses, 16, 32, chunk=2)
    whole = render_equirect(g, poses, 16, 32, background=(0.0, 0.0, 0.0))
    torch.testing.assert_close(chunked.rgb, whole.rgb)
    torch.testing.assert_close(chunked.depth, whole.depth)


@pytest.fixture()
def checkpoint(tmp_path):
    torch.manual_seed(0)
    path = tmp_path / "tiny.safetensors"
    save_model(from_config("tiny"), path)
    return path


def test_render_and_export_cli(folder, checkpoint, tmp_path, capsys):
    path, *_ = folder
    out = tmp_path / "render"
    views = tmp_path / "novel.json"
    views.write_text(json.dumps({"poses": [_yaw(0.1, (0.2, 0.0, 0.1)).tolist(), _yaw(0.2).tolist(), _yaw(0.0).tolist()]}))
    assert main(["render", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                 "--out", str(out), "--views", str(views), "--frames", "5", "--min-opacity", "0"]) == 0
    for i in range(3):
        assert Image.open(out / "views" / f"view_{i:03d}_rgb.png").size == (32, 16)
        assert Image.open(out / "views" / f"view_{i:03d}_depth.png").size == (32, 16)
    gif = Image.open(out / "flythrough.gif")
    assert gif.n_frames == 5 and gif.size == (32, 2 * 16 + 4)
    gaussians = load_ply(out / "gaussians.ply")
    assert len(gaussians) > 0 and f"reconstructed {len(gaussians):,} Gaussians" in capsys.readouterr().out
    ply = tmp_path / "scene.ply"
    assert main(["export", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                 "--out", str(ply), "--min-opacity", "0"]) == 0
    exported = load_ply(ply)
    torch.testing.assert_close(exported.means, gaussians.means)
    # The written PLY renders again without the model: same views, metric depth as .npy.
    again = tmp_path / "from_ply"
    assert main(["render", "--ply", str(out / "gaussians.ply"), "--views", str(views), "--output-resolution", "16x32",
                 "--out", str(again), "--frames", "2", "--metric-depth"]) == 0
    first = np.asarray(Image.open(out / "views" / "view_001_rgb.png"), dtype=float)
    second = np.asarray(Image.open(again / "views" / "view_001_rgb.png"), dtype=float)
    assert np.abs(first - second).max() <= 1  # same Gaussians, same camera (PLY stores float32)
    depth = np.load(again / "views" / "view_001_depth.npy")
    assert depth.shape == (16, 32) and depth.dtype == np.float32 and np.isfinite(depth).all() and depth.max() > 0
    assert (again / "flythrough.gif").is_file() and not (again / "gaussians.ply").exists()
    assert main(["render", "--ply", str(out / "gaussians.ply"), "--out", str(again)]) == 1
    assert "--views" in capsys.readouterr().err
    # Rendering again into the same folder with fewer views leaves no stale views of the first render.
    assert main(["render", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                 "--out", str(out), "--frames", "0", "--min-opacity", "0"]) == 0
    assert sorted(p.name for p in (out / "views").iterdir()) == ["view_000_depth.png", "view_000_rgb.png"]


def test_cli_errors(folder, checkpoint, tmp_path, capsys):
    path, *_ = folder
    assert main(["export", "--input", str(path), "--checkpoint", str(tmp_path / "missing.safetensors")]) == 1
    assert "checkpoint not found" in capsys.readouterr().err
    assert main(["export", "--input", str(tmp_path / "nowhere"), "--checkpoint", str(checkpoint)]) == 1
    assert "input folder not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["render", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x16"])
    assert "W == 2H" in capsys.readouterr().err
    assert main(["render", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                 "--depth-prior", "constant:abc", "--out", str(tmp_path / "r")]) == 1
    assert "not a valid depth" in capsys.readouterr().err


@pytest.mark.parametrize("convention", ["opengl_c2w", "blender_c2w", "opencv_w2c", "opengl_w2c"])
def test_pose_conventions_give_the_same_cameras(tmp_path, convention):
    from cylindersplat.inference import read_poses_file

    gl = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
    poses = [_yaw(0.3, (0.5, -0.2, 1.0)).double(), _yaw(-1.1, (2.0, 0.1, 0.0)).double()]
    written = []
    for c2w in poses:
        m = c2w @ gl if convention.startswith(("opengl", "blender")) else c2w  # the same camera, other axes
        written.append((torch.linalg.inv(m) if convention.endswith("w2c") else m).tolist())
    (tmp_path / "a.json").write_text(json.dumps({"convention": convention, "poses": written}))
    (tmp_path / "b.json").write_text(json.dumps({"poses": [p.tolist() for p in poses]}))
    for (_, got, _), (_, ref, _) in zip(read_poses_file(tmp_path / "a.json"), read_poses_file(tmp_path / "b.json")):
        torch.testing.assert_close(got, ref, atol=1e-5, rtol=0)


def test_poses_file_types_are_checked(tmp_path):
    from cylindersplat.inference import read_poses_file

    for data, message in [({"convention": "colmap", "poses": [torch.eye(4).tolist()]}, "unknown pose convention"),
                          ({"poses": "eye"}, "must be a list"),
                          ({"frames": [{"image": 3, "c2w": torch.eye(4).tolist()}]}, "must be a file name")]:
        (tmp_path / "p.json").write_text(json.dumps(data))
        with pytest.raises(ValueError, match=message):
            read_poses_file(tmp_path / "p.json")
