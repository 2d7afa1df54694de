"""Small Gaussian scenes and poses shared by the renderer tests."""

import math

import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry import make_c2w

F64 = torch.float64


def shell_scene(n, seed=0, scale=(0.1, 0.3), radius=(1.0, 3.0), sh_degree=0, dtype=F64):
    """Gaussians on a shell around the origin with distinct radial distances."""
    gen = torch.Generator().manual_seed(seed)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=dtype), dim=-1)
    dist = radius[0] + (radius[1] - radius[0]) * torch.rand(n, 1, generator=gen, dtype=dtype)
    k = (sh_degree + 1) ** 2
    return Gaussians(
        means=dirs * dist,
        scales=scale[0] + (scale[1] - scale[0]) * torch.rand(n, 3, generator=gen, dtype=dtype),
        rotations=torch.randn(n, 4, generator=gen, dtype=dtype),
        opacities=0.3 + 0.6 * torch.rand(n, generator=gen, dtype=dtype),
        sh=torch.randn(n, k, 3, generator=gen, dtype=dtype) * 0.4,
    )


def yaw_pose(angle, translation=(0.0, 0.0, 0.0), dtype=F64):
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]], dtype=dtype)
    return make_c2w(rot, torch.tensor(translation, dtype=dtype))


def degenerate_scenes():
    one = lambda *v: torch.tensor([v], dtype=torch.float32)  # noqa: E731
    q = one(1.0, 0.0, 0.0, 0.0)
    yield "zero scale", Gaussians.from_rgb(one(0.0, 0.0, 2.0), one(0.0, 0.0, 0.0), q, torch.ones(1), one(1, 1, 1))
    yield "huge scale", Gaussians.from_rgb(one(0.0, 0.0, 2.0), one(1e4, 1e4, 1e4), q, torch.ones(1), one(1, 1, 1))
    yield "at camera centre", Gaussians.from_rgb(one(0.0, 0.0, 0.0), one(0.1, 0.1, 0.1), q, torch.ones(1), one(1, 1, 1))
    yield "very close", Gaussians.from_rgb(one(0.0, 0.0, 0.011), one(0.1, 0.1, 0.1), q, torch.ones(1), one(1, 1, 1))
    yield "north pole", Gaussians.from_rgb(one(0.0, -2.0, 0.0), one(0.1, 0.1, 0.1), q, torch.ones(1), one(1, 1, 1))
    yield "south pole, flat", Gaussians.from_rgb(one(0.0, 1.0, 0.0), one(1.0, 1e-6, 1.0), q, torch.ones(1),
                                                 one(1, 1, 1))
    yield "unnormalised quaternion", Gaussians.from_rgb(one(1.0, 0.0, 2.0), one(0.1, 0.3, 0.1),
                                                        one(5.0, 1.0, -2.0, 0.5), torch.ones(1), one(1, 1, 1))
    yield "no gaussians", Gaussians.empty()
