"""Where the viewer's first view looks from: framing the scene's bounds from behind and above.

The bounds are the middle 96 % (per axis) of the visible Gaussians' centres (opacity > 0.1) and the input
cameras, so a few far floaters do not shrink the scene to a dot. The eye sits on the line from the bounds'
centre going back (against the first camera's horizontal forward axis) and up at :data:`ELEVATION_DEG`, far
enough for the bounding sphere to fill a :data:`FOV_DEG` view, looking at the centre. A room reconstructed from
panoramas is closed (ceiling, walls): from outside, only the back of a wall would show; so when that line
crosses the scene's outermost surface, the eye stops just inside it, looking down into the room from near a
ceiling corner. Never at an input camera, inside the haze of large Gaussians around it.
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
    bounds = scene_bounds(gaussians, cameras)
    if bounds is None:
        return np.array([0.0, -1.0, -3.0]), np.zeros(3)
    low, high = bounds
    centre = (low + high) / 2
    radius = max(0.5 * float(np.linalg.norm(high - low)), 1e-3)
    forward = cameras[0].c2w[:3, 2].detach().double().cpu().numpy() if cameras else np.array([0.0, 0.0, 1.0])
    horizontal = forward - (forward @ UP) * UP
    if np.linalg.norm(horizontal) < 1e-6:  # a camera looking straight up or down
        horizontal = np.array([0.0, 0.0, 1.0])
    horizontal /= np.linalg.norm(horizontal)
    elevation = math.radians(ELEVATION_DEG)
    direction = -math.cos(elevation) * horizontal + math.sin(elevation) * UP  # from the centre to the eye
    distance = radius / math.sin(math.radians(FOV_DEG) / 2)
    return centre + _free_distance(gaussians, centre, direction, distance, radius) * direction, centre


def _free_distance(gaussians, centre: np.ndarray, direction: np.ndarray, distance: float, radius: float) -> float:
    """How far along ``direction`` from ``centre`` the eye may go (up to ``distance``) and still see the centre:
    just short of the outermost surface the line crosses (a closed room's ceiling or wall), if any."""
    relative = _visible_means(gaussians) - centre
    along = relative @ direction
    across = np.linalg.norm(relative - along[:, None] * direction, axis=1)
    on_line = along[(across < 0.1 * radius) & (along > 0.2 * radius) & (along < distance)]
    if len(on_line) < 3:  # open scene: nothing between the eye and the centre
        return distance
    outermost = on_line[on_line > 0.8 * on_line.max()]  # the last surface before the eye
    return max(float(outermost.min()) - 0.05 * radius, 0.3 * radius)
