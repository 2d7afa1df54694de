"""Layered drawing (``render_layering="pixel_over_volume"``, issue 34): the compositing formula against the over
operator and the coverage normalisation, a constructed leak that the one-pass drawing shows and the layers do not,
and the model's front layer (its pixel Gaussians) through ``reconstruct_gaussians`` and ``eval``."""

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry import make_c2w
from cylindersplat.inference.pipeline import reconstruct_gaussians, render_views
from cylindersplat.render import Equirect, render
from cylindersplat.render.api import RenderOutput
from cylindersplat.render.layered import composite_layers, render_layered


def _out(rgb, depth, alpha):
    return RenderOutput(torch.as_tensor(rgb).view(3, 1, 1), torch.tensor([[depth]]), torch.tensor([[alpha]]))


def test_composite_is_the_over_operator_below_cover_and_the_front_alone_above():
    back = _out([0.0, 0.4, 0.0], 3.0, 0.8)
    thin = composite_layers(_out([0.2, 0.0, 0.0], 0.2, 0.2), back, cover=(0.3, 0.6))  # 20 % covered: plain over
    torch.testing.assert_close(thin.rgb.flatten(), torch.tensor([0.2, 0.8 * 0.4, 0.0]))
    torch.testing.assert_close(thin.depth, torch.tensor([[0.2 + 0.8 * 3.0]]))
    torch.testing.assert_close(thin.alpha, torch.tensor([[0.2 + 0.8 * 0.8]]))
    dense = composite_layers(_out([0.7, 0.0, 0.0], 0.7 * 2.0, 0.7), back, cover=(0.3, 0.6))  # above cover: opaque
    torch.testing.assert_close(dense.rgb.flatten(), torch.tensor([1.0, 0.0, 0.0]))
    torch.testing.assert_close(dense.depth, torch.tensor([[2.0]]))
    torch.testing.assert_close(dense.alpha, torch.tensor([[1.0]]))
    half = composite_layers(_out([0.45, 0.0, 0.0], 0.45, 0.45), back, cover=(0.3, 0.6))  # halfway: smoothstep 1/2
    over, own = torch.tensor([0.45, 0.55 * 0.4, 0.0]), torch.tensor([1.0, 0.0, 0.0])
    torch.testing.assert_close(half.rgb.flatten(), 0.5 * over + 0.5 * own)
    with pytest.raises(ValueError, match="cover"):
        composite_layers(back, back, cover=(0.6, 0.3))


def _wall_and_red_ball():
    """A grey wall of small opaque splats 2 m ahead (partial coverage between their centres) and a red ball 4 m
    ahead, behind it, from a camera at the origin looking along +z."""
    ys, xs = torch.meshgrid(torch.linspace(-1.0, 1.0, 21), torch.linspace(-1.0, 1.0, 21), indexing="ij")
    means = torch.stack((xs.flatten(), ys.flatten(), torch.full((441,), 2.0)), -1)
    wall = Gaussians.from_rgb(means, torch.full((441, 3), 0.02), torch.tensor([[1.0, 0, 0, 0]]).repeat(441, 1),
                              torch.ones(441), torch.full((441, 3), 0.5))
    ball = Gaussians.from_rgb(torch.tensor([[0.0, 0.0, 4.0]]), torch.full((1, 3), 0.8), torch.tensor([[1.0, 0, 0, 0]]),
                              torch.ones(1), torch.tensor([[1.0, 0.0, 0.0]]))
    return wall, ball


def test_layers_hide_what_leaks_through_a_partly_covered_surface():
    wall, ball = _wall_and_red_ball()
    camera, pose = Equirect(64, 128), torch.eye(4)
    one_pass = render(Gaussians.cat([wall, ball]), pose, camera, backend="torch")
    front = render(wall, pose, camera, backend="torch")
    layered = render_layered(wall, ball, pose, camera, backend="torch")
    covered = front.alpha > 0.6  # the wall's pixels
    assert int(covered.sum()) > 20 and float(front.alpha[covered].min()) < 0.999  # partly covered between splats
    red_leak = one_pass.rgb[0][covered] - one_pass.rgb[1][covered]
    assert float(red_leak.max()) > 0.01  # one pass: the ball shows through
    grey = front.rgb[:, covered] / front.alpha[covered]
    torch.testing.assert_close(layered.rgb[:, covered], grey)  # layers: the wall's own colour, nothing red
    assert float(layered.alpha[covered].min()) == pytest.approx(1.0)
    # where the wall covers nothing, the ball is drawn as in one pass
    empty = front.alpha < 1e-6
    torch.testing.assert_close(layered.rgb[:, empty], one_pass.rgb[:, empty], atol=1e-6, rtol=1e-5)
    # a background goes behind both layers
    grey_bg = render_layered(wall, ball, pose, camera, background=(0.5, 0.5, 0.5), backend="torch")
    torch.testing.assert_close(grey_bg.rgb, layered.rgb + (1 - layered.alpha) * 0.5)


def test_the_models_front_layer_is_its_pixel_gaussians(tiny_model):
    torch.manual_seed(0)
    model = tiny_model.with_config(render_layering="pixel_over_volume").eval()
    images, depths = torch.rand(2, 3, 64, 128), torch.full((2, 64, 128), 3.0)
    c2w = torch.stack((make_c2w(), make_c2w(translation=torch.tensor([0.5, 0.0, 0.0]))))
    with torch.no_grad():
        out = model(images[None], depths[None], c2w[None])
    gaussians, front = reconstruct_gaussians(model, images, depths, c2w, layers=True)
    assert front == out.pixel_gaussians.num_gaussians == 2 * 64 * 128
    torch.testing.assert_close(gaussians.means[:front], out.pixel_gaussians.means[0])
    threshold = float(out.gaussians.opacities.median())
    kept, kept_front = reconstruct_gaussians(model, images, depths, c2w, min_opacity=threshold, layers=True)
    assert kept_front == int((out.pixel_gaussians.opacities[0] > threshold).sum())
    assert len(kept) == int((out.gaussians.opacities[0] > threshold).sum())
    # the one-pass model has no front layer, and without layers=True the call returns the Gaussians alone
    assert reconstruct_gaussians(tiny_model, images, depths, c2w, layers=True)[1] is None
    assert isinstance(reconstruct_gaussians(model, images, depths, c2w), Gaussians)
    # render_views(front=...) is render_layered of the two parts
    views = render_views(gaussians, c2w[:1], 16, 32, front=front)
    direct = render_layered(gaussians[:front], gaussians[front:], c2w[:1], Equirect(16, 32))
    torch.testing.assert_close(views.rgb, direct.rgb)
