"""Rigid-pose helpers. Poses are camera-to-world (``c2w``) 4x4 matrices in the OpenCV frame."""

from __future__ import annotations

import torch
from jaxtyping import Float
from torch import Tensor

__all__ = [
    "validate_c2w",
    "c2w_problem_flags",
    "check_c2w_structure",
    "invert_rigid",
    "transform_points",
    "world_to_camera",
    "camera_to_world",
    "camera_centers",
    "look_at_c2w",
    "make_c2w",
]


def validate_c2w(c2w: Tensor, name: str = "c2w", atol: float = 1e-3) -> Tensor:
    """Check that ``c2w`` is a finite ``(..., 4, 4)`` rigid transform; return it unchanged.

    Raises ``ValueError`` naming the problem (shape, non-finite entries, non-orthonormal rotation,
    reflection instead of rotation, wrong last row).
    """
    flags, err = _c2w_checks(c2w, name, atol)
    if c2w.numel() and flags.any():  # one host synchronisation on a GPU, not one per check
        problems = [f"{name} contains non-finite values (NaN or Inf)",
                    f"{name} rotation part is not orthonormal (max |R R^T - I| = {float(err):.3g})",
                    f"{name} rotation part is a reflection (determinant -1), not a rotation; "
                    "check the handedness of the pose convention",
                    f"{name} last row must be [0, 0, 0, 1]"]
        raise ValueError(problems[int(flags.int().argmax())])
    return c2w


def c2w_problem_flags(c2w: Tensor, name: str = "c2w", atol: float = 1e-3) -> Tensor:
    """:func:`validate_c2w` without waiting for the device: type and shape are checked now (the same errors), the
    value checks come back as a device-side bool vector ``(4,)``, unread, true where a check fails
    (:func:`validate_c2w` then names the first)."""
    return _c2w_checks(c2w, name, atol)[0]


def _c2w_checks(c2w: Tensor, name: str, atol: float) -> tuple[Tensor, Tensor]:
    """Check type and shape (raise); the value checks' device-side flags ``(4,)`` in :func:`validate_c2w`'s order,
    and the largest ``|R R^T - I|``."""
    check_c2w_structure(c2w, name)
    if c2w.numel() == 0:
        return torch.zeros(4, dtype=torch.bool, device=c2w.device), torch.zeros((), device=c2w.device)
    rot = c2w[..., :3, :3].double()
    eye = torch.eye(3, dtype=rot.dtype, device=rot.device)
    err = (rot @ rot.transpose(-1, -2) - eye).abs().amax()
    last = c2w[..., 3, :].double()
    expected = torch.eye(4, dtype=last.dtype, device=last.device)[3]  # [0, 0, 0, 1], made on the device (no copy)
    finite = torch.isfinite(c2w).all()
    flags = torch.stack([~finite, finite & (err > atol), finite & (_det3(rot) < 0).any(),
                         finite & ((last - expected).abs().amax() > atol)])
    return flags, err


def check_c2w_structure(c2w: Tensor, name: str = "c2w") -> None:
    """The checks of :func:`validate_c2w` that need no values (type and shape): raise, without reading the device."""
    if not isinstance(c2w, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(c2w).__name__}")
    if c2w.ndim < 2 or c2w.shape[-2:] != (4, 4):
        raise ValueError(f"{name} must have shape (..., 4, 4), got {tuple(c2w.shape)}")


def _det3(m: Tensor) -> Tensor:
    """Determinants of 3x3 matrices ``(..., 3, 3)`` by the triple product (elementwise: no solver that may wait
    for the device)."""
    return (m[..., 0, :] * torch.linalg.cross(m[..., 1, :], m[..., 2, :])).sum(-1)


def invert_rigid(pose: Float[Tensor, "*batch 4 4"]) -> Float[Tensor, "*batch 4 4"]:
    """Inverse of a rigid transform using ``R^T`` (exact, differentiable)."""
    rot = pose[..., :3, :3]
    trans = pose[..., :3, 3:]
    rot_t = rot.transpose(-1, -2)
    out = torch.zeros_like(pose)
    out[..., :3, :3] = rot_t
    out[..., :3, 3:] = -rot_t @ trans
    out[..., 3, 3] = 1.0
    return out


def transform_points(pose: Float[Tensor, "*batch 4 4"], points: Float[Tensor, "*batch N 3"]) -> Tensor:
    """Apply a 4x4 transform to points ``(..., N, 3)``; batch dims broadcast."""
    return points @ pose[..., :3, :3].transpose(-1, -2) + pose[..., None, :3, 3]


def world_to_camera(points_world: Tensor, c2w: Tensor) -> Tensor:
    """World points ``(..., N, 3)`` -> camera frame of ``c2w`` ``(..., 4, 4)``."""
    rot = c2w[..., :3, :3]
    return (points_world - c2w[..., None, :3, 3]) @ rot


def camera_to_world(points_cam: Tensor, c2w: Tensor) -> Tensor:
    """Camera-frame points ``(..., N, 3)`` -> world frame."""
    return transform_points(c2w, points_cam)


def camera_centers(c2w: Tensor) -> Tensor:
    """Camera centres ``(..., 3)``."""
    return c2w[..., :3, 3]


def make_c2w(rotation: Tensor | None = None, translation: Tensor | None = None, dtype=torch.float32) -> Tensor:
    """Build a 4x4 ``c2w`` from a 3x3 rotation and 3-vector translation (either may be omitted)."""
    out = torch.eye(4, dtype=dtype)
    if rotation is not None:
        out = out.expand(*rotation.shape[:-2], 4, 4).clone().to(rotation.dtype)
        out[..., :3, :3] = rotation
    if translation is not None:
        if rotation is None:
            out = out.expand(*translation.shape[:-1], 4, 4).clone().to(translation.dtype)
        out[..., :3, 3] = translation
    return out


def look_at_c2w(eye: Tensor, target: Tensor, down: Tensor | None = None) -> Tensor:
    """OpenCV ``c2w`` at ``eye`` looking at ``target`` with camera +y as close to ``down`` as possible.

    ``down`` defaults to world +y (gravity-down convention of docs/conventions.md).
    """
    if down is None:
        down = torch.tensor([0.0, 1.0, 0.0], dtype=eye.dtype, device=eye.device).expand_as(eye)
    forward = torch.nn.functional.normalize(target - eye, dim=-1)
    right = torch.nn.functional.normalize(torch.cross(down, forward, dim=-1), dim=-1)
    new_down = torch.cross(forward, right, dim=-1)
    rot = torch.stack((right, new_down, forward), dim=-1)
    return make_c2w(rot, eye)
