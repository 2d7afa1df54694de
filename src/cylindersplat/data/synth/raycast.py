"""Exact, vectorised ray casting of a :class:`SynthScene` and equirect rendering.

Each primitive type has a closed-form intersection evaluated for all (ray, primitive) pairs at
once; the nearest positive hit wins. Rays are processed in chunks to bound memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from ...geometry import equirect_rays
from .materials import shade_hits, sky_colour
from .scene import SynthScene

__all__ = ["Hits", "cast_rays", "render_equirect_scene"]

EPS = 1e-4
INF = float("inf")


@dataclass
class Hits:
    t: Tensor  # (N,) distance along the (unit) ray, inf = miss
    normal: Tensor  # (N, 3) unit normal facing the ray origin
    material: Tensor  # (N,) material index, -1 = miss


def _boxes(o: Tensor, d: Tensor, scene: SynthScene):
    if scene.box_lo.shape[0] == 0:
        return None
    # Slab test. Per axis, the entering plane is lo for rays going +, hi for rays going -; choosing
    # it by the ray's sign (instead of min/max of both) halves the (N, B) temporaries.
    inv = 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)  # (N, 3)
    lo, hi = scene.box_lo - o, scene.box_hi - o  # (B, 3)
    positive = d >= 0
    t_near = t_far = face = None
    for a in range(3):
        pos, inv_a = positive[:, a : a + 1], inv[:, a : a + 1]
        near_a = torch.where(pos, lo[:, a], hi[:, a]) * inv_a  # (N, B)
        far_a = torch.where(pos, hi[:, a], lo[:, a]) * inv_a
        if t_near is None:
            t_near, t_far, face = near_a, far_a, torch.zeros_like(near_a, dtype=torch.uint8)
        else:
            later = near_a > t_near
            t_near = torch.where(later, near_a, t_near)
            face = torch.where(later, a, face)  # axis of the entering face
            t_far = torch.minimum(t_far, far_a)
    hit = (t_far >= t_near) & (t_near > EPS)
    t_best, k = torch.where(hit, t_near, INF).min(-1)
    axis = face.gather(1, k[:, None]).long()
    normal = torch.zeros_like(d)
    normal.scatter_(1, axis, -torch.sign(d.gather(1, axis)))
    return t_best, normal, scene.box_mat[k]


def _spheres(o: Tensor, d: Tensor, scene: SynthScene):
    if scene.sphere_radius.shape[0] == 0:
        return None
    oc = o - scene.sphere_center  # (S, 3)
    b = d @ oc.T  # (N, S)
    c = (oc * oc).sum(-1) - scene.sphere_radius**2
    disc = b * b - c
    root = torch.sqrt(disc.clamp(min=0))
    t = -b - root
    t = torch.where(t > EPS, t, -b + root)
    t = torch.where((disc >= 0) & (t > EPS), t, INF)
    t_best, k = t.min(-1)
    p = o + t_best.clamp(max=1e6)[:, None] * d
    normal = torch.nn.functional.normalize(p - scene.sphere_center[k], dim=-1)
    return t_best, normal, scene.sphere_mat[k]


def _cylinders(o: Tensor, d: Tensor, scene: SynthScene):
    if scene.cyl_radius.shape[0] == 0:
        return None
    c = scene.cyl_center
    oc = (o - c)[:, [0, 2]]  # (C, 2)
    dxz = d[:, [0, 2]]  # (N, 2)
    a = (dxz * dxz).sum(-1, keepdim=True).clamp(min=1e-12)
    b = dxz @ oc.T
    cc = (oc * oc).sum(-1) - scene.cyl_radius**2
    disc = b * b - a * cc
    t_side = (-b - torch.sqrt(disc.clamp(min=0))) / a
    y_side = o[1] + t_side * d[:, 1:2]
    y0, y1 = scene.cyl_y[:, 0], scene.cyl_y[:, 1]
    side_ok = (disc >= 0) & (t_side > EPS) & (y_side >= y0) & (y_side <= y1)
    t_side = torch.where(side_ok, t_side, INF)
    # Caps: the cap facing the origin (origins are never inside a cylinder).
    cap_y = torch.where(o[1] < y0, y0, y1)
    dy = torch.where(d[:, 1:2].abs() < 1e-12, torch.full_like(d[:, 1:2], 1e-12), d[:, 1:2])
    t_cap = (cap_y - o[1]) / dy
    pxz = o[[0, 2]] + t_cap[..., None] * dxz[:, None, :]
    in_disc = ((pxz - c[:, [0, 2]]) ** 2).sum(-1) <= scene.cyl_radius**2
    t_cap = torch.where(in_disc & (t_cap > EPS), t_cap, INF)
    t = torch.minimum(t_side, t_cap)
    t_best, k = t.min(-1)
    on_cap = t_cap.gather(1, k[:, None])[:, 0] <= t_side.gather(1, k[:, None])[:, 0]
    p = o + t_best.clamp(max=1e6)[:, None] * d
    radial = p - c[k]
    radial[:, 1] = 0.0
    normal = torch.nn.functional.normalize(radial, dim=-1)
    cap_normal = torch.zeros_like(normal)
    cap_normal[:, 1] = -torch.sign(d[:, 1])
    normal = torch.where(on_cap[:, None], cap_normal, normal)
    return t_best, normal, scene.cyl_mat[k]


def _quads(o: Tensor, d: Tensor, scene: SynthScene):
    if scene.quad_origin.shape[0] == 0:
        return None
    n = torch.nn.functional.normalize(torch.cross(scene.quad_u, scene.quad_v, dim=-1), dim=-1)  # (Q, 3)
    denom = d @ n.T  # (N, Q)
    safe = torch.where(denom.abs() < 1e-12, torch.full_like(denom, 1e-12), denom)
    t = ((scene.quad_origin - o) * n).sum(-1) / safe
    rel = o - scene.quad_origin  # (Q, 3)
    # Point on plane minus origin = rel + t d; project on the (orthogonal) edges.
    uu = (scene.quad_u * scene.quad_u).sum(-1)
    vv = (scene.quad_v * scene.quad_v).sum(-1)
    su = ((rel * scene.quad_u).sum(-1) + t * (d @ scene.quad_u.T)) / uu
    sv = ((rel * scene.quad_v).sum(-1) + t * (d @ scene.quad_v.T)) / vv
    ok = (t > EPS) & (su >= 0) & (su <= 1) & (sv >= 0) & (sv <= 1)
    t = torch.where(ok, t, INF)
    t_best, k = t.min(-1)
    normal = n[k] * -torch.sign((d * n[k]).sum(-1, keepdim=True))  # two-sided: face the viewer
    return t_best, normal, scene.quad_mat[k]


def cast_rays(origin: Float[Tensor, "3"], directions: Float[Tensor, "N 3"], scene: SynthScene) -> Hits:
    """Nearest hit of unit rays ``directions`` from one ``origin`` against every primitive."""
    n = directions.shape[0]
    best_t = torch.full((n,), INF)
    best_n = torch.zeros(n, 3)
    best_m = torch.full((n,), -1, dtype=torch.long)
    for caster in (_boxes, _spheres, _cylinders, _quads):
        found = caster(origin, directions, scene)
        if found is None:
            continue
        t, normal, mat = found
        closer = t < best_t
        best_t = torch.where(closer, t, best_t)
        best_n = torch.where(closer[:, None], normal, best_n)
        best_m = torch.where(closer, mat, best_m)
    return Hits(best_t, best_n, best_m)


@torch.no_grad()
def render_equirect_scene(
    scene: SynthScene, c2w: Float[Tensor, "4 4"], height: int, width: int, chunk: int = 16384
) -> tuple[Float[Tensor, "3 H W"], Float[Tensor, "H W"]]:
    """Equirect RGB in ``[0, 1]`` and radial depth (0 where the ray escapes to the sky)."""
    c2w = c2w.float()
    rays = equirect_rays(height, width).reshape(-1, 3) @ c2w[:3, :3].T  # world-frame unit rays
    origin = c2w[:3, 3]
    rgb = torch.zeros(rays.shape[0], 3)
    depth = torch.zeros(rays.shape[0])
    for start in range(0, rays.shape[0], chunk):
        d = rays[start : start + chunk]
        hits = cast_rays(origin, d, scene)
        hit = torch.isfinite(hits.t)
        colour = torch.zeros(d.shape[0], 3)
        if hit.any():
            points = origin + hits.t[hit, None] * d[hit]
            colour[hit] = shade_hits(points, hits.normal[hit], hits.material[hit], scene.materials,
                                     scene.noise_table, scene.lighting)
        if scene.sky is not None and (~hit).any():
            colour[~hit] = sky_colour(d[~hit], scene.sky)
        rgb[start : start + chunk] = colour
        depth[start : start + chunk] = torch.where(hit, hits.t, torch.zeros_like(hits.t))
    return rgb.T.reshape(3, height, width), depth.reshape(height, width)
