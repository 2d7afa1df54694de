"""The Triton backend's deferred input checks (issue 35): :func:`.api.render`'s value checks of the Gaussians and
the poses in one kernel launch (:mod:`.triton_checks_kernels`) instead of some seventy small PyTorch operations.

:func:`queue_input_checks` has the contract of the torch checks it replaces (``api._queue_checks_torch``): the
structure (types, shapes, dtypes, devices) is checked now with the same errors; the values come back as device
flags ``[any problem, cameras too far]``, unread, which the backend reads with its pair count. A raised flag makes
the render check its inputs on the host, which names the problem, so the kernel flags exactly what those checks
flag: non-finite values, negative scales, opacities outside [0, 1], zero quaternions (all four components zero:
the host's norm of a quaternion below ~1e-22 also underflows to zero in float32; the kernel passes those, whose
rotation the projection clamps, rather than stop a render the host would then find nothing wrong with), poses not
rigid to 1e-3 (float64, as the host) and cameras beyond :data:`cylindersplat.validation.MAX_TRANSLATION_M`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry.poses import check_c2w_structure
from ..validation import MAX_TRANSLATION_M

__all__ = ["queue_input_checks"]

_FLAT = 1024  # elements of each flat Gaussian tensor per program (256 quaternions)
_CAMERAS = 32  # cameras per step of program 0's loop
POSE_ATOL = 1e-3  # as geometry.poses.c2w_problem_flags


def queue_input_checks(gaussians: Gaussians, c2w: Tensor) -> list[Tensor]:
    """Check the structure of ``gaussians`` and ``c2w`` now (raise); their values as int64 device flags ``[any
    problem, cameras too far]`` (0-dim, unread; int64 as the values they are read with), from one kernel launch."""
    import triton

    from . import triton_checks_kernels as kernels

    gaussians.check_structure()
    check_c2w_structure(c2w)
    flags = torch.zeros(2, dtype=torch.int64, device=gaussians.device)
    flat = {name: t.reshape(-1) for name, t in gaussians.tensors().items()}  # a copy only where not contiguous
    num_gaussians = flat["opacities"].numel()
    poses = c2w.reshape(-1, 16)
    widest = max(4 * num_gaussians, flat["sh"].numel(), 1)
    kernels.input_checks_kernel[(triton.cdiv(widest, _FLAT),)](
        flat["means"], flat["scales"], flat["rotations"], flat["opacities"], flat["sh"], poses, flags,
        num_gaussians, flat["sh"].numel(), len(poses), 1.0 / POSE_ATOL, MAX_TRANSLATION_M, FLAT=_FLAT, CAMERAS=_CAMERAS)
    return [flags[0], flags[1]]
