"""Cubemap face cameras: six 90-degree pinhole cameras sharing a panorama's centre.

Face order: ``+x, -x, +y, -y, +z, -z`` (camera-frame axis each face looks along). Each face is an
OpenCV pinhole camera (x right, y down, z forward) whose rotation to the panorama's camera frame is
``CUBEMAP_ROTATIONS[k]`` (columns = face right, down, forward).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["CUBEMAP_FACES", "cubemap_rotations", "cubemap_intrinsics", "cubemap_face_c2w"]

CUBEMAP_FACES = ("+x", "-x", "+y", "-y", "+z", "-z")

# (right, down, forward) of each face, in the panorama camera frame; right = down x forward.
_FACE_AXES = (
    ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
    ((0, 0, 1), (0, 1, 0), (-1, 0, 0)),
    ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ((-1, 0, 0), (0, 1, 0), (0, 0, -1)),
)


def cubemap_rotations(device=None, dtype=torch.float32) -> Tensor:
    """Face-to-panorama-camera rotations, shape ``(6, 3, 3)`` (columns: right, down, forward)."""
    axes = torch.tensor(_FACE_AXES, device=device, dtype=dtype)  # (6, 3 vectors, 3)
    return axes.transpose(-1, -2)


def cubemap_intrinsics(face_size: int, device=None, dtype=torch.float32) -> Tensor:
    """Pinhole intrinsics ``K`` (3x3) of a 90-degree face of ``face_size`` pixels."""
    f = face_size / 2.0
    return torch.tensor([[f, 0.0, face_size / 2.0], [0.0, f, face_size / 2.0], [0.0, 0.0, 1.0]], device=device,
                        dtype=dtype)


def cubemap_face_c2w(c2w: Tensor) -> Tensor:
    """Camera-to-world poses of the six faces: ``(..., 4, 4) -> (..., 6, 4, 4)``."""
    rot = cubemap_rotations(device=c2w.device, dtype=c2w.dtype)
    faces = c2w[..., None, :, :].expand(*c2w.shape[:-2], 6, 4, 4).clone()
    faces[..., :3, :3] = c2w[..., None, :3, :3] @ rot
    return faces
