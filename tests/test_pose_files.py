"""Pose files of COLMAP, Agisoft Metashape and OpenMVG -> our OpenCV c2w (cylindersplat.data.poses).

Each reader is checked against the tool's own definition of its panorama camera (COLMAP: pycolmap's
``cam_ray_from_img``; Metashape: the user manual's spherical projection; OpenMVG: ``Camera_Spherical.hpp``'s
``project``), re-derived here, on the files in tests/data (README there names their sources), and by exact round
trips (our poses -> their format -> back)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from cylindersplat.data.poses import (
    PoseRecord,
    c2w_to_colmap,
    colmap_to_c2w,
    read_colmap,
    read_metashape_xml,
    read_openmvg,
    write_colmap,
    write_metashape_xml,
    write_openmvg,
)
from cylindersplat.data.poses.alignment import pose_errors
from cylindersplat.data.poses.colmap_model import read_colmap_model
from cylindersplat.geometry.equirect import ray_to_uv

DATA = Path(__file__).parent / "data"
# The fixture's true poses (DATASETS.md: identity rotations, centres 0.5 m apart along z; OpenCV c2w as
# data.pano_grf makes them: frame 00 at z = +0.5).
TRUE_M3D = np.stack([np.eye(4)] * 3)
TRUE_M3D[:, 2, 3] = [0.5, 0.0, -0.5]


def _random_poses(n: int, seed: int = 0) -> list[PoseRecord]:
    rng = np.random.default_rng(seed)
    records = []
    for i in range(n):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = rot, rng.normal(size=3) * 3
        records.append(PoseRecord(f"pano_{i:02d}.jpg", torch.from_numpy(c2w)))
    return records


def _uv(direction: np.ndarray, height: int, width: int) -> np.ndarray:
    u, v = ray_to_uv(torch.from_numpy(direction), height, width)
    return np.array([float(u), float(v)])


# --- COLMAP -------------------------------------------------------------------------------------------


def test_colmap_equirectangular_camera_is_our_mapping():
    pycolmap = pytest.importorskip("pycolmap")
    if not hasattr(pycolmap.CameraModelId, "EQUIRECTANGULAR"):
        pytest.skip("this pycolmap has no EQUIRECTANGULAR camera")
    from cylindersplat.geometry.equirect import uv_to_ray

    camera = pycolmap.Camera.create_from_model_id(1, pycolmap.CameraModelId.EQUIRECTANGULAR, 1.0, 64, 32)
    uv = np.array([[0.5, 0.5], [32.0, 16.0], [48.25, 7.5], [5.0, 30.0], [63.5, 31.5]])
    theirs = camera.cam_ray_from_img(uv)
    ours = uv_to_ray(torch.from_numpy(uv[:, 0]), torch.from_numpy(uv[:, 1]), 32, 64).numpy()
    np.testing.assert_allclose(theirs, ours, atol=1e-9)


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_colmap_real_model_of_the_m3d_triplet(kind):
    records = read_colmap(DATA / "colmap_m3d_sfm" / kind)
    assert [r.image for r in records] == ["pano_00.png", "pano_01.png", "pano_02.png"]
    # COLMAP's first image: cam_from_world quaternion and translation as in images.txt
    pose = records[0].c2w.numpy()
    np.testing.assert_allclose(np.linalg.inv(pose)[:3, 3], [0.0025641723866568918, -0.00040092917375090771,
                                                             -4.9987947674832665], atol=1e-12)
    errors = pose_errors(np.stack([r.c2w.numpy() for r in records]), TRUE_M3D)
    assert max(errors.rotation_deg) < 0.1 and errors.centre_over_baseline < 0.005
    assert errors.similarity.scale == pytest.approx(0.1, rel=0.01)  # SfM units: 10 per metre here


def test_colmap_text_and_binary_of_one_model_agree():
    txt, bin_ = read_colmap(DATA / "colmap_m3d_sfm" / "txt"), read_colmap(DATA / "colmap_m3d_sfm" / "bin")
    for a, b in zip(txt, bin_):
        assert a.image == b.image
        torch.testing.assert_close(a.c2w, b.c2w, atol=1e-15, rtol=0)


@pytest.mark.parametrize("kind", ["txt", "bin"])
def test_colmap_round_trip_is_exact(tmp_path, kind):
    records = _random_poses(5)
    write_colmap(tmp_path / "model", records, 2048, 1024, kind)
    back = read_colmap(tmp_path / "model")
    assert [r.image for r in back] == [r.image for r in records]
    for a, b in zip(records, back):
        torch.testing.assert_close(a.c2w, b.c2w, atol=1e-14, rtol=0)
    camera = read_colmap_model(tmp_path / "model").cameras[1]
    assert (camera.model, camera.width, camera.height) == ("EQUIRECTANGULAR", 2048, 1024)


def test_colmap_convention_by_hand():
    # cam_from_world = 90 deg about +y (quaternion w = x = cos45... here (cos45, 0, sin45, 0)), t = (1, 2, 3):
    # x_cam = R x_world + t, so the centre is -R^T t and the camera's +z (forward) is row 3 of R in the world.
    q = [math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0]
    c2w = colmap_to_c2w(q, [1.0, 2.0, 3.0]).numpy()
    rot = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    np.testing.assert_allclose(c2w[:3, :3], rot.T, atol=1e-15)
    np.testing.assert_allclose(c2w[:3, 3], -rot.T @ [1.0, 2.0, 3.0], atol=1e-15)
    qvec, tvec = c2w_to_colmap(c2w)
    np.testing.assert_allclose(qvec, q, atol=1e-15)
    np.testing.assert_allclose(tvec, [1.0, 2.0, 3.0], atol=1e-14)


def _colmap_preset_rotations() -> list[np.ndarray]:
    """cam_from_pano of COLMAP's panorama_sfm.py default preset (4 yaws; pitches -35 and +35, the upper ring turned
    by half a step): Rx(-pitch) @ Ry(-yaw), scipy's intrinsic "XY" Euler angles."""
    def rx(deg):
        a = math.radians(deg)
        return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])

    def ry(deg):
        a = math.radians(deg)
        return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])

    out = []
    for pitch in (-35.0, 35.0):
        for yaw in np.arange(4) * 90.0 + (45.0 if pitch > 0 else 0.0):
            out.append(rx(-pitch) @ ry(-yaw))
    return out


def test_colmap_panorama_rig_gives_the_panorama_pose(tmp_path):
    """A model of virtual pinhole cameras cut from panoramas (COLMAP's panorama workflow) -> the panoramas' poses."""
    from cylindersplat.data.poses.colmap_model import ColmapCamera, ColmapImage, ColmapModel, write_colmap_model

    panoramas = _random_poses(3, seed=4)
    images, image_id = {}, 1
    for pano in panoramas:
        for k, cam_from_pano in enumerate(_colmap_preset_rotations()):
            c2w = pano.c2w.numpy().copy()
            c2w[:3, :3] = c2w[:3, :3] @ cam_from_pano.T  # world_from_pano @ pano_from_cam
            qvec, tvec = c2w_to_colmap(c2w)
            images[image_id] = ColmapImage(f"pano_camera{k}/{pano.image}", 1, qvec, tvec)
            image_id += 1
    write_colmap_model(tmp_path, ColmapModel({1: ColmapCamera("PINHOLE", 256, 256, [128.0, 128.0, 128.0, 128.0])},
                                             images, {}), "bin")
    back = read_colmap(tmp_path)
    assert [r.image for r in back] == [p.image for p in panoramas]
    for a, b in zip(panoramas, back):
        torch.testing.assert_close(a.c2w, b.c2w, atol=1e-9, rtol=0)


def test_colmap_perspective_model_is_refused(tmp_path):
    write_colmap(tmp_path, _random_poses(2), 64, 32, "txt")
    text = (tmp_path / "cameras.txt").read_text().replace("EQUIRECTANGULAR 64 32 64.0 32.0",
                                                          "PINHOLE 64 32 50 50 32 16")
    (tmp_path / "cameras.txt").write_text(text)
    with pytest.raises(ValueError, match="perspective camera and is not named <virtual camera>/<panorama>"):
        read_colmap(tmp_path)


# --- Metashape ----------------------------------------------------------------------------------------


def _metashape_project(world: np.ndarray, transform: np.ndarray, chunk: np.ndarray, width: int) -> np.ndarray:
    """Metashape's spherical projection (user manual, camera models): the point in the camera frame (chunk
    similarity, then the camera transform, both undone), x = atan2(X, Z), y = atan2(Y, sqrt(X^2 + Z^2)),
    u = w/2 + f x, v = h/2 + f y with f = w / (2 pi)."""
    local = np.linalg.solve(chunk, np.append(world, 1.0))
    X, Y, Z, _ = np.linalg.solve(transform, local)
    f = width / (2 * math.pi)
    return np.array([width / 2 + f * math.atan2(X, Z), width / 4 + f * math.atan2(Y, math.hypot(X, Z))])


def test_metashape_real_layout_and_projection():
    records = read_metashape_xml(DATA / "metashape_spherical.xml")
    assert [r.image for r in records] == ["R0010001", "R0010002"]  # camera 2 has no transform: not aligned
    chunk = np.eye(4)
    chunk[:3, :3] = 2 * np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    chunk[:3, 3] = [10, 20, 30]
    transform = np.array([[0, 0, 1, 1.5], [0, 1, 0, 0], [-1, 0, 0, 0.25], [0, 0, 0, 1]], dtype=float)
    pose = records[1].c2w.numpy()
    np.testing.assert_allclose(pose[:3, 3], (chunk @ transform)[:3, 3])  # centre in the chunk's world
    for world in ([14.0, 22.0, 31.0], [3.0, 19.0, 35.0], [9.0, 30.0, 28.0]):
        world = np.array(world)
        ours = _uv(np.linalg.inv(pose)[:3] @ np.append(world, 1.0), 2880, 5760)
        np.testing.assert_allclose(ours, _metashape_project(world, transform, chunk, 5760), atol=1e-9)


def test_metashape_round_trip_is_exact(tmp_path):
    records = _random_poses(4, seed=1)
    write_metashape_xml(tmp_path / "cameras.xml", records, 2048, 1024)
    back = read_metashape_xml(tmp_path / "cameras.xml")
    for a, b in zip(records, back):
        assert a.image == b.image
        torch.testing.assert_close(a.c2w, b.c2w, atol=1e-15, rtol=0)


def test_metashape_frame_sensor_is_refused(tmp_path):
    text = (DATA / "metashape_spherical.xml").read_text().replace('sensor_id="0" component_id="0" label="R0010002"',
                                                                   'sensor_id="1" component_id="0" label="R0010002"')
    (tmp_path / "cameras.xml").write_text(text)
    with pytest.raises(ValueError, match=r"R0010002.*sensor '1' is of type 'frame'; "
                                         r"cylindersplat needs 360° panoramas"):
        read_metashape_xml(tmp_path / "cameras.xml")


# --- OpenMVG ------------------------------------------------------------------------------------------


def _openmvg_project(world: np.ndarray, rotation: np.ndarray, center: np.ndarray, width: int, height: int):
    """OpenMVG's Intrinsic_Spherical::project: X = R (x - C); lon = atan2(X, Z), lat = atan2(-Y, sqrt(X^2 + Z^2));
    cam2ima: (lon / 2pi * size + w/2, lat / 2pi * size + h/2) with size = max(w, h)."""
    X, Y, Z = rotation @ (world - center)
    lon, lat = math.atan2(X, Z), math.atan2(-Y, math.hypot(X, Z))
    size = max(width, height)
    return np.array([lon / (2 * math.pi) * size + width / 2, lat / (2 * math.pi) * size + height / 2])


def test_openmvg_layout_and_projection():
    records = read_openmvg(DATA / "openmvg_spherical_sfm_data.json")
    assert [r.image for r in records] == ["00000.jpg", "00001.jpg"]  # view 2 has no pose
    rotation = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    center = np.array([0.3, 0.2, 1.0])
    pose = records[1].c2w.numpy()
    mirror = np.diag([1.0, -1.0, 1.0])  # our world is OpenMVG's seen in a y mirror (data.poses.openmvg)
    for world in ([1.0, 2.0, 3.0], [-2.0, 0.5, 1.5], [0.4, -1.0, -2.0]):
        world = np.array(world)
        ours = _uv(np.linalg.inv(pose)[:3] @ np.append(mirror @ world, 1.0), 960, 1920)
        np.testing.assert_allclose(ours, _openmvg_project(world, rotation, center, 1920, 960), atol=1e-9)


def test_openmvg_round_trip_is_exact(tmp_path):
    records = _random_poses(4, seed=2)
    write_openmvg(tmp_path / "sfm_data.json", records, 2048, 1024)
    back = read_openmvg(tmp_path / "sfm_data.json")
    for a, b in zip(records, back):
        assert a.image == b.image
        torch.testing.assert_close(a.c2w, b.c2w, atol=1e-15, rtol=0)


def test_openmvg_pinhole_intrinsic_is_refused(tmp_path):
    text = (DATA / "openmvg_spherical_sfm_data.json").read_text().replace('"spherical"', '"pinhole_radial_k3"')
    (tmp_path / "sfm_data.json").write_text(text)
    with pytest.raises(ValueError, match="is 'pinhole_radial_k3'; cylindersplat needs 360° panoramas"):
        read_openmvg(tmp_path / "sfm_data.json")


# --- import-poses -------------------------------------------------------------------------------------


def test_import_poses_from_colmap_names_the_images(tmp_path, capsys):
    from cylindersplat.cli import main
    from cylindersplat.data.folder import read_poses_file

    images = tmp_path / "scene"
    images.mkdir()
    for name in ("pano_00.png", "pano_01.png", "pano_02.png"):
        (images / name).write_bytes(b"")
    out = images / "poses.json"
    assert main(["data", "import-poses", str(DATA / "colmap_m3d_sfm" / "txt"), "--from", "colmap", "--out", str(out),
                 "--images", str(images), "--scale", "0.1"]) == 0
    entries = read_poses_file(out)
    assert [e[0] for e in entries] == ["pano_00.png", "pano_01.png", "pano_02.png"]
    centres = np.stack([e[1][:3, 3].double().numpy() for e in entries])
    assert np.linalg.norm(centres[0] - centres[2]) == pytest.approx(1.0, rel=0.01)  # 1 m baseline in metres


def test_import_poses_from_metashape_finds_labels_without_suffix(tmp_path):
    from cylindersplat.cli import main
    from cylindersplat.data.folder import read_poses_file

    for name in ("R0010001.jpg", "R0010002.jpg"):
        (tmp_path / name).write_bytes(b"")
    out = tmp_path / "poses.json"
    assert main(["data", "import-poses", str(DATA / "metashape_spherical.xml"), "--from", "metashape", "--out",
                 str(out),
                 "--images", str(tmp_path)]) == 0
    assert [e[0] for e in read_poses_file(out)] == ["R0010001.jpg", "R0010002.jpg"]
