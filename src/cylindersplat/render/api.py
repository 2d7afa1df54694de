"""Backend-agnostic rendering API.

``render_equirect`` validates its inputs, picks a backend and reshapes the result. Backends are
functions ``(gaussians, c2w, height, width, background, settings) -> (rgb, depth, alpha)`` working on
the flattened layout of :func:`.projection.project_equirect_gaussians` (cameras flattened to
``C``); they register themselves in ``_BACKENDS``. ``"torch"`` is the PyTorch reference (CPU and
CUDA); a fast GPU backend registers as ``"triton"`` when its module imports.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.equirect import check_equirect_shape
from ..geometry.poses import validate_c2w
from .projection import RasterSettings, UnsupportedSettings, project_equirect_gaussians
from .rasterize import rasterize
from .triton_backend import triton_available, triton_backend

__all__ = ["RenderOutput", "render_equirect", "available_backends", "register_backend"]


@dataclass
class RenderOutput:
    """rgb ``(*B, V, 3, H, W)``; depth ``(*B, V, H, W)`` radial expected depth (alpha-weighted sum,
    not normalised); alpha ``(*B, V, H, W)`` accumulated opacity."""

    rgb: Tensor
    depth: Tensor
    alpha: Tensor


Backend = Callable[[Gaussians, Tensor, int, int, "Tensor | None", RasterSettings], tuple[Tensor, Tensor, Tensor]]


def _torch_backend(gaussians, c2w, height, width, background, settings):
    proj, _ = project_equirect_gaussians(gaussians, c2w, height, width, settings)
    return rasterize(proj, settings, background)


_BACKENDS: dict[str, Backend] = {"torch": _torch_backend}
if triton_available():
    _BACKENDS["triton"] = triton_backend
_AUTO_ORDER = ("triton", "torch")
_AUTO_DISABLED: set = set()  # fast backends that failed here; "auto" skips them


def register_backend(name: str, fn: Backend) -> None:
    _BACKENDS[name] = fn


def available_backends() -> list[str]:
    return list(_BACKENDS)


def _pick_backend(name: str, device: torch.device) -> Backend:
    if name == "auto":
        for cand in _AUTO_ORDER:
            if cand in _BACKENDS and (cand == "torch" or device.type == "cuda") and _BACKENDS[cand] not in _AUTO_DISABLED:
                return _BACKENDS[cand]
    if name not in _BACKENDS:
        raise ValueError(f"unknown render backend {name!r}; available: {available_backends()} or 'auto'")
    return _BACKENDS[name]


def render_equirect(
    gaussians: Gaussians,
    c2w: Tensor,
    height: int,
    width: int,
    background: Tensor | tuple[float, float, float] | None = None,
    backend: str = "auto",
    settings: RasterSettings | None = None,
) -> RenderOutput:
    """Render equirectangular panoramas of ``gaussians`` from cameras ``c2w``.

    Args:
        gaussians: unbatched (``means (N, 3)``) or batched (``means (B, N, 3)``) Gaussians.
        c2w: camera-to-world poses (OpenCV frame): ``(4, 4)`` or ``(V, 4, 4)`` for unbatched
            Gaussians, ``(B, V, 4, 4)`` for batched ones.
        height, width: panorama size, ``width == 2 * height``.
        background: RGB in [0, 1] added behind the Gaussians (default black); ``(3,)`` or per camera.
        backend: ``"auto"`` (fast GPU backend on CUDA when available, else ``"torch"``), or a name
            from :func:`available_backends`.
        settings: rasterisation constants (:class:`RasterSettings`, 3DGS conventions).

    Returns:
        :class:`RenderOutput` with leading dims ``(*B, V)`` (``V`` omitted for a single ``(4, 4)`` pose).

    Rasterisation follows 3DGS: EWA splatting with the equirect Jacobian (corrected signs, see
    :func:`cylindersplat.geometry.equirect_jacobian`), a 0.3 px^2 dilation, support inside the
    3-sigma ellipse, front-to-back compositing sorted by radial distance, alpha capped at 0.99,
    fragments with alpha < 1/255 skipped, termination once transmittance would drop below 1e-4.
    Gaussians closer than ``settings.near`` (1 cm) are culled. Footprints wrap across the
    longitude seam; near the poles the footprint is bounded (see :mod:`.projection`), so outputs and
    gradients stay finite. Differentiable w.r.t. every Gaussian parameter.
    """
    check_equirect_shape(height, width)
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"gaussians must be a cylindersplat.gaussians.Gaussians, got {type(gaussians).__name__}")
    gaussians.validate()
    validate_c2w(c2w)
    settings = settings or RasterSettings()
    if background is not None:
        background = torch.as_tensor(background, dtype=gaussians.dtype, device=gaussians.device)
        if background.shape[-1] != 3:
            raise ValueError(f"background must be RGB with a last dimension of 3, got {tuple(background.shape)}")
    c2w = c2w.to(device=gaussians.device)
    out_shape = _output_shape(gaussians, c2w)
    fn = _pick_backend(backend, gaussians.device)
    try:
        rgb, depth, alpha = fn(gaussians, c2w, height, width, background, settings)
    except torch.OutOfMemoryError:
        raise  # not a broken backend: the reference would need more memory still
    except UnsupportedSettings:
        if backend != "auto" or fn is _torch_backend:
            raise
        rgb, depth, alpha = _torch_backend(gaussians, c2w, height, width, background, settings)  # this call only
    except Exception as exc:  # noqa: BLE001
        if backend != "auto" or fn is _torch_backend:
            raise
        # The fast backend compiles at first use; if that fails on this machine, keep working.
        _AUTO_DISABLED.add(fn)
        warnings.warn(f"fast render backend failed ({type(exc).__name__}: {exc}); using the PyTorch reference from "
                      "now on (pass backend='triton' to see the error)", RuntimeWarning, stacklevel=2)
        rgb, depth, alpha = _torch_backend(gaussians, c2w, height, width, background, settings)
    return RenderOutput(
        rgb=rgb.reshape(*out_shape, 3, height, width),
        depth=depth.reshape(*out_shape, height, width),
        alpha=alpha.reshape(*out_shape, height, width),
    )


def _output_shape(gaussians: Gaussians, c2w: Tensor) -> tuple[int, ...]:
    if gaussians.batch_shape == ():
        if c2w.ndim not in (2, 3):
            raise ValueError(f"unbatched Gaussians need c2w of shape (4, 4) or (V, 4, 4), got {tuple(c2w.shape)}")
        return tuple(c2w.shape[:-2])
    b = gaussians.batch_shape
    if len(b) != 1 or c2w.ndim != 4 or c2w.shape[0] != b[0]:
        raise ValueError(f"Gaussians with batch shape {tuple(b)} need c2w of shape ({b[0] if b else 'B'}, V, 4, 4), got {tuple(c2w.shape)}")
    return tuple(c2w.shape[:2])
