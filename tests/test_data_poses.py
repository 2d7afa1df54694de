"""`cylindersplat data poses`: SfM on unposed panoramas (pycolmap), metric scale, the one-line errors.

The end-to-end test runs on the real Matterport3D triplet of the shared fixtures (skipped where it or pycolmap is
missing) and checks the recovered poses against the dataset's (DATASETS.md)."""

from __future__ import annotations

import json
import math
import shutil
import sys

import numpy as np
import pytest
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data.poses.alignment import align_similarity, pose_errors
from cylindersplat.data.poses.metric_scale import scale_from_camera_height, scale_from_depth


def _image(path, height, width, seed=0):
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (height, width, 3), dtype=np.uint8)).save(path)


def _fails_with(capsys, args, text) -> str:
    assert main(args) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if "error:" in line]  # besides progress lines ("sfm: ...")
    assert len(errors) == 1 and text in errors[0] and lines[-1] == errors[0], lines
    return errors[0]


def test_one_panorama_is_a_one_line_error(tmp_path, capsys):
    _image(tmp_path / "hall.png", 16, 32)
    _fails_with(capsys, ["data", "poses", str(tmp_path)],
                f"only one panorama in {tmp_path} (hall.png): poses need at least two overlapping panoramas")
    assert not (tmp_path / "poses.json").exists() and not (tmp_path / "sparse").exists()


def test_perspective_photos_are_refused(tmp_path, capsys):
    _image(tmp_path / "a.jpg", 16, 32)
    _image(tmp_path / "b.jpg", 30, 40)
    _fails_with(capsys, ["data", "poses", str(tmp_path)], "b.jpg is 40x30, not an equirectangular 360° panorama "
                "(width = 2 x height); data poses reconstructs 360° panoramas only: for perspective "
                "photos run COLMAP itself")
    assert not (tmp_path / "poses.json").exists()


def test_missing_pycolmap_names_the_install_command(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # as if the sfm extra were not installed
    _image(tmp_path / "a.png", 16, 32)
    _image(tmp_path / "b.png", 16, 32, seed=1)
    _fails_with(capsys, ["data", "poses", str(tmp_path)],
                "data poses needs pycolmap (COLMAP's Python bindings), which is not installed: "
                "pip install 'cylindersplat[sfm]'")
    assert not (tmp_path / "poses.json").exists()


def test_panoramas_without_overlap_say_what_to_do(tmp_path, capsys):
    pytest.importorskip("pycolmap")
    from scipy.ndimage import gaussian_filter

    for i in range(2):  # two unrelated textured scenes: features, but nothing in common
        rng = np.random.default_rng(10 + i)
        texture = gaussian_filter(rng.random((128, 256, 3)), (2, 2, 0))
        texture = (255 * (texture - texture.min()) / np.ptp(texture)).astype(np.uint8)
        Image.fromarray(texture).save(tmp_path / f"room_{i}.png")
    line = _fails_with(capsys, ["data", "poses", str(tmp_path), "--threads", "1"],
                       f"structure from motion failed on the 2 panoramas of {tmp_path} (room_0.png, room_1.png)")
    assert "take panoramas closer together" in line
    assert not (tmp_path / "poses.json").exists() and not (tmp_path / "sparse").exists()


# --- the real triplet ---------------------------------------------------------------------------------


def _true_poses(fixture) -> np.ndarray:
    from cylindersplat.data.pano_grf import panogrf_c2w

    return np.stack([panogrf_c2w(np.loadtxt(fixture / f / "rot.txt"),
                                 np.loadtxt(fixture / f / "tran.txt")).double().numpy()
                     for f in ("00", "01", "02")])


def _fixture_folder(fixture, folder, depth: bool):
    folder.mkdir()
    for f in ("00", "01", "02"):
        shutil.copy(fixture / f / "rgb.png", folder / f"pano_{f}.png")
        if depth:
            shutil.copy(fixture / f / "depth.png", folder / f"pano_{f}_depth.png")


def _poses(path) -> np.ndarray:
    frames = sorted(json.loads(path.read_text())["frames"], key=lambda f: f["image"])
    return np.array([f["c2w"] for f in frames])


def test_data_poses_on_the_real_triplet(pano_grf_fixture, tmp_path, capsys):
    pytest.importorskip("pycolmap")
    from cylindersplat.data.poses import read_colmap

    fixture = pano_grf_fixture / "00000007"
    folder = tmp_path / "scene"
    _fixture_folder(fixture, folder, depth=True)
    assert main(["data", "poses", str(folder), "--threads", "2"]) == 0
    out = capsys.readouterr()
    assert "registered 3 of 3 panoramas" in out.out and "sfm: matching (exhaustive)" in out.err
    estimated = _poses(folder / "poses.json")
    np.testing.assert_allclose(estimated[0], np.eye(4), atol=1e-12)  # the first panorama at the origin
    errors = pose_errors(estimated, _true_poses(fixture))
    assert max(errors.rotation_deg) < 1.0
    assert errors.centre_over_baseline < 0.02
    assert errors.similarity.scale == pytest.approx(1.0, rel=0.02)  # metric: the true scale within 2 %
    # The COLMAP model beside it is in the same frame and units, and an input folder reads the poses.
    model = read_colmap(folder / "sparse" / "0")
    np.testing.assert_allclose(np.stack([r.c2w.numpy() for r in model]), estimated, atol=1e-9)
    from cylindersplat.data.folder import FolderDataset

    assert len(FolderDataset(folder).example(0).frames) == 3


@pytest.mark.slow
def test_scale_from_a_blurred_depth_prior(pano_grf_fixture, tmp_path, capsys):
    pytest.importorskip("pycolmap")
    from scipy.ndimage import gaussian_filter

    fixture = pano_grf_fixture / "00000007"
    folder = tmp_path / "scene"
    _fixture_folder(fixture, folder, depth=False)
    for f in ("00", "01", "02"):  # a soft prior: the depth blurred by 8 px, written as file:blur
        mm = np.asarray(Image.open(fixture / f / "depth.png")).astype(np.float64)
        out = folder / "priors" / "blur" / f"pano_{f}.png"
        out.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(gaussian_filter(mm, 8).round().astype(np.uint16)).save(out)
    assert main(["data", "poses", str(folder), "--depth-prior", "file:blur", "--threads", "2"]) == 0
    assert "from the depth prior file:blur" in capsys.readouterr().out
    errors = pose_errors(_poses(folder / "poses.json"), _true_poses(fixture))
    assert errors.similarity.scale == pytest.approx(1.0, rel=0.15)


# --- scale and alignment, on hand-made numbers ---------------------------------------------------------


def test_scale_from_depth_is_the_median_ratio():
    # A panorama at the origin sees points at distance r (model units) whose depth is 2.5 r metres; 10 % of
    # the observations have a wrong depth: the median ignores them.
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(200, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    distance = rng.uniform(1, 4, 200)
    xyz = directions * distance[:, None]
    import torch

    from cylindersplat.geometry.equirect import ray_to_uv

    u, v = ray_to_uv(torch.from_numpy(directions), 64, 128)
    xy = np.stack([u.numpy(), v.numpy()], -1)
    depth = np.zeros((64, 128))
    cols, rows = np.floor(xy[:, 0]).astype(int) % 128, np.floor(xy[:, 1]).astype(int).clip(0, 63)
    depth[rows, cols] = 2.5 * distance
    depth[rows[:20], cols[:20]] = 50.0  # outliers
    # pixels hit twice keep the last write: vote only with observations whose pixel holds their own depth
    keep = np.isclose(depth[rows, cols], 2.5 * distance) | (np.arange(200) < 20)
    estimate = scale_from_depth({"a": (xy[keep], xyz[keep])}, {"a": np.eye(4)}, {"a": depth}, {"a": (64, 128)})
    assert estimate.scale == pytest.approx(2.5, rel=1e-9)
    assert estimate.votes == keep.sum()


def test_scale_from_camera_height():
    # Floor points 0.8 model units below a camera, a table top at 0.4 below and walls: with a 1.6 m camera
    # height, 2 m per unit (the floor is the lowest surface: its points fill the top quantiles of the heights).
    rng = np.random.default_rng(1)
    ground = np.column_stack([rng.uniform(-0.3, 0.3, 100), np.full(100, 0.8), rng.uniform(-0.3, 0.3, 100)])
    table = np.column_stack([rng.uniform(0.3, 0.6, 40), np.full(40, 0.4), rng.uniform(-0.2, 0.2, 40)])
    walls = np.column_stack([rng.uniform(-3, 3, 50), rng.uniform(-1, 0.5, 50), np.full(50, 3.0)])
    c2w = np.eye(4)
    c2w[:3, 3] = [1.0, -2.0, 0.5]
    obs = {"a": (np.zeros((190, 2)), np.concatenate([ground, table, walls]) + c2w[:3, 3])}
    assert scale_from_camera_height(obs, {"a": c2w}, 1.6).scale == pytest.approx(2.0, rel=1e-9)


def test_alignment_undoes_a_hand_made_similarity():
    angle = math.radians(30)
    rot = np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]])
    reference = np.stack([np.eye(4)] * 3)
    reference[:, 2, 3] = [0.5, 0.0, -0.5]  # collinear centres: the rotation must come from the cameras
    estimated = reference.copy()
    for pose in estimated:  # estimated = reference mapped by x -> (rot^T (x - t)) / s
        pose[:3, :3] = rot.T @ pose[:3, :3]
        pose[:3, 3] = rot.T @ (pose[:3, 3] - np.array([1.0, 2.0, 3.0])) / 4.0
    sim = align_similarity(estimated, reference)
    assert sim.scale == pytest.approx(4.0)
    np.testing.assert_allclose(sim.rotation, rot, atol=1e-12)
    np.testing.assert_allclose(sim.translation, [1.0, 2.0, 3.0], atol=1e-12)
    errors = pose_errors(estimated, reference)
    assert max(errors.rotation_deg) < 1e-6 and max(errors.centre) < 1e-12 and errors.baseline == pytest.approx(1.0)
