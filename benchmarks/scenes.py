"""Random scenes for benchmarks: Gaussians on the walls, floor and ceiling of a box room."""

from __future__ import annotations

import torch

from cylindersplat.gaussians import Gaussians


def indoor_gaussians(num: int, room=(8.0, 3.0, 6.0), seed: int = 0, device="cpu") -> Gaussians:
    """``num`` Gaussians in an ``x * y * z`` room centred on the origin (camera height ~mid-room),
    80% flattened on the six surfaces, 20% scattered inside as "furniture"; scales 1-8 cm."""
    gen = torch.Generator().manual_seed(seed)
    size = torch.tensor(room)
    n_surf = int(num * 0.8)
    pts = (torch.rand(num, 3, generator=gen) - 0.5) * size
    face = torch.randint(0, 6, (n_surf,), generator=gen)
    axis, sign = face // 2, (face % 2) * 2 - 1
    pts[torch.arange(n_surf), axis] = sign.float() * size[axis] / 2
    scales = torch.rand(num, 3, generator=gen) * 0.07 + 0.01
    scales[torch.arange(n_surf), axis] = 0.005  # flat on the wall
    rot = torch.nn.functional.normalize(torch.randn(num, 4, generator=gen), dim=-1)
    rot[:n_surf] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    opac = torch.rand(num, generator=gen) * 0.7 + 0.3
    rgb = torch.rand(num, 3, generator=gen)
    return Gaussians.from_rgb(pts, scales, rot, opac, rgb).to(device)
