"""Data set-up snags: any PanoGRF folder suffix, import-poses keeping each frame's own name, clock timestamps
(--start-time), hub ids that cannot be fetched failing at once, --checkpoint following checkpoints/latest."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data.depth_prior import hub
from cylindersplat.data.depth_prior.adapters import UniK3DAdapter
from cylindersplat.data.depth_prior.base import NoPrior
from cylindersplat.data.pano_grf import PanoGRFDataset
from cylindersplat.inference import read_poses_file
from cylindersplat.model import load_model
from cylindersplat.model.pretrained import resolve_weights
from test_data_pano_grf import write_panogrf_scene


def test_any_panogrf_dist_suffix_is_read(tmp_path):
    folder = tmp_path / "png_render_test_16x8_seq_len_3_m3d_dist_var"  # before: "pass stored_size=(H, W)"
    write_panogrf_scene(folder, "00000001", dist=0.5)
    dataset = PanoGRFDataset(folder, depth_prior=NoPrior())
    sample = dataset[0]
    assert dataset.dist is None and sample.metadata["nominal_baseline"] is None
    assert sample.context_images.shape == (2, 3, 8, 16)
    assert sample.metadata["baseline"] == pytest.approx(1.0)  # the poses still say 2 x 0.5 m


def test_a_root_without_a_png_render_name_names_the_cli_option(tmp_path, capsys):
    write_panogrf_scene(tmp_path / "png_render_test_16x8_seq_len_3_m3d_dist_var", "00000001")
    with pytest.raises(ValueError, match=r"give that folder itself as --data "
                                         r".*png_render_test_16x8_seq_len_3_m3d_dist_var"):
        PanoGRFDataset(tmp_path)
    assert main(["eval", "--format", "pano_grf", "--data", str(tmp_path), "--no-model", "--depth-prior", "none",
                 "--out", str(tmp_path / "e")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--data" in err[0] and "stored_size" not in err[0], err


def _identity_tum(path, times) -> None:
    path.write_text("".join(f"{t!r} {0.1 * k} 0 0 0 0 0 1\n" for k, t in enumerate(times)))


def test_import_poses_keeps_the_names_of_linked_images(tmp_path):
    store, scene = tmp_path / "store", tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    store.mkdir()
    for k in range(3):  # the images are links into a store with other names (a common way to pick frames)
        Image.fromarray(np.zeros((4, 8, 3), np.uint8)).save(store / f"blob_{9 - k}.png")
        (scene / "images" / f"frame_{k:03d}.png").symlink_to(store / f"blob_{9 - k}.png")
    _identity_tum(tmp_path / "tum.txt", [0.0, 0.1, 0.2])
    assert main(["data", "import-poses", str(tmp_path / "tum.txt"), "--from", "tum", "--out", str(scene / "poses.json"),
                 "--images", str(scene / "images")]) == 0
    names = [name for name, _, _ in read_poses_file(scene / "poses.json")]
    assert names == ["images/frame_000.png", "images/frame_001.png", "images/frame_002.png"]


def test_clock_timestamps_start_at_the_first_pose(tmp_path, capsys):
    scene = tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    for k in range(5):
        Image.fromarray(np.zeros((4, 8, 3), np.uint8)).save(scene / "images" / f"f{k}.png")
    clock = 1_700_000_000.0
    _identity_tum(tmp_path / "tum.txt", [clock + 0.0, clock + 0.1, clock + 0.2])  # stamped with the wall clock
    args = ["data", "import-poses", str(tmp_path / "tum.txt"), "--from", "tum", "--out", str(scene / "poses.json"),
            "--images", str(scene / "images"), "--fps", "20"]
    assert main(args) == 1
    assert "--start-time first" in capsys.readouterr().err
    assert main([*args, "--start-time", "first"]) == 0
    entries = read_poses_file(scene / "poses.json")
    assert [name for name, _, _ in entries] == ["images/f0.png", "images/f2.png", "images/f4.png"]
    assert [float(c[0, 3]) for _, c, _ in entries] == pytest.approx([0.0, 0.1, 0.2])
    assert main([*args[:-2], "--start-time", "first"]) == 1  # without --fps it means nothing
    assert "give --fps too" in capsys.readouterr().err


def test_an_unreachable_hub_id_fails_at_once(tmp_path, monkeypatch):
    monkeypatch.setattr(UniK3DAdapter, "package", "json")  # pretend the package is installed
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")  # nothing listens on the discard port: refused at once
    start = time.perf_counter()
    with pytest.raises(FileNotFoundError, match="not in the local cache .* cannot be reached .* unik3d:DIR"):
        UniK3DAdapter(weights="org/some-model")
    assert time.perf_counter() - start < hub.PROBE_SECONDS + 1
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    assert not hub.hub_reachable()
    (tmp_path / "cache" / "models--org--some-model" / "snapshots" / "0123").mkdir(parents=True)  # cached: fine offline
    assert UniK3DAdapter(weights="org/some-model").source == "org/some-model"


def test_checkpoint_pointer_is_followed(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", "--data", str(synth_dataset(2, seed=5)), "--out", str(run), "--stages", "1", "--steps", "2",
                 "--max-steps", "1", "train.tensorboard=false", "loss.use_lpips=off", "train.image_every=0",
                 "train.progress=false"]) == 0
    step = run / "checkpoints" / "step_0000001" / "model.safetensors"
    assert resolve_weights(run / "checkpoints" / "latest") == step  # before: a safetensors header error
    with pytest.warns(UserWarning, match="no final model.safetensors: using its latest checkpoint"):
        assert resolve_weights(run) == step  # an unfinished run
    expected = load_model(step).state_dict()
    got = load_model(resolve_weights(run / "checkpoints" / "latest")).state_dict()
    assert all(torch.equal(got[k], expected[k]) for k in expected)
