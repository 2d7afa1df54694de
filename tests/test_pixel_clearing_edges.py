"""``fusion.pixel_clearing="at_depth_edges"`` (issue 34): pixel clearing weighted by how much a pixel sits on a depth
edge of its own view, against a hand-computed edge measure, and the failure it exists for: two views whose priors
disagree everywhere (a constant or badly scaled depth) must not clear each other's pixels into holes."""

import math

import pytest
import torch

from cylindersplat.geometry import make_c2w
from cylindersplat.model import from_config
from cylindersplat.model.fusion import hidden_confidence

H, W = 16, 32
FLAT = {"fusion.strategy": "depth_prune", "fusion.side": "hidden", "pixel.refine_depth": "where_missing"}


def two_cameras():
    return torch.stack((make_c2w(), make_c2w(translation=torch.tensor([1.0, 0.0, 0.0]))))[None]


def run(clearing, depth, **changes):
    torch.manual_seed(0)
    model = from_config("tiny_paper", **{**FLAT, "fusion.pixel_clearing": clearing, **changes}).eval()
    images = torch.rand(1, 2, 3, H, W)
    with torch.no_grad():
        out = model(images, depth, two_cameras())
    return out, out.gaussians.opacities[:, : out.pixel_gaussians.num_gaussians]


def hand_edginess(depth: torch.Tensor, step: float) -> torch.Tensor:
    """1 - exp(-g^2 / (2 step^2)) per pixel, g the largest |log d - log d_n| over the 8 neighbours (columns wrap,
    rows do not), by explicit loops."""
    out = torch.zeros_like(depth)
    for y in range(depth.shape[0]):
        for x in range(depth.shape[1]):
            g = 0.0
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    yy = min(max(y + dy, 0), depth.shape[0] - 1)
                    g = max(g, abs(math.log(depth[yy, (x + dx) % depth.shape[1]]) - math.log(depth[y, x])))
            out[y, x] = 1 - math.exp(-0.5 * (g / step) ** 2)
    return out


def test_priors_that_disagree_everywhere_clear_nothing_at_depth_edges():
    """Two constant priors of different scale (each view's own sphere): every pixel of the nearer sphere lies in
    space the other view 'saw empty', so seen_through clears it; at_depth_edges clears nothing (no edge)."""
    depth = torch.stack((torch.full((H, W), 2.0), torch.full((H, W), 3.5)))[None]
    _, seen_through = run("seen_through", depth)
    out, edges = run("at_depth_edges", depth)
    own = out.pixel_gaussians.opacities
    assert float((seen_through < 0.5 * own).float().mean()) > 0.2  # the failure: a fifth of the pixels cleared
    torch.testing.assert_close(edges, own)  # nothing cleared


@pytest.mark.parametrize("step", [0.05, 0.2])
def test_at_depth_edges_is_seen_through_weighted_by_the_own_views_depth_step(step):
    depth = torch.full((2, H, W), 3.0)
    depth[0, 5:10, 12:20] = 1.2  # a box in front of view 0: its rim has flying pixels
    depth[1, :, 3:6] = 4.0
    out, cleared = run("at_depth_edges", depth[None], **{"fusion.clearing_edge_step": step})
    pixel = out.pixel_gaussians
    seen = hidden_confidence(pixel.means, two_cameras(), out.refined_depth, 0.1)
    edge = torch.cat([hand_edginess(depth[v], step).flatten() for v in range(2)])[None]
    torch.testing.assert_close(cleared, pixel.opacities * (1 - edge * (1 - seen)), atol=1e-5, rtol=1e-5)
    assert float(edge.max()) > 0.9 and int((edge == 0).sum()) > H * W  # the rim is an edge, the flat parts are not
