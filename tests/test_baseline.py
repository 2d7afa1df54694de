"""Forward-warp baseline against exact reprojection."""

from __future__ import annotations

import math

import pytest
import torch

from cylindersplat.baselines import forward_warp, nearest_source
from cylindersplat.geometry import make_c2w


def _random_scene(h=16, w=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, h, w, generator=g), 2.0 + torch.rand(1, h, w, generator=g)


def test_identity_pose_reproduces_the_input():
    image, depth = _random_scene()
    pose = make_c2w(translation=torch.tensor([0.3, -0.1, 0.2]))[None]
    out = forward_warp(image, depth, pose, pose)
    # Each point lands on its own pixel centre (and on neighbours it loses to by z-order ties):
    # every pixel is covered and the own point has the smallest depth.
    assert out.alpha.min() == 1
    torch.testing.assert_close(out.depth[0], depth[0], atol=1e-5, rtol=0)


def test_pure_rotation_is_a_column_shift():
    # Yaw by exactly 4 columns: a panorama of a constant-depth sphere rolls horizontally.
    h, w = 16, 32
    image, _ = _random_scene(h, w)
    depth = torch.full((1, h, w), 3.0)
    angle = 2 * math.pi * 4 / w
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])
    target = make_c2w(rotation=rot)[None]
    out = forward_warp(image, depth, make_c2w()[None], target)
    # The camera turned towards +x (longitude +angle), so the world appears 4 columns to the left.
    torch.testing.assert_close(out.rgb[0], torch.roll(image[0], shifts=-4, dims=-1), atol=1e-6, rtol=0)


def test_translation_matches_brute_force_nearest_point():
    # A single bright point at a known position: it must appear at its exact projection.
    h, w = 32, 64
    image = torch.zeros(1, 3, h, w)
    depth = torch.zeros(1, h, w)
    image[0, :, 16, 40] = 1.0
    depth[0, 16, 40] = 2.0
    target = make_c2w(translation=torch.tensor([0.5, 0.0, 0.0]))[None]
    out = forward_warp(image, depth, make_c2w()[None], target)
    from cylindersplat.geometry import equirect_rays, project_equirect

    point = equirect_rays(h, w)[16, 40] * 2.0 - torch.tensor([0.5, 0.0, 0.0])
    uv, dist = project_equirect(point, h, w)
    lit = out.alpha[0].nonzero()
    assert 1 <= len(lit) <= 4
    for row, col in lit.tolist():
        assert abs(col + 0.5 - uv[0].item()) <= 1.0 and abs(row + 0.5 - uv[1].item()) <= 1.0
        assert out.depth[0, row, col].item() == pytest.approx(dist.item(), abs=1e-5)
        assert out.rgb[0, :, row, col].tolist() == [1.0, 1.0, 1.0]


def test_z_buffer_keeps_the_nearest_surface_and_holes_get_background():
    h, w = 16, 32
    image = torch.stack([torch.ones(3, h, w), torch.zeros(3, h, w)])  # white far view, black near view
    depth = torch.stack([torch.full((h, w), 4.0), torch.full((h, w), 2.0)])
    poses = torch.stack([make_c2w(), make_c2w()])
    out = forward_warp(image, depth, poses, make_c2w()[None], sources="all")
    assert out.rgb.max() == 0  # the nearer (black) surface wins everywhere
    empty = forward_warp(image[:1], torch.zeros(1, h, w), poses[:1], poses[:1], background=(0.2, 0.4, 0.6))
    assert empty.alpha.max() == 0 and torch.allclose(empty.rgb[0, :, 0, 0], torch.tensor([0.2, 0.4, 0.6]))


def test_nearest_source_and_errors():
    sources = torch.stack([make_c2w(translation=torch.tensor([x, 0.0, 0.0])) for x in (0.0, 2.0)])
    targets = torch.stack([make_c2w(translation=torch.tensor([x, 0.0, 0.0])) for x in (0.4, 1.6)])
    assert nearest_source(sources, targets).tolist() == [0, 1]
    with pytest.raises(ValueError, match="images"):
        forward_warp(torch.rand(1, 3, 8, 16), torch.rand(1, 8, 8), sources[:1], targets)
