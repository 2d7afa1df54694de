"""Layered drawing (``render_layering="pixel_over_volume"``, issue 34): the compositing formula against the over
operator and the coverage normalisation, a constructed leak that the one-pass drawing shows and the layers do not,
and the model's front layer (its pixel Gaussians) through ``reconstruct_gaussians`` and ``eval``."""

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry import make_c2w
from cylindersplat.inference.pipeline import reconstruct_gaussians, render_views
from cylindersplat.render import Equirect, RasterSettings, render
from cylindersplat.render.api import RenderOutput
from cylindersplat.render.layered import FrontLayer, blend_front_surface, composite_layers, render_layered


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
    plain = composite_layers(_out([0.7, 0.0, 0.0], 0.7 * 2.0, 0.7), back, cover=None)  # never opaque: the over operator
    torch.testing.assert_close(plain.rgb.flatten(), torch.tensor([0.7, 0.3 * 0.4, 0.0]))
    torch.testing.assert_close(plain.alpha, torch.tensor([[0.7 + 0.3 * 0.8]]))


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
    assert front == FrontLayer(out.pixel_gaussians.num_gaussians, blend=False, opaque=True)
    assert front.count == 2 * 64 * 128
    torch.testing.assert_close(gaussians.means[:front.count], out.pixel_gaussians.means[0])
    threshold = float(out.gaussians.opacities.median())
    kept, kept_front = reconstruct_gaussians(model, images, depths, c2w, min_opacity=threshold, layers=True)
    assert kept_front.count == int((out.pixel_gaussians.opacities[0] > threshold).sum())
    assert len(kept) == int((out.gaussians.opacities[0] > threshold).sum())
    # the one-pass model has no front layer, and without layers=True the call returns the Gaussians alone
    assert reconstruct_gaussians(tiny_model, images, depths, c2w, layers=True)[1] is None
    assert isinstance(reconstruct_gaussians(model, images, depths, c2w), Gaussians)
    # render_views(front=...) is render_layered of the two parts
    views = render_views(gaussians, c2w[:1], 16, 32, front=front)
    direct = render_layered(gaussians[:front.count], gaussians[front.count:], c2w[:1], Equirect(16, 32))
    torch.testing.assert_close(views.rgb, direct.rgb)
    torch.testing.assert_close(render_views(gaussians, c2w[:1], 16, 32, front=front.count).rgb, direct.rgb)  # a count
    # the blended drawing: the same front layer, its colour by surface splatting
    blended = tiny_model.with_config(render_pixel_blending="surface").eval()
    gaussians, front = reconstruct_gaussians(blended, images, depths, c2w, layers=True)
    assert front == FrontLayer(out.pixel_gaussians.num_gaussians, blend=True, opaque=False)
    views = render_views(gaussians, c2w[:1], 16, 32, front=front)
    direct = render_layered(gaussians[:front.count], gaussians[front.count:], c2w[:1], Equirect(16, 32), cover=None,
                            blend=True)
    torch.testing.assert_close(views.rgb, direct.rgb)
    both = blended.with_config(render_layering="pixel_over_volume")
    assert reconstruct_gaussians(both, images, depths, c2w, layers=True)[1] == FrontLayer(front.count, True, True)
    # its pixel branch alone (the cheapest alternative's row) is drawn with the same blending
    alone, front = reconstruct_gaussians(blended.with_config().set_mode("pixel"), images, depths, c2w, layers=True)
    assert front == FrontLayer(len(alone), blend=True, opaque=True) and len(alone) == out.pixel_gaussians.num_gaussians


def _wall(z, colours, spacing=0.1, n=13):
    """A square grid of ``n x n`` isotropic opaque splats (std half the spacing) ``z`` metres ahead, centred on the
    view axis; ``colours`` (n*n, 3)."""
    ticks = (torch.arange(n, dtype=torch.float64) - (n - 1) / 2) * spacing
    ys, xs = torch.meshgrid(ticks, ticks, indexing="ij")
    means = torch.stack((xs.flatten(), ys.flatten(), torch.full((n * n,), float(z), dtype=torch.float64)), -1)
    count = n * n
    return Gaussians.from_rgb(means, torch.full((count, 3), spacing / 2, dtype=torch.float64),
                              torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(count, 1),
                              torch.ones(count, dtype=torch.float64), colours)


def _backends():
    """Every backend the blending may run on here (the fast ones take the tiny blending opacities too)."""
    import importlib.util

    from cylindersplat.render import available_backends

    names = ["torch"] + [b for b in ("numba",) if b in available_backends()]
    if importlib.util.find_spec("triton") is not None:  # on the CPU in Triton's interpreter (conftest.py)
        names.append("triton")
    return names


@pytest.mark.parametrize("backend", _backends())
def test_blending_is_the_normalised_weighted_mean_of_the_front_surface(backend):
    """Reference: the weights computed per pixel from the projected footprints (opacity x exp(-mahalanobis / 2)
    inside the support), summed over the front wall's splats only; the wall behind it (1.5x as far) is left out.
    Every backend: the blending pass's opacities (1/1000) are far below 3DGS's alpha threshold."""
    torch.manual_seed(0)
    dtype = torch.float64 if backend == "torch" else torch.float32
    wall = _wall(2.0, torch.rand(169, 3, dtype=torch.float64))
    behind = _wall(3.0, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64).repeat(169, 1), spacing=0.15)
    device = "cuda" if backend == "triton" and torch.cuda.is_available() else "cpu"  # else Triton's interpreter
    wall, behind = (Gaussians(**{k: v.to(dtype) for k, v in g.tensors().items()}) for g in (wall, behind))
    both = Gaussians(**{k: v.to(device) for k, v in Gaussians.cat([wall, behind]).tensors().items()})
    camera, pose, settings = Equirect(48, 96), torch.eye(4, dtype=dtype, device=device), RasterSettings(dilation=0.0)
    drawn = render(both, pose, camera, backend=backend, settings=settings)
    blended = blend_front_surface(both, pose, camera, drawn, backend=backend, settings=settings)
    drawn, blended = (RenderOutput(o.rgb.cpu(), o.depth.cpu(), o.alpha.cpu()) for o in (drawn, blended))
    pose = pose.cpu()
    proj = camera.project(wall, pose, settings)
    jj, ii = torch.meshgrid(torch.arange(96, dtype=dtype) + 0.5, torch.arange(48, dtype=dtype) + 0.5, indexing="xy")
    du = jj[None] - proj.uv[:, 0, None, None]
    dv = ii[None] - proj.uv[:, 1, None, None]
    a, b, c = (proj.conic[:, k, None, None] for k in range(3))
    mahal = a * du * du + 2 * b * du * dv + c * dv * dv
    weight = proj.opacity[:, None, None] * torch.exp(-0.5 * mahal) * (mahal <= settings.sigma_extent ** 2)
    reference = torch.einsum("nhw,nc->chw", weight, proj.color) / weight.sum(0).clamp_min(1e-30)
    covered = drawn.alpha > 0.9
    assert int(covered.sum()) >= 50
    torch.testing.assert_close(blended.rgb[:, covered] / drawn.alpha[covered], reference[:, covered], atol=3e-3,
                               rtol=0)
    assert float((drawn.rgb[:, covered] / drawn.alpha[covered] - reference[:, covered]).abs().max()) > 0.05  # over
    torch.testing.assert_close(blended.alpha, drawn.alpha)  # coverage and depth are the drawing's
    torch.testing.assert_close(blended.depth, drawn.depth)


def test_blending_averages_two_views_of_one_surface_where_the_over_operator_keeps_one():
    """Two inputs' splats on the same wall (one 0.5 % nearer): over shows mostly the nearer one's red, blending
    the mean; a wall farther behind than the tolerance is left out."""
    red = _wall(2.0, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64).repeat(169, 1))
    blue = _wall(2.01, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).repeat(169, 1))
    camera, pose = Equirect(32, 64), torch.eye(4, dtype=torch.float64)
    both = Gaussians.cat([red, blue])
    drawn = render(both, pose, camera, backend="torch")
    centre = drawn.alpha > 0.99
    assert int(centre.sum()) > 10
    over = drawn.rgb[:, centre] / drawn.alpha[centre]
    assert float((over[0] - over[2]).min()) > 0.2  # the nearer red wins (the blue shows only between red centres)
    mean = blend_front_surface(both, pose, camera, drawn, backend="torch").rgb[:, centre] / drawn.alpha[centre]
    torch.testing.assert_close(mean[0], mean[2], atol=0.02, rtol=0)  # red and blue alike
    assert float(mean[0].min()) > 0.4
    far_blue = Gaussians.cat([red, _wall(2.3, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).repeat(169, 1))])
    far = render(far_blue, pose, camera, backend="torch")
    only_red = blend_front_surface(far_blue, pose, camera, far, backend="torch").rgb[:, centre] / far.alpha[centre]
    assert float(only_red[2].max()) < 1e-6  # 15 % behind: beyond the tolerance, left out
    with pytest.raises(ValueError, match="tolerance"):
        blend_front_surface(both, pose, camera, drawn, tolerance=0.0)
