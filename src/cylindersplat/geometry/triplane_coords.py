"""Coordinate systems of a camera's local triplane volume (docs/conventions.md, paper Eq. 3-5).

Each system maps its own coordinates ``q = (q0, q1, q2)`` to camera-frame Cartesian points and
back, gives the Jacobian ``d xyz / d q`` (3x3, column k = derivative w.r.t. ``q_k``), its bounds,
which axes are periodic, and a normalisation of ``q`` to the unit cube ``[0, 1]^3`` used to index
the triplane grids. The triplane's planes are always ``(q0, q1)``, ``(q1, q2)``, ``(q2, q0)``.

* :class:`CylindricalCoords` - ``(r, theta, h)``: ``x = -r sin(theta)``, ``y = h``,
  ``z = -r cos(theta)``; theta = 2 pi u / W runs along the panorama's columns (periodic).
* :class:`SphericalCoords` - ``(rho, theta, lam)``: ``x = -rho cos(lam) sin(theta)``,
  ``y = rho sin(lam)``, ``z = -rho cos(lam) cos(theta)`` (ablation only).
* :class:`CartesianCoords` - ``(x, y, z)`` in an axis-aligned box (ablation only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["TriplaneCoordinates", "CylindricalCoords", "SphericalCoords", "CartesianCoords", "make_coordinates"]

TWO_PI = 2.0 * math.pi


class TriplaneCoordinates:
    """Interface of a triplane coordinate system (see module docstring)."""

    name: str = "abstract"
    axis_names: tuple[str, str, str] = ("q0", "q1", "q2")
    periodic: tuple[bool, bool, bool] = (False, False, False)

    def bounds(self) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
        raise NotImplementedError

    def to_cartesian(self, q: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3"]:
        raise NotImplementedError

    def from_cartesian(self, xyz: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3"]:
        raise NotImplementedError

    def jacobian(self, q: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3 3"]:
        """``J[..., i, k] = d xyz_i / d q_k``."""
        raise NotImplementedError

    # -- generic helpers -------------------------------------------------------------------
    def _lo_hi(self, ref: Tensor) -> tuple[Tensor, Tensor]:
        b = torch.tensor(self.bounds(), dtype=ref.dtype, device=ref.device)
        return b[:, 0], b[:, 1]

    def to_unit(self, q: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3"]:
        """Map coordinates to ``[0, 1]^3`` (periodic axes wrapped into ``[0, 1)``)."""
        lo, hi = self._lo_hi(q)
        t = (q - lo) / (hi - lo)
        wrap = torch.tensor(self.periodic, device=q.device)
        return torch.where(wrap, torch.remainder(t, 1.0), t)

    def from_unit(self, t: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3"]:
        lo, hi = self._lo_hi(t)
        return lo + t * (hi - lo)

    def contains(self, xyz: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch"]:
        """Boolean mask of camera-frame points inside the volume."""
        t = self.to_unit(self.from_cartesian(xyz))
        return ((t >= 0) & (t <= 1)).all(dim=-1)

    def cell_centers(self, resolution: tuple[int, int, int], device=None, dtype=torch.float32) -> Tensor:
        """Centres of an ``n0 x n1 x n2`` grid of cells, shape ``(n0, n1, n2, 3)``, in coordinates."""
        axes = [(torch.arange(n, device=device, dtype=dtype) + 0.5) / n for n in resolution]
        grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)
        return self.from_unit(grid)

    def cell_size(self, resolution: tuple[int, int, int]) -> tuple[float, float, float]:
        return tuple((hi - lo) / n for (lo, hi), n in zip(self.bounds(), resolution))  # type: ignore[return-value]


@dataclass
class CylindricalCoords(TriplaneCoordinates):
    """Cylinder of radius ``radius`` and height ``height`` centred on the camera (paper: 10 m, 10 m)."""

    radius: float = 10.0
    height: float = 10.0
    name = "cylindrical"
    axis_names = ("r", "theta", "h")
    periodic = (False, True, False)

    def bounds(self):
        return ((0.0, self.radius), (0.0, TWO_PI), (-self.height / 2, self.height / 2))

    def to_cartesian(self, q):
        r, theta, h = q.unbind(-1)
        return torch.stack((-r * torch.sin(theta), h, -r * torch.cos(theta)), dim=-1)

    def from_cartesian(self, xyz):
        x, y, z = xyz.unbind(-1)
        r = torch.sqrt(x * x + z * z)
        theta = torch.remainder(torch.atan2(-x, -z), TWO_PI)
        return torch.stack((r, theta, y), dim=-1)

    def jacobian(self, q):
        r, theta, _ = q.unbind(-1)
        s, c = torch.sin(theta), torch.cos(theta)
        zero, one = torch.zeros_like(r), torch.ones_like(r)
        rows = (
            torch.stack((-s, -r * c, zero), dim=-1),
            torch.stack((zero, zero, one), dim=-1),
            torch.stack((-c, r * s, zero), dim=-1),
        )
        return torch.stack(rows, dim=-2)


@dataclass
class SphericalCoords(TriplaneCoordinates):
    """Ball of radius ``radius`` around the camera; ``lam`` is latitude (down positive)."""

    radius: float = 10.0
    name = "spherical"
    axis_names = ("rho", "theta", "lam")
    periodic = (False, True, False)

    def bounds(self):
        return ((0.0, self.radius), (0.0, TWO_PI), (-math.pi / 2, math.pi / 2))

    def to_cartesian(self, q):
        rho, theta, lam = q.unbind(-1)
        cl = torch.cos(lam)
        return torch.stack((-rho * cl * torch.sin(theta), rho * torch.sin(lam), -rho * cl * torch.cos(theta)), dim=-1)

    def from_cartesian(self, xyz):
        x, y, z = xyz.unbind(-1)
        horiz = torch.sqrt(x * x + z * z)
        rho = torch.sqrt(horiz * horiz + y * y)
        theta = torch.remainder(torch.atan2(-x, -z), TWO_PI)
        lam = torch.atan2(y, horiz)
        return torch.stack((rho, theta, lam), dim=-1)

    def jacobian(self, q):
        rho, theta, lam = q.unbind(-1)
        st, ct, sl, cl = torch.sin(theta), torch.cos(theta), torch.sin(lam), torch.cos(lam)
        zero = torch.zeros_like(rho)
        rows = (
            torch.stack((-cl * st, -rho * cl * ct, rho * sl * st), dim=-1),
            torch.stack((sl, zero, rho * cl), dim=-1),
            torch.stack((-cl * ct, rho * cl * st, rho * sl * ct), dim=-1),
        )
        return torch.stack(rows, dim=-2)


@dataclass
class CartesianCoords(TriplaneCoordinates):
    """Axis-aligned box ``[-radius, radius] x [-height/2, height/2] x [-radius, radius]``."""

    radius: float = 10.0
    height: float = 10.0
    name = "cartesian"
    axis_names = ("x", "y", "z")
    periodic = (False, False, False)

    def bounds(self):
        return ((-self.radius, self.radius), (-self.height / 2, self.height / 2), (-self.radius, self.radius))

    def to_cartesian(self, q):
        return q

    def from_cartesian(self, xyz):
        return xyz

    def jacobian(self, q):
        return torch.eye(3, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], 3, 3)


def make_coordinates(kind: str, radius: float = 10.0, height: float = 10.0) -> TriplaneCoordinates:
    """Factory: ``kind`` in ``{"cylindrical", "spherical", "cartesian"}``."""
    if kind == "cylindrical":
        return CylindricalCoords(radius=radius, height=height)
    if kind == "spherical":
        return SphericalCoords(radius=radius)
    if kind == "cartesian":
        return CartesianCoords(radius=radius, height=height)
    raise ValueError(f"unknown triplane coordinate system {kind!r}; expected cylindrical, spherical or cartesian")
