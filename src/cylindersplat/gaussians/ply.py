"""PLY I/O in the standard 3DGS layout (as written by the original 3DGS code and read by SuperSplat,
the antimatter15 viewer, gsplat's tools, ...).

Vertex properties, all ``float``: ``x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity
scale_0..2 rot_0..3``, with

* normals written as zeros,
* ``f_rest`` channel-major: all coefficients of R, then G, then B,
* ``opacity`` stored as a logit, ``scale_*`` as natural logs, ``rot_*`` as ``(w, x, y, z)``.

A save -> load round trip reproduces the float32 values up to the logit/log transforms' rounding
(opacities are clamped to ``[1e-6, 1 - 1e-6]`` and scales to ``>= 1e-12`` before the transforms,
so degenerate values stay finite).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from ..utils.atomic import atomic_path
from .container import Gaussians, sh_degree_from_count

__all__ = ["save_ply", "load_ply"]

_OPACITY_EPS = 1e-6


def _attribute_names(num_rest: int) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(num_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names


def save_ply(gaussians: Gaussians, path: str | Path) -> Path:
    """Write unbatched ``gaussians`` to ``path`` (binary little-endian PLY). Returns the path."""
    if gaussians.batch_shape:
        raise ValueError(f"save_ply takes unbatched Gaussians, got batch shape {tuple(gaussians.batch_shape)}")
    g = gaussians.detach().to("cpu", torch.float32).validate()
    n, k = g.num_gaussians, g.sh.shape[-2]
    sh = g.sh.numpy()
    f_dc = sh[:, 0, :]
    f_rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (k - 1))  # channel-major
    opac = np.clip(g.opacities.numpy(), _OPACITY_EPS, 1 - _OPACITY_EPS)
    columns = [
        g.means.numpy(),
        np.zeros((n, 3), np.float32),
        f_dc,
        f_rest,
        np.log(opac / (1 - opac))[:, None],
        np.log(np.maximum(g.scales.numpy(), 1e-12)),
        g.rotations.numpy(),
    ]
    data = np.concatenate(columns, axis=1).astype(np.float32)
    names = _attribute_names(3 * (k - 1))
    vertex = np.empty(n, dtype=[(name, "f4") for name in names])
    for i, name in enumerate(names):
        vertex[name] = data[:, i]
    path = Path(path)
    with atomic_path(path) as tmp:  # a failed write leaves an earlier file at `path` intact
        PlyData([PlyElement.describe(vertex, "vertex")]).write(str(tmp))
    return path


def load_ply(path: str | Path, device=None, dtype=torch.float32) -> Gaussians:
    """Read a standard 3DGS PLY (see module docstring) into :class:`Gaussians`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"PLY file not found: {path}")
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"]
    except Exception as exc:  # plyfile raises several types for corrupt files
        raise ValueError(f"could not read a 3DGS PLY from {path}: {exc}") from exc
    props = {p.name for p in vertex.properties}
    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0",
                "rot_1", "rot_2", "rot_3"]
    missing = [name for name in required if name not in props]
    if missing:
        raise ValueError(f"{path} is not a 3DGS PLY: missing vertex properties {missing}")
    num_rest = len([p for p in props if p.startswith("f_rest_")])
    k = 1 + num_rest // 3
    sh_degree_from_count(k)
    col = lambda name: np.asarray(vertex[name], dtype=np.float32)  # noqa: E731
    stack = lambda names: np.stack([col(nm) for nm in names], axis=-1)  # noqa: E731
    n = len(vertex.data)
    f_dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])[:, None, :]
    if num_rest:
        f_rest = stack([f"f_rest_{i}" for i in range(num_rest)]).reshape(n, 3, k - 1).transpose(0, 2, 1)
        sh = np.concatenate([f_dc, f_rest], axis=1)
    else:
        sh = f_dc
    fields = {"position (x, y, z)": stack(["x", "y", "z"]), "colour (f_dc_*, f_rest_*)": sh, "opacity": col("opacity"),
              "scale (scale_*)": stack(["scale_0", "scale_1", "scale_2"]),
              "rotation (rot_*)": stack(["rot_0", "rot_1", "rot_2", "rot_3"])}
    for name, values in fields.items():
        bad = ~np.isfinite(values).reshape(n, -1).all(axis=1)
        if bad.any():
            raise ValueError(f"{path}: {int(bad.sum())} of {n} Gaussians have a non-finite {name}, e.g. "
                             f"vertex {int(np.argmax(bad))}")
    log_scales = fields["scale (scale_*)"].astype(np.float64)
    if (log_scales > 30).any():  # exp(30) m = 1e13 m: an overflowing or corrupt scale, not a scene
        raise ValueError(f"{path}: scale_* (log standard deviation) up to {log_scales.max():.3g}; values "
                         "above 30 are not plausible")
    if n and (np.linalg.norm(fields["rotation (rot_*)"], axis=1) == 0).any():
        raise ValueError(f"{path}: a Gaussian has the zero quaternion as rotation (rot_0..rot_3 all 0)")
    opacity = 1.0 / (1.0 + np.exp(-col("opacity").astype(np.float64)))
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device=device, dtype=dtype)  # noqa: E731
    return Gaussians(
        means=t(fields["position (x, y, z)"]),
        scales=t(np.exp(log_scales)),
        rotations=t(fields["rotation (rot_*)"]),
        opacities=t(opacity),
        sh=t(sh),
    )
