"""Camera sequences in a synthetic scene: ``frames`` poses on a straight line in free space.

Protocol of the paper/PanoGRF: consecutive frames ``spacing`` metres apart, so 2-view samples
(first/last -> middle), 1-view samples (middle -> outer) and N-view samples exist with baselines
from ``spacing`` to ``(frames - 1) * spacing``. Cameras stand at a plausible height, keep
``clearance`` metres from every solid along the whole segment, and share one random yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ...geometry import make_c2w
from .layouts import LAYOUTS, random_scene
from .raycast import render_equirect_scene
from .scene import SynthScene

__all__ = ["SequenceConfig", "SynthSequence", "sample_camera_line", "generate_sequence", "render_sequence", "scene_rng"]


@dataclass(frozen=True)
class SequenceConfig:
    frames: int = 3
    spacing: tuple[float, float] = (0.5, 0.5)  # metres between consecutive frames, uniform in range
    height: tuple[float, float] = (1.2, 1.7)  # camera height above the floor
    clearance: float = 0.3
    random_yaw: bool = True  # all frames share one yaw; False gives identity rotations (PanoGRF)
    layouts: tuple[str, ...] = LAYOUTS
    outdoor_fraction: float = 0.2
    attempts: int = 300

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        lo, hi = self.spacing
        if not 0 < lo <= hi:
            raise ValueError(f"spacing range must satisfy 0 < min <= max, got {self.spacing}")


@dataclass
class SynthSequence:
    scene: SynthScene
    poses: Tensor  # (F, 4, 4) OpenCV c2w
    spacing: float
    seed: int


def scene_rng(seed: int, index: int) -> np.random.Generator:
    """Independent, reproducible stream for scene ``index`` of a dataset generated with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))


def sample_camera_line(scene: SynthScene, rng: np.random.Generator, cfg: SequenceConfig, spacing: float) -> Tensor | None:
    """Poses ``(F, 4, 4)`` on a free segment, or ``None`` when ``cfg.attempts`` tries all fail."""
    x0, x1, z0, z1 = scene.free_region
    length = (cfg.frames - 1) * spacing
    steps = np.linspace(0.0, 1.0, max(2, int(math.ceil(length / 0.1)) + 1))
    for _ in range(cfg.attempts):
        height = rng.uniform(*cfg.height)
        if scene.ceiling_y is not None:
            height = min(height, -scene.ceiling_y - cfg.clearance - 0.05)
        start = np.array([rng.uniform(x0, x1), scene.floor_y - height, rng.uniform(z0, z1)])
        heading = rng.uniform(0, 2 * math.pi)
        direction = np.array([math.sin(heading), 0.0, math.cos(heading)])
        end = start + length * direction
        if not (x0 <= end[0] <= x1 and z0 <= end[2] <= z1):
            continue
        path = torch.from_numpy(start + steps[:, None] * (end - start)[None]).float()
        if not bool(scene.clearance_ok(path, cfg.clearance).all()):
            continue
        yaw = rng.uniform(0, 2 * math.pi) if cfg.random_yaw else 0.0
        c, s = math.cos(yaw), math.sin(yaw)
        rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # yaw about the (down) y axis
        centres = torch.from_numpy(start + np.arange(cfg.frames)[:, None] * spacing * direction[None]).float()
        return make_c2w(rot.expand(cfg.frames, 3, 3), centres)
    return None


def generate_sequence(seed: int, index: int, cfg: SequenceConfig = SequenceConfig()) -> SynthSequence:
    """Scene ``index`` of dataset ``seed`` and its camera line (re-draws the scene if no line fits)."""
    rng = scene_rng(seed, index)
    for _ in range(50):
        scene = random_scene(rng, cfg.layouts, cfg.outdoor_fraction)
        spacing = float(rng.uniform(*cfg.spacing))
        poses = sample_camera_line(scene, rng, cfg, spacing)
        if poses is not None:
            return SynthSequence(scene, poses, spacing, seed)
    raise RuntimeError(f"could not place a {cfg.frames}-frame line with spacing {cfg.spacing} (seed {seed}, scene {index})")


def render_sequence(seq: SynthSequence, height: int, width: int) -> tuple[Tensor, Tensor]:
    """RGB ``(F, 3, H, W)`` and radial depth ``(F, H, W)`` of every frame."""
    views = [render_equirect_scene(seq.scene, pose, height, width) for pose in seq.poses]
    return torch.stack([v[0] for v in views]), torch.stack([v[1] for v in views])
