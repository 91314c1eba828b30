"""Exact derivatives of the chain's inverse dynamics (numba), in the manner of Carpentier and
Mansard's RNEA derivatives (Pinocchio's ``rnea-derivatives``), extended to the slices of a segment.

Everything is in curvature coordinates ``(l, ux, uy)`` and uses the layout of
:mod:`qchain.algorithms.recursive` (the model's :class:`~qchain.algorithms.arrays.ChainArrays` ``arr``; ``q, qd, qdd`` (n, 3); the first root's
twist ``V0`` and apparent acceleration ``A0 = a_root - (g_root, 0)``).

Per segment (root frame ``j``): the generalised force ``Q_j = int Phi^T (I a + V x* I V)`` of
:mod:`qchain.model.slices` and ``M_xi`` (from the articulated-body pass when it has just
computed them), then the derivatives of every ``Q_j`` at fixed root twist ``V_j`` and
acceleration ``A_j``, ``dQ/dq_j`` and ``dQ/dxi_j``, all nodes of the chain at once
(:mod:`qchain.algorithms.slice_derivatives`, once the roots' twists and accelerations are
known); the tip (slice ``alpha = 1``) gives the variations of the next root's twist and
acceleration with the same slice variations.

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

from .._blas import gemm
from .._jit import jit, jit_helper, jit_inline, jit_pass
from ..model.arc import _put_columns, _put_rows, bend_values, slice_kinematics, take1, take2
from ..model.slices import _segment_slices, law_hessian_c, phi_matrix, pressure_jacobian_c
from ..model.spatial_kernels import ad_force, ad_twist, force_cross, motion_cross, put6, vadd, vsub
from .slice_derivatives import node_state, q_variation, qd_variation, segment_columns
from .arrays import AbaWorkspace, ChainArrays, RneaWorkspace
from .recursive import _load_xi, payload_wrench
from .recursive import _project as recursive_project

__all__ = ["segment_derivatives", "tip_derivatives", "rnea_derivatives", "rnea_workspace",
           "internal_forces_derivatives"]


@jit
def segment_derivatives(alpha, w, mass, radius, q, xi, xid, M, Q, QqT, QxT, sc):
    """``Q = int Phi^T (I a + V x* I V) dalpha`` (9,) of one segment, ``M = M_xi`` (9, 9) and
    the derivatives of ``Q`` (:mod:`qchain.algorithms.slice_derivatives`): ``QqT[c]`` (3, 9)
    ``= dQ/dq_c`` at fixed ``xi = (V_root, qdot)`` and ``xid = (A_root, qddot)``; ``QxT[k]``
    (9, 9) ``= dQ/dxi_k`` at fixed ``xid`` (``dQ/dxid = M_xi``). ``sc``: scratch of
    :data:`qchain.model.arc.SCRATCH` floats.
    """
    _segment_slices(alpha, w, mass, radius, q, xi, xid, True, M, Q, sc)
    segment_columns(alpha, w, np.array([0, alpha.shape[0]]), np.array([mass]), np.array([radius]), q.reshape((1, 3)),
                    xi[6:].reshape((1, 3)), xid[6:].reshape((1, 3)), xi[:6].reshape((1, 6)), xid[:6].reshape((1, 6)),
                    M.reshape((1, 9, 9)), QqT.reshape((1, 3, 9)), QxT.reshape((1, 9, 9)), sc)


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
    S_, o = take2(sc, 0, 6, 3)
    R, p, S, Sd, dS, K = slice_kinematics(1.0, q[0], q[1], q[2], qd[0], qd[1], qd[2], bend_values(1.0, q[0], q[1], q[2]))
    _put_rows(R1, p1, R, p)
    _put_columns(S_, S)
    _put_columns(dS1[0], dS[0])
    _put_columns(dS1[1], dS[1])
    _put_columns(dS1[2], dS[2])
    phi_matrix(R1, p1, S_, T)
    Vr, Ar, rel, V, a = node_state(R, p, S, Sd, V0, A0, qd, qdd)
    put6(rel1, rel)
    put6(V1, V)
    put6(A1, a)
    # literal indices: a tuple indexed by a loop variable is copied to memory first
    dV, da = q_variation(S[0], dS[0], K[0], qd, qdd, Vr, Ar, rel)
    put6(tipV[0], dV)
    put6(tipA[0], da)
    dV, da = q_variation(S[1], dS[1], K[1], qd, qdd, Vr, Ar, rel)
    put6(tipV[1], dV)
    put6(tipA[1], da)
    dV, da = q_variation(S[2], dS[2], K[2], qd, qdd, Vr, Ar, rel)
    put6(tipV[2], dV)
    put6(tipA[2], da)
    dV, da = qd_variation(S[0], Sd[0], V)
    put6(tipV[3], dV)
    put6(tipA[3], da)
    dV, da = qd_variation(S[1], Sd[1], V)
    put6(tipV[4], dV)
    put6(tipA[4], da)
    dV, da = qd_variation(S[2], Sd[2], V)
    put6(tipV[5], dV)
    put6(tipA[5], da)


#: Names of :func:`rnea_workspace`'s arrays (``Data`` attributes), in order.
RNEA_WORKSPACE = RneaWorkspace._fields


@jit
def rnea_workspace(n, nv):
    """Fresh arrays for :func:`rnea_derivatives` (shapes in :mod:`qchain.arm.data`), then its
    outputs ``tau_c`` (n, 3), ``F0`` (6,), ``M``, ``dtau_dq``, ``dtau_dv`` (nv, nv)."""
    return RneaWorkspace(np.zeros((n + 1, 6)), np.zeros((n + 1, 3, 3)), np.zeros((n + 1, 3)), np.zeros((n, 3, 9)),
                         np.zeros((n, 9, 9)), np.zeros((n, 6)), np.zeros((n, 6, 6)), np.zeros((n, 6, 6)),
                         np.zeros((n, 3, 6, 3)), np.zeros((6, 9 * n)), np.zeros((3 * n, 12)), np.zeros((3 * n, 6)),
                         np.zeros((12, 6 * n)), np.zeros((3 * n, 6 * n)), np.zeros((3 * n, 9 * n)),
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
    dS1, G, Y, Jw, S, P1, P2 = wd.dS1, wd.G, wd.Y, wd.Jw, wd.S, wd.P1, wd.P2
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
    _backward_pass(n, off, V, T, Q, Mxi, Rw, pw, QqT, QxT, rel1, tipV, tipA, dS1, G, Y, Jw, S, tau, M, dq, dv, F, Ic,
                   WF, sc[o:])
    for r in range(6):
        F0[r] = F[r]
    _assemble(n, off, G, Y, Jw, S, P1, P2, M, dq, dv)
    if floating:
        _floating_base(n, off, V0, g_B, G, Y, M, dq, dv, Ic, WF, sc[o:])


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
    """Root to tip: every segment's ``Q`` and ``M_xi`` (with ``blocks_known`` only ``Q +=
    M_xi xid``), its tip and the tip's variations (:func:`tip_derivatives`), the roots' twists
    ``V``, accelerations ``A`` and placements ``Rw, pw`` in the first root's frame; then every
    node at once, the derivatives of every ``Q``
    (:func:`qchain.algorithms.slice_derivatives.segment_columns`). ``R1`` (3, 3), ``p1`` (3,),
    ``xi``, ``xid`` (9,) and ``sc`` are scratch."""
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
        if blocks_known:  # Q is linear in xid
            for r in range(9):
                acc = 0.0
                for k in range(9):
                    acc += Mxi[j, r, k] * xid[k]
                Q[j, r] += acc
        else:
            a0, a1 = offs[j], offs[j + 1]
            _segment_slices(alpha[a0:a1], w[a0:a1], mass[j], radius[j], q[j], xi, xid, True, Mxi[j], Q[j], sc)
        _tip_derivatives(q[j], qd[j], qdd[j], V[j], A[j], T[j], R1, p1, V[j + 1], A[j + 1], rel1[j], tipV[j],
                         tipA[j], dS1[j], sc)
        for r in range(3):
            acc = pw[j, r]
            for s in range(3):
                acc += Rw[j, r, s] * p1[s]
                Rw[j + 1, r, s] = Rw[j, r, 0] * R1[0, s] + Rw[j, r, 1] * R1[1, s] + Rw[j, r, 2] * R1[2, s]
            pw[j + 1, r] = acc
    segment_columns(alpha, w, offs, mass, radius, q, qd, qdd, V, A, Mxi, QqT, QxT, sc)


@jit_inline
def _backward_pass(n, off, V, T, Q, Mxi, Rw, pw, QqT, QxT, rel1, tipV, tipA, dS1, G, Y, Jw, S, tau, M, dq, dv, F, Ic,
                   WF, sc):
    """Tip to root: the inverse dynamics ``tau`` and, per segment ``j``, its own blocks of
    ``dq``, ``dv``, ``M`` and what the assembly needs, in the first root's frame (the tables
    :func:`_assemble` multiplies): ``G`` (6, 9n), column ``3j + b`` of block ``h`` (``3n h + 3j
    + b``) the wrench variation at root ``j`` per unit ``q_j,b`` (``h = 0``), ``qd_j,b`` (1),
    ``qdd_j,b`` (2, the composite columns of ``M``); ``Y`` (3n, 12), row ``3j + b`` the
    subtree sensitivities ``(Ya, Yv)``; ``Jw`` (3n, 6) the twist of tip ``j`` per unit
    ``qd_j,b``; ``S`` (12, 6n), column ``3n h + 3j + b`` the twists ``(sigma2, sigma1)`` a
    variation of segment ``j`` moves its subtree by.
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
            _put_column6(G, 0, 3 * n * (col // 3) + 3 * j + col % 3, ad_force(Rw[j], pw[j], D[col, :6]))
        # world-frame rows of the subtree sensitivities and the composite columns of M
        for b in range(3):
            for r in range(6):
                t1[r] = Mh[6 + b, r]
            put6(Y[3 * j + b], ad_force(Rw[j], pw[j], t1))
            put6(t2, force_cross(V[j], t1))
            for r in range(6):
                t2[r] += Wj[6 + b, r]
            put6(Y[3 * j + b, 6:], ad_force(Rw[j], pw[j], t2))
            for r in range(6):
                t1[r] = Mh[r, 6 + b]
            _put_column6(G, 0, 6 * n + 3 * j + b, ad_force(Rw[j], pw[j], t1))
            for a in range(3):
                M[i0 + a, i0 + b] = Mh[6 + a, 6 + b]
            for r in range(6):
                t2[r] = Tj[r, 6 + b]
            put6(Jw[3 * j + b], ad_twist(Rw[j + 1], pw[j + 1], t2))
        put6(vW, ad_twist(Rw[j + 1], pw[j + 1], V[j + 1]))
        for col in range(6):
            c = 3 * n * (col // 3) + 3 * j + col % 3
            s1 = ad_twist(Rw[j + 1], pw[j + 1], tipV[j, col])
            _put_column6(S, 6, c, s1)
            _put_column6(S, 0, c, vsub(ad_twist(Rw[j + 1], pw[j + 1], tipA[j, col]), motion_cross(s1, vW)))
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


@jit_helper
def _put_column6(X, r0, c, t):
    """``X[r0:r0 + 6, c] = t`` of a matrix and a 6-tuple: a column of the tables
    :func:`_assemble` multiplies."""
    X[r0, c] = t[0]
    X[r0 + 1, c] = t[1]
    X[r0 + 2, c] = t[2]
    X[r0 + 3, c] = t[3]
    X[r0 + 4, c] = t[4]
    X[r0 + 5, c] = t[5]


@jit_inline
def _assemble(n, off, G, Y, Jw, S, P1, P2, M, dq, dv):
    """The blocks between segments: for ``i > m`` a variation of segment ``m`` moves segment
    ``i`` rigidly (``dtau_i = Ya_i sig2_m + Yv_i sig1_m``), for ``i < m`` it changes the wrench
    at root ``m`` (``dtau_i = J_i^T G_m``); ``M``'s off-diagonal blocks ``J_i^T Ms_m``. Two
    matrix products by BLAS (:func:`qchain._blas.gemm`) give every pair ``(i, m)``:
    ``P1 = Y S`` (3n, 6n) and ``P2 = Jw G`` (3n, 9n), of which each output takes its blocks
    below (``P1``) or above (``P2``) the diagonal. The products do twice the work the blocks
    need and still cost less than the 6- and 12-long sums written out, which the compiler
    vectorised poorly over rows of 3 i columns."""
    gemm(Y, S, P1)
    gemm(Jw, G, P2)
    k = 3 * n
    for i in range(n):
        for b in range(3):
            row = 3 * i + b
            ri = off + row
            for c in range(3 * i):  # m < i: segment i moves rigidly
                dq[ri, off + c] = P1[row, c]
            for c in range(3 * i):
                dv[ri, off + c] = P1[row, k + c]
            for c in range(3 * i + 3, k):  # m > i: the wrench at root m changes
                dq[ri, off + c] = P2[row, c]
            for c in range(3 * i + 3, k):
                dv[ri, off + c] = P2[row, k + c]
            for c in range(3 * i + 3, k):
                M[ri, off + c] = P2[row, 2 * k + c]
    for r in range(off, off + k):  # M is symmetric
        for c in range(r - (r - off) % 3 + 3, off + k):
            M[c, r] = M[r, c]


@jit_inline
def _floating_base(n, off, V0, g_B, G, Y, M, dq, dv, Ic, WF, sc):
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
                    dq[r, cm + col] = G[r, 3 * m + col]
                else:
                    dv[r, cm + col - 3] = G[r, 3 * n + 3 * m + col - 3]
        for b in range(3):
            for r in range(6):
                M[r, cm + b] = G[r, 6 * n + 3 * m + b]
                M[cm + b, r] = G[r, 6 * n + 3 * m + b]
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
            put6(t2, force_cross(V0, Y[3 * i + b, :6]))  # twist columns: Ya ad(V0) + Yv
            for k in range(6):
                dv[ri + b, k] = Y[3 * i + b, 6 + k] - t2[k]
            for k in range(3):
                acc = 0.0
                for s in range(3):
                    acc += Y[3 * i + b, s] * sg[k, s]
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
