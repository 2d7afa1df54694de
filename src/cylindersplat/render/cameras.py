"""Camera models: how Gaussians in a camera's frame land on its image.

A camera model turns Gaussians and camera-to-world poses into :class:`ProjectedGaussians` (pixel
means, conics, extents, radial depths, colours of the visible Gaussian-camera pairs); render
backends (:mod:`.api`) rasterize projected Gaussians of any camera model. This is the seam between
world -> camera projection and rasterization (the split gsplat makes), so a new camera model works
with every backend, and a new backend with every camera model.

* :class:`Equirect` - the direct equirectangular projection (longitude wraps across the seam);
* :class:`Pinhole` - OpenCV intrinsics; :func:`cubemap_face` is the 90-degree face of a cube map.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.cubemap import cubemap_intrinsics
from ..geometry.equirect import check_equirect_shape
from .projection import ProjectedGaussians, RasterSettings, project_equirect_gaussians, project_pinhole_gaussians

__all__ = ["CameraModel", "Equirect", "Pinhole", "cubemap_face"]


@runtime_checkable
class CameraModel(Protocol):
    """What :func:`cylindersplat.render.render` needs of a camera model."""

    height: int
    width: int

    def project(self, gaussians: Gaussians, c2w: Tensor, settings: RasterSettings) -> ProjectedGaussians:
        """Project ``gaussians`` (``(N, ...)`` or ``(B, N, ...)``) into cameras ``c2w`` (``(4, 4)``,
        ``(V, 4, 4)`` or ``(B, V, 4, 4)``); cameras are flattened to ``C`` in the result."""
        ...


def _check_size(camera) -> None:
    """Image sizes must be positive integers (stored as ``int``)."""
    for name in ("height", "width"):
        value = getattr(camera, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value <= 0:
            raise ValueError(f"image {name} must be a positive integer, got {value!r}")
        object.__setattr__(camera, name, int(value))


@dataclass(frozen=True)
class Equirect:
    """Equirectangular panorama of ``height x width`` pixels, ``width == 2 * height``."""

    height: int
    width: int

    def __post_init__(self) -> None:
        _check_size(self)
        check_equirect_shape(self.height, self.width)

    def project(self, gaussians: Gaussians, c2w: Tensor, settings: RasterSettings) -> ProjectedGaussians:
        return project_equirect_gaussians(gaussians, c2w, self.height, self.width, settings)[0]


@dataclass(frozen=True, eq=False)
class Pinhole:
    """Pinhole camera with OpenCV intrinsics ``K`` (3x3, pixel centres at +0.5), shared by all poses."""

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

    def project(self, gaussians: Gaussians, c2w: Tensor, settings: RasterSettings) -> ProjectedGaussians:
        k = self.intrinsics.to(gaussians.device)
        return project_pinhole_gaussians(gaussians, c2w, k, self.height, self.width, settings)[0]


def cubemap_face(face_size: int, dtype: torch.dtype = torch.float64) -> Pinhole:
    """The 90-degree square pinhole camera of one cube-map face (poses: :func:`cubemap_face_c2w`)."""
    return Pinhole(cubemap_intrinsics(face_size, dtype=dtype), face_size, face_size)
