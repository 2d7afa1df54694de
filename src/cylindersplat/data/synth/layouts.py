"""Random scene layouts: Manhattan indoor rooms (box, L-shape, two rooms with a doorway) with
furniture and non-Manhattan objects, and open outdoor scenes. All randomness comes from one
``numpy.random.Generator`` so a seed fixes the scene.
"""

from __future__ import annotations

import colorsys

import numpy as np
import torch

from .materials import PATTERNS, Lighting, Material, Sky
from .scene import SceneBuilder, SynthScene

__all__ = ["LAYOUTS", "OCCLUDER_KINDS", "random_material", "indoor_scene", "outdoor_scene", "random_scene",
           "add_occluders"]

LAYOUTS = ("room", "l_shape", "two_rooms", "outdoor")
WALL = 0.2  # slab thickness (m)


def _palette(rng: np.random.Generator, value=(0.35, 0.95), saturation=(0.05, 0.7)) -> tuple:
    """Two related colours: a random hue and a shifted, darker partner."""
    h = rng.uniform()
    s, v = rng.uniform(*saturation), rng.uniform(*value)
    a = colorsys.hsv_to_rgb(h, s, v)
    b = colorsys.hsv_to_rgb((h + rng.uniform(-0.15, 0.15)) % 1.0, min(1.0, s * rng.uniform(0.6, 1.5)),
                            v * rng.uniform(0.4, 0.8))
    return tuple(float(x) for x in a), tuple(float(x) for x in b)


def random_material(rng: np.random.Generator, patterns=PATTERNS, scale=(0.1, 0.8), **palette) -> Material:
    a, b = _palette(rng, **palette)
    direction = rng.normal(size=3)
    return Material(
        pattern=str(rng.choice(patterns)), color_a=a, color_b=b, scale=float(rng.uniform(*scale)),
        direction=tuple(float(x) for x in direction / np.linalg.norm(direction)),
        phase=tuple(float(x) for x in rng.uniform(0, 10, 3)),
        detail=float(rng.uniform(0.1, 0.35)), detail_scale=float(rng.uniform(0.02, 0.08)),
    )


def _lighting(rng: np.random.Generator) -> Lighting:
    az = rng.uniform(0, 2 * np.pi)
    return Lighting(direction=(float(np.cos(az)), -float(rng.uniform(0.8, 2.0)), float(np.sin(az))),
                    ambient=float(rng.uniform(0.3, 0.45)), diffuse=float(rng.uniform(0.35, 0.55)), dome=0.2)


def _furniture(b: SceneBuilder, rng, region, count: int) -> None:
    """Boxes, tables (top + legs), shelves against walls, resting on the floor (y = 0)."""
    x0, x1, z0, z1 = region
    for _ in range(count):
        mat = b.material(random_material(rng))
        w, dpt = rng.uniform(0.3, 1.6, 2)
        cx, cz = rng.uniform(x0 + w / 2, x1 - w / 2), rng.uniform(z0 + dpt / 2, z1 - dpt / 2)
        kind = rng.choice(["box", "table", "shelf"], p=[0.45, 0.3, 0.25])
        if kind == "table":
            top, leg = rng.uniform(0.65, 0.8), 0.05
            b.box((cx - w / 2, -top - 0.04, cz - dpt / 2), (cx + w / 2, -top, cz + dpt / 2), mat)
            for sx in (-1, 1):
                for sz in (-1, 1):
                    lx, lz = cx + sx * (w / 2 - leg), cz + sz * (dpt / 2 - leg)
                    b.box((lx - leg / 2, -top, lz - leg / 2), (lx + leg / 2, 0.0, lz + leg / 2), mat)
        elif kind == "shelf":  # tall and thin, pushed against a wall along x or z
            h = rng.uniform(1.2, 2.0)
            if rng.uniform() < 0.5:
                zs = z0 if rng.uniform() < 0.5 else z1 - 0.35
                b.box((cx - w / 2, -h, zs), (cx + w / 2, 0.0, zs + 0.35), mat)
            else:
                xs = x0 if rng.uniform() < 0.5 else x1 - 0.35
                b.box((xs, -h, cz - dpt / 2), (xs + 0.35, 0.0, cz + dpt / 2), mat)
        else:
            h = rng.uniform(0.3, 1.1)
            b.box((cx - w / 2, -h, cz - dpt / 2), (cx + w / 2, 0.0, cz + dpt / 2), mat)


def _non_manhattan(b: SceneBuilder, rng, region, ceiling: float | None) -> None:
    """Spheres, cylinders (columns or stools) and a slanted board leaning on something."""
    x0, x1, z0, z1 = region
    for _ in range(rng.integers(0, 3)):
        r = rng.uniform(0.15, 0.5)
        b.sphere((rng.uniform(x0 + r, x1 - r), -r - rng.choice([0.0, rng.uniform(0, 0.8)]),
                  rng.uniform(z0 + r, z1 - r)),
                 r, b.material(random_material(rng)))
    for _ in range(rng.integers(0, 3)):
        r = rng.uniform(0.1, 0.4)
        top = ceiling if (ceiling is not None and rng.uniform() < 0.5) else -rng.uniform(0.4, 1.2)
        b.cylinder(rng.uniform(x0 + r, x1 - r), rng.uniform(z0 + r, z1 - r), r, top, 0.0,
                   b.material(random_material(rng)))
    if rng.uniform() < 0.7:
        w, length, tilt = rng.uniform(0.5, 1.5), rng.uniform(1.0, 2.2), rng.uniform(0.2, 1.2)
        yaw = rng.uniform(0, 2 * np.pi)
        u = np.array([np.cos(yaw), 0.0, np.sin(yaw)]) * w
        up = np.array([-np.sin(yaw) * np.sin(tilt), -np.cos(tilt), np.cos(yaw) * np.sin(tilt)]) * length
        ox, oz = rng.uniform(x0 + 0.5, x1 - 0.5), rng.uniform(z0 + 0.5, z1 - 0.5)
        b.quad((ox, 0.0, oz), u, up, b.material(random_material(rng)))


def _paintings(b: SceneBuilder, rng, region, count: int) -> None:
    """Thin, busy-textured panels on the outer walls (high-frequency detail at eye level)."""
    x0, x1, z0, z1 = region
    for _ in range(count):
        mat = b.material(random_material(rng, patterns=("checker", "stripes", "noise"), scale=(0.03, 0.2)))
        w, h = rng.uniform(0.4, 1.2), rng.uniform(0.3, 0.9)
        yc = -rng.uniform(1.2, 1.8)
        wall = rng.integers(4)
        if wall < 2:
            x = rng.uniform(x0 + w / 2, x1 - w / 2)
            z = z0 if wall == 0 else z1 - 0.03
            b.box((x - w / 2, yc - h / 2, z), (x + w / 2, yc + h / 2, z + 0.03), mat)
        else:
            z = rng.uniform(z0 + w / 2, z1 - w / 2)
            x = x0 if wall == 2 else x1 - 0.03
            b.box((x, yc - h / 2, z - w / 2), (x + 0.03, yc + h / 2, z + w / 2), mat)


def indoor_scene(rng: np.random.Generator, layout: str = "room") -> SynthScene:
    """Closed Manhattan interior; ``layout`` in ``room``, ``l_shape``, ``two_rooms``."""
    b = SceneBuilder()
    sx = rng.uniform(6.0, 12.0) if layout == "two_rooms" else rng.uniform(3.0, 9.0)
    sz = rng.uniform(3.0, 9.0)
    height = rng.uniform(2.4, 3.2)
    x0, x1, z0, z1 = -sx / 2, sx / 2, -sz / 2, sz / 2
    floor = b.material(random_material(rng, patterns=("checker", "tiles", "stripes", "noise"), value=(0.3, 0.8)))
    ceiling = b.material(random_material(rng, patterns=("plain", "tiles"), value=(0.8, 1.0), saturation=(0.0, 0.1)))
    walls = b.material(random_material(rng, patterns=("plain", "stripes", "noise", "tiles"), value=(0.5, 0.95)))
    t = WALL
    b.box((x0 - t, 0.0, z0 - t), (x1 + t, t, z1 + t), floor)
    b.box((x0 - t, -height - t, z0 - t), (x1 + t, -height, z1 + t), ceiling)
    b.box((x0 - t, -height, z0 - t), (x0, 0.0, z1 + t), walls)
    b.box((x1, -height, z0 - t), (x1 + t, 0.0, z1 + t), walls)
    b.box((x0, -height, z0 - t), (x1, 0.0, z0), walls)
    b.box((x0, -height, z1), (x1, 0.0, z1 + t), walls)
    if layout == "l_shape":  # a solid block fills one corner
        cx, cz = rng.uniform(0.3, 0.5) * sx, rng.uniform(0.3, 0.5) * sz
        corner_x = (x1 - cx, x1) if rng.uniform() < 0.5 else (x0, x0 + cx)
        corner_z = (z1 - cz, z1) if rng.uniform() < 0.5 else (z0, z0 + cz)
        b.box((corner_x[0], -height, corner_z[0]), (corner_x[1], 0.0, corner_z[1]), walls)
    elif layout == "two_rooms":  # dividing wall along z with a doorway
        xs = x0 + rng.uniform(0.4, 0.6) * sx
        door_w, door_h = rng.uniform(0.9, 1.5), rng.uniform(2.0, min(2.3, height - 0.1))
        dz = rng.uniform(z0 + 0.2, z1 - 0.2 - door_w)
        inner = b.material(random_material(rng, patterns=("plain", "stripes", "noise"), value=(0.5, 0.95)))
        if dz - z0 > 1e-3:
            b.box((xs - t / 2, -height, z0), (xs + t / 2, 0.0, dz), inner)
        if z1 - (dz + door_w) > 1e-3:
            b.box((xs - t / 2, -height, dz + door_w), (xs + t / 2, 0.0, z1), inner)
        b.box((xs - t / 2, -height, dz), (xs + t / 2, -door_h, dz + door_w), inner)  # lintel
    doorways = ((float(xs), float(dz + door_w / 2), 1.0, 0.0),) if layout == "two_rooms" else ()
    region = (x0, x1, z0, z1)
    area = sx * sz
    _furniture(b, rng, region, int(rng.integers(2, 4 + area // 8)))
    _non_manhattan(b, rng, region, -height)
    _paintings(b, rng, region, int(rng.integers(1, 5)))
    return b.build(kind=f"indoor-{layout}", free_region=region, doorways=doorways, floor_y=0.0, ceiling_y=-height,
                   lighting=_lighting(rng), noise_table=_noise_table(rng))


def outdoor_scene(rng: np.random.Generator) -> SynthScene:
    """Open ground plane, sky gradient (depth 0), scattered buildings, trees, poles, rocks."""
    b = SceneBuilder()
    extent = 40.0
    ground = b.material(random_material(rng, patterns=("noise", "checker", "tiles"), scale=(0.3, 2.0),
                                        value=(0.3, 0.7)))
    b.box((-extent, 0.0, -extent), (extent, 0.5, extent), ground)
    for _ in range(rng.integers(6, 16)):
        dist, az = rng.uniform(2.5, 25.0), rng.uniform(0, 2 * np.pi)
        x, z = dist * np.cos(az), dist * np.sin(az)
        kind = rng.choice(["building", "tree", "pole", "rock"], p=[0.35, 0.3, 0.15, 0.2])
        mat = b.material(random_material(rng, scale=(0.2, 1.5)))
        if kind == "building":
            w, d, h = rng.uniform(1.5, 6.0), rng.uniform(1.5, 6.0), rng.uniform(2.0, 9.0)
            b.box((x - w / 2, -h, z - d / 2), (x + w / 2, 0.0, z + d / 2), mat)
        elif kind == "tree":
            trunk_h, crown = rng.uniform(1.5, 3.5), rng.uniform(0.8, 2.0)
            b.cylinder(x, z, rng.uniform(0.1, 0.3), -trunk_h, 0.0, mat)
            leaves = b.material(random_material(rng, patterns=("noise",), scale=(0.1, 0.4)))
            b.sphere((x, -trunk_h - crown * 0.7, z), crown, leaves)
        elif kind == "pole":
            b.cylinder(x, z, rng.uniform(0.05, 0.2), -rng.uniform(2.0, 5.0), 0.0, mat)
        else:
            r = rng.uniform(0.3, 1.2)
            b.sphere((x, -r * rng.uniform(0.3, 0.9), z), r, mat)
    if rng.uniform() < 0.7:  # a slanted roof-like panel
        w, length = rng.uniform(2.0, 5.0), rng.uniform(2.0, 4.0)
        ox, oz = rng.uniform(-15, 15, 2)
        if ox * ox + oz * oz > 9.0:
            b.quad((ox, 0.0, oz), (w, 0.0, 0.0), (0.0, -length * 0.6, length * 0.8), b.material(random_material(rng)))
    sky = Sky(horizon=tuple(float(x) for x in rng.uniform(0.75, 0.95, 3)),
              zenith=(float(rng.uniform(0.1, 0.35)), float(rng.uniform(0.3, 0.55)), float(rng.uniform(0.7, 0.95))))
    return b.build(kind="outdoor", sky=sky, free_region=(-6.0, 6.0, -6.0, 6.0), floor_y=0.0, ceiling_y=None,
                   lighting=_lighting(rng), noise_table=_noise_table(rng))


def _noise_table(rng: np.random.Generator) -> torch.Tensor:
    return torch.from_numpy(rng.uniform(size=(32, 32, 32)).astype(np.float32))


def random_scene(rng: np.random.Generator, layouts: tuple[str, ...] = LAYOUTS, outdoor_fraction: float = 0.2,
                 weights: tuple[float, ...] = ()) -> SynthScene:
    """One scene; ``outdoor`` with probability ``outdoor_fraction`` (if allowed), else an indoor layout,
    uniformly or, given ``weights`` (one per entry of ``layouts``; outdoor's is ignored), weighted."""
    unknown = set(layouts) - set(LAYOUTS)
    if unknown:
        raise ValueError(f"unknown layouts {sorted(unknown)}; choose from {LAYOUTS}")
    if weights and len(weights) != len(layouts):
        raise ValueError(f"need one layout weight per layout {layouts}, got {weights}")
    indoor = [name for name in layouts if name != "outdoor"]
    if "outdoor" in layouts and (not indoor or rng.uniform() < outdoor_fraction):
        return outdoor_scene(rng)
    if not weights:  # the original draw: keeps datasets of earlier versions reproducible
        return indoor_scene(rng, str(rng.choice(indoor)))
    w = np.array([float(x) for name, x in zip(layouts, weights) if name != "outdoor"])
    if (w < 0).any() or w.sum() <= 0:
        raise ValueError(f"layout weights must be >= 0 with a positive indoor sum, got {weights}")
    return indoor_scene(rng, str(rng.choice(indoor, p=w / w.sum())))


# -- occluders near the camera path ---------------------------------------------------------------

OCCLUDER_KINDS = {  # kind: probability, per setting
    "indoor": {"pillar": 0.2, "cabinet": 0.25, "screen": 0.2, "counter": 0.2, "plant": 0.15},
    "outdoor": {"wall": 0.3, "tree": 0.25, "shed": 0.2, "rock": 0.15, "pillar": 0.1},
}


def _occluder(b: SceneBuilder, rng: np.random.Generator, kind: str, ceiling: float | None):
    """Draw one occluder's shape; returns ``(half_x, half_z, height, place)`` where ``place(cx, cz)``
    adds its primitives (resting on the floor ``y = 0``, centred at ``(cx, cz)``) to ``b``."""
    mat = random_material(rng)
    swap = rng.uniform() < 0.5

    def oriented(long_half, short_half):
        return (short_half, long_half) if swap else (long_half, short_half)

    def box(hx, hz, h):
        return lambda cx, cz: b.box((cx - hx, -h, cz - hz), (cx + hx, 0.0, cz + hz), b.material(mat))

    if kind == "pillar":
        r = rng.uniform(0.12, 0.35)
        h = -ceiling if ceiling is not None else rng.uniform(2.5, 4.5)
        if rng.uniform() < 0.5:
            return r, r, h, lambda cx, cz: b.cylinder(cx, cz, r, -h, 0.0, b.material(mat))
        return r, r, h, box(r, r, h)
    if kind == "cabinet":
        hx, hz = oriented(rng.uniform(0.3, 0.7), rng.uniform(0.2, 0.35))
        h = rng.uniform(1.4, 2.1)
        return hx, hz, h, box(hx, hz, h)
    if kind == "screen":  # free-standing partition
        hx, hz = oriented(rng.uniform(0.5, 1.1), 0.03)
        h = rng.uniform(1.5, 1.95)
        return hx, hz, h, box(hx, hz, h)
    if kind == "counter":  # below eye level: hides the floor behind it
        hx, hz = oriented(rng.uniform(0.4, 1.0), rng.uniform(0.25, 0.45))
        h = rng.uniform(0.8, 1.1)
        return hx, hz, h, box(hx, hz, h)
    if kind == "wall":
        hx, hz = oriented(rng.uniform(1.0, 2.5), rng.uniform(0.1, 0.2))
        h = rng.uniform(1.0, 2.5)
        return hx, hz, h, box(hx, hz, h)
    if kind == "shed":
        hx, hz, h = rng.uniform(0.5, 1.2), rng.uniform(0.5, 1.2), rng.uniform(2.0, 3.0)
        return hx, hz, h, box(hx, hz, h)
    if kind == "rock":
        r = rng.uniform(0.4, 0.9)
        sink = rng.uniform(0.1, 0.5) * r
        return r, r, 2 * r - sink, lambda cx, cz: b.sphere((cx, -(r - sink), cz), r, b.material(mat))
    if kind in ("plant", "tree"):
        trunk = rng.uniform(0.08, 0.2)
        crown = rng.uniform(0.3, 0.5) if kind == "plant" else rng.uniform(0.7, 1.4)
        stem = rng.uniform(0.4, 0.7) if kind == "plant" else rng.uniform(1.5, 2.5)
        leaves = random_material(rng, patterns=("noise",), scale=(0.1, 0.4))

        def place(cx, cz):
            b.cylinder(cx, cz, trunk, -stem, 0.0, b.material(mat))
            b.sphere((cx, -stem - 0.8 * crown, cz), crown, b.material(leaves))

        return crown, crown, stem + 1.8 * crown, place
    raise ValueError(f"unknown occluder kind {kind!r}")


def add_occluders(scene: SynthScene, rng: np.random.Generator, path: np.ndarray, count: int, clearance: float,
                  reach: tuple[float, float] = (0.2, 1.2), tries: int = 40) -> SynthScene:
    """``scene`` plus up to ``count`` occluders (pillars, cabinets, screens, counters, plants; outdoors
    walls, trees, sheds, rocks) standing ``reach`` metres beyond ``clearance`` from the camera ``path``
    (points ``(P, 3)``), between the cameras and the walls, so they hide what lies behind them from some
    views. Each keeps ``clearance`` from every path point, stays inside the free region and does not
    cut into existing solids; one that finds no such place after ``tries`` draws is skipped."""
    x0, x1, z0, z1 = scene.free_region
    setting = "indoor" if scene.ceiling_y is not None else "outdoor"
    kinds = OCCLUDER_KINDS[setting]
    names, probs = list(kinds), np.array(list(kinds.values()))
    path_t = torch.as_tensor(np.asarray(path), dtype=torch.float32)
    for _ in range(count):
        for _ in range(tries):
            b = SceneBuilder()
            hx, hz, h, place = _occluder(b, rng, str(rng.choice(names, p=probs / probs.sum())), scene.ceiling_y)
            anchor = path[rng.integers(len(path))]
            angle = rng.uniform(0, 2 * np.pi)
            dist = clearance + rng.uniform(*reach) + max(hx, hz)
            cx, cz = anchor[0] + dist * np.cos(angle), anchor[2] + dist * np.sin(angle)
            if not (x0 + hx <= cx <= x1 - hx and z0 + hz <= cz <= z1 - hz):
                continue
            place(cx, cz)
            if not bool(b.build().clearance_ok(path_t, clearance).all()):
                continue
            # Footprint x height samples (<= 0.2 m apart) must lie outside every existing solid.
            gx = np.linspace(cx - hx, cx + hx, max(2, int(np.ceil(2 * hx / 0.2)) + 1))
            gz = np.linspace(cz - hz, cz + hz, max(2, int(np.ceil(2 * hz / 0.2)) + 1))
            gy = np.linspace(-0.1, -h + 0.1, max(2, int(np.ceil(h / 0.3)) + 1))
            grid = torch.tensor(np.stack(np.meshgrid(gx, gy, gz, indexing="ij"), -1).reshape(-1, 3),
                                dtype=torch.float32)
            if not bool(scene.clearance_ok(grid, 0.03).all()):
                continue
            scene = scene.extended(b)
            break
    return scene
