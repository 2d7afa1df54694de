"""Built-in Gaussian scenes (no download needed): a textured demo room and a random indoor layout.

Coordinates follow docs/conventions.md: world +y is down, the camera sits at the origin about 1.6 m above the
floor, metres throughout.
"""

from __future__ import annotations

import math

import torch

from .gaussians import Gaussians

__all__ = ["demo_room", "random_indoor"]


def _surface(
    origin, axis_a, axis_b, n_a: int, n_b: int, color_fn, thickness: float = 0.01
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A rectangle ``origin + s*axis_a + t*axis_b`` covered by a grid of flat Gaussians."""
    origin, axis_a, axis_b = (torch.tensor(x, dtype=torch.float32) for x in (origin, axis_a, axis_b))
    s = (torch.arange(n_a) + 0.5) / n_a
    t = (torch.arange(n_b) + 0.5) / n_b
    ss, tt = torch.meshgrid(s, t, indexing="ij")
    means = origin + ss.reshape(-1, 1) * axis_a + tt.reshape(-1, 1) * axis_b
    step_a, step_b = axis_a.norm() / n_a, axis_b.norm() / n_b
    normal = torch.linalg.cross(axis_a, axis_b)
    # Scales along the world axes: the surface's own extents, thin along its normal.
    scales = torch.empty(len(means), 3)
    for i in range(3):
        scales[:, i] = 0.6 * float(abs(axis_a[i]) / axis_a.norm() * step_a + abs(axis_b[i]) / axis_b.norm() * step_b)
    scales[:, int(normal.abs().argmax())] = thickness
    colors = color_fn(ss.reshape(-1) * axis_a.norm(), tt.reshape(-1) * axis_b.norm())
    rot = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(len(means), 4)
    return means, scales.clamp_min(thickness), rot, colors


def _checker(c0, c1, period: float):
    c0, c1 = torch.tensor(c0), torch.tensor(c1)

    def fn(a, b):
        mask = ((torch.floor(a / period) + torch.floor(b / period)) % 2)[:, None]
        return c0 * (1 - mask) + c1 * mask

    return fn


def _stripes(c0, c1, period: float):
    c0, c1 = torch.tensor(c0), torch.tensor(c1)

    def fn(a, b):
        w = (0.5 + 0.5 * torch.sin(2 * math.pi * a / period))[:, None]
        return c0 * (1 - w) + c1 * w

    return fn


def demo_room(density: float = 12.0) -> Gaussians:
    """A 6 x 2.8 x 5 m room: checkered floor, striped walls, a ceiling, a table-like box and three
    coloured balls. ``density`` is Gaussians per metre along each surface axis (12 -> ~20k)."""
    half_x, half_z, floor_y, ceil_y = 3.0, 2.5, 1.6, -1.2
    n = lambda length: max(int(length * density), 1)  # noqa: E731
    parts = [
        _surface((-half_x, floor_y, -half_z), (2 * half_x, 0, 0), (0, 0, 2 * half_z), n(6), n(5),
                 _checker((0.85, 0.8, 0.7), (0.25, 0.2, 0.18), 0.5)),
        _surface((-half_x, ceil_y, -half_z), (2 * half_x, 0, 0), (0, 0, 2 * half_z), n(6), n(5),
                 _checker((0.95, 0.95, 0.95), (0.8, 0.8, 0.85), 1.0)),
        _surface((-half_x, ceil_y, half_z), (2 * half_x, 0, 0), (0, 2.8, 0), n(6), n(2.8),
                 _stripes((0.8, 0.3, 0.2), (0.95, 0.8, 0.5), 0.6)),
        _surface((-half_x, ceil_y, -half_z), (2 * half_x, 0, 0), (0, 2.8, 0), n(6), n(2.8),
                 _stripes((0.2, 0.4, 0.7), (0.8, 0.9, 0.95), 0.4)),
        _surface((half_x, ceil_y, -half_z), (0, 0, 2 * half_z), (0, 2.8, 0), n(5), n(2.8),
                 _stripes((0.3, 0.6, 0.3), (0.9, 0.95, 0.8), 0.8)),
        _surface((-half_x, ceil_y, -half_z), (0, 0, 2 * half_z), (0, 2.8, 0), n(5), n(2.8),
                 _checker((0.9, 0.85, 0.4), (0.5, 0.35, 0.2), 0.35)),
        # a table top and its front
        _surface((0.5, 0.85, 0.8), (1.2, 0, 0), (0, 0, 0.8), n(1.2), n(0.8),
                 _checker((0.55, 0.35, 0.2), (0.45, 0.28, 0.15), 0.2)),
        _surface((0.5, 0.85, 0.8), (1.2, 0, 0), (0, 0.75, 0), n(1.2), n(0.75),
                 _stripes((0.5, 0.3, 0.15), (0.35, 0.2, 0.1), 0.3)),
    ]
    means, scales, rots, colors = (torch.cat([p[i] for p in parts]) for i in range(4))
    balls = []
    gen = torch.Generator().manual_seed(0)
    for centre, color in (((-1.5, 1.2, 1.5), (0.9, 0.1, 0.1)), ((-1.0, 1.3, -1.6), (0.1, 0.7, 0.2)),
                          ((1.8, 1.25, -1.2), (0.15, 0.3, 0.95))):
        pts = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen), dim=-1) * 0.35 + torch.tensor(centre)
        shade = 0.6 + 0.4 * (-(pts[:, 1] - centre[1]) / 0.35).clamp(-1, 1)[:, None]  # lit from above
        balls.append((pts, torch.full((400, 3), 0.06), shade * torch.tensor(color)))
    means = torch.cat([means] + [b[0] for b in balls])
    scales = torch.cat([scales] + [b[1] for b in balls])
    colors = torch.cat([colors] + [b[2] for b in balls])
    rots = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(len(means), 4).clone()
    return Gaussians.from_rgb(means, scales, rots, torch.full((len(means),), 0.95), colors.clamp(0, 1))


def random_indoor(num: int, room=(8.0, 3.0, 6.0), seed: int = 0) -> Gaussians:
    """``num`` Gaussians in an ``x * y * z`` room centred on the origin: 80% flat on its six
    surfaces, 20% scattered inside ("furniture"); scales 1-8 cm, random colours (benchmarks)."""
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
    return Gaussians.from_rgb(pts, scales, rot, opac, rgb)
