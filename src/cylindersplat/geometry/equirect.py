"""Equirectangular image <-> ray geometry (docs/conventions.md).

Conventions, shared by every module:

* camera frame is OpenCV: +x right, +y down, +z forward;
* an ``H x W`` panorama (``W = 2H``) has pixel centres at ``u = j + 0.5``, ``v = i + 0.5``;
* longitude ``phi = 2*pi*u/W - pi``, latitude ``lam = pi*v/H - pi/2``;
* unit ray ``d = (cos(lam) sin(phi), sin(lam), cos(lam) cos(phi))``; so the centre column looks
  along +z and the top row looks up (-y);
* inverse: ``phi = atan2(x, z)``, ``lam = atan2(y, sqrt(x^2 + z^2))``.

All functions broadcast over leading dimensions and are differentiable.
"""

from __future__ import annotations

import math

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = [
    "pixel_centers",
    "uv_to_angles",
    "angles_to_uv",
    "uv_to_ray",
    "ray_to_uv",
    "equirect_rays",
    "project_equirect",
    "equirect_jacobian",
    "check_equirect_shape",
]


def check_equirect_shape(height: int, width: int) -> None:
    """Raise a clear error unless ``width == 2 * height`` (both positive)."""
    if height <= 0 or width <= 0:
        raise ValueError(f"panorama size must be positive, got {height}x{width} (HxW)")
    if width != 2 * height:
        raise ValueError(
            f"equirectangular panoramas must have width == 2 * height, got {height}x{width} (HxW)"
        )


def pixel_centers(
    height: int, width: int, device=None, dtype=torch.float32
) -> tuple[Float[Tensor, "H W"], Float[Tensor, "H W"]]:
    """Pixel-centre coordinates ``(u, v)``, each of shape ``(H, W)``."""
    v = torch.arange(height, device=device, dtype=dtype) + 0.5
    u = torch.arange(width, device=device, dtype=dtype) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return uu, vv


def uv_to_angles(u: Tensor, v: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Pixel coordinates -> (longitude phi in [-pi, pi), latitude lam in [-pi/2, pi/2])."""
    phi = 2.0 * math.pi * u / width - math.pi
    lam = math.pi * v / height - math.pi / 2.0
    return phi, lam


def angles_to_uv(phi: Tensor, lam: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """(longitude, latitude) -> continuous pixel coordinates ``(u, v)``."""
    u = width * (phi + math.pi) / (2.0 * math.pi)
    v = height * (lam + math.pi / 2.0) / math.pi
    return u, v


def uv_to_ray(u: Tensor, v: Tensor, height: int, width: int) -> Float[Tensor, "*batch 3"]:
    """Continuous pixel coordinates -> unit ray direction in the camera frame."""
    phi, lam = uv_to_angles(u, v, height, width)
    cos_lam = torch.cos(lam)
    return torch.stack((cos_lam * torch.sin(phi), torch.sin(lam), cos_lam * torch.cos(phi)), dim=-1)


def ray_to_uv(
    directions: Float[Tensor, "*batch 3"], height: int, width: int
) -> tuple[Float[Tensor, "*batch"], Float[Tensor, "*batch"]]:
    """Direction (need not be normalised) -> continuous pixel coordinates ``(u, v)``.

    ``u`` lies in ``[0, W]`` (atan2's branch cut is the seam ``u = 0 = W``).
    """
    x, y, z = directions.unbind(-1)
    rho2 = x * x + z * z
    # On the vertical axis (x = z = 0: a pole, or the camera centre) atan2 and sqrt have no derivative and
    # autograd returns NaN (0 * inf), which poisons every gradient upstream. There the longitude is set
    # to 0 and the latitude to +-90 degrees as constants; safe operands keep the unused branch finite.
    on_axis = rho2 <= _AXIS_EPS * (rho2 + y * y)  # relative: directions need not be normalised
    phi = torch.where(on_axis, 0.0, torch.atan2(torch.where(on_axis, 0.0, x), torch.where(on_axis, 1.0, z)))
    rho = torch.sqrt(torch.where(on_axis, 1.0, rho2))
    pole = torch.atan2(y.detach(), torch.zeros_like(y))  # +-pi/2 (0 at the centre), as atan2(y, 0) gives
    lam = torch.where(on_axis, pole, torch.atan2(y, rho))
    return angles_to_uv(phi, lam, height, width)


_AXIS_EPS = 1e-12  # (angle from the vertical axis)^2 below which a direction counts as on it


def equirect_rays(height: int, width: int, device=None, dtype=torch.float32) -> Float[Tensor, "H W 3"]:
    """Unit ray of every pixel centre, shape ``(H, W, 3)``."""
    u, v = pixel_centers(height, width, device=device, dtype=dtype)
    return uv_to_ray(u, v, height, width)


def project_equirect(
    points_cam: Float[Tensor, "*batch 3"], height: int, width: int
) -> tuple[Float[Tensor, "*batch 2"], Float[Tensor, "*batch"]]:
    """Camera-frame points -> (pixel ``uv``, radial distance)."""
    u, v = ray_to_uv(points_cam, height, width)
    return torch.stack((u, v), dim=-1), torch.linalg.vector_norm(points_cam, dim=-1)


def equirect_jacobian(
    points_cam: Float[Tensor, "*batch 3"], height: int, width: int, min_rho: float | Tensor = 0.0
) -> Float[Tensor, "*batch 2 3"]:
    """Jacobian d(u, v)/d(x, y, z) of the equirect projection at camera-frame points.

    This is the *corrected* Jacobian (docs/conventions.md, "Rendering"): the paper prints d v/d x with the
    wrong sign (``+H/pi * x y / (r^2 rho)``); its d v/d z is right (``tests/test_geometry.py``
    checks every entry against autograd)::

        du/dx =  W/(2 pi) * z / rho^2      du/dy = 0      du/dz = -W/(2 pi) * x / rho^2
        dv/dx = -H/pi * x y / (r^2 rho)    dv/dy = H/pi * rho / r^2
        dv/dz = -H/pi * z y / (r^2 rho)

    with ``rho = sqrt(x^2 + z^2)`` and ``r^2 = x^2 + y^2 + z^2``.  ``min_rho`` (scalar or
    per-point) bounds ``rho`` from below so the map stays finite at the poles; it changes nothing
    for points with ``rho >= min_rho``.
    """
    x, y, z = points_cam.unbind(-1)
    rho2 = x * x + z * z
    if isinstance(min_rho, Tensor) or min_rho > 0:
        rho2 = torch.maximum(rho2, torch.as_tensor(min_rho, dtype=rho2.dtype, device=rho2.device) ** 2)
    rho = torch.sqrt(rho2)
    r2 = rho2 + y * y
    su = width / (2.0 * math.pi)
    sv = height / math.pi
    zero = torch.zeros_like(x)
    row_u = torch.stack((su * z / rho2, zero, -su * x / rho2), dim=-1)
    row_v = torch.stack((-sv * x * y / (r2 * rho), sv * rho / r2, -sv * z * y / (r2 * rho)), dim=-1)
    return torch.stack((row_u, row_v), dim=-2)
