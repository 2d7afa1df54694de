"""Camera models: how Gaussians in a camera's frame land on its image.

A camera model is its *pixel map* (:meth:`CameraModel.pixel_map`): camera-frame means -> pixel
coordinates, radial depth, the map's Jacobian and which means are in view. Everything else of the
projection is shared (:mod:`.projection`: one world -> camera step before the pixel map, one EWA
footprint after it), so a camera model is one small function, and render backends (:mod:`.api`)
rasterize projected Gaussians of any camera model (the split gsplat makes).

* :class:`Equirect` - the direct equirectangular projection (longitude wraps across the seam);
* :class:`Pinhole` - OpenCV intrinsics; :func:`cubemap_face` is the 90-degree face of a cube map.
"""

from __future__ import annotations

import numbers
from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.cubemap import cubemap_intrinsics
from ..geometry.equirect import check_equirect_shape, equirect_jacobian, ray_to_uv
from .projection import PixelMap, ProjectedGaussians, RasterSettings, flatten_cameras, project_gaussians

__all__ = ["CameraModel", "Equirect", "Pinhole", "cubemap_face"]


class CameraModel(ABC):
    """What :func:`cylindersplat.render.render` needs of a camera model: its image size, its pixel map
    and three constants."""

    height: int
    width: int
    wrap_u: bool = False  # footprints continue across u = 0 = W (a 360-degree image)
    sees_every_direction: bool = False  # nothing visible at all then means a unit or pose problem

    @property
    @abstractmethod
    def max_std(self) -> tuple[float, float]:
        """Caps of the 2D standard deviations along u and v (pixels), where the linearisation breaks down."""

    @abstractmethod
    def pixel_map(self, points: Tensor, settings: RasterSettings) -> PixelMap:
        """Camera-frame means ``(B, V, N, 3)`` (float64) -> :class:`PixelMap` of shape ``(B, V, N)``."""

    def project(self, gaussians: Gaussians, c2w: Tensor, settings: RasterSettings) -> ProjectedGaussians:
        """Project ``gaussians`` (``(N, ...)`` or ``(B, N, ...)``) into cameras ``c2w`` (``(4, 4)``,
        ``(V, 4, 4)`` or ``(B, V, 4, 4)``); cameras are flattened to ``C`` in the result."""
        gaussians, c2w, _ = flatten_cameras(gaussians, c2w)
        return project_gaussians(gaussians, c2w, self, settings)


def _check_size(camera) -> None:
    """Image sizes must be positive integers (stored as ``int``)."""
    for name in ("height", "width"):
        value = getattr(camera, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value <= 0:
            raise ValueError(f"image {name} must be a positive integer, got {value!r}")
        object.__setattr__(camera, name, int(value))


@dataclass(frozen=True)
class Equirect(CameraModel):
    """Equirectangular panorama of ``height x width`` pixels, ``width == 2 * height``.

    Safeguards: pairs with radial distance ``<= near`` are out of view; inside the Jacobian
    ``rho = sqrt(x^2 + z^2)`` is bounded below by ``pole_eps * r`` (finite, very wide footprints at
    the poles, where ``u`` is taken as ``W / 2``); the u standard deviation is capped at ``W / 6``
    (3 sigma = half the panorama, so a footprint never wraps onto itself), the v one at ``2 H``.
    """

    height: int
    width: int
    wrap_u = True
    sees_every_direction = True

    def __post_init__(self) -> None:
        _check_size(self)
        check_equirect_shape(self.height, self.width)

    @property
    def max_std(self) -> tuple[float, float]:
        return self.width / 6.0, 2.0 * self.height

    def pixel_map(self, points: Tensor, settings: RasterSettings) -> PixelMap:
        x, y, z = points.unbind(-1)
        r = torch.sqrt((x * x + y * y + z * z).clamp_min(1e-30))
        valid = r > settings.near
        u, v = ray_to_uv(points, self.height, self.width)  # finite gradients on the pole axis
        # Culled pairs get harmless operands, so that no NaN reaches the gradients of the others.
        r_safe = torch.where(valid, r, torch.ones_like(r))
        p_safe = torch.where(valid[..., None], points, torch.ones_like(points))
        jac = equirect_jacobian(p_safe, self.height, self.width, min_rho=settings.pole_eps * r_safe)
        return PixelMap(u, v, r, jac, valid)


@dataclass(frozen=True, eq=False)
class Pinhole(CameraModel):
    """Pinhole camera with OpenCV intrinsics ``K`` (3x3, pixel centres at +0.5), shared by all poses.

    Pairs with ``z <= near`` or a mean outside a guard band of 1.3x the field of view are out of
    view (as in 3DGS, to keep the linearisation sane); depth is the radial distance, so that direct
    and cube-map renders composite in the same order.
    """

    intrinsics: Tensor
    height: int
    width: int

    def __post_init__(self) -> None:
        _check_size(self)
        k = torch.as_tensor(self.intrinsics)
        if k.shape != (3, 3):
            raise ValueError(f"intrinsics must be a 3x3 matrix, got {tuple(k.shape)}")
        if not torch.isfinite(k).all() or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ValueError("intrinsics must be finite with positive focal lengths fx, fy")
        object.__setattr__(self, "intrinsics", k)
        # Read once here: a render reads them as Python numbers, which for intrinsics on a GPU would be four waits
        # for the device per render.
        fx, fy, cx, cy = k.detach().double()[[0, 1, 0, 1], [0, 1, 2, 2]].tolist()
        object.__setattr__(self, "_focal_and_centre", (fx, fy, cx, cy))

    @property
    def max_std(self) -> tuple[float, float]:
        return 4.0 * self.width, 4.0 * self.height

    @property
    def focal_and_centre(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` as Python floats (of the intrinsics as they were given)."""
        return self._focal_and_centre

    def pixel_map(self, points: Tensor, settings: RasterSettings) -> PixelMap:
        fx, fy, cx, cy = self.focal_and_centre
        x, y, z = points.unbind(-1)
        valid = z > settings.near
        z_safe = torch.where(valid, z, torch.ones_like(z))
        tx, ty = x / z_safe, y / z_safe
        lim_x, lim_y = 1.3 * (self.width / 2) / fx, 1.3 * (self.height / 2) / fy
        valid = (valid & ((tx - (cx - self.width / 2) / fx).abs() <= lim_x)
                 & ((ty - (cy - self.height / 2) / fy).abs() <= lim_y))
        zero = torch.zeros_like(z)
        jac = torch.stack(
            (
                torch.stack((fx / z_safe, zero, -fx * x / z_safe**2), dim=-1),
                torch.stack((zero, fy / z_safe, -fy * y / z_safe**2), dim=-1),
            ),
            dim=-2,
        )
        return PixelMap(fx * tx + cx, fy * ty + cy, torch.linalg.vector_norm(points, dim=-1), jac, valid)


def cubemap_face(face_size: int, dtype: torch.dtype = torch.float64) -> Pinhole:
    """The 90-degree square pinhole camera of one cube-map face (poses: :func:`cubemap_face_c2w`)."""
    return Pinhole(cubemap_intrinsics(face_size, dtype=dtype), face_size, face_size)
