"""Issue 23's model pieces against constructed scenes and hand-computed references: the colour rules for hidden
points, the released tap features, pixel clearing, k Gaussians per cell, all-view attention, the released volume
loss, and the string choices defined once."""

import math
import typing

import pytest
import torch

from cylindersplat.geometry import equirect_rays, make_c2w
from cylindersplat.model import from_config
from cylindersplat.model.config import CHOICES, COLOR_RULES, config_from_dict, config_to_dict, get_config
from cylindersplat.model.fusion import fuse, hidden_confidence
from cylindersplat.model.rgb_retrieval import retrieve_colors, retrieve_colors_window, tap_features


def occluded_wall(h=32, w=64):
    """One camera at the origin facing a wall 5 m away everywhere (blue), with a red occluder 2 m away over a
    3x3-pixel patch around the pixel (row 16, column 32). Returns images (1, 1, 3, H, W), depth (1, 1, H, W),
    c2w (1, 1, 4, 4) and the hidden wall point straight behind the occluder's centre pixel (1, 1, 3)."""
    depth = torch.full((h, w), 5.0)
    image = torch.zeros(3, h, w)
    image[2] = 1.0
    depth[15:18, 31:34] = 2.0
    image[:, 15:18, 31:34] = torch.tensor([1.0, 0.0, 0.0])[:, None, None]
    ray = equirect_rays(h, w)[16, 32]
    return image[None, None], depth[None, None], torch.eye(4)[None, None], (5.0 * ray)[None, None]


def test_eq6_colours_a_hidden_point_with_its_occluder_and_the_surface_rule_with_the_hidden_surface():
    images, depth, c2w, hidden = occluded_wall()
    eq6, _ = retrieve_colors(hidden, images, depth, c2w, temperature=1.0)
    surface, weights = retrieve_colors_window(hidden, images, depth, c2w, window=4, temperature=0.1)
    red, blue = torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0])
    torch.testing.assert_close(eq6[0, 0], red)  # one view: Eq. 6's softmax has nothing else to pick
    # the nearest observed points are the wall beside the occluder, 0.5-1 m from the point against 3 m to the occluder
    assert torch.dist(surface[0, 0], blue) < 1e-3
    assert weights.shape == (1, 1, 81, 1) and float(weights.sum()) == pytest.approx(1.0)


def test_tap_features_are_the_3x3_neighbourhood_and_the_depth_difference():
    torch.manual_seed(0)
    h, w = 16, 32
    images, depth = torch.rand(1, 2, 3, h, w), torch.rand(1, 2, h, w) + 1.0
    c2w = torch.stack((make_c2w(), make_c2w(translation=torch.tensor([0.5, 0.0, 0.0]))))[None]
    ray = equirect_rays(h, w)[7, 11]  # a pixel centre of view 0, 3 m away
    point = (3.0 * ray)[None, None]
    features = tap_features(point, images, depth, c2w, window=1)  # (1, 1, V, 9, 4)
    assert features.shape == (1, 1, 2, 9, 4)
    expected = images[0, 0, :, 6:9, 10:13].permute(1, 2, 0).reshape(9, 3)  # x fastest within a row
    torch.testing.assert_close(features[0, 0, 0, :, :3], expected)
    torch.testing.assert_close(features[0, 0, 0, :, 3], torch.full((9,), 3.0 - float(depth[0, 0, 7, 11])))
    # view 1: the difference is read at the projection, the same for its nine taps
    distance = float(torch.linalg.vector_norm(point[0, 0] - torch.tensor([0.5, 0.0, 0.0])))
    assert torch.allclose(features[0, 0, 1, :, 3], features[0, 0, 1, 0, 3])
    assert distance - 2.0 <= float(features[0, 0, 1, 0, 3]) <= distance - 1.0  # the prior lies in [1, 2]


def test_released_mlp_rejects_more_views_than_it_was_built_for():
    model = from_config("tiny_paper", **{"volume.color": "released_mlp", "volume.color_views": 2})
    images, depth = torch.rand(1, 3, 3, 16, 32), torch.ones(1, 3, 16, 32)
    c2w = torch.eye(4).repeat(1, 3, 1, 1)
    with pytest.raises(ValueError, match="at most volume.color_views=2 input views, got 3"):
        model(images, depth, c2w)


def test_pixel_clearing_fades_pixel_gaussians_in_space_another_view_saw_empty():
    torch.manual_seed(0)
    model = from_config("tiny_paper", **{"fusion.strategy": "depth_prune", "fusion.side": "hidden",
                                         "fusion.pixel_clearing": "seen_through"}).eval()
    images, depth = torch.rand(1, 2, 3, 64, 128), torch.full((1, 2, 64, 128), 3.0)
    c2w = torch.stack((make_c2w(), make_c2w(translation=torch.tensor([1.0, 0.0, 0.0]))))[None]
    with torch.no_grad():
        out = model(images, depth, c2w)
    pixel = out.pixel_gaussians
    n = pixel.num_gaussians
    expected = pixel.opacities * hidden_confidence(pixel.means, c2w, out.refined_depth, 0.1)
    torch.testing.assert_close(out.gaussians.opacities[:, :n], expected)
    # unchanged when there is no volume branch output (stage 1) or clearing is off
    assert torch.equal(fuse(pixel, None, out.refined_depth, c2w, model.config.fusion)[0].opacities, pixel.opacities)
    model.config.fusion.pixel_clearing = "none"
    with torch.no_grad():
        assert torch.equal(model(images, depth, c2w).gaussians.opacities[:, :n], pixel.opacities)


def test_pixel_clearing_keeps_surfaces_and_fades_a_flying_pixel():
    # camera 0 at the origin, camera 1 at x = 2; both see a surface 3 m away everywhere
    c2w = torch.stack((make_c2w(), make_c2w(translation=torch.tensor([2.0, 0.0, 0.0]))))[None]
    depth = torch.full((1, 2, 16, 32), 3.0)
    on_surface = torch.tensor([0.0, 0.0, 3.0])  # on camera 0's surface, 3.6 m from camera 1: behind its surface
    flying = torch.tensor([1.0, 0.0, 1.5])  # 1.8 m from both: space both saw empty
    conf = hidden_confidence(torch.stack((on_surface, flying))[None], c2w, depth, 0.1)
    assert float(conf[0, 0]) == pytest.approx(1.0, abs=1e-4) and float(conf[0, 1]) < 1e-6


def test_k_gaussians_per_cell_stay_inside_their_cell():
    torch.manual_seed(0)
    k = 3
    changes = {"volume.gaussians_per_cell": k, "fusion.strategy": "concat"}
    model = from_config("tiny_paper", **changes).set_mode("volume")
    images, depth = torch.rand(1, 1, 3, 64, 128), torch.full((1, 1, 64, 128), 2.0)
    with torch.no_grad():
        out = model(images, depth, torch.eye(4)[None, None])
    vb = model.volume_branch
    cells = math.prod(model.config.volume.grid)
    assert vb.gaussians_per_camera == cells * k and out.gaussians.num_gaussians == cells * k
    # every Gaussian lies in the cell it was decoded for (cells in grid order, k side by side)
    q = vb.coords.from_cartesian(out.gaussians.means[0])
    centers = vb.coords.cell_centers(model.config.volume.grid).reshape(-1, 3).repeat_interleave(k, dim=0)
    half = torch.tensor(vb.coords.cell_size(model.config.volume.grid)) / 2
    delta = (q - centers).abs()
    delta[:, 1] = torch.minimum(delta[:, 1], 2 * math.pi - delta[:, 1])  # theta wraps
    assert bool((delta <= half + 1e-4).all())
    # the k Gaussians of a cell differ (own offsets), they are not copies
    assert float((out.gaussians.means[0, 0::k] - out.gaussians.means[0, 1::k]).abs().max()) > 1e-4


def test_all_view_attention_with_one_view_equals_own_view_attention():
    torch.manual_seed(0)
    own = from_config("tiny_paper").eval()
    every = from_config("tiny_paper", **{"volume.image_views": "all"}).eval()
    every.load_state_dict(own.state_dict())
    images, depth = torch.rand(1, 1, 3, 64, 128), torch.rand(1, 1, 64, 128) + 1.0
    c2w = make_c2w(translation=torch.tensor([0.3, -0.2, 0.5]))[None, None]
    with torch.no_grad():
        a, b = own(images, depth, c2w), every(images, depth, c2w)
    torch.testing.assert_close(a.gaussians.means, b.gaussians.means, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(a.gaussians.opacities, b.gaussians.opacities, atol=1e-5, rtol=1e-5)
    # with two views the triplanes read the other view too: the volume Gaussians change
    images2, depth2 = torch.rand(1, 2, 3, 64, 128), torch.rand(1, 2, 64, 128) + 1.0
    c2w2 = torch.stack((make_c2w(), make_c2w(translation=torch.tensor([1.0, 0.0, 0.0]))))[None]
    with torch.no_grad():
        n = 2 * 64 * 128
        diff = own(images2, depth2, c2w2).gaussians.means[:, n:] - every(images2, depth2, c2w2).gaussians.means[:, n:]
    assert float(diff.abs().max()) > 1e-4


def test_stored_configs_with_a_retrieval_window_load_as_the_surface_rule():
    stored = config_to_dict(get_config("tiny_paper"))
    stored["volume"] = {k: v for k, v in stored["volume"].items()
                        if k not in ("surface_window", "surface_temperature", "learn_temperature", "color_views",
                                     "image_views", "gaussians_per_cell")}
    stored["volume"].update(retrieval_window=2, visibility_temperature=0.5)
    cfg = config_from_dict(stored).validate()
    assert (cfg.volume.color, cfg.volume.surface_window, cfg.volume.surface_temperature) == ("surface", 2, 0.5)
    stored["volume"]["retrieval_window"] = 0
    assert config_from_dict(stored).volume.color == "retrieval"


def test_every_string_choice_is_defined_once():
    """The config's Literal annotations, its validation and the colour registry agree with CHOICES."""
    from cylindersplat.model import config as module

    for key, allowed in CHOICES.items():
        section, _, name = key.rpartition(".")
        if section in ("train", "loss", "data"):  # the training run's choices: tests/test_config_keys.py
            continue
        cls = {"": module.ModelConfig, "volume": module.VolumeBranchConfig, "fusion": module.FusionConfig,
               "pixel": module.PixelBranchConfig}[section]
        hints = typing.get_type_hints(cls)
        assert typing.get_args(hints[name]) == allowed, key
        with pytest.raises(ValueError, match=f"{key} must be one of"):
            get_config("tiny_paper", **{key: "nonsense"})
    assert tuple(COLOR_RULES) == CHOICES["volume.color"]
    for color in COLOR_RULES:  # every registered rule builds and runs
        model = from_config("tiny_paper", **{"volume.color": color})
        out = model(torch.rand(1, 2, 3, 64, 128), torch.ones(1, 2, 64, 128), torch.eye(4).repeat(1, 2, 1, 1))
        assert torch.isfinite(out.gaussians.rgb).all()


def test_released_volume_loss_is_the_released_weighted_sum():
    from cylindersplat.training.losses import LossConfig, RenderLoss

    torch.manual_seed(0)
    rgb, target = torch.rand(1, 1, 3, 4, 8), torch.rand(1, 1, 3, 4, 8)
    depth, reference = torch.rand(1, 1, 4, 8) + 1, torch.rand(1, 1, 4, 8) + 1
    reference[..., 0, :] = 0  # invalid reference: left out of the depth mean
    terms = RenderLoss(LossConfig(use_lpips="off")).released_volume(rgb, depth, target, reference)
    valid = reference > 0
    expected = 0.1 * ((rgb - target) ** 2).mean() + 0.1 * (depth - reference)[valid].abs().mean()
    assert float(terms.total) == pytest.approx(float(expected), rel=1e-6)
