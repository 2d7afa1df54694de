"""Where the viewer's first view (and ``view --screenshot``) looks from.

With input cameras (a reconstruction from panoramas): from the middle of the cameras, looking along the first
camera's horizontal forward axis (the panorama's centre column) at the median distance of the scene ahead. That
is where the scene was seen from, so it is inside the room the panoramas show, never behind a wall, and the
Gaussians there are those the inputs saw sharpest. Measured on the demo's reconstruction and the real
Matterport3D fixture (240x320, 90 degrees): image standard deviation 0.09 / 0.20 from there, against a
near-uniform wall (0.09 with no structure / 0.07, beige) from the framing below.

Without cameras (a bare splat file): the bounds are the middle 96 % (per axis) of the visible Gaussians' centres
(opacity > 0.1), so a few far floaters do not shrink the scene to a dot. An open scene is framed from outside:
the eye sits on the line from the bounds' centre going back (against +z) and up at :data:`ELEVATION_DEG`, far
enough for the bounding sphere to fill a :data:`FOV_DEG` view, looking at the centre. A closed one (that line
crosses a surface: a room's ceiling or wall) would show the back of a wall, or from just inside it the inside of
its Gaussians (a reconstruction's are tens of centimetres: one colour fills the picture); it is seen as with
cameras, from the bounds' centre (where panoramas of a room are taken) looking along +z.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["scene_bounds", "default_view", "FOV_DEG", "ELEVATION_DEG"]

UP = np.array([0.0, -1.0, 0.0])  # OpenCV world: +y is down
FOV_DEG = 60.0  # the view the bounds must fit in (viser opens at about this vertical field of view)
ELEVATION_DEG = 35.0  # how far above the horizontal the eye looks down
MIN_OPACITY = 0.1  # Gaussians fainter than this do not count for the bounds


def _visible_means(gaussians) -> np.ndarray:
    """``(M, 3)`` float64 centres of the Gaussians with opacity > :data:`MIN_OPACITY` (all if none is)."""
    means = gaussians.means.detach().to("cpu", torch.float64).reshape(-1, 3).numpy()
    opacity = gaussians.opacities.detach().to("cpu", torch.float64).reshape(-1).numpy()
    visible = means[opacity > MIN_OPACITY]
    return visible if len(visible) else means


def scene_bounds(gaussians, cameras=()) -> tuple[np.ndarray, np.ndarray] | None:
    """``(low, high)`` corners (3,) of the middle 96 % of the visible centres and the camera positions; None for an
    empty scene without cameras."""
    points = [_visible_means(gaussians)] + [c.c2w[:3, 3].detach().double().cpu().numpy()[None] for c in cameras]
    points = np.concatenate([p for p in points if len(p)]) if any(len(p) for p in points) else np.zeros((0, 3))
    if len(points) == 0:
        return None
    return np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)


def default_view(gaussians, cameras=()) -> tuple[np.ndarray, np.ndarray]:
    """``(position, look_at)`` (float64 (3,)) of the first view (see the module docstring)."""
    if cameras:
        return _from_the_cameras(gaussians, cameras)
    bounds = scene_bounds(gaussians, cameras)
    if bounds is None:
        return np.array([0.0, -1.0, -3.0]), np.zeros(3)
    low, high = bounds
    centre = (low + high) / 2
    radius = max(0.5 * float(np.linalg.norm(high - low)), 1e-3)
    horizontal = _horizontal(np.array([0.0, 0.0, 1.0]))
    elevation = math.radians(ELEVATION_DEG)
    direction = -math.cos(elevation) * horizontal + math.sin(elevation) * UP  # from the centre to the eye
    distance = radius / math.sin(math.radians(FOV_DEG) / 2)
    if _crosses_a_surface(gaussians, centre, direction, distance, radius):
        return _looking_from(gaussians, centre, horizontal)
    return centre + distance * direction, centre


def _horizontal(forward: np.ndarray) -> np.ndarray:
    """``forward`` without its vertical part, unit length (+z for a camera looking straight up or down)."""
    horizontal = forward - (forward @ UP) * UP
    if np.linalg.norm(horizontal) < 1e-6:
        horizontal = np.array([0.0, 0.0, 1.0])
    return horizontal / np.linalg.norm(horizontal)


def _from_the_cameras(gaussians, cameras) -> tuple[np.ndarray, np.ndarray]:
    """From the cameras' mean centre along the first camera's horizontal forward axis."""
    eye = np.stack([c.c2w[:3, 3].detach().double().cpu().numpy() for c in cameras]).mean(axis=0)
    return _looking_from(gaussians, eye, _horizontal(cameras[0].c2w[:3, 2].detach().double().cpu().numpy()))


def _looking_from(gaussians, eye: np.ndarray, forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(eye, look_at)``: looking along unit ``forward`` at the median distance of the visible Gaussians ahead
    (1 m where there are none), which is also where the browser view orbits around."""
    ahead = (_visible_means(gaussians) - eye) @ forward
    distance = float(np.median(ahead[ahead > 0])) if (ahead > 0).any() else 1.0
    return eye, eye + max(distance, 1e-3) * forward


def _crosses_a_surface(gaussians, centre: np.ndarray, direction: np.ndarray, distance: float, radius: float) -> bool:
    """Whether visible Gaussians lie on the line from ``centre`` along ``direction`` (up to ``distance``, past
    the middle fifth): a closed room's ceiling or wall between the outside view and the centre."""
    relative = _visible_means(gaussians) - centre
    along = relative @ direction
    across = np.linalg.norm(relative - along[:, None] * direction, axis=1)
    return int(((across < 0.1 * radius) & (along > 0.2 * radius) & (along < distance)).sum()) >= 3
