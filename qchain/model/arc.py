"""Closed-form kinematics of a constant-strain (constant-curvature, extensible) slice and its
configuration derivatives.

The per-node kernel of the model, compiled with numba (it runs at every quadrature node of
every segment in every dynamics call). docs/model.md section 2 gives the slice placement
``g(alpha) = exp6(alpha l xi_u)``, ``xi_u = (0, 0, 1, -uy, ux, 0)``, the slice Jacobian ``S``
and its time derivative ``Sdot`` in closed form, with ``A = ad(xi_u)``, ``A^3 = -kappa^2 A``,
the entire functions ``f0(x) = sin(x)/x``, ``f1(x) = (1 - cos x)/x^2``,
``f2(x) = (x - sin x)/x^3`` of the bending angle ``x = s kappa``, ``g_n(x) = f_n'(x)/x``
(Taylor series below ``x = 2``, closed form above) and ``a1 = s f0, a2 = s^2 f1, a3 = s^3 f2``.

One order more, for the derivatives of the dynamics (:mod:`qchain.algorithms.rnea_derivatives`,
:func:`arc_node_derivatives`):

* ``dS[c] = dS/dq_c`` (6, 3) for ``c = l, ux, uy``;
* ``K[c] = d/dq_c (Sd(qdot) qdot)`` (6,) at fixed ``qdot``: the configuration derivative
  of the velocity-product part of the slice acceleration, a contraction of ``d^2 S/dq^2``.

With ``eta_i = d xi_u / d u_i`` the columns are ``S_l = alpha xi_u`` and
``S_ui = (s - a2 A + a3 A^2) eta_i``, and

    Sd(qdot) qdot = alpha ldot xid + alpha ldot (1 - a1 A + a2 A^2) xid
                    + (u . udot) (-s^4 g1 A + s^5 g2 A^2) xid + a3 xid x (A xid)

with ``xid = sum_i udot_i eta_i``. Their derivatives use ``d a1/ds = cos x``, ``d a2/ds = a1``,
``d a3/ds = a2``, ``d a_n/du_i = s^(n+2) g_(n-1) u_i`` and one more family of entire functions,
``h_n(x) = g_n'(x) / x`` (:func:`bend_h`; Taylor series below ``x = 2``, closed form above), so
nothing divides by the curvature: the straight pose is a regular point here too.

The kernels write these forms out entry by entry: ``xi_u``, ``eta_i`` and ``xid`` have two or
three nonzero entries, so each product by ``A`` is a few entries (``A xid = (-udot, 0, 0, c)``
with ``c = ux uyd - uy uxd``, ``A^2 xid = (0, 0, u . udot, c u, 0)``) and ``S``, ``Sd``, ``dS``
and ``K`` are short polynomials in ``u``, its rates and ``a1, a2, a3``. Six-vector cross
products would compute every zero (the compiler may not drop ``0 * x``: ``x`` could be
infinite), several times the arithmetic of a node. Each form is written once, as a function of
tuples (:func:`node_jacobian`, :func:`jacobian_rate`, :func:`node_derivatives`; together
:func:`slice_kinematics`), which the array kernels store and
:mod:`qchain.algorithms.slice_derivatives` evaluates for many nodes at once.

``tests/test_arc.py`` holds ``g``, ``Ad(g)^-1`` and ``S`` equal to Pinocchio's ``exp6``,
``SE3.action`` and ``Jexp6`` to 1e-14, and ``Sdot`` to finite differences;
``tests/test_derivatives.py`` holds ``dS`` and ``K`` to central differences of :func:`arc_node`.

Unchecked by design: the compiled kernels (:func:`arc_node`, :func:`arc_pose`, :func:`bend_h`,
:func:`arc_node_derivatives`) take arguments the checked API has validated (``docs/engine.md``,
"Unchecked kernels"); call the checked API (:func:`arc_nodes`, :func:`bend_functions`) unless you
guarantee them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from math import factorial

import numpy as np

from .._jit import jit, jit_helper, jit_inline, view2, view3
from ..checks.convert import as_batch, as_real_array
from .spatial import _inv_adjoint as inv_adjoint
from .spatial_kernels import put6

__all__ = ["ArcNodes", "arc_nodes", "bend_functions", "strain_twist", "arc_node", "arc_node_bias", "arc_pose", "bend_h",
           "arc_node_derivatives"]

_SERIES_BELOW = 2.0  # rad; at x = 2 the 16-term series is exact to 1e-25
_NTERMS = 16
# below x = 0.5 rad 8 terms do: the first term left out is under 5e-20 of the sum's size;
# below 1.25 rad 11 terms do (the first left out under 1e-20 of it)
_SHORT_BELOW, _NTERMS_SHORT = 0.5, 8
_MID_BELOW, _NTERMS_MID = 1.25, 11
_F_COEF = np.array([[(-1) ** k / factorial(2 * k + n + 1) for k in range(_NTERMS)] for n in range(3)])
_G_COEF = np.array(
    [[(-1) ** k * 2 * k / factorial(2 * k + n + 1) for k in range(1, _NTERMS + 1)] for n in range(3)]
)
_NTERMS_H = 16
# h_n(x) = sum_{k >= 2} (-1)^k 2k (2k - 2) x^(2k - 4) / (2k + n + 1)!, n = 1, 2
_H_COEF = np.array(
    [[(-1) ** k * 2 * k * (2 * k - 2) / factorial(2 * k + n + 1) for k in range(2, _NTERMS_H + 2)] for n in (1, 2)]
)


@jit
def _bend(x):
    """``(f0, f1, f2, g0, g1, g2)`` at bending angle ``x >= 0`` (rad)."""
    if x < _SERIES_BELOW:
        # the usual bend of a node takes the short series: half the work
        nt = _NTERMS_SHORT if x < _SHORT_BELOW else (_NTERMS_MID if x < _MID_BELOW else _NTERMS)
        t = x * x
        f0 = _F_COEF[0, nt - 1]
        f1 = _F_COEF[1, nt - 1]
        f2 = _F_COEF[2, nt - 1]
        g0 = _G_COEF[0, nt - 1]
        g1 = _G_COEF[1, nt - 1]
        g2 = _G_COEF[2, nt - 1]
        for k in range(nt - 2, -1, -1):
            f0 = f0 * t + _F_COEF[0, k]
            f1 = f1 * t + _F_COEF[1, k]
            f2 = f2 * t + _F_COEF[2, k]
            g0 = g0 * t + _G_COEF[0, k]
            g1 = g1 * t + _G_COEF[1, k]
            g2 = g2 * t + _G_COEF[2, k]
        return f0, f1, f2, g0, g1, g2
    s = np.sin(x)
    c = np.cos(x)
    x2 = x * x
    return (
        s / x,
        (1.0 - c) / x2,
        (x - s) / (x2 * x),
        (x * c - s) / (x2 * x),
        (x * s - 2.0 * (1.0 - c)) / (x2 * x2),
        (x * (1.0 - c) - 3.0 * (x - s)) / (x2 * x2 * x),
    )


@jit_inline
def _pose(a1, a2, ux, uy):
    """``(R, p)``: ``R = I + a1 [w] + a2 [w]^2`` (three row 3-tuples) with ``w = (-uy, ux, 0)``
    (``[w]^2 = w w^T - |w|^2 I``) and ``p = (a2 ux, a2 uy, a1)``."""
    k2 = ux * ux + uy * uy
    wx, wy = -uy, ux
    R = ((1.0 + a2 * (wx * wx - k2), a2 * wx * wy, a1 * wy),
         (a2 * wx * wy, 1.0 + a2 * (wy * wy - k2), -a1 * wx),
         (-a1 * wy, a1 * wx, 1.0 - a2 * k2))
    return R, (a2 * ux, a2 * uy, a1)


@jit_helper
def _write_pose(a1, a2, ux, uy, R, p):
    """:func:`_pose` into ``R`` (3, 3) and ``p`` (3,)."""
    Rt, pt = _pose(a1, a2, ux, uy)
    _put_rows(R, p, Rt, pt)


@jit_helper
def _put_rows(R, p, Rt, pt):
    """``R`` (3, 3) and ``p`` (3,) from three row 3-tuples ``Rt`` and a 3-tuple ``pt``."""
    for r in range(3):
        p[r] = pt[r]
        for c in range(3):
            R[r, c] = Rt[r][c]


@jit
def arc_pose(alpha, l, ux, uy, R, p):
    """Slice placement only (the ``R``, ``p`` of :func:`arc_node`), for drawing: slice
    ``alpha`` of a segment at ``(l, ux, uy)`` (m, 1/m, 1/m) into ``R`` (3, 3) and ``p`` (3,) (m)."""
    s = alpha * l
    f0, f1, _, _, _, _ = _bend(s * np.sqrt(ux * ux + uy * uy))
    _write_pose(s * f0, s * s * f1, ux, uy, R, p)


@jit_inline
def node_jacobian(alpha, l, ux, uy, f0, f1, f2):
    """``(s, a1, a2, a3, R, p, S)`` of slice ``alpha`` from the bend functions ``f0, f1, f2``
    at its bending angle (:func:`_bend`): ``R`` three row 3-tuples, ``p`` a 3-tuple and ``S``
    its three columns (6-tuples): ``S_l = alpha xi_u`` and ``S_ui = s eta_i - a2 (xi_u x eta_i)
    + a3 xi_u x (xi_u x eta_i)`` with ``eta_1 = e_5``, ``eta_2 = -e_4``, written out (the
    products of ``xi_u = (0, 0, 1, -uy, ux, 0)`` with them are a few of its entries)."""
    s = alpha * l
    s2 = s * s
    a1 = s * f0
    a2 = s2 * f1
    a3 = s2 * s * f2
    R, p = _pose(a1, a2, ux, uy)
    a3x, a3y = a3 * ux, a3 * uy
    S = ((0.0, 0.0, alpha, -alpha * uy, alpha * ux, 0.0),
         (a2, 0.0, a3x, -a3x * uy, s - a3y * uy, a2 * uy),
         (0.0, a2, a3y, a3x * ux - s, a3y * ux, -a2 * ux))
    return s, a1, a2, a3, R, p, S


@jit_helper
def _put_columns(S, cols):
    """``S[:, c] = cols[c]`` of a (6, 3) array and three 6-tuples."""
    for c in range(3):
        for r in range(6):
            S[r, c] = cols[c][r]


@jit_helper
def _node_jacobian(alpha, l, ux, uy, R, p, S):
    """``R``, ``p`` and ``S`` of :func:`arc_node`, and ``(s, a1, a2, a3, g1, g2)`` for the rates."""
    f0, f1, f2, g0, g1, g2 = _bend(alpha * l * np.sqrt(ux * ux + uy * uy))
    s, a1, a2, a3, Rt, pt, St = node_jacobian(alpha, l, ux, uy, f0, f1, f2)
    _put_rows(R, p, Rt, pt)
    _put_columns(S, St)
    return s, a1, a2, a3, g1, g2


@jit_helper
def _rates(alpha, ld, ux, uy, uxd, uyd, s, a1, a2, g1, g2):
    """The rates the slice's velocity terms are made of: ``(sdot, a2dot, a3dot, ud, c)`` with
    ``sdot = alpha ldot``, ``a2dot = sdot a1 + s^4 g1 ud`` and ``a3dot = sdot a2 + s^5 g2 ud``
    (the time derivatives of ``a2``, ``a3``), ``ud = u . udot`` and ``c = ux uyd - uy uxd``
    (the bend's turning rate times ``kappa^2``)."""
    sdot = alpha * ld
    ud = ux * uxd + uy * uyd
    s4 = s * s * s * s
    return sdot, sdot * a1 + s4 * g1 * ud, sdot * a2 + s4 * s * g2 * ud, ud, ux * uyd - uy * uxd


@jit
def arc_node_bias(alpha, l, ux, uy, ld, uxd, uyd, R, p, S, sd):
    """:func:`arc_node` with ``sd = Sd qdot`` (6,) in place of ``Sd``: the slice's bias
    acceleration from its own rates, all the passes use of ``Sd``, in closed form (the
    module docstring's ``Sd(qdot) qdot``, written out: with ``A xid = (-udot, 0, 0, c)``,
    ``A^2 xid = (0, 0, ud, c u, 0)`` and ``xid x (A xid) = (0, 0, |udot|^2, c udot, 0)``)."""
    s, a1, a2, a3, g1, g2 = _node_jacobian(alpha, l, ux, uy, R, p, S)
    sdot, a2d, a3d, ud, c = _rates(alpha, ld, ux, uy, uxd, uyd, s, a1, a2, g1, g2)
    sd[0] = a2d * uxd
    sd[1] = a2d * uyd
    sd[2] = a3d * ud + a3 * (uxd * uxd + uyd * uyd)
    sd[3] = c * (a3d * ux + a3 * uxd) - 2.0 * sdot * uyd
    sd[4] = c * (a3d * uy + a3 * uyd) + 2.0 * sdot * uxd
    sd[5] = -a2d * c


@jit
def arc_node(alpha, l, ux, uy, ld, uxd, uyd, R, p, S, Sd):
    """Slice kinematics at one node (numba; also callable from Python): ``g(alpha)``, ``S(alpha)``
    and ``dS/dt`` of docs/model.md section 2 (the paper's eq. (1) at ``s = alpha l``).

    ``Sd`` is the time derivative of :func:`_node_jacobian`'s closed form of ``S``, entry by
    entry (``d a2/dt``, ``d a3/dt`` from :func:`_rates`).

    Parameters
    ----------
    alpha : float            slice coordinate in [0, 1].
    l, ux, uy : float        configuration (m, 1/m, 1/m).
    ld, uxd, uyd : float     velocity for ``Sd`` (zeros if not wanted).
    R : (3, 3) out           slice rotation in the root frame.
    p : (3,) out             slice centre in the root frame (m).
    S : (6, 3) out           slice Jacobian (slice body frame).
    Sd : (6, 3) out          ``dS/dt`` along ``(ld, uxd, uyd)``.
    """
    s, a1, a2, a3, g1, g2 = _node_jacobian(alpha, l, ux, uy, R, p, S)
    sdot, a2d, a3d, _, _ = _rates(alpha, ld, ux, uy, uxd, uyd, s, a1, a2, g1, g2)
    _put_columns(Sd, jacobian_rate(alpha, ux, uy, uxd, uyd, a2, a3, sdot, a2d, a3d))


@jit_inline
def jacobian_rate(alpha, ux, uy, uxd, uyd, a2, a3, sdot, a2d, a3d):
    """``Sd = dS/dt`` (three column 6-tuples): the time derivative of :func:`node_jacobian`'s
    ``S`` entry by entry, with the rates ``sdot, a2d, a3d`` of :func:`_rates`."""
    # S[:, 1] = (a2, 0, a3 ux, -a3 ux uy, s - a3 uy^2, a2 uy)
    # S[:, 2] = (0, a2, a3 uy, a3 ux^2 - s, a3 ux uy, -a2 ux)
    cross = a3d * ux * uy + a3 * (uxd * uy + ux * uyd)
    return ((0.0, 0.0, 0.0, -alpha * uyd, alpha * uxd, 0.0),
            (a2d, 0.0, a3d * ux + a3 * uxd, -cross, sdot - a3d * uy * uy - 2.0 * a3 * uy * uyd, a2d * uy + a2 * uyd),
            (0.0, a2d, a3d * uy + a3 * uyd, a3d * ux * ux + 2.0 * a3 * ux * uxd - sdot, cross, -(a2d * ux + a2 * uxd)))


@jit
def bend_h(x):
    """``(h1, h2)`` with ``h_n(x) = g_n'(x) / x`` at bending angle ``x >= 0`` (rad).

    At ``x = 0``: ``h1 = 1/90``, ``h2 = 1/630``.
    """
    if x < _SERIES_BELOW:
        t = x * x
        h1 = _H_COEF[0, _NTERMS_H - 1]
        h2 = _H_COEF[1, _NTERMS_H - 1]
        for k in range(_NTERMS_H - 2, -1, -1):
            h1 = h1 * t + _H_COEF[0, k]
            h2 = h2 * t + _H_COEF[1, k]
        return h1, h2
    s = np.sin(x)
    c = np.cos(x)
    x2 = x * x
    x6 = x2 * x2 * x2
    return (x2 * c - 5.0 * x * s + 8.0 * (1.0 - c)) / x6, (x2 * s + 7.0 * x * c + 8.0 * x - 15.0 * s) / (x6 * x)


@jit
def arc_node_derivatives(alpha, l, ux, uy, ld, uxd, uyd, dS, K):
    """``dS`` (3, 6, 3) ``= dS/dq_c`` and ``K`` (3, 6) ``= d(Sd qdot)/dq_c`` at one node.

    Same arguments as :func:`arc_node` (``alpha``; ``q = (l, ux, uy)`` in m, 1/m;
    ``qdot = (ld, uxd, uyd)``); ``c`` runs over ``l, ux, uy``. Slice body frame,
    ``[linear; angular]``. Both are the derivatives of closed forms, entry by entry:
    ``dS`` of :func:`_node_jacobian`'s ``S``, ``K`` of :func:`arc_node_bias`'s ``sd``, with the
    module docstring's derivatives of ``a1, a2, a3`` and of ``s^4 g1``, ``s^5 g2``
    (``d/ds: 4 s^3 g1 + s^5 kappa^2 h1``, ``5 s^4 g2 + s^6 kappa^2 h2``;
    ``d/du_i: s^6 h1 u_i``, ``s^7 h2 u_i``).
    """
    f0, f1, f2, g0, g1, g2, h1, h2 = bend_values(alpha, l, ux, uy)
    s = alpha * l
    s2 = s * s
    a1 = s * f0
    a2 = s2 * f1
    a3 = s2 * s * f2
    sdot, a2d, a3d, ud, c = _rates(alpha, ld, ux, uy, uxd, uyd, s, a1, a2, g1, g2)
    dSt, Kt = node_derivatives(alpha, ux, uy, uxd, uyd, s, a1, a2, a3, f1, g0, g1, g2, h1, h2, sdot, a2d, a3d, ud, c)
    # literal indices: a tuple indexed by a loop variable is copied to memory first
    _put_columns(dS[0], dSt[0])
    _put_columns(dS[1], dSt[1])
    _put_columns(dS[2], dSt[2])
    put6(K[0], Kt[0])
    put6(K[1], Kt[1])
    put6(K[2], Kt[2])


@jit_inline
def node_derivatives(alpha, ux, uy, uxd, uyd, s, a1, a2, a3, f1, g0, g1, g2, h1, h2, sdot, a2d, a3d, ud, c):
    """``(dS, K)`` of :func:`arc_node_derivatives` as tuples: ``dS[k]`` the three columns
    (6-tuples) of ``dS/dq_k``, ``K[k]`` (6-tuple) ``= d(Sd qdot)/dq_k``, from the slice's ``s,
    a1, a2, a3``, the bend functions ``f1, g0, g1, g2, h1, h2`` and the rates of :func:`_rates`."""
    k2 = ux * ux + uy * uy
    s2 = s * s
    s3 = s2 * s
    s4 = s2 * s2
    cx = 1.0 - s2 * k2 * f1  # cos x from f1 = (1 - cos x) / x^2: no transcendental call per node
    G1 = s4 * g1  # d a2 / du_i = G1 u_i
    G2 = s4 * s * g2  # d a3 / du_i = G2 u_i
    b1 = s3 * g0  # d a1 / du_i = b1 u_i
    qd2 = uxd * uxd + uyd * uyd
    z6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    # dS/dl = alpha dS/ds (d a1/ds = cos x, d a2/ds = a1, d a3/ds = a2); S[:, 0] does not move
    dl = (z6,
          (alpha * a1, 0.0, alpha * a2 * ux, -alpha * a2 * ux * uy, alpha * (1.0 - a2 * uy * uy), alpha * a1 * uy),
          (0.0, alpha * a1, alpha * a2 * uy, alpha * (a2 * ux * ux - 1.0), alpha * a2 * ux * uy, -alpha * a1 * ux))
    # dS/dux, dS/duy: S[:, 0] = alpha (0, 0, 1, -uy, ux, 0)
    tx = a3 + G2 * ux * ux
    ty = a3 + G2 * uy * uy
    gxy = G2 * ux * uy
    dx = ((0.0, 0.0, 0.0, 0.0, alpha, 0.0),
          (G1 * ux, 0.0, tx, -uy * tx, -gxy * uy, G1 * ux * uy),
          (0.0, G1 * ux, gxy, ux * (a3 + tx), uy * tx, -(a2 + G1 * ux * ux)))
    dy = ((0.0, 0.0, 0.0, -alpha, 0.0, 0.0),
          (G1 * uy, 0.0, gxy, -ux * ty, -uy * (a3 + ty), a2 + G1 * uy * uy),
          (0.0, G1 * uy, ty, gxy * ux, ux * ty, -G1 * ux * uy))
    # K[k] = d sd / dq_k of sd = (a2d udot, a3d ud + a3 |udot|^2, c (a3d u + a3 udot) +
    # 2 sdot (-uyd, uxd), -a2d c), at fixed rates: dud/du_i = udot_i, dc/du = (uyd, -uxd)
    Kl = _k_row(alpha * (sdot * cx + (4.0 * s3 * g1 + s4 * s * k2 * h1) * ud),
                alpha * (sdot * a1 + (5.0 * s4 * g2 + s4 * s2 * k2 * h2) * ud), alpha * a2,
                0.0, 0.0, 0.0, 0.0, ux, uy, uxd, uyd, a2d, a3d, a3, ud, c, qd2)
    Kx = _k_row((sdot * b1 + s4 * s2 * h1 * ud) * ux + G1 * uxd, (sdot * G1 + s4 * s3 * h2 * ud) * ux + G2 * uxd,
                G2 * ux, uxd, uyd, 1.0, 0.0, ux, uy, uxd, uyd, a2d, a3d, a3, ud, c, qd2)
    Ky = _k_row((sdot * b1 + s4 * s2 * h1 * ud) * uy + G1 * uyd, (sdot * G1 + s4 * s3 * h2 * ud) * uy + G2 * uyd,
                G2 * uy, uyd, -uxd, 0.0, 1.0, ux, uy, uxd, uyd, a2d, a3d, a3, ud, c, qd2)
    return (dl, dx, dy), (Kl, Kx, Ky)


@jit_helper
def _k_row(da2d, da3d, da3, dud, dc, dux, duy, ux, uy, uxd, uyd, a2d, a3d, a3, ud, c, qd2):
    """One ``K[k]`` (6-tuple) from the derivatives of ``a2d, a3d, a3, ud, c, ux, uy`` by ``q_k``."""
    return (da2d * uxd, da2d * uyd, da3d * ud + a3d * dud + da3 * qd2,
            dc * (a3d * ux + a3 * uxd) + c * (da3d * ux + a3d * dux + da3 * uxd),
            dc * (a3d * uy + a3 * uyd) + c * (da3d * uy + a3d * duy + da3 * uyd),
            -(da2d * c + a2d * dc))


@jit_inline
def slice_kinematics(alpha, l, ux, uy, ld, uxd, uyd, bend):
    """``(R, p, S, Sd, dS, K)`` of slice ``alpha`` (as tuples: ``R``
    three rows, ``S``, ``Sd`` three columns, ``dS[c]`` the three columns of ``dS/dq_c``, ``K[c]
    = d(Sd qdot)/dq_c``) from the bend functions ``bend = (f0, f1, f2, g0, g1, g2, h1, h2)`` at
    its bending angle."""
    f0, f1, f2, g0, g1, g2, h1, h2 = bend
    s, a1, a2, a3, R, p, S = node_jacobian(alpha, l, ux, uy, f0, f1, f2)
    sdot, a2d, a3d, ud, c = _rates(alpha, ld, ux, uy, uxd, uyd, s, a1, a2, g1, g2)
    Sd = jacobian_rate(alpha, ux, uy, uxd, uyd, a2, a3, sdot, a2d, a3d)
    dS, K = node_derivatives(alpha, ux, uy, uxd, uyd, s, a1, a2, a3, f1, g0, g1, g2, h1, h2, sdot, a2d, a3d, ud, c)
    return R, p, S, Sd, dS, K


@jit_helper
def bend_values(alpha, l, ux, uy):
    """``(f0, f1, f2, g0, g1, g2, h1, h2)`` at the bending angle of slice ``alpha``."""
    x = alpha * l * np.sqrt(ux * ux + uy * uy)
    f0, f1, f2, g0, g1, g2 = _bend(x)
    h1, h2 = bend_h(x)
    return f0, f1, f2, g0, g1, g2, h1, h2


@jit
def _arc_nodes_kernel(alpha, q, qd, R, p, S, Sd):
    for k in range(alpha.shape[0]):
        arc_node(alpha[k], q[k, 0], q[k, 1], q[k, 2], qd[k, 0], qd[k, 1], qd[k, 2], R[k], p[k], S[k], Sd[k])


@jit
def _bend_kernel(x, out):
    for k in range(x.shape[0]):
        r = _bend(x[k])
        for n in range(6):
            out[n, k] = r[n]


def bend_functions(x, derivatives: bool = False):
    """The entire functions ``(f0, f1, f2)`` (and ``(g0, g1, g2)`` with ``derivatives``) of
    bending angles ``x`` (rad; even functions, so any finite real), each of the shape of
    ``x``. At ``x = 0``: ``f = (1, 1/2, 1/6)``, ``g = (-1/3, -1/12, -1/60)``.
    ``x`` must be real and finite (``TypeError``/``ValueError`` naming it)."""
    x = as_real_array("x", x)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"x must be finite, got non-finite entries at flat indices "
                         f"{np.flatnonzero(~np.isfinite(x.ravel())).tolist()[:10]}")
    xa = np.ascontiguousarray(np.atleast_1d(x).ravel())
    out = np.empty((6, xa.size))
    _bend_kernel(xa, out)
    out = out.reshape((6,) + np.shape(x))
    return (out[:3], out[3:]) if derivatives else out[:3]


def strain_twist(q: np.ndarray) -> np.ndarray:
    """Unit-length strain twist ``xi_u = (0, 0, 1, -uy, ux, 0)``, ``(..., 3)`` -> ``(..., 6)``
    (``q`` real and finite, else ``TypeError``/``ValueError`` naming it)."""
    q = as_batch("q", q, 3)
    xi = np.zeros(q.shape[:-1] + (6,))
    xi[..., 2] = 1.0
    xi[..., 3] = -q[..., 2]
    xi[..., 4] = q[..., 1]
    return xi


@dataclass(frozen=True)
class ArcNodes:
    """Slice kinematics at N nodes, in curvature coordinates ``q = (l, ux, uy)``.

    Attributes
    ----------
    R : (N, 3, 3)  rotation of the slice frame in the root frame.
    p : (N, 3)     slice centre in the root frame (m).
    Ad_inv : (N, 6, 6)  ``Ad(g)^-1``: root-frame twist -> slice-frame twist.
    S : (N, 6, 3)  slice Jacobian: slice body twist per unit ``qdot`` (columns l, ux, uy).
    Sdot : (N, 6, 3)  ``dS/dt`` along the given ``qdot`` (zeros without one).
    """

    R: np.ndarray
    p: np.ndarray
    S: np.ndarray
    Sdot: np.ndarray

    @cached_property
    def Ad_inv(self) -> np.ndarray:
        """``Ad(g)^-1`` (N, 6, 6), formed on first use."""
        return inv_adjoint(self.R, self.p)


def arc_nodes(alpha, q, qdot=None) -> ArcNodes:
    """Slice kinematics at nodes ``alpha`` (N,) for configurations ``q`` (N, 3) or (3,).

    ``qdot`` ((N, 3) or (3,)) adds the exact time derivative ``Sdot`` of the Jacobian.
    Every argument must be real and finite, ``alpha`` a number or 1-D (``TypeError`` or
    ``ValueError`` naming the argument); the kinematics is that of any curvature (a
    segment's own domain, ``|kappa| r_s < 1``, is checked by :class:`qchain.Segment`).
    """
    alpha = np.atleast_1d(as_real_array("alpha", alpha))
    if alpha.ndim != 1 or not np.all(np.isfinite(alpha)):
        raise ValueError(f"alpha must be a finite number or 1-D array of them, got shape {alpha.shape}"
                         + ("" if alpha.ndim != 1 else " with non-finite entries"))
    alpha = np.ascontiguousarray(alpha)
    N = alpha.shape[0]
    q = _per_node("q", q, N)
    qd = np.zeros((N, 3)) if qdot is None else _per_node("qdot", qdot, N)
    R = np.empty((N, 3, 3))
    p = np.empty((N, 3))
    S = np.empty((N, 6, 3))
    Sd = np.empty((N, 6, 3))
    _arc_nodes_kernel(alpha, q, qd, R, p, S, Sd)
    return ArcNodes(R=R, p=p, S=S, Sdot=Sd)


def _per_node(name: str, x, N: int) -> np.ndarray:
    """``x`` (3,) or (N, 3), real and finite, as a C-contiguous (N, 3) float array."""
    x = as_batch(name, x, 3)
    if x.shape not in ((3,), (N, 3)):
        raise ValueError(f"{name} must have shape (3,) or ({N}, 3) (one a node), got {x.shape}")
    return np.ascontiguousarray(np.broadcast_to(x, (N, 3)))


#: Floats of per-call scratch a compiled pass carves its small temporaries from
#: (:func:`take1`): the derivative pass's blocks of lanes take about 4200
#: (:data:`qchain.algorithms.slice_derivatives.LANE_SCRATCH`), every other nest of passes under
#: a thousand.
SCRATCH = 8192


@jit_helper
def take1(sc, o, k):
    """``(sc[o:o+k], o + k)``: a vector of scratch, no allocation."""
    return sc[o : o + k], o + k


@jit_helper
def take2(sc, o, r, c):
    """A (r, c) matrix of scratch from offset ``o`` and the next offset."""
    return view2(sc[o : o + r * c], r, c), o + r * c


@jit_helper
def take3(sc, o, a, b, c):
    """An (a, b, c) array of scratch from offset ``o`` and the next offset."""
    return view3(sc[o : o + a * b * c], a, b, c), o + a * b * c
