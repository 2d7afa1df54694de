"""Model inputs shared by the model tests: random images, depths of 1-4 m, cameras with some yaw."""

import math

import torch

from cylindersplat.geometry import make_c2w


def make_inputs(views: int = 2, batch: int = 1, seed: int = 0, height: int = 64, width: int = 128):
    """``images (B, V, 3, H, W)``, ``depth (B, V, H, W)``, ``c2w (B, V, 4, 4)`` for a seed."""
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(batch, views, 3, height, width, generator=g)
    depth = 1.0 + 3.0 * torch.rand(batch, views, height, width, generator=g)
    poses = []
    for v in range(views):
        yaw = 0.3 * v
        rot = torch.tensor([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])
        poses.append(make_c2w(rot, torch.tensor([0.4 * v, 0.05 * v, -0.2 * v])))
    c2w = torch.stack(poses).expand(batch, -1, -1, -1).clone()
    return images, depth, c2w
