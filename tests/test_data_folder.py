"""A folder of posed panoramas is a dataset like the others (``folder``): one reader for render, eval and train."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data import FolderDataset, Sample, make_dataset
from cylindersplat.data.depth_prior import ConstantPrior, NoPrior, StoredDepthPrior
from cylindersplat.data.io import write_depth_png
from cylindersplat.inference import load_panorama_folder, write_panorama_folder


def _three_frames(folder, seed=0):
    """Three posed 16x32 panoramas 0.5 m apart on x with depth PNGs: ``(path, images, depths, poses)``."""
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(3, 3, 16, 32, generator=g)
    depths = torch.rand(3, 16, 32, generator=g) * 3 + 0.5
    poses = torch.eye(4).repeat(3, 1, 1)
    poses[:, 0, 3] = torch.tensor([0.0, 0.5, 1.0])
    return write_panorama_folder(folder, images, poses, depths), images, depths, poses


def _without_depth_files(path, keep=()):
    data = json.loads((path / "poses.json").read_text())
    for frame in data["frames"]:
        if frame["image"] not in keep:
            (path / frame.pop("depth")).unlink()
    (path / "poses.json").write_text(json.dumps(data))


def test_load_panorama_folder_is_the_folder_dataset(panorama_folder):
    path, images, depths, poses = panorama_folder
    sample = make_dataset("folder", path, views="all_inputs", resolution=(16, 32))[0]
    inputs = load_panorama_folder(path, (16, 32))
    assert sample.num_context == 2 and sample.num_target == 0 and sample.target_depths is None
    torch.testing.assert_close(inputs.images, sample.context_images)
    torch.testing.assert_close(inputs.depths, sample.context_priors)  # the depth files are the priors
    torch.testing.assert_close(inputs.depths, depths, atol=6e-4, rtol=0)
    torch.testing.assert_close(sample.context_poses, poses)
    assert sample.metadata["dataset"] == "folder" and sample.metadata["scene"] == "scene"
    assert sample.metadata["depth_prior"] == "depth files"


def test_held_out_frames_and_protocols(tmp_path):
    path, images, depths, poses = _three_frames(tmp_path / "scene")
    s = make_dataset("folder", path, targets=["pano_01.png"])[0]  # by name; the registry's views are overridden
    assert s.metadata["context_indices"] == [0, 2] and s.metadata["target_indices"] == [1]
    torch.testing.assert_close(s.target_poses, poses[1:2])
    torch.testing.assert_close(s.target_depths, depths[1:2], atol=6e-4, rtol=0)  # the reference of depth metrics
    torch.testing.assert_close(s.context_gt_depths, s.context_priors)
    assert s.metadata["baseline"] == pytest.approx(1.0)
    assert FolderDataset(path, targets=["pano_00", 2])[0].metadata["target_indices"] == [0, 2]  # stems, indices
    assert make_dataset("folder", path, views="one_view")[0].metadata["target_indices"] == [0, 2]
    with pytest.raises(ValueError, match="no frame 'nope' to hold out.*pano_00.png, pano_01.png, pano_02.png"):
        FolderDataset(path, targets=["nope"])
    with pytest.raises(ValueError, match="every frame is held out"):
        FolderDataset(path, targets=[0, 1, 2])
    with pytest.raises(ValueError, match="unknown views 'all_between'"):
        FolderDataset(path, views="all_between")


def test_a_folder_of_folders_is_one_example_each(tmp_path):
    _three_frames(tmp_path / "b", seed=1)
    _three_frames(tmp_path / "a", seed=2)
    (tmp_path / "notes").mkdir()  # no poses file: not a scene
    ds = make_dataset("folder", tmp_path, views="two_view")
    assert len(ds) == 2 and [ds[i].metadata["scene"] for i in range(2)] == ["a", "b"]
    assert ds.data_root == tmp_path
    with pytest.raises(FileNotFoundError, match="missing poses file"):
        FolderDataset(tmp_path / "notes")


def test_depth_files_else_the_chosen_prior(tmp_path):
    path, _, depths, _ = _three_frames(tmp_path / "scene")
    _without_depth_files(path, keep=("pano_00.png",))
    with pytest.raises(FileNotFoundError, match="no depth prior for pano_01.png, pano_02.png.*data.depth_prior"):
        make_dataset("folder", path, views="all_inputs")
    with pytest.raises(FileNotFoundError, match="--depth-prior"):
        load_panorama_folder(path, (16, 32))
    s = make_dataset("folder", path, views="all_inputs", depth_prior="constant:2.5")[0]
    torch.testing.assert_close(s.context_priors[0], depths[0], atol=6e-4, rtol=0)  # the file wins
    assert s.context_priors[1:].eq(2.5).all() and s.metadata["depth_prior"] == "depth files, else constant:2.5"
    # Only the inputs need a prior: the held-out frame has none and needs none.
    s = make_dataset("folder", path, targets=["pano_02.png"], depth_prior="constant:2")[0]
    assert s.target_depths is None and s.context_gt_depths is None
    # File priors fill the frames without a depth file; missing ones fail before loading, naming data priors.
    with pytest.raises(FileNotFoundError, match="2 of 2 panoramas have no prior file.*cylindersplat data priors"):
        make_dataset("folder", path, views="all_inputs", depth_prior="file:mono")
    for name in ("pano_01", "pano_02"):
        write_depth_png(path / "priors" / "mono" / f"{name}.png", torch.full((16, 32), 3.0))
    s = make_dataset("folder", path, views="all_inputs", depth_prior="file:mono")[0]
    assert s.context_priors[1:].sub(3.0).abs().max() < 1e-6


def test_depth_files_as_reference_only(tmp_path):
    path, _, depths, _ = _three_frames(tmp_path / "scene")
    ds = make_dataset("folder", path, views="two_view", depth_prior="constant:4", depth_files="reference")
    s = ds[0]
    assert s.context_priors.eq(4).all()
    torch.testing.assert_close(s.target_depths, depths[1:2], atol=6e-4, rtol=0)
    with pytest.raises(ValueError, match="data.depth_prior=file:NAME"):  # no prior of its own then
        make_dataset("folder", path, depth_files="reference")


def test_depth_scale_npy_and_zero_depth(tmp_path):
    path, _, depths, _ = _three_frames(tmp_path / "scene")
    data = json.loads((path / "poses.json").read_text())
    data["depth_scale"] = 500  # PNG units per metre
    np.save(path / "pano_01_depth.npy", depths[1].numpy())  # .npy: metres
    data["frames"][1]["depth"] = "pano_01_depth.npy"
    (path / "poses.json").write_text(json.dumps(data))
    inputs = load_panorama_folder(path, (16, 32))
    torch.testing.assert_close(inputs.depths[0], depths[0] * 2, atol=2e-3, rtol=0)  # mm read at 500 per metre
    torch.testing.assert_close(inputs.depths[1], depths[1])
    write_depth_png(path / "pano_02_depth.png", torch.zeros(16, 32))
    with pytest.raises(ValueError, match="depth file .*pano_02_depth.png has no positive depth"):
        load_panorama_folder(path, (16, 32))
    assert load_panorama_folder(path, (16, 32), depth_prior=NoPrior()).depths[2].eq(0).all()  # asked for by name


def test_stored_depth_prior():
    prior = StoredDepthPrior(ConstantPrior(2.0))
    assert not prior.allows_zeros and StoredDepthPrior(NoPrior()).allows_zeros
    from cylindersplat.data.depth_prior import PriorQuery

    image = torch.rand(3, 4, 8)
    stored = torch.rand(4, 8)
    assert torch.equal(prior(PriorQuery(image, stored, None, "k")), stored)
    assert prior(PriorQuery(image, None, None, "k")).eq(2.0).all()
    with pytest.raises(ValueError, match="needs a depth prior"):
        StoredDepthPrior()(PriorQuery(image, None, None, "k"))


def test_context_depths_is_a_deprecated_alias():
    s = Sample(torch.rand(2, 3, 4, 8), torch.rand(2, 4, 8), torch.eye(4).expand(2, 4, 4), torch.rand(1, 3, 4, 8), None,
               torch.eye(4)[None])
    with pytest.warns(DeprecationWarning, match="context_priors"):
        assert s.context_depths is s.context_priors
    with pytest.raises(AttributeError):
        s.context_depths = torch.zeros(2, 4, 8)  # read-only
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s.context_priors  # the new name does not warn


def test_eval_cli_on_a_folder(tmp_path, tiny_checkpoint, capsys):
    path, *_ = _three_frames(tmp_path / "scene")
    out = tmp_path / "eval"
    common = ["--checkpoint", str(tiny_checkpoint), "--out", str(out), "--lpips", "off", "--device", "cpu"]
    assert main(["eval", "--format", "folder", "--data", str(path), "--targets", "pano_01.png", "--pictures", "1",
                 *common]) == 0
    data = json.loads((out / "results.json").read_text())
    (key,) = data["means"]
    assert "held_out (1 examples)" in key and set(data["means"][key]) == {
        "CylinderSplat", "its pixel branch", "its pixel branch + mean fill", "its pixel branch + inpaint fill",
        "Forward warp", "Forward warp + mean fill", "Forward warp + inpaint fill"}
    assert data["means"][key]["Forward warp"]["abs_rel"] is not None  # the held-out frame's depth file
    assert len(list((out / "examples" / "held_out").glob("*.png"))) == 1
    capsys.readouterr()
    assert main(["eval", "--format", "folder", "--data", str(path), *common]) == 0  # --protocols two_view
    assert "two_view (1 examples)" in capsys.readouterr().out
    # without --format the layout is read from the folder (poses.json: a folder of panoramas)
    assert main(["eval", "--data", str(path), "--targets", "pano_01.png", *common]) == 0
    assert "data layout: folder (detected" in capsys.readouterr().out
    # --targets belongs to folders: a synthetic dataset named explicitly stops with the format it needs
    assert main(["eval", "--format", "synthetic", "--data", str(path), "--targets", "pano_01.png", "--out",
                 str(out)]) == 1
    assert "--format folder" in capsys.readouterr().err


def test_train_config_takes_the_folder_format(tmp_path):
    from cylindersplat.training import load_config
    from cylindersplat.training.data import build_dataset

    path, *_ = _three_frames(tmp_path / "scene")
    cfg = load_config("tiny", [f"data.root={path}", "data.format=folder", "data.options={targets: [pano_02.png]}"])
    s = build_dataset(cfg.data, cfg.loss)[0]
    assert s.metadata["target_indices"] == [2] and s.num_context == 2
