"""``fusion.pixel_footprint="covisible"`` (issue 34): a pixel Gaussian's footprint shrinks by sqrt(c), c the number of
input views that see its point. Checked on a box room both cameras see whole (c = 2 on its walls, from ray-box
distances computed here) with an object only view 0's prior holds (c = 1 there: the other view sees the wall)."""

import torch

from cylindersplat.geometry import equirect_rays, make_c2w
from cylindersplat.model import from_config
from cylindersplat.model.fusion import covisibility

H, W = 16, 32
ROOM = torch.tensor([[-3.0, -1.5, -2.5], [3.5, 1.5, 2.5]])  # the box's low and high corners (world = camera 0)
SHARP = {"pixel.footprint": "surface", "pixel.refine_depth": "where_missing", "pixel.opacity": "opaque"}


def cameras():
    return torch.stack((make_c2w(), make_c2w(translation=torch.tensor([1.0, 0.2, -0.3]))))


def box_depth(c2w: torch.Tensor) -> torch.Tensor:
    """Radial distance from the camera to the room's walls along each pixel's ray (slab method, from inside)."""
    rays = equirect_rays(H, W, dtype=torch.float64).reshape(-1, 3) @ c2w[:3, :3].double().T
    origin = c2w[:3, 3].double()
    safe = torch.where(rays.abs() < 1e-12, torch.full_like(rays, 1e-12), rays)
    exits = torch.maximum((ROOM[0].double() - origin) / safe, (ROOM[1].double() - origin) / safe)
    return exits.amin(dim=-1).reshape(H, W).float()


def forward(footprint: str, depth: torch.Tensor):
    torch.manual_seed(0)
    model = from_config("tiny_paper", **SHARP, **{"fusion.pixel_footprint": footprint}).eval()
    with torch.no_grad():
        return model(torch.rand(1, 2, 3, H, W), depth[None], cameras()[None])


def test_a_surface_two_views_see_gets_half_the_footprint_area():
    poses = cameras()
    depth = torch.stack([box_depth(c) for c in poses])
    depth[0, 6:10, 4:9] = 1.0  # an object only view 0 holds: view 1 sees the wall behind it
    apart, together = forward("per_view", depth), forward("covisible", depth)
    n = apart.pixel_gaussians.num_gaussians  # the fused set: pixel Gaussians first
    ratio = (together.gaussians.scales[:, :n] / apart.gaussians.scales[:, :n])[0, :, 0]
    count = covisibility(apart.pixel_gaussians.means, poses[None], apart.refined_depth, 0.1)[0]
    torch.testing.assert_close(ratio, count.clamp_min(1).rsqrt(), atol=1e-5, rtol=1e-5)
    walls = torch.ones(2, H, W, dtype=torch.bool)
    walls[0, 5:11, 3:10] = False  # the object and its rim
    # both views see the walls (but for view 1's rays that pass the object, which view 0 cannot see past)
    assert ((count.view(2, H, W)[walls] - 2).abs() < 0.05).float().mean() > 0.85
    assert (count.view(2, H, W)[0, 6:10, 4:9] < 1.05).all()  # the object: its own view only
    torch.testing.assert_close(together.gaussians.means, apart.gaussians.means)  # only the size changes


def test_one_view_keeps_its_footprint():
    depth = box_depth(cameras()[0])[None]
    torch.manual_seed(0)
    images, pose = torch.rand(1, 1, 3, H, W), cameras()[:1][None]
    outs = []
    for footprint in ("per_view", "covisible"):
        torch.manual_seed(0)
        model = from_config("tiny_paper", **SHARP, **{"fusion.pixel_footprint": footprint}).eval()
        with torch.no_grad():
            outs.append(model(images, depth[None], pose).gaussians.scales)
    torch.testing.assert_close(outs[0], outs[1])
