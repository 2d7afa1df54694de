"""Volume branch (paper Sec. 3.2): one local triplane per input camera -> volume Gaussians.

For every input camera ``t`` (all cameras processed in parallel, batch ``B*V``):

1. **Init** (:class:`TriplaneInitializer`): learnable grid embeddings plus a projection of the
   scatter-mean of the pixel branch's feature points inside the camera's volume (``shared``: all
   views' points; ``isolated``: its own only).
2. **Refinement** (:class:`~.triplane_attention.TriplaneRefinementLayer` x ``layers``):
   cross-plane attention (Eq. 1), triplane-to-image attention into the camera's own ``F_pano``
   (Eq. 2), feed-forward.
3. **Decoding**: summed plane features at the ``N_r x N_theta x N_z`` cell centres -> MLP ->
   bounded local offsets and scales, rotation, opacity (:class:`~.gaussian_heads.VolumeGaussianHead`);
   positions by ``coords.to_cartesian`` (Eq. 3); scales by the Jacobian (Eq. 4-5); camera ->
   world with the pose.
4. **Colour** from the input views by the rule ``volume.color`` (Eq. 6 by default;
   :mod:`~.rgb_retrieval`).

The coordinate system (cylindrical / spherical / Cartesian) is a pluggable
:class:`~cylindersplat.geometry.TriplaneCoordinates`; nothing here is specific to the cylinder.

Ablation switches (``VolumeBranchConfig``; paper Table "Ablation Study" and Table "scale_ablation"):

* ``color="decoded"`` - row "Only Cylindrical Volume Branch (w/o RGB)": step 4 replaced by
  :class:`~.rgb_retrieval.DecodedColor` (``sigmoid(MLP(colour feature))``, no image lookup).
* ``placement="central"`` - row "Full (w/o Multi Triplane)" (OmniScene): a single triplane per
  scene in the frame :func:`central_frame` (mean camera centre, first camera's rotation); init
  scatters all views' points into it; its triplane-to-image attention reads every view's
  ``F_pano``; ``G`` Gaussians per scene instead of ``V*G``.
* ``scale_transform="cartesian"`` - row "Ours (Cartesian Scale)": metric scales straight from the
  head, no Jacobian (see :func:`~.gaussian_heads.local_to_cartesian_scales`).
* ``image_query="full"`` - Eq. 2 as printed (queries at the plane resolution).
* ``image_views="all"`` - the released code's triplane-to-image attention: every per-camera triplane
  reads every view's ``F_pano`` (the paper: its own camera's).
* ``gaussians_per_cell=k`` - ``k`` Gaussians decoded per cell (the released configs: 3), each with its
  own offset inside the cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..gaussians import Gaussians
from ..geometry import TriplaneCoordinates, camera_to_world, invert_rigid, make_coordinates, world_to_camera
from ..geometry.rotations import matrix_to_quaternion, quaternion_multiply
from .config import ModelConfig
from .gaussian_heads import VolumeGaussianHead, cell_cartesian_extent, local_to_cartesian_scales
from .rgb_retrieval import build_color_module
from .triplane import grid_features, plane_shape, scatter_points_to_triplanes
from .triplane_attention import TriplaneRefinementLayer

__all__ = ["TriplaneInitializer", "VolumeBranchOutput", "VolumeBranch", "central_frame"]


class TriplaneInitializer(nn.Module):
    def __init__(self, point_feature_dim: int, channels: int, grid: tuple[int, int, int]):
        super().__init__()
        self.grid = grid
        self.embeddings = nn.ParameterList(
            nn.Parameter(torch.randn(*plane_shape(grid, k), channels) * 0.02) for k in range(3)
        )
        self.project = nn.Linear(point_feature_dim, channels)

    def forward(
        self,
        points_world: Float[Tensor, "B V P 3"],
        point_features: Float[Tensor, "B V P C"],
        frames: Float[Tensor, "B T 4 4"],
        coords: TriplaneCoordinates,
        strategy: str,
    ) -> list[Tensor]:
        """Planes ``(B*T, n_a, n_b, C)`` of the triplanes in ``frames`` (triplane-to-world)."""
        means, counts = scatter_points_to_triplanes(points_world, point_features, frames, coords, self.grid, strategy)
        planes = []
        for embedding, mean, count in zip(self.embeddings, means, counts):
            lifted = torch.where(count[..., None] > 0, self.project(mean), 0.0)
            planes.append(embedding + lifted)
        return planes


def central_frame(c2w: Float[Tensor, "B V 4 4"]) -> Float[Tensor, "B 1 4 4"]:
    """Frame of OmniScene's single central triplane (``volume.placement="central"``; paper Table
    "Ablation Study", row "Full (w/o Multi Triplane)"): origin at the mean of the input camera
    centres, axes of the first camera (so with upright panoramas the cylinder axis is vertical,
    and with one view it is that view's camera)."""
    frame = c2w[:, :1].clone()
    frame[..., :3, 3] = c2w[..., :3, 3].mean(dim=1, keepdim=True)
    return frame


@dataclass
class VolumeBranchOutput:
    gaussians: Gaussians  # (B, T*G, ...) world frame, triplane-major order (T = V per camera, 1 central)
    # centres in the frame of the camera whose refined depth checks them in depth-guided fusion:
    # per camera (B, V, G, 3), each triplane's own camera; central (B, 1, G, 3), view ``depth_view``'s
    points_cam: Float[Tensor, "B T G 3"]
    planes: list[Tensor]  # refined planes (B*T, n_a, n_b, C)
    frames: Float[Tensor, "B T 4 4"]  # triplane-to-world transforms
    depth_view: int | None = None  # None: points_cam[:, t] belongs to view t; else all belong to this view


class VolumeBranch(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        vc = cfg.volume
        self.cfg = vc
        self.coords = make_coordinates(vc.coordinates, radius=vc.radius, height=vc.height)
        self.initializer = TriplaneInitializer(cfg.pixel.feature_dim, vc.channels, vc.grid)
        query_grid = vc.grid if vc.image_query == "full" else None
        self.layers = nn.ModuleList(
            TriplaneRefinementLayer(
                vc.channels, cfg.pixel.feature_dim, vc.heads, vc.mlp_ratio, self.coords, vc.image_grid, query_grid
            )
            for _ in range(vc.layers)
        )
        self.head = VolumeGaussianHead(vc.channels, vc.decoder_hidden, vc.color_hidden, vc.max_scale_cells,
                                       vc.min_scale_cells, vc.gaussians_per_cell)
        # the colour rule (volume.color); its attribute name is the one earlier checkpoints' state dicts use
        self._color_name = "color_decoder" if vc.color == "decoded" else "rgb"
        self.add_module(self._color_name, build_color_module(vc))

    @property
    def gaussians_per_camera(self) -> int:
        """Gaussians per triplane (``N_r * N_theta * N_z`` cells x ``gaussians_per_cell``)."""
        n0, n1, n2 = self.cfg.grid
        return n0 * n1 * n2 * self.cfg.gaussians_per_cell

    def num_triplanes(self, views: int) -> int:
        return views if self.cfg.placement == "per_camera" else 1

    def num_gaussians(self, views: int) -> int:
        """Volume Gaussians per scene for ``views`` input views (``V*G`` per camera, ``G`` central)."""
        return self.num_triplanes(views) * self.gaussians_per_camera

    def forward(
        self,
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
        image_features: Float[Tensor, "B V C H W"],
        points_world: Float[Tensor, "B V P 3"],
        point_features: Float[Tensor, "B V P C"],
    ) -> VolumeBranchOutput:
        b = images.shape[0]
        per_camera = self.cfg.placement == "per_camera"
        frames = c2w if per_camera else central_frame(c2w)  # (B, T, 4, 4)
        t = frames.shape[1]
        planes = self.initializer(points_world, point_features, frames, self.coords, self.cfg.init)
        if per_camera and self.cfg.image_views == "all":  # every triplane reads every view's F_pano
            v = c2w.shape[1]
            features = image_features[:, None].expand(-1, v, -1, -1, -1, -1).flatten(0, 1)  # (B*T, V, C, H, W)
            view_from_plane = (invert_rigid(c2w)[:, None] @ c2w[:, :, None]).flatten(0, 1)  # (B*T, V, 4, 4)
        elif per_camera:  # each triplane reads its own camera's F_pano (identity pose)
            features, view_from_plane = image_features.flatten(0, 1), None
        else:  # the central triplane reads every view: central frame -> view camera transforms
            features, view_from_plane = image_features, invert_rigid(c2w) @ frames
        for layer in self.layers:
            planes = layer(planes, features, view_from_plane)

        dtype, device = images.dtype, images.device
        cell = torch.tensor(self.coords.cell_size(self.cfg.grid), dtype=dtype, device=device)
        centers = self.coords.cell_centers(self.cfg.grid, device=device, dtype=dtype).reshape(1, -1, 3)
        scale_unit = None
        if self.cfg.scale_transform == "cartesian":  # metric bounds: the cell's Cartesian extent
            scale_unit = cell_cartesian_extent(self.coords, centers, cell)[..., None, :]
        # (BT, cells, per_cell, .) -> (BT, G, .): a cell's Gaussians side by side
        cell_params = self.head(grid_features(planes).flatten(1, 3), cell, scale_unit)
        params = {k: p.flatten(1, 2) for k, p in cell_params.items()}
        centers = centers.repeat_interleave(self.cfg.gaussians_per_cell, dim=1)
        q = centers + params["offsets"]
        points_plane = self.coords.to_cartesian(q).view(b, t, -1, 3)
        scales, rotations_cam = local_to_cartesian_scales(
            self.coords, q, params["local_scales"], params["rotations"], self.cfg.scale_transform
        )
        camera_rotation = matrix_to_quaternion(frames[..., :3, :3])[:, :, None]  # (B, T, 1, 4)
        rotations = quaternion_multiply(camera_rotation, rotations_cam.view(b, t, -1, 4))
        means = camera_to_world(points_plane, frames).flatten(1, 2)
        color_feature = params["color_feature"].view(b, -1, self.cfg.color_hidden)
        colors = getattr(self, self._color_name)(means, color_feature, images, depth_prior, c2w)
        gaussians = Gaussians.from_rgb(
            means,
            scales.view(b, -1, 3),
            rotations.flatten(1, 2),
            params["opacities"].view(b, -1),
            colors,
        )
        if per_camera:
            points_cam, depth_view = points_plane, None
        else:
            # depth-guided fusion checks the central triplane's Gaussians against view 0's refined
            # depth (the camera whose axes the central frame shares)
            points_cam, depth_view = world_to_camera(means, c2w[:, 0])[:, None], 0
        return VolumeBranchOutput(
            gaussians=gaussians, points_cam=points_cam, planes=planes, frames=frames, depth_view=depth_view
        )
