"""The viewer (and view --screenshot) opens on the scene: from the input cameras' middle where there are cameras,
from outside an open scene, from the middle of a closed room; the picture shows the scene, not one colour."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry import make_c2w
from cylindersplat.scenes import demo_room
from cylindersplat.view_framing import FOV_DEG, default_view, scene_bounds
from cylindersplat.viewer import ViewCamera

CAMERAS = [ViewCamera(make_c2w(translation=torch.tensor([x, 0.0, 0.3 * x]))) for x in (-1.0, 0.0, 1.0)]


def test_with_cameras_the_view_starts_in_their_middle_along_the_first_ones_forward():
    room = demo_room()
    eye, target = default_view(room, CAMERAS)
    np.testing.assert_allclose(eye, np.mean([c.c2w[:3, 3].numpy() for c in CAMERAS], axis=0), atol=1e-9)
    direction = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(direction, [0.0, 0.0, 1.0], atol=1e-9)  # the first camera's +z, level
    means = room.means.double().numpy()[room.opacities.numpy() > 0.1]
    ahead = (means - eye)[:, 2]
    assert np.linalg.norm(target - eye) == pytest.approx(np.median(ahead[ahead > 0]))  # the orbit's centre


def test_a_tilted_first_camera_still_gives_a_level_view():
    tilt = math.radians(30)
    pitched = torch.tensor([[1.0, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    eye, target = default_view(demo_room(), [ViewCamera(make_c2w(rotation=pitched))])
    assert target[1] == pytest.approx(eye[1]) and target[2] > eye[2]


def test_a_closed_room_without_cameras_is_seen_from_its_middle():
    eye, target = default_view(demo_room(), [])  # walls x = +-3, z = +-2.5; ceiling y = -1.2, floor y = 1.6
    low, high = scene_bounds(demo_room())
    np.testing.assert_allclose(eye, (low + high) / 2)
    assert -3 < eye[0] < 3 and -2.5 < eye[2] < 2.5 and -1.2 < eye[1] < 1.6  # inside
    assert target[2] > eye[2] and target[1] == pytest.approx(eye[1])


def _floor_patch() -> Gaussians:
    """An open scene: a 4 x 4 m floor of Gaussians, nothing above it."""
    u, v = torch.meshgrid(torch.linspace(-2, 2, 40), torch.linspace(-2, 2, 40), indexing="ij")
    means = torch.stack([u.flatten(), torch.full((1600,), 1.5), v.flatten()], dim=-1)
    return Gaussians.from_rgb(means, torch.full((1600, 3), 0.05), torch.tensor([1.0, 0, 0, 0]).expand(1600, 4),
                              torch.full((1600,), 0.9), torch.rand(1600, 3))


def test_an_open_scene_is_framed_from_outside_and_above():
    scene = _floor_patch()
    eye, target = default_view(scene, [])
    low, high = scene_bounds(scene)
    radius = np.linalg.norm(high - low) / 2
    assert np.linalg.norm(eye - target) >= radius  # outside the bounding sphere
    assert eye[1] < low[1] - 0.5 * radius  # above it
    forward = (target - eye) / np.linalg.norm(target - eye)
    for corner in np.array(np.meshgrid(*zip(low, high))).T.reshape(-1, 3):  # every corner of the bounds in view
        to_corner = (corner - eye) / np.linalg.norm(corner - eye)
        assert math.degrees(math.acos(np.clip(to_corner @ forward, -1, 1))) <= FOV_DEG / 2 + 1e-6


def test_an_empty_scene_still_has_a_view():
    eye, target = default_view(Gaussians.empty(), [])
    assert np.isfinite(eye).all() and np.isfinite(target).all() and np.linalg.norm(eye - target) > 0
