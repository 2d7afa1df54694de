"""The compact ``.splat`` format read by web 3DGS viewers (antimatter15/splat, SuperSplat import).

32 bytes per Gaussian, little endian, no header: position ``3 x float32``, scale ``3 x float32``
(standard deviations, not logs), colour ``4 x uint8`` (RGB of the degree-0 SH, alpha = opacity) and
rotation ``4 x uint8`` (unit quaternion ``w, x, y, z`` mapped from ``[-1, 1]`` to ``[0, 255]`` by
``q * 128 + 128``). Higher SH degrees are dropped. Gaussians are written by decreasing
``opacity x volume``, the order those viewers expect for progressive loading. ~5x smaller than PLY.
Read back by :func:`load_splat` (colours and opacities to 1/255, rotations to 1/128 per component).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..utils.atomic import atomic_path
from .container import Gaussians, sh0_to_rgb

__all__ = ["save_splat", "load_splat", "SPLAT_DTYPE"]

SPLAT_DTYPE = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])


def save_splat(gaussians: Gaussians, path: str | Path) -> Path:
    """Write unbatched ``gaussians`` as a ``.splat`` file. Returns the path."""
    if gaussians.batch_shape:
        raise ValueError(f"save_splat takes unbatched Gaussians, got batch shape {tuple(gaussians.batch_shape)}")
    g = gaussians.detach().to("cpu", torch.float32).validate()
    rgb = sh0_to_rgb(g.sh[:, 0, :]).clamp(0, 1)
    quat = torch.nn.functional.normalize(g.rotations, dim=-1)
    order = torch.argsort(-(g.opacities * g.scales.prod(dim=-1)), stable=True)
    data = np.empty(len(g), dtype=SPLAT_DTYPE)
    data["position"] = g.means[order].numpy()
    data["scale"] = g.scales[order].numpy()
    rgba = torch.cat((rgb, g.opacities[:, None]), dim=-1)[order]
    data["rgba"] = (rgba * 255 + 0.5).clamp(0, 255).to(torch.uint8).numpy()
    data["rotation"] = (quat[order] * 128 + 128).round().clamp(0, 255).to(torch.uint8).numpy()
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.tobytes())
    return path


def load_splat(path: str | Path, device=None, dtype=torch.float32) -> Gaussians:
    """Read a ``.splat`` file (any writer of the layout above) as degree-0 :class:`Gaussians`; a file whose size is
    not a multiple of 32 bytes, or with non-finite or non-positive values, raises ``ValueError`` naming it."""
    path = Path(path)
    raw = path.read_bytes()
    if len(raw) % SPLAT_DTYPE.itemsize:
        raise ValueError(f"{path}: {len(raw)} bytes is not a whole number of 32-byte .splat "
                         "records; is it a .splat file?")
    data = np.frombuffer(raw, dtype=SPLAT_DTYPE)
    means = torch.from_numpy(data["position"].astype(np.float32))
    scales = torch.from_numpy(data["scale"].astype(np.float32))
    rgba = torch.from_numpy(data["rgba"].astype(np.float32)) / 255
    rotations = (torch.from_numpy(data["rotation"].astype(np.float32)) - 128) / 128
    if not (torch.isfinite(means).all() and torch.isfinite(scales).all()) or (scales < 0).any():
        raise ValueError(f"{path}: non-finite positions or negative scales; is it a .splat file?")
    # A quaternion quantised to zero (a corrupt record) would render as nothing useful: make it the identity.
    rotations[rotations.norm(dim=-1) == 0] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    gaussians = Gaussians.from_rgb(means, scales.clamp_min(1e-12), torch.nn.functional.normalize(rotations, dim=-1),
                                   rgba[:, 3], rgba[:, :3])
    return gaussians.to(device=device, dtype=dtype)
