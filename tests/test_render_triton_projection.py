"""The fused Triton projection (float32, analytic backward) against the PyTorch reference projection.

The reference is itself checked against an independent float64 construction
(``tests/test_render_projection.py``); here the kernel must give the same visible pairs, the same
footprints (float32 accuracy) and the same gradients of means, scales and quaternions as autograd
through the reference, at the seam, the poles (the clamped Jacobian and the std caps), the near
plane and for degenerate Gaussians. Without CUDA the kernels run in Triton's interpreter.
"""

import math

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.geometry.cubemap import cubemap_face_c2w  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, cubemap_face, render  # noqa: E402
from cylindersplat.render.projection import UnsupportedSettings, flatten_cameras, project_dense  # noqa: E402
from cylindersplat.render.triton_projection import project_dense_triton  # noqa: E402
from render_scenes import degenerate_scenes, shell_scene, yaw_pose  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F64 = torch.float64
SETTINGS = RasterSettings()


def _both(g: Gaussians, c2w, camera, settings=SETTINGS, seed=0):
    """Dense projection by the reference (float64) and the kernel: ``(geo, valid, grads)`` each, the
    gradients of a fixed random weighting of the visible pairs' ``geo``."""
    g, c2w, _ = flatten_cameras(g, c2w)
    results = []
    weights = None
    for dense in (project_dense, project_dense_triton):
        params = [t.detach().to(DEVICE, F64).clone().requires_grad_() for t in (g.means, g.scales, g.rotations)]
        geo, valid = dense(*params, g.opacities.to(DEVICE), c2w.to(DEVICE), camera, settings)
        if weights is None:
            gen = torch.Generator().manual_seed(seed)
            weights = torch.randn(geo.shape, generator=gen, dtype=F64).to(DEVICE) * valid[..., None]
        loss = (geo.to(F64) * weights).sum()
        results.append((geo.detach().to(F64).cpu(), valid.cpu(), [t.cpu() for t in torch.autograd.grad(loss, params)]))
    return results


def _assert_match(ref, fast, width=None, grad_rtol=1e-3):
    (geo_r, valid_r, grads_r), (geo_f, valid_f, grads_f) = ref, fast
    assert torch.equal(valid_r, valid_f)
    if not valid_r.any():
        return
    a, b = geo_r[valid_r], geo_f[valid_r]
    if width is not None:  # u modulo the panorama width
        du = torch.remainder(b[:, 0] - a[:, 0] + width / 2, width) - width / 2
        b = torch.cat(((a[:, 0] + du)[:, None], b[:, 1:]), -1)
    assert torch.isfinite(b).all()
    # pixel positions to 1e-3 px; the conic relative to its largest entry per pair; extents, depth relative
    assert (b[:, :2] - a[:, :2]).abs().max() < 1e-3, ("uv", (b[:, :2] - a[:, :2]).abs().max())
    conic_scale = torch.maximum(a[:, 2], a[:, 4])[:, None]
    conic_gap = ((b[:, 2:5] - a[:, 2:5]).abs() / conic_scale).max()
    assert conic_gap < 2e-4, ("conic", conic_gap)
    assert ((b[:, 5:] - a[:, 5:]).abs() / a[:, 5:].abs()).max() < 2e-4, (
        "extent, depth", ((b[:, 5:] - a[:, 5:]).abs() / a[:, 5:]).max())
    overall = max(float(gr.abs().max()) for gr in grads_r)  # float32 rounding floor: exact zeros come out ~1e-7
    for name, gr, gf in zip(("means", "scales", "quats"), grads_r, grads_f):
        assert torch.isfinite(gf).all(), name
        # every component against its own size (float32 gives ~1e-6 relative here, also at the poles,
        # where d/dy is 1e-4 of d/dx), with a floor for components that are zero up to rounding
        err = (gf - gr).abs() - grad_rtol * gr.abs()
        assert err.max() <= 1e-7 * overall, (name, err.max(), overall)


def _gaussians(means, seed=0, scale=(0.05, 0.3)):
    gen = torch.Generator().manual_seed(seed)
    n = len(means)
    return Gaussians.from_rgb(means.to(F64),
                              scale[0] + (scale[1] - scale[0]) * torch.rand(n, 3, generator=gen, dtype=F64),
                              torch.randn(n, 4, generator=gen, dtype=F64),
                              0.2 + 0.7 * torch.rand(n, generator=gen, dtype=F64),
                              torch.rand(n, 3, generator=gen, dtype=F64))


def _directions(lat_deg, lon_deg):
    lat, lon = torch.deg2rad(lat_deg.to(F64)), torch.deg2rad(lon_deg.to(F64))
    return torch.stack((torch.cos(lat) * torch.sin(lon), torch.sin(lat), torch.cos(lat) * torch.cos(lon)), -1)


def test_equirect_random_scene_matches_the_reference():
    g = shell_scene(150, seed=21, radius=(0.5, 4.0))
    poses = torch.stack((yaw_pose(0.0), yaw_pose(1.3, (0.3, -0.2, 0.1))))
    _assert_match(*_both(g, poses, Equirect(32, 64)), width=64)


def test_pinhole_and_cubemap_faces_match_the_reference():
    k = torch.tensor([[18.0, 0.0, 16.3], [0.0, 19.0, 11.8], [0.0, 0.0, 1.0]], dtype=F64)
    g = shell_scene(120, seed=22, radius=(0.5, 3.0))
    poses = torch.stack((yaw_pose(0.2), yaw_pose(-2.0, (0.1, 0.1, 0.4))))
    ref, fast = _both(g, poses, Pinhole(k, 24, 32))
    assert ref[1].sum() > 20 and not ref[1].all()  # some pairs in view, some culled
    _assert_match(ref, fast)
    faces = cubemap_face_c2w(yaw_pose(0.5, (0.0, 0.1, 0.0))).reshape(-1, 4, 4)
    _assert_match(*_both(g, faces, cubemap_face(16)))


def test_seam_matches_the_reference():
    gen = torch.Generator().manual_seed(23)
    n = 60
    lon = 180.0 + torch.randn(n, generator=gen, dtype=F64) * 3  # both sides of +-180 degrees
    lon[:3] = torch.tensor([180.0, -180.0, 179.999])
    means = _directions(torch.randn(n, generator=gen, dtype=F64) * 30, lon)
    means = means * (1 + 2 * torch.rand(n, 1, generator=gen, dtype=F64))
    _assert_match(*_both(_gaussians(means, seed=23), torch.eye(4, dtype=F64), Equirect(32, 64)), width=64)


def test_poles_match_the_reference_through_the_clamped_jacobian_and_the_std_caps():
    # From 60 degrees to the axis itself: exact Jacobian, rho bounded by pole_eps * r (above 89.94
    # degrees), the u and v std caps, and the vertical axis where u, v are constants.
    lat = torch.tensor([60.0, 75.0, 85.0, 88.0, 89.5, 89.9, 89.95, 89.99, 89.999, 90.0], dtype=F64)
    lat = torch.cat((lat, -lat))
    means = _directions(lat, torch.linspace(-170, 170, len(lat), dtype=F64)) * 1.5
    g = _gaussians(means, seed=24, scale=(0.02, 0.2))
    ref, fast = _both(g, yaw_pose(0.3), Equirect(32, 64))
    assert ref[1].all()
    cap_u2 = (64 / 6.0) ** 2
    extent_u = ref[0][0, 0, :, 5]
    assert (extent_u >= 3 * math.sqrt(cap_u2) * (1 - 1e-9)).any() and (extent_u < 3 * math.sqrt(cap_u2) * 0.9).any()
    _assert_match(ref, fast, width=64)


def test_near_plane_matches_the_reference():
    near = SETTINGS.near
    radius = near * torch.tensor([0.5, 0.99, 1.01, 1.5, 3.0, 10.0], dtype=F64)
    dirs = _directions(torch.tensor([0.0, 20.0, -30.0, 10.0, 45.0, -5.0], dtype=F64),
                       torch.tensor([0.0, 40.0, -90.0, 170.0, 10.0, -20.0], dtype=F64))
    g = _gaussians(dirs * radius[:, None], seed=25, scale=(1e-3, 5e-3))
    ref, fast = _both(g, torch.eye(4, dtype=F64), Equirect(16, 32))
    assert ref[1][0, 0].tolist() == [False, False, True, True, True, True]
    _assert_match(ref, fast, width=32)
    k = torch.tensor([[8.0, 0.0, 8.0], [0.0, 8.0, 8.0], [0.0, 0.0, 1.0]], dtype=F64)
    z_axis = _gaussians(torch.tensor([[0.0, 0.0, 1.0]], dtype=F64) * radius[:, None], seed=25, scale=(1e-3, 5e-3))
    ref, fast = _both(z_axis, torch.eye(4, dtype=F64), Pinhole(k, 16, 16))
    assert ref[1][0, 0].tolist() == [False, False, True, True, True, True]
    _assert_match(ref, fast)


@pytest.mark.parametrize("name,g", [s for s in degenerate_scenes() if s[0] != "no gaussians"],
                         ids=[s[0] for s in degenerate_scenes() if s[0] != "no gaussians"])
def test_degenerate_gaussians_match_the_reference(name, g):
    ref, fast = _both(g.to(F64), torch.eye(4, dtype=F64), Equirect(16, 32))
    _assert_match(ref, fast, width=32)


def test_zero_quaternion_and_transparent_gaussians():
    means = torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 1.0], [0.0, 0.5, -1.0]], dtype=F64)
    g = Gaussians.from_rgb(means, torch.tensor([0.1, 0.2, 0.05], dtype=F64).expand(3, 3),
                           torch.tensor([[0.0, 0, 0, 0], [1.0, 0, 0, 0], [0.3, 0.1, 0.2, 0.9]], dtype=F64),
                           torch.tensor([0.5, 1e-3, 0.5], dtype=F64), torch.ones(3, 3, dtype=F64))
    ref, fast = _both(g, torch.eye(4, dtype=F64), Equirect(16, 32))
    assert ref[1][0, 0].tolist() == [True, False, True]  # below alpha_min: culled
    _assert_match(ref, fast, width=32)


def test_invisible_pairs_rows_are_inert_and_keeping_every_pair_equals_the_masked_reference():
    # The kernel writes an invisible pair's row as projection._INERT_UV (u = v = -1, the rest 0), so keeping every
    # pair needs no masking (project_dense_triton.writes_inert_rows); the reference's pairs are masked instead.
    from cylindersplat.render.projection import project_gaussians

    means = torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 1.0], [0.0, 0.0, 0.001], [0.0, 0.5, -1.0]])
    g = Gaussians.from_rgb(means, torch.full((4, 3), 0.1), torch.tensor([[1.0, 0, 0, 0]]).expand(4, 4),
                           torch.tensor([0.5, 1e-3, 0.5, 0.5]), torch.ones(4, 3)).to(DEVICE)
    c2w = torch.eye(4, device=DEVICE)
    batched = (t[None] for t in (g.means, g.scales, g.rotations, g.opacities))
    geo, valid = project_dense_triton(*batched, c2w[None, None], Equirect(16, 32), SETTINGS)
    assert valid[0, 0].tolist() == [True, False, False, True]  # transparent, then closer than the near plane
    inert = torch.tensor([-1.0, -1.0, 0, 0, 0, 0, 0, 0], device=DEVICE)
    assert torch.equal(geo[0, 0, 1], inert) and torch.equal(geo[0, 0, 2], inert)
    assert project_dense_triton.writes_inert_rows
    flat, flat_c2w, _ = flatten_cameras(g, c2w)
    kept = project_gaussians(flat, flat_c2w, Equirect(16, 32), SETTINGS, project_dense_triton, every_pair=True)
    masked = project_gaussians(flat.to(F64), flat_c2w.to(F64), Equirect(16, 32), SETTINGS, every_pair=True)
    assert torch.equal(kept.uv[~valid.view(-1)], masked.uv[~valid.view(-1)].float())
    assert torch.equal(kept.depth[~valid.view(-1)], masked.depth[~valid.view(-1)].float())
    assert int(kept.visible) == int(masked.visible) == 2


@pytest.mark.parametrize("num_b,num_v", [(1, 1), (1, 3), (2, 1), (2, 3)])
def test_every_pair_kept_has_contiguous_indices_and_broadcast_values_equal_to_the_gathered_ones(num_b, num_v):
    # Keeping every pair broadcasts cameras, Gaussian rows, opacities and colours instead of gathering them; the
    # binning kernels read the camera of each pair by pointer, so it must be a whole contiguous tensor (one camera's
    # broadcast would be a view of one element).
    from cylindersplat.render.projection import project_gaussians

    scenes = [shell_scene(12, seed=40 + b, sh_degree=1, dtype=torch.float32) for b in range(num_b)]
    g = Gaussians(**{k: torch.stack([getattr(s, k) for s in scenes]) for k in scenes[0].tensors()}).to(DEVICE)
    c2w = torch.stack([torch.stack([yaw_pose(0.5 * v, (0.1 * v, 0.0, 0.0)) for v in range(num_v)])] * num_b)
    flat, flat_c2w, _ = flatten_cameras(g, c2w.float().to(DEVICE))
    kept = project_gaussians(flat, flat_c2w, Equirect(8, 16), SETTINGS, project_dense_triton, every_pair=True)
    index = torch.arange(num_b * num_v * 12, device=DEVICE)
    assert kept.camera.is_contiguous() and torch.equal(kept.camera, index // 12)
    assert kept.gaussian.is_contiguous() and torch.equal(kept.gaussian, index % 12 + index // (num_v * 12) * 12)
    assert torch.equal(kept.opacity, flat.opacities.reshape(-1)[kept.gaussian])
    visible = project_gaussians(flat, flat_c2w, Equirect(8, 16), SETTINGS, project_dense_triton)  # gathered
    at = visible.camera * 12 + visible.gaussian % 12
    assert torch.equal(kept.color[at], visible.color) and torch.equal(kept.opacity[at], visible.opacity)


def test_batched_gaussians_and_several_cameras_sum_gradients_over_cameras():
    a, b = shell_scene(30, seed=26), shell_scene(30, seed=27)
    batched = Gaussians(**{k: torch.stack((getattr(a, k), getattr(b, k))) for k in a.tensors()})
    poses = torch.stack([torch.stack((yaw_pose(0.2 * i), yaw_pose(-0.5, (0.2, 0, 0.1)), yaw_pose(2.0)))
                         for i in range(2)])
    _assert_match(*_both(batched, poses, Equirect(16, 32)), width=32)


def test_render_with_the_triton_backend_uses_the_kernel_and_falls_back_where_it_cannot(monkeypatch):
    from cylindersplat.render import api, triton_projection

    calls = []
    real = triton_projection.project_dense_triton

    def counting(*args):
        calls.append(type(args[5]).__name__)
        return real(*args)

    monkeypatch.setitem(api._PROJECTIONS, api._BACKENDS["triton"], counting)
    g = shell_scene(40, seed=28, dtype=torch.float32).to(DEVICE)
    pose = yaw_pose(0.1, dtype=torch.float32).to(DEVICE)
    out = render(g, pose, Equirect(8, 16), backend="triton")
    ref = render(g, pose, Equirect(8, 16), backend="torch")
    torch.testing.assert_close(out.rgb, ref.rgb, atol=2e-4, rtol=0)
    assert calls == ["Equirect"]
    # Poses that need gradients: the reference projects (the kernel treats poses as constants).
    with pytest.raises(UnsupportedSettings):
        project_dense_triton(g.means[None], g.scales[None], g.rotations[None], g.opacities[None],
                             pose[None, None].clone().requires_grad_(), Equirect(8, 16), SETTINGS)
    pose_grad = pose.clone().requires_grad_()
    out = render(g, pose_grad, Equirect(8, 16), backend="triton")
    out.rgb.sum().backward()
    assert pose_grad.grad is not None and torch.isfinite(pose_grad.grad).all()


def test_the_backward_reads_the_pairs_geo_gradient_in_place_where_its_rows_are_evenly_spaced():
    from cylindersplat.render.triton_projection import _pair_rows

    rows = torch.randn(2 * 3 * 5, 12)  # the compositing rows' gradient: geo in the first 8 columns
    grad_geo = rows[:, :8].reshape(2, 3, 5, 8)
    same, stride = _pair_rows(grad_geo)
    assert same is grad_geo and stride == 12
    contiguous = torch.randn(2, 3, 5, 8)
    assert _pair_rows(contiguous) == (contiguous, 8)
    uneven = torch.randn(2, 5, 3, 8).transpose(1, 2)  # pairs not evenly spaced: copied
    copied, stride = _pair_rows(uneven)
    assert stride == 8 and copied.is_contiguous() and torch.equal(copied, uneven)
    half = torch.randn(1, 1, 4, 8, dtype=torch.float16)  # another dtype: converted
    assert _pair_rows(half)[0].dtype == torch.float32
