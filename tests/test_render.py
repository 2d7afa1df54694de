"""The PyTorch reference equirect rasterizer against independent references."""

import math

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.render import Equirect, render_cubemap, render_equirect, render_pinhole
from cylindersplat.render.brute_force import composite_brute_force
from cylindersplat.render.projection import RasterSettings
from cylindersplat.render.rasterize import bin_to_tiles, rasterize
from render_scenes import degenerate_scenes, shell_scene, yaw_pose

F64 = torch.float64


def test_tiled_rasterizer_matches_brute_force():
    g = shell_scene(40, sh_degree=3)
    c2w = torch.stack((yaw_pose(0.0), yaw_pose(0.7, (0.3, -0.1, 0.2))))
    settings = RasterSettings()
    proj = Equirect(16, 32).project(g, c2w, settings)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    tiled = rasterize(proj, settings, bg)
    brute = composite_brute_force(proj, settings, bg)
    for a, b in zip(tiled, brute):
        assert (a - b).abs().max() <= 1e-5
    assert tiled[2].max() > 0.9  # the scene actually covers pixels


def test_result_does_not_depend_on_tile_size():
    g = shell_scene(40, seed=3)
    c2w = yaw_pose(0.2)
    ref = render_equirect(g, c2w, 16, 32, settings=RasterSettings(tile_size=16))
    for tile in (4, 7, 32):
        out = render_equirect(g, c2w, 16, 32, settings=RasterSettings(tile_size=tile))
        torch.testing.assert_close(out.rgb, ref.rgb, atol=1e-10, rtol=0)


@pytest.mark.slow  # 51 s at load 12 (2 shared cores)
def test_gradients_match_finite_differences():
    g = shell_scene(5, seed=1, scale=(0.15, 0.35), radius=(1.0, 2.0), sh_degree=1)
    c2w = yaw_pose(0.3)
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=F64)

    def fn(means, scales, rotations, opacities, sh):
        out = render_equirect(Gaussians(means, scales, rotations, opacities, sh), c2w, 8, 16, background=bg)
        return out.rgb, out.depth, out.alpha

    inputs = [t.clone().requires_grad_() for t in g.tensors().values()]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_direct_and_cubemap_renders_agree_away_from_the_poles():
    # Without the (resolution-dependent) 2D dilation both renderers draw the same 3D Gaussians; what
    # remains is the difference of the two EWA linearisations plus bilinear resampling of the faces.
    # Measured: mean |diff| 0.010 within 60 degrees of the equator, 0.018 over the whole sphere
    # (the cube's linearisation is worst where rays meet face corners, the equirect one at the poles).
    g = shell_scene(300, seed=0, scale=(0.1, 0.2), radius=(2.0, 4.0))
    g = Gaussians.from_rgb(g.means, g.scales, g.rotations, g.opacities, torch.rand(300, 3, dtype=F64))
    settings = RasterSettings(dilation=0.0)
    h = 64
    direct = render_equirect(g, torch.eye(4, dtype=F64), h, 2 * h, settings=settings)
    cube = render_cubemap(g, torch.eye(4, dtype=F64), h, 2 * h, face_size=h, settings=settings)
    lat = ((torch.arange(h) + 0.5) / h - 0.5) * 180
    band = lat.abs() < 60
    diff = (direct.rgb - cube.rgb).abs().mean(0)
    assert diff[band].mean() < 0.02
    assert (direct.depth - cube.depth).abs()[band].mean() < 0.1
    assert diff.mean() < 0.03


def test_seam_is_continuous_and_rotation_equivariant():
    # One Gaussian straight behind the camera (u = 0 = W) straddles the seam.
    g = Gaussians.from_rgb(
        torch.tensor([[0.0, 0.1, -2.0]], dtype=F64),
        torch.tensor([[0.3, 0.2, 0.1]], dtype=F64),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64),
        torch.tensor([0.9], dtype=F64),
        torch.tensor([[1.0, 0.5, 0.2]], dtype=F64),
    )
    h, w = 32, 64
    out = render_equirect(g, torch.eye(4, dtype=F64), h, w)
    assert out.alpha[:, 0].max() > 0.5  # it is really on the seam
    lrce = (out.rgb[..., 0] - out.rgb[..., -1]).abs().mean()
    assert lrce < 1e-3
    # Turning the camera by 180 degrees moves the Gaussian to the centre: the image is the rolled one.
    turned = render_equirect(g, yaw_pose(math.pi), h, w)
    torch.testing.assert_close(turned.rgb, torch.roll(out.rgb, w // 2, dims=-1), atol=1e-9, rtol=0)


def test_single_opaque_gaussian_depth_is_its_distance():
    g = Gaussians.from_rgb(
        torch.tensor([[0.0, 0.0, 3.0]]), torch.full((1, 3), 0.5), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1),
        torch.ones(1, 3)
    )
    out = render_equirect(g, torch.eye(4), 16, 32)
    centre = (slice(7, 9), slice(15, 17))
    assert (out.alpha[centre] > 0.5).all()
    assert out.alpha.max() <= 0.99 + 1e-6  # the 3DGS alpha cap
    torch.testing.assert_close(out.depth[centre] / out.alpha[centre], torch.full((2, 2), 3.0), atol=1e-5, rtol=0)


def test_batched_rendering_matches_per_item_rendering():
    a, b = shell_scene(20, seed=4, dtype=torch.float32), shell_scene(20, seed=5, dtype=torch.float32)
    batched = Gaussians(**{k: torch.stack((getattr(a, k), getattr(b, k))) for k in a.tensors()})
    poses = torch.stack([torch.stack((yaw_pose(0.1 * i, dtype=torch.float32),
                                      yaw_pose(-0.4, (0.2, 0, 0), dtype=torch.float32))) for i in range(2)])
    out = render_equirect(batched, poses, 8, 16)
    assert out.rgb.shape == (2, 2, 3, 8, 16) and out.depth.shape == (2, 2, 8, 16)
    for i, g in enumerate((a, b)):
        single = render_equirect(g, poses[i], 8, 16)
        torch.testing.assert_close(out.rgb[i], single.rgb)


@pytest.mark.parametrize("name,g", list(degenerate_scenes()), ids=[n for n, _ in degenerate_scenes()])
def test_degenerate_inputs_give_finite_outputs_and_gradients(name, g):
    params = [t.clone().requires_grad_() for t in g.tensors().values()]
    out = render_equirect(Gaussians(*params), torch.eye(4), 16, 32, background=(0.5, 0.5, 0.5))
    for t in (out.rgb, out.depth, out.alpha):
        assert torch.isfinite(t).all(), name
    loss = out.rgb.sum() + out.depth.sum() + out.alpha.sum()
    if loss.requires_grad:
        grads = torch.autograd.grad(loss, params, allow_unused=True)
        for grad in grads:
            assert grad is None or torch.isfinite(grad).all(), name


def test_bad_inputs_raise_clear_errors():
    g = shell_scene(3, dtype=torch.float32)
    with pytest.raises(ValueError, match="width == 2 \\* height"):
        render_equirect(g, torch.eye(4), 16, 16)
    pose = torch.eye(4)
    pose[0, 3] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        render_equirect(g, pose, 8, 16)
    with pytest.raises(ValueError, match="c2w"):
        render_equirect(g, torch.eye(4)[None, None], 8, 16)
    bad = Gaussians(g.means.clone(), g.scales, g.rotations, g.opacities, g.sh)
    bad.means[0, 0] = float("nan")
    with pytest.raises(ValueError, match="means"):
        render_equirect(bad, torch.eye(4), 8, 16)
    with pytest.raises(ValueError, match="backend"):
        render_equirect(g, torch.eye(4), 8, 16, backend="nope")


def test_tile_binning_wraps_around_the_seam():
    g = Gaussians.from_rgb(
        torch.tensor([[0.0, 0.0, -2.0]]), torch.full((1, 3), 0.2), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1),
        torch.ones(1, 3)
    )
    proj = Equirect(32, 64).project(g, torch.eye(4), RasterSettings())
    bins = bin_to_tiles(proj, tile_size=8)
    tiles_x = bins.tile % bins.tiles_x
    assert {0, bins.tiles_x - 1} <= set(tiles_x.tolist())  # both sides of the seam
    assert not ({3, 4} & set(tiles_x.tolist()))  # nothing in the middle of the panorama
    key = bins.tile.double() * 1e6 + proj.depth[bins.gaussian].double()
    assert (key[1:] >= key[:-1]).all()  # sorted by (tile, depth)


def test_pinhole_renderer_centres_a_gaussian_on_its_axis():
    g = Gaussians.from_rgb(
        torch.tensor([[0.0, 0.0, 2.0]]), torch.full((1, 3), 0.05), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1),
        torch.ones(1, 3)
    )
    k = torch.tensor([[16.0, 0, 16.0], [0, 16.0, 16.0], [0, 0, 1.0]])
    out = render_pinhole(g, torch.eye(4), k, 32, 32)
    a = out.alpha
    jj, ii = torch.meshgrid(torch.arange(32) + 0.5, torch.arange(32) + 0.5, indexing="xy")
    assert float((a * jj).sum() / a.sum()) == pytest.approx(16.0, abs=1e-4)
    assert float((a * ii).sum() / a.sum()) == pytest.approx(16.0, abs=1e-4)


def test_auto_backend_fallback_rules(monkeypatch):
    """``backend="auto"``: a fast backend that fails to run is replaced by the reference (once, with a
    warning); one that cannot honour the settings is bypassed for that call only; out of memory is raised."""
    from cylindersplat.render import api
    from cylindersplat.render.projection import UnsupportedSettings

    g = shell_scene(10, seed=2, dtype=torch.float32)
    ref = render_equirect(g, torch.eye(4), 8, 16, backend="torch")
    calls = []

    def fast(error):
        def backend(*args):
            calls.append(error)
            raise error
        return backend

    def run_with(backend_fn):
        monkeypatch.setattr(api, "_pick_backend", lambda name, device: backend_fn)
        return render_equirect(g, torch.eye(4), 8, 16, backend="auto")

    monkeypatch.setattr(api, "_AUTO_DISABLED", set())
    unsupported = fast(UnsupportedSettings("tile size"))
    torch.testing.assert_close(run_with(unsupported).rgb, ref.rgb)
    assert unsupported not in api._AUTO_DISABLED  # still used for other settings

    broken = fast(RuntimeError("no compiler"))
    with pytest.warns(RuntimeWarning, match="no compiler"):
        torch.testing.assert_close(run_with(broken).rgb, ref.rgb)
    assert broken in api._AUTO_DISABLED

    with pytest.raises(torch.OutOfMemoryError):
        run_with(fast(torch.OutOfMemoryError("out of memory")))
    # Asking for a backend by name shows its errors instead of falling back.
    monkeypatch.setattr(api, "_pick_backend", lambda name, device: broken)
    with pytest.raises(RuntimeError, match="no compiler"):
        render_equirect(g, torch.eye(4), 8, 16, backend="triton")
    assert len(calls) == 4


def test_a_backends_own_projection_is_used_and_replaced_where_it_cannot_run(monkeypatch):
    """A backend's projection (``register_backend(..., projection=)``): used when it can; one that
    declines (UnsupportedSettings) leaves the call to the reference projection, named or under "auto";
    one that fails under "auto" disables the backend with a warning."""
    from cylindersplat.render import api
    from cylindersplat.render.projection import UnsupportedSettings, project_dense

    g = shell_scene(10, seed=2, dtype=torch.float32)
    ref = render_equirect(g, torch.eye(4), 8, 16, backend="torch")
    calls = []

    def fast(proj, settings, background):
        return rasterize(proj, settings, background)

    def projection_that(outcome):
        def dense(*args):
            calls.append(outcome)
            if outcome == "works":
                return project_dense(*args)
            raise UnsupportedSettings("no pixel map") if outcome == "declines" else RuntimeError("no compiler")
        return dense

    monkeypatch.setattr(api, "_pick_backend", lambda name, device: fast)
    monkeypatch.setattr(api, "_AUTO_DISABLED", set())
    for outcome, backend in (("works", "fast"), ("declines", "fast"), ("declines", "auto")):
        monkeypatch.setitem(api._PROJECTIONS, fast, projection_that(outcome))
        torch.testing.assert_close(render_equirect(g, torch.eye(4), 8, 16, backend=backend).rgb, ref.rgb)
    monkeypatch.setitem(api._PROJECTIONS, fast, projection_that("fails"))
    with pytest.raises(RuntimeError, match="no compiler"):
        render_equirect(g, torch.eye(4), 8, 16, backend="fast")
    with pytest.warns(RuntimeWarning, match="no compiler"):
        torch.testing.assert_close(render_equirect(g, torch.eye(4), 8, 16, backend="auto").rgb, ref.rgb)
    assert fast in api._AUTO_DISABLED
    assert calls == ["works", "declines", "declines", "fails", "fails"]
