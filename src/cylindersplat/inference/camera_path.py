"""Camera paths for fly-throughs: smooth interpolation of c2w poses through the input cameras."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

from ..geometry.rotations import matrix_to_quaternion, quaternion_to_matrix

__all__ = ["slerp", "interpolate_poses", "flythrough_path", "midpoint_poses"]


def slerp(q0: Float[Tensor, "4"], q1: Float[Tensor, "4"], t: Float[Tensor, " K"]) -> Float[Tensor, "K 4"]:
    """Spherical linear interpolation of unit quaternions along the shorter arc."""
    dot = (q0 * q1).sum()
    if dot < 0:  # q and -q are the same rotation; take the short way round
        q1, dot = -q1, -dot
    t = t[:, None]
    if dot > 0.9995:  # nearly parallel: lerp is exact enough and avoids 0/0
        q = (1 - t) * q0 + t * q1
    else:
        theta = torch.arccos(dot.clamp(-1, 1))
        q = (torch.sin((1 - t) * theta) * q0 + torch.sin(t * theta) * q1) / torch.sin(theta)
    return q / q.norm(dim=-1, keepdim=True)


def interpolate_poses(a: Float[Tensor, "4 4"], b: Float[Tensor, "4 4"],
                      t: Float[Tensor, " K"]) -> Float[Tensor, "K 4 4"]:
    """Poses at fractions ``t`` from ``a`` to ``b``: linear centres, slerped rotations."""
    qa, qb = matrix_to_quaternion(a[:3, :3]), matrix_to_quaternion(b[:3, :3])
    out = torch.eye(4, dtype=a.dtype).repeat(len(t), 1, 1)
    out[:, :3, :3] = quaternion_to_matrix(slerp(qa, qb, t))
    out[:, :3, 3] = (1 - t[:, None]) * a[:3, 3] + t[:, None] * b[:3, 3]
    return out


def _eased(n: int) -> Tensor:
    """``n`` fractions in ``[0, 1)`` with smooth (cosine) speed so segments join without jerks."""
    t = torch.arange(n, dtype=torch.float64) / n
    return ((1 - torch.cos(torch.pi * t)) / 2).float()


def flythrough_path(c2w: Float[Tensor, "V 4 4"], frames: int = 48, loop: bool = True) -> Float[Tensor, "K 4 4"]:
    """``frames`` poses through the cameras in order (and back when ``loop``), eased per segment.

    One camera gives a full turn in place (yaw about the camera's own up axis).
    """
    c2w = c2w.float().cpu()
    if frames < 2:
        raise ValueError(f"a fly-through needs at least 2 frames, got {frames}")
    if len(c2w) == 1:
        angle = torch.arange(frames) / frames * 2 * torch.pi
        yaw = torch.zeros(frames, 4, 4)
        yaw[:, 0, 0], yaw[:, 0, 2], yaw[:, 2, 0], yaw[:, 2, 2] = angle.cos(), angle.sin(), -angle.sin(), angle.cos()
        yaw[:, 1, 1] = yaw[:, 3, 3] = 1
        return c2w[0] @ yaw
    stops = list(c2w) + (list(c2w.flip(0))[1:] if loop else [])
    segments = len(stops) - 1
    counts = [frames // segments + (1 if i < frames % segments else 0) for i in range(segments)]
    path = [interpolate_poses(stops[i], stops[i + 1], _eased(n)) for i, n in enumerate(counts) if n]
    if not loop:  # end exactly on the last camera
        path.append(stops[-1][None])
    return torch.cat(path)[:frames] if loop else torch.cat(path)


def midpoint_poses(c2w: Float[Tensor, "V 4 4"]) -> Float[Tensor, "V-1 4 4"]:
    """Poses halfway between consecutive cameras (default novel views); one camera -> itself."""
    if len(c2w) == 1:
        return c2w.clone()
    half = torch.tensor([0.5])
    return torch.cat([interpolate_poses(c2w[i], c2w[i + 1], half) for i in range(len(c2w) - 1)])
