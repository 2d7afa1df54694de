"""The CPU backend's projection: the reference's three steps (world -> camera, pixel map, EWA footprint)
fused into one float64 numba loop per direction (:mod:`.numba_projection_kernels`).

:func:`project_dense_numba` has the signature of :func:`.projection.project_dense` and is registered as
the ``"numba"`` backend's projection (:func:`.api.register_backend`). It handles the
:class:`.cameras.Equirect` and :class:`.cameras.Pinhole` camera models (cube-map faces included); for
other camera models, or poses or intrinsics that require gradients (the kernels treat them as
constants), it raises :class:`.projection.UnsupportedSettings` and the reference projects. Gradients
reach means, scales and quaternions (analytic backward, summed over cameras); opacities and colours
are gathered outside the kernel as in the reference.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .cameras import Equirect, Pinhole
from .numba_backend import compile_notice
from .projection import RasterSettings, UnsupportedSettings

__all__ = ["project_dense_numba"]

_MODELS = {Equirect: 0, Pinhole: 1}  # the kernels' model number per camera model


def _kernels():
    from . import numba_projection_kernels
    from .numba_backend import _kernels as set_threads

    set_threads()
    return numba_projection_kernels


def _f64(t: Tensor) -> np.ndarray:
    return t.detach().to(torch.float64).contiguous().numpy()


class _NumbaProjection(torch.autograd.Function):
    """means, scales ``(B, N, 3)``, quats ``(B, N, 4)``, opacities ``(B, N)``, cams ``(B * V, 12)``
    -> ``geo (B, V, N, 8)`` float64, ``valid (B, V, N)`` bool."""

    @staticmethod
    def forward(ctx, means, scales, quats, opacities, cams, num_views: int, model: int, consts: np.ndarray):
        with compile_notice("project"):
            geo, valid = _kernels().project_forward(_f64(means), _f64(scales), _f64(quats), _f64(opacities), cams,
                                                    num_views, model, consts)
        ctx.save_for_backward(means, scales, quats)
        ctx.cams, ctx.valid, ctx.num_views, ctx.model, ctx.consts = cams, valid, num_views, model, consts
        visible = torch.from_numpy(valid)
        ctx.mark_non_differentiable(visible)
        return torch.from_numpy(geo), visible

    @staticmethod
    def backward(ctx, grad_geo, _grad_valid):
        means, scales, quats = ctx.saved_tensors
        with compile_notice("project backward"):
            grads = torch.from_numpy(_kernels().project_backward(
                _f64(means), _f64(scales), _f64(quats), ctx.cams, ctx.valid, _f64(grad_geo), ctx.num_views, ctx.model,
                ctx.consts))
        return (grads[..., 0:3].to(means.dtype), grads[..., 3:6].to(scales.dtype), grads[..., 6:10].to(quats.dtype),
                None, None, None, None, None)


def project_dense_numba(
    means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, c2w: Tensor, camera, settings: RasterSettings
) -> tuple[Tensor, Tensor]:
    """:func:`.projection.project_dense` on the CPU kernels: ``geo (B, V, N, 8)`` float64, ``valid (B, V, N)``."""
    model = _MODELS.get(type(camera))
    if model is None:
        raise UnsupportedSettings(f"the numba projection has no pixel map for {type(camera).__name__}")
    if means.device.type != "cpu":
        raise UnsupportedSettings(f"the numba projection runs on the CPU, not on {means.device.type}")
    if c2w.requires_grad or (model == 1 and camera.intrinsics.requires_grad):
        raise UnsupportedSettings("the numba projection treats cameras as constants; cameras that require "
                                  "gradients are projected by the reference")
    fx, fy, cx, cy = camera.focal_and_centre if model == 1 else (0.0, 0.0, 0.0, 0.0)
    max_u, max_v = camera.max_std
    consts = np.array([camera.height, camera.width, fx, fy, cx, cy, settings.near, settings.pole_eps,
                       settings.dilation, settings.sigma_extent, settings.alpha_min, max_u * max_u, max_v * max_v],
                      dtype=np.float64)
    num_b, num_v = c2w.shape[:2]
    cams = torch.cat((c2w[..., :3, :3].reshape(num_b * num_v, 9), c2w[..., :3, 3].reshape(num_b * num_v, 3)), -1)
    return _NumbaProjection.apply(means, scales, quats, opacities, _f64(cams), num_v, model, consts)
