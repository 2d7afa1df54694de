"""Triton kernel of the render's deferred input checks (:mod:`.triton_checks`): every value check of the Gaussians
and the poses in one launch.

Imported lazily by :mod:`.triton_checks` (``TRITON_INTERPRET=1`` must be set before the first import to select
Triton's CPU interpreter). Program ``p`` reads elements ``p * FLAT .. (p + 1) * FLAT - 1`` of each flat Gaussian
tensor (the rotations as ``FLAT / 4`` whole quaternions); program 0 also reads every camera. Each compares in the
inputs' own float type (widened to float64, exactly; poses in float64 as the host's checks): no rounding, so the
kernel flags nothing the host's checks would pass. It raises
``flags[0]`` (an input problem) or ``flags[1]`` (a camera beyond the plausible distance) with one masked atomic.
"""

from __future__ import annotations

import triton
import triton.language as tl


@triton.jit
def _nonfinite(x):
    """Whether each of ``x`` is NaN or infinite (no arithmetic on it: no floating-point warnings in the interpreter)."""
    return (x != x) | (tl.abs(x) == float("inf"))


@triton.jit
def _widened(x):
    """``x`` in float64: exact for every float type (Triton's interpreter does not compare bfloat16), so each check
    decides as the host's check in the input's own type. The kernel is bound by memory, not arithmetic."""
    return x.to(tl.float64)


@triton.jit
def _any(bad):
    return tl.max(bad.to(tl.int32), axis=0)


@triton.jit
def _flat_problems(ptr, numel, start, FLAT: tl.constexpr):
    """``x``, ``on`` and the flag of non-finite values of elements ``start .. start + FLAT - 1`` of a flat tensor."""
    at = start + tl.arange(0, FLAT)
    on = at < numel
    x = _widened(tl.load(ptr + at, mask=on, other=0.0))
    return x, on, _any(on & _nonfinite(x))


@triton.jit
def input_checks_kernel(
    means_ptr, scales_ptr, rotations_ptr, opacities_ptr, sh_ptr, c2w_ptr, flags_ptr,
    num_gaussians, sh_numel, num_cameras, inv_atol, max_distance,
    FLAT: tl.constexpr, CAMERAS: tl.constexpr,
):
    pid = tl.program_id(0)
    start = pid.to(tl.int64) * FLAT
    _, _, bad = _flat_problems(means_ptr, 3 * num_gaussians, start, FLAT)
    scales, on, nonfinite = _flat_problems(scales_ptr, 3 * num_gaussians, start, FLAT)
    bad = tl.maximum(bad, tl.maximum(nonfinite, _any(on & (scales < 0))))
    opacities, on, nonfinite = _flat_problems(opacities_ptr, num_gaussians, start, FLAT)
    bad = tl.maximum(bad, tl.maximum(nonfinite, _any(on & ((opacities < 0) | (opacities > 1)))))
    _, _, nonfinite = _flat_problems(sh_ptr, sh_numel, start, FLAT)
    bad = tl.maximum(bad, nonfinite)
    # Rotations: the same elements as whole quaternions (rows of 4), for the zero quaternion.
    row = pid.to(tl.int64) * (FLAT // 4) + tl.arange(0, FLAT // 4)
    four = tl.arange(0, 4)
    on = row < num_gaussians
    q = _widened(tl.load(rotations_ptr + row[:, None] * 4 + four[None, :], mask=on[:, None], other=1.0))
    zero = tl.sum((q == 0).to(tl.int32), axis=1) == 4
    nonfinite = tl.max(on[:, None] & _nonfinite(q), axis=1)  # per quaternion
    bad = tl.maximum(bad, tl.maximum(_any(nonfinite), _any(on & zero)))
    far = bad * 0
    if pid == 0:
        for first in range(0, num_cameras, CAMERAS):
            pose_bad, pose_far = _pose_problems(c2w_ptr, first, num_cameras, inv_atol, max_distance, CAMERAS)
            bad = tl.maximum(bad, pose_bad)
            far = tl.maximum(far, pose_far)
    kind = flags_ptr.dtype.element_ty
    tl.atomic_max(flags_ptr, bad.to(kind), mask=bad > 0)
    tl.atomic_max(flags_ptr + 1, far.to(kind), mask=far > 0)


@triton.jit
def _pose_problems(c2w_ptr, first, num_cameras, inv_atol, max_distance, CAMERAS: tl.constexpr):
    """Cameras ``first .. first + CAMERAS - 1`` of the ``(C, 16)`` poses, in float64 as the host's checks:
    the flag of a problem (non-finite, rotation not orthonormal to ``1 / inv_atol``, a reflection, last row not [0,
    0, 0, 1] to ``1 / inv_atol``) and that of a camera beyond ``max_distance`` of the origin. The tolerance comes as
    its inverse, 1000, which float32 (Triton's type of a float argument) holds exactly, unlike 1e-3."""
    cam = first + tl.arange(0, CAMERAS)
    on = cam < num_cameras
    base = c2w_ptr + cam.to(tl.int64) * 16
    r00 = tl.load(base + 0, mask=on, other=1.0).to(tl.float64)
    r01 = tl.load(base + 1, mask=on, other=0.0).to(tl.float64)
    r02 = tl.load(base + 2, mask=on, other=0.0).to(tl.float64)
    tx = tl.load(base + 3, mask=on, other=0.0).to(tl.float64)
    r10 = tl.load(base + 4, mask=on, other=0.0).to(tl.float64)
    r11 = tl.load(base + 5, mask=on, other=1.0).to(tl.float64)
    r12 = tl.load(base + 6, mask=on, other=0.0).to(tl.float64)
    ty = tl.load(base + 7, mask=on, other=0.0).to(tl.float64)
    r20 = tl.load(base + 8, mask=on, other=0.0).to(tl.float64)
    r21 = tl.load(base + 9, mask=on, other=0.0).to(tl.float64)
    r22 = tl.load(base + 10, mask=on, other=1.0).to(tl.float64)
    tz = tl.load(base + 11, mask=on, other=0.0).to(tl.float64)
    l0 = tl.load(base + 12, mask=on, other=0.0).to(tl.float64)
    l1 = tl.load(base + 13, mask=on, other=0.0).to(tl.float64)
    l2 = tl.load(base + 14, mask=on, other=0.0).to(tl.float64)
    l3 = tl.load(base + 15, mask=on, other=1.0).to(tl.float64)
    nonfinite = (_nonfinite(r00) | _nonfinite(r01) | _nonfinite(r02) | _nonfinite(tx) | _nonfinite(r10)
                 | _nonfinite(r11) | _nonfinite(r12) | _nonfinite(ty) | _nonfinite(r20) | _nonfinite(r21)
                 | _nonfinite(r22) | _nonfinite(tz) | _nonfinite(l0) | _nonfinite(l1) | _nonfinite(l2)
                 | _nonfinite(l3))
    # |R R^T - I|, entry by entry (the symmetric ones once)
    err = tl.abs(r00 * r00 + r01 * r01 + r02 * r02 - 1.0)
    err = tl.maximum(err, tl.abs(r10 * r10 + r11 * r11 + r12 * r12 - 1.0))
    err = tl.maximum(err, tl.abs(r20 * r20 + r21 * r21 + r22 * r22 - 1.0))
    err = tl.maximum(err, tl.abs(r00 * r10 + r01 * r11 + r02 * r12))
    err = tl.maximum(err, tl.abs(r00 * r20 + r01 * r21 + r02 * r22))
    err = tl.maximum(err, tl.abs(r10 * r20 + r11 * r21 + r12 * r22))
    det = (r00 * (r11 * r22 - r12 * r21) + r01 * (r12 * r20 - r10 * r22) + r02 * (r10 * r21 - r11 * r20))
    last = tl.maximum(tl.maximum(tl.abs(l0), tl.abs(l1)), tl.maximum(tl.abs(l2), tl.abs(l3 - 1.0)))
    bad = nonfinite | (err * inv_atol > 1.0) | (det < 0) | (last * inv_atol > 1.0)
    far = tl.sqrt(tx * tx + ty * ty + tz * tz) > max_distance
    return _any(on & bad), _any(on & far)
