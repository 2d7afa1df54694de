"""The numba CPU backend against the PyTorch reference (and the brute-force compositor): outputs and
gradients, equirect and pinhole, seam and poles, tiles, degenerate input, batches, and ``"auto"``'s choice."""

import math

import pytest
import torch

pytest.importorskip("numba")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Pinhole, render, render_equirect  # noqa: E402
from cylindersplat.render.cameras import Equirect  # noqa: E402
from cylindersplat.render.projection import RasterSettings  # noqa: E402
from render_scenes import degenerate_scenes, shell_scene, yaw_pose  # noqa: E402

F32, F64 = torch.float32, torch.float64


def _both(g, poses, camera, background=(0.2, 0.3, 0.4), settings=None):
    """Render with both backends; return outputs and gradients (every Gaussian parameter) of a fixed random loss."""
    results = []
    for backend in ("torch", "numba"):
        params = {k: v.detach().clone().requires_grad_() for k, v in g.tensors().items()}
        out = render(Gaussians(**params), poses, camera, background=background, backend=backend, settings=settings)
        gen = torch.Generator().manual_seed(5)
        outputs = (out.rgb, out.depth, out.alpha)
        loss = sum((torch.randn(t.shape, generator=gen, dtype=t.dtype) * t).sum() for t in outputs)
        grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
        results.append((out, dict(zip(params, grads))))
    return results


def _assert_match(ref, fast, atol=2e-4, grad_rtol=2e-3):
    """The Triton backend's tolerances (tests/test_render_triton.py)."""
    (out_ref, grad_ref), (out_fast, grad_fast) = ref, fast
    for name in ("rgb", "depth", "alpha"):
        torch.testing.assert_close(getattr(out_fast, name), getattr(out_ref, name), atol=atol, rtol=1e-4, msg=name)
    for name, g_ref in grad_ref.items():
        g_fast = grad_fast[name]
        assert torch.isfinite(g_fast).all(), name
        scale = g_ref.abs().max().clamp_min(1e-6)
        assert (g_fast - g_ref).abs().max() <= grad_rtol * scale + 1e-6, (name, (g_fast - g_ref).abs().max(), scale)


def _pinhole(h, w, fov_deg=90.0, dtype=F32):
    f = 0.5 * w / math.tan(math.radians(fov_deg) / 2)
    return Pinhole(torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], dtype=dtype), h, w)


def test_auto_picks_numba_on_the_cpu():
    from cylindersplat.render import api
    from cylindersplat.render.numba_backend import numba_backend

    assert api._pick_backend("auto", torch.device("cpu")) is numba_backend
    assert api._pick_backend("numba", torch.device("cpu")) is numba_backend


def test_random_scene_matches_reference_with_every_gradient():
    g = shell_scene(60, seed=1, sh_degree=1, dtype=F32)
    poses = torch.stack([yaw_pose(0.0, dtype=F32), yaw_pose(1.0, (0.2, 0.1, -0.3), dtype=F32)])
    ref, fast = _both(g, poses, Equirect(16, 32))
    _assert_match(ref, fast)
    assert all(grad.abs().max() > 0 for grad in fast[1].values())  # every parameter really gets a gradient


def test_float64_matches_reference_to_rounding():
    g = shell_scene(40, seed=2, sh_degree=1)
    (out_ref, grad_ref), (out_fast, grad_fast) = _both(g, yaw_pose(0.4)[None], Equirect(16, 32))
    for name in ("rgb", "depth", "alpha"):
        torch.testing.assert_close(getattr(out_fast, name), getattr(out_ref, name), atol=1e-10, rtol=1e-10)
    for name, ref in grad_ref.items():
        torch.testing.assert_close(grad_fast[name], ref, atol=1e-9, rtol=1e-7, msg=name)


@pytest.mark.slow  # 86 s at load 13 (2 shared cores)
def test_gradients_match_finite_differences():
    g = shell_scene(4, seed=1, scale=(0.15, 0.35), radius=(1.0, 2.0), sh_degree=1)
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=F64)

    def fn(means, scales, rotations, opacities, sh):
        out = render_equirect(Gaussians(means, scales, rotations, opacities, sh), yaw_pose(0.3), 8, 16, background=bg,
                              backend="numba")
        return out.rgb, out.depth, out.alpha

    inputs = [t.clone().requires_grad_() for t in g.tensors().values()]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_pinhole_matches_reference():
    g = shell_scene(80, seed=4, sh_degree=1, dtype=F32)
    poses = torch.stack([yaw_pose(math.pi, dtype=F32), yaw_pose(2.5, (0.1, 0.0, 0.2), dtype=F32)])
    ref, fast = _both(g, poses, _pinhole(24, 32))
    _assert_match(ref, fast)
    assert fast[0].alpha.max() > 0.5


def test_seam_and_pole_scenes_match_reference():
    gen = torch.Generator().manual_seed(2)
    n = 30
    # Behind the camera (-z) the longitude seam u = 0 = W runs through every footprint.
    seam = torch.stack((0.3 * torch.randn(n, generator=gen), 0.5 * torch.randn(n, generator=gen),
                        -1.5 - torch.rand(n, generator=gen)), -1)
    # Near the poles (+-y): wide, strongly distorted footprints.
    pole = torch.stack((0.2 * torch.randn(n, generator=gen),
                        torch.sign(torch.randn(n, generator=gen)) * (1.5 + torch.rand(n, generator=gen)),
                        0.2 * torch.randn(n, generator=gen)), -1)
    g = Gaussians.from_rgb(torch.cat((seam, pole)), 0.05 + 0.2 * torch.rand(2 * n, 3, generator=gen),
                           torch.randn(2 * n, 4, generator=gen), 0.3 + 0.6 * torch.rand(2 * n, generator=gen),
                           torch.rand(2 * n, 3, generator=gen))
    _assert_match(*_both(g, yaw_pose(0.0, dtype=F32)[None], Equirect(16, 32)))


def test_seam_is_continuous_and_rotation_equivariant():
    g = Gaussians.from_rgb(torch.tensor([[0.0, 0.1, -2.0]]), torch.tensor([[0.3, 0.2, 0.1]]),
                           torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.tensor([0.9]), torch.tensor([[1.0, 0.5, 0.2]]))
    h, w = 16, 32
    out = render_equirect(g, torch.eye(4), h, w, backend="numba")
    assert out.alpha[:, 0].max() > 0.5  # it really is on the seam
    assert (out.rgb[..., 0] - out.rgb[..., -1]).abs().mean() < 1e-3
    turned = render_equirect(g, yaw_pose(math.pi, dtype=F32), h, w, backend="numba")
    torch.testing.assert_close(turned.rgb, torch.roll(out.rgb, w // 2, dims=-1), atol=1e-5, rtol=0)


@pytest.mark.parametrize("tile", [4, 7, 32])
def test_other_tiles_and_opaque_stacks_match_reference(tile):
    # Many opaque layers: the transmittance termination rule and the per-tile early exit.
    g = shell_scene(100, seed=3, scale=(0.3, 0.6), dtype=F32)
    g = Gaussians(g.means, g.scales, g.rotations, torch.full_like(g.opacities, 0.95), g.sh)
    _assert_match(*_both(g, yaw_pose(0.3, dtype=F32)[None], Equirect(16, 32), settings=RasterSettings(tile_size=tile)))


@pytest.mark.parametrize("opacity,count", [(0.02, 300), (0.3, 200)], ids=["300 faint layers", "200 opaque layers"])
def test_deep_stacks_keep_gradients_accurate(opacity, count):
    gen = torch.Generator().manual_seed(7)
    depth = torch.linspace(1.0, 4.0, count)
    dirs = torch.nn.functional.normalize(torch.tensor([0.05, 0.02, 1.0]) + 0.01 * torch.randn(count, 3, generator=gen),
                                         dim=-1)
    g = Gaussians.from_rgb(dirs * depth[:, None], torch.tensor([0.6, 0.3, 0.45]) * depth[:, None],
                           torch.randn(count, 4, generator=gen), torch.full((count,), opacity),
                           torch.rand(count, 3, generator=gen))
    (out_ref, grad_ref), (out_fast, grad_fast) = _both(g, yaw_pose(0.0, dtype=F32)[None], Equirect(8, 16))
    torch.testing.assert_close(out_fast.rgb, out_ref.rgb, atol=2e-4, rtol=1e-4)
    for name, ref in grad_ref.items():
        fast = grad_fast[name]
        err = (fast - ref).abs().flatten(1).amax(1) if ref.ndim > 1 else (fast - ref).abs()
        size = ref.abs().flatten(1).amax(1) if ref.ndim > 1 else ref.abs()
        big = size > 1e-3 * size.max()
        assert (err[big] / size[big]).max() < 2e-3, (name, (err[big] / size[big]).max())


@pytest.mark.filterwarnings("ignore:none of the")
@pytest.mark.parametrize("name,g", list(degenerate_scenes()), ids=[n for n, _ in degenerate_scenes()])
def test_degenerate_inputs_stay_finite(name, g):
    params = [t.clone().requires_grad_() for t in g.tensors().values()]
    out = render_equirect(Gaussians(*params), torch.eye(4), 16, 32, background=(0.5, 0.5, 0.5), backend="numba")
    ref = render_equirect(g, torch.eye(4), 16, 32, background=(0.5, 0.5, 0.5), backend="torch")
    torch.testing.assert_close(out.rgb, ref.rgb, atol=2e-4, rtol=1e-4)
    loss = out.rgb.sum() + out.depth.sum() + out.alpha.sum()
    if loss.requires_grad:
        for grad in torch.autograd.grad(loss, params, allow_unused=True):
            assert grad is None or torch.isfinite(grad).all(), name


@pytest.mark.filterwarnings("ignore:none of the")
def test_empty_scene_is_background_with_zero_gradients():
    g = shell_scene(3, seed=0, dtype=F32)
    far = Gaussians(g.means + 100.0, g.scales, g.rotations, torch.zeros_like(g.opacities), g.sh)  # all culled
    params = [t.clone().requires_grad_() for t in far.tensors().values()]
    out = render_equirect(Gaussians(*params), torch.eye(4), 8, 16, background=(0.1, 0.2, 0.3), backend="numba")
    torch.testing.assert_close(out.rgb, torch.tensor([0.1, 0.2, 0.3]).view(3, 1, 1).expand(3, 8, 16))
    assert out.alpha.abs().max() == 0
    grads = torch.autograd.grad(out.rgb.sum(), params, allow_unused=True)
    assert all(grad is None or grad.abs().max() == 0 for grad in grads)


def test_compositing_matches_brute_force():
    from cylindersplat.render.brute_force import composite_brute_force
    from cylindersplat.render.numba_backend import bin_pairs_numba, composite_numba

    g = shell_scene(40, sh_degree=3)
    c2w = torch.stack((yaw_pose(0.0), yaw_pose(0.7, (0.3, -0.1, 0.2))))
    settings = RasterSettings()
    proj = Equirect(16, 32).project(g, c2w, settings)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=F64)
    brute = composite_brute_force(proj, settings, bg)
    fast = composite_numba(proj, bin_pairs_numba(proj, settings.tile_size), settings, bg)
    for a, b in zip(fast, brute):
        assert (a - b).abs().max() <= 1e-10
    assert brute[2].max() > 0.9  # the scene actually covers pixels


def test_pairs_are_the_references_in_the_same_order():
    from cylindersplat.render.numba_backend import bin_pairs_numba
    from cylindersplat.render.rasterize import bin_to_tiles

    g = shell_scene(50, seed=8, scale=(0.05, 0.6), dtype=F32)
    c2w = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(2.0, (0.2, 0.0, 0.1), dtype=F32)))
    proj = Equirect(16, 32).project(g, c2w, RasterSettings())
    ref = bin_to_tiles(proj, 8)
    fast = bin_pairs_numba(proj, 8)
    assert torch.equal(torch.from_numpy(fast.pairs >> 1), ref.gaussian)
    counts = torch.bincount(ref.tile, minlength=len(fast.tile_start) - 1)
    assert torch.equal(torch.from_numpy(fast.tile_start[1:] - fast.tile_start[:-1]), counts)


def test_a_slow_first_call_says_numba_is_compiling_once(monkeypatch):
    """A stage's first call that outlasts COMPILE_NOTICE_AFTER_S gets one Notice while it runs; a quick first call,
    a later call and another slow stage in the same process get none."""
    import time
    import warnings

    from cylindersplat.render import numba_backend
    from cylindersplat.utils import notices

    monkeypatch.setattr(numba_backend, "COMPILE_NOTICE_AFTER_S", 0.05)
    monkeypatch.setattr(numba_backend, "_CALLED_STAGES", set())
    monkeypatch.setattr(notices, "_said", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with numba_backend.compile_notice("quick"):
            pass
        time.sleep(0.2)
        assert caught == []  # the quick call's timer was cancelled
        with numba_backend.compile_notice("slow"):
            time.sleep(0.5)
            assert [str(w.message) for w in caught] == [numba_backend.COMPILE_NOTICE]  # said while it waits
        with numba_backend.compile_notice("slow"), numba_backend.compile_notice("other slow stage"):
            time.sleep(0.3)
    assert len(caught) == 1 and issubclass(caught[0].category, notices.Notice)
    assert caught[0].filename.endswith("numba_backend.py")  # not threading.py


def test_every_kernel_stage_is_watched_for_compilation(monkeypatch):
    """A forward and backward on the CPU pass through the notice's watch at each stage that compiles."""
    from cylindersplat.render import numba_backend

    monkeypatch.setattr(numba_backend, "_CALLED_STAGES", set())
    g = shell_scene(20, seed=3, dtype=F32)
    for t in g.tensors().values():
        t.requires_grad_()
    out = render_equirect(g, yaw_pose(0.0, dtype=F32), 16, 32, backend="numba")
    (out.rgb.sum() + out.depth.sum()).backward()
    assert numba_backend._CALLED_STAGES == {"project", "bin", "composite", "composite backward", "project backward"}


@pytest.mark.parametrize("num", [0, 1, 7, 5000])
def test_depth_order_is_a_stable_sort_of_the_depths(num):
    """The radix sort against numpy's stable argsort: ties by row (repeated depths), and for signed zeros, negatives
    and infinities the order of their bit patterns as int32 (what sorting the 64-bit keys gave before)."""
    import numpy as np

    from cylindersplat.render.numba_backend import _depth_order

    rng = np.random.default_rng(num)
    depth = rng.uniform(0.1, 30.0, num).astype(np.float32)
    depth[::3] = depth[:1]  # many ties
    order = _depth_order(depth)
    assert order.dtype == np.int64
    np.testing.assert_array_equal(order, np.argsort(depth, kind="stable"))
    if num > 5:
        depth[1:6] = [-2.0, -0.0, 0.0, np.inf, 3e-39]  # a negative, signed zeros, infinity, a subnormal
        keys = (depth.view(np.int32).astype(np.int64) << 32) | np.arange(num, dtype=np.int64)
        np.testing.assert_array_equal(_depth_order(depth), np.sort(keys) & 0xFFFFFFFF)


def test_batched_rendering_matches_per_item_rendering():
    a, b = shell_scene(20, seed=4, dtype=F32), shell_scene(20, seed=5, dtype=F32)
    batched = Gaussians(**{k: torch.stack((getattr(a, k), getattr(b, k))) for k in a.tensors()})
    poses = torch.stack([torch.stack((yaw_pose(0.1 * i, dtype=F32), yaw_pose(-0.4, (0.2, 0, 0), dtype=F32)))
                         for i in range(2)])
    out = render_equirect(batched, poses, 8, 16, backend="numba")
    assert out.rgb.shape == (2, 2, 3, 8, 16)
    for i, g in enumerate((a, b)):
        single = render_equirect(g, poses[i], 8, 16, backend="numba")
        torch.testing.assert_close(out.rgb[i], single.rgb, atol=1e-6, rtol=0)
        ref = render_equirect(g, poses[i], 8, 16, backend="torch")
        torch.testing.assert_close(out.rgb[i], ref.rgb, atol=2e-4, rtol=1e-4)


def test_auto_falls_back_to_the_reference_with_one_warning_when_numba_fails(monkeypatch):
    from cylindersplat.render import api, numba_backend

    def no_compiler():
        raise RuntimeError("numba could not compile: no LLVM")

    g = shell_scene(10, seed=2, dtype=F32)
    ref = render_equirect(g, torch.eye(4), 8, 16, backend="torch")
    monkeypatch.setattr(api, "_AUTO_DISABLED", set())
    monkeypatch.setattr(numba_backend, "_kernels", no_compiler)
    with pytest.warns(RuntimeWarning, match="'numba' failed .*no LLVM.*PyTorch reference") as caught:
        torch.testing.assert_close(render_equirect(g, torch.eye(4), 8, 16).rgb, ref.rgb)
        torch.testing.assert_close(render_equirect(g, torch.eye(4), 8, 16).rgb, ref.rgb)
    assert len([w for w in caught if "numba" in str(w.message)]) == 1
    with pytest.raises(RuntimeError, match="no LLVM"):  # asked for by name: its error
        render_equirect(g, torch.eye(4), 8, 16, backend="numba")


def test_without_numba_auto_uses_the_reference_with_one_warning_and_the_name_is_refused(monkeypatch):
    from cylindersplat.errors import InputError
    from cylindersplat.render import api

    monkeypatch.delitem(api._BACKENDS, "numba")
    monkeypatch.setattr(api, "_WARNED_NO_NUMBA", [False])
    g = shell_scene(10, seed=2, dtype=F32)
    with pytest.warns(RuntimeWarning, match="numba is not installed.*pip install numba") as caught:
        render_equirect(g, torch.eye(4), 8, 16)
        render_equirect(g, torch.eye(4), 8, 16)
    assert len(caught) == 1
    with pytest.raises(InputError, match="needs the numba package: pip install numba"):
        render_equirect(g, torch.eye(4), 8, 16, backend="numba")


def test_memory_refusal_names_the_pairs(monkeypatch):
    from cylindersplat.render import rasterize

    monkeypatch.setattr(rasterize, "available_memory", lambda device: 1000)
    with pytest.raises(rasterize.RenderMemoryError, match="GiB for [\\d,]+ tile pairs"):
        render_equirect(shell_scene(10, seed=2, dtype=F32), torch.eye(4), 8, 16, backend="numba")


@pytest.mark.parametrize("backend", ["torch", "numba"])
def test_zero_area_footprints_draw_nothing_without_dilation(backend):
    """Zero scales with ``dilation=0`` (a pixel Gaussian at a hole of the depth prior, issue 34) are culled: the
    render equals the render without them (before, numba's projection divided by zero inside its parallel loop and
    marked them visible, spoiling whole tiles; the reference painted a tile with conic 0)."""
    from cylindersplat.gaussians import Gaussians
    from cylindersplat.render import Equirect, RasterSettings, render

    torch.manual_seed(0)
    n = 200
    means = torch.randn(n, 3) * 0.3 + torch.tensor([0.0, 0.0, 2.0])
    scales = torch.full((n, 3), 0.02)
    scales[:4] = 0.0
    g = Gaussians.from_rgb(means, scales, torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4), torch.ones(n), torch.rand(n, 3))
    settings = RasterSettings(dilation=0.0)
    out = render(g, torch.eye(4), Equirect(32, 64), settings=settings, backend=backend)
    reference = render(g[4:], torch.eye(4), Equirect(32, 64), settings=settings, backend="torch")
    assert torch.allclose(out.rgb, reference.rgb, atol=1e-5) and torch.allclose(out.alpha, reference.alpha, atol=1e-5)
