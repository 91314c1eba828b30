"""Exact derivatives of the chain's inverse dynamics (numba), in the manner of Carpentier and
Mansard's RNEA derivatives (Pinocchio's ``rnea-derivatives``), extended to the slices of a segment.

Everything is in curvature coordinates ``(l, ux, uy)`` and uses the layout of
:mod:`qchain.algorithms.recursive` (the model's :class:`~qchain.algorithms.arrays.ChainArrays` ``arr``; ``q, qd, qdd`` (n, 3); the first root's
twist ``V0`` and apparent acceleration ``A0 = a_root - (g_root, 0)``).

Per segment (root frame ``j``), one pass over the slices gives the generalised force
``Q_j = int Phi^T (I a + V x* I V)`` of :mod:`qchain.model.slices` and its derivatives at fixed root
twist ``V_j`` and acceleration ``A_j``: ``dQ/dq_j`` (the slices move: ``dV = -S_c x V_r + dS_c
qdot``, ``da = -S_c x A_r + dS_c qddot + K_c - (dS_c qdot) x V_r + (S qdot) x (S_c x V_r)``,
with ``dS`` and ``K`` from :func:`qchain.model.arc.arc_node_derivatives`) and ``dQ/dxi_j`` (``dV = Phi``,
``da = [-(S qdot) x Ad^-1, 2 Sd - S_c x V]``); the tip (slice ``alpha = 1``) gives the same
variations of the next root's twist and acceleration.

The chain then needs no per-column sweep. Backwards from the tip, the subtree beyond root
``j`` has wrench/force sensitivities ``d(F_j, tau_j)/dA_j = Mh_j[:, :6]`` (the composite
block of the mass matrix) and ``W_j = d(F_j, tau_j)/dV_j``. A variation of segment ``m``'s
coordinates moves everything beyond tip ``m`` rigidly; in the first root's frame it is a pair
of twists ``(sigma1, sigma2)`` shared by all that hangs there, so for ``i > m``

    dtau_i = Y_i Ad(X_i)^-1 sigma2 + (W_i - Y_i ad(V_i)) Ad(X_i)^-1 sigma1,   Y_i = Mh_i[6:, :6],

and for ``i < m`` ``dtau_i = J_i^T G_m`` with ``J_i`` the tip Jacobian and ``G_m`` the variation
of the wrench at root ``m`` (first root's frame). The work is O(n * nodes) in the slices and
O(n^2) small products in the assembly. A floating base adds its twist (``sigma1 = I``,
``sigma2 = ad(V0)``) and attitude (gravity turns: ``sigma2 = (e_k x g_B, 0)``) columns and the
rows of its wrench ``F0``.

Arrays named ``...T`` hold derivatives by their first index: ``QqT[c]`` is ``dQ/dq_c``.
``tests/test_derivatives.py`` holds every output to central differences of the model. The
forward-dynamics derivatives built on these passes are :mod:`qchain.algorithms.aba_derivatives`'s.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit, jit_helper, jit_inline, jit_pass
from ..model.arc import arc_node, arc_node_derivatives, take1, take2, take3
from ..model.slices import (
    law_hessian_c, mass_finish, mass_node, phi_matrix, phi_transpose_force, pressure_jacobian_c)
from ..model.spatial_kernels import (ad_force, ad_inv_twist, ad_twist, column6, column_dot6, force_cross, matvec63,
                                     matvec66, motion_cross, put6, vadd, vmul, vsub)
from .arrays import AbaWorkspace, ChainArrays, RneaWorkspace
from .recursive import _load_xi, payload_wrench
from .recursive import _project as recursive_project

__all__ = ["segment_derivatives", "tip_derivatives", "rnea_derivatives", "rnea_workspace",
           "internal_forces_derivatives"]


@jit_helper
def _force_variation(Id, V, hV, dV, da):
    """``I da + dV x* (I V) + V x* (I dV)`` (6-tuple): the slice force's variation
    (``I = diag(Id)``, ``hV = I V``)."""
    return vadd(vadd(force_cross(dV, hV), vmul(Id, da)), force_cross(V, vmul(Id, dV)))


@jit_helper
def _node_state(R, p, S, Sd, V0, A0, qd, qdd):
    """``(Vr, Ar, rel, V, a)`` (6-tuples) at a node whose kinematics ``R, p, S, Sd`` are known:
    ``Vr = Ad^-1 V0``, ``Ar = Ad^-1 A0``, ``rel = S qdot``, the slice twist ``V = Vr + rel`` and
    acceleration ``a = Ar + S qddot + Sd qdot - rel x Vr``."""
    Vr = ad_inv_twist(R, p, V0)
    Ar = ad_inv_twist(R, p, A0)
    rel = matvec63(S, qd)
    a = vsub(vadd(vadd(Ar, matvec63(S, qdd)), matvec63(Sd, qd)), motion_cross(rel, Vr))
    return Vr, Ar, rel, vadd(Vr, rel), a


@jit_helper
def _q_variation(c, S, dS, K, qd, qdd, Vr, Ar, rel):
    """``(dV, da)`` (6-tuples) of a slice for a unit change of ``q_c`` (fixed root twist and
    acceleration): ``dV = dS_c qdot - S_c x Vr``, ``da = rel x (S_c x Vr) + K_c + dS_c qddot -
    (dS_c qdot) x Vr - S_c x Ar``."""
    Sc = column6(S, c)
    dSq = matvec63(dS[c], qd)
    t1 = motion_cross(Sc, Vr)
    da = vadd(vadd(motion_cross(rel, t1), K[c]), matvec63(dS[c], qdd))
    da = vsub(vsub(da, motion_cross(dSq, Vr)), motion_cross(Sc, Ar))
    return vsub(dSq, t1), da


@jit_helper
def _qd_variation(c, S, Sd, V):
    """``(dV, da)`` (6-tuples) of a slice for a unit change of ``qdot_c``: ``S_c`` and
    ``2 Sd_c - S_c x V``."""
    Sc = column6(S, c)
    Sdc = column6(Sd, c)
    return Sc, vsub(vadd(Sdc, Sdc), motion_cross(Sc, V))


@jit
def segment_derivatives(alpha, w, mass, radius, q, xi, xid, M, Q, QqT, QxT, sc):
    """``Q = int Phi^T (I a + V x* I V) dalpha`` (9,) of one segment, ``M = M_xi`` (9, 9) and
    the derivatives of ``Q``, in one pass over the nodes (as :func:`qchain.model.slices.segment_slices`).

    ``QqT[c]`` (3, 9) ``= dQ/dq_c`` at fixed ``xi = (V_root, qdot)`` and ``xid = (A_root,
    qddot)``; ``QxT[k]`` (9, 9) ``= dQ/dxi_k`` at fixed ``xid`` (``dQ/dxid = M_xi``).
    """
    _segment_derivatives(alpha, w, mass, radius, q, xi, xid, M, Q, QqT, QxT, sc)


@jit_helper
def _segment_derivatives(alpha, w, mass, radius, q, xi, xid, M, Q, QqT, QxT, sc, blocks_known=False):
    """:func:`segment_derivatives`, the body the kernels call: compiled into them, without a
    Python entry point (:data:`qchain._jit.jit_helper`). With ``blocks_known``, ``M`` already
    holds ``M_xi`` at this ``q`` and ``Q`` the bias force ``Q(xid = 0)`` at this ``xi`` (the
    articulated-body pass just wrote them): ``M`` is left as it is and ``Q += M xid`` (``Q`` is
    linear in ``xid``), so the nodes' inertia and force sums are not done twice."""
    o = 0
    R, o = take2(sc, o, 3, 3)
    p, o = take1(sc, o, 3)
    S, o = take2(sc, o, 6, 3)
    Sd, o = take2(sc, o, 6, 3)
    dS, o = take3(sc, o, 3, 6, 3)
    K, o = take2(sc, o, 3, 6)
    t1, o = take1(sc, o, 6)
    E, o = take2(sc, o, 6, 6)
    EA, o = take2(sc, o, 6, 6)
    ixx = 0.25 * mass * radius * radius
    Id, o = take1(sc, o, 6)
    Id[:3] = mass
    Id[3] = Id[4] = ixx
    Id[5] = 2.0 * ixx
    V0 = xi[:6]
    qd = xi[6:]
    A0 = xid[:6]
    qdd = xid[6:]
    QqT[:, :] = 0.0
    QxT[:, :] = 0.0
    if blocks_known:
        for r in range(9):
            acc = 0.0
            for k in range(9):
                acc += M[r, k] * xid[k]
            Q[r] += acc
    else:
        M[:, :] = 0.0
        Q[:] = 0.0
    mp, o = take1(sc, o, 3)
    mp[:] = 0.0
    Irot, o = take2(sc, o, 3, 3)
    Irot[:, :] = 0.0
    wsum = 0.0
    for k in range(alpha.shape[0]):
        wk = w[k]
        wsum += wk
        arc_node(alpha[k], q[0], q[1], q[2], qd[0], qd[1], qd[2], R, p, S, Sd)
        arc_node_derivatives(alpha[k], q[0], q[1], q[2], qd[0], qd[1], qd[2], dS, K)
        Vr, Ar, rel, V, a = _node_state(R, p, S, Sd, V0, A0, qd, qdd)
        hV = vmul(Id, V)
        f = vadd(force_cross(V, hV), vmul(Id, a))
        if not blocks_known:
            phi_transpose_force(R, p, S, f, wk, Q)
            mass_node(R, p, S, Id, wk, M, mp, Irot, t1)
        for c in range(3):
            dV, da = _q_variation(c, S, dS, K, qd, qdd, Vr, Ar, rel)
            # d(Phi^T f) = Phi^T df + [Ad^-T (S_c x* f); dS_c^T f]
            Sf = force_cross(column6(S, c), f)
            phi_transpose_force(R, p, S, vadd(_force_variation(Id, V, hV, dV, da), Sf), wk, QqT[c])
            dSc = dS[c]
            for cc in range(3):
                QqT[c, 6 + cc] += wk * (column_dot6(dSc, cc, f) - column_dot6(S, cc, Sf))
        # velocity columns through E = d f / d V_slice at fixed root acceleration:
        # E = (I V) x*bar + (V x*) I - I ad(rel); root twist: df = E Ad^-1; qdot_c: df = E S_c +
        # I (2 Sd_c - S_c x (V + rel))
        _velocity_force_matrix(Id, V, hV, rel, E)
        Vp = vadd(V, rel)
        for c in range(3):
            # S_c, and 2 Sd_c - S_c x (V + rel): the acceleration's change, as _qd_variation's with V + rel
            Sc, da = _qd_variation(c, S, Sd, Vp)
            phi_transpose_force(R, p, S, vadd(vmul(Id, da), matvec66(E, Sc)), wk, QxT[6 + c])
        for r in range(6):  # E Ad^-1, row by row: x^T Ad^-1 = (Ad^-T x)^T
            put6(EA[r], ad_force(R, p, E[r]))
        for kk in range(6):
            phi_transpose_force(R, p, S, column6(EA, kk), wk, QxT[kk])
    if not blocks_known:
        mass_finish(M, mp, Irot, mass * wsum)


@jit_helper
def _velocity_force_matrix(Id, V, hV, rel, E):
    """``E = d f / d V`` (6, 6) of a slice force ``f = I a + V x* I V`` whose acceleration moves
    with its twist as ``da = -rel x dV``: ``[I V] x*bar + [V x*] I - I ad(rel)``."""
    for r in range(6):
        for c in range(6):
            E[r, c] = 0.0
    # [h] x*bar: a -> a x* h = [[0, -[f]], [-[f], -[n]]] a
    f0, f1, f2, n0, n1, n2 = hV[0], hV[1], hV[2], hV[3], hV[4], hV[5]
    _add_skew(E, 0, 3, f0, f1, f2, -1.0)
    _add_skew(E, 3, 0, f0, f1, f2, -1.0)
    _add_skew(E, 3, 3, n0, n1, n2, -1.0)
    # [V x*] I = [[w^, 0], [v^, w^]] diag(Id)
    _add_skew_cols(E, 0, 0, V[3], V[4], V[5], Id, 0)
    _add_skew_cols(E, 3, 3, V[3], V[4], V[5], Id, 3)
    _add_skew_cols(E, 3, 0, V[0], V[1], V[2], Id, 0)
    # - I ad(rel) = - diag(Id) [[wr^, vr^], [0, wr^]]
    _add_skew_rows(E, 0, 0, rel[3], rel[4], rel[5], Id, 0)
    _add_skew_rows(E, 0, 3, rel[0], rel[1], rel[2], Id, 0)
    _add_skew_rows(E, 3, 3, rel[3], rel[4], rel[5], Id, 3)


@jit_helper
def _add_skew(E, r0, c0, x, y, z, scale):
    """``E[r0:r0+3, c0:c0+3] += scale [(x, y, z)]x``."""
    E[r0, c0 + 1] -= scale * z
    E[r0, c0 + 2] += scale * y
    E[r0 + 1, c0] += scale * z
    E[r0 + 1, c0 + 2] -= scale * x
    E[r0 + 2, c0] -= scale * y
    E[r0 + 2, c0 + 1] += scale * x


@jit_helper
def _add_skew_cols(E, r0, c0, x, y, z, Id, i0):
    """``E[r0:r0+3, c0:c0+3] += [(x, y, z)]x diag(Id[i0:i0+3])``."""
    E[r0, c0 + 1] -= z * Id[i0 + 1]
    E[r0, c0 + 2] += y * Id[i0 + 2]
    E[r0 + 1, c0] += z * Id[i0]
    E[r0 + 1, c0 + 2] -= x * Id[i0 + 2]
    E[r0 + 2, c0] -= y * Id[i0]
    E[r0 + 2, c0 + 1] += x * Id[i0 + 1]


@jit_helper
def _add_skew_rows(E, r0, c0, x, y, z, Id, i0):
    """``E[r0:r0+3, c0:c0+3] -= diag(Id[i0:i0+3]) [(x, y, z)]x``."""
    E[r0, c0 + 1] += z * Id[i0]
    E[r0, c0 + 2] -= y * Id[i0]
    E[r0 + 1, c0] -= z * Id[i0 + 1]
    E[r0 + 1, c0 + 2] += x * Id[i0 + 1]
    E[r0 + 2, c0] += y * Id[i0 + 2]
    E[r0 + 2, c0 + 1] -= x * Id[i0 + 2]


@jit
def tip_derivatives(q, qd, qdd, V0, A0, T, R1, p1, V1, A1, rel1, tipV, tipA, dS1, sc):
    """The tip (slice ``alpha = 1``) of one segment and its variations.

    Outputs: tip map ``T = Phi(1)`` (6, 9); tip placement ``R1`` (3, 3), ``p1`` (3,) in the
    root frame; the next root's twist ``V1`` and acceleration ``A1`` (6,); ``rel1 = S(1) qdot``;
    ``tipV[k], tipA[k]`` (6, 6): their variations for ``k < 3`` a unit ``q_k``, ``k >= 3`` a unit
    ``qdot_(k-3)`` (fixed root twist and acceleration); ``dS1`` (3, 6, 3) ``= dS(1)/dq``.
    """
    _tip_derivatives(q, qd, qdd, V0, A0, T, R1, p1, V1, A1, rel1, tipV, tipA, dS1, sc)


@jit_helper
def _tip_derivatives(q, qd, qdd, V0, A0, T, R1, p1, V1, A1, rel1, tipV, tipA, dS1, sc):
    """:func:`tip_derivatives`, the body the kernels call: compiled into them, without a
    Python entry point (:data:`qchain._jit.jit_helper`)."""
    o = 0
    S, o = take2(sc, o, 6, 3)
    Sd, o = take2(sc, o, 6, 3)
    K, o = take2(sc, o, 3, 6)
    arc_node(1.0, q[0], q[1], q[2], qd[0], qd[1], qd[2], R1, p1, S, Sd)
    arc_node_derivatives(1.0, q[0], q[1], q[2], qd[0], qd[1], qd[2], dS1, K)
    phi_matrix(R1, p1, S, T)
    Vr, Ar, rel, V, a = _node_state(R1, p1, S, Sd, V0, A0, qd, qdd)
    put6(rel1, rel)
    put6(V1, V)
    put6(A1, a)
    for c in range(3):
        dV, da = _q_variation(c, S, dS1, K, qd, qdd, Vr, Ar, rel)
        put6(tipV[c], dV)
        put6(tipA[c], da)
        dV, da = _qd_variation(c, S, Sd, V)
        put6(tipV[3 + c], dV)
        put6(tipA[3 + c], da)


#: Names of :func:`rnea_workspace`'s arrays (``Data`` attributes), in order.
RNEA_WORKSPACE = RneaWorkspace._fields


@jit
def rnea_workspace(n, nv):
    """Fresh arrays for :func:`rnea_derivatives` (shapes in :mod:`qchain.arm.data`), then its
    outputs ``tau_c`` (n, 3), ``F0`` (6,), ``M``, ``dtau_dq``, ``dtau_dv`` (nv, nv)."""
    return RneaWorkspace(np.zeros((n + 1, 6)), np.zeros((n + 1, 3, 3)), np.zeros((n + 1, 3)), np.zeros((n, 3, 9)),
                         np.zeros((n, 9, 9)), np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros((n, 6, 6)),
                         np.zeros((n, 3, 6, 3)), np.zeros((n, 6, 6)), np.zeros((n, 3, 6)), np.zeros((n, 3, 6)),
                         np.zeros((n, 3, 6)), np.zeros((n, 3, 6)), np.zeros((n, 6, 6)), np.zeros((n, 6, 6)),
                         np.zeros((n, 3)), np.zeros(6), np.zeros((nv, nv)), np.zeros((nv, nv)), np.zeros((nv, nv)))


@jit_pass
def rnea_derivatives(arr, q, qd, qdd, V0, A0, floating, g_B, ws, wd, sc):
    """Inverse dynamics and its exact derivatives, curvature coordinates.

    ``arr`` is the model's :class:`~qchain.algorithms.arrays.ChainArrays`,
    ``ws`` :meth:`qchain.arm.data.Data.aba_workspace`, ``wd`` :meth:`~qchain.arm.data.Data.rnea_workspace`,
    ``sc`` scratch (:data:`qchain.model.arc.SCRATCH`).
    Writes its ``tau_c`` (n, 3) and ``F0`` (6,) as :func:`qchain.algorithms.recursive.rnea` does,
    ``dtau_dq`` and ``dtau_dv`` (nv, nv): ``d(F0, tau)/d(q, v)`` (rows: the base wrench for a
    floating base, then the segments; columns: the base's tangent ``(translation, rotation)``
    / twist, then the segments), and ``M`` (nv, nv) ``= d(F0, tau)/da``. ``g_B`` (3,) is gravity
    in the first root's frame (it turns with a floating base).
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = AbaWorkspace(*ws)
    wd = RneaWorkspace(*wd)
    _rnea_derivatives(arr, q, qd, qdd, V0, A0, floating, g_B, ws, wd, sc)


@jit_helper
def _rnea_derivatives(arr, q, qd, qdd, V0, A0, floating, g_B, ws, wd, sc, blocks_known=False):
    """:func:`rnea_derivatives`, the body the kernels call: compiled into them, without a
    Python entry point (:data:`qchain._jit.jit_helper`). ``blocks_known``: ``ws.M_xi`` and
    ``ws.Q`` already hold every segment's ``M_xi`` and bias force ``Q(xid = 0)`` at ``(q, qd, V0)``
    (:func:`qchain.algorithms.recursive.aba` at this state wrote them). Its passes, :func:`_forward_pass`,
    :func:`_backward_pass`, :func:`_assemble` and, for a floating base, :func:`_floating_base`,
    are inlined into it (:data:`qchain._jit.jit_inline`): the same code as one function."""
    alpha, w, offs, mass, radius = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius
    n = q.shape[0]
    off = 6 if floating else 0
    V, T, Q, Mxi = ws.V, ws.T, ws.Q, ws.M_xi
    A, Rw, pw, QqT, QxT, rel1, tipV, tipA = wd.A, wd.R_0j, wd.p_0j, wd.QqT, wd.QxT, wd.rel1, wd.tipV, wd.tipA
    dS1, G, Ya, Yv, Ms, Jw, sig1, sig2 = wd.dS1, wd.G, wd.Ya, wd.Yv, wd.Ms, wd.Jw, wd.sig1, wd.sig2
    tau, F0, M, dq, dv = wd.tau_c, wd.F0, wd.M, wd.dtau_dq, wd.dtau_dv
    o = 0
    R1, o = take2(sc, o, 3, 3)
    p1, o = take1(sc, o, 3)
    xi, o = take1(sc, o, 9)
    xid, o = take1(sc, o, 9)
    _forward_pass(alpha, w, offs, mass, radius, q, qd, qdd, V0, A0, V, T, Q, Mxi, A, Rw, pw, QqT, QxT, rel1, tipV,
                  tipA, dS1, R1, p1, xi, xid, sc[o:], blocks_known)
    # the subtree beyond the current root: its wrench F, composite inertia Ic, W = dF/dV;
    # beyond the tip, the payload (zeros without one)
    F, o = take1(sc, o, 6)
    Ic, o = take2(sc, o, 6, 6)
    WF, o = take2(sc, o, 6, 6)
    _payload_blocks(arr.payload, V[n], A[n], F, Ic, WF, sc[o:])
    dq[:, :] = 0.0
    dv[:, :] = 0.0
    M[:, :] = 0.0
    _backward_pass(n, off, V, T, Q, Mxi, Rw, pw, QqT, QxT, rel1, tipV, tipA, dS1, G, Ya, Yv, Ms, Jw, sig1, sig2, tau,
                   M, dq, dv, F, Ic, WF, sc[o:])
    for r in range(6):
        F0[r] = F[r]
    _assemble(n, off, G, Ya, Yv, Ms, Jw, sig1, sig2, M, dq, dv)
    if floating:
        _floating_base(n, off, V0, g_B, G, Ya, Yv, Ms, M, dq, dv, Ic, WF, sc[o:])


@jit_helper
def _payload_blocks(P, V, A, F, Ic, WF, sc):
    """The payload (spatial inertia ``P`` (6, 6)) at the tip twist ``V`` and apparent
    acceleration ``A`` (6,): its wrench ``F = P A + V x* (P V)``, ``Ic = P = dF/dA`` and
    ``WF = dF/dV = (. x* P V) + V x* P .`` column by column (6, 6); ``sc`` scratch."""
    o = 0
    h, o = take1(sc, o, 6)
    e, o = take1(sc, o, 6)
    t1, o = take1(sc, o, 6)
    t2, o = take1(sc, o, 6)
    payload_wrench(P, V, A, h, F)
    for s in range(6):
        for r in range(6):
            Ic[r, s] = P[r, s]
            e[r] = P[r, s]
        put6(t1, force_cross(V, e))  # V x* (P e_s)
        e[:] = 0.0
        e[s] = 1.0
        put6(t2, force_cross(e, h))  # e_s x* (P V)
        for r in range(6):
            WF[r, s] = t1[r] + t2[r]


@jit_inline
def _forward_pass(alpha, w, offs, mass, radius, q, qd, qdd, V0, A0, V, T, Q, Mxi, A, Rw, pw, QqT, QxT, rel1, tipV,
                  tipA, dS1, R1, p1, xi, xid, sc, blocks_known):
    """Root to tip: every segment's ``Q``, ``M_xi`` and their derivatives
    (:func:`segment_derivatives`), its tip and the tip's variations (:func:`tip_derivatives`),
    the roots' twists ``V``, accelerations ``A`` and placements ``Rw, pw`` in the first root's
    frame. ``R1`` (3, 3), ``p1`` (3,), ``xi``, ``xid`` (9,) and ``sc`` are scratch."""
    for r in range(6):
        V[0, r] = V0[r]
        A[0, r] = A0[r]
    for r in range(3):
        for s in range(3):
            Rw[0, r, s] = 1.0 if r == s else 0.0
    pw[0] = 0.0
    for j in range(q.shape[0]):
        _load_xi(xi, V[j], qd[j])
        _load_xi(xid, A[j], qdd[j])
        a0, a1 = offs[j], offs[j + 1]
        _segment_derivatives(alpha[a0:a1], w[a0:a1], mass[j], radius[j], q[j], xi, xid, Mxi[j], Q[j], QqT[j], QxT[j],
                             sc, blocks_known)
        _tip_derivatives(q[j], qd[j], qdd[j], V[j], A[j], T[j], R1, p1, V[j + 1], A[j + 1], rel1[j], tipV[j],
                         tipA[j], dS1[j], sc)
        for r in range(3):
            acc = pw[j, r]
            for s in range(3):
                acc += Rw[j, r, s] * p1[s]
                Rw[j + 1, r, s] = Rw[j, r, 0] * R1[0, s] + Rw[j, r, 1] * R1[1, s] + Rw[j, r, 2] * R1[2, s]
            pw[j + 1, r] = acc


@jit_inline
def _backward_pass(n, off, V, T, Q, Mxi, Rw, pw, QqT, QxT, rel1, tipV, tipA, dS1, G, Ya, Yv, Ms, Jw, sig1, sig2, tau,
                   M, dq, dv, F, Ic, WF, sc):
    """Tip to root: the inverse dynamics ``tau`` and, per segment ``j``, its own blocks of
    ``dq``, ``dv``, ``M`` and what the assembly needs, in the first root's frame: ``G[m, col]``
    the wrench variation at root ``m``; ``Ya``, ``Yv`` the subtree sensitivities; ``Ms[j, b]``
    the wrench at root ``j`` per unit ``qdd_j,b``; ``Jw[i, b]`` the twist of tip ``i`` per unit
    ``qd_i,b``; ``sig1``, ``sig2`` the twists a variation of segment ``j`` moves its subtree by.
    ``F``, ``Ic``, ``WF`` come in zero and leave as the whole chain's (the base's) wrench,
    composite inertia and ``dF/dV``; ``sc`` is scratch."""
    o = 0
    Mh, o = take2(sc, o, 9, 9)
    Wj, o = take2(sc, o, 9, 6)
    ET, o = take2(sc, o, 6, 6)
    IcT, o = take2(sc, o, 6, 9)
    D, o = take2(sc, o, 6, 9)  # D[col] = d(F_j, tau_j)/d col, cols q_j then qd_j
    dF, o = take1(sc, o, 6)
    t1, o = take1(sc, o, 6)
    t2, o = take1(sc, o, 6)
    vW, o = take1(sc, o, 6)
    TF, o = take1(sc, o, 9)
    for j in range(n - 1, -1, -1):
        Tj = T[j]
        i0 = off + 3 * j
        # inverse dynamics: (F_j, tau_j) = Q_j + T^T F_{j+1}
        for k in range(9):
            acc = 0.0
            for r in range(6):
                acc += Tj[r, k] * F[r]
            TF[k] = acc
        _subtree_blocks(Tj, Mxi[j], QxT[j], rel1[j], Ic, WF, ET, IcT, Mh, Wj)
        _segment_columns(Tj, QqT[j], QxT[j], dS1[j], tipV[j], tipA[j], F, Ic, WF, D, dF, t1, t2)
        for col in range(6):
            for b in range(3):
                if col < 3:
                    dq[i0 + b, i0 + col] = D[col, 6 + b]
                else:
                    dv[i0 + b, i0 + col - 3] = D[col, 6 + b]
            put6(G[j, col], ad_force(Rw[j], pw[j], D[col, :6]))
        # world-frame rows of the subtree sensitivities and the composite columns of M
        for b in range(3):
            for r in range(6):
                t1[r] = Mh[6 + b, r]
            put6(Ya[j, b], ad_force(Rw[j], pw[j], t1))
            put6(t2, force_cross(V[j], t1))
            for r in range(6):
                t2[r] += Wj[6 + b, r]
            put6(Yv[j, b], ad_force(Rw[j], pw[j], t2))
            for r in range(6):
                t1[r] = Mh[r, 6 + b]
            put6(Ms[j, b], ad_force(Rw[j], pw[j], t1))
            for a in range(3):
                M[i0 + a, i0 + b] = Mh[6 + a, 6 + b]
            for r in range(6):
                t2[r] = Tj[r, 6 + b]
            put6(Jw[j, b], ad_twist(Rw[j + 1], pw[j + 1], t2))
        put6(vW, ad_twist(Rw[j + 1], pw[j + 1], V[j + 1]))
        for col in range(6):
            put6(sig1[j, col], ad_twist(Rw[j + 1], pw[j + 1], tipV[j, col]))
            put6(sig2[j, col], ad_twist(Rw[j + 1], pw[j + 1], tipA[j, col]))
            put6(t1, motion_cross(sig1[j, col], vW))
            for r in range(6):
                sig2[j, col, r] -= t1[r]
        # move one root inwards
        for r in range(6):
            F[r] = Q[j, r] + TF[r]
            for s in range(6):
                Ic[r, s] = Mh[r, s]
                WF[r, s] = Wj[r, s]
        for b in range(3):
            tau[j, b] = Q[j, 6 + b] + TF[6 + b]


@jit_inline
def _subtree_blocks(Tj, Mxi, QxT, rel1, Ic, WF, ET, IcT, Mh, Wj):
    """Composite inertia ``Mh = M_xi + T^T Ic T`` (9, 9) and ``Wj = dQ/dV + T^T (WF - Ic
    ad(rel1)) T_V`` (9, 6) of the subtree from root ``j`` on, from its segment's ``T``, ``M_xi``,
    ``QxT`` and tip ``rel1`` and the subtree beyond's ``Ic``, ``WF``; ``ET`` (6, 6) and ``IcT``
    (6, 9) scratch."""
    # row r of E = WF - Ic ad(rel1) is WF[r] + rel1 x* Ic[r] (x* = -ad^T); then E T_V, whose
    # factor T_V = Ad^-1 has a zero lower left block (the sums leave out exact zeros)
    for r in range(6):
        e = vadd(WF[r], force_cross(rel1, Ic[r]))
        for s in range(3):
            ET[r, s] = e[0] * Tj[0, s] + e[1] * Tj[1, s] + e[2] * Tj[2, s]
        for s in range(3, 6):
            ET[r, s] = (e[0] * Tj[0, s] + e[1] * Tj[1, s] + e[2] * Tj[2, s] + e[3] * Tj[3, s] + e[4] * Tj[4, s]
                        + e[5] * Tj[5, s])
    recursive_project(Mxi, Tj, Ic, IcT, Mh)
    for a in range(9):
        for b in range(6):
            acc = QxT[b, a]
            for r in range(3 if a < 3 else 6):
                acc += Tj[r, a] * ET[r, b]
            Wj[a, b] = acc


@jit_inline
def _segment_columns(Tj, QqT, QxT, dS1, tipV, tipA, F, Ic, WF, D, dF, t1, t2):
    """``D[col]`` (9,) ``= d(F_j, tau_j)/d col`` for this segment's own coordinates (``col < 3``
    ``q_col``, else ``qd_(col-3)``): intrinsic + ``T^T (WF dV1 + Ic dA1)`` (+ ``dT^T F`` for
    ``q``), with ``F``, ``Ic``, ``WF`` the subtree beyond its tip's; ``dF``, ``t1``, ``t2`` scratch."""
    for col in range(6):
        if col < 3:
            for k in range(9):
                D[col, k] = QqT[col, k]
            for r in range(6):
                t2[r] = Tj[r, 6 + col]
            put6(t1, force_cross(t2, F))  # S1_c x* F
            for r in range(6):
                acc = 0.0
                for k in range(6):
                    acc += Tj[k, r] * t1[k]
                D[col, r] += acc
            for b in range(3):
                acc = 0.0
                for r in range(6):
                    acc += dS1[col, r, b] * F[r]
                D[col, 6 + b] += acc
        else:
            for k in range(9):
                D[col, k] = QxT[6 + col - 3, k]
        for r in range(6):
            acc = 0.0
            for k in range(6):
                acc += WF[r, k] * tipV[col, k] + Ic[r, k] * tipA[col, k]
            dF[r] = acc
        for k in range(9):
            acc = 0.0
            for r in range(6):
                acc += Tj[r, k] * dF[r]
            D[col, k] += acc


@jit_inline
def _assemble(n, off, G, Ya, Yv, Ms, Jw, sig1, sig2, M, dq, dv):
    """The blocks between segments, O(n^2) small products: for ``i > m`` a variation of segment
    ``m`` moves segment ``i`` rigidly (``dtau_i = Ya_i sig2_m + Yv_i sig1_m``), for ``i < m`` it
    changes the wrench at root ``m`` (``dtau_i = J_i^T G_m``); ``M``'s off-diagonal blocks
    ``J_i^T Ms_m``."""
    for i in range(n):
        ri = off + 3 * i
        for m in range(i):  # m < i: segment i moves rigidly
            cm = off + 3 * m
            for b in range(3):
                for col in range(3):
                    accq = 0.0
                    accv = 0.0
                    for r in range(6):
                        accq += Ya[i, b, r] * sig2[m, col, r] + Yv[i, b, r] * sig1[m, col, r]
                        accv += Ya[i, b, r] * sig2[m, 3 + col, r] + Yv[i, b, r] * sig1[m, 3 + col, r]
                    dq[ri + b, cm + col] = accq
                    dv[ri + b, cm + col] = accv
        for m in range(i + 1, n):  # m > i: the wrench at root m changes
            cm = off + 3 * m
            for b in range(3):
                for col in range(3):
                    accq = 0.0
                    accv = 0.0
                    for r in range(6):
                        accq += Jw[i, b, r] * G[m, col, r]
                        accv += Jw[i, b, r] * G[m, 3 + col, r]
                    dq[ri + b, cm + col] = accq
                    dv[ri + b, cm + col] = accv
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for r in range(6):
                        acc += Jw[i, a, r] * Ms[m, b, r]
                    M[ri + a, cm + b] = acc
                    M[cm + b, ri + a] = acc


@jit_inline
def _floating_base(n, off, V0, g_B, G, Ya, Yv, Ms, M, dq, dv, Ic, WF, sc):
    """A floating base's rows (its wrench ``F0``) and columns (twist ``sigma1 = I``,
    ``sigma2 = ad(V0)``; attitude: gravity in the base frame turns, ``sigma2 = (e_k x g_B, 0)``),
    with ``Ic``, ``WF`` the whole chain's composite inertia and ``dF/dV``; ``sc`` scratch."""
    o = 0
    t1, o = take1(sc, o, 6)
    t2, o = take1(sc, o, 6)
    sg, o = take2(sc, o, 3, 6)
    for m in range(n):
        cm = off + 3 * m
        for col in range(6):
            for r in range(6):
                if col < 3:
                    dq[r, cm + col] = G[m, col, r]
                else:
                    dv[r, cm + col - 3] = G[m, col, r]
        for b in range(3):
            for r in range(6):
                M[r, cm + b] = Ms[m, b, r]
                M[cm + b, r] = Ms[m, b, r]
    for r in range(6):
        for s in range(6):
            M[r, s] = Ic[r, s]
            dv[r, s] = WF[r, s]
    # attitude: gravity in the base frame turns, dA0 = (e_k x g_B, 0)
    for k in range(3):
        t1[:] = 0.0
        t1[k] = 1.0
        sg[k, :] = 0.0
        sg[k, 0] = t1[1] * g_B[2] - t1[2] * g_B[1]
        sg[k, 1] = t1[2] * g_B[0] - t1[0] * g_B[2]
        sg[k, 2] = t1[0] * g_B[1] - t1[1] * g_B[0]
        for r in range(6):
            acc = 0.0
            for s in range(3):
                acc += Ic[r, s] * sg[k, s]
            dq[r, 3 + k] = acc
    for i in range(n):
        ri = off + 3 * i
        for b in range(3):
            put6(t2, force_cross(V0, Ya[i, b]))  # twist columns: Ya ad(V0) + Yv
            for k in range(6):
                dv[ri + b, k] = Yv[i, b, k] - t2[k]
            for k in range(3):
                acc = 0.0
                for s in range(3):
                    acc += Ya[i, b, s] * sg[k, s]
                dq[ri + b, 3 + k] = acc


@jit_pass
def internal_forces_derivatives(arr, q, p, dfq, dfv, sc):
    """Derivatives of the internal forces ``f = B p - D qd - dU_el/dq`` of
    :func:`qchain.algorithms.recursive.internal_forces` (curvature coordinates):
    ``dfq[j] = d(B p)/dq - d^2 U_el/dq^2`` and ``dfv[j] = -D`` (n, 3, 3); ``arr`` the model's
    :class:`~qchain.algorithms.arrays.ChainArrays`."""
    _internal_forces_derivatives(ChainArrays(*arr), q, p, dfq, dfv, sc)  # a plain tuple from Python, named here


@jit_helper
def _internal_forces_derivatives(arr, q, p, dfq, dfv, sc):
    """:func:`internal_forces_derivatives`, the body the kernels call: compiled into them, without a
    Python entry point (:data:`qchain._jit.jit_helper`)."""
    o = 0
    Kp, o = take2(sc, o, 3, 3)
    H, o = take2(sc, o, 3, 3)
    for j in range(q.shape[0]):
        pressure_jacobian_c(q[j], p[j], arr.A_ch[j], arr.r_ch[j], arr.paper_act[j], Kp, sc[o:])
        law_hessian_c(q[j], arr.l0[j], arr.EI[j], arr.EA[j], arr.linear_law[j], arr.K[j], H)
        D = arr.D[j]
        for a in range(3):
            for b in range(3):
                dfq[j, a, b] = Kp[a, b] - H[a, b]
                dfv[j, a, b] = -D[a, b]
