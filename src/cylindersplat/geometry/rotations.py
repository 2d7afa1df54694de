"""Rotations: unit quaternions (``w, x, y, z``, Hamilton convention) <-> matrices, their product, angle-axis
vectors and the nearest rotation to a matrix.

Shared by the renderer (Gaussian covariances), the model (Gaussian frames in world space) and the pose readers
(:mod:`cylindersplat.data.poses`: float64 poses from other tools' quaternion orders and angle-axis vectors)."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["quaternion_multiply", "matrix_to_quaternion", "quaternion_to_matrix", "quaternion_wxyz_to_matrix",
           "quaternion_xyzw_to_matrix", "axis_angle_to_matrix", "nearest_rotation"]


def quaternion_multiply(a: Float[Tensor, "*B 4"], b: Float[Tensor, "*B 4"]) -> Float[Tensor, "*B 4"]:
    """Hamilton product ``a * b`` (rotation ``b`` first, then ``a``)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def quaternion_to_matrix(q: Float[Tensor, "*B 4"], eps: float = 1e-12) -> Float[Tensor, "*B 3 3"]:
    """Rotation matrices from (not necessarily normalised) quaternions; a zero quaternion gives 0."""
    w, x, y, z = (q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(eps)).unbind(-1)
    rows = (
        torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), dim=-1),
        torch.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), dim=-1),
        torch.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), dim=-1),
    )
    return torch.stack(rows, dim=-2)


def matrix_to_quaternion(m: Float[Tensor, "*B 3 3"]) -> Float[Tensor, "*B 4"]:
    """Rotation matrix -> unit quaternion with ``w >= 0``.

    Computes all four candidate solutions (each well conditioned when its component is the
    largest) and keeps the best one, so it is stable for every rotation.
    """
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    four_sq = torch.stack(
        (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22), dim=-1
    )
    big = torch.sqrt(four_sq.clamp_min(1e-12))  # 2 * |component|
    d21, d02, d10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    s10, s02, s21 = m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]
    candidates = torch.stack(
        (
            torch.stack((big[..., 0] ** 2, d21, d02, d10), -1),
            torch.stack((d21, big[..., 1] ** 2, s10, s02), -1),
            torch.stack((d02, s10, big[..., 2] ** 2, s21), -1),
            torch.stack((d10, s02, s21, big[..., 3] ** 2), -1),
        ),
        dim=-2,
    ) / (2 * big.unsqueeze(-1))
    best = four_sq.argmax(dim=-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = torch.nn.functional.normalize(q, dim=-1)
    return torch.where(q[..., :1] < 0, -q, q)


def quaternion_wxyz_to_matrix(q: Sequence[float]) -> Float[Tensor, "3 3"]:
    """One quaternion ``(qw, qx, qy, qz)`` (COLMAP's order; normalised here) -> 3x3 rotation (float64);
    ``ValueError`` for a zero or non-finite one (:func:`quaternion_to_matrix` would give 0 or NaN)."""
    values = [float(v) for v in q]
    if len(values) != 4 or not all(math.isfinite(v) for v in values) or not math.hypot(*values) > 1e-9:
        raise ValueError(f"quaternion {q} has no length")
    return quaternion_to_matrix(torch.tensor(values, dtype=torch.float64))


def quaternion_xyzw_to_matrix(q: Sequence[float]) -> Float[Tensor, "3 3"]:
    """One quaternion ``(qx, qy, qz, qw)`` (TUM's order; normalised here) -> 3x3 rotation (float64)."""
    x, y, z, w = q
    return quaternion_wxyz_to_matrix((w, x, y, z))


def axis_angle_to_matrix(r: Sequence[float]) -> Float[Tensor, "3 3"]:
    """Rodrigues: rotation vector (axis * angle in radians) -> 3x3 rotation (float64)."""
    r = torch.as_tensor(r, dtype=torch.float64)
    angle = float(torch.linalg.vector_norm(r))
    if angle < 1e-12:
        return torch.eye(3, dtype=torch.float64)
    k = r / angle
    kx = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def nearest_rotation(m: Float[np.ndarray, "3 3"]) -> Float[np.ndarray, "3 3"]:
    """The rotation nearest to ``m`` in the Frobenius sense (SVD, determinant +1): the chordal mean of a sum of
    rotations."""
    u, _, vt = np.linalg.svd(m)
    return u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
