"""Attention on triplanes: cross-plane (paper Eq. 1) and triplane-to-image (paper Eq. 2).

Triplane-to-image attention queries at ``image_grid`` (default, "coarse") or at the plane's own
resolution (``volume.image_query="full"``, Eq. 2 as printed) and reads either the triplane's own
camera's panorama or, given triplane -> view poses, every input view's (the central triplane of
the ``volume.placement="central"`` ablation, Table "Ablation Study" row "Full (w/o Multi Triplane)").

Both modules are coordinate-system agnostic; they receive the coordinate system object and use
only its ``to_cartesian`` / ``from_unit`` / ``periodic``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from ..geometry import TriplaneCoordinates, project_equirect, transform_points
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
    """Triplane-to-image attention (Eq. 2).

    Query resolution (``query_grid``):

    * coarse (default, ``query_grid=None`` -> ``image_grid``): the planes are resampled to
      ``image_grid`` (seam-aware bilinear), each coarse cell queries, and the update is upsampled
      back to the plane resolution and added (residual).
    * full (``query_grid = grid``, config ``volume.image_query="full"``; Eq. 2 as printed): every
      cell of the plane at its own resolution queries and the update is added directly.

    For a query cell ``(i, j)`` of plane ``(a, b)``, ``N'_c = image_grid[c]`` points at the
    ``image_grid`` cell centres along the orthogonal axis ``c`` are mapped to the triplane's frame
    (``coords.to_cartesian``), projected into the panorama (``project_equirect``) and ``F_pano`` is
    read there (bilinear, wrapping in ``u``). The cell attends to these samples (keys/values =
    F_pano + a code of the sample's triplane coordinates).

    Which panoramas are read (``view_from_plane`` in :meth:`forward`):

    * ``None`` (per-camera triplanes): the triplane's frame *is* its camera's frame (identity pose)
      and only that camera's ``F_pano`` is read - ``M = N'_c`` keys per query.
    * ``(N, V, 4, 4)`` rigid transforms from the triplane's frame to each of ``V`` view cameras'
      frames (the central triplane of ``volume.placement="central"``): the samples are moved into
      every view's frame, projected into that view and read from its ``F_pano``; a query attends to
      all ``V x N'_c`` samples jointly (one softmax). With ``V = 1`` and an identity transform this
      is the same computation as ``None``.
    """

    def __init__(
        self,
        channels: int,
        image_feature_dim: int,
        heads: int,
        coords: TriplaneCoordinates,
        image_grid: tuple[int, int, int],
        query_grid: tuple[int, int, int] | None = None,
    ):
        super().__init__()
        self.heads, self.coords, self.image_grid = heads, coords, image_grid
        self.query_grid = tuple(image_grid) if query_grid is None else tuple(query_grid)
        self.norm = nn.LayerNorm(channels)
        self.q = nn.Linear(channels, channels)
        self.kv_in = nn.Linear(image_feature_dim + 6, channels)
        self.kv = nn.Linear(channels, 2 * channels)
        self.out = nn.Linear(channels, channels)

    def sample_units(self, k: int, device, dtype) -> Float[Tensor, "A B M 3"]:
        """Unit coordinates of the samples of plane ``k``: query cell (i, j) x ``N'_c`` along c."""
        a, b = PLANE_AXES[k]
        c = 3 - a - b
        query = cell_center_units(self.query_grid, device=device, dtype=dtype)
        centers = cell_center_units(self.image_grid, device=device, dtype=dtype)
        grids = torch.meshgrid(query[a], query[b], centers[c], indexing="ij")
        unit = torch.empty(*grids[0].shape, 3, device=device, dtype=dtype)
        unit[..., a], unit[..., b], unit[..., c] = grids
        return unit

    def sample_locations(
        self, k: int, height: int, width: int, device=None, dtype=torch.float32
    ) -> tuple[Tensor, Tensor]:
        """Unit coordinates ``(A, B, M, 3)`` of plane ``k``'s samples and their panorama pixels ``(A, B, M, 2)``
        in the triplane's own camera (identity pose)."""
        unit = self.sample_units(k, device, dtype)
        points = self.coords.to_cartesian(self.coords.from_unit(unit))
        uv, _ = project_equirect(points, height, width)
        return unit, uv

    def _read_views(
        self, unit: Tensor, image_features: Tensor, view_from_plane: Tensor
    ) -> Float[Tensor, "N AB VM Cf"]:
        """``F_pano`` of every view at the samples ``unit`` (A, B, M, 3) of every triplane."""
        n, v, cf, h, w = image_features.shape
        na, nb, m = unit.shape[:3]
        points = self.coords.to_cartesian(self.coords.from_unit(unit)).reshape(1, 1, -1, 3)
        in_views = transform_points(view_from_plane, points)  # (N, V, P, 3)
        uv, _ = project_equirect(in_views, h, w)
        samples = sample_panorama(image_features.reshape(n * v, cf, h, w), uv.reshape(n * v, -1, 2))
        samples = samples.view(n, v, na * nb, m, cf).permute(0, 2, 1, 3, 4)  # (N, AB, V, M, Cf)
        return samples.reshape(n, na * nb, v * m, cf)

    def forward(
        self,
        planes: list[Tensor],
        image_features: Float[Tensor, "N Cf H W"] | Float[Tensor, "N V Cf H W"],
        view_from_plane: Float[Tensor, "N V 4 4"] | None = None,
    ) -> list[Tensor]:
        n = planes[0].shape[0]
        h, w = image_features.shape[-2:]
        if view_from_plane is None:
            if image_features.ndim == 5:
                if image_features.shape[1] != 1:
                    raise ValueError("several views need view_from_plane (the triplane -> view camera transforms)")
                image_features = image_features[:, 0]
        else:
            if image_features.ndim == 4:
                image_features = image_features[:, None]
            if view_from_plane.shape != (n, image_features.shape[1], 4, 4):
                raise ValueError(
                    f"view_from_plane must be {(n, image_features.shape[1], 4, 4)}, got {tuple(view_from_plane.shape)}"
                )
        periodic = self.coords.periodic
        queries = resample_planes(planes, self.query_grid, periodic)  # the planes themselves when full
        updated = []
        for k, (a, b) in enumerate(PLANE_AXES):
            if view_from_plane is None:
                unit, uv = self.sample_locations(k, h, w, image_features.device, image_features.dtype)
                samples = sample_panorama(image_features, uv.reshape(1, -1, 2).expand(n, -1, -1))
                views = 1
            else:
                unit = self.sample_units(k, image_features.device, image_features.dtype)
                samples = self._read_views(unit, image_features, view_from_plane).flatten(1, 2)
                views = image_features.shape[1]
            na, nb, m = unit.shape[:3]
            code = encode_unit_coordinates(unit, periodic).reshape(1, na * nb, 1, m, 6)
            code = code.expand(n, -1, views, -1, -1).reshape(n, -1, 6)
            keys, values = self.kv(self.kv_in(torch.cat((samples, code), dim=-1))).chunk(2, dim=-1)
            # one query per cell, attending to its (V x) M samples
            m = views * m
            q = _split_heads(self.q(self.norm(queries[k])), self.heads).reshape(n * na * nb, 1, self.heads, -1)
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

    def __init__(self, channels, image_feature_dim, heads, mlp_ratio, coords, image_grid, query_grid=None):
        super().__init__()
        self.cross_plane = CrossPlaneAttention(channels, heads)
        self.to_image = TriplaneImageAttention(channels, image_feature_dim, heads, coords, image_grid, query_grid)
        self.mlp = PlaneMlp(channels, mlp_ratio)

    def forward(
        self, planes: list[Tensor], image_features: Tensor, view_from_plane: Tensor | None = None
    ) -> list[Tensor]:
        return self.mlp(self.to_image(self.cross_plane(planes), image_features, view_from_plane))
