"""PanoGRF/PanSplat layout: the real Matterport3D triplet proves the pose convention; tiny
written fixtures exercise the loader and its error messages."""

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.data import PanoGRFDataset, collate_samples, panogrf_c2w, reprojection_consistency
from cylindersplat.data.depth_prior import GroundTruthPrior, NoPrior


@pytest.fixture(scope="module")
def real_sample(pano_grf_fixture):  # conftest.py
    return PanoGRFDataset(pano_grf_fixture, resolution=(256, 512), depth_prior=GroundTruthPrior())[0]


def test_real_triplet_loads(real_sample):
    s = real_sample
    assert s.context_images.shape == (2, 3, 256, 512) and s.target_images.shape == (1, 3, 256, 512)
    assert s.target_depths.shape == (1, 256, 512) and s.context_gt_depths.shape == (2, 256, 512)
    assert s.metadata["baseline"] == pytest.approx(1.0) and s.metadata["scene"] == "00000007"
    # Identity rotations stay identity; the three centres lie on the z axis, 0.5 m apart.
    assert torch.allclose(s.context_poses[:, :3, :3], torch.eye(3).expand(2, 3, 3))
    assert torch.allclose(s.context_poses[:, :3, 3], torch.tensor([[0, 0, 0.5], [0, 0, -0.5]]))
    valid = s.target_depths > 0
    assert 0.9 < valid.float().mean() and s.target_depths[valid].max() < 10.0


def _check(sample, flip_translation=False):
    src = (sample.target_images[0], sample.target_depths[0], sample.target_poses[0])
    results = []
    for k in range(2):
        pose = sample.context_poses[k].clone()
        if flip_translation:
            pose[:3, 3] *= -1
        results.append(reprojection_consistency(*src, sample.context_images[k], sample.context_gt_depths[k], pose,
                                                rel_tol=0.1))
    return results


def test_real_triplet_reprojection_consistency(real_sample):
    good = _check(real_sample)
    bad = _check(real_sample, flip_translation=True)
    for g, b in zip(good, bad):
        # Measured at 256x512: L1 0.026 / 0.017, consistent 93.4% / 97.3%.
        assert 0.01 < g.weighted_l1 < 0.035
        assert g.consistent_fraction > 0.92 and g.valid_fraction > 0.99
        assert b.weighted_l1 > 4 * g.weighted_l1
        assert b.consistent_fraction < 0.6


def test_panogrf_pose_conversion_matches_pansplat_up_to_world_rotation():
    # PanSplat: c2w = W @ [R|t] @ diag(1,-1,-1,1) with a fixed W; ours differ by one world rotation,
    # so relative poses must coincide.
    w = torch.tensor([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=torch.float64)
    c = torch.diag(torch.tensor([1.0, -1, -1, 1], dtype=torch.float64))
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(2):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))
        t = rng.normal(size=3)
        m = torch.eye(4, dtype=torch.float64)
        m[:3, :3], m[:3, 3] = torch.from_numpy(q), torch.from_numpy(t)
        poses.append((q, t, w @ m @ c))
    ours = [panogrf_c2w(q, t).double() for q, t, _ in poses]
    rel_ours = torch.linalg.inv(ours[0]) @ ours[1]
    rel_pansplat = torch.linalg.inv(poses[0][2]) @ poses[1][2]
    assert torch.allclose(rel_ours, rel_pansplat, atol=1e-5)
    # World +y is gravity-down: an identity Habitat pose keeps the OpenCV camera upright.
    assert torch.allclose(panogrf_c2w(np.eye(3), np.zeros(3)), torch.eye(4))


# ---- tiny written fixtures -------------------------------------------------------------------------

def write_panogrf_scene(root, scene="00000001", size=(8, 16), frames=3, dist=0.5, depth=True):
    h, w = size
    rng = np.random.default_rng(0)
    for k in range(frames):
        d = root / scene / f"{k:02d}"
        d.mkdir(parents=True)
        Image.fromarray(rng.integers(0, 256, (h, w, 3), dtype=np.uint8)).save(d / "rgb.png")
        if depth:
            Image.fromarray(np.full((h, w), 1000 + 100 * k, dtype=np.uint16)).save(d / "depth.png")
        np.savetxt(d / "rot.txt", np.eye(3))
        np.savetxt(d / "tran.txt", [0.0, 0.0, (k - (frames - 1) / 2) * dist])


@pytest.fixture
def tiny_root(tmp_path):
    folder = tmp_path / "png_render_test_16x8_seq_len_3_replica_dist_1.0"
    write_panogrf_scene(folder, "00000001", dist=1.0)
    write_panogrf_scene(folder, "00000002", dist=1.0)
    return tmp_path, folder


def test_tiny_loader_root_lookup_and_collate(tiny_root):
    root, folder = tiny_root
    with pytest.raises(ValueError, match="has none of its own; choose one"):  # default: no silent zeros
        PanoGRFDataset(root, stored_size=(8, 16), name="replica", dist=1.0)[1]
    ds = PanoGRFDataset(root, stored_size=(8, 16), name="replica", dist=1.0, depth_prior=NoPrior())
    assert ds.folder == folder and len(ds) == 2 and ds.dataset_name == "replica"
    s = ds[1]
    assert s.metadata["baseline"] == pytest.approx(2.0) and s.metadata["nominal_baseline"] == 2.0
    assert torch.allclose(s.target_depths, torch.full((1, 8, 16), 1.1))
    assert torch.equal(s.context_priors, torch.zeros(2, 8, 16))  # none, asked for by name
    (folder / "priors" / "x").mkdir(parents=True)  # prior files of `data priors` are not a scene
    assert len(PanoGRFDataset(folder, depth_prior=NoPrior())) == 2
    batch = collate_samples([ds[0], ds[1]])
    assert batch.context_images.shape == (2, 2, 3, 8, 16) and batch.metadata["scene"] == ["00000001", "00000002"]


def test_tiny_loader_one_view_and_resize(tiny_root):
    _, folder = tiny_root
    s = PanoGRFDataset(folder, views="one_view", resolution=(4, 8), depth_prior=GroundTruthPrior())[0]
    assert s.context_images.shape == (1, 3, 4, 8) and s.target_images.shape == (2, 3, 4, 8)
    assert s.metadata["context_indices"] == [1] and s.metadata["target_indices"] == [0, 2]
    assert torch.allclose(s.target_depths, torch.tensor([1.0, 1.2]).view(2, 1, 1).expand(2, 4, 8))


def test_missing_depth_gives_none(tmp_path):
    folder = tmp_path / "png_render_test_16x8_seq_len_3_residential_dist_0.5"
    write_panogrf_scene(folder, depth=False)
    s = PanoGRFDataset(folder, depth_prior=NoPrior())[0]
    assert s.target_depths is None and s.context_gt_depths is None


@pytest.mark.parametrize("damage, error, fragment", [
    ("missing_rgb", FileNotFoundError, "01/rgb.png"),
    ("corrupt_png", ValueError, "01/rgb.png"),
    ("wrong_size", ValueError, "01/rgb.png"),
    ("not_2to1", ValueError, "2:1"),
    ("nan_pose", ValueError, "01/tran.txt"),
    ("bad_rotation", ValueError, "01"),
])
def test_bad_data_errors_name_the_file(tiny_root, damage, error, fragment):
    _, folder = tiny_root
    frame = folder / "00000001" / "01"
    if damage == "missing_rgb":
        (frame / "rgb.png").unlink()
    elif damage == "corrupt_png":
        (frame / "rgb.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    elif damage == "wrong_size":
        Image.fromarray(np.zeros((4, 8, 3), np.uint8)).save(frame / "rgb.png")
    elif damage == "not_2to1":
        Image.fromarray(np.zeros((8, 8, 3), np.uint8)).save(frame / "rgb.png")
    elif damage == "nan_pose":
        (frame / "tran.txt").write_text("0 nan 0")
    elif damage == "bad_rotation":
        np.savetxt(frame / "rot.txt", 2 * np.eye(3))
    with pytest.raises(error, match=fragment):
        PanoGRFDataset(folder)[0]


def test_bad_folder_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing dataset folder"):
        PanoGRFDataset(tmp_path, stored_size=(8, 16))
    with pytest.raises(ValueError, match="png_render"):
        PanoGRFDataset(tmp_path)


def test_no_default_silently_feeds_zero_priors(tiny_root, tmp_path, capsys):
    """Training or evaluating PanoGRF data (which has no depth prior of its own) must name the choice."""
    from cylindersplat.cli import main
    from cylindersplat.training import load_config
    from cylindersplat.training.data import build_dataset

    _, folder = tiny_root
    cfg = load_config("tiny", [f"data.root={folder}", "data.format=pano_grf", "data.split=test"])
    with pytest.raises(ValueError, match="data.depth_prior=gt"):
        build_dataset(cfg.data)
    for choice in ("gt", "constant:2.0", "none"):  # an explicit choice is the user's
        cfg = load_config("tiny", [f"data.root={folder}", "data.format=pano_grf", "data.split=test",
                                   f"data.depth_prior={choice}"])
        assert len(build_dataset(cfg.data)) == 2
    assert main(["eval", "--format", "pano_grf", "--data", str(folder), "--out", str(tmp_path / "ev"), "--lpips",
                 "off"]) == 1
    assert "--depth-prior=gt" in capsys.readouterr().err
