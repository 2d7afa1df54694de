"""train.render_drawing: training can draw its targets as inference does (issue 34: the volume branch supervised
only where it shows), and the default stays the paper's one pass."""

from __future__ import annotations

import pytest
import torch

from cylindersplat.data import collate_samples
from cylindersplat.inference.pipeline import raster_settings, reconstruct_gaussians, render_views
from cylindersplat.render import render_equirect
from cylindersplat.render.layered import FrontLayer
from cylindersplat.training import Trainer, load_config


@pytest.fixture(scope="module")
def synth_root(synth_dataset):  # conftest.py
    return synth_dataset(3, seed=1)


def _trainer(root, out, preset, *extra):
    cfg = load_config(preset, [
        f"data.root={root}", f"output_dir={out}", "train.progress=false", "train.tensorboard=false",
        "loss.use_lpips=off", "train.image_every=0", "train.stages=[3]", "train.steps_per_stage=[1]",
        "data.batch_size=2", "train.render_backend=torch", *extra,
    ])
    trainer = Trainer(cfg)
    trainer.stage_index = 0
    trainer._begin_stage()
    return trainer


def _batch(trainer):
    return collate_samples([trainer.dataset[0], trainer.dataset[1]])


def test_model_drawing_is_the_inference_drawing(synth_root, tmp_path):
    torch.manual_seed(0)
    trainer = _trainer(synth_root, tmp_path / "run", "recipes/tiny_sharp", "train.render_drawing=model")
    model, batch = trainer.model.eval(), _batch(trainer)
    with torch.no_grad():
        out = model(batch.context_images, batch.context_priors, batch.context_poses)
        front = model.front_layer(out)
        assert front == FrontLayer(out.pixel_gaussians.num_gaussians, blend=True, opaque=False)
        drawn = trainer._render(out.gaussians, batch, front)
    h, w = batch.target_images.shape[-2:]
    for b in range(2):  # what eval and render draw from the same scene
        gaussians, layer = reconstruct_gaussians(model, batch.context_images[b], batch.context_priors[b],
                                                 batch.context_poses[b], layers=True, check_plausibility=False)
        assert layer == front
        expected = render_views(gaussians, batch.target_poses[b], h, w, settings=raster_settings(model.config),
                                front=layer)
        torch.testing.assert_close(drawn.rgb[b], expected.rgb, atol=2e-4, rtol=0)
        torch.testing.assert_close(drawn.alpha[b], expected.alpha, atol=2e-4, rtol=0)
    # and it is not the one-pass drawing (the volume would show through the pixel layer elsewhere)
    one_pass = render_equirect(out.gaussians, batch.target_poses, h, w, backend="torch")
    assert (one_pass.rgb - drawn.rgb).abs().max() > 1e-3


def test_model_drawing_trains_both_branches(synth_root, tmp_path):
    torch.manual_seed(0)
    trainer = _trainer(synth_root, tmp_path / "run", "recipes/tiny_sharp", "train.render_drawing=model")
    trainer.model.train()
    terms = trainer.compute_loss(_batch(trainer))
    terms.total.backward()
    for branch in ("pixel", "volume"):
        grads = [p.grad for p in trainer.model.branch_parameters(branch) if p.grad is not None]
        assert grads and all(torch.isfinite(g).all() for g in grads), branch
        assert sum(float(g.abs().sum()) for g in grads) > 0, branch


def test_one_pass_stays_the_default(synth_root, tmp_path):
    trainer = _trainer(synth_root, tmp_path / "run", "tiny")
    assert trainer.config.train.render_drawing == "one_pass"
    batch = _batch(trainer)
    with torch.no_grad():
        out = trainer.model.eval()(batch.context_images, batch.context_priors, batch.context_poses)
        h, w = batch.target_images.shape[-2:]
        expected = render_equirect(out.gaussians, batch.target_poses, h, w, backend="torch")
        torch.testing.assert_close(trainer._render(out.gaussians, batch).rgb, expected.rgb)
    with pytest.raises(ValueError, match="render_drawing"):
        load_config("tiny", ["train.render_drawing=layers"])
