"""Triplane data layout, point scattering and periodic sampling (coordinate-system agnostic).

A triplane over coordinates ``q = (q0, q1, q2)`` with grid ``(n0, n1, n2)`` is a list of three
channels-last planes ``[P01 (N, n0, n1, C), P12 (N, n1, n2, C), P20 (N, n2, n0, C)]``; for the
cylinder ``(r, theta, h)`` these are the paper's ``F_r-theta``, ``F_theta-z`` and ``F_z-r``.
Positions are given as *unit coordinates* ``t = coords.to_unit(q)`` in ``[0, 1]^3``; cell ``j``
of an axis with ``n`` cells covers ``[j/n, (j+1)/n)``. Periodic axes (``theta``) wrap in every
operation here: scattering (``to_unit`` already wraps), bilinear sampling (neighbours taken modulo
``n``), and resampling between resolutions.
"""

from __future__ import annotations

import math

import torch
from jaxtyping import Bool, Float
from torch import Tensor

from ..geometry import TriplaneCoordinates, world_to_camera
from .sampling import bilinear_sample

__all__ = [
    "PLANE_AXES",
    "plane_shape",
    "encode_unit_coordinates",
    "cell_center_units",
    "scatter_mean_to_planes",
    "scatter_points_to_triplanes",
    "sample_plane",
    "sample_triplane",
    "resample_plane",
    "resample_planes",
    "grid_features",
]

PLANE_AXES = ((0, 1), (1, 2), (2, 0))


def plane_shape(grid: tuple[int, int, int], k: int) -> tuple[int, int]:
    a, b = PLANE_AXES[k]
    return grid[a], grid[b]


def encode_unit_coordinates(unit: Float[Tensor, "*B 3"], periodic: tuple[bool, bool, bool]) -> Float[Tensor, "*B 6"]:
    """Position code of unit coordinates: ``(sin, cos)(2 pi t)`` on periodic axes (seam-free),
    ``(2t - 1, 0)`` otherwise."""
    parts = []
    for axis, wraps in enumerate(periodic):
        t = unit[..., axis]
        if wraps:
            parts += [torch.sin(2 * math.pi * t), torch.cos(2 * math.pi * t)]
        else:
            parts += [2 * t - 1, torch.zeros_like(t)]
    return torch.stack(parts, dim=-1)


def cell_center_units(resolution: tuple[int, ...], device=None, dtype=torch.float32) -> list[Tensor]:
    """Unit coordinates of the cell centres along each axis."""
    return [(torch.arange(n, device=device, dtype=dtype) + 0.5) / n for n in resolution]


def scatter_mean_to_planes(
    unit: Float[Tensor, "N P 3"],
    features: Float[Tensor, "N P C"],
    inside: Bool[Tensor, "N P"],
    grid: tuple[int, int, int],
) -> tuple[list[Tensor], list[Tensor]]:
    """Average the features of the points inside the volume into every plane cell.

    Returns ``(means, counts)``: per plane ``(N, n_a, n_b, C)`` (zero where empty) and
    ``(N, n_a, n_b)`` point counts.
    """
    n, p, c = features.shape
    cells = [(unit[..., axis] * size).floor().long().clamp(0, size - 1) for axis, size in enumerate(grid)]
    means, counts = [], []
    for k, (a, b) in enumerate(PLANE_AXES):
        na, nb = grid[a], grid[b]
        flat = cells[a] * nb + cells[b] + torch.arange(n, device=unit.device)[:, None] * (na * nb)
        dump = n * na * nb  # outside points land in one extra cell that is dropped
        index = torch.where(inside, flat, torch.full_like(flat, dump)).reshape(-1)
        sums = features.new_zeros(dump + 1, c).index_add_(0, index, features.reshape(-1, c))
        count = features.new_zeros(dump + 1).index_add_(0, index, features.new_ones(n * p))
        count = count[:dump].view(n, na, nb)
        means.append(sums[:dump].view(n, na, nb, c) / count.clamp_min(1)[..., None])
        counts.append(count)
    return means, counts


def scatter_points_to_triplanes(
    points_world: Float[Tensor, "B V P 3"],
    point_features: Float[Tensor, "B V P C"],
    c2w: Float[Tensor, "B V 4 4"],
    coords: TriplaneCoordinates,
    grid: tuple[int, int, int],
    strategy: str = "shared",
) -> tuple[list[Tensor], list[Tensor]]:
    """Initial plane features of every triplane (paper Sec. 3.2 and App. B).

    ``c2w`` holds the triplanes' frames ``(B, T, 4, 4)``: the ``V`` cameras for per-camera
    triplanes (``T = V``), or any other frames, e.g. the single central frame (``T = 1``) of the
    ``placement="central"`` ablation.

    * ``"shared"``: triplane ``t`` averages the points of *all* views that fall inside its
      volume (expressed in frame ``t``) - for static scenes;
    * ``"isolated"``: triplane ``t`` uses only view ``t``'s own points - for dynamic scenes
      (needs ``T = V``).

    Returns per plane ``(B*T, n_a, n_b, C)`` means and ``(B*T, n_a, n_b)`` counts, triplanes
    ordered like the frames.
    """
    if strategy not in ("shared", "isolated"):
        raise ValueError(f"unknown triplane initialisation {strategy!r}; expected 'shared' or 'isolated'")
    b, v, p, c = point_features.shape
    targets = c2w.shape[1]
    if strategy == "isolated" and targets != v:
        raise ValueError(f"isolated initialisation needs one triplane per view ({v}), got {targets} frames")
    per_target = []
    for t in range(targets):  # loop over targets: avoids a T-fold copy of the (large) feature cloud
        sources = slice(None) if strategy == "shared" else slice(t, t + 1)
        pts = points_world[:, sources].reshape(b, -1, 3)
        feats = point_features[:, sources].reshape(b, -1, c)
        unit = coords.to_unit(coords.from_cartesian(world_to_camera(pts, c2w[:, t])))
        inside = ((unit >= 0) & (unit <= 1)).all(dim=-1)
        per_target.append(scatter_mean_to_planes(unit, feats, inside, grid))
    means = [torch.stack([m[k] for m, _ in per_target], dim=1).flatten(0, 1) for k in range(3)]
    counts = [torch.stack([n[k] for _, n in per_target], dim=1).flatten(0, 1) for k in range(3)]
    return means, counts


def sample_plane(
    plane: Float[Tensor, "N A B C"],
    unit_a: Float[Tensor, "N P"],
    unit_b: Float[Tensor, "N P"],
    periodic_a: bool,
    periodic_b: bool,
) -> Float[Tensor, "N P C"]:
    """Bilinear read of a channels-last plane at unit coordinates (wrapping periodic axes)."""
    na, nb = plane.shape[1:3]
    return bilinear_sample(plane.permute(0, 3, 1, 2), unit_b * nb, unit_a * na, wrap_x=periodic_b, wrap_y=periodic_a)


def sample_triplane(
    planes: list[Tensor], unit: Float[Tensor, "N P 3"], periodic: tuple[bool, bool, bool]
) -> Float[Tensor, "N P C"]:
    """Sum of the three planes' bilinear features at arbitrary points."""
    out = 0
    for k, (a, b) in enumerate(PLANE_AXES):
        out = out + sample_plane(planes[k], unit[..., a], unit[..., b], periodic[a], periodic[b])
    return out


def resample_plane(
    plane: Float[Tensor, "N A B C"], shape: tuple[int, int], periodic_a: bool, periodic_b: bool
) -> Tensor:
    """One plane resampled to ``shape`` (bilinear at the new cell centres; seam-aware)."""
    if tuple(plane.shape[1:3]) == tuple(shape):
        return plane
    ca, cb = cell_center_units(shape, device=plane.device, dtype=plane.dtype)
    ua, ub = torch.meshgrid(ca, cb, indexing="ij")
    n = plane.shape[0]
    out = sample_plane(plane, ua.reshape(1, -1).expand(n, -1), ub.reshape(1, -1).expand(n, -1), periodic_a, periodic_b)
    return out.view(n, *shape, -1)


def resample_planes(
    planes: list[Tensor], grid: tuple[int, int, int], periodic: tuple[bool, bool, bool]
) -> list[Tensor]:
    """All three planes resampled to another ``grid``."""
    return [
        resample_plane(planes[k], (grid[a], grid[b]), periodic[a], periodic[b]) for k, (a, b) in enumerate(PLANE_AXES)
    ]


def grid_features(planes: list[Tensor]) -> Float[Tensor, "N n0 n1 n2 C"]:
    """``f(i, j, k) = P01[i, j] + P12[j, k] + P20[k, i]`` at every grid cell (paper Sec. 3.2.3)."""
    p01, p12, p20 = planes
    return p01[:, :, :, None] + p12[:, None] + p20.permute(0, 2, 1, 3)[:, :, None]
