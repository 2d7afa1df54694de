"""Metric scale of an SfM reconstruction (arbitrary units) from depth the user has, or from the camera height.

:func:`scale_from_depth`: every 3-D point seen at pixel ``(x, y)`` of a panorama lies at distance ``r`` (model units)
from that panorama's centre, and the panorama's depth (metres, radial: docs/conventions.md) at that pixel says
``d``; ``d / r`` is the scale, one vote per observation. The median of the votes is robust to wrong depth at
edges and to mismatched points; the interquartile range is reported as the spread.

:func:`scale_from_camera_height`: with upright panoramas (camera +y = gravity down), the floor is the lowest
surface a camera sees below it: among the points seen below the horizon (latitude > 20 degrees) the 90th percentile
of their heights below the camera (model units) is taken as the floor (furniture and table tops lie above it, a
few mismatched points below), and the known camera height over it gives the scale. A heuristic: on the real
Matterport3D triplet, whose floor is mostly textureless, it under-estimates the floor's depth and the scale comes
out about 13 % too large (studies/results/sfm_fixture.json); depth, where there is any, is far better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

__all__ = ["ScaleEstimate", "scale_from_depth", "scale_from_camera_height", "sample_depth"]

MIN_VOTES = 20


@dataclass
class ScaleEstimate:
    """``scale`` metres per model unit (the median vote), ``q25``/``q75`` the interquartile range of the votes,
    ``votes`` how many, ``source`` what they came from."""

    scale: float
    q25: float
    q75: float
    votes: int
    source: str

    @property
    def spread(self) -> float:
        """Half the interquartile range relative to the median (0.01 = votes within about 1 %)."""
        return (self.q75 - self.q25) / (2 * self.scale)

    def describe(self) -> str:
        return (f"{self.scale:.6g} m per SfM unit from {self.source} ({self.votes} points; spread "
                f"{self.q25:.6g}-{self.q75:.6g}, +-{100 * self.spread:.1f} %)")


def sample_depth(depth: np.ndarray, xy: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Depth ``(H_d, W_d)`` at COLMAP pixel positions ``xy (P, 2)`` of an ``image_size`` (H, W) panorama, nearest
    pixel (a depth map of another size is sampled at the same angles; no blending across depth edges)."""
    h, w = depth.shape
    cols = np.floor(xy[:, 0] * (w / image_size[1])).astype(np.int64) % w  # longitude wraps around
    rows = np.clip(np.floor(xy[:, 1] * (h / image_size[0])).astype(np.int64), 0, h - 1)
    return depth[rows, cols]


def _estimate(votes: np.ndarray, source: str, what: str) -> ScaleEstimate:
    votes = votes[np.isfinite(votes) & (votes > 0)]
    if votes.size < MIN_VOTES:
        raise ValueError(f"too few points to fix the metric scale from {source} ({votes.size} {what}, "
                         f"{MIN_VOTES} needed): give --scale METRES_PER_UNIT or --camera-height")
    q25, median, q75 = np.percentile(votes, [25, 50, 75])
    return ScaleEstimate(float(median), float(q25), float(q75), int(votes.size), source)


def scale_from_depth(observations: Mapping[str, tuple[np.ndarray, np.ndarray]], c2w: Mapping[str, np.ndarray],
                     depths: Mapping[str, np.ndarray], image_sizes: Mapping[str, tuple[int, int]],
                     source: str = "depth", min_depth: float = 0.1, max_depth: float = 100.0) -> ScaleEstimate:
    """Metres per model unit from metric radial depth maps.

    ``observations[name] = (xy (P, 2), xyz (P, 3))`` (pixels of a panorama, their 3-D points in model units);
    ``c2w[name]`` (4, 4) in model units; ``depths[name]`` ``(H, W)`` metres (0 = unknown) for the panoramas that
    have one; ``image_sizes[name]`` the panorama's (H, W). Depths outside ``[min_depth, max_depth]`` do not vote.
    """
    votes = []
    for name, depth in depths.items():
        if name not in observations or name not in c2w:
            continue
        xy, xyz = observations[name]
        distance = np.linalg.norm(xyz - np.asarray(c2w[name])[:3, 3], axis=1)
        metric = sample_depth(np.asarray(depth, dtype=np.float64), xy, image_sizes[name])
        keep = (metric > min_depth) & (metric < max_depth) & (distance > 0)
        votes.append(metric[keep] / distance[keep])
    return _estimate(np.concatenate(votes) if votes else np.zeros(0), source, "with depth")


def scale_from_camera_height(observations: Mapping[str, tuple[np.ndarray, np.ndarray]],
                             c2w: Mapping[str, np.ndarray], height: float, min_latitude_deg: float = 20.0,
                             floor_quantile: float = 90.0) -> ScaleEstimate:
    """Metres per model unit from the camera height above the floor (metres): upright panoramas assumed.
    ``q25``/``q75`` of the result are the scales the 85th and 95th percentiles would give (the floor's spread)."""
    if not (isinstance(height, (int, float)) and math.isfinite(height) and height > 0):
        raise ValueError(f"--camera-height must be a positive number of metres, got {height!r}")
    below = []
    sin_min = math.sin(math.radians(min_latitude_deg))
    for name, (_, xyz) in observations.items():
        pose = np.asarray(c2w[name])
        local = (xyz - pose[:3, 3]) @ pose[:3, :3]  # camera frame: +y down
        distance = np.linalg.norm(local, axis=1)
        steep = local[:, 1] > sin_min * np.maximum(distance, 1e-12)
        below.append(local[steep, 1])
    heights = np.concatenate(below) if below else np.zeros(0)
    if heights.size < MIN_VOTES:
        raise ValueError(f"too few points seen below the cameras ({heights.size}, {MIN_VOTES} needed) to use "
                         "--camera-height: is the floor visible and textured? give --scale or a depth instead")
    low, floor, high = np.percentile(heights, [floor_quantile - 5, floor_quantile, min(floor_quantile + 5, 100)])
    return ScaleEstimate(float(height / floor), float(height / high), float(height / low), int(heights.size),
                         f"a camera height of {height:g} m (floor: the {floor_quantile:g}th percentile of points "
                         "below)")
