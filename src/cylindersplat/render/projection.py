"""EWA projection of 3D Gaussians into the images of any camera model (the PyTorch reference).

Three steps, the arrangement gsplat uses:

1. **world -> camera**, shared by every camera model (:func:`to_camera_frame`): camera-frame means
   ``p = W (mu - t)`` and the camera-frame covariance factor ``W M`` (``Sigma = M M^T``,
   ``M = R(q) diag(s)``, ``W = R_c2w^T``);
2. **the camera model's pixel map** (:mod:`.cameras`, ``camera.pixel_map``): pixel mean, radial
   depth, the map's Jacobian ``J`` at the mean and which pairs are in view;
3. **the EWA footprint**, shared again (:func:`ewa_footprint`): ``Sigma_2d = J W Sigma W^T J^T +
   dilation * I`` with the camera model's standard-deviation caps, its inverse (the conic) and the
   support's extent.

The result is a :class:`ProjectedGaussians` (one row per visible Gaussian-camera pair), which the
rasterizer (:mod:`.rasterize`) turns into pixels. The reference computes in float64 (cheap: one row
per pair) because near the poles the entries span many orders of magnitude; the fast backend's
fused kernel (:mod:`.triton_projection`) does the same steps in float32 with the safeguards below.

Safeguards of the equirect camera model (:class:`.cameras.Equirect` applies the first two in its pixel
map, :func:`ewa_footprint` the caps), documented so the fast backend can match them:

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
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.rotations import quaternion_to_matrix
from .covariance import eval_sh

__all__ = ["ProjectedGaussians", "RasterSettings", "UnsupportedSettings", "PixelMap", "flatten_cameras",
           "DeferredValues", "InputCheckFailed", "read_count", "RecordedRead", "recording_reads",
           "is_recording",
           "to_camera_frame",
           "ewa_footprint", "project_dense", "project_gaussians", "compile_projection"]


class UnsupportedSettings(ValueError):
    """A render backend cannot honour these settings (e.g. a tile size); ``backend="auto"`` uses the reference."""


MIN_FOOTPRINT_DET = 1e-12  # px^4: a 2-D covariance of smaller determinant (std-devs multiplying to < 1e-6 px^2)


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
        number("alpha_max", isinstance(self.alpha_max, (int, float)) and 0 < self.alpha_max <= 1,
               "in (0, 1] (e.g. 0.99)")
        number("alpha_min", isinstance(self.alpha_min, (int, float)) and 0 <= self.alpha_min < self.alpha_max,
               "in [0, alpha_max) (e.g. 1/255)")
        number("transmittance_min", isinstance(self.transmittance_min, (int, float))
               and 0 <= self.transmittance_min < 1, "in [0, 1) (e.g. 1e-4)")
        number("pole_eps", isinstance(self.pole_eps, (int, float)) and 0 < self.pole_eps < 1, "in (0, 1) (e.g. 1e-3)")
        if isinstance(self.tile_size, bool) or not isinstance(self.tile_size, int) or self.tile_size < 1:
            raise InputError(f"RasterSettings.tile_size must be an integer >= 1 (e.g. 16), got {self.tile_size!r}")


class InputCheckFailed(Exception):
    """A deferred input check (:class:`DeferredValues`) failed: the render stops and checks its inputs on the host,
    which raises the check's own error. Not a ``ValueError``: no backend fallback catches it."""


class DeferredValues:
    """Device-side values a render reads together with its one host read (the backend's pair count) instead of on
    their own (issue 35): one-element integer or bool tensors, ``values[0]`` the flag of the input checks that stop
    the render (any non-zero: :class:`InputCheckFailed` at the read), the rest read for the caller (:attr:`host`).
    They are joined only at the read, with the count: one concatenation, one copy. While reads are recorded
    (:func:`recording_reads`), nothing is read: the joined values stay on the device (:class:`RecordedRead`)."""

    def __init__(self, values: list[Tensor]):
        self.values = [v.reshape(1) for v in values]
        self.host: list[int] | None = None
        self.recorded = False

    def joined_with(self, count: Tensor) -> Tensor:
        """``(1 + len(values),)`` int64 on the device: ``count`` then :attr:`values` (the one copy's source)."""
        return torch.cat((count.reshape(1).long(), *self.values))  # (cat promotes the flags to int64)

    def read_with(self, count: Tensor) -> int:
        """The value of ``count`` (a one-element integer device tensor), read in one copy with :attr:`values`."""
        count_value, *self.host = self.joined_with(count).tolist()
        self._stop_on_failed_checks()
        return count_value

    def read(self) -> list[int] | None:
        """:attr:`values` on the host: read now where no backend read them with its pair count; None where they were
        recorded for a later read (:func:`recording_reads`)."""
        if self.recorded:
            return None
        if self.host is None:
            if _RECORDS:  # no backend read: the values alone are recorded
                _RECORDS[-1].note(self.joined_with(torch.zeros(1, dtype=torch.long, device=self.values[0].device)))
                self.recorded = True
                return None
            self.host = torch.cat(self.values).long().tolist()
        self._stop_on_failed_checks()
        return self.host

    def _stop_on_failed_checks(self) -> None:
        if self.host[0]:
            raise InputCheckFailed("an input check failed (the render checks its inputs on the host to name it)")


@dataclass
class RecordedRead:
    """A render's one host read, recorded instead of made (:func:`recording_reads`; for a render captured as a CUDA
    graph, which cannot wait for the device: :mod:`.graphs`).

    values:   ``(1 + k,)`` int64 on the device, written by the render's work: the pair count, then the render's
              deferred values (:class:`DeferredValues`: the input checks' flag, the cameras-too-far flag and, where
              the projection kept every pair, the number visible); None before the render reads
    capacity: the pair buffers' size the render was made with (the count must not exceed it)"""

    values: Tensor | None = None
    capacity: int | None = None

    def note(self, values: Tensor, capacity: int | None = None) -> None:
        if self.values is not None:
            raise RuntimeError("a recorded render read the device twice; a recorded render may read it once")
        self.values, self.capacity = values, capacity


_RECORDS: list[RecordedRead] = []  # the innermost recording_reads() last


@contextmanager
def recording_reads():
    """Within: a render's one host read is not made but recorded (:class:`RecordedRead`, yielded), and the render
    goes on as if its pairs fit their buffers and its checks passed: the caller reads the values once the work has
    run, and redoes the render where they say otherwise. Only a backend that sizes nothing by the read can be
    recorded (the Triton backend's lean forward); another raises."""
    record = RecordedRead()
    _RECORDS.append(record)
    try:
        yield record
    finally:
        _RECORDS.remove(record)


def is_recording() -> bool:
    """Whether reads are recorded now (:func:`recording_reads`): a recorded read's value is not the count."""
    return bool(_RECORDS)


def read_count(proj: "ProjectedGaussians", count: Tensor, capacity: int | None = None) -> int:
    """A backend's one host read: the value of ``count`` (one element, on the device), with the render's deferred
    values (:attr:`ProjectedGaussians.deferred`) in the same copy where it has some. ``capacity``: the size of the
    buffers the count must fit, where the backend sized them before this read; only such a read can be recorded
    (:func:`recording_reads`: then 0 is returned and nothing is read)."""
    if _RECORDS:
        if capacity is None:
            raise RuntimeError("this render sizes its buffers by its pair count, which a recorded render (a CUDA graph "
                               "capture) cannot read: record the Triton backend's lean forward")
        deferred = proj.deferred
        _RECORDS[-1].note(count.reshape(1).long() if deferred is None else deferred.joined_with(count), capacity)
        if deferred is not None:
            deferred.recorded = True
        return 0
    return int(count) if proj.deferred is None else proj.deferred.read_with(count)


@dataclass
class ProjectedGaussians:
    """(Gaussian, camera) pairs, flattened over cameras: the visible ones, or every pair with the invisible ones
    inert (outside the image with no extent: they meet no tile), where ``visible`` is given.

    camera:   (M,)   index of the camera (0 .. num_cameras - 1)
    gaussian: (M,)   row of the Gaussian in the flattened ``(B * N)`` Gaussians
    uv:       (M, 2) projected mean in pixels
    conic:    (M, 3) inverse 2D covariance entries (A, B, C): power = -(A du^2 + 2 B du dv + C dv^2) / 2
    extent:   (M, 2) half-widths of the support's bounding box in u and v (pixels)
    depth:    (M,)   radial distance of the mean (sort key and depth output)
    opacity:  (M,)
    color:    (M, 3)
    """

    camera: Tensor
    gaussian: Tensor
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
    visible: Tensor | None = None  # every pair's rows: the number of visible pairs (0-dim int64, on the device)
    deferred: DeferredValues | None = None  # read with the backend's pair count (:func:`read_count`)


@dataclass
class PixelMap:
    """A camera model's pixel map at the camera-frame means of ``(B, V, N)`` pairs.

    u, v:     (B, V, N) pixel coordinates of the mean
    depth:    (B, V, N) radial distance of the mean (sort key and depth output)
    jacobian: (B, V, N, 2, 3) d(u, v)/d(x, y, z) at the mean, finite everywhere
    valid:    (B, V, N) bool: in front of the near plane and inside the model's view
    """

    u: Tensor
    v: Tensor
    depth: Tensor
    jacobian: Tensor
    valid: Tensor


def flatten_cameras(gaussians: Gaussians, c2w: Tensor) -> tuple[Gaussians, Tensor, tuple[int, ...]]:
    """Check the shapes once: Gaussians to ``(B, N, ...)``, cameras to ``(B, V, 4, 4)``, and the output
    batch shape ``(*B, V)`` (``V`` omitted for a single ``(4, 4)`` pose)."""
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
            raise ValueError(f"Gaussians with batch shape ({b},) need c2w of shape ({b}, V, 4, 4), got "
                             f"{tuple(c2w.shape)}")
        out_shape = tuple(c2w.shape[:2])
    else:
        raise ValueError(f"Gaussians may have at most one batch dimension, got {tuple(gaussians.batch_shape)}")
    return gaussians, c2w, out_shape


def to_camera_frame(means: Tensor, scales: Tensor, quats: Tensor, c2w: Tensor) -> tuple[Tensor, Tensor]:
    """Step 1 (every camera model): camera-frame means ``p (B, V, N, 3)`` and covariance factors
    ``W M (B, V, N, 3, 3)`` (``Sigma_cam = (W M)(W M)^T``, positive semi-definite by construction).

    means, scales ``(B, N, 3)``; quats ``(B, N, 4)`` (any norm); c2w ``(B, V, 4, 4)``. Float64."""
    f64 = torch.float64
    rot = c2w[..., :3, :3].to(f64)  # (B, V, 3, 3); W = rot^T
    points = (means.to(f64)[:, None] - c2w[:, :, None, :3, 3].to(f64)) @ rot
    m = quaternion_to_matrix(quats.to(f64)) * scales.to(f64)[..., None, :]  # (B, N, 3, 3)
    # (W M)[i, j] = sum_k rot[k, i] M[k, j]
    factor = (rot.transpose(-1, -2)[:, :, None, :, :, None] * m[:, None, :, None, :, :]).sum(-2)
    return points, factor


def ewa_footprint(
    pixels: PixelMap, factor: Tensor, opacities: Tensor, settings: RasterSettings, max_std: tuple[float, float],
    height: int, width: int, wrap_u: bool,
) -> tuple[Tensor, Tensor]:
    """Step 3 (every camera model): ``Sigma_2d = (J W M)(J W M)^T + dilation * I`` with standard
    deviations capped at ``max_std`` (by scaling rows/columns, which keeps it positive definite), its
    inverse, the ``sigma_extent`` bounding box and the culling of pairs outside the image.

    factor ``(B, V, N, 3, 3)``; opacities ``(B, N)``. Returns ``geo (B, V, N, 8)`` =
    ``[u, v, conic A, B, C, extent u, extent v, depth]`` and ``valid (B, V, N)``."""
    t = (pixels.jacobian[..., :, :, None] * factor[..., None, :, :]).sum(-2)  # J (W M): (B, V, N, 2, 3)
    row_u, row_v = t[..., 0, :], t[..., 1, :]
    a = (row_u * row_u).sum(-1) + settings.dilation
    b = (row_u * row_v).sum(-1)
    c = (row_v * row_v).sum(-1) + settings.dilation
    fu = torch.clamp(max_std[0] ** 2 / a, max=1.0)
    fv = torch.clamp(max_std[1] ** 2 / c, max=1.0)
    a, b, c = a * fu, b * torch.sqrt(fu * fv), c * fv
    det = a * c - b * b
    # a footprint of (near) zero area (zero scales with no dilation) draws nothing: culled, not a full tile of conic 0
    degenerate = det <= MIN_FOOTPRINT_DET
    det = det.clamp_min(1e-30)
    extent_u = settings.sigma_extent * torch.sqrt(a)
    extent_v = settings.sigma_extent * torch.sqrt(c)
    u, v = pixels.u, pixels.v
    valid = pixels.valid & (opacities[:, None] >= settings.alpha_min) & ~degenerate
    valid = valid & (v - extent_v < height) & (v + extent_v > 0)
    if not wrap_u:
        valid = valid & (u - extent_u < width) & (u + extent_u > 0)
    geo = torch.stack((u, v, c / det, -b / det, a / det, extent_u, extent_v, pixels.depth), dim=-1)
    return geo, valid


def project_dense(
    means: Tensor, scales: Tensor, quats: Tensor, opacities: Tensor, c2w: Tensor, camera, settings: RasterSettings
) -> tuple[Tensor, Tensor]:
    """Steps 1-3 for every (camera, Gaussian) pair: ``geo (B, V, N, 8)``, ``valid (B, V, N)`` (:func:`ewa_footprint`).

    The reference's dense projection; a fast backend may bring its own with this signature."""
    points, factor = to_camera_frame(means, scales, quats, c2w)
    pixels = camera.pixel_map(points, settings)
    return ewa_footprint(pixels, factor, opacities, settings, camera.max_std, camera.height, camera.width,
                         camera.wrap_u)


def _view_colors(gaussians: Gaussians, c2w: Tensor, camera: Tensor, gauss: Tensor) -> Tensor:
    """RGB ``(M, 3)`` of visible pairs: flat camera index ``camera`` (over ``B*V``) and Gaussian row
    ``gauss`` (over ``B*N``); view-independent for SH degree 0."""
    sh = gaussians.sh.reshape(-1, *gaussians.sh.shape[-2:])
    if sh.shape[-2] == 1:
        return eval_sh(sh.index_select(0, gauss), None)
    means = gaussians.means.reshape(-1, 3).index_select(0, gauss)
    origins = c2w[..., :3, 3].reshape(-1, 3).to(means.dtype).index_select(0, camera)
    return eval_sh(sh.index_select(0, gauss), _view_directions(means, origins))


def _view_directions(means: Tensor, origins: Tensor) -> Tensor:
    """Unit directions camera -> Gaussian (``means - origins``, broadcast)."""
    dirs = means - origins
    return dirs / torch.linalg.vector_norm(dirs, dim=-1, keepdim=True).clamp_min(1e-12)


def _dense_pair_indices(num_b: int, num_v: int, num_n: int, device) -> tuple[Tensor, Tensor]:
    """Camera ``(B * V * N,)`` (over ``B * V``) and Gaussian row (over ``B * N``) of every pair, camera-major;
    contiguous (the binning kernels read them by pointer: one camera's broadcast would be a view of one element)."""
    if num_b * num_v == 1:
        camera = torch.zeros(num_n, dtype=torch.int64, device=device)  # one launch, not a range and its copy
    else:
        camera = torch.arange(num_b * num_v, device=device)[:, None].expand(num_b * num_v, num_n).contiguous().view(-1)
    rows = torch.arange(num_n, device=device)
    if num_b > 1:
        rows = torch.arange(num_b, device=device)[:, None, None] * num_n + rows
    return camera, rows.expand(num_b, num_v, num_n).contiguous().view(-1)


def _dense_view_colors(gaussians: Gaussians, c2w: Tensor, num_b: int, num_v: int, num_n: int) -> Tensor:
    """RGB ``(B * V * N, 3)`` of every pair, camera-major (:func:`_view_colors`' values): degree 0 evaluated once per
    Gaussian and broadcast over the cameras, higher degrees with the directions broadcast (no gathers)."""
    sh = gaussians.sh.reshape(num_b, 1, num_n, *gaussians.sh.shape[-2:])
    if sh.shape[-2] == 1:
        rgb = eval_sh(sh, None)
    else:
        means = gaussians.means.reshape(num_b, 1, num_n, 3)
        origins = c2w[..., :3, 3].reshape(num_b, num_v, 1, 3).to(means.dtype)
        rgb = eval_sh(sh, _view_directions(means, origins))
    return rgb.expand(num_b, num_v, num_n, 3).reshape(-1, 3)


# An invisible pair's row where every pair is kept: u = v = -1 (outside the image: its pixel rows end before row 0),
# the rest (conic, extent, depth) 0. It meets no tile, so no binning counts it and no compositing reads it.
_INERT_UV = -1.0


def _pairs(geo: Tensor, valid: Tensor, gaussians: Gaussians, c2w: Tensor, camera_model,
           every_pair: bool = False, inert_rows: bool = False) -> ProjectedGaussians:
    """The visible pairs (one index computation and gathers: every ``x[mask]`` would synchronise again), or with
    ``every_pair`` all ``B * V * N`` of them, the invisible ones inert (:data:`_INERT_UV`; ``inert_rows``: ``geo``
    holds them so already), so that nothing waits for the device to learn how many are visible."""
    num_b, num_v, num_n = valid.shape
    geo = geo.reshape(-1, 8)
    visible = None
    dense = every_pair  # the pairs are all B * V * N, in order: no gathers
    if every_pair:
        if not inert_rows:
            inert = torch.zeros(8, dtype=geo.dtype, device=geo.device)
            inert[:2] = _INERT_UV  # filled on the device: no host-to-device copy
            geo = torch.where(valid.reshape(-1, 1), geo, inert)
        visible = valid.sum()
    else:
        index = valid.reshape(-1).nonzero().squeeze(1)
        dense = len(index) == len(geo)  # all visible (a panorama's usual case): the index is the identity
        if not dense:
            geo = geo.index_select(0, index)
    geo = geo.to(gaussians.dtype)
    if dense:  # pair (b, v, n) is Gaussian (b, n): broadcasts over the cameras, no gathers (views for one)
        camera, gauss = _dense_pair_indices(num_b, num_v, num_n, valid.device)
        opacity = gaussians.opacities.reshape(num_b, 1, num_n).expand(num_b, num_v, num_n).reshape(-1)
        color = _dense_view_colors(gaussians, c2w, num_b, num_v, num_n)
    else:
        gauss = index % num_n + (index // (num_v * num_n)) * num_n  # row of the (B*N) Gaussians
        camera = index // num_n
        opacity = gaussians.opacities.reshape(-1).index_select(0, gauss)
        color = _view_colors(gaussians, c2w, camera, gauss)
    return ProjectedGaussians(
        camera=camera,
        gaussian=gauss,
        uv=geo[:, 0:2],
        conic=geo[:, 2:5],
        extent=geo[:, 5:7],
        depth=geo[:, 7],
        opacity=opacity,
        color=color,
        num_cameras=num_b * num_v,
        height=camera_model.height,
        width=camera_model.width,
        wrap_u=camera_model.wrap_u,
        visible=visible,
    )


# torch.compile of the dense math (opt-in): fused kernels forward and backward on a GPU.
_COMPILED: dict = {}
_USE_COMPILED = False


def compile_projection(enabled: bool = True) -> None:
    """Run the reference's per-pair projection math through ``torch.compile`` (fewer, fused GPU
    kernels, forward and backward). The first call per camera model and dtype compiles (seconds);
    results are identical up to floating-point reassociation. Off by default."""
    global _USE_COMPILED
    _USE_COMPILED = bool(enabled)


def _reference_dense():
    if not _USE_COMPILED:
        return project_dense
    if project_dense not in _COMPILED:
        _COMPILED[project_dense] = torch.compile(project_dense, dynamic=True)
    return _COMPILED[project_dense]


DenseProjection = Callable[[Tensor, Tensor, Tensor, Tensor, Tensor, Any, RasterSettings], tuple[Tensor, Tensor]]


def project_gaussians(
    gaussians: Gaussians, c2w: Tensor, camera, settings: RasterSettings, dense: DenseProjection | None = None,
    every_pair: bool = False,
) -> ProjectedGaussians:
    """Project flattened Gaussians ``(B, N, ...)`` into cameras ``(B, V, 4, 4)`` (:func:`flatten_cameras`)
    with a camera model (:mod:`.cameras`); cameras are flattened to ``C = B * V`` in the result.

    ``dense`` replaces the reference's per-pair math (:func:`project_dense`), e.g. by a fused kernel.
    ``every_pair``: keep all ``B * V * N`` pairs, the invisible ones inert (no host synchronisation; for backends
    that bin by tile spans), instead of the visible ones.
    """
    g = gaussians
    geo, valid = (dense or _reference_dense())(g.means, g.scales, g.rotations, g.opacities, c2w, camera, settings)
    return _pairs(geo, valid, gaussians, c2w, camera, every_pair, getattr(dense, "writes_inert_rows", False))
