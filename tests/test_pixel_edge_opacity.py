"""Edge-aware pixel opacity (``model.pixel.edge_sigma``): the flying-pixel factor against a brute-force
loop, and its effect on the pixel Gaussians."""

import math

import torch

from cylindersplat.model import from_config
from cylindersplat.model.pixel_branch import depth_edge_confidence


def _brute_force(depth: torch.Tensor, sigma: float) -> torch.Tensor:
    n, h, w = depth.shape
    out = torch.empty_like(depth)
    for k in range(n):
        for y in range(h):
            for x in range(w):
                step = 0.0
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        yy = min(max(y + dy, 0), h - 1)  # rows clamp at the poles
                        xx = (x + dx) % w  # columns wrap around the seam
                        step = max(step, abs(math.log(depth[k, yy, xx]) - math.log(depth[k, y, x])))
                out[k, y, x] = math.exp(-0.5 * (step / sigma) ** 2)
    return out


def test_edge_confidence_matches_a_brute_force_loop():
    depth = torch.rand(2, 5, 10, dtype=torch.float64) * 4 + 0.5
    torch.testing.assert_close(depth_edge_confidence(depth, 0.3), _brute_force(depth, 0.3))


def test_edge_confidence_fades_only_the_two_sides_of_a_step_including_the_seam():
    depth = torch.full((1, 4, 12), 2.0, dtype=torch.float64)
    depth[..., 3:6] = 1.0  # a foreground object: steps between columns 2|3 and 5|6
    depth[..., 11] = 1.0  # another at the seam: it neighbours column 0
    conf = depth_edge_confidence(depth, 0.1)[0, 0]
    faded = (conf < 1e-6).nonzero().flatten().tolist()
    assert faded == [0, 2, 3, 5, 6, 10, 11]
    assert torch.all(conf[[1, 4, 7, 8, 9]] == 1.0)  # flat interior, on either depth


def test_edge_sigma_scales_pixel_opacity_by_the_confidence():
    torch.manual_seed(0)
    images = torch.rand(1, 2, 3, 32, 64)
    prior = torch.full((1, 2, 32, 64), 3.0)
    prior[..., 10:20, 20:30] = 1.0  # a box in front of the wall
    c2w = torch.eye(4).repeat(1, 2, 1, 1)
    c2w[0, 1, 0, 3] = 0.5
    plain = from_config("tiny_paper", mode="pixel").eval()
    faded = from_config("tiny_paper", mode="pixel", **{"pixel.edge_sigma": 0.1}).eval()
    faded.load_state_dict(plain.state_dict())
    with torch.no_grad():
        a, b = plain(images, prior, c2w), faded(images, prior, c2w)
    expected = depth_edge_confidence(a.refined_depth.flatten(0, 1), 0.1).reshape(1, -1)
    torch.testing.assert_close(b.gaussians.opacities, a.gaussians.opacities * expected)
    torch.testing.assert_close(b.gaussians.means, a.gaussians.means)
