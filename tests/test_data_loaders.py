"""360Loc layout, view protocols, Sample/collate, image/depth I/O and resizing."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.data import Loc360Dataset, Sample, ViewSplit, collate_samples, select_views
from cylindersplat.data.depth_prior import NoPrior
from cylindersplat.data.io import read_depth_png, read_rgb, resize_depth, write_depth_png, write_rgb
from cylindersplat.data.views import all_between, all_between_starts


def write_loc360(root, location="atrium", seq="daytime_360_0", frames=6, size=(8, 16), folder="mapping"):
    d = root / location / folder / seq
    (d / "image").mkdir(parents=True)
    poses = {}
    rng = np.random.default_rng(1)
    for k in range(frames):
        name = f"{k:05d}.jpg"
        Image.fromarray(rng.integers(0, 256, (*size, 3), dtype=np.uint8)).save(d / "image" / name)
        c2w = np.eye(4)
        c2w[:3, 3] = [0.47 * k, 0.0, 0.0]
        poses[name] = c2w.tolist()
    (d / "camera_pose.json").write_text(json.dumps(poses))
    return d


def test_loc360_layout_and_protocol(tmp_path):
    write_loc360(tmp_path)
    write_loc360(tmp_path, location="hall")  # a train location, not in the test split
    with pytest.raises(ValueError, match="has none of its own; choose one"):  # no silent zero prior by default
        Loc360Dataset(tmp_path, split="test", times_per_sequence=3)[0]
    ds = Loc360Dataset(tmp_path, split="test", times_per_sequence=3, depth_prior=NoPrior())
    assert len(ds) == 3
    s = ds[2]  # starts 0, 1, 2 for 6 frames and gap 3
    assert s.metadata["context_indices"] == [2, 5] and s.metadata["target_indices"] == [2, 3, 4, 5]
    assert s.metadata["scene"] == "atrium-daytime_360_0" and s.metadata["dataset"] == "360loc"
    assert s.metadata["baseline"] == pytest.approx(3 * 0.47, rel=1e-5)
    assert s.target_images.shape == (4, 3, 8, 16) and s.target_depths is None
    assert torch.equal(s.target_images[0], s.context_images[0])  # contexts are targets too
    assert torch.allclose(s.context_poses[1, :3, 3], torch.tensor([5 * 0.47, 0, 0]))
    assert len(Loc360Dataset(tmp_path, split="train", times_per_sequence=2)) == 2


def test_loc360_errors(tmp_path):
    d = write_loc360(tmp_path)
    with pytest.raises(ValueError, match="no 360Loc sequences"):
        Loc360Dataset(tmp_path, split="train")
    poses = json.loads((d / "camera_pose.json").read_text())
    poses["00001.jpg"] = [[1, 0, 0]]
    (d / "camera_pose.json").write_text(json.dumps(poses))
    with pytest.raises(ValueError, match="camera_pose.json.*00001.jpg"):
        Loc360Dataset(tmp_path)
    (d / "camera_pose.json").write_text("{not json")
    with pytest.raises(ValueError, match="invalid JSON"):
        Loc360Dataset(tmp_path)


def test_view_protocols():
    assert select_views(3, "two_view") == ViewSplit((0, 2), (1,))
    assert select_views(9, "two_view") == ViewSplit((0, 8), (4,))  # Residential: 0, 8 -> 4
    assert select_views(3, "one_view") == ViewSplit((1,), (0, 2))
    assert select_views(5, "n_view") == ViewSplit((0, 1, 3, 4), (2,))
    assert all_between(2, 3) == ViewSplit((2, 5), (2, 3, 4, 5))
    assert all_between_starts(10, 3, 4) == [0, 2, 4, 6]
    with pytest.raises(ValueError, match="unknown view protocol"):
        select_views(3, "three_view")
    with pytest.raises(ValueError, match="out of range"):
        select_views(3, ViewSplit((0, 3), (1,)))


def test_sample_validation_and_collate():
    def make(t_depth=True):
        return Sample(torch.rand(2, 3, 4, 8), torch.rand(2, 4, 8), torch.eye(4).expand(2, 4, 4),
                      torch.rand(1, 3, 4, 8), torch.rand(1, 4, 8) if t_depth else None, torch.eye(4)[None],
                      {"scene": "a"})
    batch = collate_samples([make(), make()])
    assert batch.context_images.shape == (2, 2, 3, 4, 8) and batch.target_depths.shape == (2, 1, 4, 8)
    assert collate_samples([make(), make(False)]).target_depths is None
    with pytest.raises(ValueError, match="context_depths"):
        Sample(torch.rand(2, 3, 4, 8), torch.rand(2, 4, 9), torch.eye(4).expand(2, 4, 4),
               torch.rand(1, 3, 4, 8), None, torch.eye(4)[None])
    assert make().to("cpu").num_context == 2


def test_rgb_depth_roundtrip_and_resize(tmp_path):
    img = torch.rand(3, 8, 16)
    write_rgb(tmp_path / "a.png", img)
    assert torch.allclose(read_rgb(tmp_path / "a.png"), img, atol=0.5 / 255 + 1e-6)
    # Lanczos resize equals PIL's on the stored 8-bit image.
    ref = np.asarray(Image.open(tmp_path / "a.png").resize((8, 4), Image.LANCZOS), dtype=np.float32) / 255
    assert torch.allclose(read_rgb(tmp_path / "a.png", size=(4, 8)), torch.from_numpy(ref).permute(2, 0, 1))
    depth = torch.rand(8, 16) * 5 + 0.5
    depth[0, :2] = 0
    write_depth_png(tmp_path / "d.png", depth)
    assert torch.allclose(read_depth_png(tmp_path / "d.png"), depth, atol=5e-4)
    assert Image.open(tmp_path / "d.png").mode.startswith("I;16")


def test_resize_depth_area_ignores_holes_and_nearest():
    d = torch.tensor([[1.0, 3.0, 0.0, 0.0], [5.0, 0.0, 0.0, 0.0]])
    assert torch.equal(resize_depth(d, (1, 2)), torch.tensor([[3.0, 0.0]]))  # mean of 1, 3, 5; empty block -> 0
    n = resize_depth(torch.arange(16.0).view(2, 8), (1, 2), mode="nearest")
    assert torch.equal(n, torch.tensor([[10.0, 14.0]]))  # centres at row 1, cols 2 and 6
    assert resize_depth(torch.ones(3, 6), (2, 4)).shape == (2, 4)  # non-integer factor -> nearest
    with pytest.raises(ValueError, match="resize mode"):
        resize_depth(d, (1, 2), mode="bilinear")


def test_io_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.png"):
        read_rgb(tmp_path / "nope.png")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="bad.png"):
        read_rgb(tmp_path / "bad.png")
    Image.fromarray(np.zeros((8, 16, 3), np.uint8)).save(tmp_path / "rgb_as_depth.png")
    with pytest.raises(ValueError, match="16-bit"):
        read_depth_png(tmp_path / "rgb_as_depth.png")
