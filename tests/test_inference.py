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
)
from cylindersplat.render import render_equirect
from cylindersplat.scenes import demo_room


def _yaw(angle: float, t=(0.0, 0.0, 0.0)) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return make_c2w(rot, torch.tensor(t))


@pytest.fixture()
def folder(panorama_folder):  # conftest.py
    return panorama_folder


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
def checkpoint(tiny_checkpoint):  # conftest.py
    return tiny_checkpoint


def test_render_and_export_cli(folder, checkpoint, tmp_path, capsys):
    path, *_ = folder
    out = tmp_path / "render"
    views = tmp_path / "novel.json"
    views.write_text(json.dumps({"poses": [_yaw(0.1, (0.2, 0.0, 0.1)).tolist(), _yaw(0.2).tolist(),
                                           _yaw(0.0).tolist()]}))
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
    assert sorted(p.name for p in (out / "views").iterdir()) == ["poses.json", "view_000_depth.png", "view_000_rgb.png"]


def test_render_pixel_blending_option(folder, checkpoint, tmp_path, capsys):
    """--pixel-blending overrides the model's drawing of its pixel Gaussians (said in one line); the blended views are
    those of render_layered(blend=True) on the same Gaussians, and a bad value is refused naming the choices."""
    from cylindersplat.inference.pipeline import reconstruct_gaussians, render_views
    from cylindersplat.model.pretrained import from_pretrained

    path, *_ = folder
    common = ["render", "--input", str(path), "--checkpoint", str(checkpoint), "--resolution", "16x32", "--frames", "0",
              "--min-opacity", "0", "--no-ply"]
    assert main([*common, "--out", str(tmp_path / "over"), "--pixel-blending", "over"]) == 0
    assert "--pixel-blending over" not in capsys.readouterr().out  # the model's own drawing already: nothing to say
    assert main([*common, "--out", str(tmp_path / "surface"), "--pixel-blending", "surface"]) == 0
    assert "pixel Gaussians drawn with --pixel-blending surface (this model's own: over)" in capsys.readouterr().out
    over, surface = (np.asarray(Image.open(tmp_path / name / "views" / "view_000_rgb.png"), dtype=float)
                     for name in ("over", "surface"))
    assert np.abs(over - surface).max() > 2  # the drawing changed
    model = from_pretrained(str(checkpoint)).with_config(render_pixel_blending="surface")
    inputs = load_panorama_folder(path, (16, 32))
    gaussians, front = reconstruct_gaussians(model, inputs.images, inputs.depths, inputs.c2w, layers=True)
    poses = json.loads((tmp_path / "surface" / "views" / "poses.json").read_text())
    c2w = torch.tensor(poses["frames"][0]["c2w"], dtype=torch.float32)[None]
    expected = render_views(gaussians, c2w, 16, 32, front=front)
    expected = (expected.rgb[0].clamp(0, 1).permute(1, 2, 0).numpy() * 255).round()
    assert np.abs(expected - surface).max() <= 1
    with pytest.raises(SystemExit):
        main([*common, "--out", str(tmp_path / "x"), "--pixel-blending", "blur"])
    assert "invalid choice: 'blur'" in (err := capsys.readouterr().err) and "surface" in err


def test_cli_errors(folder, checkpoint, tmp_path, capsys):
    path, *_ = folder
    assert main(["export", "--input", str(path), "--checkpoint", str(tmp_path / "missing.safetensors")]) == 1
    assert "missing.safetensors" in (err := capsys.readouterr().err) and "not found" in err
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


def test_a_transforms_json_folder_reconstructs_like_poses_json(folder, checkpoint, tmp_path):
    """A nerfstudio folder (transforms.json, OpenGL c2w, EQUIRECTANGULAR) just works for export/render."""
    path, *_ = folder
    gl = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0]))
    frames = [{"file_path": f["image"], "depth_file_path": f["depth"],
               "transform_matrix": (torch.tensor(f["c2w"]) @ gl).tolist()}
              for f in _frames(path)["frames"]]
    ns = tmp_path / "ns"
    ns.mkdir()
    for f in path.iterdir():
        if f.name != "poses.json":
            (ns / f.name).write_bytes(f.read_bytes())
    (ns / "transforms.json").write_text(json.dumps({"camera_model": "EQUIRECTANGULAR", "w": 32, "h": 16,
                                                    "frames": frames}))
    for source, out in ((path, tmp_path / "a.ply"), (ns, tmp_path / "b.ply")):
        assert main(["export", "--input", str(source), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                     "--out", str(out), "--min-opacity", "0"]) == 0
    a, b = load_ply(tmp_path / "a.ply"), load_ply(tmp_path / "b.ply")
    torch.testing.assert_close(b.means, a.means, atol=1e-4, rtol=0)
    (ns / "transforms.json").write_text(json.dumps({"camera_model": "OPENCV", "frames": frames}))
    assert main(["export", "--input", str(ns), "--checkpoint", str(checkpoint), "--out", str(tmp_path / "c.ply")]) == 1


def test_flythrough_streams_frames_into_the_video(tmp_path, monkeypatch):
    """N frames rendered two at a time, each chunk written before the next is rendered; the GIF has N frames."""
    from cylindersplat.inference import pipeline, video, write_flythrough

    written, held = [], []
    append = video._GifStream.append
    monkeypatch.setattr(video._GifStream, "append", lambda self, frame: (written.append(1), append(self, frame)))
    render = pipeline.render

    def spy(gaussians, c2w, camera, **kwargs):
        held.append(len(c2w) + (rendered[0] - len(written)))  # frames in memory: this chunk + any not yet written
        rendered[0] += len(c2w)
        return render(gaussians, c2w, camera, **kwargs)

    rendered = [0]
    monkeypatch.setattr(pipeline, "render", spy)
    cams = torch.stack([_yaw(0.0), _yaw(0.5, (0.3, 0.0, 0.0))])
    path = write_flythrough(tmp_path / "fly.gif", demo_room(4.0), cams, 8, 16, frames=9, fps=10)
    assert len(written) == 9 and max(held) <= 2
    gif = Image.open(path)
    assert gif.n_frames == 9 and gif.size == (16, 2 * 8 + 4)


def test_render_any_ply_pinhole_panorama_metric_depth_and_poses(tmp_path):
    """render --ply: perspective and panoramic views, metric depth (npy exact, 16-bit PNG within 1 mm), the poses
    written next to the images and of the fly-through round-trip, a fly-through along a given camera path."""
    from cylindersplat.gaussians import save_ply
    from cylindersplat.inference import normalized_depth, read_poses_file
    from cylindersplat.inference.pipeline import pinhole_intrinsics
    from cylindersplat.render import Pinhole, render

    ply = save_ply(demo_room(4.0), tmp_path / "room.ply")
    scene = load_ply(ply)
    poses = torch.stack([_yaw(0.3, (0.2, 0.1, -0.3)), _yaw(-1.0, (-0.4, 0.0, 0.5))])
    (tmp_path / "views.json").write_text(json.dumps({"poses": poses.tolist()}))
    path = torch.stack([_yaw(0.1 * k, (0.05 * k, 0.0, 0.0)) for k in range(5)])
    (tmp_path / "path.json").write_text(json.dumps({"convention": "opengl_c2w", "poses": (path @ torch.diag(
        torch.tensor([1.0, -1.0, -1.0, 1.0]))).tolist()}))
    out = tmp_path / "pin"
    assert main(["render", "--ply", str(ply), "--views", str(tmp_path / "views.json"), "--camera", "pinhole", "--fov",
                 "75",
                 "--output-resolution", "12x20", "--metric-depth", "--camera-path", str(tmp_path / "path.json"),
                 "--out", str(out)]) == 0
    k = pinhole_intrinsics(12, 20, 75.0)
    reference = render(scene, poses, Pinhole(k, 12, 20), background=(0.0, 0.0, 0.0))
    written = read_poses_file(out / "views" / "poses.json")
    record = json.loads((out / "views" / "poses.json").read_text())
    assert record["camera"]["model"] == "pinhole" and np.allclose(record["camera"]["K"], k.tolist())
    for i, (image, c2w, depth_file) in enumerate(written):
        torch.testing.assert_close(c2w, poses[i])  # poses.json round-trips
        rgb = np.asarray(Image.open(out / "views" / image))
        assert rgb.shape == (12, 20, 3)
        expected = (reference.rgb[i].clamp(0, 1) * 255 + 0.5).floor().permute(1, 2, 0).numpy()
        assert np.abs(rgb.astype(int) - expected).max() <= 1
        metric = normalized_depth(reference.depth[i], reference.alpha[i])
        npy = np.load(out / "views" / depth_file)
        assert npy.dtype == np.float32 and npy.shape == (12, 20) and (npy > 0).any()
        np.testing.assert_allclose(npy, metric.numpy(), atol=1e-5, rtol=0)
        png = np.asarray(Image.open(out / "views" / f"view_{i:03d}_depth_mm.png")).astype(np.float64) / 1000
        assert np.abs(png - npy).max() <= 0.0005 + 1e-6  # within 1 mm (rounded to the nearest mm)
    gif = Image.open(out / "flythrough.gif")
    assert gif.n_frames == 5 and gif.size == (20, 2 * 12 + 4)  # one frame per camera-path pose
    fly = torch.stack([p for _, p, _ in read_poses_file(out / "flythrough_poses.json")])
    torch.testing.assert_close(fly, path, atol=1e-6, rtol=0)
    # Panoramas: the generated fly-through passes through the views, poses.json loads as an input folder.
    pano = tmp_path / "pano"
    assert main(["render", "--ply", str(ply), "--views", str(tmp_path / "views.json"), "--output-resolution", "8x16",
                 "--metric-depth", "--frames", "4", "--out", str(pano)]) == 0
    assert Image.open(pano / "flythrough.gif").n_frames == 4
    inputs = load_panorama_folder(pano / "views", (8, 16))
    torch.testing.assert_close(inputs.c2w, poses)
    assert main(["render", "--ply", str(ply), "--views", str(tmp_path / "views.json"), "--output-resolution", "8x20",
                 "--out", str(pano)]) == 1  # a panorama must be 2:1
