"""Geometry conventions (DESIGN.md section 2) checked against autograd and hand-derived values."""

import math

import pytest
import torch

from cylindersplat.geometry import (
    CartesianCoords,
    CylindricalCoords,
    SphericalCoords,
    camera_to_world,
    cubemap_face_c2w,
    cubemap_rotations,
    equirect_jacobian,
    equirect_rays,
    invert_rigid,
    look_at_c2w,
    ray_to_uv,
    uv_to_ray,
    validate_c2w,
    world_to_camera,
)

H, W = 8, 16


def test_ray_directions_follow_the_convention():
    # centre column looks along +z, top row looks up (-y), u = 3W/4 looks along +x.
    d = uv_to_ray(torch.tensor([W / 2, W / 2, 3 * W / 4]), torch.tensor([H / 2, 0.0, H / 2]), H, W)
    torch.testing.assert_close(d, torch.tensor([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]), atol=1e-6, rtol=0)


def test_uv_ray_round_trip_and_unit_norm():
    rays = equirect_rays(H, W, dtype=torch.float64)
    torch.testing.assert_close(rays.norm(dim=-1), torch.ones(H, W, dtype=torch.float64))
    u, v = ray_to_uv(rays * 3.7, H, W)
    jj, ii = torch.meshgrid(torch.arange(W), torch.arange(H), indexing="xy")
    torch.testing.assert_close(u, jj.double() + 0.5)
    torch.testing.assert_close(v, ii.double() + 0.5)


def _project(p):
    u, v = ray_to_uv(p, H, W)
    return torch.stack((u, v))


def test_equirect_jacobian_matches_autograd_and_fixes_the_paper_sign():
    gen = torch.Generator().manual_seed(0)
    pts = torch.randn(20, 3, generator=gen, dtype=torch.float64) * 2
    jac = equirect_jacobian(pts, H, W)
    for p, j in zip(pts, jac):
        ref = torch.autograd.functional.jacobian(_project, p)
        torch.testing.assert_close(j, ref)
    # The paper prints dv/dx = +H/pi * x y / (r^2 rho); the true sign is negative.
    x, y, z = 1.0, 0.5, 2.0
    rho, r2 = math.hypot(x, z), x * x + y * y + z * z
    printed = H / math.pi * x * y / (r2 * rho)
    got = equirect_jacobian(torch.tensor([x, y, z], dtype=torch.float64), H, W)
    assert got[1, 0] == pytest.approx(-printed)
    # Its dv/dz = -H/pi * z y / (r^2 rho) is printed right: only dv/dx is mis-signed.
    assert got[1, 2] == pytest.approx(-H / math.pi * z * y / (r2 * rho))
    ref = torch.autograd.functional.jacobian(_project, torch.tensor([x, y, z], dtype=torch.float64))
    assert ref[1, 2].item() == pytest.approx(-H / math.pi * z * y / (r2 * rho))


@pytest.mark.parametrize("coords", [CylindricalCoords(), SphericalCoords(), CartesianCoords()])
def test_triplane_coordinates_round_trip_and_jacobian(coords):
    gen = torch.Generator().manual_seed(1)
    xyz = (torch.rand(16, 3, generator=gen, dtype=torch.float64) - 0.5) * 8
    q = coords.from_cartesian(xyz)
    torch.testing.assert_close(coords.to_cartesian(q), xyz)
    jac = coords.jacobian(q)
    for qi, ji in zip(q, jac):
        torch.testing.assert_close(ji, torch.autograd.functional.jacobian(coords.to_cartesian, qi))
    t = coords.to_unit(q)
    assert ((t >= 0) & (t <= 1)).all()
    torch.testing.assert_close(coords.from_unit(t), q)


def test_cylinder_theta_runs_along_panorama_columns():
    # theta = 2 pi u / W and h is the camera-frame y.
    u = torch.tensor([0.5, 3.0, 8.0, 15.5], dtype=torch.float64)
    v = torch.full_like(u, 2.5)
    q = CylindricalCoords().from_cartesian(uv_to_ray(u, v, H, W) * 2.0)
    torch.testing.assert_close(q[:, 1], 2 * math.pi * u / W)
    torch.testing.assert_close(q[:, 2], uv_to_ray(u, v, H, W)[:, 1] * 2.0)
    # Periodicity: theta and theta + 2 pi are the same point.
    a = torch.tensor([[2.0, 0.3, 1.0]], dtype=torch.float64)
    b = a + torch.tensor([[0.0, 2 * math.pi, 0.0]], dtype=torch.float64)
    c = CylindricalCoords()
    torch.testing.assert_close(c.to_cartesian(a), c.to_cartesian(b))
    torch.testing.assert_close(c.to_unit(a), c.to_unit(b))


def test_poses_round_trip_and_validation():
    eye = torch.tensor([1.0, -0.5, 2.0])
    c2w = look_at_c2w(eye, torch.tensor([0.0, 0.0, 0.0]))
    validate_c2w(c2w)
    pts = torch.randn(5, 3)
    torch.testing.assert_close(camera_to_world(world_to_camera(pts, c2w), c2w), pts, atol=1e-5, rtol=0)
    torch.testing.assert_close(invert_rigid(c2w) @ c2w, torch.eye(4), atol=1e-6, rtol=0)
    # The target is straight ahead (+z) in the camera frame.
    ahead = world_to_camera(torch.zeros(1, 3), c2w)[0]
    torch.testing.assert_close(ahead / ahead.norm(), torch.tensor([0.0, 0.0, 1.0]), atol=1e-6, rtol=0)
    bad = c2w.clone()
    bad[0, 3] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        validate_c2w(bad)
    with pytest.raises(ValueError, match="shape"):
        validate_c2w(torch.eye(3))
    with pytest.raises(ValueError, match="orthonormal"):
        validate_c2w(torch.diag(torch.tensor([2.0, 1.0, 1.0, 1.0])))


def test_cubemap_faces_are_proper_rotations_covering_all_axes():
    rot = cubemap_rotations(dtype=torch.float64)
    torch.testing.assert_close(rot @ rot.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(6, 3, 3))
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(6, dtype=torch.float64))
    forwards = rot[:, :, 2]
    expected = torch.tensor([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=torch.float64)
    torch.testing.assert_close(forwards, expected)
    assert cubemap_face_c2w(torch.eye(4)).shape == (6, 4, 4)


def test_projection_gradients_stay_finite_on_the_vertical_axis():
    """A point on a camera's vertical axis (a pole, or the centre) has no derivative of its longitude; the
    projection gives it zero gradient instead of NaN (which once poisoned a whole training run through
    hidden-space fusion), keeps atan2's values everywhere, and matches autograd of the plain formula off the axis."""
    from cylindersplat.geometry.equirect import angles_to_uv, ray_to_uv

    points = torch.tensor([[0.0, 1.5, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.5, -1.0], [1e-3, 1.0, 2e-3],
                           [1e-7, 1e-7, 1e-7]], dtype=torch.float64, requires_grad=True)
    u, v = ray_to_uv(points, 64, 128)
    (u.sum() + v.sum()).backward()
    assert torch.isfinite(points.grad).all() and (points.grad[:3] == 0).all()
    x, y, z = points.detach().unbind(-1)
    phi, lam = torch.atan2(x, z), torch.atan2(y, torch.sqrt(x * x + z * z))
    plain = points.detach()[3:].clone().requires_grad_(True)
    px, py, pz = plain.unbind(-1)
    pu, pv = angles_to_uv(torch.atan2(px, pz), torch.atan2(py, torch.sqrt(px * px + pz * pz)), 64, 128)
    torch.testing.assert_close(u[3:], pu.detach())
    torch.testing.assert_close(torch.stack((u, v)), torch.stack(angles_to_uv(phi, lam, 64, 128)))
    (pu.sum() + pv.sum()).backward()
    torch.testing.assert_close(points.grad[3:], plain.grad)
