"""Poses from other 360° tools: every format of the same cameras imports to the same OpenCV c2w (and renders).

Each tool's own equirect pixel -> ray formula (nerfstudio's EQUIRECTANGULAR camera, OpenSfM's spherical
camera, stella_vslam's equirectangular camera), applied with that tool's pose, must give the same
world ray as our convention applied with the imported pose: this checks the axes, not just that a
conversion inverts itself.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data.io import write_depth_png, write_rgb
from cylindersplat.data.poses import read_kitti, read_opensfm, read_transforms_json, read_tum
from cylindersplat.geometry import quaternion_to_matrix, uv_to_ray
from cylindersplat.geometry.rotations import axis_angle_to_matrix
from cylindersplat.inference import load_panorama_folder, read_poses_file
from cylindersplat.render import render_equirect
from cylindersplat.scenes import demo_room

GL = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
H, W = 6, 12


def _cameras() -> torch.Tensor:
    """Three OpenCV c2w with rotations about every axis (an axis mix-up cannot hide)."""
    g = torch.Generator().manual_seed(3)
    c2w = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    q = torch.randn(3, 4, generator=g, dtype=torch.float64)
    c2w[:, :3, :3] = quaternion_to_matrix(q / q.norm(dim=-1, keepdim=True))
    c2w[:, :3, 3] = torch.randn(3, 3, generator=g, dtype=torch.float64) * 0.3
    return c2w


def _matrix_to_axis_angle(rot: torch.Tensor) -> list[float]:
    angle = math.acos(max(-1.0, min(1.0, (float(torch.trace(rot)) - 1) / 2)))
    axis = torch.stack([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]]) / (2 * math.sin(angle))
    return (axis * angle).tolist()


def _matrix_to_quaternion_xyzw(rot: torch.Tensor) -> list[float]:
    from cylindersplat.geometry import matrix_to_quaternion

    w, x, y, z = matrix_to_quaternion(rot).tolist()
    return [x, y, z, w]


def _pixels():
    i, j = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    return i.flatten(), j.flatten()


def _our_world_rays(c2w: torch.Tensor) -> torch.Tensor:
    i, j = _pixels()
    return uv_to_ray(j + 0.5, i + 0.5, H, W) @ c2w[:3, :3].T


def _nerfstudio_world_rays(transform_matrix: torch.Tensor) -> torch.Tensor:
    """nerfstudio Cameras.generate_rays for EQUIRECTANGULAR (fx = W/2, fy = H, cx = W/2, cy = H/2, pixel centres)."""
    i, j = _pixels()
    c0, c1 = (j + 0.5 - W / 2) / (W / 2), -(i + 0.5 - H / 2) / H
    theta, phi = -math.pi * c0, math.pi * (0.5 - c1)
    d = torch.stack((-torch.sin(theta) * torch.sin(phi), torch.cos(phi), -torch.cos(theta) * torch.sin(phi)), -1)
    return d @ transform_matrix[:3, :3].T


def _opensfm_world_rays(rotation: list[float]) -> torch.Tensor:
    """OpenSfM SphericalProjection::Backward of normalized coordinates ((px + 0.5 - size/2) / max(W, H))."""
    i, j = _pixels()
    x, y = (j + 0.5 - W / 2) / max(W, H), (i + 0.5 - H / 2) / max(W, H)
    lon, lat = x * 2 * math.pi, -y * 2 * math.pi
    bearing = torch.stack((torch.cos(lat) * torch.sin(lon), -torch.sin(lat), torch.cos(lat) * torch.cos(lon)), -1)
    r_cw = axis_angle_to_matrix(rotation)
    return bearing @ r_cw  # R_cw^T @ bearing, row-wise


def _stella_world_rays(c2w_tool: torch.Tensor) -> torch.Tensor:
    """stella_vslam equirectangular::convert_point_to_bearing (at pixel centres), rotated by its cam_pose_wc."""
    i, j = _pixels()
    lon, lat = ((j + 0.5) / W - 0.5) * 2 * math.pi, -((i + 0.5) / H - 0.5) * math.pi
    bearing = torch.stack((torch.cos(lat) * torch.sin(lon), -torch.sin(lat), torch.cos(lat) * torch.cos(lon)), -1)
    return bearing @ c2w_tool[:3, :3].T


def _write_all_formats(folder, cams):
    """The same cameras as every supported file: {name: (path, reader)}."""
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"pano_{k}.png" for k in range(len(cams))]
    (folder / "opencv_c2w.json").write_text(json.dumps({"frames": [{"image": n, "c2w": c.tolist()}
                                                                   for n, c in zip(names, cams)]}))
    (folder / "opengl_c2w.json").write_text(json.dumps({"convention": "opengl_c2w",
                                                        "poses": [(c @ GL).tolist() for c in cams]}))
    (folder / "opencv_w2c.json").write_text(json.dumps({"convention": "opencv_w2c",
                                                        "poses": [torch.linalg.inv(c).tolist() for c in cams]}))
    (folder / "opengl_w2c.json").write_text(json.dumps({"convention": "opengl_w2c",
                                                        "poses": [torch.linalg.inv(c @ GL).tolist() for c in cams]}))
    (folder / "transforms.json").write_text(json.dumps({
        "camera_model": "EQUIRECTANGULAR", "w": W, "h": H, "fl_x": W / 2, "fl_y": H, "cx": W / 2, "cy": H / 2,
        "frames": [{"file_path": n, "transform_matrix": (c @ GL).tolist()} for n, c in zip(names, cams)]}))
    shots = {}
    for n, c in zip(names, cams):
        r_cw = c[:3, :3].T
        shots[n] = {"camera": "v2 spherical", "rotation": _matrix_to_axis_angle(r_cw),
                    "translation": (-r_cw @ c[:3, 3]).tolist()}
    (folder / "reconstruction.json").write_text(json.dumps([{
        "cameras": {"v2 spherical": {"projection_type": "spherical", "width": W, "height": H}}, "shots": shots,
        "points": {}}]))
    (folder / "tum.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "".join(
        f"{k / 10} {' '.join(map(repr, c[:3, 3].tolist()))} "
        f"{' '.join(map(repr, _matrix_to_quaternion_xyzw(c[:3, :3])))}\n"
        for k, c in enumerate(cams)))
    (folder / "kitti.txt").write_text("".join(" ".join(map(repr, c[:3].flatten().tolist())) + "\n" for c in cams))
    return names, shots


def test_each_tool_sees_the_same_rays_through_the_same_pixels(tmp_path):
    cams = _cameras()
    _, shots = _write_all_formats(tmp_path, cams)
    records = read_transforms_json(tmp_path / "transforms.json")
    opensfm = read_opensfm(tmp_path / "reconstruction.json")
    tum, kitti = read_tum(tmp_path / "tum.txt"), read_kitti(tmp_path / "kitti.txt")
    for k, c in enumerate(cams):
        ours = _our_world_rays(c)
        torch.testing.assert_close(_nerfstudio_world_rays(c @ GL), _our_world_rays(records[k].c2w), atol=1e-9, rtol=0)
        torch.testing.assert_close(_nerfstudio_world_rays(c @ GL), ours, atol=1e-9, rtol=0)
        torch.testing.assert_close(_opensfm_world_rays(shots[f"pano_{k}.png"]["rotation"]),
                                   _our_world_rays(opensfm[k].c2w),
                                   atol=1e-9, rtol=0)
        torch.testing.assert_close(_stella_world_rays(tum[k].c2w), ours, atol=1e-7, rtol=0)
        torch.testing.assert_close(_stella_world_rays(kitti[k].c2w), ours, atol=1e-7, rtol=0)


def test_every_format_imports_the_same_cameras_and_renders_the_same(tmp_path):
    cams = _cameras()
    _write_all_formats(tmp_path, cams)
    reference = torch.stack([pose for _, pose, _ in read_poses_file(tmp_path / "opencv_c2w.json")]).double()
    torch.testing.assert_close(reference, cams, atol=1e-6, rtol=0)
    imported = {name: torch.stack([pose for _, pose, _ in read_poses_file(tmp_path / f"{name}.json")]).double()
                for name in ("opengl_c2w", "opencv_w2c", "opengl_w2c", "transforms")}
    imported["opensfm"] = torch.stack([r.c2w for r in read_opensfm(tmp_path / "reconstruction.json")])
    imported["tum"] = torch.stack([r.c2w for r in read_tum(tmp_path / "tum.txt")])
    imported["kitti"] = torch.stack([r.c2w for r in read_kitti(tmp_path / "kitti.txt")])
    scene = demo_room(4.0)
    image = render_equirect(scene, reference.float(), 8, 16)
    for name, c2w in imported.items():
        torch.testing.assert_close(c2w, reference, atol=1e-6, rtol=0, msg=name)
        out = render_equirect(scene, c2w.float(), 8, 16)
        torch.testing.assert_close(out.rgb, image.rgb, atol=1e-4, rtol=0, msg=name)
        torch.testing.assert_close(out.depth, image.depth, atol=1e-4, rtol=0, msg=name)


def test_non_panorama_files_are_refused_in_one_line(tmp_path):
    base = {"w": 64, "h": 32, "frames": [{"file_path": "a.png", "transform_matrix": torch.eye(4).tolist()}]}
    for extra, message in [({"camera_model": "OPENCV"}, "camera_model 'OPENCV' is not a 360° panorama"),
                           ({}, "no camera_model"),
                           ({"camera_model": "EQUIRECTANGULAR", "w": 50}, "twice as wide as high")]:
        (tmp_path / "transforms.json").write_text(json.dumps({**base, **extra}))
        with pytest.raises(ValueError, match=message) as info:
            read_poses_file(tmp_path / "transforms.json")
        assert "\n" not in str(info.value)
    (tmp_path / "r.json").write_text(json.dumps([{"cameras": {"c": {"projection_type": "perspective"}},
                                                  "shots": {"a.jpg": {"camera": "c", "rotation": [0, 0, 0],
                                                                      "translation": [0, 0, 0]}}}]))
    with pytest.raises(ValueError, match="projection_type 'perspective'"):
        read_opensfm(tmp_path / "r.json")


def test_a_nerfstudio_folder_loads_like_a_poses_json_folder(tmp_path):
    """transforms.json instead of poses.json: same images, depths (PNG mm and nerfstudio's .npy in mm), poses."""
    torch.manual_seed(0)
    cams = _cameras()[:2].float()
    ours, ns = tmp_path / "ours", tmp_path / "ns"
    for folder in (ours, ns / "images"):
        folder.mkdir(parents=True)
    depths = torch.rand(2, 8, 16) * 3 + 0.5
    frames, ns_frames = [], []
    for k in range(2):
        image = torch.rand(3, 8, 16)
        write_rgb(ours / f"p{k}.png", image)
        write_rgb(ns / "images" / f"p{k}.png", image)
        write_depth_png(ours / f"p{k}_depth.png", depths[k])
        frames.append({"image": f"p{k}.png", "c2w": cams[k].tolist(), "depth": f"p{k}_depth.png"})
        if k == 0:
            write_depth_png(ns / "images" / "d0.png", depths[k])
            depth_file = "images/d0.png"
        else:  # nerfstudio .npy depth: the same units as its PNGs (mm), not metres
            np.save(ns / "images" / "d1.npy", np.round(depths[k].numpy().astype(np.float64) * 1000))
            depth_file = "images/d1.npy"
        ns_frames.append({"file_path": f"images/p{k}.png", "transform_matrix": (cams[k].double() @ GL).tolist(),
                          "depth_file_path": depth_file})
    (ours / "poses.json").write_text(json.dumps({"frames": frames}))
    (ns / "transforms.json").write_text(json.dumps({"camera_model": "EQUIRECTANGULAR", "w": 16, "h": 8,
                                                    "frames": ns_frames[::-1]}))  # sorted by file name on reading
    a, b = load_panorama_folder(ours, (8, 16)), load_panorama_folder(ns, (8, 16))
    assert b.names == ["images/p0.png", "images/p1.png"]
    torch.testing.assert_close(b.images, a.images)
    torch.testing.assert_close(b.depths, a.depths, atol=1e-6, rtol=0)
    torch.testing.assert_close(b.c2w, a.c2w, atol=1e-6, rtol=0)
    # The same transforms.json given from elsewhere (--poses-file): its names stay relative to its own folder.
    moved = load_panorama_folder(ours, (8, 16), poses_file=ns / "transforms.json")
    torch.testing.assert_close(moved.images, a.images)


def test_import_poses_cli(tmp_path, capsys):
    cams = _cameras()
    names, _ = _write_all_formats(tmp_path / "src", cams)
    scene = tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    for name in names:
        Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(scene / "images" / name)
    # OpenSfM: shot names found under --images, positions scaled to metres.
    assert main(["data", "import-poses", str(tmp_path / "src" / "reconstruction.json"), "--from", "opensfm",
                 "--out", str(scene / "poses.json"), "--images", str(scene / "images"), "--scale", "2"]) == 0
    assert "wrote 3 poses" in capsys.readouterr().out
    entries = read_poses_file(scene / "poses.json")
    assert [name for name, _, _ in entries] == [f"images/{n}" for n in names]
    scaled = cams.clone()
    scaled[:, :3, 3] *= 2
    torch.testing.assert_close(torch.stack([p for _, p, _ in entries]).double(), scaled, atol=1e-5, rtol=0)
    # TUM (stella_vslam keyframes at t = frame / fps): poses matched to images by timestamp.
    for k in range(5):
        Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(scene / "images" / f"frame_{k:03d}.png")
    for name in names:
        (scene / "images" / name).unlink()
    assert main(["data", "import-poses", str(tmp_path / "src" / "tum.txt"), "--from", "tum", "--out",
                 str(scene / "tum_poses.json"), "--images", str(scene / "images"), "--fps", "20"]) == 0
    entries = read_poses_file(scene / "tum_poses.json")
    assert [name for name, _, _ in entries] == ["images/frame_000.png", "images/frame_002.png", "images/frame_004.png"]
    torch.testing.assert_close(torch.stack([p for _, p, _ in entries]).double(), cams, atol=1e-5, rtol=0)
    # Without images a trajectory becomes {"poses": [...]}, matched to a folder's images in name order.
    assert main(["data", "import-poses", str(tmp_path / "src" / "kitti.txt"), "--from", "kitti", "--out",
                 str(scene / "kitti.json")]) == 0
    assert "poses" in json.loads((scene / "kitti.json").read_text())
    assert main(["data", "import-poses", str(tmp_path / "src" / "tum.txt"), "--from", "tum", "--out",
                 str(scene / "x.json"), "--images", str(scene / "images"), "--fps", "100"]) == 1
    assert "frame 10 at 100 fps, but only 5 images" in capsys.readouterr().err
