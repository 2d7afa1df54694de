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
4. **Colour** by visibility-aware RGB retrieval over all input views (Eq. 6).

The coordinate system (cylindrical / spherical / Cartesian) is a pluggable
:class:`~cylindersplat.geometry.TriplaneCoordinates`; nothing here is specific to the cylinder.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor, nn

from ..gaussians import Gaussians
from ..geometry import TriplaneCoordinates, camera_to_world, make_coordinates
from .config import ModelConfig
from .gaussian_heads import VolumeGaussianHead, local_to_cartesian_scales
from .rgb_retrieval import RGBRetrieval
from ..geometry.rotations import matrix_to_quaternion, quaternion_multiply
from .triplane import grid_features, plane_shape, scatter_points_to_triplanes
from .triplane_attention import TriplaneRefinementLayer

__all__ = ["TriplaneInitializer", "VolumeBranchOutput", "VolumeBranch"]


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
        c2w: Float[Tensor, "B V 4 4"],
        coords: TriplaneCoordinates,
        strategy: str,
    ) -> list[Tensor]:
        means, counts = scatter_points_to_triplanes(points_world, point_features, c2w, coords, self.grid, strategy)
        planes = []
        for embedding, mean, count in zip(self.embeddings, means, counts):
            lifted = torch.where(count[..., None] > 0, self.project(mean), 0.0)
            planes.append(embedding + lifted)
        return planes


@dataclass
class VolumeBranchOutput:
    gaussians: Gaussians  # (B, V*G, ...) world frame, camera-major order
    points_cam: Float[Tensor, "B V G 3"]  # centres in their own camera's frame (for fusion)
    planes: list[Tensor]  # refined planes (B*V, n_a, n_b, C)


class VolumeBranch(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        vc = cfg.volume
        self.cfg = vc
        self.coords = make_coordinates(vc.coordinates, radius=vc.radius, height=vc.height)
        self.initializer = TriplaneInitializer(cfg.pixel.feature_dim, vc.channels, vc.grid)
        self.layers = nn.ModuleList(
            TriplaneRefinementLayer(vc.channels, cfg.pixel.feature_dim, vc.heads, vc.mlp_ratio, self.coords, vc.image_grid)
            for _ in range(vc.layers)
        )
        self.head = VolumeGaussianHead(vc.channels, vc.decoder_hidden, vc.color_hidden, vc.max_scale_cells, vc.min_scale_cells)
        self.rgb = RGBRetrieval(vc.color_hidden, vc.color_hidden, vc.visibility_temperature)

    @property
    def gaussians_per_camera(self) -> int:
        n0, n1, n2 = self.cfg.grid
        return n0 * n1 * n2

    def forward(
        self,
        images: Float[Tensor, "B V 3 H W"],
        depth_prior: Float[Tensor, "B V H W"],
        c2w: Float[Tensor, "B V 4 4"],
        image_features: Float[Tensor, "B V C H W"],
        points_world: Float[Tensor, "B V P 3"],
        point_features: Float[Tensor, "B V P C"],
    ) -> VolumeBranchOutput:
        b, v = images.shape[:2]
        planes = self.initializer(points_world, point_features, c2w, self.coords, self.cfg.init)
        flat_features = image_features.flatten(0, 1)
        for layer in self.layers:
            planes = layer(planes, flat_features)

        dtype, device = images.dtype, images.device
        cell = torch.tensor(self.coords.cell_size(self.cfg.grid), dtype=dtype, device=device)
        params = self.head(grid_features(planes).flatten(1, 3), cell)  # (BV, G, .)
        centers = self.coords.cell_centers(self.cfg.grid, device=device, dtype=dtype).reshape(1, -1, 3)
        q = centers + params["offsets"]
        points_cam = self.coords.to_cartesian(q).view(b, v, -1, 3)
        scales, rotations_cam = local_to_cartesian_scales(
            self.coords, q, params["local_scales"], params["rotations"], self.cfg.scale_transform
        )
        camera_rotation = matrix_to_quaternion(c2w[..., :3, :3])[:, :, None]  # (B, V, 1, 4)
        rotations = quaternion_multiply(camera_rotation, rotations_cam.view(b, v, -1, 4))
        means = camera_to_world(points_cam, c2w).flatten(1, 2)
        colors = self.rgb(means, params["color_feature"].view(b, -1, self.cfg.color_hidden), images, depth_prior, c2w)
        gaussians = Gaussians.from_rgb(
            means,
            scales.view(b, -1, 3),
            rotations.flatten(1, 2),
            params["opacities"].view(b, -1),
            colors,
        )
        return VolumeBranchOutput(gaussians=gaussians, points_cam=points_cam, planes=planes)
