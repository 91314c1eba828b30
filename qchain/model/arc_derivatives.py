"""Configuration derivatives of the slice kinematics, closed form (numba).

:mod:`qchain.model.arc` gives a slice's Jacobian ``S(alpha; q)`` (6, 3) and its time derivative
``Sd = sum_i qdot_i dS/dq_i``. The derivatives of the dynamics (:mod:`qchain.algorithms.derivatives`)
need one order more:

* ``dS[c] = dS/dq_c`` (6, 3) for ``c = l, ux, uy``;
* ``K[c] = d/dq_c (Sd(qdot) qdot)`` (6,) at fixed ``qdot``: the configuration derivative
  of the velocity-product part of the slice acceleration, a contraction of ``d^2 S/dq^2``.

With ``s = alpha l``, ``A = ad(xi_u)``, ``eta_i = d xi_u / d u_i`` and the bending functions
of :mod:`qchain.model.arc` (``a1 = s f0``, ``a2 = s^2 f1``, ``a3 = s^3 f2``), the columns are
``S_l = alpha xi_u`` and ``S_ui = (s - a2 A + a3 A^2) eta_i``, and

    Sd(qdot) qdot = alpha ldot xid + alpha ldot (1 - a1 A + a2 A^2) xid
                    + (u . udot) (-s^4 g1 A + s^5 g2 A^2) xid + a3 xid x (A xid)

with ``xid = sum_i udot_i eta_i``. Their derivatives use ``d a1/ds = cos x``, ``d a2/ds = a1``,
``d a3/ds = a2``, ``d a_n/du_i = s^(n+2) g_(n-1) u_i`` and one more family of entire functions,
``h_n(x) = g_n'(x) / x`` (Taylor series below ``x = 2``, closed form above), so nothing
divides by the curvature: the straight pose is a regular point here too.
``tests/test_derivatives.py`` holds ``dS`` and ``K`` to central differences of
:func:`qchain.model.arc.arc_node`.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

from math import factorial

import numpy as np

from .arc import _SERIES_BELOW, _bend, _mcross, jit

__all__ = ["bend_h", "arc_node_derivatives"]

_NTERMS_H = 16
# h_n(x) = sum_{k >= 2} (-1)^k 2k (2k - 2) x^(2k - 4) / (2k + n + 1)!, n = 1, 2
_H_COEF = np.array(
    [[(-1) ** k * 2 * k * (2 * k - 2) / factorial(2 * k + n + 1) for k in range(2, _NTERMS_H + 2)] for n in (1, 2)]
)


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

    Same arguments as :func:`qchain.model.arc.arc_node` (``alpha``; ``q = (l, ux, uy)`` in m, 1/m;
    ``qdot = (ld, uxd, uyd)``); ``c`` runs over ``l, ux, uy``. Slice body frame,
    ``[linear; angular]``.
    """
    s = alpha * l
    k2 = ux * ux + uy * uy
    x = s * np.sqrt(k2)
    f0, f1, f2, g0, g1, g2 = _bend(x)
    h1, h2 = bend_h(x)
    s2 = s * s
    s3 = s2 * s
    s4 = s2 * s2
    s5 = s4 * s
    a1 = s * f0
    a2 = s2 * f1
    a3 = s3 * f2
    cx = np.cos(x)
    ud = ux * uxd + uy * uyd
    u = (ux, uy)
    udot = (uxd, uyd)
    xi = (0.0, 0.0, 1.0, -uy, ux, 0.0)
    xd = (0.0, 0.0, 0.0, -uyd, uxd, 0.0)
    eta = ((0.0, 0.0, 0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, -1.0, 0.0, 0.0))
    # first derivatives of S
    for r in range(6):
        dS[0, r, 0] = 0.0
    for j in range(2):
        ej = eta[j]
        Ae = _mcross(xi, ej)
        AAe = _mcross(xi, Ae)
        for r in range(6):
            dS[0, r, 1 + j] = alpha * (ej[r] - a1 * Ae[r] + a2 * AAe[r])
        for i in range(2):
            ei = eta[i]
            EiEj = _mcross(ei, ej)
            EiAe = _mcross(ei, Ae)
            AEiEj = _mcross(xi, EiEj)
            ci2 = s4 * g1 * u[i]
            ci3 = s5 * g2 * u[i]
            for r in range(6):
                dS[1 + i, r, 1 + j] = -ci2 * Ae[r] - a2 * EiEj[r] + ci3 * AAe[r] + a3 * (EiAe[r] + AEiEj[r])
    for i in range(2):
        for r in range(6):
            dS[1 + i, r, 0] = alpha * eta[i][r]
    # derivatives of Sd(qdot) qdot
    Ax = _mcross(xi, xd)
    AAx = _mcross(xi, Ax)
    XAx = _mcross(xd, Ax)
    cl_A = -(4.0 * s3 * g1 + s5 * k2 * h1)
    cl_AA = 5.0 * s4 * g2 + s4 * s2 * k2 * h2
    for r in range(6):
        K[0, r] = alpha * (alpha * ld * (-cx * Ax[r] + a1 * AAx[r]) + ud * (cl_A * Ax[r] + cl_AA * AAx[r]) + a2 * XAx[r])
    for i in range(2):
        ei = eta[i]
        Ex = _mcross(ei, xd)
        EAx = _mcross(ei, Ax)
        AEx = _mcross(xi, Ex)
        XEx = _mcross(xd, Ex)
        ui = u[i]
        for r in range(6):
            K[1 + i, r] = (
                alpha * ld * (-s3 * g0 * ui * Ax[r] - a1 * Ex[r] + s4 * g1 * ui * AAx[r] + a2 * (EAx[r] + AEx[r]))
                + udot[i] * (-s4 * g1 * Ax[r] + s5 * g2 * AAx[r])
                + ud * (-s4 * s2 * h1 * ui * Ax[r] - s4 * g1 * Ex[r] + s5 * s2 * h2 * ui * AAx[r]
                        + s5 * g2 * (EAx[r] + AEx[r]))
                + s5 * g2 * ui * XAx[r]
                + a3 * XEx[r]
            )
