"""Training: the loss goes down, resume is exact, configs fail loudly, the CLI runs."""

from __future__ import annotations

import json

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data.synth import write_synthetic_dataset
from cylindersplat.training import Trainer, load_config


@pytest.fixture(scope="module")
def synth_root(synth_dataset):  # conftest.py
    return synth_dataset(3, seed=1)


def _config(root, out, *extra):
    return load_config("tiny", [
        f"data.root={root}", f"output_dir={out}", "train.progress=false", "train.tensorboard=false",
        "loss.use_lpips=off", "train.log_every=1", "train.image_every=0", *extra,
    ])


@pytest.mark.slow
def test_training_lowers_the_loss(synth_root, tmp_path):
    # One scene, pixel stage, a few dozen steps: the model must fit it clearly better.
    cfg = _config(synth_root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[30]", "train.lr=2e-3",
                  "data.options={scenes: ['00000000']}")
    history = Trainer(cfg).fit()["history"]
    losses = [h["total"] for h in history]
    first, last = sum(losses[:5]) / 5, sum(losses[-5:]) / 5
    print(f"loss {first:.4f} -> {last:.4f}")
    assert last < 0.8 * first, (first, last)
    assert (tmp_path / "run" / "model.safetensors").is_file()


def _params_and_optimizer(trainer):
    params = {k: v.detach().clone() for k, v in trainer.model.state_dict().items()}
    opt = trainer.optimizer.state_dict()["state"]
    moments = {k: (v["exp_avg"].clone(), v["exp_avg_sq"].clone()) for k, v in opt.items()}
    return params, moments


@pytest.mark.slow
def test_resume_after_kill_is_exact(synth_root, tmp_path):
    extra = ("train.stages=[1,3]", "train.steps_per_stage=[3,3]", "train.checkpoint_every=1")
    # Uninterrupted: 5 steps (stage 1 complete + 2 steps of stage 3).
    full = Trainer(_config(synth_root, tmp_path / "full", *extra))
    full.fit(max_steps=5)
    # Interrupted after 4 steps (mid stage 3), a new process resumes and does the 5th.
    killed = Trainer(_config(synth_root, tmp_path / "killed", *extra))
    killed.fit(max_steps=4)
    del killed
    resumed = Trainer(_config(synth_root, tmp_path / "killed", *extra), resume=tmp_path / "killed")
    assert (resumed.stage_index, resumed.stage_step, resumed.global_step) == (1, 1, 4)
    resumed.fit(max_steps=1)
    (p_full, m_full), (p_res, m_res) = _params_and_optimizer(full), _params_and_optimizer(resumed)
    for key in p_full:
        torch.testing.assert_close(p_res[key], p_full[key], rtol=0, atol=0, msg=key)
    assert m_full.keys() == m_res.keys()
    for key in m_full:
        torch.testing.assert_close(m_res[key], m_full[key], rtol=0, atol=0)


def test_config_overrides_and_errors(tmp_path):
    cfg = load_config("tiny", ["train.lr=3e-4", "train.stages=[3]", "model.volume.init=isolated",
                               "data.resolution=[32,64]"])
    assert cfg.train.lr == 3e-4 and cfg.train.stages == (3,) and cfg.model.volume.init == "isolated"
    assert cfg.data.resolution == (32, 64)
    with pytest.raises(ValueError, match="unknown config key 'train.lrr'"):
        load_config("tiny", ["train.lrr=1"])
    with pytest.raises(ValueError, match="train.stages"):
        load_config("tiny", ["train.stages=[4]"])
    with pytest.raises(ValueError, match="section.key=value"):
        load_config("tiny", ["lr"])
    with pytest.raises(FileNotFoundError, match="presets"):
        load_config("no_such_preset")


@pytest.mark.slow  # 35 s at load 10 (2 shared cores)
def test_resume_with_other_stages_starts_the_first_unfinished_one(synth_root, tmp_path):
    """``train --resume RUN --stages 3`` after a stage-1 run: stage 3 from the run's weights (issue 37)."""
    Trainer(_config(synth_root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[1]")).fit()
    resumed = Trainer(_config(synth_root, tmp_path / "run", "train.stages=[3]"), resume=tmp_path / "run")
    assert (resumed.stage_index, resumed.stage_step, resumed.global_step) == (0, 0, 1)


@pytest.mark.slow
def test_train_cli_end_to_end(synth_root, tmp_path, capsys):
    out = tmp_path / "cli"
    code = main(["train", "--data", str(synth_root), "--out", str(out), "--stages", "1,2,3", "--steps", "1",
                 "train.progress=false", "loss.use_lpips=off", "train.image_every=1"])
    assert code == 0
    assert "training finished" in capsys.readouterr().out
    for stage in (1, 2, 3):
        assert (out / f"model_stage{stage}.safetensors").is_file()
        assert any((out / "images").glob(f"stage{stage}_*.png"))
    assert (out / "metrics.jsonl").read_text().count("\n") >= 3
    assert main(["train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "other")]) == 1
    capsys.readouterr()
    # The folder holds a run now: a second train into it must not mix two runs.
    history = (out / "metrics.jsonl").read_text()
    args = ["train", "--data", str(synth_root), "--out", str(out), "--stages", "1", "--steps", "1",
            "train.progress=false", "loss.use_lpips=off", "train.image_every=0"]
    assert main(args) == 1
    assert "--resume" in capsys.readouterr().err and (out / "metrics.jsonl").read_text() == history
    (out / "notes.txt").write_text("mine")
    assert main(args + ["--overwrite"]) == 0
    assert (out / "metrics.jsonl").read_text() != history and (out / "notes.txt").read_text() == "mine"
    assert not (out / "model_stage3.safetensors").exists()


# -- non-finite guard ---------------------------------------------------------------------------
def _nan_grad_on(trainer, steps: set[int]) -> list[str]:
    """Make the first trainable parameter's grad NaN on the given (1-based) global steps; returns [its name]."""
    begin, name = trainer._begin_stage, []

    def begin_and_hook():
        begin()
        key, param = next((k, p) for k, p in trainer.model.named_parameters() if p.requires_grad)
        name[:] = [key]
        param.register_hook(lambda g: g * float("nan") if trainer.global_step + 1 in steps else g)

    trainer._begin_stage = begin_and_hook
    return name


@pytest.mark.slow
def test_nonfinite_step_is_skipped(synth_root, tmp_path):
    cfg = _config(synth_root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[3]",
                  "data.options={scenes: ['00000000']}")
    trainer = Trainer(cfg)
    bad_param = _nan_grad_on(trainer, {2})
    after, train_step = [], trainer.train_step

    def step_and_snapshot(batch):  # weights, AdamW moments and schedule position after every step
        parts = train_step(batch)
        after.append((*_params_and_optimizer(trainer), trainer.scheduler.last_epoch))
        return parts

    trainer.train_step = step_and_snapshot
    with pytest.warns(RuntimeWarning, match=r"step 2 \(stage 1\) skipped: loss finite, grad norm nan") as record:
        summary = trainer.fit()
    assert bad_param[0] in str(record[0].message) and "gaussian grads: all finite" in str(record[0].message)
    assert [h["skipped"] for h in summary["history"]] == [0.0, 1.0, 0.0]
    assert summary["skipped_steps"] == 1 and summary["finished"] and summary["global_step"] == 3
    assert trainer.consecutive_skips == 0
    (p1, m1, _), (p2, m2, _), (p3, _, _) = after
    for key in p1:  # the skipped step changed nothing (no update, no weight decay) and left all finite
        assert torch.isfinite(p2[key]).all(), key
        torch.testing.assert_close(p2[key], p1[key], rtol=0, atol=0, msg=key)
    for key in m1:
        torch.testing.assert_close(m2[key], m1[key], rtol=0, atol=0)
    assert [a[2] for a in after] == [1, 2, 3]  # the schedule still advanced
    assert any(not torch.equal(p3[k], p2[k]) for k in p3)  # step 3 trained again
    assert all(torch.isfinite(v).all() for v in p3.values())
    lines = (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["train/skipped"] for line in lines] == [0.0, 1.0, 0.0]


@pytest.mark.slow
def test_nonfinite_loss_every_step_diverges(synth_root, tmp_path, monkeypatch):
    cfg = _config(synth_root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[5]",
                  "train.max_nonfinite_steps=2", "data.options={scenes: ['00000000']}")
    trainer = Trainer(cfg)
    compute = trainer.compute_loss

    def nan_loss(batch):
        terms = compute(batch)
        terms.total = terms.total * float("nan")
        return terms

    monkeypatch.setattr(trainer, "compute_loss", nan_loss)
    with pytest.warns(RuntimeWarning, match="loss non-finite"):
        with pytest.raises(RuntimeError, match=r"training diverged: 3 consecutive steps .*last at step 3.*"
                                               r"gaussians\.means.*train\.render_backend=torch"):
            trainer.fit()
    assert trainer.skipped_steps == 3
    assert all(torch.isfinite(p).all() for p in trainer.model.parameters())


def test_render_backend_option(synth_root, tmp_path):
    cfg = _config(synth_root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[1]",
                  "train.render_backend=torch", "data.options={scenes: ['00000000']}")
    assert cfg.train.render_backend == "torch"
    assert Trainer(cfg).fit()["finished"]
    with pytest.raises(ValueError, match="train.render_backend='nope' is not available here"):
        Trainer(_config(synth_root, tmp_path / "bad", "train.render_backend=nope"))
    with pytest.raises(ValueError, match="max_nonfinite_steps"):
        load_config("tiny", ["train.max_nonfinite_steps=-1"])


def test_volume_lr_scale_gives_the_volume_branch_its_own_rate(tmp_path, synth_root):
    cfg = _config(synth_root, tmp_path / "run", "train.stages=[3]", "train.steps_per_stage=[1]",
                  "train.volume_lr_scale=0.25", "train.warmup_steps=0")
    trainer = Trainer(cfg)
    trainer.stage_index = 0
    trainer._begin_stage()
    volume = {id(p) for p in trainer.model.branch_parameters("volume")}
    rates = {id(p): g["lr"] for g in trainer.optimizer.param_groups for p in g["params"]}
    assert {rates[i] for i in volume} == {cfg.train.lr * 0.25}
    assert {r for i, r in rates.items() if i not in volume} == {cfg.train.lr}
    with pytest.raises(ValueError, match="volume_lr_scale"):
        load_config("tiny", ["train.volume_lr_scale=0"])


def test_occluded_pixels_can_weigh_more(tmp_path, monkeypatch):
    from cylindersplat.data.synth import profile_config
    from cylindersplat.training.losses import LossConfig, RenderLoss

    # The weighted L1 is the weighted mean of |rgb - target| over pixels and channels.
    gen = torch.Generator().manual_seed(0)
    rgb, target = torch.rand(1, 1, 3, 4, 8, generator=gen), torch.rand(1, 1, 3, 4, 8, generator=gen)
    weight = 1 + 4 * (torch.rand(1, 1, 4, 8, generator=gen) > 0.7).float()
    terms = RenderLoss(LossConfig(use_lpips="off", depth_l1=0))(rgb, torch.zeros(1, 1, 4, 8), torch.ones(1, 1, 4, 8),
                                                                  target, None, pixel_weight=weight)
    expected = (weight[:, :, None] * (rgb - target).abs()).sum() / (3 * weight.sum())
    assert terms.parts["rgb_l1"] == pytest.approx(float(expected), rel=1e-6)

    # The trainer derives the weights from the reference depths of targets and contexts.
    root = tmp_path / "occ"
    write_synthetic_dataset(root, 2, (32, 64), profile_config("occlusion"), seed=4, progress=False)
    cfg = _config(root, tmp_path / "run", "train.stages=[1]", "train.steps_per_stage=[1]", "loss.occluded_weight=4")
    trainer = Trainer(cfg)
    seen = []
    monkeypatch.setattr(trainer.loss_fn, "forward", lambda *a, pixel_weight=None: seen.append(pixel_weight) or
                        RenderLoss.forward(trainer.loss_fn, *a, pixel_weight=pixel_weight))
    trainer.fit()
    assert seen[0] is not None and set(seen[0].unique().tolist()) <= {1.0, 5.0} and (seen[0] == 5).any()
    with pytest.raises(ValueError, match="occluded_weight"):
        load_config("tiny", ["loss.occluded_weight=-1"])


def test_code_changes_and_command_line_overrides_are_one_mechanism(tmp_path):
    """``changes`` (typed values from code, as the demo and the ablation pass them) give the same config
    as the equivalent ``key=value`` overrides, and are checked the same way."""
    from cylindersplat.training import load_config

    strings = load_config("tiny", [f"data.root={tmp_path}", "data.resolution=[32,64]", "train.lr=3e-4",
                                   "data.options={scenes: [a, b]}", "train.stages=[1,3]", "model.pixel.edge_sigma=0"])
    typed = load_config("tiny", changes={"data.root": tmp_path, "data.resolution": [32, 64], "train.lr": 3e-4,
                                         "data.options": {"scenes": ["a", "b"]}, "train.stages": [1, 3],
                                         "model.pixel.edge_sigma": 0})
    assert typed == strings
    assert load_config("tiny", ["train.lr=1e-3"], changes={"train.lr": 5e-4}).train.lr == 5e-4  # code wins
    with pytest.raises(ValueError, match="train.seed must be an integer"):
        load_config("tiny", changes={"train.seed": "abc"})
    with pytest.raises(ValueError, match="unknown config key"):
        load_config("tiny", changes={"train.nope": 1})


@pytest.mark.slow  # 33 + 14 s at load 10 (2 shared cores)
@pytest.mark.parametrize("volume_loss", ["scaled", "released"])
def test_volume_weight_adds_the_volume_branchs_own_render_loss(synth_root, tmp_path, volume_loss):
    """loss.volume_weight=w: total = loss(fused render) + w * L(volume Gaussians rendered alone, before fusion), with
    L the same loss (``scaled``) or the released code's 0.1 L2 + 0.1 depth L1 (``released``, no LPIPS weights here),
    recomputed here from the model's outputs with the renderer and the formulas directly."""
    from cylindersplat.data import collate_samples
    from cylindersplat.render import render_equirect
    from cylindersplat.training.trainer import batch_to_device

    cfg = _config(synth_root, tmp_path / "run", "train.stages=[3]", "train.steps_per_stage=[1]",
                  "loss.volume_weight=0.5",
                  f"loss.volume_loss={volume_loss}", "loss.use_lpips=off")
    trainer = Trainer(cfg)
    trainer._begin_stage()
    batch = batch_to_device(collate_samples([trainer.dataset[0]]), trainer.device)
    terms = trainer.compute_loss(batch)

    with torch.no_grad():
        out = trainer.model(batch.context_images, batch.context_priors, batch.context_poses)
    h, w = batch.target_images.shape[-2:]
    reference = batch.target_depths

    def render(gaussians):
        return render_equirect(gaussians, batch.target_poses, h, w, background=tuple(cfg.train.background))

    def loss_of(gaussians):
        r = render(gaussians)
        return trainer.loss_fn(r.rgb, r.depth, r.alpha, batch.target_images, reference).total

    fused = loss_of(out.gaussians)
    if volume_loss == "scaled":
        alone = loss_of(out.volume_gaussians)
    else:
        r = render(out.volume_gaussians)
        valid = reference > 0
        alone = 0.1 * ((r.rgb - batch.target_images) ** 2).mean() + 0.1 * (r.depth - reference)[valid].abs().mean()
    assert float(alone) != pytest.approx(float(fused), rel=1e-3)  # the two renders differ
    assert float(terms.total.detach()) == pytest.approx(float(fused + 0.5 * alone), rel=1e-5)
    assert terms.parts["volume_total"] == pytest.approx(float(alone), rel=1e-5)
    with pytest.raises(ValueError, match="volume_weight"):
        load_config("tiny", ["loss.volume_weight=-1"])
    with pytest.raises(ValueError, match="loss.volume_loss must be one of scaled, released"):
        load_config("tiny", ["loss.volume_loss=nonsense"])


def test_stage_one_can_leave_hidden_pixels_to_the_volume_branch(tmp_path, monkeypatch):
    """loss.pixel_stage_hidden=leave: in stage 1 of a curriculum with later volume stages, pixels no context
    view sees weigh 0 in the RGB term (the occlusion mask from the reference depths) and drop out of the
    depth term; a pixel-only schedule and the later stages keep every pixel."""
    from cylindersplat.data import collate_samples
    from cylindersplat.data.occlusion import occluded_mask
    from cylindersplat.data.synth import profile_config
    from cylindersplat.training.losses import LossConfig, RenderLoss
    from cylindersplat.training.trainer import batch_to_device

    # the depth term: the mean |depth - reference| over pixels with a reference and a non-zero weight
    gen = torch.Generator().manual_seed(1)
    depth, reference = torch.rand(1, 1, 4, 8, generator=gen) + 1, torch.rand(1, 1, 4, 8, generator=gen) + 1
    weight = (torch.rand(1, 1, 4, 8, generator=gen) > 0.4).float()
    terms = RenderLoss(LossConfig(use_lpips="off"))(torch.zeros(1, 1, 3, 4, 8), depth, torch.ones(1, 1, 4, 8),
                                                   torch.zeros(1, 1, 3, 4, 8), reference, pixel_weight=weight)
    kept = weight > 0
    assert terms.parts["depth_l1"] == pytest.approx(float((depth - reference).abs()[kept].mean()), rel=1e-6)

    root = tmp_path / "occ"
    write_synthetic_dataset(root, 2, (32, 64), profile_config("occlusion"), seed=4, progress=False)
    for stages, stage, leaves in (([1, 2, 3], 1, True), ([1], 1, False), ([1, 2, 3], 3, False)):
        cfg = _config(root, tmp_path / f"run{len(stages)}{stage}", f"train.stages={stages}",
                      f"train.steps_per_stage={[1] * len(stages)}", "loss.pixel_stage_hidden=leave")
        trainer = Trainer(cfg)
        trainer.stage_index = cfg.train.stages.index(stage)
        batch = batch_to_device(collate_samples([trainer.dataset[0]]), trainer.device)
        weights = trainer.objective.pixel_weights(batch, trainer.stage)
        if not leaves:
            assert weights is None
            continue
        hidden = occluded_mask(batch.target_depths[0, 0], batch.target_poses[0, 0], batch.context_gt_depths[0],
                               batch.context_poses[0])
        assert hidden.any() and torch.equal(weights[0, 0], (~hidden).float())
    with pytest.raises(ValueError, match="pixel_stage_hidden"):
        load_config("tiny", ["loss.pixel_stage_hidden=maybe"])
