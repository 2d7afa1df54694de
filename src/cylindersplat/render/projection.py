"""EWA projection of 3D Gaussians into equirectangular and pinhole images.

Both projections produce a :class:`ProjectedGaussians` (one row per visible Gaussian-camera
pair), which the rasterizer (:mod:`.rasterize`) turns into pixels. The 2D covariance is the EWA
linearisation ``Sigma_2d = J W Sigma_3d W^T J^T + dilation * I`` with ``J`` the projection's
Jacobian at the mean. It is computed in float64 (cheap: one row per Gaussian) because near the
poles its entries span many orders of magnitude.

Safeguards (equirect), documented so the fast backend can match them:

* Gaussians with radial distance ``< near`` are culled (no contribution, zero gradient).
* ``rho = sqrt(x^2 + z^2)`` is bounded below by ``pole_eps * r`` inside the Jacobian, so a
  Gaussian on the pole axis gets a finite (very wide in ``u``) footprint; at the pole itself
  ``u`` is taken as ``W / 2``.
* The 2D standard deviation along ``u`` is capped at ``W / 6`` (3 sigma = half the panorama), so a
  footprint never reaches around the sphere onto itself and stays continuous across the seam; the
  ``v`` standard deviation is capped at ``2 H``. Capping scales the covariance row/column, which
  keeps it positive definite.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.equirect import equirect_jacobian, ray_to_uv
from ..geometry.rotations import quaternion_to_matrix
from .covariance import eval_sh

__all__ = ["ProjectedGaussians", "RasterSettings", "UnsupportedSettings", "project_equirect_gaussians", "project_pinhole_gaussians"]


class UnsupportedSettings(ValueError):
    """A render backend cannot honour these settings (e.g. a tile size); ``backend="auto"`` uses the reference."""


@dataclass(frozen=True)
class RasterSettings:
    """Constants shared by every backend (3DGS conventions unless stated)."""

    near: float = 0.01  # metres: closer Gaussians are culled
    dilation: float = 0.3  # px^2 added to the 2D covariance (anti-aliasing low-pass)
    sigma_extent: float = 3.0  # support: the sigma_extent-sigma ellipse of the 2D Gaussian
    alpha_max: float = 0.99
    alpha_min: float = 1.0 / 255.0
    transmittance_min: float = 1e-4
    pole_eps: float = 1e-3  # rho >= pole_eps * r inside the equirect Jacobian
    tile_size: int = 16

    def __post_init__(self) -> None:
        """Refuse settings no backend can honour (one-line :class:`~cylindersplat.errors.InputError`)."""
        from ..errors import InputError

        def number(name: str, ok: bool, rule: str) -> None:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not ok:
                raise InputError(f"RasterSettings.{name} must be {rule}, got {value!r}")

        number("near", isinstance(self.near, (int, float)) and self.near > 0, "> 0 metres (e.g. 0.01)")
        number("dilation", isinstance(self.dilation, (int, float)) and self.dilation >= 0, ">= 0 px^2 (e.g. 0.3)")
        number("sigma_extent", isinstance(self.sigma_extent, (int, float)) and self.sigma_extent > 0, "> 0 (e.g. 3)")
        number("alpha_max", isinstance(self.alpha_max, (int, float)) and 0 < self.alpha_max <= 1, "in (0, 1] (e.g. 0.99)")
        number("alpha_min", isinstance(self.alpha_min, (int, float)) and 0 <= self.alpha_min < self.alpha_max,
               "in [0, alpha_max) (e.g. 1/255)")
        number("transmittance_min", isinstance(self.transmittance_min, (int, float))
               and 0 <= self.transmittance_min < 1, "in [0, 1) (e.g. 1e-4)")
        number("pole_eps", isinstance(self.pole_eps, (int, float)) and 0 < self.pole_eps < 1, "in (0, 1) (e.g. 1e-3)")
        if isinstance(self.tile_size, bool) or not isinstance(self.tile_size, int) or self.tile_size < 1:
            raise InputError(f"RasterSettings.tile_size must be an integer >= 1 (e.g. 16), got {self.tile_size!r}")


@dataclass
class ProjectedGaussians:
    """Visible (Gaussian, camera) pairs, flattened over cameras.

    camera:   (M,)   index of the camera (0 .. num_cameras - 1)
    uv:       (M, 2) projected mean in pixels
    conic:    (M, 3) inverse 2D covariance entries (A, B, C): power = -(A du^2 + 2 B du dv + C dv^2) / 2
    extent:   (M, 2) half-widths of the support's bounding box in u and v (pixels)
    depth:    (M,)   radial distance of the mean (sort key and depth output)
    opacity:  (M,)
    color:    (M, 3)
    """

    camera: Tensor
    uv: Tensor
    conic: Tensor
    extent: Tensor
    depth: Tensor
    opacity: Tensor
    color: Tensor
    num_cameras: int
    height: int
    width: int
    wrap_u: bool


def _flatten_cameras(gaussians: Gaussians, c2w: Tensor) -> tuple[Gaussians, Tensor, tuple[int, ...]]:
    """Bring Gaussians to ``(B, N, ...)`` and cameras to ``(B, V, 4, 4)``; returns the output batch shape."""
    if gaussians.batch_shape == ():
        if c2w.ndim == 2:
            out_shape: tuple[int, ...] = ()
            c2w = c2w[None, None]
        elif c2w.ndim == 3:
            out_shape = (c2w.shape[0],)
            c2w = c2w[None]
        else:
            raise ValueError(f"unbatched Gaussians need c2w of shape (4, 4) or (V, 4, 4), got {tuple(c2w.shape)}")
        gaussians = Gaussians(**{k: v[None] for k, v in gaussians.tensors().items()})
    elif len(gaussians.batch_shape) == 1:
        b = gaussians.batch_shape[0]
        if c2w.ndim != 4 or c2w.shape[0] != b:
            raise ValueError(f"Gaussians with batch size {b} need c2w of shape ({b}, V, 4, 4), got {tuple(c2w.shape)}")
        out_shape = tuple(c2w.shape[:2])
    else:
        raise ValueError(f"Gaussians may have at most one batch dimension, got {tuple(gaussians.batch_shape)}")
    return gaussians, c2w, out_shape


def _view_colors(gaussians: Gaussians, c2w: Tensor, camera: Tensor, gauss: Tensor) -> Tensor:
    """RGB ``(M, 3)`` of visible pairs: flat camera index ``camera`` (over ``B*V``) and Gaussian row
    ``gauss`` (over ``B*N``); view-independent for SH degree 0."""
    sh = gaussians.sh.reshape(-1, *gaussians.sh.shape[-2:])
    if sh.shape[-2] == 1:
        return eval_sh(sh.index_select(0, gauss), None)
    means = gaussians.means.reshape(-1, 3).index_select(0, gauss)
    origins = c2w[..., :3, 3].reshape(-1, 3).to(means.dtype).index_select(0, camera)
    dirs = means - origins
    dirs = dirs / torch.linalg.vector_norm(dirs, dim=-1, keepdim=True).clamp_min(1e-12)
    return eval_sh(sh.index_select(0, gauss), dirs)


def _cov2d_entries(jac_cam: Tensor, rot_c2w: Tensor, scales: Tensor, quats: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Entries ``(a, b, c)`` of ``Sigma_2d = J W Sigma_3d W^T J^T`` (before dilation), ``(B, V, N)`` each.

    With ``Sigma_3d = M M^T`` and ``M = R_q diag(s)``, ``Sigma_2d = (T M)(T M)^T`` where
    ``T = J W`` (``W = R_c2w^T``, world -> camera): two 2x3 products per pair instead of 3x3 chains,
    written elementwise so a GPU runs a few fused passes rather than batched tiny matrix products,
    and positive semi-definite by construction.

    jac_cam ``(B, V, N, 2, 3)``; rot_c2w ``(B, V, 3, 3)``; scales ``(B, N, 3)``; quats ``(B, N, 4)``.
    """
    # T[i, j] = sum_k J[i, k] W[k, j] = sum_k J[i, k] R[j, k]
    t = (jac_cam[..., :, None, :] * rot_c2w[:, :, None, None, :, :]).sum(-1)  # (B, V, N, 2, 3)
    m = quaternion_to_matrix(quats) * scales[..., None, :]  # (B, N, 3, 3)
    tm = (t[..., :, :, None] * m[:, None, :, None, :, :]).sum(-2)  # (B, V, N, 2, 3)
    row_u, row_v = tm[..., 0, :], tm[..., 1, :]
    return (row_u * row_u).sum(-1), (row_u * row_v).sum(-1), (row_v * row_v).sum(-1)


def _dense_tail(
    cov2d: tuple[Tensor, Tensor, Tensor],
    uv: Tensor,
    depth: Tensor,
    valid: Tensor,
    opacities: Tensor,
    settings: RasterSettings,
    max_std: tuple[float, float],
    height: int,
    width: int,
    wrap_u: bool,
) -> tuple[Tensor, Tensor]:
    """Shared tail: dilation, std caps, conic, extents, culling (all ``(B, V, N, ...)``).

    Returns ``geo (B, V, N, 8)`` = ``[u, v, conic A, B, C, extent u, extent v, depth]`` and ``valid``."""
    a, b, c = cov2d
    a, c = a + settings.dilation, c + settings.dilation
    # Cap the standard deviations by scaling rows/columns (keeps the matrix positive definite).
    fu = torch.clamp(max_std[0] ** 2 / a, max=1.0)
    fv = torch.clamp(max_std[1] ** 2 / c, max=1.0)
    a, b, c = a * fu, b * torch.sqrt(fu * fv), c * fv
    det = (a * c - b * b).clamp_min(1e-30)
    extent_u = settings.sigma_extent * torch.sqrt(a)
    extent_v = settings.sigma_extent * torch.sqrt(c)
    u, v = uv
    valid = valid & (opacities[:, None] >= settings.alpha_min)
    valid = valid & (v - extent_v < height) & (v + extent_v > 0)
    if not wrap_u:
        valid = valid & (u - extent_u < width) & (u + extent_u > 0)
    geo = torch.stack((u, v, c / det, -b / det, a / det, extent_u, extent_v, depth), dim=-1)
    return geo, valid


def _compact(
    geo: Tensor, valid: Tensor, gaussians: Gaussians, c2w: Tensor, height: int, width: int, wrap_u: bool
) -> ProjectedGaussians:
    """Keep the visible pairs: one index computation and gathers (every ``x[mask]`` would synchronise again)."""
    num_b, num_v, num_n = valid.shape
    index = valid.reshape(-1).nonzero().squeeze(1)
    geo = geo.reshape(-1, 8).index_select(0, index).to(gaussians.dtype)
    gauss = index % num_n + (index // (num_v * num_n)) * num_n  # row of the (B*N) Gaussians
    camera = index // num_n
    return ProjectedGaussians(
        camera=camera,
        uv=geo[:, 0:2],
        conic=geo[:, 2:5],
        extent=geo[:, 5:7],
        depth=geo[:, 7],
        opacity=gaussians.opacities.reshape(-1).index_select(0, gauss),
        color=_view_colors(gaussians, c2w, camera, gauss),
        num_cameras=num_b * num_v,
        height=height,
        width=width,
        wrap_u=wrap_u,
    )


def _equirect_dense(
    means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, c2w: Tensor, height: int, width: int,
    settings: RasterSettings,
) -> tuple[Tensor, Tensor]:
    """Every (camera, Gaussian) pair of ``(B, N)`` Gaussians and ``(B, V)`` cameras -> ``geo, valid`` (:func:`_dense_tail`)."""
    f64 = torch.float64
    rot = c2w[..., :3, :3].to(f64)  # (B, V, 3, 3)
    p = (means.to(f64)[:, None] - c2w[:, :, None, :3, 3].to(f64)) @ rot  # (B, V, N, 3) camera frame
    x, y, z = p.unbind(-1)
    rho2 = x * x + z * z
    r = torch.sqrt((rho2 + y * y).clamp_min(1e-30))
    valid = r > settings.near

    u, v = ray_to_uv(p, height, width)  # finite gradients on the pole axis

    r_safe = torch.where(valid, r, torch.ones_like(r))
    p_safe = torch.where(valid[..., None], p, torch.ones_like(p))
    jac = equirect_jacobian(p_safe, height, width, min_rho=settings.pole_eps * r_safe)  # (B, V, N, 2, 3)
    cov2d = _cov2d_entries(jac, rot, scales.to(f64), quats.to(f64))
    return _dense_tail(cov2d, (u, v), r, valid, opacities, settings, (width / 6.0, 2.0 * height), height, width, True)


def _pinhole_dense(
    means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, c2w: Tensor, intrinsics: Tensor, height: int,
    width: int, settings: RasterSettings,
) -> tuple[Tensor, Tensor]:
    f64 = torch.float64
    rot = c2w[..., :3, :3].to(f64)
    p = (means.to(f64)[:, None] - c2w[:, :, None, :3, 3].to(f64)) @ rot
    x, y, z = p.unbind(-1)
    k = intrinsics.to(f64)
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    valid = z > settings.near
    z_safe = torch.where(valid, z, torch.ones_like(z))
    tx, ty = x / z_safe, y / z_safe
    lim_x, lim_y = 1.3 * (width / 2) / fx, 1.3 * (height / 2) / fy
    valid = valid & ((tx - (cx - width / 2) / fx).abs() <= lim_x) & ((ty - (cy - height / 2) / fy).abs() <= lim_y)
    zero = torch.zeros_like(z)
    jac = torch.stack(
        (
            torch.stack((fx / z_safe, zero, -fx * x / z_safe**2), dim=-1),
            torch.stack((zero, fy / z_safe, -fy * y / z_safe**2), dim=-1),
        ),
        dim=-2,
    )
    cov2d = _cov2d_entries(jac, rot, scales.to(f64), quats.to(f64))
    r = torch.linalg.vector_norm(p, dim=-1)
    uv = (fx * tx + cx, fy * ty + cy)
    return _dense_tail(cov2d, uv, r, valid, opacities, settings, (4.0 * width, 4.0 * height), height, width, False)


# torch.compile of the dense math (opt-in): fused kernels forward and backward on a GPU.
_COMPILED: dict = {}
_USE_COMPILED = False


def compile_projection(enabled: bool = True) -> None:
    """Run the per-pair projection math through ``torch.compile`` (fewer, fused GPU kernels, forward and
    backward). The first call per camera model and dtype compiles (seconds); results are identical
    up to floating-point reassociation. Off by default."""
    global _USE_COMPILED
    _USE_COMPILED = bool(enabled)


def _dense(fn):
    if not _USE_COMPILED:
        return fn
    if fn not in _COMPILED:
        _COMPILED[fn] = torch.compile(fn, dynamic=True)
    return _COMPILED[fn]


def project_equirect_gaussians(
    gaussians: Gaussians, c2w: Tensor, height: int, width: int, settings: RasterSettings = RasterSettings()
) -> tuple[ProjectedGaussians, tuple[int, ...]]:
    """Project into equirect cameras. Returns the projection and the output batch shape ``(*B, V)``."""
    gaussians, c2w, out_shape = _flatten_cameras(gaussians, c2w)
    g = gaussians
    geo, valid = _dense(_equirect_dense)(g.means, g.scales, g.rotations, g.opacities, c2w, height, width, settings)
    return _compact(geo, valid, gaussians, c2w, height, width, wrap_u=True), out_shape


def project_pinhole_gaussians(
    gaussians: Gaussians,
    c2w: Tensor,
    intrinsics: Tensor,
    height: int,
    width: int,
    settings: RasterSettings = RasterSettings(),
) -> tuple[ProjectedGaussians, tuple[int, ...]]:
    """Project into pinhole cameras (``intrinsics`` 3x3, shared). Depth output is radial distance.

    Gaussians are culled when ``z <= near`` or when their mean lies outside a guard band of 1.3x the
    field of view (as 3DGS does, to keep the linearisation sane); the sort key is the radial
    distance so that direct and cubemap renders composite in the same order.
    """
    gaussians, c2w, out_shape = _flatten_cameras(gaussians, c2w)
    g = gaussians
    geo, valid = _dense(_pinhole_dense)(g.means, g.scales, g.rotations, g.opacities, c2w, intrinsics, height, width,
                                        settings)
    return _compact(geo, valid, gaussians, c2w, height, width, wrap_u=False), out_shape
