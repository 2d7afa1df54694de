"""The paper presets, wired faithfully: UniK3D files as input prior and as D_ref, Depth Anywhere files as the
PCC reference; the three choices are separate settings, and missing files stop the run at start-up.

The "UniK3D" and "Depth Anywhere" networks here are tiny modules exported in the test; their files are
written by `cylindersplat data priors` into a copy of the real Matterport3D triplet of the fixtures."""

from __future__ import annotations

import json
import shutil

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data import collate_samples
from cylindersplat.data.io import read_rgb
from cylindersplat.training import Trainer, load_config
from cylindersplat.training.data import build_dataset
from cylindersplat.training.trainer import batch_to_device
from test_data_priors_cli import FIXTURE, expected_depth, export_torchscript

SMALL = ["model.preset=tiny_paper", "data.resolution=[32,64]", "data.num_workers=0", "train.epochs_per_stage=null",
         "train.steps_per_stage=[1]", "loss.use_lpips=off", "train.progress=false", "train.tensorboard=false",
         "train.image_every=0", "train.log_every=1"]


@pytest.fixture(scope="module")
def m3d(tmp_path_factory):
    """A writable copy of the real triplet, with "unik3d" and "depth_anywhere" priors at 32x64."""
    if not (FIXTURE / "00000007").is_dir():
        pytest.skip(f"real fixture missing: {FIXTURE}")
    base = tmp_path_factory.mktemp("paper")
    copy = base / FIXTURE.name
    shutil.copytree(FIXTURE, copy)
    for name, offset in (("unik3d", 0.5), ("depth_anywhere", 1.0)):
        net = export_torchscript(base / f"{name}.pt", offset=offset)
        assert main(["data", "priors", "--data", str(copy), "--net", f"exported:{net}", "--name", name,
                     "--resolution", "32x64", "--device", "cpu"]) == 0
    return copy


def _want(copy, frame, offset=0.5):
    return expected_depth(copy / "00000007" / frame / "rgb.png", (32, 64), offset)


def test_paper_preset_feeds_unik3d_to_the_model_and_the_loss(m3d, tmp_path):
    cfg = load_config("paper", [f"data.root={m3d}", f"output_dir={tmp_path / 'run'}", *SMALL])
    assert (cfg.data.depth_prior, cfg.loss.depth_reference, cfg.eval.pcc_reference) == (
        "file:unik3d", "prior", "file:depth_anywhere")
    trainer = Trainer(cfg)
    sample = trainer.dataset[0]
    for k, frame in enumerate(("00", "02")):  # the contexts' input prior: the UniK3D files (within 1 mm)
        assert (sample.context_priors[k] - _want(m3d, frame)).abs().max() <= 5e-4 + 1e-6
    # D_ref: the same network on the target view, not the ground truth.
    assert (sample.target_reference_depths[0] - _want(m3d, "01")).abs().max() <= 5e-4 + 1e-6
    assert (sample.target_reference_depths[0] - sample.target_depths[0]).abs().mean() > 0.1

    seen = {}
    trainer._begin_stage()
    trainer.model.register_forward_pre_hook(lambda module, args: seen.update(prior=args[1].detach().clone()))
    forward = trainer.loss_fn.forward
    trainer.loss_fn.forward = lambda *a, **k: (seen.update(reference=a[4].detach().clone()), forward(*a, **k))[1]
    terms = trainer.compute_loss(batch_to_device(collate_samples([sample]), trainer.device))
    torch.testing.assert_close(seen["prior"][0], sample.context_priors)
    torch.testing.assert_close(seen["reference"][0], sample.target_reference_depths)
    assert "depth_l1" in terms.parts

    # The choices are separate: gt as D_ref, or no depth term at all.
    gt = build_dataset(load_config("paper", [f"data.root={m3d}", "loss.depth_reference=gt", *SMALL]).data,
                       load_config("paper", ["loss.depth_reference=gt"]).loss)
    assert gt[0].target_reference_depths is None and gt.depth_prior.spec == "file:unik3d"


def test_train_config_paper_runs_and_refuses_missing_priors(m3d, tmp_path, capsys):
    args = ["train", "--config", "paper", "--out", str(tmp_path / "run"), f"data.root={m3d}", *SMALL]
    assert main(args) == 0
    assert "training finished" in capsys.readouterr().out
    rows = [json.loads(line) for line in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert rows and all("depth_l1" in row for row in rows if "total" in row)
    # The same preset on data without the UniK3D files stops before the first step, naming the command.
    bare = tmp_path / m3d.name
    shutil.copytree(m3d, bare, ignore=shutil.ignore_patterns("priors"))
    assert main(["train", "--config", "paper", "--out", str(tmp_path / "bare"), f"data.root={bare}", *SMALL]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "file:unik3d" in err[0] and "cylindersplat data priors" in err[0]
    assert not (tmp_path / "bare" / "metrics.jsonl").exists()
    # A D_ref that does not exist is refused at start-up too (here: a prior name nobody wrote).
    assert main(["train", "--config", "paper", "--out", str(tmp_path / "x"), f"data.root={m3d}", *SMALL,
                 "loss.depth_reference=file:midas"]) == 1
    assert "loss.depth_reference=file:midas" in capsys.readouterr().err
    assert main(["train", "--config", "paper", "--out", str(tmp_path / "x"), f"data.root={m3d}", *SMALL,
                 "loss.depth_reference=nope"]) == 1
    assert "loss.depth_reference must be one of" in capsys.readouterr().err


@pytest.mark.slow  # 35 s at load 9 (2 shared cores)
def test_eval_config_paper_scores_pcc_against_depth_anywhere(m3d, tmp_path, capsys):
    common = ["eval", "--config", "paper", "--data", str(m3d), "--resolution", "32x64", "--lpips", "off",
              "--pictures", "0"]
    assert main([*common, "--out", str(tmp_path / "da")]) == 0
    assert "PCC against file:depth_anywhere" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "gt"), "--pcc-reference", "gt"]) == 0
    capsys.readouterr()

    def row(folder):
        return json.loads((folder / "results.json").read_text())["views"]["two_view"][0]

    da, gt = row(tmp_path / "da"), row(tmp_path / "gt")
    assert da["pcc"] != pytest.approx(gt["pcc"])
    assert da["abs_rel"] == pytest.approx(gt["abs_rel"])  # the other depth columns stay against the ground truth
    # Without the Depth Anywhere files: one line naming the command that writes them.
    bare = tmp_path / m3d.name
    shutil.copytree(m3d, bare, ignore=shutil.ignore_patterns("depth_anywhere"))
    assert main(["eval", "--config", "paper", "--data", str(bare), "--out", str(tmp_path / "e"), "--lpips", "off"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--pcc-reference=file:depth_anywhere" in err[0] and "cylindersplat data priors" in err[0]


_FAKE_TRANSFORMERS = '''
import types
import numpy as np
import torch
import torch.nn.functional as F

class _Processor:
    def __call__(self, images, return_tensors):
        x = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() / 255
        return {"pixel_values": F.interpolate(x, size=(28, 56), mode="bilinear", align_corners=False)}

class AutoImageProcessor:
    @classmethod
    def from_pretrained(cls, source):
        return _Processor()

class _Model(torch.nn.Module):
    def __init__(self, kind):
        super().__init__()
        self.config = types.SimpleNamespace(depth_estimation_type=kind)
    def forward(self, pixel_values):
        return types.SimpleNamespace(predicted_depth=1 + pixel_values.mean(1))

class AutoModelForDepthEstimation:
    @classmethod
    def from_pretrained(cls, source):
        return _Model(open(source + "/kind").read())
'''


def test_network_specs_work_from_configs(m3d, tmp_path, monkeypatch, request):
    # A stand-in `transformers` with the API the Depth Anything V2 adapter calls, and the fake UniK3D package.
    from test_data_priors import _FAKE_UNIK3D, install_fakes

    install_fakes(tmp_path, monkeypatch, request, {**_FAKE_UNIK3D, "transformers/__init__.py": _FAKE_TRANSFORMERS})
    weights = tmp_path / "unik3d-vitl"
    weights.mkdir()
    cfg = load_config("paper", [f"data.root={m3d}", f"data.depth_prior=unik3d:{weights}", *SMALL])
    sample = build_dataset(cfg.data, cfg.loss)[0]
    rgb8 = (read_rgb(m3d / "00000007" / "01" / "rgb.png", size=(32, 64)) * 255 + 0.5).to(torch.uint8).float().mean(0)
    want = (1 + rgb8[::2, ::2] / 100).repeat_interleave(2, 0).repeat_interleave(2, 1)
    torch.testing.assert_close(sample.target_reference_depths[0], want)  # D_ref = the prior of the target
    for kind in ("metric", "relative"):
        model = tmp_path / f"dav2-{kind}"
        model.mkdir()
        (model / "kind").write_text(kind)
        cfg = load_config("paper", [f"data.root={m3d}", f"data.depth_prior=depth_anything_v2:{model}", *SMALL])
        depth = build_dataset(cfg.data)[0].context_priors[0]
        image = read_rgb(m3d / "00000007" / "00" / "rgb.png", size=(32, 64))
        small = torch.nn.functional.interpolate(
            ((image * 255 + 0.5).to(torch.uint8).float() / 255)[None], size=(28, 56), mode="bilinear")
        out = torch.nn.functional.interpolate((1 + small.mean(1))[None], size=(32, 64), mode="bilinear")[0, 0]
        if kind == "metric":
            torch.testing.assert_close(depth, out)
        else:  # 1 / disparity, median 2 m
            torch.testing.assert_close(depth, (1 / out) * (2.0 / (1 / out).median()))


@pytest.mark.slow  # 30 s at load 9 (2 shared cores)
def test_finetune_360loc_preset_runs_on_priors_without_ground_truth(tmp_path, capsys):
    from test_data_loaders import write_loc360

    write_loc360(tmp_path / "loc", location="hall", size=(32, 64))  # a train location
    write_loc360(tmp_path / "loc", location="atrium", size=(32, 64))  # the test location
    root = tmp_path / "loc"
    for name, offset in (("unik3d", 0.5), ("depth_anywhere", 1.0)):
        net = export_torchscript(tmp_path / f"{name}.pt", offset=offset)
        assert main(["data", "priors", "--data", str(root), "--net", f"exported:{net}", "--name", name,
                     "--device", "cpu"]) == 0
    assert "12 written" in capsys.readouterr().out
    assert (root / "priors" / "unik3d" / "hall" / "mapping" / "daytime_360_0" / "image" / "00000.png").is_file()
    args = ["train", "--config", "finetune_360loc", "--out", str(tmp_path / "run"), f"data.root={root}", *SMALL]
    assert main(args) == 0
    assert "training finished" in capsys.readouterr().out
    # 360Loc has no ground-truth depth: a gt D_ref is refused at start-up instead of dropping the depth term.
    assert main([*args[:4], str(tmp_path / "gt"), *args[5:], "loss.depth_reference=gt"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loss.depth_reference=gt" in err[0] and "no ground-truth depth" in err[0]
    # Evaluation: PCC against the Depth Anywhere files although there is no ground truth.
    assert main(["eval", "--config", "finetune_360loc", "--data", str(root), "--protocols", "all_between",
                 "--resolution", "32x64",
                 "--out", str(tmp_path / "eval"), "--lpips", "off", "--pictures", "0", "--max-examples", "1"]) == 0
    means = next(iter(json.loads((tmp_path / "eval" / "results.json").read_text())["means"].values()))
    assert means["Forward warp"]["pcc"] is not None and means["Forward warp"]["abs_rel"] is None
