"""Unit quaternions (``w, x, y, z``, Hamilton convention) <-> rotation matrices, and their product.

Shared by the renderer (Gaussian covariances) and the model (Gaussian frames in world space)."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = ["quaternion_multiply", "matrix_to_quaternion", "quaternion_to_matrix"]


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
    candidates = torch.stack(
        (
            torch.stack((big[..., 0] ** 2, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]), -1),
            torch.stack((m[..., 2, 1] - m[..., 1, 2], big[..., 1] ** 2, m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0]), -1),
            torch.stack((m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] + m[..., 0, 1], big[..., 2] ** 2, m[..., 2, 1] + m[..., 1, 2]), -1),
            torch.stack((m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2], big[..., 3] ** 2), -1),
        ),
        dim=-2,
    ) / (2 * big.unsqueeze(-1))
    best = four_sq.argmax(dim=-1)
    q = torch.gather(candidates, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = torch.nn.functional.normalize(q, dim=-1)
    return torch.where(q[..., :1] < 0, -q, q)
