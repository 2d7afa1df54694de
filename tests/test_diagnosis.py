"""Issue 34: the detail diagnosis (regions, oracle ladder, source shares) and the sharp pixel-Gaussian switches."""

import math

import pytest
import torch

from cylindersplat.data import SyntheticDataset
from cylindersplat.evaluation.diagnosis import REGIONS, ladder, source_shares, target_regions
from cylindersplat.geometry import equirect_rays
from cylindersplat.geometry.rotations import quaternion_to_matrix
from cylindersplat.metrics import ws_psnr
from cylindersplat.model import from_config
from cylindersplat.model.gaussian_heads import surface_footprints
from cylindersplat.render import Equirect, RasterSettings, render


@pytest.fixture(scope="module")
def sample(synth_dataset):
    return SyntheticDataset(synth_dataset(2, 0), views="two_view", depth_prior=None)[0]


@pytest.fixture(scope="module")
def model_output(sample):
    torch.manual_seed(0)
    model = from_config("tiny_paper").eval()
    with torch.no_grad():
        return model(sample.context_images[None], sample.context_priors[None], sample.context_poses[None])


def test_regions_partition_the_valid_target_pixels(sample):
    masks = target_regions(sample)
    assert set(masks) == set(REGIONS)
    parts = [masks[name] for name in REGIONS if name != "all"]
    total = sum(part.int() for part in parts)
    assert int(total.max()) <= 1  # disjoint
    valid = sample.target_depths > 1e-3
    assert torch.equal(total.bool(), valid)  # and together every pixel with depth
    assert masks["all"].all()


def test_first_rung_at_an_inputs_own_pose_redraws_that_input(sample, model_output):
    """The splatted warp of the nearest input, drawn from that input's own pose with its pixels' own surface
    patches and no dilation, is that input image again (the reference is the image itself)."""
    rungs = ladder(model_output, sample.context_images, sample.context_gt_depths, sample.context_poses, 0, 0.5)
    h, w = sample.context_images.shape[-2:]
    out = render(rungs["splat warp"], sample.context_poses[:1], Equirect(h, w), settings=RasterSettings(dilation=0.0),
                 backend="torch")
    assert float(out.alpha.mean()) > 0.97
    assert float(ws_psnr(out.rgb.clamp(0, 1), sample.context_images[:1])) > 30.0
    # each rung changes one thing: the colours of "+ learned colour" are the head's, the geometry stays
    assert torch.equal(rungs["+ all views"].means, rungs["+ learned colour"].means)
    assert len(rungs["+ all views"]) == 2 * len(rungs["splat warp"])


def test_source_shares_add_up_to_the_renders_coverage(sample, model_output):
    h, w = sample.target_images.shape[-2:]
    shares = source_shares(model_output, sample.target_poses[0], h, w, nearest=0, num_views=2)
    fused = model_output.gaussians.batch(0)[model_output.keep_mask[0]]
    alpha = render(fused, sample.target_poses[0], Equirect(h, w), backend="torch").alpha
    assert torch.allclose(shares.sum(0), alpha, atol=1e-4)


def _plane_depth(h=32, w=64, height=1.5):
    rays = equirect_rays(h, w)
    return torch.where(rays[..., 1] > 0.05, height / rays[..., 1].clamp_min(1e-3), torch.full((h, w), 10.0))


def test_surface_footprints_lie_flat_on_the_surface():
    depth = _plane_depth()
    scales, quats = surface_footprints(depth[None], 0.5)
    axes = quaternion_to_matrix(quats[0]).reshape(32, 64, 3, 3)
    floor = (slice(22, 30), slice(None))  # rows that see the floor (y = +1.5, camera y down)
    normal = axes[floor][..., :, 2]
    assert torch.allclose(normal.abs(), torch.tensor([0.0, 1.0, 0.0]).expand_as(normal), atol=1e-4)
    # in-plane std-devs are footprint_px times the shorter surface step to a neighbouring pixel along the row
    points = equirect_rays(32, 64) * depth[..., None]
    forward = (points.roll(-1, dims=1) - points).norm(dim=-1)
    step = torch.minimum(forward, (points - points.roll(1, dims=1)).norm(dim=-1))
    frontal = depth * math.pi / 32
    expected = 0.5 * torch.minimum(step, 4 * frontal)
    assert torch.allclose(scales[0].reshape(32, 64, 3)[floor][..., 0], expected[floor], rtol=1e-4)
    assert torch.allclose(scales[0].reshape(32, 64, 3)[..., 2], 0.05 * frontal, rtol=1e-5)


def test_surface_footprints_make_no_needles_at_depth_edges():
    """A pixel beside a depth step takes its patch from the neighbour on its own surface: no Gaussian is stretched
    across the step (every in-plane std-dev stays about the frontal one: a sphere of 4 m around the camera with a
    patch at 1 m in front of it)."""
    h, w = 32, 64
    depth = torch.full((h, w), 4.0)
    depth[10:20, 20:30] = 1.0
    scales, _ = surface_footprints(depth[None], 0.5)
    frontal = depth * math.pi / h * 0.5
    ratio = scales[0].reshape(h, w, 3)[..., :2] / frontal[..., None]
    rows = slice(12, 18)  # near the equator, where a pixel's patch is about square
    assert float(ratio[rows].max()) < 1.5


def test_pixel_switches_do_what_they_say(sample):
    torch.manual_seed(0)
    base = from_config("tiny_paper", **{"pixel.edge_sigma": 0.0}).eval()
    images, prior, c2w = sample.context_images[None], sample.context_priors[None].clone(), sample.context_poses[None]
    prior[0, 0, :4] = 0.0  # a hole in the first view's prior
    h = images.shape[-2]
    with torch.no_grad():
        pixel = base.with_config(**{"pixel.footprint": "pixel", "pixel.footprint_px": 0.4})(images, prior, c2w)
        opaque = base.with_config(**{"pixel.opacity": "opaque"})(images, prior, c2w)
        kept = base.with_config(**{"pixel.refine_depth": "where_missing"})(images, prior, c2w)
        plain = base(images, prior, c2w)
    scales = pixel.pixel_gaussians.scales[0]
    expected = pixel.refined_depth[0].reshape(-1) * math.pi / h * 0.4
    assert torch.allclose(scales, expected[:, None].expand_as(scales), rtol=1e-5)
    assert torch.all(opaque.pixel_gaussians.opacities == 1.0)
    valid = prior[0] > 0
    assert torch.allclose(kept.refined_depth[0][valid], prior[0][valid])
    # where the prior has a hole, the refinement still moves the filled-in depth (the view's median valid prior)
    view_median = torch.stack([view[view > 0].median() for view in prior[0]])  # (V,)
    filled = view_median[:, None, None].expand_as(prior[0])
    assert not torch.allclose(kept.refined_depth[0][~valid], filled[~valid])
    assert not torch.allclose(plain.refined_depth[0][valid], prior[0][valid])  # the paper's refinement moves it


def test_with_config_keeps_the_weights_and_refuses_a_shape_change():
    torch.manual_seed(0)
    model = from_config("tiny_paper")
    other = model.with_config(render_dilation=0.0)
    assert other.config.render_dilation == 0.0 and model.config.render_dilation == 0.3
    for (name, a), (_, b) in zip(model.state_dict().items(), other.state_dict().items()):
        assert torch.equal(a, b), name
    with pytest.raises(ValueError, match="change the model's parameters"):
        model.with_config(**{"pixel.head_hidden": 8})
    with pytest.raises(ValueError, match="pixel.footprint"):
        model.with_config(**{"pixel.footprint": "huge"})


def test_model_method_draws_with_the_models_dilation(sample):
    from cylindersplat.evaluation import model_method
    from cylindersplat.inference import reconstruct_gaussians

    torch.manual_seed(0)
    model = from_config("tiny_paper", render_dilation=0.0).eval()
    out = model_method(model).run(sample)
    gaussians = reconstruct_gaussians(model, sample.context_images, sample.context_priors, sample.context_poses)
    h, w = sample.target_images.shape[-2:]
    sharp = render(gaussians, sample.target_poses, Equirect(h, w), settings=RasterSettings(dilation=0.0))
    soft = render(gaussians, sample.target_poses, Equirect(h, w))
    assert torch.allclose(out.rgb, sharp.rgb, atol=1e-5)
    assert not torch.allclose(out.rgb, soft.rgb, atol=1e-3)


def test_surface_clearance_fades_volume_gaussians_just_behind_a_seen_surface():
    """``fusion.surface_clearance``: with a wall 2 m in front of the camera, volume points in front of it fade (seen
    empty), points just behind it fade (inside the surface), points far behind it stay (hidden space); the factor
    is the documented ``exp(-e^2/2s^2) * (1 - exp(-e^2/2c^2))`` of the relative depth error ``e``."""
    from cylindersplat.model.fusion import hidden_confidence

    depth = torch.full((1, 1, 16, 32), 2.0)
    c2w = torch.eye(4)[None, None]
    distances = torch.tensor([1.0, 1.9, 2.0, 2.1, 2.4, 4.0])
    points = torch.stack([torch.zeros(6), torch.zeros(6), distances], dim=-1)[None]  # straight ahead
    plain = hidden_confidence(points, c2w, depth, sigma=0.1)[0]
    cleared = hidden_confidence(points, c2w, depth, sigma=0.1, clearance=0.2)[0]
    e = (distances - 2.0) / 2.0
    front = torch.exp(-0.5 * (e.clamp(max=0) / 0.1) ** 2)
    assert torch.allclose(plain, front, atol=1e-5)
    assert torch.allclose(cleared, front * (1 - torch.exp(-0.5 * (e.clamp(min=0) / 0.2) ** 2)), atol=1e-5)
    assert cleared[2] < 1e-6 and cleared[3] < 0.05 and cleared[5] > 0.99 and cleared[0] < 1e-6
