"""The Triton backend against the PyTorch reference: outputs and gradients, seam, poles, degenerate input.

On a machine without a GPU the kernels run in Triton's interpreter (``TRITON_INTERPRET=1``, set
here before the kernels are first imported); with CUDA they are compiled and run on the GPU.
"""


import contextlib

import pytest
import torch

pytest.importorskip("triton")  # the test extra installs it; conftest.py selects the interpreter without CUDA

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import render_equirect  # noqa: E402
from cylindersplat.render.projection import RasterSettings  # noqa: E402
from render_scenes import degenerate_scenes, shell_scene, yaw_pose  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F32 = torch.float32


def _both(g, poses, h, w, background=(0.2, 0.3, 0.4), settings=None, outputs=("rgb", "depth", "alpha")):
    """Render with both backends; return outputs and gradients of a fixed random loss on ``outputs``."""
    results = []
    for backend in ("torch", "triton"):
        params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
        out = render_equirect(Gaussians(**params), poses.to(DEVICE), h, w, background=background, backend=backend,
                              settings=settings)
        gen = torch.Generator().manual_seed(5)
        weights = [torch.randn(t.shape, generator=gen).to(DEVICE) for t in (out.rgb, out.depth, out.alpha)]
        loss = sum((wt * getattr(out, name)).sum() for wt, name in zip(weights, ("rgb", "depth", "alpha"))
                   if name in outputs)
        grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
        results.append((out, dict(zip(params, grads))))
    return results


def _assert_match(ref, fast, atol=2e-4, grad_rtol=2e-3):
    (out_ref, grad_ref), (out_fast, grad_fast) = ref, fast
    for name in ("rgb", "depth", "alpha"):
        torch.testing.assert_close(getattr(out_fast, name), getattr(out_ref, name), atol=atol, rtol=1e-4, msg=name)
    for name, g_ref in grad_ref.items():
        g_fast = grad_fast[name]
        assert torch.isfinite(g_fast).all(), name
        scale = g_ref.abs().max().clamp_min(1e-6)
        assert (g_fast - g_ref).abs().max() <= grad_rtol * scale + 1e-6, (name, (g_fast - g_ref).abs().max(), scale)


@pytest.mark.parametrize("outputs", [("rgb",), ("depth",), ("alpha",), ("rgb", "alpha")])
def test_a_loss_on_some_outputs_gets_the_references_gradients(outputs):
    # The outputs without a gradient reach the backward as None (read as zero, not made): each on its own.
    g = shell_scene(30, seed=41, dtype=F32)
    poses = torch.stack([yaw_pose(0.0, dtype=F32), yaw_pose(1.5, (0.1, 0.0, 0.2), dtype=F32)])
    _assert_match(*_both(g, poses, 16, 32, background=None, outputs=outputs))


def test_outputs_are_planar_contiguous_tensors():
    g = shell_scene(10, seed=42, dtype=F32).to(DEVICE)
    out = render_equirect(g, torch.eye(4, device=DEVICE), 8, 16, backend="triton")
    assert out.rgb.shape == (3, 8, 16) and out.rgb.is_contiguous() and out.depth.is_contiguous()
    assert out.alpha.is_contiguous()


def test_auto_picks_triton_on_cuda_and_not_on_the_cpu():
    from cylindersplat.render import api
    from cylindersplat.render.triton_backend import triton_backend

    assert api._pick_backend("auto", torch.device("cuda")) is triton_backend
    assert api._pick_backend("auto", torch.device("cpu")) is not triton_backend  # numba's, or the reference


@pytest.mark.slow
def test_random_scene_matches_reference():
    g = shell_scene(80, seed=1, dtype=F32)
    poses = torch.stack([yaw_pose(0.0, dtype=F32), yaw_pose(1.0, (0.2, 0.1, -0.3), dtype=F32)])
    _assert_match(*_both(g, poses, 32, 64))


@pytest.mark.slow
def test_seam_and_pole_scenes_match_reference():
    gen = torch.Generator().manual_seed(2)
    n = 40
    # Behind the camera (-z) the longitude seam u = 0 = W runs through every footprint.
    seam = torch.stack((0.3 * torch.randn(n, generator=gen), 0.5 * torch.randn(n, generator=gen),
                        -1.5 - torch.rand(n, generator=gen)), -1)
    # Near the poles (+-y): wide, strongly distorted footprints.
    pole = torch.stack((0.2 * torch.randn(n, generator=gen),
                        torch.sign(torch.randn(n, generator=gen)) * (1.5 + torch.rand(n, generator=gen)),
                        0.2 * torch.randn(n, generator=gen)), -1)
    means = torch.cat((seam, pole))
    g = Gaussians.from_rgb(means, 0.05 + 0.2 * torch.rand(2 * n, 3, generator=gen),
                           torch.randn(2 * n, 4, generator=gen),
                           0.3 + 0.6 * torch.rand(2 * n, generator=gen), torch.rand(2 * n, 3, generator=gen))
    _assert_match(*_both(g, yaw_pose(0.0, dtype=F32)[None], 32, 64))


@pytest.mark.slow
def test_smaller_tiles_and_opaque_stacks_match_reference():
    # Many opaque layers: exercises the transmittance termination rule and per-tile early exit.
    g = shell_scene(120, seed=3, scale=(0.3, 0.6), dtype=F32)
    g = Gaussians(g.means, g.scales, g.rotations, torch.full_like(g.opacities, 0.95), g.sh)
    _assert_match(*_both(g, yaw_pose(0.3, dtype=F32)[None], 16, 32, settings=RasterSettings(tile_size=8)))



def test_footprints_that_meet_a_tile_twice_match_reference():
    # Close, wide footprints across the seam (some meet a tile twice: two lanes of one vector atomic on the same
    # Gaussian), two cameras.
    from cylindersplat.render import Equirect
    from cylindersplat.render.rasterize import bin_to_tiles

    g = shell_scene(12, seed=32, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    poses = torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)])
    settings = RasterSettings(tile_size=8)
    bins = bin_to_tiles(Equirect(16, 32).project(g, poses, settings), 8)
    assert len((bins.gaussian * 10_000 + bins.tile).unique()) < len(bins.tile)
    _assert_match(*_both(g, poses, 16, 32, settings=settings))


def test_unknown_input_check_variant_is_refused_by_name(monkeypatch):
    # (the forward's and the compaction's: test_render_triton_lean.py, test_render_deferred_checks.py)
    from cylindersplat.render import triton_backend

    monkeypatch.setattr(triton_backend, "CHECK", "numpy")
    g = shell_scene(10, seed=9, dtype=F32).to(DEVICE)
    with pytest.raises(ValueError, match="unknown Triton input check 'numpy': choose one of fused, torch"):
        render_equirect(g, torch.eye(4, device=DEVICE), 8, 16, backend="triton")


@pytest.mark.parametrize("name,g", list(degenerate_scenes()), ids=[n for n, _ in degenerate_scenes()])
def test_degenerate_inputs_stay_finite(name, g):
    params = [t.clone().to(DEVICE).requires_grad_() for t in g.tensors().values()]
    out = render_equirect(Gaussians(*params), torch.eye(4, device=DEVICE), 16, 32, background=(0.5, 0.5, 0.5),
                          backend="triton")
    ref = render_equirect(g.to(DEVICE), torch.eye(4, device=DEVICE), 16, 32, background=(0.5, 0.5, 0.5),
                          backend="torch")
    torch.testing.assert_close(out.rgb, ref.rgb, atol=2e-4, rtol=1e-4)
    loss = out.rgb.sum() + out.depth.sum() + out.alpha.sum()
    if loss.requires_grad:
        for grad in torch.autograd.grad(loss, params, allow_unused=True):
            assert grad is None or torch.isfinite(grad).all(), name


# The reference backend's own checks against independent references, run on the Triton backend.


def test_triton_compositing_matches_brute_force():
    from cylindersplat.render import Equirect
    from cylindersplat.render.brute_force import composite_brute_force
    from cylindersplat.render.rasterize import bin_to_tiles
    from cylindersplat.render.triton_backend import composite_triton

    g = shell_scene(40, sh_degree=3, dtype=F32)
    c2w = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(0.7, (0.3, -0.1, 0.2), dtype=F32)))
    settings = RasterSettings()
    proj = Equirect(16, 32).project(g, c2w, settings)
    bg = torch.tensor([0.1, 0.2, 0.3])
    brute = composite_brute_force(proj, settings, bg)
    proj_dev = Equirect(16, 32).project(g.to(DEVICE), c2w.to(DEVICE), settings)
    fast = composite_triton(proj_dev, bin_to_tiles(proj_dev, settings.tile_size), settings, bg.to(DEVICE))
    for a, b in zip(fast, brute):
        assert (a.cpu() - b).abs().max() <= 2e-5
    assert brute[2].max() > 0.9  # the scene actually covers pixels


def test_triton_result_does_not_depend_on_tile_size():
    g = shell_scene(40, seed=3, dtype=F32).to(DEVICE)
    c2w = yaw_pose(0.2, dtype=F32).to(DEVICE)
    ref = render_equirect(g, c2w, 16, 32, settings=RasterSettings(tile_size=16), backend="triton")
    for tile in (4, 32):
        out = render_equirect(g, c2w, 16, 32, settings=RasterSettings(tile_size=tile), backend="triton")
        torch.testing.assert_close(out.rgb, ref.rgb, atol=1e-5, rtol=0)


def test_triton_seam_is_continuous_and_rotation_equivariant():
    import math

    g = Gaussians.from_rgb(torch.tensor([[0.0, 0.1, -2.0]]), torch.tensor([[0.3, 0.2, 0.1]]),
                           torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.tensor([0.9]), torch.tensor([[1.0, 0.5, 0.2]]))
    g = g.to(DEVICE)
    h, w = 16, 32
    out = render_equirect(g, torch.eye(4, device=DEVICE), h, w, backend="triton")
    assert out.alpha[:, 0].max() > 0.5  # it really is on the seam
    assert (out.rgb[..., 0] - out.rgb[..., -1]).abs().mean() < 1e-3
    turned = render_equirect(g, yaw_pose(math.pi, dtype=F32).to(DEVICE), h, w, backend="triton")
    torch.testing.assert_close(turned.rgb, torch.roll(out.rgb, w // 2, dims=-1), atol=1e-5, rtol=0)


def test_triton_batched_rendering_matches_per_item_rendering():
    a, b = shell_scene(20, seed=4, dtype=F32), shell_scene(20, seed=5, dtype=F32)
    batched = Gaussians(**{k: torch.stack((getattr(a, k), getattr(b, k))) for k in a.tensors()}).to(DEVICE)
    poses = torch.stack([torch.stack((yaw_pose(0.1 * i, dtype=F32), yaw_pose(-0.4, (0.2, 0, 0), dtype=F32)))
                         for i in range(2)]).to(DEVICE)
    out = render_equirect(batched, poses, 8, 16, backend="triton")
    assert out.rgb.shape == (2, 2, 3, 8, 16)
    for i, g in enumerate((a, b)):
        single = render_equirect(g.to(DEVICE), poses[i], 8, 16, backend="triton")
        torch.testing.assert_close(out.rgb[i], single.rgb, atol=1e-6, rtol=0)


def test_tile_size_the_kernels_cannot_use_is_refused_by_name():
    from cylindersplat.render.projection import UnsupportedSettings

    g = shell_scene(10, seed=6, dtype=F32).to(DEVICE)
    with pytest.raises(UnsupportedSettings, match="power-of-two"):
        render_equirect(g, torch.eye(4, device=DEVICE), 8, 16, settings=RasterSettings(tile_size=12), backend="triton")


@pytest.mark.slow
@pytest.mark.parametrize("opacity,count", [(0.02, 300), (0.3, 200)], ids=["300 faint layers", "200 opaque layers"])
def test_deep_stacks_keep_gradients_accurate(opacity, count):
    """Hundreds of Gaussians on every pixel's ray: the float32 Triton backward (prefix sums of the
    contributions) against the reference's float64 suffix sums."""
    gen = torch.Generator().manual_seed(7)
    depth = torch.linspace(1.0, 4.0, count)
    dirs = torch.nn.functional.normalize(torch.tensor([0.05, 0.02, 1.0]) + 0.01 * torch.randn(count, 3, generator=gen),
                                         dim=-1)
    g = Gaussians.from_rgb(dirs * depth[:, None], torch.tensor([0.6, 0.3, 0.45]) * depth[:, None],
                           torch.randn(count, 4, generator=gen), torch.full((count,), opacity),
                           torch.rand(count, 3, generator=gen))
    (out_ref, grad_ref), (out_fast, grad_fast) = _both(g, yaw_pose(0.0, dtype=F32)[None], 8, 16)
    torch.testing.assert_close(out_fast.rgb, out_ref.rgb, atol=2e-4, rtol=1e-4)
    for name, ref in grad_ref.items():
        fast = grad_fast[name]
        # per-Gaussian relative error, against each Gaussian's own gradient size (not the largest)
        err = (fast - ref).abs().flatten(1).amax(1) if ref.ndim > 1 else (fast - ref).abs()
        size = ref.abs().flatten(1).amax(1) if ref.ndim > 1 else ref.abs()
        big = size > 1e-3 * size.max()
        assert (err[big] / size[big]).max() < 2e-3, (name, (err[big] / size[big]).max())


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_empty_and_invisible_scenes_have_zero_gradients(forward, monkeypatch):
    """No pairs at all (no Gaussians, or none in front of the camera): the kernels walk empty tiles - the backward's
    first pair load is masked off - and every gradient is zero."""
    from cylindersplat.render import triton_backend

    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    scene = shell_scene(6, seed=4, dtype=F32)
    behind = Gaussians(**{**scene.tensors(), "means": scene.means * 1e-4})  # all closer than the near plane
    empty = Gaussians(**{k: v[:0] for k, v in scene.tensors().items()})
    for g, warns in ((empty, contextlib.nullcontext()), (behind, pytest.warns(RuntimeWarning, match="none of the 6"))):
        params = {k: v.to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
        with warns:
            out = render_equirect(Gaussians(**params), yaw_pose(0.0, dtype=F32).to(DEVICE), 8, 16,
                                  background=(0.2, 0.3, 0.4), backend="triton")
        assert torch.allclose(out.rgb, torch.tensor([0.2, 0.3, 0.4], device=DEVICE)[:, None, None].expand_as(out.rgb))
        (out.rgb.sum() + out.depth.sum() + out.alpha.sum()).backward()
        for name, t in params.items():
            assert t.grad is not None and not t.grad.any(), name
