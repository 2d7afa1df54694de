"""The Triton backend's projection: the reference's three steps (world -> camera, pixel map, EWA
footprint) fused into one float32 kernel per direction (:mod:`.triton_projection_kernels`).

:func:`project_dense_triton` has the signature of :func:`.projection.project_dense` and is registered
as the ``"triton"`` backend's projection (:func:`.api.register_backend`). It handles the
:class:`.cameras.Equirect` and :class:`.cameras.Pinhole` camera models (cube-map faces included);
for any other camera model, or poses that require gradients (the kernel treats poses as
constants), it raises :class:`.projection.UnsupportedSettings` and the reference projects.
Gradients reach means, scales and quaternions (analytic backward, per pair, summed over cameras);
opacities and colours are gathered outside the kernel as in the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .cameras import Equirect, Pinhole
from .projection import RasterSettings, UnsupportedSettings

__all__ = ["project_dense_triton"]

_BLOCK = 128
_MODELS = {Equirect: 0, Pinhole: 1}  # the kernel's MODEL constant per camera model


def _camera_constants(camera) -> tuple[int, tuple[float, float, float, float]]:
    model = _MODELS.get(type(camera))
    if model is None:
        raise UnsupportedSettings(f"the fused projection kernel has no pixel map for {type(camera).__name__}")
    return model, (camera.focal_and_centre if model == 1 else (0.0, 0.0, 0.0, 0.0))


class _FusedProjection(torch.autograd.Function):
    """means, scales ``(B, N, 3)``, quats ``(B, N, 4)``, opacities ``(B, N)`` (float32, contiguous),
    cams ``(B * V, 16)`` (the c2w poses, row-major) -> ``geo (B, V, N, 8)``,
    ``valid (B, V, N)`` bool."""

    @staticmethod
    def forward(ctx, means, scales, quats, opacities, cams, num_views, model, constants):
        from . import triton_projection_kernels as kernels

        num_b, num_n = means.shape[:2]
        num_pairs = num_b * num_views * num_n
        geo = torch.empty(num_b, num_views, num_n, 8, dtype=torch.float32, device=means.device)
        valid = torch.empty(num_b, num_views, num_n, dtype=torch.bool, device=means.device)
        (height, width, fx, fy, cx, cy, near, pole_eps, dilation, sigma_extent, alpha_min, max_u2, max_v2) = constants
        if num_pairs > 0:
            grid = ((num_pairs + _BLOCK - 1) // _BLOCK,)
            kernels.project_forward_kernel[grid](
                means, scales, quats, opacities, cams, geo, valid, num_pairs, num_views, num_n, height, width,
                fx, fy, cx, cy, near, pole_eps, dilation, sigma_extent, alpha_min, max_u2, max_v2,
                MODEL=model, BLOCK=_BLOCK)
        ctx.save_for_backward(means, scales, quats, cams, valid)
        ctx.num_views, ctx.model, ctx.constants = num_views, model, constants
        ctx.mark_non_differentiable(valid)
        ctx.set_materialize_grads(False)  # no zeros made for valid's gradient (a launch in every backward)
        return geo, valid

    @staticmethod
    def backward(ctx, grad_geo, _grad_valid):
        from . import triton_projection_kernels as kernels

        if grad_geo is None:  # the rows reached no loss
            return (None,) * 8
        means, scales, quats, cams, valid = ctx.saved_tensors
        num_b, num_n = means.shape[:2]
        num_views = ctx.num_views
        num_pairs = num_b * num_views * num_n
        (height, width, fx, fy, cx, cy, near, pole_eps, dilation, sigma_extent, _, max_u2, max_v2) = ctx.constants
        grads = [torch.empty(num_b, num_views, num_n, k, dtype=torch.float32, device=means.device) for k in (3, 3, 4)]
        grad_geo, row_stride = _pair_rows(grad_geo)
        if num_pairs > 0:
            grid = ((num_pairs + _BLOCK - 1) // _BLOCK,)
            kernels.project_backward_kernel[grid](
                means, scales, quats, cams, valid, grad_geo, *grads, row_stride, num_pairs, num_views,
                num_n, height, width, fx, fy, cx, cy, near, pole_eps, dilation, sigma_extent, max_u2, max_v2,
                MODEL=ctx.model, BLOCK=_BLOCK)
        # Summed over the cameras; with one camera each is already a whole, contiguous gradient (no copy).
        grads = [g[:, 0] if num_views == 1 else g.sum(1) for g in grads]
        return *grads, None, None, None, None, None


def _pair_rows(grad_geo: Tensor) -> tuple[Tensor, int]:
    """``grad_geo (B, V, N, 8)`` as float32 rows one pair apart, and that distance: read in place where its pairs
    are evenly spaced rows of unit column stride (e.g. the first 8 columns of the compositing rows' gradient), else
    a contiguous copy (8)."""
    *lead, _ = grad_geo.shape
    stride = grad_geo.stride(-2) if grad_geo.dim() > 1 else 8
    expected = [stride]
    for size in reversed(lead[1:]):
        expected.insert(0, expected[0] * size)
    if (grad_geo.dtype == torch.float32 and grad_geo.stride(-1) == 1 and stride >= 8
            and all(grad_geo.stride(d) == e or grad_geo.shape[d] == 1 for d, e in enumerate(expected))):
        return grad_geo, stride
    return grad_geo.float().contiguous(), 8


def project_dense_triton(
    means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, c2w: Tensor, camera, settings: RasterSettings
) -> tuple[Tensor, Tensor]:
    """:func:`.projection.project_dense` on the fused kernel: ``geo (B, V, N, 8)`` float32, ``valid (B, V, N)``; the
    rows of invisible pairs are already inert (:attr:`writes_inert_rows`)."""
    if c2w.requires_grad:
        raise UnsupportedSettings("the fused projection kernel treats poses as constants; poses that require "
                                  "gradients are projected by the reference")
    model, (fx, fy, cx, cy) = _camera_constants(camera)
    max_u, max_v = camera.max_std
    constants = (camera.height, camera.width, fx, fy, cx, cy, settings.near, settings.pole_eps, settings.dilation,
                 settings.sigma_extent, settings.alpha_min, max_u * max_u, max_v * max_v)
    num_b, num_v = c2w.shape[:2]
    cams = c2w.reshape(num_b * num_v, 16)  # the kernel reads each 4x4 pose in place (no copy for float32 poses)
    f32 = torch.float32
    return _FusedProjection.apply(means.to(f32).contiguous(), scales.to(f32).contiguous(), quats.to(f32).contiguous(),
                                  opacities.to(f32).contiguous(), cams.to(f32).contiguous(), num_v, model, constants)


# The kernel writes an invisible pair's row inert (projection._INERT_UV), so keeping every pair needs no masking.
project_dense_triton.writes_inert_rows = True
