"""Attention on triplanes: cross-plane (paper Eq. 1) and triplane-to-image (paper Eq. 2).

Both modules are coordinate-system agnostic; they receive the coordinate system object and use
only its ``to_cartesian`` / ``from_unit`` / ``periodic``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from ..geometry import TriplaneCoordinates, project_equirect
from .attention import Mlp
from .sampling import sample_panorama
from .triplane import PLANE_AXES, cell_center_units, encode_unit_coordinates, resample_plane, resample_planes

__all__ = ["CrossPlaneAttention", "TriplaneImageAttention", "PlaneMlp", "TriplaneRefinementLayer"]


def _split_heads(x: Tensor, heads: int) -> Tensor:
    return x.unflatten(-1, (heads, x.shape[-1] // heads))


class CrossPlaneAttention(nn.Module):
    """Each cell of plane ``(a, b)`` attends to the ``2 n_c`` features it meets along the orthogonal
    axis ``c``: ``P_bc[j, :]`` and ``P_ca[:, i]`` (Eq. 1), with a residual connection.

    Keys are exact grid entries (the ``N_c`` samples along ``c`` are the plane's own cells), so no
    interpolation - and no seam handling - is needed. All three planes update in parallel from
    the same inputs; weights are shared between the planes (each plane has its own embeddings).
    Implemented with einsums so the ``(cells x 2 n_c)`` key set is never materialised.
    """

    def __init__(self, channels: int, heads: int):
        super().__init__()
        self.heads = heads
        self.norm = nn.LayerNorm(channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.out = nn.Linear(channels, channels)

    def forward(self, planes: list[Tensor]) -> list[Tensor]:
        qkv = [self.qkv(self.norm(p)).chunk(3, dim=-1) for p in planes]
        q, k, v = ([_split_heads(t[i], self.heads) for t in qkv] for i in range(3))  # each (N, A, B, h, d)
        scale = q[0].shape[-1] ** -0.5
        updated = []
        for index in range(3):
            bc, ca = (index + 1) % 3, (index + 2) % 3  # plane (b, c) and plane (c, a)
            s_bc = torch.einsum("nijhd,njmhd->nijhm", q[index], k[bc]) * scale
            s_ca = torch.einsum("nijhd,nmihd->nijhm", q[index], k[ca]) * scale
            weights = torch.softmax(torch.cat((s_bc, s_ca), dim=-1), dim=-1)
            w_bc, w_ca = weights.split((s_bc.shape[-1], s_ca.shape[-1]), dim=-1)
            context = torch.einsum("nijhm,njmhd->nijhd", w_bc, v[bc]) + torch.einsum("nijhm,nmihd->nijhd", w_ca, v[ca])
            updated.append(planes[index] + self.out(context.flatten(-2)))
        return updated


class TriplaneImageAttention(nn.Module):
    """Triplane-to-image attention (Eq. 2) at the coarser ``image_grid`` resolution.

    The planes are resampled to ``image_grid`` (seam-aware bilinear). For each coarse cell of plane
    ``(a, b)``, ``N'_c`` points at the coarse cell centres along the orthogonal axis are mapped to
    the camera frame (``coords.to_cartesian``), projected into this camera's panorama
    (``project_equirect``) and ``F_pano`` is read there (bilinear, wrapping in ``u``). The cell
    attends to these samples (keys/values = F_pano + a code of the sample's position); the update is
    upsampled back to the plane resolution and added (residual).
    """

    def __init__(
        self,
        channels: int,
        image_feature_dim: int,
        heads: int,
        coords: TriplaneCoordinates,
        image_grid: tuple[int, int, int],
    ):
        super().__init__()
        self.heads, self.coords, self.image_grid = heads, coords, image_grid
        self.norm = nn.LayerNorm(channels)
        self.q = nn.Linear(channels, channels)
        self.kv_in = nn.Linear(image_feature_dim + 6, channels)
        self.kv = nn.Linear(channels, 2 * channels)
        self.out = nn.Linear(channels, channels)

    def sample_units(self, k: int, device, dtype) -> Float[Tensor, "A B M 3"]:
        """Unit coordinates of the samples of plane ``k``: coarse cell (i, j) x ``N'_c`` along c."""
        a, b = PLANE_AXES[k]
        c = 3 - a - b
        centers = cell_center_units(self.image_grid, device=device, dtype=dtype)
        grids = torch.meshgrid(centers[a], centers[b], centers[c], indexing="ij")
        unit = torch.empty(*grids[0].shape, 3, device=device, dtype=dtype)
        unit[..., a], unit[..., b], unit[..., c] = grids
        return unit

    def sample_locations(self, k: int, height: int, width: int, device=None, dtype=torch.float32) -> tuple[Tensor, Tensor]:
        """Unit coordinates ``(A, B, M, 3)`` of plane ``k``'s samples and their panorama pixels ``(A, B, M, 2)``."""
        unit = self.sample_units(k, device, dtype)
        points = self.coords.to_cartesian(self.coords.from_unit(unit))
        uv, _ = project_equirect(points, height, width)
        return unit, uv

    def forward(self, planes: list[Tensor], image_features: Float[Tensor, "N Cf H W"]) -> list[Tensor]:
        n = planes[0].shape[0]
        h, w = image_features.shape[-2:]
        periodic = self.coords.periodic
        coarse = resample_planes(planes, self.image_grid, periodic)
        updated = []
        for k, (a, b) in enumerate(PLANE_AXES):
            unit, uv = self.sample_locations(k, h, w, image_features.device, image_features.dtype)
            na, nb, m = unit.shape[:3]
            samples = sample_panorama(image_features, uv.reshape(1, -1, 2).expand(n, -1, -1))
            code = encode_unit_coordinates(unit, periodic).reshape(1, -1, 6).expand(n, -1, -1)
            keys, values = self.kv(self.kv_in(torch.cat((samples, code), dim=-1))).chunk(2, dim=-1)
            # one query per coarse cell, attending to its M samples
            q = _split_heads(self.q(self.norm(coarse[k])), self.heads).reshape(n * na * nb, 1, self.heads, -1)
            keys = _split_heads(keys, self.heads).reshape(n * na * nb, m, self.heads, -1)
            values = _split_heads(values, self.heads).reshape(n * na * nb, m, self.heads, -1)
            context = F.scaled_dot_product_attention(q.transpose(1, 2), keys.transpose(1, 2), values.transpose(1, 2))
            delta = self.out(context.transpose(1, 2).reshape(n, na, nb, -1))
            updated.append(planes[k] + resample_plane(delta, planes[k].shape[1:3], periodic[a], periodic[b]))
        return updated


class PlaneMlp(nn.Module):
    """Position-wise feed-forward update of every plane (shared weights)."""

    def __init__(self, channels: int, ratio: float):
        super().__init__()
        self.norm = nn.LayerNorm(channels)
        self.mlp = Mlp(channels, int(channels * ratio))

    def forward(self, planes: list[Tensor]) -> list[Tensor]:
        return [p + self.mlp(self.norm(p)) for p in planes]


class TriplaneRefinementLayer(nn.Module):
    """Cross-plane attention -> triplane-to-image attention -> feed-forward."""

    def __init__(self, channels, image_feature_dim, heads, mlp_ratio, coords, image_grid):
        super().__init__()
        self.cross_plane = CrossPlaneAttention(channels, heads)
        self.to_image = TriplaneImageAttention(channels, image_feature_dim, heads, coords, image_grid)
        self.mlp = PlaneMlp(channels, mlp_ratio)

    def forward(self, planes: list[Tensor], image_features: Tensor) -> list[Tensor]:
        return self.mlp(self.to_image(self.cross_plane(planes), image_features))
