"""Compiled free-flyer configuration algebra, in Pinocchio's conventions.

A free-flyer configuration ``q = (x, y, z, qx, qy, qz, qw)`` (7,) is the placement
``M = (R, p)`` of the base in the world: ``p`` (m) and the unit quaternion of ``R``
(Eigen's coefficient order, scalar last). A tangent ``d = [v; w]`` (6,) is a twist in the
base's *body* frame, linear (m) then angular (rad), as ``pinocchio.Motion.vector``.

* ``ff_integrate(q, d)  = M exp6(d)``        (``pinocchio.integrate`` of a JointModelFreeFlyer)
* ``ff_difference(q0, q1) = log6(M0^-1 M1)`` (``pinocchio.difference``)
* ``dexp_inv(d) = Jexp6(d)^-1``              (right Jacobian of exp6, inverted in closed form)

The formulas are Pinocchio 4's quaternion ones (``quaternion::exp6``, ``log6(quat, vec)``,
``Jlog6``): the result quaternion of ``integrate`` has a non-negative dot product with the
input's, ``difference`` returns the rotation angle in ``[0, pi]``. They differ in two ways
that only make them more accurate: the quaternion is normalised exactly (Pinocchio does a
first-order step) and every function of ``theta = |w|`` is evaluated by its Taylor series
(Horner in ``theta^2``, 12 terms, exact to rounding) for ``theta < 1`` rad and in closed form
above, so nothing divides by ``|w|`` and the cancellations of the closed forms
(``theta - sin theta``, ``1 - (theta/2) cot(theta/2)`` and the ``1/theta^4`` one in
``Jlog6``, where Pinocchio 4.1's ``Jexp6`` loses up to 5e-8 at ``|w| = 1e-3``) never bite.
Like Pinocchio, the input quaternions are taken as unit ones. The functions of ``theta``:

* ``b = (1 - cos theta)/theta^2``, ``c = (theta - sin theta)/theta^3`` (``V = I + b[w] + c[w]^2``);
* ``beta = (1 - (theta/2) cot(theta/2))/theta^2 = sum |B_2n| theta^(2n-2)/(2n)!`` and
  ``beta'/theta`` (Bernoulli numbers ``B_2n``; the series converge for ``theta < 2 pi``,
  where ``Jexp6`` becomes singular).

Everything is allocation-free: the caller passes the float64 output arrays.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

from fractions import Fraction
from math import comb, factorial

import numpy as np

from ..._jit import jit

__all__ = ["ff_integrate", "ff_difference", "dexp_inv", "dexp_inv_apply"]

_SERIES_BELOW = 1.0  # rad; at theta = 1 every 12-term series below is exact to < 1e-19 relative
_NT = 12


def _bernoulli(n: int) -> list[Fraction]:
    """``B_0 .. B_n`` (``B_1 = -1/2``) from the defining recurrence, exactly."""
    B = [Fraction(1)]
    for m in range(1, n + 1):
        B.append(-sum(comb(m + 1, k) * B[k] for k in range(m)) / (m + 1))
    return B


_B = _bernoulli(2 * _NT + 2)
_CH_COEF = np.array([(-1) ** k / (4**k * factorial(2 * k)) for k in range(_NT)])  # cos(t/2)
_SH_COEF = np.array([(-1) ** k / (2 * 4**k * factorial(2 * k + 1)) for k in range(_NT)])  # sin(t/2)/t
_B_COEF = np.array([(-1) ** k / factorial(2 * k + 2) for k in range(_NT)])  # (1 - cos t)/t^2
_C_COEF = np.array([(-1) ** k / factorial(2 * k + 3) for k in range(_NT)])  # (t - sin t)/t^3
_BETA_COEF = np.array([float(abs(_B[2 * k + 2]) / factorial(2 * k + 2)) for k in range(_NT)])
_BDOT_COEF = np.array([float((2 * k + 2) * abs(_B[2 * k + 4]) / factorial(2 * k + 4)) for k in range(_NT)])


@jit
def _series(coef, x):
    """``sum_k coef[k] x^k`` by Horner's rule."""
    r = coef[coef.size - 1]
    for k in range(coef.size - 2, -1, -1):
        r = r * x + coef[k]
    return r


@jit
def _exp_coefs(t2):
    """``(cos(t/2), sin(t/2)/t, b, c)`` at ``t = sqrt(t2)`` rad (see the module docstring)."""
    if t2 < _SERIES_BELOW * _SERIES_BELOW:
        # LLVM unrolls and interleaves the four Horner loops: ~12 ns for all four
        return _series(_CH_COEF, t2), _series(_SH_COEF, t2), _series(_B_COEF, t2), _series(_C_COEF, t2)
    t = np.sqrt(t2)
    sh = np.sin(0.5 * t)
    ch = np.cos(0.5 * t)
    sht = sh / t
    return ch, sht, 2.0 * sht * sht, (t - 2.0 * sh * ch) / (t * t2)


@jit
def _dexp_coefs(t2):
    """``(b, c, beta, beta'/t)`` at ``t = sqrt(t2)`` rad, ``t < 2 pi``."""
    if t2 < _SERIES_BELOW * _SERIES_BELOW:
        return _series(_B_COEF, t2), _series(_C_COEF, t2), _series(_BETA_COEF, t2), _series(_BDOT_COEF, t2)
    t = np.sqrt(t2)
    sh = np.sin(0.5 * t)
    ch = np.cos(0.5 * t)
    cot = ch / sh
    beta = 1.0 / t2 - 0.5 * cot / t
    bdot = -2.0 / (t2 * t2) + 0.5 * cot / (t * t2) + 0.25 / (t2 * sh * sh)
    return 2.0 * sh * sh / t2, (t - 2.0 * sh * ch) / (t * t2), beta, bdot


@jit
def _quat_mul(ax, ay, az, aw, bx, by, bz, bw):
    """Hamilton product ``a b`` (Eigen's order of operations)."""
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by + ay * bw + az * bx - ax * bz,
        aw * bz + az * bw + ax * by - ay * bx,
        aw * bw - ax * bx - ay * by - az * bz,
    )


@jit
def _quat_rotate(qx, qy, qz, qw, vx, vy, vz):
    """``R(q) v`` as Eigen's ``quat * v``: ``v + 2 qw (qv x v) + qv x (2 qv x v)``."""
    ux = 2.0 * (qy * vz - qz * vy)
    uy = 2.0 * (qz * vx - qx * vz)
    uz = 2.0 * (qx * vy - qy * vx)
    return (
        vx + qw * ux + (qy * uz - qz * uy),
        vy + qw * uy + (qz * ux - qx * uz),
        vz + qw * uz + (qx * uy - qy * ux),
    )


@jit
def _so3_poly(wx, wy, wz, b, c, x0, x1, x2):
    """``x + b w x x + c w x (w x x)`` (3-tuple): ``V(w) x``, ``V(w)^-1 x``, ``Jlog3(w) x``."""
    ux = wy * x2 - wz * x1
    uy = wz * x0 - wx * x2
    uz = wx * x1 - wy * x0
    return (
        x0 + b * ux + c * (wy * uz - wz * uy),
        x1 + b * uy + c * (wz * ux - wx * uz),
        x2 + b * uz + c * (wx * uy - wy * ux),
    )


@jit
def ff_integrate(q, d, out):
    """``M exp6(d)``: Pinocchio's ``integrate`` of a free-flyer joint.

    Parameters
    ----------
    q : (7,) float64
        ``(x, y, z, qx, qy, qz, qw)``: position (m, world) and unit quaternion of the base.
    d : (6,) float64
        Tangent ``[v; w]`` in the base's body frame (m, rad).
    out : (7,) float64
        Result, quaternion normalised, sign chosen with ``dot(q_out, q_in) >= 0`` as Pinocchio
        does. May alias ``q``.
    """
    vx, vy, vz, wx, wy, wz = d[0], d[1], d[2], d[3], d[4], d[5]
    qx, qy, qz, qw = q[3], q[4], q[5], q[6]
    ch, sht, b, c = _exp_coefs(wx * wx + wy * wy + wz * wz)
    px, py, pz = _so3_poly(wx, wy, wz, b, c, vx, vy, vz)  # translation of exp6(d): V v
    rx, ry, rz = _quat_rotate(qx, qy, qz, qw, px, py, pz)
    nx, ny, nz, nw = _quat_mul(qx, qy, qz, qw, sht * wx, sht * wy, sht * wz, ch)
    # Pinocchio keeps the hemisphere of the input quaternion
    s = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz + nw * nw)
    if nx * qx + ny * qy + nz * qz + nw * qw < 0.0:
        s = -s
    out[0] = q[0] + rx
    out[1] = q[1] + ry
    out[2] = q[2] + rz
    out[3] = s * nx
    out[4] = s * ny
    out[5] = s * nz
    out[6] = s * nw


@jit
def ff_difference(q0, q1, out):
    """``log6(M0^-1 M1)``: Pinocchio's ``difference`` of a free-flyer joint.

    Parameters
    ----------
    q0, q1 : (7,) float64
        Free-flyer configurations (m, unit quaternions).
    out : (6,) float64
        ``[v; w]`` in the body frame of ``M0`` (m, rad), ``|w| <= pi``, so that
        ``ff_integrate(q0, out) == q1`` (up to the quaternion's sign).
    """
    ax, ay, az, aw = -q0[3], -q0[4], -q0[5], q0[6]  # conj(q0) = q0^-1
    px, py, pz = _quat_rotate(ax, ay, az, aw, q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2])
    rx, ry, rz, rw = _quat_mul(ax, ay, az, aw, q1[3], q1[4], q1[5], q1[6])
    if rw < 0.0:  # the other hemisphere: same rotation, angle <= pi
        rx, ry, rz, rw = -rx, -ry, -rz, -rw
    s = np.sqrt(rx * rx + ry * ry + rz * rz)  # |q| sin(theta/2)
    theta = 2.0 * np.arctan2(s, rw)
    if s < 1e-5:
        # theta/s = (2/rw) atan(x)/x, x = s/rw: series (truncation x^6/7 < 1e-30)
        x2 = (s / rw) * (s / rw)
        k = (2.0 / rw) * (1.0 - x2 / 3.0 + x2 * x2 / 5.0)
    else:
        k = theta / s
    wx, wy, wz = k * rx, k * ry, k * rz
    t2 = theta * theta
    if theta < _SERIES_BELOW:
        beta = _series(_BETA_COEF, t2)
    else:
        beta = 1.0 / t2 - 0.5 * (rw / s) / theta
    out[0], out[1], out[2] = _so3_poly(wx, wy, wz, -0.5, beta, px, py, pz)  # V^-1 p
    out[3] = wx
    out[4] = wy
    out[5] = wz


@jit
def dexp_inv(d, out):
    """``Jexp6(d)^-1`` in closed form (Pinocchio's ``Jlog6`` written in terms of ``d``).

    ``Jexp6(d) = [[Jr, -Jr C], [0, Jr]]`` with ``Jr`` the right Jacobian of exp3, so the
    inverse is ``[[A, C A], [0, A]]`` with ``A = Jr^-1 = I + [w]/2 + beta [w]^2`` (Jlog3) and

        C = [p]/2 + beta'/theta (w.p) w w^T - (theta beta' + 2 beta) p w^T + beta (w.p) I + beta w p^T,

    ``p = V(w) v`` the translation of ``exp6(d)`` (``w.p = w.v``).

    Parameters
    ----------
    d : (6,) float64
        ``[v; w]`` (m, rad), ``|w| < 2 pi``.
    out : (6, 6) float64
        Written in full; the lower-left block serves as scratch for ``C`` before it is zeroed.
    """
    vx, vy, vz, wx, wy, wz = d[0], d[1], d[2], d[3], d[4], d[5]
    t2 = wx * wx + wy * wy + wz * wz
    b, c, beta, bdot = _dexp_coefs(t2)
    p0, p1, p2 = _so3_poly(wx, wy, wz, b, c, vx, vy, vz)
    w = (wx, wy, wz)
    p = (p0, p1, p2)
    wp = wx * vx + wy * vy + wz * vz
    diag = 1.0 - beta * t2
    k1 = bdot * wp
    k2 = t2 * bdot + 2.0 * beta
    for i in range(3):
        for j in range(3):
            out[i, j] = beta * w[i] * w[j]
            out[i + 3, j] = k1 * w[i] * w[j] - k2 * p[i] * w[j] + beta * w[i] * p[j]
        out[i, i] += diag
        out[i + 3, i] += beta * wp
    for i in range(3):  # + [w]/2 on A, + [p]/2 on C: [x]_jk = -x_i, [x]_kj = x_i
        j, k = (i + 1) % 3, (i + 2) % 3
        out[j, k] -= 0.5 * w[i]
        out[k, j] += 0.5 * w[i]
        out[j + 3, k] -= 0.5 * p[i]
        out[k + 3, j] += 0.5 * p[i]
    for i in range(3):
        for j in range(3):
            out[i + 3, j + 3] = out[i, j]
            out[i, j + 3] = out[i + 3, 0] * out[0, j] + out[i + 3, 1] * out[1, j] + out[i + 3, 2] * out[2, j]
    for i in range(3):
        for j in range(3):
            out[i + 3, j] = 0.0


@jit
def dexp_inv_apply(d, u, out):
    """``dexp_inv(d) @ u`` without forming the matrix.

    Parameters
    ----------
    d : (6,) float64
        ``[v; w]`` (m, rad), ``|w| < 2 pi``.
    u : (6,) float64
        Vector to map ``[linear; angular]``.
    out : (6,) float64
        Result; may alias ``u``.
    """
    vx, vy, vz, wx, wy, wz = d[0], d[1], d[2], d[3], d[4], d[5]
    t2 = wx * wx + wy * wy + wz * wz
    b, c, beta, bdot = _dexp_coefs(t2)
    px, py, pz = _so3_poly(wx, wy, wz, b, c, vx, vy, vz)
    wp = wx * vx + wy * vy + wz * vz
    y0, y1, y2 = _so3_poly(wx, wy, wz, 0.5, beta, u[3], u[4], u[5])  # A u_ang
    z0, z1, z2 = _so3_poly(wx, wy, wz, 0.5, beta, u[0], u[1], u[2])  # A u_lin
    # C y = [p]y/2 + (beta'/t (w.p)(w.y) + beta (p.y)) w - (t beta' + 2 beta)(w.y) p + beta (w.p) y
    wdy = wx * y0 + wy * y1 + wz * y2
    kw = bdot * wp * wdy + beta * (px * y0 + py * y1 + pz * y2)
    kp = -(t2 * bdot + 2.0 * beta) * wdy
    ky = beta * wp
    out[0] = z0 + 0.5 * (py * y2 - pz * y1) + kw * wx + kp * px + ky * y0
    out[1] = z1 + 0.5 * (pz * y0 - px * y2) + kw * wy + kp * py + ky * y1
    out[2] = z2 + 0.5 * (px * y1 - py * y0) + kw * wz + kp * pz + ky * y2
    out[3] = y0
    out[4] = y1
    out[5] = y2
