"""Numba kernels of the CPU backend's projection: world -> camera, pixel map, EWA footprint; forward and
analytic backward in float64, one parallel iteration per Gaussian (its cameras in a row, so the
backward sums over cameras without races).

Imported lazily by :mod:`.numba_projection`. The steps and rules are the reference's (:mod:`.projection`,
:mod:`.cameras`), per pair on scalars, with the same arrangement as the Triton backend's fused kernel
(:mod:`.triton_projection_kernels`): ``det(T T^T)`` by Lagrange's identity, the conic's gradient through
``-Sigma^-1 dSigma Sigma^-1``, capped entries passing back only their effect on ``b``, culled pairs
computed on harmless operands with zero gradient, ``u, v`` fixed (zero gradient) on the vertical axis.
Every ``*_vjp`` function is the reverse-mode derivative of the function of the same name.

``consts`` (float64): ``height, width, fx, fy, cx, cy, near, pole_eps, dilation, sigma_extent, alpha_min,
max_u^2, max_v^2``; ``model`` 0 is equirect, 1 pinhole.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_AXIS_EPS = 1e-12  # as geometry.equirect.ray_to_uv: (angle from the vertical axis)^2 below which u is fixed
_PI = math.pi
# Gaussians per parallel iteration: each iteration allocates its small work arrays once, not once per Gaussian (a
# heap allocation per array per Gaussian cost about as much as the arithmetic).
_CHUNK = 256


@njit(cache=True)
def _rotation(qw, qx, qy, qz, rot):
    """Normalised quaternion (zero -> zero rotation, as geometry.rotations) and its norm; the matrix R (row-major) is
    written into ``rot`` (9,)."""
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / max(norm, 1e-12)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    rot[0] = 1.0 - 2.0 * (y * y + z * z)
    rot[1] = 2.0 * (x * y - w * z)
    rot[2] = 2.0 * (x * z + w * y)
    rot[3] = 2.0 * (x * y + w * z)
    rot[4] = 1.0 - 2.0 * (x * x + z * z)
    rot[5] = 2.0 * (y * z - w * x)
    rot[6] = 2.0 * (x * z - w * y)
    rot[7] = 2.0 * (y * z + w * x)
    rot[8] = 1.0 - 2.0 * (x * x + y * y)
    return w, x, y, z, norm


@njit(cache=True)
def _rotation_vjp(w, x, y, z, norm, g):
    """Gradient of the (unnormalised) quaternion from the gradient ``g`` (9, row-major) of R."""
    gw = 2.0 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7])
    gx = 2.0 * (y * g[1] + z * g[2] + y * g[3] - 2.0 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2.0 * x * g[8])
    gy = 2.0 * (-2.0 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2.0 * y * g[8])
    gz = 2.0 * (-2.0 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2.0 * z * g[4] + y * g[5] + x * g[6] + y * g[7])
    # q / max(|q|, eps): project out the radial part (only where the norm is not clamped), scale by 1/|q|
    radial = w * gw + x * gx + y * gy + z * gz if norm >= 1e-12 else 0.0
    inv = 1.0 / max(norm, 1e-12)
    return (gw - w * radial) * inv, (gx - x * radial) * inv, (gy - y * radial) * inv, (gz - z * radial) * inv


@njit(cache=True)
def _equirect_map(x, y, z, consts, jac):
    """``u, v, depth, valid`` of the equirect camera; its Jacobian into ``jac`` (6, row-major)."""
    height, width, near, pole_eps = consts[0], consts[1], consts[6], consts[7]
    rho2 = x * x + z * z
    r2 = rho2 + y * y
    r = math.sqrt(max(r2, 1e-30))
    valid = r > near
    on_axis = rho2 <= _AXIS_EPS * r2
    if on_axis:
        phi = 0.0
        lam = _PI / 2.0 if y > 0.0 else (-_PI / 2.0 if y < 0.0 else 0.0)
    else:
        phi = math.atan2(x, z)
        lam = math.atan2(y, math.sqrt(rho2))
    u = width * (phi + _PI) / (2.0 * _PI)
    v = height * (lam + _PI / 2.0) / _PI
    # Jacobian on safe operands (culled pairs), with rho >= pole_eps * r.
    xs, ys, zs, rs = (x, y, z, r) if valid else (1.0, 1.0, 1.0, 1.0)
    rho2c = max(xs * xs + zs * zs, pole_eps * pole_eps * rs * rs)
    su, sv = width / (2.0 * _PI), height / _PI
    inv = 1.0 / rho2c
    rhoc = math.sqrt(rho2c)
    r2j = rho2c + ys * ys
    k = sv / (r2j * rhoc)
    jac[0], jac[1], jac[2] = su * zs * inv, 0.0, -su * xs * inv
    jac[3], jac[4], jac[5] = -k * xs * ys, sv * rhoc / r2j, -k * zs * ys
    return u, v, r, valid


@njit(cache=True)
def _equirect_map_vjp(x, y, z, consts, gu, gv, gd, gj):
    """Gradient of the camera-frame mean from those of ``u, v, depth, J`` (valid pairs; J01 is 0)."""
    height, width, pole_eps = consts[0], consts[1], consts[7]
    su, sv = width / (2.0 * _PI), height / _PI
    rho2 = x * x + z * z
    r2 = rho2 + y * y
    r = math.sqrt(max(r2, 1e-30))
    gx = gy = gz = 0.0
    if not rho2 <= _AXIS_EPS * r2:  # u, v are constants on the vertical axis
        rho = math.sqrt(rho2)
        gx = gu * su * z / rho2 - gv * sv * x * y / (r2 * rho)
        gy = gv * sv * rho / r2
        gz = -gu * su * x / rho2 - gv * sv * z * y / (r2 * rho)
    gx += gd * x / r
    gy += gd * y / r
    gz += gd * z / r
    # J, with rho2c = max(rho2, (pole_eps r)^2)
    bound = pole_eps * pole_eps * r2
    clamped = rho2 < bound
    rho2c = max(rho2, bound)
    inv = 1.0 / rho2c
    rhoc = math.sqrt(rho2c)
    r2j = rho2c + y * y
    k = sv / (r2j * rhoc)
    j11 = sv * rhoc / r2j
    gz += gj[0] * su * inv
    gx += -gj[2] * su * inv
    g_rho2c = -su * (gj[0] * z - gj[2] * x) * inv * inv
    g_k = -y * (gj[3] * x + gj[5] * z)
    gx += -gj[3] * k * y
    gz += -gj[5] * k * y
    gy += -k * (gj[3] * x + gj[5] * z)
    g_r2j = -(g_k * k + gj[4] * j11) / r2j
    g_rhoc = -g_k * k / rhoc + gj[4] * sv / r2j
    g_rho2c += g_r2j + g_rhoc / (2.0 * rhoc)
    gy += 2.0 * y * g_r2j
    # rho2c is rho2 = x^2 + z^2, or (pole_eps r)^2 where clamped
    scale = 2.0 * pole_eps * pole_eps * g_rho2c if clamped else 2.0 * g_rho2c
    gx += scale * x
    gz += scale * z
    if clamped:
        gy += scale * y
    return gx, gy, gz


@njit(cache=True)
def _pinhole_map(x, y, z, consts, jac):
    """``u, v, depth, valid`` of the pinhole camera; its Jacobian into ``jac`` (6, row-major)."""
    height, width, fx, fy, cx, cy, near = consts[0], consts[1], consts[2], consts[3], consts[4], consts[5], consts[6]
    valid = z > near
    zs = z if valid else 1.0
    tx, ty = x / zs, y / zs
    lim_x = 1.3 * (width / 2.0) / fx
    lim_y = 1.3 * (height / 2.0) / fy
    valid = valid and abs(tx - (cx - width / 2.0) / fx) <= lim_x and abs(ty - (cy - height / 2.0) / fy) <= lim_y
    jac[0], jac[1], jac[2] = fx / zs, 0.0, -fx * x / (zs * zs)
    jac[3], jac[4], jac[5] = 0.0, fy / zs, -fy * y / (zs * zs)
    return fx * tx + cx, fy * ty + cy, math.sqrt(x * x + y * y + z * z), valid


@njit(cache=True)
def _pinhole_map_vjp(x, y, z, consts, gu, gv, gd, gj):
    """Gradient of the camera-frame mean (valid pairs: z > near)."""
    fx, fy = consts[2], consts[3]
    inv_z = 1.0 / z
    inv_z2 = inv_z * inv_z
    r = math.sqrt(max(x * x + y * y + z * z, 1e-30))
    gx = gu * fx * inv_z - gj[2] * fx * inv_z2 + gd * x / r
    gy = gv * fy * inv_z - gj[5] * fy * inv_z2 + gd * y / r
    gz = (-(gu * fx * x + gv * fy * y) * inv_z2 - (gj[0] * fx + gj[4] * fy) * inv_z2
          + 2.0 * (gj[2] * fx * x + gj[5] * fy * y) * inv_z2 * inv_z + gd * z / r)
    return gx, gy, gz


@njit(cache=True)
def _footprint(t, consts):
    """``T = J W M`` (6, rows T_u, T_v) -> conic ``(A, B, C)``, extents ``(e_u, e_v)``."""
    dilation, sigma_extent, max_u2, max_v2 = consts[8], consts[9], consts[11], consts[12]
    a0 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
    b0 = t[0] * t[3] + t[1] * t[4] + t[2] * t[5]
    c0 = t[3] * t[3] + t[4] * t[4] + t[5] * t[5]
    w0 = t[1] * t[5] - t[2] * t[4]
    w1 = t[2] * t[3] - t[0] * t[5]
    w2 = t[0] * t[4] - t[1] * t[3]
    a, c = a0 + dilation, c0 + dilation
    det = max(w0 * w0 + w1 * w1 + w2 * w2 + dilation * (a0 + c0) + dilation * dilation, 1e-30)
    fu, fv = min(max_u2 / a, 1.0), min(max_v2 / c, 1.0)
    # capped: a' = a fu, c' = c fv, b' = b0 sqrt(fu fv), det' = fu fv det
    return (c / (fu * det), -b0 / (math.sqrt(fu * fv) * det), a / (fv * det),
            sigma_extent * math.sqrt(a * fu), sigma_extent * math.sqrt(c * fv))


@njit(cache=True)
def _footprint_det(t, dilation):
    """``det`` of the dilated 2-D covariance (before the extent cap, which only shrinks huge footprints)."""
    a0 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
    c0 = t[3] * t[3] + t[4] * t[4] + t[5] * t[5]
    w0 = t[1] * t[5] - t[2] * t[4]
    w1 = t[2] * t[3] - t[0] * t[5]
    w2 = t[0] * t[4] - t[1] * t[3]
    return w0 * w0 + w1 * w1 + w2 * w2 + dilation * (a0 + c0) + dilation * dilation


@njit(cache=True)
def _footprint_vjp(t, consts, g_ca, g_cb, g_cc, g_eu, g_ev, g_t):
    """Gradients of ``T`` (into ``g_t``) from those of the conic and the extents."""
    dilation, max_u2, max_v2 = consts[8], consts[11], consts[12]
    a0 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
    b0 = t[0] * t[3] + t[1] * t[4] + t[2] * t[5]
    c0 = t[3] * t[3] + t[4] * t[4] + t[5] * t[5]
    ca, cb, cc, eu, ev = _footprint(t, consts)
    a, c = a0 + dilation, c0 + dilation
    fu, fv = min(max_u2 / a, 1.0), min(max_v2 / c, 1.0)
    s = math.sqrt(fu * fv)
    # dL/dSigma' = -Sigma'^-1 G Sigma'^-1 with G = [[gA, gB/2], [gB/2, gC]]
    x00 = ca * g_ca + cb * g_cb * 0.5
    x01 = ca * g_cb * 0.5 + cb * g_cc
    x10 = cb * g_ca + cc * g_cb * 0.5
    x11 = cb * g_cb * 0.5 + cc * g_cc
    g_a1 = -(x00 * ca + x01 * cb) + g_eu * eu / (2.0 * a * fu)
    g_c1 = -(x10 * cb + x11 * cc) + g_ev * ev / (2.0 * c * fv)
    g_b1 = -(x00 * cb + x01 * cc) - (x10 * ca + x11 * cb)
    b1 = b0 * s
    g_a = -g_b1 * b1 / (2.0 * a) if max_u2 < a else g_a1
    g_c = -g_b1 * b1 / (2.0 * c) if max_v2 < c else g_c1
    g_b0 = g_b1 * s
    for j in range(3):
        g_t[j] = 2.0 * g_a * t[j] + g_b0 * t[3 + j]
        g_t[3 + j] = 2.0 * g_c * t[3 + j] + g_b0 * t[j]


@njit(cache=True)
def _camera_frame(means, scales, cams, b, n, cam, rot, wm):
    """``p = W (mu - t)`` and ``WM = W R diag(s)`` (into ``wm``, row-major), ``W = Rc^T``."""
    c = cams[cam]
    dx, dy, dz = means[b, n, 0] - c[9], means[b, n, 1] - c[10], means[b, n, 2] - c[11]
    px = c[0] * dx + c[3] * dy + c[6] * dz
    py = c[1] * dx + c[4] * dy + c[7] * dz
    pz = c[2] * dx + c[5] * dy + c[8] * dz
    for i in range(3):
        for j in range(3):
            wm[3 * i + j] = (c[i] * rot[j] + c[3 + i] * rot[3 + j] + c[6 + i] * rot[6 + j]) * scales[b, n, j]
    return px, py, pz


@njit(cache=True)
def _pixel_map(px, py, pz, consts, model, jac):
    if model == 0:
        return _equirect_map(px, py, pz, consts, jac)
    return _pinhole_map(px, py, pz, consts, jac)


@njit(cache=True)
def _times_wm(jac, wm, t):
    for r in range(2):
        for j in range(3):
            t[3 * r + j] = jac[3 * r] * wm[j] + jac[3 * r + 1] * wm[3 + j] + jac[3 * r + 2] * wm[6 + j]


@njit(parallel=True, cache=True)
def project_forward(means, scales, quats, opacities, cams, num_views, model, consts):
    """means, scales ``(B, N, 3)``, quats ``(B, N, 4)``, opacities ``(B, N)``, cams ``(B * V, 12)`` (c2w rotation
    row-major, then translation) -> ``geo (B, V, N, 8)`` ``[u, v, A, B, C, e_u, e_v, depth]``, ``valid (B, V, N)``."""
    num_b, num_n = means.shape[0], means.shape[1]
    height, width, alpha_min = consts[0], consts[1], consts[10]
    geo = np.empty((num_b, num_views, num_n, 8))
    valid = np.empty((num_b, num_views, num_n), np.bool_)
    num = num_b * num_n
    for chunk in prange((num + _CHUNK - 1) // _CHUNK):
        rot, wm, jac, t = np.empty(9), np.empty(9), np.empty(6), np.empty(6)
        for i in range(chunk * _CHUNK, min(num, chunk * _CHUNK + _CHUNK)):
            b, n = i // num_n, i % num_n
            _rotation(quats[b, n, 0], quats[b, n, 1], quats[b, n, 2], quats[b, n, 3], rot)
            for view in range(num_views):
                px, py, pz = _camera_frame(means, scales, cams, b, n, b * num_views + view, rot, wm)
                u, v, depth, ok = _pixel_map(px, py, pz, consts, model, jac)
                _times_wm(jac, wm, t)
                out = geo[b, view, n]
                if _footprint_det(t, consts[8]) <= 1e-12:  # projection.MIN_FOOTPRINT_DET: zero area draws nothing
                    out[:] = 0.0
                    valid[b, view, n] = False
                    continue
                ca, cb, cc, eu, ev = _footprint(t, consts)
                ok = ok and opacities[b, n] >= alpha_min and v - ev < height and v + ev > 0.0
                if model != 0:  # images that do not wrap around
                    ok = ok and u - eu < width and u + eu > 0.0
                out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7] = u, v, ca, cb, cc, eu, ev, depth
                valid[b, view, n] = ok
    return geo, valid


@njit(parallel=True, cache=True)
def project_backward(means, scales, quats, cams, valid, grad_geo, num_views, model, consts):
    """Gradients ``(B, N, 10)``: ``[mean (3), scale (3), quaternion (4)]`` summed over cameras (culled pairs: 0)."""
    num_b, num_n = means.shape[0], means.shape[1]
    grads = np.zeros((num_b, num_n, 10))
    num = num_b * num_n
    for chunk in prange((num + _CHUNK - 1) // _CHUNK):
        rot, wm, jac, t, g_t, g_wm, g_rot, g_jac = (np.empty(9), np.empty(9), np.empty(6), np.empty(6), np.empty(6),
                                                     np.empty(9), np.empty(9), np.empty(6))
        for i in range(chunk * _CHUNK, min(num, chunk * _CHUNK + _CHUNK)):
            b, n = i // num_n, i % num_n
            qw, qx, qy, qz, qn = _rotation(quats[b, n, 0], quats[b, n, 1], quats[b, n, 2], quats[b, n, 3], rot)
            for view in range(num_views):
                if not valid[b, view, n]:
                    continue
                cam = b * num_views + view
                px, py, pz = _camera_frame(means, scales, cams, b, n, cam, rot, wm)
                _pixel_map(px, py, pz, consts, model, jac)
                _times_wm(jac, wm, t)
                gg = grad_geo[b, view, n]
                _footprint_vjp(t, consts, gg[2], gg[3], gg[4], gg[5], gg[6], g_t)
                # T = J WM:  dJ[r, i] = sum_j dT[r, j] WM[i, j];  dWM[i, j] = sum_r J[r, i] dT[r, j]
                for r in range(2):
                    for k in range(3):
                        g_jac[3 * r + k] = (g_t[3 * r] * wm[3 * k] + g_t[3 * r + 1] * wm[3 * k + 1]
                                            + g_t[3 * r + 2] * wm[3 * k + 2])
                if model == 0:
                    g_px, g_py, g_pz = _equirect_map_vjp(px, py, pz, consts, gg[0], gg[1], gg[7], g_jac)
                else:
                    g_px, g_py, g_pz = _pinhole_map_vjp(px, py, pz, consts, gg[0], gg[1], gg[7], g_jac)
                for k in range(3):
                    for j in range(3):
                        g_wm[3 * k + j] = jac[k] * g_t[j] + jac[3 + k] * g_t[3 + j]
                # WM = Rc^T R diag(s):  d(R diag(s))[k, j] = sum_i Rc[k, i] dWM[i, j]
                c = cams[cam]
                for k in range(3):
                    for j in range(3):
                        gm = c[3 * k] * g_wm[j] + c[3 * k + 1] * g_wm[3 + j] + c[3 * k + 2] * g_wm[6 + j]
                        grads[b, n, 3 + j] += gm * rot[3 * k + j]
                        g_rot[3 * k + j] = gm * scales[b, n, j]
                g_qw, g_qx, g_qy, g_qz = _rotation_vjp(qw, qx, qy, qz, qn, g_rot)
                grads[b, n, 6] += g_qw
                grads[b, n, 7] += g_qx
                grads[b, n, 8] += g_qy
                grads[b, n, 9] += g_qz
                # p = W (mu - t):  d mu = Rc dp
                for k in range(3):
                    grads[b, n, k] += c[3 * k] * g_px + c[3 * k + 1] * g_py + c[3 * k + 2] * g_pz
    return grads
