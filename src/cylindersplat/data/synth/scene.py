"""Scene description of the procedural generator: solid primitives with materials.

World frame follows docs/conventions.md: metres, +y is gravity-down (the floor is the plane ``y = 0`` and the
ceiling is at ``y = -height``). Everything is a *solid* seen from outside: a room is the free space
left between floor, ceiling and wall slabs, so occlusions, doorways and L-shapes come for free.

Primitives, each stored as batched tensors (one row per primitive):

* axis-aligned boxes ``lo``/``hi`` ``(N, 3)``;
* spheres ``center`` ``(N, 3)``, ``radius`` ``(N,)``;
* vertical cylinders (axis along y) ``center`` ``(N, 3)`` (its y unused), ``radius``, ``y0 < y1``;
* two-sided rectangles (slanted planes) ``origin``, ``edge_u``, ``edge_v`` ``(N, 3)`` with
  ``edge_u`` orthogonal to ``edge_v``.

Each primitive refers to a :class:`~cylindersplat.data.synth.materials.Material` by index.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from .materials import Lighting, Material, Sky

__all__ = ["SceneBuilder", "SynthScene"]


@dataclass
class SynthScene:
    """Immutable, batched scene (build it with :class:`SceneBuilder`)."""

    box_lo: Tensor
    box_hi: Tensor
    box_mat: Tensor
    sphere_center: Tensor
    sphere_radius: Tensor
    sphere_mat: Tensor
    cyl_center: Tensor
    cyl_radius: Tensor
    cyl_y: Tensor  # (N, 2): y0, y1
    cyl_mat: Tensor
    quad_origin: Tensor
    quad_u: Tensor
    quad_v: Tensor
    quad_mat: Tensor
    materials: list[Material]
    sky: Sky | None = None  # None: rays that escape are black with depth 0 (indoor scenes are closed)
    kind: str = "indoor"
    free_region: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # x0, x1, z0, z1 for cameras
    doorways: tuple[tuple[float, float, float, float], ...] = ()  # (x, z, normal_x, normal_z): centre, through-axis
    floor_y: float = 0.0
    ceiling_y: float | None = None
    noise_table: Tensor = field(default_factory=lambda: torch.rand(32, 32, 32,
                                                                   generator=torch.Generator().manual_seed(0)))
    lighting: Lighting = Lighting()

    def num_primitives(self) -> int:
        return len(self.box_mat) + len(self.sphere_mat) + len(self.cyl_mat) + len(self.quad_mat)

    def clearance_ok(self, points: Tensor, margin: float) -> Tensor:
        """``(N,)`` bool: each point ``(N, 3)`` is at least ``margin`` away from every solid."""
        p = points[:, None, :]
        inside_box = ((p > self.box_lo - margin) & (p < self.box_hi + margin)).all(-1).any(-1)
        d_sphere = torch.linalg.vector_norm(p - self.sphere_center, dim=-1) - self.sphere_radius
        horiz = torch.linalg.vector_norm((p - self.cyl_center)[..., [0, 2]], dim=-1) - self.cyl_radius
        in_span = (p[..., 1] > self.cyl_y[:, 0] - margin) & (p[..., 1] < self.cyl_y[:, 1] + margin)
        near_cyl = (horiz < margin) & in_span
        rel = p - self.quad_origin
        su = (rel * self.quad_u).sum(-1) / (self.quad_u * self.quad_u).sum(-1)
        sv = (rel * self.quad_v).sum(-1) / (self.quad_v * self.quad_v).sum(-1)
        closest = self.quad_origin + su.clamp(0, 1)[..., None] * self.quad_u + sv.clamp(0, 1)[..., None] * self.quad_v
        d_quad = torch.linalg.vector_norm(p - closest, dim=-1)
        bad = inside_box | (d_sphere < margin).any(-1) | near_cyl.any(-1) | (d_quad < margin).any(-1)
        return ~bad

    def extended(self, extra: SceneBuilder) -> SynthScene:
        """This scene plus the primitives of ``extra`` (its material indices are local to ``extra``)."""
        if not extra.materials and not (extra.boxes or extra.spheres or extra.cylinders or extra.quads):
            return self
        add = extra.build()
        offset = len(self.materials)
        fields = {}
        for prefix, names in (("box", ("lo", "hi")), ("sphere", ("center", "radius")),
                              ("cyl", ("center", "radius", "y")), ("quad", ("origin", "u", "v"))):
            for name in names:
                key = f"{prefix}_{name}"
                fields[key] = torch.cat([getattr(self, key), getattr(add, key)])
            key = f"{prefix}_mat"
            fields[key] = torch.cat([getattr(self, key), getattr(add, key) + offset])
        return replace(self, materials=[*self.materials, *add.materials], **fields)


@dataclass
class SceneBuilder:
    """Accumulates primitives (python lists) and freezes them into a :class:`SynthScene`."""

    materials: list[Material] = field(default_factory=list)
    boxes: list = field(default_factory=list)
    spheres: list = field(default_factory=list)
    cylinders: list = field(default_factory=list)
    quads: list = field(default_factory=list)

    def material(self, material: Material) -> int:
        self.materials.append(material)
        return len(self.materials) - 1

    def box(self, lo, hi, mat: int) -> None:
        lo, hi = [float(x) for x in lo], [float(x) for x in hi]
        if any(a >= b for a, b in zip(lo, hi)):
            raise ValueError(f"degenerate box lo={lo} hi={hi}")
        self.boxes.append((lo, hi, mat))

    def sphere(self, center, radius: float, mat: int) -> None:
        self.spheres.append(([float(x) for x in center], float(radius), mat))

    def cylinder(self, center_x: float, center_z: float, radius: float, y0: float, y1: float, mat: int) -> None:
        self.cylinders.append(([float(center_x), 0.0, float(center_z)], float(radius), (float(y0), float(y1)), mat))

    def quad(self, origin, edge_u, edge_v, mat: int) -> None:
        self.quads.append(([float(x) for x in origin], [float(x) for x in edge_u], [float(x) for x in edge_v], mat))

    def build(self, **scene_fields) -> SynthScene:
        f32 = torch.float32

        def col(items, k, shape):
            return torch.tensor([it[k] for it in items], dtype=f32).reshape(shape)

        def mats(items):
            return torch.tensor([it[-1] for it in items], dtype=torch.long)

        b, s, c, q = self.boxes, self.spheres, self.cylinders, self.quads
        return SynthScene(
            box_lo=col(b, 0, (-1, 3)), box_hi=col(b, 1, (-1, 3)), box_mat=mats(b),
            sphere_center=col(s, 0, (-1, 3)), sphere_radius=col(s, 1, (-1,)), sphere_mat=mats(s),
            cyl_center=col(c, 0, (-1, 3)), cyl_radius=col(c, 1, (-1,)), cyl_y=col(c, 2, (-1, 2)), cyl_mat=mats(c),
            quad_origin=col(q, 0, (-1, 3)), quad_u=col(q, 1, (-1, 3)), quad_v=col(q, 2, (-1, 3)), quad_mat=mats(q),
            materials=list(self.materials), **scene_fields,
        )
