"""The EWA projection of every camera model against an independent float64 construction.

The reference (:mod:`cylindersplat.render.projection`) writes the 2D covariance elementwise with a
hand-derived Jacobian. Here it is rebuilt from the textbook formula, in float64, with nothing of the
library but the camera conventions of DESIGN.md section 2:

    Sigma_2d = J W Sigma W^T J^T + dilation * I,   Sigma = R(q) diag(s^2) R(q)^T,   W = R_c2w^T

with ``J`` the Jacobian of the camera's pixel map obtained by *autograd* of the plain projection
formula (``atan2`` for equirect, ``f x / z + c`` for pinhole), and ``R(q)`` from the vector form of
the quaternion rotation. Gradients of the reference are checked by finite differences.
"""

import math

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry.cubemap import cubemap_face_c2w
from cylindersplat.render import Equirect, Pinhole, RasterSettings, cubemap_face
from render_scenes import yaw_pose

F64 = torch.float64
SETTINGS = RasterSettings()


# ---- the independent construction ----------------------------------------------------------------


def rotation_from_quaternion(q):
    """``R = (w^2 - v.v) I + 2 v v^T + 2 w [v]_x`` for the normalised quaternion ``(w, v)``; ``(N, 3, 3)``."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, v = q[:, 0], q[:, 1:]
    cross = torch.zeros(len(q), 3, 3, dtype=q.dtype)
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    cross = cross - cross.transpose(1, 2)
    eye = torch.eye(3, dtype=q.dtype).expand(len(q), 3, 3)
    return ((w * w - (v * v).sum(-1))[:, None, None] * eye + 2 * v[:, :, None] * v[:, None, :]
            + 2 * w[:, None, None] * cross)


def equirect_pixel(h, w):
    def pixel(p):  # DESIGN.md section 2: phi = atan2(x, z), lam = atan2(y, sqrt(x^2 + z^2))
        x, y, z = p
        return torch.stack((w / (2 * math.pi) * (torch.atan2(x, z) + math.pi),
                            h / math.pi * (torch.atan2(y, torch.sqrt(x * x + z * z)) + math.pi / 2)))
    return pixel


def pinhole_pixel(k):
    def pixel(p):
        x, y, z = p
        return torch.stack((k[0, 0] * x / z + k[0, 2], k[1, 1] * y / z + k[1, 2]))
    return pixel


def expected_projection(g: Gaussians, c2w, pixel, dilation=SETTINGS.dilation):
    """Per Gaussian (one camera): pixel mean ``(N, 2)``, 2D covariance ``(N, 2, 2)`` with dilation,
    conic ``(N, 3)``, 3-sigma extent ``(N, 2)``, radial depth ``(N,)``."""
    rot_w2c = c2w[:3, :3].T
    p = (g.means - c2w[:3, 3]) @ rot_w2c.T
    r = rotation_from_quaternion(g.rotations)
    sigma = r @ torch.diag_embed(g.scales**2) @ r.transpose(1, 2)
    uv = torch.stack([pixel(pi) for pi in p])
    jac = torch.stack([torch.autograd.functional.jacobian(pixel, pi) for pi in p])  # (N, 2, 3)
    t = jac @ rot_w2c
    cov = t @ sigma @ t.transpose(1, 2) + dilation * torch.eye(2, dtype=F64)
    inv = torch.linalg.inv(cov)
    conic = torch.stack((inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]), -1)
    extent = 3 * torch.sqrt(torch.diagonal(cov, dim1=1, dim2=2))
    return uv, cov, conic, extent, p.norm(dim=-1)


def random_gaussians(means, seed=0, scale=(0.02, 0.2)):
    gen = torch.Generator().manual_seed(seed)
    n = len(means)
    return Gaussians.from_rgb(means.to(F64),
                              scale[0] + (scale[1] - scale[0]) * torch.rand(n, 3, generator=gen, dtype=F64),
                              torch.randn(n, 4, generator=gen, dtype=F64), torch.full((n,), 0.8, dtype=F64),
                              torch.rand(n, 3, generator=gen, dtype=F64))


def directions(lat_deg, lon_deg):
    lat, lon = torch.deg2rad(torch.as_tensor(lat_deg, dtype=F64)), torch.deg2rad(torch.as_tensor(lon_deg, dtype=F64))
    return torch.stack((torch.cos(lat) * torch.sin(lon), torch.sin(lat), torch.cos(lat) * torch.cos(lon)), -1)


def project_one(camera, g, c2w):
    """The reference projection of ``g`` into one camera, rows in Gaussian order (visible ones only)."""
    proj = camera.project(g, c2w, SETTINGS)
    order = torch.argsort(proj.gaussian)
    return proj, order


def assert_projection_matches(proj, order, expected, visible, atol=1e-9, rtol=1e-9, wrap_width=None):
    uv, _, conic, extent, depth = (e[visible] for e in expected)
    got_uv = proj.uv[order]
    if wrap_width is not None:  # u is defined modulo the panorama width (the seam u = 0 = W)
        du = torch.remainder(got_uv[:, 0] - uv[:, 0] + wrap_width / 2, wrap_width) - wrap_width / 2
        got_uv = torch.stack((uv[:, 0] + du, got_uv[:, 1]), -1)
    torch.testing.assert_close(proj.gaussian[order], visible.nonzero().squeeze(1))
    torch.testing.assert_close(got_uv, uv, atol=atol, rtol=rtol)
    torch.testing.assert_close(proj.conic[order], conic, atol=atol, rtol=rtol)
    torch.testing.assert_close(proj.extent[order], extent, atol=atol, rtol=rtol)
    torch.testing.assert_close(proj.depth[order], depth, atol=atol, rtol=rtol)


# ---- equirect ------------------------------------------------------------------------------------


def test_equirect_matches_the_float64_construction_with_the_corrected_jacobian():
    gen = torch.Generator().manual_seed(1)
    n = 60
    dirs = directions(-60 + 120 * torch.rand(n, generator=gen, dtype=F64),
                      -179 + 358 * torch.rand(n, generator=gen, dtype=F64))
    g = random_gaussians(dirs * (0.8 + 3 * torch.rand(n, 1, generator=gen, dtype=F64)), seed=1)
    c2w = yaw_pose(0.4, (0.1, -0.05, 0.2))
    h, w = 32, 64
    proj, order = project_one(Equirect(h, w), g, c2w)
    expected = expected_projection(g, c2w, equirect_pixel(h, w))
    assert len(order) == n  # all visible, none capped: the formula holds exactly
    assert_projection_matches(proj, order, expected, torch.ones(n, dtype=torch.bool), wrap_width=w)


def test_equirect_jacobian_sign_matters():
    """The paper's printed dv/dx (opposite sign) gives a visibly different covariance for an
    off-axis Gaussian; the reference follows the corrected one (the test above) and not the printed one."""
    g = random_gaussians(directions(torch.tensor([35.0]), torch.tensor([50.0])) * 2.0, seed=2, scale=(0.2, 0.4))
    h, w = 32, 64
    uv, cov, *_ = expected_projection(g, torch.eye(4, dtype=F64), equirect_pixel(h, w))
    p = g.means[0]
    x, y, z = p
    rho, r2 = torch.sqrt(x * x + z * z), p @ p
    printed = torch.autograd.functional.jacobian(equirect_pixel(h, w), p)
    printed[1, 0] = (h / math.pi) * x * y / (r2 * rho)  # the paper's sign
    r = rotation_from_quaternion(g.rotations)[0]
    wrong = printed @ r @ torch.diag(g.scales[0] ** 2) @ r.T @ printed.T + SETTINGS.dilation * torch.eye(2, dtype=F64)
    proj, _ = project_one(Equirect(h, w), g, torch.eye(4, dtype=F64))
    conic = proj.conic[0]
    got = torch.linalg.inv(torch.tensor([[conic[0], conic[1]], [conic[1], conic[2]]]))
    torch.testing.assert_close(got, cov[0], atol=1e-9, rtol=1e-9)
    assert (got - wrong).abs().max() > 0.05 * got.abs().max()


def test_equirect_seam_footprints_are_the_formula_on_both_sides():
    # Straight behind the camera the longitude jumps from +180 to -180 degrees; the Jacobian does not.
    lon = torch.tensor([179.9, -179.9, 180.0, 179.0, -178.5], dtype=F64)
    g = random_gaussians(directions(torch.tensor([5.0, -3.0, 0.0, 20.0, -10.0], dtype=F64), lon) * 2.0, seed=3)
    h, w = 32, 64
    proj, order = project_one(Equirect(h, w), g, torch.eye(4, dtype=F64))
    assert ((proj.uv[:, 0] >= 0) & (proj.uv[:, 0] <= w)).all()
    expected = expected_projection(g, torch.eye(4, dtype=F64), equirect_pixel(h, w))
    assert_projection_matches(proj, order, expected, torch.ones(len(lon), dtype=torch.bool), wrap_width=w)


def test_equirect_near_the_poles_the_formula_holds_until_the_std_cap_and_stays_bounded_beyond():
    h, w = 32, 64
    lat = torch.tensor([80.0, -85.0, 89.0, -89.9, 89.999, 90.0, -90.0], dtype=F64)
    g = random_gaussians(directions(lat, torch.full_like(lat, 30.0)) * 2.0, seed=4, scale=(0.05, 0.1))
    proj, order = project_one(Equirect(h, w), g, torch.eye(4, dtype=F64))
    assert len(order) == len(lat)  # the poles are visible
    uv, cov, conic, extent, depth = expected_projection(g, torch.eye(4, dtype=F64), equirect_pixel(h, w))
    max_std = (w / 6.0, 2.0 * h)
    uncapped = (cov[:, 0, 0] < max_std[0] ** 2) & (cov[:, 1, 1] < max_std[1] ** 2)
    assert uncapped[:2].all() and not uncapped[-3:].any()  # both regimes are exercised
    assert_projection_matches(proj, order[uncapped[: len(order)]], expected=(uv, cov, conic, extent, depth),
                              visible=uncapped, atol=1e-8, rtol=1e-8)
    # Beyond: rows/columns scaled to the cap (the footprint keeps its orientation), finite, positive definite.
    got = proj.conic[order]
    assert torch.isfinite(got).all() and torch.isfinite(proj.extent).all()
    assert (got[:, 0] > 0).all() and (got[:, 0] * got[:, 2] - got[:, 1] ** 2 > 0).all()
    assert (proj.extent[:, 0] <= 3 * max_std[0] * (1 + 1e-12)).all()
    assert (proj.extent[:, 1] <= 3 * max_std[1] * (1 + 1e-12)).all()
    # v at the pole is exact (the top and bottom rows), whatever the cap.
    torch.testing.assert_close(proj.uv[order][-2:, 1], torch.tensor([float(h), 0.0], dtype=F64))


def test_near_plane_culls_by_radial_distance_for_equirect_and_by_z_for_pinhole():
    near = SETTINGS.near
    means = torch.tensor([[0.0, 0.0, 0.9 * near], [0.0, 0.0, 1.1 * near], [0.0, 0.0, -1.5 * near],
                          [0.5 * near, 0.0, 0.8 * near], [0.0, 0.0, 0.0]], dtype=F64)
    g = random_gaussians(means, seed=5, scale=(1e-3, 2e-3))
    eq = Equirect(16, 32).project(g, torch.eye(4, dtype=F64), SETTINGS)
    # radial: r > near keeps rows 1, 2 (behind the camera is in view for a panorama), culls 0, 3 (r < near), 4
    assert sorted(eq.gaussian.tolist()) == [1, 2]
    k = torch.tensor([[8.0, 0, 8.0], [0, 8.0, 8.0], [0, 0, 1.0]], dtype=F64)
    pin = Pinhole(k, 16, 16).project(g, torch.eye(4, dtype=F64), SETTINGS)
    assert pin.gaussian.tolist() == [1]  # z > near only
    for proj in (eq, pin):
        assert all(torch.isfinite(t).all() for t in (proj.uv, proj.conic, proj.extent, proj.depth))


def test_degenerate_gaussians_project_to_the_formula():
    """Zero scale: only the dilation is left (conic = I / 0.3). A flat disk seen edge-on: the formula.
    An unnormalised quaternion: the rotation of the normalised one."""
    means = torch.tensor([[0.3, -0.2, 2.0], [1.0, 0.5, 1.5], [-0.5, 0.1, 2.5]], dtype=F64)
    scales = torch.tensor([[0.0, 0.0, 0.0], [0.3, 1e-9, 0.3], [0.1, 0.2, 0.05]], dtype=F64)
    quats = torch.tensor([[1.0, 0, 0, 0], [0.9, 0.1, 0.3, -0.2], [5.0, 1.0, -2.0, 0.5]], dtype=F64)
    g = Gaussians.from_rgb(means, scales, quats, torch.full((3,), 0.5, dtype=F64), torch.ones(3, 3, dtype=F64))
    h, w = 32, 64
    proj, order = project_one(Equirect(h, w), g, torch.eye(4, dtype=F64))
    expected = expected_projection(g, torch.eye(4, dtype=F64), equirect_pixel(h, w))
    assert_projection_matches(proj, order, expected, torch.ones(3, dtype=torch.bool))
    torch.testing.assert_close(proj.conic[order][0], torch.tensor([1 / 0.3, 0.0, 1 / 0.3], dtype=F64))
    g_unit = Gaussians.from_rgb(means, scales, quats / quats.norm(dim=-1, keepdim=True), g.opacities, g.sh)
    torch.testing.assert_close(Equirect(h, w).project(g_unit, torch.eye(4, dtype=F64), SETTINGS).conic, proj.conic)


# ---- pinhole and cube-map faces ------------------------------------------------------------------


def test_pinhole_matches_the_float64_construction():
    gen = torch.Generator().manual_seed(6)
    n = 40
    k = torch.tensor([[30.0, 0.0, 20.3], [0.0, 28.0, 14.8], [0.0, 0.0, 1.0]], dtype=F64)
    h, w = 30, 40
    z = 1.0 + 3 * torch.rand(n, generator=gen, dtype=F64)
    x = (torch.rand(n, generator=gen, dtype=F64) * w - k[0, 2]) / k[0, 0] * z
    y = (torch.rand(n, generator=gen, dtype=F64) * h - k[1, 2]) / k[1, 1] * z
    c2w = yaw_pose(-0.3, (0.2, 0.1, -0.4))
    g = random_gaussians(torch.stack((x, y, z), -1) @ c2w[:3, :3].T + c2w[:3, 3], seed=6)
    proj, order = project_one(Pinhole(k, h, w), g, c2w)
    expected = expected_projection(g, c2w, pinhole_pixel(k))
    assert len(order) == n
    assert_projection_matches(proj, order, expected, torch.ones(n, dtype=torch.bool))


def test_pinhole_guard_band_culls_means_far_outside_the_view():
    k = torch.tensor([[10.0, 0.0, 10.0], [0.0, 10.0, 10.0], [0.0, 0.0, 1.0]], dtype=F64)
    # half field of view: tan = 1; the guard band is 1.3x that.
    means = torch.tensor([[1.25, 0.0, 1.0], [1.35, 0.0, 1.0], [0.0, -1.2, 1.0], [0.0, 1.4, 1.0]], dtype=F64)
    proj = Pinhole(k, 20, 20).project(random_gaussians(means, seed=7, scale=(0.5, 0.6)), torch.eye(4, dtype=F64),
                                      SETTINGS)
    assert sorted(proj.gaussian.tolist()) == [0, 2]


def test_cubemap_faces_match_the_float64_construction():
    size = 16
    camera = cubemap_face(size, dtype=F64)
    faces = cubemap_face_c2w(yaw_pose(0.25, (0.1, 0.0, -0.1)))  # (6, 4, 4)
    gen = torch.Generator().manual_seed(8)
    for face in range(6):
        c2w = faces[face]
        n = 12
        z = 1.0 + 2 * torch.rand(n, generator=gen, dtype=F64)
        xy = (torch.rand(n, 2, generator=gen, dtype=F64) * 1.6 - 0.8) * z[:, None]  # inside the 90-degree face
        means = torch.cat((xy, z[:, None]), -1) @ c2w[:3, :3].T + c2w[:3, 3]
        g = random_gaussians(means, seed=face)
        proj, order = project_one(camera, g, c2w)
        expected = expected_projection(g, c2w, pinhole_pixel(camera.intrinsics))
        assert len(order) == n, face
        assert_projection_matches(proj, order, expected, torch.ones(n, dtype=torch.bool))


# ---- gradients -----------------------------------------------------------------------------------


@pytest.mark.parametrize("camera_name", ["equirect", "pinhole"])
def test_projection_gradients_match_finite_differences(camera_name):
    gen = torch.Generator().manual_seed(9)
    n = 4
    means = torch.stack((torch.randn(n, generator=gen, dtype=F64) * 0.3, torch.randn(n, generator=gen, dtype=F64) * 0.3,
                         1.5 + torch.rand(n, generator=gen, dtype=F64)), -1)
    base = random_gaussians(means, seed=9, scale=(0.1, 0.3))
    k = torch.tensor([[12.0, 0, 8], [0, 12.0, 8], [0, 0, 1]], dtype=F64)
    camera = Equirect(16, 32) if camera_name == "equirect" else Pinhole(k, 16, 16)
    c2w = yaw_pose(0.2, (0.05, 0.0, 0.1))

    def fn(m, s, q):
        proj = camera.project(Gaussians.from_rgb(m, s, q, base.opacities, torch.ones(n, 3, dtype=F64)), c2w, SETTINGS)
        assert len(proj.gaussian) == n
        return proj.uv, proj.conic, proj.extent, proj.depth

    assert torch.autograd.gradcheck(fn, (means.clone().requires_grad_(), base.scales.clone().requires_grad_(),
                                         base.rotations.clone().requires_grad_()), eps=1e-6, atol=1e-6, rtol=1e-5)


def test_projection_gradients_match_autograd_of_the_construction():
    """The reference's gradients against autograd through the independent construction (equirect)."""
    gen = torch.Generator().manual_seed(10)
    n = 8
    dirs = directions(-50 + 100 * torch.rand(n, generator=gen, dtype=F64),
                      -170 + 340 * torch.rand(n, generator=gen, dtype=F64))
    base = random_gaussians(dirs * 2.0, seed=10)
    h, w = 16, 32
    weights = [torch.randn(n, 2, generator=gen, dtype=F64), torch.randn(n, 3, generator=gen, dtype=F64),
               torch.randn(n, 2, generator=gen, dtype=F64), torch.randn(n, generator=gen, dtype=F64)]
    grads = []
    for build in ("reference", "construction"):
        params = [t.clone().requires_grad_() for t in (base.means, base.scales, base.rotations)]
        g = Gaussians.from_rgb(*params, base.opacities, torch.ones(n, 3, dtype=F64))
        if build == "reference":
            proj, order = project_one(Equirect(h, w), g, torch.eye(4, dtype=F64))
            outs = (proj.uv[order], proj.conic[order], proj.extent[order], proj.depth[order])
        else:
            uv, _, conic, extent, depth = _construction_differentiable(g, h, w)
            outs = (uv, conic, extent, depth)
        loss = sum((wt * o).sum() for wt, o in zip(weights, outs))
        grads.append(torch.autograd.grad(loss, params))
    for ref, ind in zip(*grads):
        torch.testing.assert_close(ref, ind, atol=1e-8, rtol=1e-7)


def _construction_differentiable(g, h, w):
    """:func:`expected_projection` for the identity pose with a Jacobian built by ``create_graph=True``
    (so that it can be differentiated again)."""
    pixel = equirect_pixel(h, w)
    r = rotation_from_quaternion(g.rotations)
    sigma = r @ torch.diag_embed(g.scales**2) @ r.transpose(1, 2)
    uv = torch.stack([pixel(p) for p in g.means])
    jac = torch.stack([torch.autograd.functional.jacobian(pixel, p, create_graph=True) for p in g.means])
    cov = jac @ sigma @ jac.transpose(1, 2) + SETTINGS.dilation * torch.eye(2, dtype=F64)
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] ** 2
    conic = torch.stack((cov[:, 1, 1], -cov[:, 0, 1], cov[:, 0, 0]), -1) / det[:, None]
    extent = 3 * torch.sqrt(torch.stack((cov[:, 0, 0], cov[:, 1, 1]), -1))
    return uv, cov, conic, extent, g.means.norm(dim=-1)


def test_every_pair_visible_skips_the_gathers_with_the_same_pairs_and_gradients():
    """All pairs visible (a panorama's usual case): the pairs come without gathers, and they are what the gathers by
    the visible pairs' index give - rows, indices, opacities, view-dependent colours, and their gradients."""
    from cylindersplat.render.projection import _view_colors, flatten_cameras, project_gaussians
    from render_scenes import shell_scene

    scenes = [shell_scene(5, seed=s, sh_degree=1) for s in (1, 2)]
    g = Gaussians(**{k: torch.stack([s.tensors()[k] for s in scenes]).requires_grad_()
                     for k in scenes[0].tensors()})
    c2w = torch.stack([torch.stack((yaw_pose(0.3 * b), yaw_pose(1.0, (0.1, 0.0, 0.2 * b)))) for b in range(2)])
    from cylindersplat.benchmarks.launches import count_launches

    flat, cams = flatten_cameras(g, c2w)[:2]
    launches = count_launches(lambda: project_gaussians(flat, cams, Equirect(16, 32), SETTINGS))
    assert not {"index_select", "index", "gather"} & set(launches.torch_ops), launches.torch_ops  # no gathers
    proj = project_gaussians(flat, cams, Equirect(16, 32), SETTINGS)
    index = torch.arange(2 * 2 * 5)  # every (b, v, n) pair, camera-major
    assert proj.visible is None and len(proj.depth) == len(index)
    gauss, camera = index % 5 + (index // 10) * 5, index // 5
    torch.testing.assert_close(proj.gaussian, gauss, rtol=0, atol=0)
    torch.testing.assert_close(proj.camera, camera, rtol=0, atol=0)
    opacity = flat.opacities.reshape(-1).index_select(0, gauss)
    color = _view_colors(flat, cams, camera, gauss)
    torch.testing.assert_close(proj.opacity, opacity, rtol=0, atol=0)
    torch.testing.assert_close(proj.color, color, rtol=1e-15, atol=1e-15)
    weights = torch.rand(len(index), 4, generator=torch.Generator().manual_seed(0), dtype=F64)
    got = torch.autograd.grad((proj.opacity * weights[:, 0] + (proj.color * weights[:, 1:]).sum(-1)).sum(),
                              (g.opacities, g.sh, g.means))
    want = torch.autograd.grad((opacity * weights[:, 0] + (color * weights[:, 1:]).sum(-1)).sum(),
                               (g.opacities, g.sh, g.means))
    for a, b in zip(got, want):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)
