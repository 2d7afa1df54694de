"""The camera-model seam: every camera model on every backend against the brute-force compositor.

The brute-force compositor (:mod:`cylindersplat.render.brute_force`) loops over every Gaussian at
every pixel, with none of the backends' binning or tiling. Without CUDA the Triton backend runs in
Triton's CPU interpreter (conftest.py).
"""

import math

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry.cubemap import cubemap_face_c2w
from cylindersplat.render import (
    Equirect,
    Pinhole,
    RasterSettings,
    api,
    available_backends,
    cubemap_face,
    register_backend,
    render,
    render_cubemap,
    render_equirect,
    render_pinhole,
)
from cylindersplat.render.brute_force import composite_brute_force
from render_scenes import shell_scene, yaw_pose

F32 = torch.float32
F64 = torch.float64
DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
BACKENDS = [b for b in ("torch", "triton") if b in available_backends()]


def _pinhole_k(h, w, fov_deg=100.0):
    f = (w / 2) / math.tan(math.radians(fov_deg) / 2)
    return torch.tensor([[f, 0.0, w / 2 + 0.3], [0.0, f, h / 2 - 0.2], [0.0, 0.0, 1.0]])


CAMERAS = {
    "equirect": Equirect(16, 32),
    "pinhole": Pinhole(_pinhole_k(20, 28), 20, 28),
    "cubemap face": cubemap_face(16, dtype=F32),
}


def _poses(camera_name):
    base = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(2.2, (0.2, -0.1, 0.3), dtype=F32)))
    if camera_name == "cubemap face":
        return cubemap_face_c2w(base).reshape(-1, 4, 4)  # all six faces of both cube maps
    return base


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("camera_name", list(CAMERAS))
def test_every_camera_model_on_every_backend_matches_brute_force(camera_name, backend):
    camera = CAMERAS[camera_name]
    g = shell_scene(60, seed=11, sh_degree=1, dtype=F32).to(DEVICE)
    poses = _poses(camera_name).to(DEVICE)
    settings = RasterSettings()
    bg = torch.tensor([0.1, 0.2, 0.3], device=DEVICE)
    out = render(g, poses, camera, background=bg, backend=backend, settings=settings)
    assert out.rgb.shape == (len(poses), 3, camera.height, camera.width)

    proj = camera.project(g.to("cpu"), poses.cpu(), settings)
    rgb, depth, alpha = composite_brute_force(proj, settings, bg.cpu())
    torch.testing.assert_close(out.rgb.cpu(), rgb, atol=3e-5, rtol=0)
    torch.testing.assert_close(out.depth.cpu(), depth, atol=1e-4, rtol=0)
    torch.testing.assert_close(out.alpha.cpu(), alpha, atol=3e-5, rtol=0)
    assert alpha.max() > 0.5  # the cameras really see the scene


@pytest.mark.skipif("triton" not in BACKENDS, reason="Triton is not installed")
@pytest.mark.parametrize("camera_name", list(CAMERAS))
def test_triton_gradients_match_the_reference_on_every_camera_model(camera_name):
    camera = CAMERAS[camera_name]
    g = shell_scene(50, seed=12, sh_degree=1, dtype=F32)
    poses = _poses(camera_name).to(DEVICE)
    grads = []
    for backend in ("torch", "triton"):
        params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
        out = render(Gaussians(**params), poses, camera, background=(0.3, 0.3, 0.3), backend=backend)
        gen = torch.Generator().manual_seed(3)
        loss = sum((torch.randn(t.shape, generator=gen).to(DEVICE) * t).sum() for t in (out.rgb, out.depth, out.alpha))
        grads.append(torch.autograd.grad(loss, list(params.values())))
    for name, ref, fast in zip(g.tensors(), *grads):
        scale = ref.abs().max().clamp_min(1e-6)
        assert (fast - ref).abs().max() <= 2e-3 * scale + 1e-6, name


@pytest.mark.parametrize("backend", BACKENDS)
def test_cubemap_route_is_the_same_on_every_backend(backend):
    g = shell_scene(80, seed=13, dtype=F32).to(DEVICE)
    c2w = yaw_pose(0.4, dtype=F32).to(DEVICE)
    ref = render_cubemap(g, c2w, 16, 32, backend="torch")
    out = render_cubemap(g, c2w, 16, 32, backend=backend)
    torch.testing.assert_close(out.rgb, ref.rgb, atol=2e-4, rtol=0)
    torch.testing.assert_close(out.depth, ref.depth, atol=1e-3, rtol=0)


def test_named_entry_points_are_the_seam():
    g = shell_scene(30, seed=14)
    c2w = yaw_pose(0.1)
    torch.testing.assert_close(render_equirect(g, c2w, 8, 16).rgb, render(g, c2w, Equirect(8, 16)).rgb)
    k = _pinhole_k(12, 16).double()
    torch.testing.assert_close(render_pinhole(g, c2w, k, 12, 16).rgb, render(g, c2w, Pinhole(k, 12, 16)).rgb)


def test_registered_backend_serves_every_camera_model(monkeypatch):
    monkeypatch.setattr(api, "_BACKENDS", dict(api._BACKENDS))
    calls = []

    def brute(proj, settings, background):
        calls.append(proj.wrap_u)
        return composite_brute_force(proj, settings, background)

    register_backend("brute", brute)
    assert "brute" in available_backends()
    g = shell_scene(20, seed=15)
    for name, camera in CAMERAS.items():
        poses = _poses(name).double()
        ref = render(g, poses, camera, backend="torch")
        out = render(g, poses, camera, backend="brute")
        torch.testing.assert_close(out.rgb, ref.rgb, atol=1e-6, rtol=0)
    assert calls == [True, False, False]  # equirect wraps across the seam, pinhole images do not


def test_seam_rejects_bad_cameras_and_backends():
    g = shell_scene(5, seed=16)
    with pytest.raises(ValueError, match="width == 2"):
        Equirect(16, 16)
    with pytest.raises(ValueError, match="positive integer"):
        Equirect(16.0, 32)
    with pytest.raises(ValueError, match="3x3"):
        Pinhole(torch.eye(4), 8, 8)
    with pytest.raises(ValueError, match="focal"):
        Pinhole(torch.zeros(3, 3), 8, 8)
    with pytest.raises(TypeError, match="camera model"):
        render(g, torch.eye(4, dtype=torch.float64), (16, 32))
    with pytest.raises(ValueError, match="unknown render backend"):
        render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16), backend="nope")
    with pytest.raises(ValueError, match="background"):
        render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16), background=(0.0, 0.0))
    with pytest.raises(ValueError, match="background must be finite"):
        render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16), background=(float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="no cameras"):
        render(g, torch.zeros(0, 4, 4, dtype=torch.float64), Equirect(8, 16))
    with pytest.raises(ValueError, match="other than 'auto'"):
        register_backend("auto", lambda *a: None)


@pytest.mark.slow
def test_compiled_projection_matches_eager(monkeypatch):
    """``compile_projection()``: the dense projection math through torch.compile, outputs and gradients."""
    from cylindersplat.render import projection

    g = shell_scene(40, seed=17, sh_degree=1, dtype=F32)
    poses = _poses("equirect")
    results = []
    for compiled in (False, True):
        monkeypatch.setattr(projection, "_USE_COMPILED", compiled)
        params = {k: v.clone().requires_grad_() for k, v in g.tensors().items()}
        out = render(Gaussians(**params), poses, CAMERAS["equirect"], backend="torch")
        loss = (out.rgb * torch.linspace(0, 1, out.rgb.numel()).view_as(out.rgb)).sum() + out.depth.sum()
        results.append((out, torch.autograd.grad(loss, list(params.values()))))
    (ref, ref_grads), (fast, fast_grads) = results
    torch.testing.assert_close(fast.rgb, ref.rgb, atol=1e-5, rtol=0)
    for name, a, b in zip(g.tensors(), ref_grads, fast_grads):
        torch.testing.assert_close(b, a, atol=1e-4 * float(a.abs().max()) + 1e-7, rtol=0, msg=name)


def test_a_scene_smaller_than_the_near_plane_warns():
    g = shell_scene(10, seed=18, radius=(0.001, 0.005), scale=(1e-4, 2e-4))  # millimetres, as if units were off
    with pytest.warns(RuntimeWarning, match="none of the 10 Gaussians is visible"):
        out = render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16))
    assert out.alpha.max() == 0


def test_renders_that_would_not_fit_in_memory_are_refused(monkeypatch):
    from cylindersplat.render import rasterize as rast

    g = shell_scene(30, seed=19)
    out = render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16), backend="torch")  # fits
    monkeypatch.setattr(rast, "available_memory", lambda device: 1000)  # 1 kB free
    with pytest.raises(rast.RenderMemoryError, match="GiB for .* (fragments|row spans)"):
        render(g, torch.eye(4, dtype=torch.float64), Equirect(8, 16), backend="torch")
    assert out.alpha.max() > 0
    assert rast.available_memory(torch.device("cpu")) is None or rast.available_memory(torch.device("cpu")) > 0


def test_a_new_camera_model_is_one_pixel_map():
    """A camera model implements only its pixel map (and std caps); world -> camera, the EWA footprint,
    shape checks and every backend come with the seam. Here an orthographic camera looking along +z."""
    from cylindersplat.render.cameras import CameraModel
    from cylindersplat.render.projection import PixelMap

    class Orthographic(CameraModel):
        height, width, scale = 12, 16, 6.0  # pixels per metre
        max_std = (64.0, 64.0)

        def pixel_map(self, points, settings):
            x, y, z = points.unbind(-1)
            jac = torch.zeros(*points.shape[:-1], 2, 3, dtype=points.dtype)
            jac[..., 0, 0] = jac[..., 1, 1] = self.scale
            return PixelMap(self.scale * x + self.width / 2, self.scale * y + self.height / 2,
                            torch.linalg.vector_norm(points, dim=-1), jac, z > settings.near)

    g = shell_scene(30, seed=20)
    poses = torch.stack((yaw_pose(0.0), yaw_pose(0.1, (0.1, 0.0, -2.0))))
    camera = Orthographic()
    proj = camera.project(g, poses, RasterSettings())
    # The footprint of an orthographic camera is the 3D covariance's xy block, scaled (plus the dilation).
    row = proj.camera == 0
    from cylindersplat.render.covariance import covariance_3d

    cov = covariance_3d(g.scales, g.rotations)[proj.gaussian[row], :2, :2] * camera.scale**2
    cov = cov + 0.3 * torch.eye(2, dtype=F64)
    inv = torch.linalg.inv(cov)
    torch.testing.assert_close(proj.conic[row], torch.stack((inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]), -1))
    for backend in BACKENDS:
        out = render(g.to(F32), poses.to(F32), camera, background=(0.1, 0.2, 0.3), backend=backend)
        ref = composite_brute_force(camera.project(g.to(F32), poses.to(F32), RasterSettings()), RasterSettings(),
                                    torch.tensor([0.1, 0.2, 0.3]))
        torch.testing.assert_close(out.rgb, ref[0], atol=3e-5, rtol=0)
        assert out.alpha.max() > 0.5
