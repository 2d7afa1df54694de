"""Heads that turn features into Gaussian parameters, and the volume branch's geometry transform.

* :class:`PixelGaussianHead` - one Gaussian per pixel, centred on the refined depth along the ray.
* :class:`VolumeGaussianHead` - one Gaussian per triplane grid cell, with *local* (coordinate
  system) offsets and scales bounded by the cell (paper Sec. 3.2.3).
* :func:`local_to_cartesian_scales` - paper Eq. 4 (``S' = |J| S_local``, the default), the exact
  first-order push-forward ``Sigma = J diag(S^2) J^T``, or (ablation) ``"cartesian"``: the head's
  scales already are Cartesian std-devs in metres (bounded per cell by
  :func:`cell_cartesian_extent`) and pass through unchanged.

Rotation frames (the paper only says "predicted in the global Cartesian frame"): every head
predicts its quaternion in the frame where its scales are axis-aligned - the camera frame for
pixel Gaussians and for Eq. 4 volume Gaussians (``|J| S`` is axis-aligned in the camera frame),
the cell frame ``(e_q0, e_q1, e_q2)`` for the exact transform - and the result is composed with
the camera's rotation to give the world quaternion. With an identity pose this is exactly the
paper's choice; with a rotated camera it keeps the prediction consistent with the scales.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from ..geometry import TriplaneCoordinates, equirect_rays
from ..geometry.rotations import matrix_to_quaternion, quaternion_multiply

__all__ = [
    "IDENTITY_QUATERNION",
    "PixelGaussianHead",
    "VolumeGaussianHead",
    "local_to_cartesian_scales",
    "cell_cartesian_extent",
    "cell_frame",
    "SCALE_TRANSFORMS",
    "surface_footprints",
]

SCALE_TRANSFORMS = ("paper", "exact", "cartesian")

IDENTITY_QUATERNION = (1.0, 0.0, 0.0, 0.0)


def _unit_quaternion(raw: Tensor) -> Tensor:
    # biased towards identity so that an untrained head gives well-defined frames
    bias = raw.new_tensor(IDENTITY_QUATERNION)
    return F.normalize(raw + bias, dim=-1)


def _bounded(raw: Tensor, low: Tensor | float, high: Tensor | float) -> Tensor:
    return low + (high - low) * torch.sigmoid(raw)


SURFACE_STRETCH_MAX = 4.0  # a surface footprint is at most this many frontal footprints long (depth edges, grazing)
SURFACE_THICKNESS = 0.1  # its std-dev along the normal, in frontal footprints


def surface_footprints(
    depth: Float[Tensor, "N H W"], footprint_px: float
) -> tuple[Float[Tensor, "N HW 3"], Float[Tensor, "N HW 4"]]:
    """Camera-frame scales and rotations of flat Gaussians lying on the surface each pixel sees: the pixel's own
    patch of that surface (``footprint="surface"``).

    The patch is spanned by the surface steps to the next pixel along the row and the column: of the steps to the
    two neighbours on each axis, the shorter one (at a depth edge, the neighbour on the pixel's own surface; columns
    wrap around the seam, rows are one-sided at the poles). Its std-devs are ``footprint_px`` times their lengths
    (the second made orthogonal to the first), each at most :data:`SURFACE_STRETCH_MAX` frontal footprints
    (``depth x pi / H x footprint_px``), so a pixel between two edges gives no needle; the thickness along the
    normal is :data:`SURFACE_THICKNESS` of a frontal footprint. Seen from another viewpoint the patch stays closed
    where an isotropic ball per pixel leaves cracks (slanted floors and walls)."""
    n, h, w = depth.shape
    points = equirect_rays(h, w, device=depth.device, dtype=depth.dtype) * depth[..., None]  # (N, H, W, 3)

    def shorter(forward: Tensor, backward: Tensor) -> Tensor:
        keep = forward.norm(dim=-1, keepdim=True) <= backward.norm(dim=-1, keepdim=True)
        return torch.where(keep, forward, backward)

    along_row = shorter(points.roll(-1, dims=2) - points, points - points.roll(1, dims=2))
    step = points[:, 1:] - points[:, :-1]  # from row i to row i + 1; the first and last rows have one neighbour
    along_col = shorter(torch.cat((step, step[:, -1:]), dim=1), torch.cat((step[:, :1], step), dim=1))
    frontal = (depth * (math.pi / h))[..., None]
    e1 = F.normalize(along_row, dim=-1, eps=1e-12)
    second = along_col - (along_col * e1).sum(-1, keepdim=True) * e1
    e2 = F.normalize(second, dim=-1, eps=1e-12)
    e3 = torch.cross(e1, e2, dim=-1)
    length1 = along_row.norm(dim=-1, keepdim=True).clamp(frontal * 1e-3, SURFACE_STRETCH_MAX * frontal)
    length2 = second.norm(dim=-1, keepdim=True).clamp(frontal * 1e-3, SURFACE_STRETCH_MAX * frontal)
    scales = torch.cat((length1, length2, SURFACE_THICKNESS * frontal), dim=-1) * footprint_px
    frame = torch.stack((e1, e2, e3), dim=-1)  # columns: the Gaussian's axes in the camera frame
    return scales.reshape(n, h * w, 3), matrix_to_quaternion(frame).reshape(n, h * w, 4)


class PixelGaussianHead(nn.Module):
    """Per-pixel MLP (1x1 convs) on ``[F_pano, rgb]`` -> scale, rotation, opacity, colour.

    * scale: std-dev = refined depth x angular pixel size (pi / H) x factor in ``scale_range``
      (``footprint="pixel"``: x ``footprint_px``, isotropic, no rotation; ``"surface"``: flat on the pixel's
      patch of the surface, :func:`surface_footprints`);
    * rotation: unit quaternion in the camera frame;
    * opacity: sigmoid (``opacity="opaque"``: 1);
    * colour: the input pixel colour corrected in logit space (starts at the image itself).
    """

    NUM_OUTPUTS = 3 + 4 + 1 + 3

    def __init__(self, feature_dim: int, hidden: int, scale_range: tuple[float, float], footprint: str = "learned",
                 footprint_px: float = 0.35, opacity: str = "learned"):
        super().__init__()
        self.scale_range = scale_range
        self.footprint, self.footprint_px, self.opacity = footprint, footprint_px, opacity
        self.mlp = nn.Sequential(
            nn.Conv2d(feature_dim + 3, hidden, 1), nn.GELU(), nn.Conv2d(hidden, hidden, 1), nn.GELU(),
            nn.Conv2d(hidden, self.NUM_OUTPUTS, 1),
        )

    def forward(
        self, features: Float[Tensor, "N C H W"], rgb: Float[Tensor, "N 3 H W"], depth: Float[Tensor, "N H W"]
    ) -> dict[str, Tensor]:
        """Returns per-pixel parameters flattened to ``(N, H*W, .)`` (rotations in the camera frame)."""
        n, _, h, w = features.shape
        raw = self.mlp(torch.cat((features, rgb), dim=1)).flatten(2).transpose(1, 2)  # (N, HW, 11)
        raw_scale, raw_rot, raw_opacity, raw_color = raw.split((3, 4, 1, 3), dim=-1)
        footprint = depth.reshape(n, h * w, 1) * (math.pi / h)
        pixel_rgb = rgb.flatten(2).transpose(1, 2).clamp(0.01, 0.99)
        color = torch.sigmoid(torch.logit(pixel_rgb) + raw_color)
        if self.footprint == "pixel":  # the input pixel's own size, isotropic: a splatted warp's footprint
            scales = (footprint * self.footprint_px).expand(n, h * w, 3)
            rotations = _unit_quaternion(torch.zeros_like(raw_rot))
        elif self.footprint == "surface":  # the pixel's own patch of the surface it sees
            scales, rotations = surface_footprints(depth, self.footprint_px)
        else:
            scales = footprint * _bounded(raw_scale, *self.scale_range)
            rotations = _unit_quaternion(raw_rot)
        opacities = torch.sigmoid(raw_opacity.squeeze(-1))
        if self.opacity == "opaque":
            opacities = torch.ones_like(opacities)
        return {"scales": scales, "rotations": rotations, "opacities": opacities, "colors": color}


class VolumeGaussianHead(nn.Module):
    """MLP on summed triplane features -> bounded local offsets/scales, rotation, opacity.

    Offsets are bounded by half a ``cell_size`` (coordinate units). Scales lie in
    ``[min_scale_cells, max_scale_cells] x scale_unit``; ``scale_unit`` defaults to ``cell_size``
    (local scales in coordinate units, theta in radians - Eq. 4 / exact transforms). The
    ``scale_transform="cartesian"`` ablation passes the per-cell metric extent
    (:func:`cell_cartesian_extent`) instead, so the scales come out in metres along camera x, y, z.

    Also emits a ``color_feature`` that the RGB retrieval's colour MLP (or, for ``color="decoded"``,
    the colour decoder) conditions on.
    """

    def __init__(self, channels: int, hidden: int, color_feature_dim: int, max_scale_cells: float,
                 min_scale_cells: float, per_cell: int = 1):
        super().__init__()
        self.max_scale_cells, self.min_scale_cells = max_scale_cells, min_scale_cells
        self.color_feature_dim, self.per_cell = color_feature_dim, per_cell
        self.mlp = nn.Sequential(
            nn.Linear(channels, hidden), nn.GELU(), nn.Linear(hidden, hidden), nn.GELU(),
            nn.Linear(hidden, per_cell * (3 + 3 + 4 + 1 + color_feature_dim)),
        )

    def forward(
        self,
        features: Float[Tensor, "*B C"],
        cell_size: Float[Tensor, "3"],
        scale_unit: Float[Tensor, "*#B 3"] | None = None,
    ) -> dict[str, Tensor]:
        """Parameters ``(*B, per_cell, .)`` of the ``per_cell`` Gaussians of every cell (``scale_unit``
        broadcasts against ``(*B, 1, 3)``)."""
        raw = self.mlp(features).unflatten(-1, (self.per_cell, -1))
        raw_offset, raw_scale, raw_rot, raw_opacity, color_feature = raw.split(
            (3, 3, 4, 1, self.color_feature_dim), dim=-1
        )
        unit = cell_size if scale_unit is None else scale_unit
        return {
            # strictly inside the cell: |offset| < half a cell along every axis
            "offsets": torch.tanh(raw_offset) * (0.5 * cell_size),
            "local_scales": _bounded(raw_scale, self.min_scale_cells * unit, self.max_scale_cells * unit),
            "rotations": _unit_quaternion(raw_rot),
            "opacities": torch.sigmoid(raw_opacity.squeeze(-1)),
            "color_feature": color_feature,
        }


def cell_frame(jacobian: Float[Tensor, "*B 3 3"]) -> tuple[Float[Tensor, "*B 3 3"], Float[Tensor, "*B 3"]]:
    """Split an orthogonal-column Jacobian into a proper rotation and column lengths.

    All three coordinate systems have mutually orthogonal Jacobian columns, so
    ``J = Q diag(lengths)``; a column is negated when needed to make ``det Q = +1`` (a sign flip
    of an axis leaves the covariance unchanged).
    """
    lengths = torch.linalg.vector_norm(jacobian, dim=-2).clamp_min(1e-12)
    frame = jacobian / lengths.unsqueeze(-2)
    flip = torch.where(torch.linalg.det(frame) < 0, -1.0, 1.0).to(frame.dtype)
    frame = torch.cat((frame[..., :2], frame[..., 2:] * flip[..., None, None]), dim=-1)
    return frame, lengths


def cell_cartesian_extent(
    coords: TriplaneCoordinates, q_center: Float[Tensor, "*B 3"], cell_size: Float[Tensor, "3"]
) -> Float[Tensor, "*B 3"]:
    """Metric size of a grid cell along the camera's x, y, z axes (first order): ``|J(q_c)| @ dq``.

    ``J`` is evaluated at the cell centre ``q_c``; its column ``k`` scaled by the cell size
    ``dq_k`` is the cell's metric edge along ``q_k`` (``dr``, ``r dtheta``, ``dh`` for the
    cylinder), and ``|J| @ dq`` sums the absolute projections of these edges on each Cartesian
    axis, i.e. the axis-aligned bounding box of the (linearised) cell. It grows with the radius
    along the tangential direction and is strictly positive for every cell centre of the three
    coordinate systems. The ``scale_transform="cartesian"`` ablation bounds its metric scales by
    ``[min_scale_cells, max_scale_cells]`` times this extent.
    """
    return (coords.jacobian(q_center).abs() @ cell_size.unsqueeze(-1)).squeeze(-1)


def local_to_cartesian_scales(
    coords: TriplaneCoordinates,
    q: Float[Tensor, "*B 3"],
    local_scales: Float[Tensor, "*B 3"],
    local_rotations: Float[Tensor, "*B 4"],
    mode: str = "paper",
) -> tuple[Float[Tensor, "*B 3"], Float[Tensor, "*B 4"]]:
    """Camera-frame scales and rotations of Gaussians defined in a triplane's coordinates.

    * ``"paper"`` (Eq. 4): ``S' = |J| @ S_local`` (matrix-vector product with the element-wise
      absolute Jacobian), axis-aligned with the camera frame, rotated by ``local_rotations``
      (interpreted in the camera frame).
    * ``"exact"``: with ``J = Q diag(lengths)`` (orthogonal columns), scales
      ``lengths * S_local`` and camera-frame rotation ``Q R``, i.e. covariance
      ``Q R diag((lengths S_local)^2) R^T Q^T``: the local rotation ``R`` turns the Gaussian inside
      the metric cell frame. For ``R = I`` this is exactly the first-order push-forward
      ``J diag(S_local^2) J^T`` of an axis-aligned local Gaussian.
    * ``"cartesian"`` (ablation "Ours (Cartesian Scale)", paper appendix "Derivation and Validity
      of Scale Transformation"): ``local_scales`` are taken as they are as Cartesian standard
      deviations in metres along the camera's x, y, z axes, and ``local_rotations`` as the
      camera-frame rotation - no Jacobian, no push-forward; the result does not depend on ``q``
      (the Gaussian's radius or angle). The only geometry the cell contributes is the *bound* the
      head applies before this call (``[min, max]`` x :func:`cell_cartesian_extent` at the cell
      centre), so a Gaussian stays about the size of its cell.
    """
    if mode == "cartesian":
        return local_scales, local_rotations
    jac = coords.jacobian(q)
    if mode == "paper":
        return (jac.abs() @ local_scales.unsqueeze(-1)).squeeze(-1), local_rotations
    if mode == "exact":
        frame, lengths = cell_frame(jac)
        return lengths * local_scales, quaternion_multiply(matrix_to_quaternion(frame), local_rotations)
    raise ValueError(f"unknown scale transform {mode!r}; expected one of {SCALE_TRANSFORMS}")
