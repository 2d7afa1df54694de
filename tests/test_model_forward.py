"""CylinderSplat model: shapes, counts, finiteness, gradients per curriculum mode, presets, I/O."""

import math

import pytest
import torch

from cylindersplat.geometry import equirect_rays
from cylindersplat.model import from_config, get_config, load_model, save_model
from model_inputs import make_inputs as shared_make_inputs

H, W = 64, 128


def make_inputs(views: int = 2, batch: int = 1, seed: int = 0, height: int = H, width: int = W):
    return shared_make_inputs(views, batch, seed, height, width)


@pytest.mark.parametrize("views", [1, 2, 3, 4])
def test_shapes_counts_and_finite(tiny_model, views):
    images, depth, c2w = make_inputs(views)
    with torch.no_grad():
        out = tiny_model.set_mode("both")(images, depth, c2w)
    cells = math.prod(tiny_model.config.volume.grid)
    assert out.pixel_gaussians.num_gaussians == views * H * W
    assert out.volume_gaussians.num_gaussians == views * cells
    assert out.gaussians.num_gaussians == views * (H * W + cells)
    assert out.gaussians.batch_shape == (1,)
    assert out.refined_depth.shape == (1, views, H, W)
    assert out.features.shape == (1, views, tiny_model.config.pixel.feature_dim, H, W)
    assert out.keep_mask.shape == (1, out.gaussians.num_gaussians) and out.keep_mask.all()
    out.gaussians.validate()  # finite, positive scales, opacities in [0, 1], shapes
    assert torch.isfinite(out.refined_depth).all() and torch.isfinite(out.features).all()


def test_batch_of_two_and_branch_modes(tiny_model):
    images, depth, c2w = make_inputs(2, batch=2)
    with torch.no_grad():
        pix = tiny_model.set_mode("pixel")(images, depth, c2w)
        vol = tiny_model.set_mode("volume")(images, depth, c2w)
    tiny_model.set_mode("both")
    assert pix.volume_gaussians is None and pix.gaussians.num_gaussians == 2 * H * W
    assert vol.pixel_gaussians is None and vol.gaussians.num_gaussians == 2 * math.prod(tiny_model.config.volume.grid)
    assert pix.gaussians.batch_shape == (2,) and vol.gaussians.batch_shape == (2,)
    # the two branches' refined depth is the same computation
    torch.testing.assert_close(pix.refined_depth, vol.refined_depth)


def test_pixel_gaussians_lie_on_refined_depth(tiny_model):
    images, depth, c2w = make_inputs(2)
    with torch.no_grad():
        out = tiny_model.set_mode("pixel")(images, depth, c2w)
    tiny_model.set_mode("both")
    means = out.pixel_gaussians.means.view(2, H * W, 3)
    rays_cam = equirect_rays(H, W).reshape(-1, 3)
    for v in range(2):
        offset = means[v] - c2w[0, v, :3, 3]
        torch.testing.assert_close(offset.norm(dim=-1), out.refined_depth[0, v].reshape(-1), rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(offset / offset.norm(dim=-1, keepdim=True), rays_cam @ c2w[0, v, :3, :3].T,
                                   atol=1e-5, rtol=0)
    # refinement is a bounded multiplicative residual on the prior
    ratio = out.refined_depth / depth
    bound = math.exp(tiny_model.config.pixel.max_log_depth_offset)
    assert (ratio <= bound * (1 + 1e-5)).all() and (ratio >= (1 - 1e-5) / bound).all()


@pytest.mark.parametrize("stage", [1, 2, 3])
def test_gradients_reach_every_trainable_parameter(stage):
    torch.manual_seed(1)
    model = from_config("tiny_paper").configure_stage(stage)
    images, depth, c2w = make_inputs(2, seed=stage)
    out = model(images, depth, c2w)
    g = torch.Generator().manual_seed(5)
    loss = sum((t * torch.randn(t.shape, generator=g)).sum() for t in out.gaussians.tensors().values())
    if stage != 2:
        loss = loss + (out.refined_depth * torch.randn(out.refined_depth.shape, generator=g)).sum()
    loss.backward()
    active = {1: ["pixel"], 2: ["volume"], 3: ["pixel", "volume"]}[stage]
    for branch in ("pixel", "volume"):
        for name, p in getattr(model, f"{branch}_branch").named_parameters():
            if branch in active:
                assert p.requires_grad, name
                assert p.grad is not None and p.grad.abs().sum() > 0, f"no gradient reaches {branch}.{name}"
                assert torch.isfinite(p.grad).all(), name
            else:
                assert p.grad is None, f"inactive {branch}.{name} received a gradient"


@pytest.mark.parametrize("kind", ["spherical", "cartesian"])
def test_coordinate_variants(kind):
    torch.manual_seed(2)
    model = from_config("tiny_paper", **{"volume.coordinates": kind, "volume.scale_transform": "exact"})
    assert model.volume_branch.coords.name == kind
    images, depth, c2w = make_inputs(2)
    with torch.no_grad():
        out = model(images, depth, c2w)
    out.gaussians.validate()
    assert out.volume_gaussians.num_gaussians == 2 * math.prod(model.config.volume.grid)


def test_depth_prune_fusion_runs_and_marks_pruned():
    torch.manual_seed(3)
    model = from_config("tiny_paper", **{"fusion.strategy": "depth_prune", "fusion.prune_threshold": 0.3})
    images, depth, c2w = make_inputs(2)
    with torch.no_grad():
        out = model(images, depth, c2w)
    n_pix = out.pixel_gaussians.num_gaussians
    assert out.keep_mask[:, :n_pix].all()  # pixel Gaussians are never pruned
    assert not out.keep_mask[:, n_pix:].all()  # most volume cells are far from any surface
    fused_volume = out.gaussians.opacities[:, n_pix:]
    assert (fused_volume <= out.volume_gaussians.opacities + 1e-7).all()  # attenuation only lowers
    assert torch.equal(out.keep_mask[:, n_pix:], fused_volume >= 0.3)


def test_paper_parameter_count():
    model = from_config("paper")
    counts = model.parameter_counts()
    print("paper parameter counts:", counts)
    assert abs(counts["total"] - 13.6e6) / 13.6e6 < 0.15
    assert get_config("paper").volume.grid == (16, 128, 64)
    assert get_config("paper").volume.image_grid == (8, 64, 32)


def test_save_load_roundtrip(tmp_path):
    torch.manual_seed(4)
    model = from_config("tiny_paper", **{"volume.init": "isolated"})
    path = tmp_path / "model.safetensors"
    save_model(model, path)
    loaded = load_model(path)
    assert loaded.config == model.config
    images, depth, c2w = make_inputs(1)
    with torch.no_grad():
        a, b = model(images, depth, c2w), loaded(images, depth, c2w)
    torch.testing.assert_close(a.gaussians.means, b.gaussians.means)
    torch.testing.assert_close(a.gaussians.sh, b.gaussians.sh)


def test_invalid_inputs_raise(tiny_model):
    images, depth, c2w = make_inputs(1)
    with pytest.raises(ValueError):
        tiny_model(images, depth[..., :-1], c2w)
    with pytest.raises(ValueError):
        tiny_model.set_mode("voxels")
    with pytest.raises(ValueError):
        from_config("huge")


def test_end_to_end_render_backpropagates_to_every_parameter():
    """Model -> render_equirect -> loss: the whole network is trainable through the renderer."""
    from cylindersplat.render import render_equirect as render
    torch.manual_seed(6)
    model = from_config("tiny_paper")
    images, depth, c2w = make_inputs(1)
    out = model(images, depth, c2w)
    rendered = render(out.gaussians, c2w, 16, 32)
    assert rendered.rgb.shape == (1, 1, 3, 16, 32) and rendered.depth.shape == (1, 1, 16, 32)
    assert torch.isfinite(rendered.rgb).all() and torch.isfinite(rendered.depth).all()
    (rendered.rgb.mean() + 0.1 * rendered.depth.mean()).backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or p.grad.abs().sum() == 0]
    assert not missing, f"no gradient through the renderer for {missing}"
