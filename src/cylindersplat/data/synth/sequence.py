"""Camera sequences in a synthetic scene: ``frames`` poses on a straight line in free space.

Protocol of the paper/PanoGRF: consecutive frames ``spacing`` metres apart, so 2-view samples
(first/last -> middle), 1-view samples (middle -> outer) and N-view samples exist with baselines
from ``spacing`` to ``(frames - 1) * spacing``. Cameras stand at a plausible height, keep
``clearance`` metres from every solid along the whole segment, and share one random yaw.

Disocclusion options (all off by default, so earlier datasets are reproduced file for file):
``target_offset`` moves the middle frame (the ``two_view`` / ``n_view`` target) off the segment,
``occluders`` stands extra objects near the camera path, ``layout_weights`` favours doorway and
L-shaped rooms. :data:`PROFILES` names settings; ``occlusion`` turns them on together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ...geometry import make_c2w
from .layouts import LAYOUTS, add_occluders, random_scene
from .raycast import render_equirect_scene
from .scene import SynthScene

__all__ = ["SequenceConfig", "SynthSequence", "PROFILES", "profile_config", "camera_path", "target_offset",
           "sample_camera_line", "generate_sequence", "render_sequence", "scene_rng"]


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
    # Disocclusion (defaults off; see the module docstring and docs/data.md):
    target_offset: tuple[float, float] = (0.0, 0.0)  # metres the middle frame leaves the line, uniform in range
    occluders: int = 0  # extra objects placed near the camera path (pillars, cabinets, screens, ...)
    layout_weights: tuple[float, ...] = ()  # one per entry of ``layouts`` (outdoor's ignored); () = uniform
    through_doorways: float = 0.0  # share of scenes with a doorway whose camera line passes through it

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        lo, hi = self.spacing
        if not 0 < lo <= hi:
            raise ValueError(f"spacing range must satisfy 0 < min <= max, got {self.spacing}")
        lo, hi = self.target_offset
        if not 0 <= lo <= hi:
            raise ValueError(f"target_offset range must satisfy 0 <= min <= max, got {self.target_offset}")
        if hi > 0 and self.frames < 3:
            raise ValueError("target_offset needs >= 3 frames (it moves the middle frame, a "
                             "target between two contexts)")
        if not 0 <= self.through_doorways <= 1:
            raise ValueError(f"through_doorways must be in [0, 1], got {self.through_doorways}")
        if self.occluders < 0:
            raise ValueError(f"occluders must be >= 0, got {self.occluders}")
        if self.layout_weights:
            if len(self.layout_weights) != len(self.layouts):
                raise ValueError(f"layout_weights needs one weight per layout {self.layouts}, "
                                 f"got {self.layout_weights}")
            indoor = [w for name, w in zip(self.layouts, self.layout_weights) if name != "outdoor"]
            if min(self.layout_weights) < 0 or (indoor and sum(indoor) <= 0):
                raise ValueError(f"layout_weights must be >= 0 with a positive indoor sum, got {self.layout_weights}")

    @property
    def middle(self) -> int:
        """Index of the frame ``target_offset`` moves (the two_view / n_view target)."""
        return (self.frames - 1) // 2


# Named settings for ``SequenceConfig`` (``cylindersplat data synth --profile NAME``). ``default`` is
# the plain straight line; ``occlusion`` gives two_view targets a real share of pixels that neither
# context sees (about 4 % on average at 64x128 instead of 0.5 %, docs/data.md): the target leaves the
# segment by 0.4-1.0 m, six occluders stand near the path, baselines are 1-2 m, doorway and L-shaped
# rooms are favoured and most lines in a doorway room walk through the doorway.
PROFILES: dict[str, dict] = {
    "default": {},
    "occlusion": {
        "spacing": (0.5, 1.0),
        "target_offset": (0.4, 1.0),
        "occluders": 6,
        "through_doorways": 0.7,
        "layouts": LAYOUTS,
        "layout_weights": (1.0, 2.0, 3.0, 1.0),  # room, l_shape, two_rooms, (outdoor: by outdoor_fraction)
        "outdoor_fraction": 0.15,
    },
}


def profile_config(name: str = "default", **overrides) -> SequenceConfig:
    """``SequenceConfig`` of profile ``name`` with ``overrides`` (``None`` values are ignored). Giving
    ``layouts`` without ``layout_weights`` drops the profile's weights (they belong to its layout list)."""
    if name not in PROFILES:
        raise ValueError(f"unknown profile {name!r}; choose from {sorted(PROFILES)}")
    given = {k: v for k, v in overrides.items() if v is not None}
    fields = dict(PROFILES[name])
    if "layouts" in given and "layout_weights" not in given:
        fields.pop("layout_weights", None)
    fields.update(given)
    return SequenceConfig(**fields)


@dataclass
class SynthSequence:
    scene: SynthScene
    poses: Tensor  # (F, 4, 4) OpenCV c2w
    spacing: float
    seed: int


def scene_rng(seed: int, index: int) -> np.random.Generator:
    """Independent, reproducible stream for scene ``index`` of a dataset generated with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))


def _segment(a: np.ndarray, b: np.ndarray, step: float = 0.1) -> np.ndarray:
    """Points from ``a`` to ``b`` (both included) at most ``step`` apart."""
    n = max(2, math.ceil(float(np.linalg.norm(b - a)) / step) + 1)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)[None]


def camera_path(poses: Tensor) -> np.ndarray:
    """Points ``(P, 3)`` (<= 0.1 m apart) the cameras of a sequence must keep clear: the segment from the
    first to the last centre and, for a moved middle frame, the way from its place on the line to it."""
    centres = poses[:, :3, 3].double().numpy()
    first, last = centres[0], centres[-1]
    parts = [_segment(first, last)]
    if len(centres) >= 3:
        mid = (len(centres) - 1) // 2
        on_line = first + mid / (len(centres) - 1) * (last - first)
        if np.linalg.norm(centres[mid] - on_line) > 1e-6:
            parts.append(_segment(on_line, centres[mid]))
    return np.concatenate(parts)


def target_offset(poses: Tensor) -> float:
    """Distance (m) of the middle frame's centre from the line through the first and last centres."""
    centres = poses[:, :3, 3].double()
    if len(centres) < 3:
        return 0.0
    a, b, m = centres[0], centres[-1], centres[(len(centres) - 1) // 2]
    u = b - a
    rel = m - a
    if float(u.norm()) < 1e-9:
        return float(rel.norm())
    u = u / u.norm()
    return float((rel - (rel @ u) * u).norm())


def _offset_target(scene: SynthScene, rng: np.random.Generator, cfg: SequenceConfig, start: np.ndarray,
                   direction: np.ndarray, spacing: float) -> np.ndarray | None:
    """Centre of the middle frame moved ``cfg.target_offset`` metres off the line, mostly sideways
    (within 45 degrees of the line's normal, random side), or ``None`` if it or the way there is blocked."""
    x0, x1, z0, z1 = scene.free_region
    on_line = start + cfg.middle * spacing * direction
    distance = rng.uniform(*cfg.target_offset)
    side = 1.0 if rng.uniform() < 0.5 else -1.0
    angle = rng.uniform(-math.pi / 4, math.pi / 4)
    normal = np.array([direction[2], 0.0, -direction[0]]) * side
    target = on_line + distance * (math.cos(angle) * normal + math.sin(angle) * direction)
    if not (x0 <= target[0] <= x1 and z0 <= target[2] <= z1):
        return None
    way = torch.from_numpy(_segment(on_line, target)).float()
    return target if bool(scene.clearance_ok(way, cfg.clearance).all()) else None


def sample_camera_line(scene: SynthScene, rng: np.random.Generator, cfg: SequenceConfig,
                       spacing: float) -> Tensor | None:
    """Poses ``(F, 4, 4)`` on a free segment, or ``None`` when ``cfg.attempts`` tries all fail.

    With ``cfg.target_offset`` the middle frame is moved off the segment (see :func:`_offset_target`);
    it and the way to it keep ``cfg.clearance`` like the segment itself."""
    x0, x1, z0, z1 = scene.free_region
    length = (cfg.frames - 1) * spacing
    steps = np.linspace(0.0, 1.0, max(2, int(math.ceil(length / 0.1)) + 1))
    # Only draws when enabled, so default datasets stay as they were.
    doorway = bool(cfg.through_doorways > 0 and scene.doorways and length > 0 and rng.uniform() < cfg.through_doorways)
    for attempt in range(cfg.attempts):
        height = rng.uniform(*cfg.height)
        if scene.ceiling_y is not None:
            height = min(height, -scene.ceiling_y - cfg.clearance - 0.05)
        if doorway and attempt < cfg.attempts // 2:  # then fall back to a free line
            dx, dz, nx, nz = scene.doorways[int(rng.integers(len(scene.doorways)))]
            heading = math.atan2(nx, nz) + (math.pi if rng.uniform() < 0.5 else 0.0) + rng.uniform(-0.6, 0.6)
            direction = np.array([math.sin(heading), 0.0, math.cos(heading)])
            start = np.array([dx, scene.floor_y - height, dz]) - rng.uniform(0.15, 0.85) * length * direction
        else:
            start = np.array([rng.uniform(x0, x1), scene.floor_y - height, rng.uniform(z0, z1)])
            heading = rng.uniform(0, 2 * math.pi)
            direction = np.array([math.sin(heading), 0.0, math.cos(heading)])
        end = start + length * direction
        if not (x0 <= end[0] <= x1 and z0 <= end[2] <= z1):
            continue
        path = torch.from_numpy(start + steps[:, None] * (end - start)[None]).float()
        if not bool(scene.clearance_ok(path, cfg.clearance).all()):
            continue
        moved = None
        if cfg.target_offset[1] > 0:  # draws nothing otherwise: default datasets stay as they were
            moved = _offset_target(scene, rng, cfg, start, direction, spacing)
            if moved is None:
                continue
        yaw = rng.uniform(0, 2 * math.pi) if cfg.random_yaw else 0.0
        c, s = math.cos(yaw), math.sin(yaw)
        rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # yaw about the (down) y axis
        centres = start + np.arange(cfg.frames)[:, None] * spacing * direction[None]
        if moved is not None:
            centres[cfg.middle] = moved
        return make_c2w(rot.expand(cfg.frames, 3, 3), torch.from_numpy(centres).float())
    return None


def generate_sequence(seed: int, index: int, cfg: SequenceConfig = SequenceConfig()) -> SynthSequence:
    """Scene ``index`` of dataset ``seed`` and its camera line (re-draws the scene if no line fits)."""
    rng = scene_rng(seed, index)
    for _ in range(50):
        scene = random_scene(rng, cfg.layouts, cfg.outdoor_fraction, cfg.layout_weights)
        spacing = float(rng.uniform(*cfg.spacing))
        poses = sample_camera_line(scene, rng, cfg, spacing)
        if poses is not None:
            if cfg.occluders:
                scene = add_occluders(scene, rng, camera_path(poses), cfg.occluders, cfg.clearance)
            return SynthSequence(scene, poses, spacing, seed)
    raise RuntimeError(f"could not place a {cfg.frames}-frame line with spacing {cfg.spacing} "
                       f"(seed {seed}, scene {index})")


def render_sequence(seq: SynthSequence, height: int, width: int) -> tuple[Tensor, Tensor]:
    """RGB ``(F, 3, H, W)`` and radial depth ``(F, H, W)`` of every frame."""
    views = [render_equirect_scene(seq.scene, pose, height, width) for pose in seq.poses]
    return torch.stack([v[0] for v in views]), torch.stack([v[1] for v in views])
