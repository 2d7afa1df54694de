"""Occluded-pixel masks against an analytic scene: segment-sphere intersection decides visibility."""

import math

import pytest
import torch

from cylindersplat.data.occlusion import occluded_fraction, occluded_mask
from cylindersplat.geometry import equirect_rays, make_c2w

ROOM_R = 6.0  # the scene: inside a sphere of radius 6 (the "walls") with one opaque ball
BALL_C = torch.tensor([1.5, 0.0, 0.0], dtype=torch.float64)
BALL_R = 0.8


def _hit(origin, dirs, centre, radius, inside):
    """Distance along unit ``dirs`` from ``origin`` to a sphere (far root if inside, near root else; inf if missed)."""
    oc = origin - centre
    b = (dirs * oc).sum(-1)
    c = (oc * oc).sum() - radius**2
    disc = b * b - c
    root = torch.sqrt(disc.clamp_min(0))
    t = -b + root if inside else -b - root
    return torch.where((disc >= 0) & (t > 0), t, torch.full_like(t, math.inf))


def _depth(centre, h, w):
    dirs = equirect_rays(h, w, dtype=torch.float64)
    wall = _hit(centre, dirs, torch.zeros(3, dtype=torch.float64), ROOM_R, inside=True)
    return torch.minimum(wall, _hit(centre, dirs, BALL_C, BALL_R, inside=False))


def _pose(centre):
    return make_c2w(translation=centre)


def test_mask_matches_segment_sphere_visibility():
    h, w = 48, 96
    target, context = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64), torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64)
    t_depth = _depth(target, h, w)
    mask = occluded_mask(t_depth, _pose(target), _depth(context, h, w)[None], _pose(context)[None], rel_tol=0.05)

    # Reference: the target pixel's point is hidden from the context when the segment context -> point
    # crosses the ball before reaching the point.
    points = equirect_rays(h, w, dtype=torch.float64) * t_depth[..., None]
    to_point = points - context
    dist = torch.linalg.vector_norm(to_point, dim=-1)
    t_ball = _hit(context, to_point / dist[..., None], BALL_C, BALL_R, inside=False)
    hidden = t_ball < dist * 0.95
    agree = (mask == hidden).double().mean()
    assert hidden.sum() > 20  # the ball really casts a shadow from the context's viewpoint
    assert agree > 0.98  # disagreements only at the shadow's boundary (nearest sampling, tolerance)
    # Pixels on the ball itself face the context: never hidden.
    on_ball = _hit(target, equirect_rays(h, w, dtype=torch.float64), BALL_C, BALL_R, inside=False) < math.inf
    assert not (mask & on_ball & (points[..., 0] > BALL_C[0])).any()


def test_a_view_sees_itself_and_more_contexts_hide_less():
    h, w = 32, 64
    target = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64)
    a, b = torch.tensor([3.0, 0.0, 0.0], dtype=torch.float64), torch.tensor([1.5, 0.0, 2.0], dtype=torch.float64)
    t_depth = _depth(target, h, w)
    assert not occluded_mask(t_depth, _pose(target), t_depth[None], _pose(target)[None]).any()
    one = occluded_mask(t_depth, _pose(target), _depth(a, h, w)[None], _pose(a)[None])
    two = occluded_mask(t_depth, _pose(target), torch.stack((_depth(a, h, w), _depth(b, h, w))), torch.stack((_pose(a), _pose(b))))
    assert one.any() and (two <= one).all() and two.sum() < one.sum()
    assert 0 < occluded_fraction(two) < occluded_fraction(one) < 1


def test_invalid_depths_and_bad_shapes():
    h, w = 8, 16
    target = torch.zeros(3, dtype=torch.float64)
    t_depth = _depth(target, h, w)
    t_depth[0] = 0  # no depth: never counted as occluded
    ctx = torch.zeros_like(t_depth)  # a context without depth sees nothing
    mask = occluded_mask(t_depth, _pose(target), ctx[None], _pose(torch.tensor([1.0, 0, 0]))[None])
    assert not mask[0].any() and mask[1:].all()
    with pytest.raises(ValueError, match="context depths"):
        occluded_mask(t_depth, _pose(target), ctx, _pose(target)[None])
