"""One rendering entry for every camera model and backend.

:func:`render` validates its inputs once, lets the camera model project the Gaussians
(:mod:`.cameras`: equirect, pinhole, cube-map faces) and hands the projected Gaussians to a backend
that rasterizes them. A backend is a function ``(projected, settings, background) -> (rgb, depth,
alpha)`` on the flattened layout of :class:`.projection.ProjectedGaussians` (cameras flattened to
``C``); backends work for every camera model. ``"torch"`` is the PyTorch reference (CPU and CUDA);
``"triton"`` is the fast GPU backend, registered when Triton imports; ``"numba"`` the fast CPU
backend, registered when numba is installed. ``"auto"`` picks the fast backend of the device and
falls back to the reference (with one warning) where it cannot run. :func:`register_backend` adds others.

On the ``"triton"`` backend a render waits for the device once (issue 35): its input checks are queued as device
flags and read with the binning's pair count (:class:`.projection.DeferredValues`), every pair is projected (the
invisible ones inert: no count of the visible ones to read, :data:`.triton_backend.COMPACTION`), and a failed check
is named on the host with the same message as on the other backends, which check at once.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from ..errors import InputError
from ..gaussians import Gaussians
from ..geometry.poses import c2w_problem_flags, validate_c2w
from ..validation import MAX_TRANSLATION_M, camera_too_far, farthest_camera
from .cameras import CameraModel, Equirect
from .numba_backend import numba_available, numba_backend
from .numba_projection import project_dense_numba
from .projection import (
    DeferredValues,
    DenseProjection,
    InputCheckFailed,
    ProjectedGaussians,
    RasterSettings,
    UnsupportedSettings,
    flatten_cameras,
    project_gaussians,
)
from .rasterize import rasterize
from .triton_backend import queue_checks as triton_queue_checks
from .triton_backend import takes_every_pair, triton_available, triton_backend
from .triton_projection import project_dense_triton

__all__ = ["RenderOutput", "render", "render_equirect", "available_backends", "register_backend", "Backend"]


@dataclass
class RenderOutput:
    """rgb ``(*B, V, 3, H, W)``; depth ``(*B, V, H, W)`` radial expected depth (alpha-weighted sum,
    not normalised); alpha ``(*B, V, H, W)`` accumulated opacity."""

    rgb: Tensor
    depth: Tensor
    alpha: Tensor


Backend = Callable[[ProjectedGaussians, RasterSettings, "Tensor | None"], tuple[Tensor, Tensor, Tensor]]
# (gaussians, c2w) -> device flags [any problem, cameras too far], or None: the PyTorch checks this time
QueueChecks = Callable[[Gaussians, Tensor], "list[Tensor] | None"]

_reference_backend: Backend = rasterize
_BACKENDS: dict[str, Backend] = {"torch": _reference_backend}
_PROJECTIONS: dict = {}  # backend -> its own dense projection (projection.project_dense's signature)
_DEFERRING: dict = {}  # backend -> whether it takes every pair this render (it reads the deferred checks)
_QUEUED_CHECKS: dict = {}  # backend -> how it queues the deferred input checks (default: _queue_checks_torch)
_AUTO_ORDER: dict[str, list[str]] = {}  # device type -> fast backends "auto" tries there, in order
_AUTO_DISABLED: set = set()  # fast backends that failed here; "auto" skips them
_WARNED_NO_NUMBA: list[bool] = [False]


def register_backend(name: str, fn: Backend, auto: bool = False, projection: DenseProjection | None = None,
                     devices: tuple[str, ...] = ("cuda",), deferred_checks: Callable[[], bool] | None = None,
                     queue_checks: QueueChecks | None = None) -> None:
    """Make ``fn`` available as ``backend=name``.

    ``fn(projected, settings, background)`` gets :class:`ProjectedGaussians` of any camera model
    and returns ``rgb (C, 3, H, W), depth (C, H, W), alpha (C, H, W)``, differentiable w.r.t. the
    projected tensors. It may raise :class:`UnsupportedSettings` for inputs it cannot honour.
    ``auto=True`` lets ``backend="auto"`` pick it on the device types ``devices`` (default CUDA), before
    those registered earlier.
    ``projection`` (optional) replaces the reference's per-pair projection math for this backend
    (:func:`.projection.project_dense`'s signature); it may raise :class:`UnsupportedSettings` for a
    camera model or input it does not handle, and the reference's is used for that call.
    ``deferred_checks`` (optional) marks a backend that makes one host read, its pair count, through
    :func:`.projection.read_count`: :func:`render` then queues its input checks as device flags that this read
    brings along (:attr:`.projection.ProjectedGaussians.deferred`; a failed one stops the render there with the
    check's own error) instead of reading them first. Called once per render, it says whether the backend takes
    every pair from the projection, the invisible ones inert (no host read of the visible count), or the visible ones.
    ``queue_checks`` (optional, with ``deferred_checks``) queues those checks the backend's way
    (:func:`_queue_checks_torch`'s contract; e.g. one kernel launch), or returns None for PyTorch's (the default).
    """
    if not isinstance(name, str) or not name or name == "auto":
        raise ValueError(f"backend name must be a non-empty string other than 'auto', got {name!r}")
    if not callable(fn):
        raise TypeError(f"backend {name!r} must be callable")
    _BACKENDS[name] = fn
    if projection is not None:
        _PROJECTIONS[fn] = projection
    if deferred_checks is not None:
        _DEFERRING[fn] = deferred_checks
    if queue_checks is not None:
        _QUEUED_CHECKS[fn] = queue_checks
    for device_type in devices if auto else ():
        order = _AUTO_ORDER.setdefault(device_type, [])
        if name not in order:
            order.insert(0, name)


if triton_available():
    register_backend("triton", triton_backend, auto=True, projection=project_dense_triton,
                     deferred_checks=takes_every_pair, queue_checks=triton_queue_checks)
if numba_available():
    register_backend("numba", numba_backend, auto=True, projection=project_dense_numba, devices=("cpu",))


def available_backends() -> list[str]:
    return list(_BACKENDS)


def _pick_backend(name: str, device: torch.device) -> Backend:
    if name == "triton" and device.type != "cuda" and os.environ.get("TRITON_INTERPRET") != "1":
        # Triton compiles for GPUs only (its CPU interpreter, TRITON_INTERPRET=1, is for tests)
        raise InputError(f"backend='triton' needs a CUDA GPU, but the Gaussians are on {device.type}; use "
                         "backend='torch' (or 'auto'), or move the Gaussians to CUDA")
    if name == "numba" and device.type != "cpu":
        raise InputError(f"backend='numba' renders on the CPU, but the Gaussians are on {device.type}; use "
                         "backend='auto' (or 'triton' on CUDA), or move the Gaussians to the CPU")
    if name == "auto":
        for cand in _AUTO_ORDER.get(device.type, []):
            if cand in _BACKENDS and _BACKENDS[cand] not in _AUTO_DISABLED:
                return _BACKENDS[cand]
        if device.type == "cpu" and "numba" not in _BACKENDS and not _WARNED_NO_NUMBA[0]:
            _WARNED_NO_NUMBA[0] = True
            warnings.warn("numba is not installed: CPU renders use the PyTorch reference, many times slower "
                          "(pip install numba)", RuntimeWarning, stacklevel=3)
        return _reference_backend
    if name not in _BACKENDS:
        package = {"triton": "triton", "numba": "numba"}.get(name)
        needs = f" (needs the {package} package: pip install {package})" if package else ""
        raise InputError(f"unknown render backend {name!r}{needs}; "
                         f"available: {', '.join(available_backends())} or auto")
    return _BACKENDS[name]


def _run_fast(fn: Backend, backend: str, fast: Callable, reference: Callable, unsupported_is_final: bool):
    """Run ``fast()``; fall back to ``reference()`` where the fast backend cannot run.

    :class:`UnsupportedSettings` falls back for this call only (under ``"auto"``, or always when
    ``unsupported_is_final`` is False); another error under ``"auto"`` disables the fast backend
    (it compiles at first use, which may fail on this machine) with a warning."""
    try:
        return fast()
    except InputCheckFailed:
        raise  # bad input, not a broken backend: render names the problem
    except (torch.OutOfMemoryError, MemoryError):
        raise  # not a broken backend (RenderMemoryError included): the reference would need more memory still
    except UnsupportedSettings:
        if unsupported_is_final and (backend != "auto" or fn is _reference_backend):
            raise
        return reference()
    except Exception as exc:  # noqa: BLE001
        if backend != "auto" or fn is _reference_backend:
            raise
        _AUTO_DISABLED.add(fn)
        name = next((k for k, v in _BACKENDS.items() if v is fn), None)
        detail = (str(exc).splitlines() or [""])[0][:200]
        see = f" (pass backend={name!r} to see the error)" if name else ""
        warnings.warn(f"fast render backend{f' {name!r}' if name else ''} failed ({type(exc).__name__}: {detail}); "
                      f"using the PyTorch reference from now on{see}", RuntimeWarning, stacklevel=4)
        return reference()


def _project(fn: Backend, backend: str, gaussians: Gaussians, c2w: Tensor, camera: CameraModel,
             settings: RasterSettings, every_pair: bool = False):
    """The backend's own projection where it has one and can take this input, else the reference's
    (a backend's projection that cannot take a camera model or input leaves it to the reference);
    ``every_pair``: :func:`.projection.project_gaussians`'."""
    dense = _PROJECTIONS.get(fn)
    reference = lambda: project_gaussians(gaussians, c2w, camera, settings, every_pair=every_pair)  # noqa: E731
    if dense is None or fn in _AUTO_DISABLED:
        return reference()
    return _run_fast(fn, backend, lambda: project_gaussians(gaussians, c2w, camera, settings, dense, every_pair),
                     reference, unsupported_is_final=False)


def _rasterize(fn: Backend, backend: str, proj: ProjectedGaussians, settings, background):
    """Run a backend; under ``"auto"`` fall back to the reference where the fast one cannot run (or its own
    projection already failed in this call)."""
    if backend == "auto" and fn in _AUTO_DISABLED:
        return _reference_backend(proj, settings, background)
    return _run_fast(fn, backend, lambda: fn(proj, settings, background),
                     lambda: _reference_backend(proj, settings, background), unsupported_is_final=True)


def render(
    gaussians: Gaussians,
    c2w: Tensor,
    camera: CameraModel,
    background: Tensor | tuple[float, float, float] | None = None,
    backend: str = "auto",
    settings: RasterSettings | None = None,
) -> RenderOutput:
    """Render ``gaussians`` from cameras ``c2w`` with a camera model (:mod:`cylindersplat.render.cameras`).

    Args:
        gaussians: unbatched (``means (N, 3)``) or batched (``means (B, N, 3)``) Gaussians.
        c2w: camera-to-world poses (OpenCV frame): ``(4, 4)`` or ``(V, 4, 4)`` for unbatched
            Gaussians, ``(B, V, 4, 4)`` for batched ones.
        camera: e.g. ``Equirect(512, 1024)``, ``Pinhole(K, 480, 640)``, ``cubemap_face(256)``.
        background: RGB in [0, 1] added behind the Gaussians (default black); ``(3,)`` or one per camera.
        backend: ``"auto"`` (the fast backend of the device: ``"triton"`` on CUDA, ``"numba"`` on the CPU,
            else ``"torch"``), or a name from :func:`available_backends`.
        settings: rasterisation constants (:class:`RasterSettings`, 3DGS conventions).

    Returns:
        :class:`RenderOutput` with leading dims ``(*B, V)`` (``V`` omitted for a single ``(4, 4)`` pose).
    """
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"gaussians must be a cylindersplat.gaussians.Gaussians, got {type(gaussians).__name__}")
    if not isinstance(camera, CameraModel):
        raise TypeError(f"camera must be a camera model (cylindersplat.render.cameras), got {type(camera).__name__}")
    # A backend that reads the device once (its pair count) reads the input checks with it; others check now.
    deferred = _defers_checks(backend, gaussians.device)
    if deferred and isinstance(c2w, Tensor):
        c2w = c2w.to(device=gaussians.device)  # once: poses elsewhere (e.g. the CPU) are checked where they are used
    checks = _queue_checks(backend, gaussians, c2w) if deferred else _check_inputs(gaussians, c2w)
    settings = settings or RasterSettings()
    if not isinstance(settings, RasterSettings):
        raise TypeError(f"settings must be a RasterSettings, got {type(settings).__name__}")
    flat_gaussians, flat_c2w, out_shape = flatten_cameras(gaussians, c2w.to(device=gaussians.device))
    num_cameras = math.prod(out_shape)
    if num_cameras == 0:
        raise ValueError(f"c2w holds no cameras (shape {tuple(c2w.shape)}); give at least one 4x4 camera-to-world pose")
    if background is not None:
        background = _background(background, gaussians, out_shape, num_cameras, checks)
    fn = _pick_backend(backend, gaussians.device)
    proj = _project(fn, backend, flat_gaussians, flat_c2w, camera, settings, deferred and _DEFERRING[fn]())
    if checks is None:
        _warn_none_visible(len(proj.camera), gaussians, camera, settings)
    else:
        proj.deferred = _deferred_values(checks, proj)
    try:
        rgb, depth, alpha = _rasterize(fn, backend, proj, settings, background)
        found = None if checks is None else proj.deferred.read()  # read with the pair count (or now: none read)
    except InputCheckFailed:
        found = None  # named below, outside this handler (the error alone, without this one as its context)
    else:
        if found is not None:  # the checks' warnings, as the immediate ones (the far cameras' first)
            _warn_far(c2w, far=found[1] != 0, stacklevel=3)
            if proj.visible is not None:
                _warn_none_visible(found[2], gaussians, camera, settings)
        h, w = camera.height, camera.width
        return RenderOutput(
            rgb=rgb.reshape(*out_shape, 3, h, w), depth=depth.reshape(*out_shape, h, w),
            alpha=alpha.reshape(*out_shape, h, w)
        )
    _check_inputs(gaussians, c2w, background)  # a deferred check failed: today's checks, in order, name it
    raise RuntimeError("a deferred input check of render failed, but checking the inputs again found nothing")


def _defers_checks(backend: str, device: torch.device) -> bool:
    """Whether this render's backend reads the input checks with its pair count (``register_backend``'s
    ``deferred_checks``). A backend that cannot be used is refused later, after the input checks, as before; "auto"
    on the CPU never defers (and is not asked here: it may warn that numba is missing)."""
    if backend == "auto" and device.type == "cpu":
        return False
    try:
        return _pick_backend(backend, device) in _DEFERRING
    except InputError:
        return False


def _check_inputs(gaussians: Gaussians, c2w: Tensor, background: Tensor | None = None) -> None:
    """The input checks that read the device, now: the Gaussians' and poses' values (raise), the cameras' distance
    (warn) and the background's values (raise: ``background`` already has its checked shape)."""
    gaussians.validate()
    validate_c2w(c2w)
    _warn_far(c2w)
    if background is not None:
        _check_background_finite(background)


def _queue_checks(backend: str, gaussians: Gaussians, c2w: Tensor) -> list[Tensor]:
    """The deferring backend's way of queuing the input checks (``register_backend``'s ``queue_checks``), else
    :func:`_queue_checks_torch`."""
    queue = _QUEUED_CHECKS.get(_pick_backend(backend, gaussians.device))
    checks = None if queue is None else queue(gaussians, c2w)
    return _queue_checks_torch(gaussians, c2w) if checks is None else checks


def _queue_checks_torch(gaussians: Gaussians, c2w: Tensor) -> list[Tensor]:
    """:func:`_check_inputs` without waiting for the device: shapes are checked now (the same errors), the values
    queued as device flags ``[any problem, cameras too far]`` (0-dim bool or integer, non-zero where a check fails;
    :func:`_background` adds its own)."""
    return [torch.cat((gaussians.problem_flags(), c2w_problem_flags(c2w))).any(), camera_too_far(c2w)]


def _deferred_values(checks: list[Tensor], proj: ProjectedGaussians) -> DeferredValues:
    """What the backend reads with its pair count: ``[any input problem, cameras too far]`` and, where the
    projection kept every pair, the number visible (joined with the count at its read, not here)."""
    return DeferredValues([checks[0], checks[1]] + ([proj.visible] if proj.visible is not None else []))


def _warn_far(c2w: Tensor, far: bool | None = None, stacklevel: int = 4) -> None:
    """Warn where a camera lies beyond MAX_TRANSLATION_M (``far``: already known, else read now); ``stacklevel``: at
    render's caller from :func:`_check_inputs`."""
    distance = farthest_camera(c2w) if far is None or far else 0.0
    if distance > MAX_TRANSLATION_M:  # float32 positions keep ~1 m / 2^24 of relative precision: splats smear, jitter
        warnings.warn(f"cameras up to {distance:.3g} m from the origin (beyond {MAX_TRANSLATION_M:g} m): float32 "
                      "loses centimetres there and the render is wrong; recentre the scene (subtract a common origin)",
                      RuntimeWarning, stacklevel=stacklevel)


def _warn_none_visible(num_visible: int, gaussians: Gaussians, camera: CameraModel, settings: RasterSettings) -> None:
    if num_visible == 0 and gaussians.means.shape[-2] > 0 and camera.sees_every_direction:
        # A panorama sees every direction: nothing visible means a unit or pose problem, not framing.
        warnings.warn(f"none of the {gaussians.means.shape[-2]:,} Gaussians is visible from these cameras (all closer "
                      f"than settings.near={settings.near} m or transparent); check the scene's scale and the poses",
                      RuntimeWarning, stacklevel=4)


def _background(background, gaussians: Gaussians, out_shape: tuple[int, ...], num_cameras: int,
                checks: list[Tensor] | None) -> Tensor:
    """``background`` as a tensor of the Gaussians' dtype and device, its shape checked; its values checked now
    (``checks`` None) or queued (a flag or-ed into ``checks[0]``). RGB numbers (a tuple or list, as training and
    inference pass them) are checked on the host and made on the device once (:func:`_on_device`)."""
    numbers = _rgb_numbers(background)
    if numbers is not None:
        if not all(math.isfinite(v) for v in numbers):
            raise ValueError(f"background must be finite (RGB in [0, 1]), got {list(numbers)}")
        return _on_device(numbers, gaussians.dtype, gaussians.device)
    try:
        background = torch.as_tensor(background, dtype=gaussians.dtype, device=gaussians.device)
    except (TypeError, ValueError, RuntimeError):
        raise TypeError("background must be RGB numbers in [0, 1] (3 floats or a tensor), got "
                        f"{background!r:.80}") from None
    if background.shape[-1:] != (3,) or background.numel() not in (3, 3 * num_cameras):
        raise ValueError(f"background must be RGB, (3,) or one per camera {(*out_shape, 3)}, got "
                         f"{tuple(background.shape)}")
    if checks is None:
        _check_background_finite(background)
    else:
        checks[0] = checks[0] | ~torch.isfinite(background).all()
    return background


def _rgb_numbers(values) -> tuple[float, float, float] | None:
    """``values`` as three Python floats where it is a flat tuple or list of three numbers (bool excluded), else
    None."""
    if isinstance(values, (tuple, list)) and len(values) == 3 and all(type(v) in (int, float) for v in values):
        return tuple(float(v) for v in values)
    return None


# RGB backgrounds made on a device, by (values, dtype, device): a render per training step would otherwise launch
# four fills and seven checks for three numbers. Read-only (blended under the image, never returned); bounded.
_BACKGROUNDS: dict[tuple, Tensor] = {}
_MAX_BACKGROUNDS = 16


def _on_device(numbers: tuple[float, float, float], dtype: torch.dtype, device: torch.device) -> Tensor:
    """The RGB ``numbers`` as a tensor on ``device``, made once per (numbers, dtype, device). Made by fills: a
    host-to-device copy - ``torch.tensor(..., device=...)`` or ``out[i] = value``, which copies the number from the
    host - waits for the device on CUDA."""
    key = (numbers, dtype, torch.device(device))
    cached = _BACKGROUNDS.get(key)
    if cached is None:
        if len(_BACKGROUNDS) >= _MAX_BACKGROUNDS:
            _BACKGROUNDS.clear()
        if len(set(numbers)) == 1:  # black, white, grey: one fill
            cached = torch.full((len(numbers),), numbers[0], dtype=dtype, device=device)
        else:
            cached = torch.empty(len(numbers), dtype=dtype, device=device)
            for i, value in enumerate(numbers):
                cached[i].fill_(value)
        _BACKGROUNDS[key] = cached
    return cached


def _check_background_finite(background: Tensor) -> None:
    if not torch.isfinite(background).all():
        raise ValueError("background must be finite (RGB in [0, 1]), got "
                         f"{background.tolist() if background.numel() <= 12 else 'NaN/inf values'}")


def render_equirect(
    gaussians: Gaussians,
    c2w: Tensor,
    height: int,
    width: int,
    background: Tensor | tuple[float, float, float] | None = None,
    backend: str = "auto",
    settings: RasterSettings | None = None,
) -> RenderOutput:
    """Render equirectangular panoramas of ``gaussians`` from cameras ``c2w``:
    ``render(gaussians, c2w, Equirect(height, width), ...)``.

    Args:
        gaussians: unbatched (``means (N, 3)``) or batched (``means (B, N, 3)``) Gaussians.
        c2w: camera-to-world poses (OpenCV frame): ``(4, 4)`` or ``(V, 4, 4)`` for unbatched
            Gaussians, ``(B, V, 4, 4)`` for batched ones.
        height, width: panorama size, ``width == 2 * height``.
        background: RGB in [0, 1] added behind the Gaussians (default black); ``(3,)`` or per camera.
        backend: ``"auto"`` (the fast backend of the device: ``"triton"`` on CUDA, ``"numba"`` on the CPU,
            else ``"torch"``), or a name from :func:`available_backends`.
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
    return render(gaussians, c2w, Equirect(height, width), background, backend, settings)
