"""360Loc layout, view protocols, Sample/collate, image/depth I/O and resizing."""

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.data import Loc360Dataset, Sample, ViewSplit, collate_samples, select_views
from cylindersplat.data.depth_prior import NoPrior
from cylindersplat.data.io import read_depth_png, read_rgb, resize_depth, write_depth_png, write_rgb
from cylindersplat.data.views import all_between, all_between_span, all_between_starts


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
    with pytest.raises(ValueError, match="not valid JSON"):
        Loc360Dataset(tmp_path)


# 360Loc with 2, 3, 4 context views and wider gaps: (views, gap, layout) -> (contexts, targets) of the three
# examples of a 12-frame sequence with times_per_sequence=3, worked out by hand from the sampler
# start_i = int((12 - span - 1) * i / 2), span = first to last context.
LOC360_CASES = {
    (2, 3, "spaced"): [((0, 3), range(0, 4)), ((4, 7), range(4, 8)), ((8, 11), range(8, 12))],  # span 3, starts 0 4 8
    (3, 3, "spaced"): [((0, 3, 6), range(0, 7)), ((2, 5, 8), range(2, 9)), ((5, 8, 11), range(5, 12))],  # span 6: 0 2 5
    (4, 3, "spaced"): [((0, 3, 6, 9), range(0, 10)), ((1, 4, 7, 10), range(1, 11)), ((2, 5, 8, 11), range(2, 12))],
    (2, 6, "spaced"): [((0, 6), range(0, 7)), ((2, 8), range(2, 9)), ((5, 11), range(5, 12))],  # span 6: 0 2 5
    (2, 10, "spaced"): [((0, 10), range(0, 11)), ((0, 10), range(0, 11)), ((1, 11), range(1, 12))],  # span 10: 0 0 1
    (3, 5, "spaced"): [((0, 5, 10), range(0, 11)), ((0, 5, 10), range(0, 11)), ((1, 6, 11), range(1, 12))],
    # the released three_sample / four_sample (span gap+1 / gap+2, targets strictly inside the outer contexts)
    (3, 3, "released"): [((0, 3, 4), (1, 2, 3)), ((3, 6, 7), (4, 5, 6)), ((7, 10, 11), (8, 9, 10))],  # span 4: 0 3 7
    (4, 3, "released"): [((0, 1, 4, 5), (1, 2, 3, 4)), ((3, 4, 7, 8), (4, 5, 6, 7)), ((6, 7, 10, 11), (7, 8, 9, 10))],
    (3, 6, "released"): [((0, 6, 7), range(1, 7)), ((2, 8, 9), range(3, 9)), ((4, 10, 11), range(5, 11))],  # span 7
    (2, 3, "released"): [((0, 3), range(0, 4)), ((4, 7), range(4, 8)), ((8, 11), range(8, 12))],  # = two_sample
}


@pytest.mark.parametrize("views,gap,layout", list(LOC360_CASES))
def test_loc360_context_views_and_gaps(tmp_path, views, gap, layout):
    from cylindersplat.data import make_dataset

    write_loc360(tmp_path, frames=12)
    ds = make_dataset("loc360", tmp_path, views="all_between", depth_prior="constant:2", times_per_sequence=3,
                      context_views=views, gap=gap, context_layout=layout)
    assert len(ds) == 3
    for index, (context, target) in enumerate(LOC360_CASES[views, gap, layout]):
        ref = ds.example(index)
        assert ref.views.context == tuple(context) and ref.views.target == tuple(target)
        assert ref.metadata == {"start": context[0], "gap": gap, "context_views": views, "context_layout": layout}
    s = ds[2]  # the loaded sample: frames k stand at x = 0.47 k
    context, target = LOC360_CASES[views, gap, layout][2]
    assert s.metadata["context_indices"] == list(context) and s.metadata["target_indices"] == list(target)
    assert s.context_images.shape[0] == views and s.target_images.shape[0] == len(target)
    torch.testing.assert_close(s.context_poses[:, 0, 3], 0.47 * torch.tensor(context, dtype=torch.float32))
    torch.testing.assert_close(s.target_poses[:, 0, 3], 0.47 * torch.tensor(list(target), dtype=torch.float32))
    assert s.metadata["baseline"] == pytest.approx(0.47 * (context[-1] - context[0]), rel=1e-5)
    assert all_between_span(gap, views, layout) == context[-1] - context[0]


def test_loc360_views_errors(tmp_path):
    from cylindersplat.data import make_dataset

    write_loc360(tmp_path, frames=12)
    with pytest.raises(ValueError, match="span 12 frames, but the longest sequence has 12"):
        make_dataset("loc360", tmp_path, views="all_between", depth_prior="constant:2", context_views=4, gap=4)
    assert len(Loc360Dataset(tmp_path, context_views=4, gap=4)) == 0  # the class itself stays usable (data priors)
    with pytest.raises(ValueError, match="2, 3 and 4 context views only"):
        Loc360Dataset(tmp_path, context_views=5, context_layout="released")
    with pytest.raises(ValueError, match="context views >= 2"):
        Loc360Dataset(tmp_path, context_views=1)
    with pytest.raises(ValueError, match="gap between context frames"):
        all_between(0, 0)
    with pytest.raises(ValueError, match="unknown all_between layout"):
        all_between(0, 3, 3, "nested")


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
    with pytest.raises(ValueError, match="context_priors"):
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
