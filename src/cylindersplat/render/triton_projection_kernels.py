"""Triton kernels of the fused projection: world -> camera, pixel map, EWA footprint; forward and
analytic backward, float32, one program per block of (camera, Gaussian) pairs.

Imported lazily by :mod:`.triton_projection` (so that ``TRITON_INTERPRET=1`` set by a test before the
first call selects Triton's CPU interpreter). The steps and their rules are the reference's
(:mod:`.projection`, :mod:`.cameras`), written per pair on scalars:

1. ``p = W (mu - t)``, ``W M`` with ``M = R(q / |q|) diag(s)``  (:func:`_camera_frame`);
2. the camera model's pixel map: ``(u, v)``, radial depth, the Jacobian ``J`` (2x3), in view or not
   (:func:`_equirect_map`, :func:`_pinhole_map`);
3. ``T = J W M``; ``Sigma_2d = T T^T + dilation I`` with std caps, conic and extent (:func:`_footprint`).

Float32 safeguards, explicit here because the reference gets away with float64:

* ``det(T T^T) = |T_u x T_v|^2`` (Lagrange's identity) instead of ``a c - b^2``: no cancellation
  for thin footprints, positive by construction; with the dilation
  ``det = |T_u x T_v|^2 + d (a0 + c0) + d^2 >= d^2``; the backward pass avoids such differences
  too (:func:`_footprint_vjp`);
* ``atan2`` is written out (the interpreter has no libdevice): octant reduction and an odd series
  on ``|t| <= tan(pi/8)``, error < 3e-8 rad;
* culled pairs (behind the near plane, out of view) are computed on harmless operands and their
  gradients are selected away with ``where`` (never multiplied by zero: ``0 * inf = NaN``);
* at the poles ``rho`` is bounded below by ``pole_eps * r`` inside the Jacobian, and ``u, v`` take
  their limits on the vertical axis with zero gradient, as the reference does.

Every ``*_vjp`` function is the reverse-mode derivative of the function of the same name; together
they form the backward kernel, which recomputes the forward per pair and writes per-pair gradients
(summed over cameras by the caller).
"""

from __future__ import annotations

import math

import triton
import triton.language as tl

# Globals read inside @triton.jit functions must be constexpr (the compiler refuses others).
PI = tl.constexpr(math.pi)
# as geometry.equirect.ray_to_uv: (angle from the vertical axis)^2 below which u is fixed
_AXIS_EPS = tl.constexpr(1e-12)
_TAN_PI_8 = tl.constexpr(0.41421356237309503)


# ---- scalar helpers ------------------------------------------------------------------------------


@triton.jit
def _atan_unit(t):
    """atan(t) for 0 <= t <= 1: reduced to |t'| <= tan(pi/8) around pi/4, then the odd series to t'^15."""
    big = t > _TAN_PI_8
    t = tl.where(big, (t - 1.0) / (t + 1.0), t)
    s = t * t
    poly = 1.0 / 15.0
    poly = 1.0 / 13.0 - s * poly
    poly = 1.0 / 11.0 - s * poly
    poly = 1.0 / 9.0 - s * poly
    poly = 1.0 / 7.0 - s * poly
    poly = 1.0 / 5.0 - s * poly
    poly = 1.0 / 3.0 - s * poly
    poly = 1.0 - s * poly
    return tl.where(big, PI / 4.0, 0.0) + t * poly


@triton.jit
def _atan2(y, x):
    """atan2(y, x) in (-pi, pi] (atan2(0, 0) = 0), like torch.atan2 up to float32 rounding."""
    ax = tl.abs(x)
    ay = tl.abs(y)
    hi = tl.maximum(ax, ay)
    lo = tl.minimum(ax, ay)
    t = _atan_unit(lo / tl.where(hi > 0.0, hi, 1.0))
    t = tl.where(ay > ax, PI / 2.0 - t, t)
    t = tl.where(x < 0.0, PI - t, t)
    return tl.where(y < 0.0, -t, t)


@triton.jit
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


# ---- step 1: world -> camera ---------------------------------------------------------------------


@triton.jit
def _rotation(qw, qx, qy, qz):
    """Normalised quaternion (zero -> zero rotation, as geometry.rotations) and its matrix R (row-major)."""
    norm = tl.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / tl.maximum(norm, 1e-12)
    w = qw * inv
    x = qx * inv
    y = qy * inv
    z = qz * inv
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r01 = 2.0 * (x * y - w * z)
    r02 = 2.0 * (x * z + w * y)
    r10 = 2.0 * (x * y + w * z)
    r11 = 1.0 - 2.0 * (x * x + z * z)
    r12 = 2.0 * (y * z - w * x)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    return w, x, y, z, norm, r00, r01, r02, r10, r11, r12, r20, r21, r22


@triton.jit
def _rotation_vjp(w, x, y, z, norm, g00, g01, g02, g10, g11, g12, g20, g21, g22):
    """Gradient of the (unnormalised) quaternion from the gradient of R."""
    gw = 2.0 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21)
    gx = 2.0 * (y * g01 + z * g02 + y * g10 - 2.0 * x * g11 - w * g12 + z * g20 + w * g21 - 2.0 * x * g22)
    gy = 2.0 * (-2.0 * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - 2.0 * y * g22)
    gz = 2.0 * (-2.0 * z * g00 - w * g01 + x * g02 + w * g10 - 2.0 * z * g11 + y * g12 + x * g20 + y * g21)
    # q / max(|q|, eps): project out the radial part (only where the norm is not clamped), scale by 1/|q|
    radial = tl.where(norm >= 1e-12, w * gw + x * gx + y * gy + z * gz, 0.0)
    inv = 1.0 / tl.maximum(norm, 1e-12)
    return (gw - w * radial) * inv, (gx - x * radial) * inv, (gy - y * radial) * inv, (gz - z * radial) * inv


# ---- step 2: pixel maps --------------------------------------------------------------------------


@triton.jit
def _equirect_map(x, y, z, height, width, near, pole_eps):
    """``u, v, depth, J (6, row-major), valid`` of the equirect camera (see cameras.Equirect)."""
    rho2 = x * x + z * z
    r2 = rho2 + y * y
    r = tl.sqrt(tl.maximum(r2, 1e-30))
    valid = r > near
    on_axis = rho2 <= _AXIS_EPS * r2
    phi = tl.where(on_axis, 0.0, _atan2(tl.where(on_axis, 0.0, x), tl.where(on_axis, 1.0, z)))
    pole = tl.where(y > 0.0, PI / 2.0, tl.where(y < 0.0, -PI / 2.0, 0.0))
    lam = tl.where(on_axis, pole, _atan2(y, tl.sqrt(rho2)))
    u = width * (phi + PI) / (2.0 * PI)
    v = height * (lam + PI / 2.0) / PI
    # Jacobian on safe operands (culled pairs), with rho >= pole_eps * r.
    xs = tl.where(valid, x, 1.0)
    ys = tl.where(valid, y, 1.0)
    zs = tl.where(valid, z, 1.0)
    rs = tl.where(valid, r, 1.0)
    rho2c = tl.maximum(xs * xs + zs * zs, pole_eps * pole_eps * rs * rs)
    su = width / (2.0 * PI)
    sv = height / PI
    inv = 1.0 / rho2c
    rhoc = tl.sqrt(rho2c)
    r2j = rho2c + ys * ys
    k = sv / (r2j * rhoc)
    return u, v, r, su * zs * inv, 0.0 * xs, -su * xs * inv, -k * xs * ys, sv * rhoc / r2j, -k * zs * ys, valid


@triton.jit
def _equirect_map_vjp(x, y, z, height, width, pole_eps, gu, gv, gd, gj00, gj02, gj10, gj11, gj12):
    """Gradient of the camera-frame mean from those of ``u, v, depth, J`` (valid pairs; J01 is 0)."""
    su = width / (2.0 * PI)
    sv = height / PI
    rho2 = x * x + z * z
    r2 = rho2 + y * y
    r = tl.sqrt(tl.maximum(r2, 1e-30))
    # u, v: the exact derivatives; zero on the vertical axis (u, v are constants there).
    on_axis = rho2 <= _AXIS_EPS * r2
    rho2_s = tl.where(on_axis, 1.0, rho2)
    rho_s = tl.sqrt(rho2_s)
    r2_s = tl.where(on_axis, 1.0, r2)
    gx = tl.where(on_axis, 0.0, gu * su * z / rho2_s - gv * sv * x * y / (r2_s * rho_s))
    gy = tl.where(on_axis, 0.0, gv * sv * rho_s / r2_s)
    gz = tl.where(on_axis, 0.0, -gu * su * x / rho2_s - gv * sv * z * y / (r2_s * rho_s))
    # depth r
    gx += gd * x / r
    gy += gd * y / r
    gz += gd * z / r
    # J, with rho2c = max(rho2, (pole_eps r)^2)
    bound = pole_eps * pole_eps * r2
    clamped = rho2 < bound
    rho2c = tl.maximum(rho2, bound)
    inv = 1.0 / rho2c
    rhoc = tl.sqrt(rho2c)
    r2j = rho2c + y * y
    k = sv / (r2j * rhoc)
    j11 = sv * rhoc / r2j
    gz += gj00 * su * inv
    gx += -gj02 * su * inv
    g_rho2c = -su * (gj00 * z - gj02 * x) * inv * inv
    g_k = -y * (gj10 * x + gj12 * z)
    gx += -gj10 * k * y
    gz += -gj12 * k * y
    gy += -k * (gj10 * x + gj12 * z)
    g_r2j = -(g_k * k + gj11 * j11) / r2j
    g_rhoc = -g_k * k / rhoc + gj11 * sv / r2j
    g_rho2c += g_r2j + g_rhoc / (2.0 * rhoc)
    gy += 2.0 * y * g_r2j
    # rho2c is rho2 = x^2 + z^2, or (pole_eps r)^2 where clamped
    scale = tl.where(clamped, 2.0 * pole_eps * pole_eps * g_rho2c, 2.0 * g_rho2c)
    gx += scale * x
    gz += scale * z
    gy += tl.where(clamped, scale * y, 0.0)
    return gx, gy, gz


@triton.jit
def _pinhole_map(x, y, z, height, width, fx, fy, cx, cy, near):
    """``u, v, depth, J (6, row-major), valid`` of the pinhole camera (see cameras.Pinhole)."""
    valid = z > near
    zs = tl.where(valid, z, 1.0)
    tx = x / zs
    ty = y / zs
    lim_x = 1.3 * (width / 2.0) / fx
    lim_y = 1.3 * (height / 2.0) / fy
    valid = valid & (tl.abs(tx - (cx - width / 2.0) / fx) <= lim_x) & (tl.abs(ty - (cy - height / 2.0) / fy) <= lim_y)
    depth = tl.sqrt(x * x + y * y + z * z)
    zero = 0.0 * x
    return (fx * tx + cx, fy * ty + cy, depth, fx / zs, zero, -fx * x / (zs * zs), zero, fy / zs, -fy * y / (zs * zs),
            valid)


@triton.jit
def _pinhole_map_vjp(x, y, z, fx, fy, gu, gv, gd, gj00, gj02, gj11, gj12):
    """Gradient of the camera-frame mean (valid pairs: z > near)."""
    inv_z = 1.0 / z
    inv_z2 = inv_z * inv_z
    r = tl.sqrt(tl.maximum(x * x + y * y + z * z, 1e-30))
    gx = gu * fx * inv_z - gj02 * fx * inv_z2 + gd * x / r
    gy = gv * fy * inv_z - gj12 * fy * inv_z2 + gd * y / r
    gz = (-(gu * fx * x + gv * fy * y) * inv_z2 - (gj00 * fx + gj11 * fy) * inv_z2
          + 2.0 * (gj02 * fx * x + gj12 * fy * y) * inv_z2 * inv_z + gd * z / r)
    return gx, gy, gz


# ---- step 3: EWA footprint -----------------------------------------------------------------------


@triton.jit
def _footprint(tu0, tu1, tu2, tv0, tv1, tv2, dilation, sigma_extent, max_u2, max_v2):
    """Rows ``T_u, T_v`` of ``T = J W M`` -> conic ``(A, B, C)``, extents ``(e_u, e_v)``."""
    a0 = tu0 * tu0 + tu1 * tu1 + tu2 * tu2
    b0 = tu0 * tv0 + tu1 * tv1 + tu2 * tv2
    c0 = tv0 * tv0 + tv1 * tv1 + tv2 * tv2
    w0, w1, w2 = _cross(tu0, tu1, tu2, tv0, tv1, tv2)
    a = a0 + dilation
    c = c0 + dilation
    det = tl.maximum(w0 * w0 + w1 * w1 + w2 * w2 + dilation * (a0 + c0) + dilation * dilation, 1e-30)
    fu = tl.minimum(max_u2 / a, 1.0)
    fv = tl.minimum(max_v2 / c, 1.0)
    # capped: a' = a fu, c' = c fv, b' = b0 sqrt(fu fv), det' = fu fv det
    conic_a = c / (fu * det)
    conic_b = -b0 / (tl.sqrt(fu * fv) * det)
    conic_c = a / (fv * det)
    return conic_a, conic_b, conic_c, sigma_extent * tl.sqrt(a * fu), sigma_extent * tl.sqrt(c * fv)


@triton.jit
def _footprint_vjp(tu0, tu1, tu2, tv0, tv1, tv2, dilation, sigma_extent, max_u2, max_v2, g_ca, g_cb, g_cc, g_eu, g_ev):
    """Gradients of ``T_u, T_v`` from those of the conic and the extents.

    Written without differences of large, nearly equal terms: the conic's gradient goes through
    ``d(Sigma^-1) = -Sigma^-1 dSigma Sigma^-1`` (not through the determinant), and a capped entry
    (constant) passes nothing back but its effect on ``b' = b sqrt(fu fv)``."""
    a0 = tu0 * tu0 + tu1 * tu1 + tu2 * tu2
    b0 = tu0 * tv0 + tu1 * tv1 + tu2 * tv2
    c0 = tv0 * tv0 + tv1 * tv1 + tv2 * tv2
    ca, cb, cc, eu, ev = _footprint(tu0, tu1, tu2, tv0, tv1, tv2, dilation, sigma_extent, max_u2, max_v2)
    a = a0 + dilation
    c = c0 + dilation
    capped_u = max_u2 < a
    capped_v = max_v2 < c
    fu = tl.minimum(max_u2 / a, 1.0)
    fv = tl.minimum(max_v2 / c, 1.0)
    s = tl.sqrt(fu * fv)
    # Sigma' = [[a', b'], [b', c']], Sigma'^-1 = [[A, B], [B, C]], G = [[gA, gB/2], [gB/2, gC]]:
    # dL/dSigma' = -Sigma'^-1 G Sigma'^-1
    x00 = ca * g_ca + cb * g_cb * 0.5
    x01 = ca * g_cb * 0.5 + cb * g_cc
    x10 = cb * g_ca + cc * g_cb * 0.5
    x11 = cb * g_cb * 0.5 + cc * g_cc
    g_a1 = -(x00 * ca + x01 * cb) + g_eu * eu / (2.0 * a * fu)
    g_c1 = -(x10 * cb + x11 * cc) + g_ev * ev / (2.0 * c * fv)
    g_b1 = -(x00 * cb + x01 * cc) - (x10 * ca + x11 * cb)
    # a' = a fu, c' = c fv, b' = b0 sqrt(fu fv); fu = max_u2 / a where capped (then a' is constant)
    b1 = b0 * s
    g_a = tl.where(capped_u, -g_b1 * b1 / (2.0 * a), g_a1)
    g_c = tl.where(capped_v, -g_b1 * b1 / (2.0 * c), g_c1)
    g_b0 = g_b1 * s
    g_tu0 = 2.0 * g_a * tu0 + g_b0 * tv0
    g_tu1 = 2.0 * g_a * tu1 + g_b0 * tv1
    g_tu2 = 2.0 * g_a * tu2 + g_b0 * tv2
    g_tv0 = 2.0 * g_c * tv0 + g_b0 * tu0
    g_tv1 = 2.0 * g_c * tv1 + g_b0 * tu1
    g_tv2 = 2.0 * g_c * tv2 + g_b0 * tu2
    return g_tu0, g_tu1, g_tu2, g_tv0, g_tv1, g_tv2


# ---- the pair kernels ----------------------------------------------------------------------------


@triton.jit
def _load3(ptr, row, mask):
    return (tl.load(ptr + row * 3 + 0, mask=mask, other=0.0), tl.load(ptr + row * 3 + 1, mask=mask, other=0.0),
            tl.load(ptr + row * 3 + 2, mask=mask, other=0.0))


@triton.jit
def _pair_indices(num_pairs, num_views, num_gaussians, BLOCK: tl.constexpr):
    """Pair ``(b, v, n)`` in row-major order -> its Gaussian row ``b N + n`` and camera row ``b V + v``."""
    pair = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    mask = pair < num_pairs
    n = pair % num_gaussians
    camera = pair // num_gaussians
    gaussian = (camera // num_views) * num_gaussians + n
    return pair, mask, gaussian, camera


@triton.jit
def _camera_frame(means_ptr, scales_ptr, quats_ptr, cams_ptr, gaussian, camera, mask):
    """Step 1: loads one pair; returns the camera rotation ``Rc`` (c2w, row-major; ``W = Rc^T``), the
    quaternion terms, scales, ``p = W (mu - t)`` and ``WM = W R diag(s)`` (row-major)."""
    mx, my, mz = _load3(means_ptr, gaussian, mask)
    sx, sy, sz = _load3(scales_ptr, gaussian, mask)
    qb = quats_ptr + gaussian * 4
    qw0 = tl.load(qb + 0, mask=mask, other=1.0)
    qx0 = tl.load(qb + 1, mask=mask, other=0.0)
    qy0 = tl.load(qb + 2, mask=mask, other=0.0)
    qz0 = tl.load(qb + 3, mask=mask, other=0.0)
    cb = cams_ptr + camera * 16  # the camera's 4x4 c2w, row-major: rotation row i at 4i..4i+2, translation at 4i+3
    c00 = tl.load(cb + 0, mask=mask, other=1.0)
    c01 = tl.load(cb + 1, mask=mask, other=0.0)
    c02 = tl.load(cb + 2, mask=mask, other=0.0)
    c10 = tl.load(cb + 4, mask=mask, other=0.0)
    c11 = tl.load(cb + 5, mask=mask, other=1.0)
    c12 = tl.load(cb + 6, mask=mask, other=0.0)
    c20 = tl.load(cb + 8, mask=mask, other=0.0)
    c21 = tl.load(cb + 9, mask=mask, other=0.0)
    c22 = tl.load(cb + 10, mask=mask, other=1.0)
    dx = mx - tl.load(cb + 3, mask=mask, other=0.0)
    dy = my - tl.load(cb + 7, mask=mask, other=0.0)
    dz = mz - tl.load(cb + 11, mask=mask, other=0.0)
    # p_i = sum_k Rc[k, i] d_k
    px = c00 * dx + c10 * dy + c20 * dz
    py = c01 * dx + c11 * dy + c21 * dz
    pz = c02 * dx + c12 * dy + c22 * dz
    qw, qx, qy, qz, qn, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotation(qw0, qx0, qy0, qz0)
    # M[k, j] = R[k, j] s_j;  WM[i, j] = sum_k Rc[k, i] M[k, j]
    m00 = r00 * sx
    m01 = r01 * sy
    m02 = r02 * sz
    m10 = r10 * sx
    m11 = r11 * sy
    m12 = r12 * sz
    m20 = r20 * sx
    m21 = r21 * sy
    m22 = r22 * sz
    w00 = c00 * m00 + c10 * m10 + c20 * m20
    w01 = c00 * m01 + c10 * m11 + c20 * m21
    w02 = c00 * m02 + c10 * m12 + c20 * m22
    w10 = c01 * m00 + c11 * m10 + c21 * m20
    w11 = c01 * m01 + c11 * m11 + c21 * m21
    w12 = c01 * m02 + c11 * m12 + c21 * m22
    w20 = c02 * m00 + c12 * m10 + c22 * m20
    w21 = c02 * m01 + c12 * m11 + c22 * m21
    w22 = c02 * m02 + c12 * m12 + c22 * m22
    return (c00, c01, c02, c10, c11, c12, c20, c21, c22, qw, qx, qy, qz, qn,
            r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz, px, py, pz,
            w00, w01, w02, w10, w11, w12, w20, w21, w22)


@triton.jit
def _pixel_map(px, py, pz, height, width, fx, fy, cx, cy, near, pole_eps, MODEL: tl.constexpr):
    """Step 2 for the camera model ``MODEL`` (0 equirect, 1 pinhole)."""
    if MODEL == 0:
        return _equirect_map(px, py, pz, height, width, near, pole_eps)
    else:
        return _pinhole_map(px, py, pz, height, width, fx, fy, cx, cy, near)


@triton.jit
def project_forward_kernel(
    means_ptr, scales_ptr, quats_ptr, opacities_ptr, cams_ptr, geo_ptr, valid_ptr,
    num_pairs, num_views, num_gaussians, height, width, fx, fy, cx, cy,
    near, pole_eps, dilation, sigma_extent, alpha_min, max_u2, max_v2,
    MODEL: tl.constexpr, BLOCK: tl.constexpr,
):
    """Per pair: ``geo = [u, v, A, B, C, e_u, e_v, depth]`` (inert where not valid) and ``valid`` (bool)."""
    pair, mask, gaussian, camera = _pair_indices(num_pairs, num_views, num_gaussians, BLOCK)
    (c00, c01, c02, c10, c11, c12, c20, c21, c22, qw, qx, qy, qz, qn,
     r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz, px, py, pz,
     w00, w01, w02, w10, w11, w12, w20, w21, w22) = _camera_frame(means_ptr, scales_ptr, quats_ptr, cams_ptr,
                                                                  gaussian, camera, mask)
    u, v, depth, j00, j01, j02, j10, j11, j12, valid = _pixel_map(px, py, pz, height, width, fx, fy, cx, cy, near,
                                                                  pole_eps, MODEL)
    tu0 = j00 * w00 + j01 * w10 + j02 * w20
    tu1 = j00 * w01 + j01 * w11 + j02 * w21
    tu2 = j00 * w02 + j01 * w12 + j02 * w22
    tv0 = j10 * w00 + j11 * w10 + j12 * w20
    tv1 = j10 * w01 + j11 * w11 + j12 * w21
    tv2 = j10 * w02 + j11 * w12 + j12 * w22
    ca, cb, cc, eu, ev = _footprint(tu0, tu1, tu2, tv0, tv1, tv2, dilation, sigma_extent, max_u2, max_v2)
    opacity = tl.load(opacities_ptr + gaussian, mask=mask, other=0.0)
    valid = valid & (opacity >= alpha_min) & (v - ev < height) & (v + ev > 0.0)
    if MODEL != 0:  # images that do not wrap around
        valid = valid & (u - eu < width) & (u + eu > 0.0)
    # An invisible pair's row is inert (projection._INERT_UV: u = v = -1, the rest 0): it meets no tile.
    out = geo_ptr + pair * 8
    tl.store(out + 0, tl.where(valid, u, -1.0), mask=mask)
    tl.store(out + 1, tl.where(valid, v, -1.0), mask=mask)
    tl.store(out + 2, tl.where(valid, ca, 0.0), mask=mask)
    tl.store(out + 3, tl.where(valid, cb, 0.0), mask=mask)
    tl.store(out + 4, tl.where(valid, cc, 0.0), mask=mask)
    tl.store(out + 5, tl.where(valid, eu, 0.0), mask=mask)
    tl.store(out + 6, tl.where(valid, ev, 0.0), mask=mask)
    tl.store(out + 7, tl.where(valid, depth, 0.0), mask=mask)
    tl.store(valid_ptr + pair, valid.to(valid_ptr.dtype.element_ty), mask=mask)  # bool (or int8)


@triton.jit
def project_backward_kernel(
    means_ptr, scales_ptr, quats_ptr, cams_ptr, valid_ptr, grad_geo_ptr, grad_means_ptr, grad_scales_ptr,
    grad_quats_ptr, grad_geo_stride, num_pairs, num_views, num_gaussians, height, width, fx, fy, cx, cy,
    near, pole_eps, dilation, sigma_extent, max_u2, max_v2,
    MODEL: tl.constexpr, BLOCK: tl.constexpr,
):
    """Per pair: gradients of the mean (3), scale (3) and quaternion (4), each in its own ``(pairs, k)`` buffer
    (zero for culled pairs), from the pairs' ``geo`` gradients, rows ``grad_geo_stride`` apart (8, or 12 where they
    are the first columns of the compositing rows' gradient)."""
    pair, mask, gaussian, camera = _pair_indices(num_pairs, num_views, num_gaussians, BLOCK)
    (c00, c01, c02, c10, c11, c12, c20, c21, c22, qw, qx, qy, qz, qn,
     r00, r01, r02, r10, r11, r12, r20, r21, r22, sx, sy, sz, px, py, pz,
     w00, w01, w02, w10, w11, w12, w20, w21, w22) = _camera_frame(means_ptr, scales_ptr, quats_ptr, cams_ptr,
                                                                  gaussian, camera, mask)
    valid = (tl.load(valid_ptr + pair, mask=mask, other=0) != 0) & mask
    # Culled pairs: harmless operands, gradients selected away at the end.
    px = tl.where(valid, px, 0.0)
    py = tl.where(valid, py, 0.0)
    pz = tl.where(valid, pz, 1.0)
    u, v, depth, j00, j01, j02, j10, j11, j12, _ = _pixel_map(px, py, pz, height, width, fx, fy, cx, cy, near,
                                                              pole_eps, MODEL)
    tu0 = j00 * w00 + j01 * w10 + j02 * w20
    tu1 = j00 * w01 + j01 * w11 + j02 * w21
    tu2 = j00 * w02 + j01 * w12 + j02 * w22
    tv0 = j10 * w00 + j11 * w10 + j12 * w20
    tv1 = j10 * w01 + j11 * w11 + j12 * w21
    tv2 = j10 * w02 + j11 * w12 + j12 * w22
    gb = grad_geo_ptr + pair * grad_geo_stride
    g_u = tl.load(gb + 0, mask=valid, other=0.0)
    g_v = tl.load(gb + 1, mask=valid, other=0.0)
    g_ca = tl.load(gb + 2, mask=valid, other=0.0)
    g_cb = tl.load(gb + 3, mask=valid, other=0.0)
    g_cc = tl.load(gb + 4, mask=valid, other=0.0)
    g_eu = tl.load(gb + 5, mask=valid, other=0.0)
    g_ev = tl.load(gb + 6, mask=valid, other=0.0)
    g_d = tl.load(gb + 7, mask=valid, other=0.0)
    g_tu0, g_tu1, g_tu2, g_tv0, g_tv1, g_tv2 = _footprint_vjp(tu0, tu1, tu2, tv0, tv1, tv2, dilation, sigma_extent,
                                                             max_u2, max_v2, g_ca, g_cb, g_cc, g_eu, g_ev)
    # T = J WM:  dJ[r, i] = sum_j dT[r, j] WM[i, j];  dWM[i, j] = sum_r J[r, i] dT[r, j]
    g_j00 = g_tu0 * w00 + g_tu1 * w01 + g_tu2 * w02
    g_j02 = g_tu0 * w20 + g_tu1 * w21 + g_tu2 * w22
    g_j10 = g_tv0 * w00 + g_tv1 * w01 + g_tv2 * w02
    g_j11 = g_tv0 * w10 + g_tv1 * w11 + g_tv2 * w12
    g_j12 = g_tv0 * w20 + g_tv1 * w21 + g_tv2 * w22
    if MODEL == 0:
        g_px, g_py, g_pz = _equirect_map_vjp(px, py, pz, height, width, pole_eps, g_u, g_v, g_d,
                                             g_j00, g_j02, g_j10, g_j11, g_j12)
    else:
        g_px, g_py, g_pz = _pinhole_map_vjp(px, py, pz, fx, fy, g_u, g_v, g_d, g_j00, g_j02, g_j11, g_j12)
    gw00 = j00 * g_tu0 + j10 * g_tv0
    gw01 = j00 * g_tu1 + j10 * g_tv1
    gw02 = j00 * g_tu2 + j10 * g_tv2
    gw10 = j01 * g_tu0 + j11 * g_tv0
    gw11 = j01 * g_tu1 + j11 * g_tv1
    gw12 = j01 * g_tu2 + j11 * g_tv2
    gw20 = j02 * g_tu0 + j12 * g_tv0
    gw21 = j02 * g_tu1 + j12 * g_tv1
    gw22 = j02 * g_tu2 + j12 * g_tv2
    # WM = W M with W = Rc^T:  dM[k, j] = sum_i Rc[k, i] dWM[i, j]
    gm00 = c00 * gw00 + c01 * gw10 + c02 * gw20
    gm01 = c00 * gw01 + c01 * gw11 + c02 * gw21
    gm02 = c00 * gw02 + c01 * gw12 + c02 * gw22
    gm10 = c10 * gw00 + c11 * gw10 + c12 * gw20
    gm11 = c10 * gw01 + c11 * gw11 + c12 * gw21
    gm12 = c10 * gw02 + c11 * gw12 + c12 * gw22
    gm20 = c20 * gw00 + c21 * gw10 + c22 * gw20
    gm21 = c20 * gw01 + c21 * gw11 + c22 * gw21
    gm22 = c20 * gw02 + c21 * gw12 + c22 * gw22
    # M = R diag(s)
    g_sx = gm00 * r00 + gm10 * r10 + gm20 * r20
    g_sy = gm01 * r01 + gm11 * r11 + gm21 * r21
    g_sz = gm02 * r02 + gm12 * r12 + gm22 * r22
    g_qw, g_qx, g_qy, g_qz = _rotation_vjp(qw, qx, qy, qz, qn, gm00 * sx, gm01 * sy, gm02 * sz, gm10 * sx,
                                           gm11 * sy, gm12 * sz, gm20 * sx, gm21 * sy, gm22 * sz)
    # p = W (mu - t):  d mu = Rc dp
    g_mx = c00 * g_px + c01 * g_py + c02 * g_pz
    g_my = c10 * g_px + c11 * g_py + c12 * g_pz
    g_mz = c20 * g_px + c21 * g_py + c22 * g_pz
    out = grad_means_ptr + pair * 3
    tl.store(out + 0, tl.where(valid, g_mx, 0.0), mask=mask)
    tl.store(out + 1, tl.where(valid, g_my, 0.0), mask=mask)
    tl.store(out + 2, tl.where(valid, g_mz, 0.0), mask=mask)
    out = grad_scales_ptr + pair * 3
    tl.store(out + 0, tl.where(valid, g_sx, 0.0), mask=mask)
    tl.store(out + 1, tl.where(valid, g_sy, 0.0), mask=mask)
    tl.store(out + 2, tl.where(valid, g_sz, 0.0), mask=mask)
    out = grad_quats_ptr + pair * 4
    tl.store(out + 0, tl.where(valid, g_qw, 0.0), mask=mask)
    tl.store(out + 1, tl.where(valid, g_qx, 0.0), mask=mask)
    tl.store(out + 2, tl.where(valid, g_qy, 0.0), mask=mask)
    tl.store(out + 3, tl.where(valid, g_qz, 0.0), mask=mask)
