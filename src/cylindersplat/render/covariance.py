"""3D covariance from scales and quaternions, and spherical-harmonic colour evaluation."""

from __future__ import annotations

from jaxtyping import Float
from torch import Tensor

from ..geometry.rotations import quaternion_to_matrix

__all__ = ["covariance_3d", "eval_sh"]


def covariance_3d(scales: Float[Tensor, "*batch 3"], quat: Float[Tensor, "*batch 4"]) -> Float[Tensor, "*batch 3 3"]:
    """``Sigma = R diag(s^2) R^T`` with ``s`` the standard deviations."""
    rot = quaternion_to_matrix(quat)
    m = rot * scales[..., None, :]
    return m @ m.transpose(-1, -2)


# Real spherical-harmonic basis constants of the reference 3DGS implementation.
_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def eval_sh(sh: Float[Tensor, "*batch K 3"], dirs: Float[Tensor, "*batch 3"]) -> Float[Tensor, "*batch 3"]:
    """Colour ``max(SH(dirs) + 0.5, 0)`` for unit view directions (camera -> Gaussian); ``dirs`` may be
    ``None`` for degree 0 (view-independent)."""
    k = sh.shape[-2]
    out = _C0 * (sh.squeeze(-2) if k == 1 else sh[..., 0, :])  # degree 0: a view whose backward launches nothing
    if k > 1:
        x, y, z = (d[..., None] for d in dirs.unbind(-1))
        out = out - _C1 * y * sh[..., 1, :] + _C1 * z * sh[..., 2, :] - _C1 * x * sh[..., 3, :]
        if k > 4:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            out = (
                out
                + _C2[0] * xy * sh[..., 4, :]
                + _C2[1] * yz * sh[..., 5, :]
                + _C2[2] * (2 * zz - xx - yy) * sh[..., 6, :]
                + _C2[3] * xz * sh[..., 7, :]
                + _C2[4] * (xx - yy) * sh[..., 8, :]
            )
            if k > 9:
                out = (
                    out
                    + _C3[0] * y * (3 * xx - yy) * sh[..., 9, :]
                    + _C3[1] * xy * z * sh[..., 10, :]
                    + _C3[2] * y * (4 * zz - xx - yy) * sh[..., 11, :]
                    + _C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[..., 12, :]
                    + _C3[4] * x * (4 * zz - xx - yy) * sh[..., 13, :]
                    + _C3[5] * z * (xx - yy) * sh[..., 14, :]
                    + _C3[6] * x * (xx - 3 * yy) * sh[..., 15, :]
                )
    return (out + 0.5).clamp_min(0.0)
