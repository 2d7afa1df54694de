"""Procedural solid textures and simple view-independent shading.

Textures are *solid* (functions of the 3-D world point), so every view sees the same surface
colour: the multi-view consistency a Gaussian-splatting model needs. Each material mixes two
palette colours with a pattern and multiplies a fine fractal value-noise for high-frequency detail.
Patterns on planar faces ignore the coordinate along the face normal (it is constant there).

Shading is Lambertian under one directional light plus ambient and a sky-dome term
(up-facing surfaces brighter); it does not depend on the viewing direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["Material", "Sky", "Lighting", "PATTERNS", "value_noise", "fbm", "shade_hits", "sky_colour"]

PATTERNS = ("plain", "checker", "stripes", "tiles", "noise")


@dataclass(frozen=True)
class Material:
    pattern: str  # one of PATTERNS
    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    scale: float = 0.5  # pattern period in metres
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)  # stripes
    phase: tuple[float, float, float] = (0.0, 0.0, 0.0)
    detail: float = 0.25  # amplitude of the fine noise (relative brightness)
    detail_scale: float = 0.05  # its finest period in metres

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"unknown pattern {self.pattern!r}; choose from {PATTERNS}")


@dataclass(frozen=True)
class Sky:
    """Vertical colour gradient for rays that hit nothing (depth 0 there)."""

    horizon: tuple[float, float, float] = (0.85, 0.88, 0.92)
    zenith: tuple[float, float, float] = (0.25, 0.45, 0.85)


@dataclass(frozen=True)
class Lighting:
    direction: tuple[float, float, float] = (0.4, -1.0, 0.3)  # towards the light; -y is up
    ambient: float = 0.35
    diffuse: float = 0.5
    dome: float = 0.2


def value_noise(points: Tensor, table: Tensor) -> Tensor:
    """Trilinear value noise in ``[0, 1]`` at ``points`` ``(N, 3)`` (lattice units) from a periodic
    random ``table`` ``(S, S, S)``; smoothstep-interpolated so it has no lattice creases."""
    size = table.shape[0]
    base = torch.floor(points)
    frac = points - base
    frac = frac * frac * (3.0 - 2.0 * frac)
    idx = base.long() % size
    out = torch.zeros(points.shape[0], dtype=points.dtype, device=points.device)
    flat = table.reshape(-1)
    for dx in (0, 1):
        wx = frac[:, 0] if dx else 1.0 - frac[:, 0]
        ix = (idx[:, 0] + dx) % size
        for dy in (0, 1):
            wy = frac[:, 1] if dy else 1.0 - frac[:, 1]
            iy = (idx[:, 1] + dy) % size
            for dz in (0, 1):
                wz = frac[:, 2] if dz else 1.0 - frac[:, 2]
                iz = (idx[:, 2] + dz) % size
                out = out + wx * wy * wz * flat[(ix * size + iy) * size + iz]
    return out


def fbm(points: Tensor, table: Tensor, octaves: int = 3) -> Tensor:
    """Fractal sum of :func:`value_noise` octaves (each half the period, half the amplitude), in [0, 1]."""
    total, amp, norm = 0.0, 1.0, 0.0
    for k in range(octaves):
        # Irrational-ish offsets decorrelate the octaves.
        total = total + amp * value_noise(points * (2.0**k) + 17.3 * k, table)
        norm += amp
        amp *= 0.5
    return total / norm


def _pattern(mat: Material, p: Tensor, normal: Tensor, table: Tensor) -> Tensor:
    """Mixing weight in ``[0, 1]`` between ``color_a`` and ``color_b`` for points ``p`` ``(N, 3)``."""
    q = (p + torch.tensor(mat.phase, dtype=p.dtype)) / mat.scale
    tangent = normal.abs() < 0.9  # axes that vary across the surface
    if mat.pattern == "plain":
        return torch.zeros(p.shape[0], dtype=p.dtype)
    if mat.pattern == "checker":
        cells = (torch.floor(q) * tangent).sum(-1)
        return torch.remainder(cells, 2.0)
    if mat.pattern == "stripes":
        d = torch.tensor(mat.direction, dtype=p.dtype)
        return (torch.sin(2 * math.pi * (q * d).sum(-1)) > 0).to(p.dtype)
    if mat.pattern == "tiles":
        dist_to_line = torch.minimum(q - torch.floor(q), torch.ceil(q) - q)
        return ((dist_to_line < 0.06) & tangent).any(-1).to(p.dtype)
    return fbm(q * 2.0, table, octaves=3)  # "noise": marble-like blotches


def shade_hits(
    points: Tensor, normals: Tensor, material_ids: Tensor, materials: list[Material], table: Tensor,
    lighting: Lighting = Lighting(),
) -> Tensor:
    """RGB ``(N, 3)`` of surface points ``(N, 3)`` with unit normals facing the viewer."""
    rgb = torch.zeros_like(points)
    for index in torch.unique(material_ids).tolist():
        sel = material_ids == index
        mat = materials[index]
        p, n = points[sel], normals[sel]
        t = _pattern(mat, p, n, table)[:, None]
        a, b = torch.tensor(mat.color_a), torch.tensor(mat.color_b)
        albedo = a + (b - a) * t
        detail = fbm(p / mat.detail_scale, table, octaves=2) - 0.5
        rgb[sel] = albedo * (1.0 + 2.0 * mat.detail * detail)[:, None]
    light = torch.nn.functional.normalize(torch.tensor(lighting.direction, dtype=points.dtype), dim=0)
    lambert = (normals @ light).clamp(min=0.0)
    dome = 0.5 * (1.0 - normals[:, 1])  # 1 for up-facing (n_y = -1), 0 for down-facing
    shade = lighting.ambient + lighting.diffuse * lambert + lighting.dome * dome
    return (rgb * shade[:, None]).clamp(0.0, 1.0)


def sky_colour(directions: Tensor, sky: Sky) -> Tensor:
    """Sky RGB ``(N, 3)`` for unit ray directions ``(N, 3)`` (gradient in elevation)."""
    up = (-directions[:, 1]).clamp(0.0, 1.0).sqrt()[:, None]
    h, z = torch.tensor(sky.horizon), torch.tensor(sky.zenith)
    return h + (z - h) * up
