"""Recursive passes over a chain of segments (numba), in the manner of Pinocchio's algorithms.

docs/model.md section 8 derives them: the chain form of the paper's eq. (9), assembled from
each segment's eq. (6) block ``M_xi`` and slice Newton-Euler integral (section 4).

The passes work on per-segment blocks and plain arrays, never on the ``Chain`` facade:

* ``arr``, first argument: the model's :class:`~qchain.algorithms.arrays.ChainArrays`, of which
  the passes read ``alpha, w`` (N,), ``offs`` (n + 1,): the Gauss nodes and weights of all
  segments, segment ``j`` owning ``alpha[offs[j]:offs[j+1]]``; ``mass, radius`` (n,): kg, m;
  ``locked`` (:func:`aba`); the material arrays (:func:`internal_forces`);
* ``q, qd, qdd`` (n, 3): segment configurations and their derivatives in curvature
  coordinates ``(l, ux, uy)`` (the ``Chain`` maps paper coordinates in and out);
* ``V0, A0`` (6,): the first root's body twist and "apparent" acceleration in its own
  frame, ``A0 = a_root - (R^T g, 0)``: gravity enters as an upward acceleration of the base
  (Featherstone's device), so every pass includes it at no cost.

A rigid tip payload (``arr.payload`` (6, 6), its spatial inertia ``I_p`` at the tip origin,
zeros for none; :mod:`qchain.arm.payload`) is what hangs beyond root ``n``: the backward
sweeps start from its wrench ``I_p A_n + V_n x* (I_p V_n)`` (:func:`payload_wrench`,
:func:`rnea`), its inertia (the composite inertia of :func:`crba`, the articulated inertia of
:func:`aba`) and its bias force ``V_n x* (I_p V_n)`` (:func:`aba`).

Root ``j + 1`` is the tip of segment ``j``: its twist is ``T_j xi_j`` with the tip map
``T_j = Phi_j(1) = [Ad(g_j(1))^-1, S_j(1)]`` (6 x 9), and its acceleration
``T_j xidot_j + c_j`` with the tip bias acceleration ``c_j = Phidot_j(1) xi_j``.

* :func:`rnea` -- recursive Newton-Euler over the slices, O(n * nodes);
* :func:`crba` -- composite-body assembly of ``M = sum_j A_j^T M_xi_j A_j``, O(n^2);
* :func:`aba` -- articulated-body forward dynamics on the 9 x 9 segment blocks, O(n);
  :func:`forward_dynamics` -- it with the material law's forces, in one call from Python;
* :func:`frames` -- world frames of the roots and the tip and backbone points, for many
  configurations in one call (drawing and logging).

``tests/test_chain.py`` holds them to particle brute force, to each other
(``nle == rnea(q, v, 0)``, ``aba == solve(crba, tau - nle)``) and to ``pinocchio.crba``.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

import numpy as np

from .arrays import AbaWorkspace, ChainArrays
from .._jit import jit, jit_helper, jit_inline, jit_pass
from ..model.arc import SCRATCH, arc_node_bias, arc_pose, take1, take2
from ..model.slices import (
    _segment_slices, domain_violation, input_matrix_c, law_gradient_c, phi_matrix, slice_twist)
from ..model.spatial_kernels import add6, force_cross, motion_cross, sub6

__all__ = ["rnea", "crba", "aba", "forward_dynamics", "tip_maps", "frames", "internal_forces", "first_invalid", "first_invalid_of",
           "payload_wrench"]


@jit_helper
def _tip(q, qd, xi, T, c, sc):
    """Tip map ``T = Phi(1)`` (6, 9) and tip bias acceleration ``c = Phidot(1) xi`` (6,)."""
    o = 0
    R, o = take2(sc, o, 3, 3)
    p, o = take1(sc, o, 3)
    S, o = take2(sc, o, 6, 3)
    sd, o = take1(sc, o, 6)
    arc_node_bias(1.0, q[0], q[1], q[2], qd[0], qd[1], qd[2], R, p, S, sd)
    phi_matrix(R, p, S, T)
    Vr, o = take1(sc, o, 6)
    zero3, o = take1(sc, o, 3)
    zero3[:] = 0.0
    slice_twist(R, p, S, xi[:6], zero3, Vr)
    rel, o = take1(sc, o, 6)
    for r in range(6):
        rel[r] = S[r, 0] * qd[0] + S[r, 1] * qd[1] + S[r, 2] * qd[2]
        c[r] = sd[r]
    sub6(c, motion_cross(rel, Vr))


@jit_helper
def payload_wrench(P, V, A, h, F):
    """``F = P A + V x* (P V)`` (6,): the wrench (tip frame) the tip must exert on a rigid
    payload of spatial inertia ``P`` (6, 6) moving with twist ``V`` and apparent acceleration
    ``A`` (gravity folded in as the passes do); ``h`` (6,) receives ``P V``. ``P = 0``: ``F = 0``."""
    for r in range(6):
        acc = 0.0
        acc2 = 0.0
        for s in range(6):
            acc += P[r, s] * V[s]
            acc2 += P[r, s] * A[s]
        h[r] = acc
        F[r] = acc2
    add6(F, force_cross(V, h))


@jit_helper
def _matvec(T, x, out):
    for r in range(T.shape[0]):
        acc = 0.0
        for k in range(T.shape[1]):
            acc += T[r, k] * x[k]
        out[r] = acc


@jit_helper
def _load_xi(xi, V, qd):
    """``xi = (V, qd)`` (9,) from a twist (6,) and a segment velocity (3,), element by element:
    an array-to-array slice assignment (``xi[:6] = V``) costs a compile of numba's shape-mismatch
    error message (string formatting, seconds) and its code in every kernel library."""
    for r in range(6):
        xi[r] = V[r]
    for r in range(3):
        xi[6 + r] = qd[r]


@jit
def tip_maps(q, qd, V0, T, c, V):
    """Forward velocity pass: tip maps ``T`` (n, 6, 9), tip biases ``c`` (n, 6) and root
    twists ``V`` (n + 1, 6), ``V[0] = V0``, ``V[j + 1] = T_j xi_j`` (docs/model.md section 8)."""
    n = q.shape[0]
    sc = np.empty(SCRATCH)  # called from Python, once per call
    xi, o = take1(sc, 0, 9)
    for r in range(6):
        V[0, r] = V0[r]
    for j in range(n):
        _load_xi(xi, V[j], qd[j])
        _tip(q[j], qd[j], xi, T[j], c[j], sc[o:])
        _matvec(T[j], xi, V[j + 1])


@jit_pass
def rnea(arr, q, qd, qdd, V0, A0, tau, F0, ws, sc):
    """Inverse dynamics ``tau = M qdd + C qd + g`` (n, 3) and the base wrench ``F0`` (6,): the
    inertial and gravity terms of the paper's eq. (9) for the chain, by Newton-Euler over the
    slices (docs/model.md section 8).

    ``F0`` is the wrench (first root frame) the base exerts on the chain: the generalised
    force of a floating base, the mount's reaction for a fixed or prescribed one. ``ws`` is
    :meth:`qchain.arm.data.Data.aba_workspace`; ``arr`` the model's
    :class:`~qchain.algorithms.arrays.ChainArrays`.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = AbaWorkspace(*ws)
    alpha, w, offs, mass, radius = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius
    n = q.shape[0]
    T, c, Q = ws.T, ws.c, ws.Q
    o = 0
    xi, o = take1(sc, o, 9)
    xid, o = take1(sc, o, 9)
    V, o = take1(sc, o, 6)
    A, o = take1(sc, o, 6)
    for r in range(6):
        V[r] = V0[r]
        A[r] = A0[r]
    Mdummy, o = take2(sc, o, 1, 1)
    F, o = take1(sc, o, 6)
    out, o = take1(sc, o, 9)
    for j in range(n):
        _load_xi(xi, V, qd[j])
        _load_xi(xid, A, qdd[j])
        _segment_slices(alpha[offs[j] : offs[j + 1]], w[offs[j] : offs[j + 1]], mass[j], radius[j], q[j], xi, xid,
                        False, Mdummy, Q[j], sc[o:])
        _tip(q[j], qd[j], xi, T[j], c[j], sc[o:])
        _matvec(T[j], xi, V)
        _matvec(T[j], xid, A)
        for r in range(6):
            A[r] += c[j, r]
    h, o = take1(sc, o, 6)
    payload_wrench(arr.payload, V, A, h, F)  # V, A: the tip's (root n) twist and acceleration
    for j in range(n - 1, -1, -1):
        out[:] = 0.0
        for r in range(6):  # T^T F
            for k in range(9):
                out[k] += T[j, r, k] * F[r]
        for r in range(6):
            F[r] = Q[j, r] + out[r]
        for r in range(3):
            tau[j, r] = Q[j, 6 + r] + out[6 + r]
    for r in range(6):
        F0[r] = F[r]


@jit_helper
def _project(M, T, I, IT, out):
    """``out = M + T^T I T`` (9, 9): a segment's 9x9 block with the inertia ``I`` (6, 6) of what
    hangs beyond its tip carried to its root through the tip map ``T`` (6, 9); ``IT`` (6, 9)
    receives ``I T``. ``T``'s lower left 3 x 3 block is zero (the linear velocity's share of
    the angular one, ``Ad^-1``'s): both products skip it (the sums they leave out are exact
    zeros). ``out`` is symmetric: its upper triangle is formed, then mirrored."""
    for r in range(6):
        for k in range(9):
            acc = 0.0
            for s in range(3 if k < 3 else 6):
                acc += I[r, s] * T[s, k]
            IT[r, k] = acc
    for a in range(9):
        for b in range(a, 9):
            acc = M[a, b]
            for r in range(3 if a < 3 else 6):
                acc += T[r, a] * IT[r, b]
            out[a, b] = acc
            out[b, a] = acc


@jit_pass
def crba(arr, q, floating, H, ws, sc):
    """Composite-body assembly of the joint-space inertia ``H`` (nv, nv), curvature coordinates
    (``M = sum_j A_j^T M_xi_j A_j`` of the segments' eq. (6) blocks; docs/model.md section 8).

    Backwards from the tip: the composite inertia ``Ic`` of everything beyond root ``j + 1``
    gives ``Mh = M_xi_j + T_j^T Ic T_j`` (9 x 9): its ``qq`` block is ``H_jj``, its ``Vq``
    block the wrench at root ``j`` per unit ``qddot_j``, carried inwards by ``T_i^T`` to give
    ``H_ij`` (and, for a floating base, ``H_base,j``); its ``VV`` block is the next ``Ic``.
    ``ws`` is :meth:`qchain.arm.data.Data.aba_workspace`; ``arr`` the model's
    :class:`~qchain.algorithms.arrays.ChainArrays`.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = AbaWorkspace(*ws)
    alpha, w, offs, mass, radius = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius
    n = q.shape[0]
    off = 6 if floating else 0
    T = ws.T
    o = 0
    c, o = take1(sc, o, 6)
    Mj, o = take2(sc, o, 9, 9)
    Q, o = take1(sc, o, 9)
    z9, o = take1(sc, o, 9)
    z9[:] = 0.0
    z3, o = take1(sc, o, 3)
    z3[:] = 0.0
    for j in range(n):
        _tip(q[j], z3, z9, T[j], c, sc[o:])
    Ic, o = take2(sc, o, 6, 6)
    for r in range(6):  # what hangs beyond the tip: the payload
        for s in range(6):
            Ic[r, s] = arr.payload[r, s]
    IcT, o = take2(sc, o, 6, 9)
    Mh, o = take2(sc, o, 9, 9)
    F, o = take2(sc, o, 6, 3)
    Fn, o = take2(sc, o, 6, 3)
    H[:, :] = 0.0
    for j in range(n - 1, -1, -1):
        _segment_slices(alpha[offs[j] : offs[j + 1]], w[offs[j] : offs[j + 1]], mass[j], radius[j], q[j], z9, z9,
                        True, Mj, Q, sc[o:])
        _project(Mj, T[j], Ic, IcT, Mh)
        i0 = off + 3 * j
        for a in range(3):
            for b in range(3):
                H[i0 + a, i0 + b] = Mh[6 + a, 6 + b]
        for r in range(6):
            for b in range(3):
                F[r, b] = Mh[r, 6 + b]
        for i in range(j - 1, -1, -1):
            k0 = off + 3 * i
            for a in range(9):
                for b in range(3):
                    acc = 0.0
                    for r in range(6):
                        acc += T[i, r, a] * F[r, b]
                    if a >= 6:
                        H[k0 + a - 6, i0 + b] = acc
                        H[i0 + b, k0 + a - 6] = acc
                    else:
                        Fn[a, b] = acc
            for a in range(6):
                for b in range(3):
                    F[a, b] = Fn[a, b]
        if floating:
            for r in range(6):
                for b in range(3):
                    H[r, i0 + b] = F[r, b]
                    H[i0 + b, r] = F[r, b]
        for r in range(6):
            for s in range(6):
                Ic[r, s] = Mh[r, s]
    if floating:
        for r in range(6):
            for s in range(6):
                H[r, s] = Ic[r, s]


@jit_inline
def _chol(A, k):
    """In-place Cholesky ``A = L L^T`` of the leading ``k x k`` block (lower triangle). False if not SPD."""
    for j in range(k):
        d = A[j, j]
        for s in range(j):
            d -= A[j, s] * A[j, s]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, k):
            acc = A[i, j]
            for s in range(j):
                acc -= A[i, s] * A[j, s]
            A[i, j] = acc / d
    return True


@jit_helper
def _chol_solve(L, k, b):
    """Solve ``L L^T x = b`` in place (``b`` of length k)."""
    for i in range(k):
        acc = b[i]
        for s in range(i):
            acc -= L[i, s] * b[s]
        b[i] = acc / L[i, i]
    for i in range(k - 1, -1, -1):
        acc = b[i]
        for s in range(i + 1, k):
            acc -= L[s, i] * b[s]
        b[i] = acc / L[i, i]


@jit_helper
def _spd3_inverse(A):
    """``A`` (3, 3) symmetric positive definite (its lower triangle read) replaced by its inverse
    through its Cholesky factor ``L`` (``A^-1 = L^-T L^-1``), written out: a segment's
    articulated block is inverted once and then multiplies seven vectors, where a general
    :func:`_chol_solve` a vector cost as much as the whole inverse. False, ``A`` unchanged, if
    a pivot is not positive (not positive definite)."""
    l00 = A[0, 0]
    if not l00 > 0.0:
        return False
    l00 = np.sqrt(l00)
    l10 = A[1, 0] / l00
    l20 = A[2, 0] / l00
    l11 = A[1, 1] - l10 * l10
    if not l11 > 0.0:
        return False
    l11 = np.sqrt(l11)
    l21 = (A[2, 1] - l20 * l10) / l11
    l22 = A[2, 2] - l20 * l20 - l21 * l21
    if not l22 > 0.0:
        return False
    l22 = np.sqrt(l22)
    # M = L^-1 (lower triangular), then A^-1 = M^T M
    m00 = 1.0 / l00
    m11 = 1.0 / l11
    m22 = 1.0 / l22
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    A[0, 0] = m00 * m00 + m10 * m10 + m20 * m20
    A[1, 1] = m11 * m11 + m21 * m21
    A[2, 2] = m22 * m22
    A[0, 1] = A[1, 0] = m10 * m11 + m20 * m21
    A[0, 2] = A[2, 0] = m20 * m22
    A[1, 2] = A[2, 1] = m21 * m22
    return True


@jit_pass
def aba(arr, q, qd, tau, V0, A0, floating, F0, qdd, A0_out, ws, sc):
    """Articulated-body forward dynamics: ``qdd`` (n, 3) from ``M qdd + C qd + g = tau`` (the
    paper's eq. (9) for the chain; docs/model.md section 8).

    ``tau`` (n, 3) is the total generalised force on the segment coordinates (pressure,
    elastic, damping, external). ``arr.locked`` (n, 3) bool holds coordinates still (ideal
    constraints: their ``qdd`` is zero, their constraint forces are not computed). For a
    fixed or prescribed base ``A0`` is the root's
    apparent acceleration; for a floating base ``F0`` (6,) is the wrench applied to the base
    and ``A0_out`` receives the solved apparent base acceleration. Returns False if an
    articulated block is not positive definite (a singular configuration). ``ws`` is
    :meth:`qchain.arm.data.Data.aba_workspace`; ``arr`` the model's
    :class:`~qchain.algorithms.arrays.ChainArrays`.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = AbaWorkspace(*ws)
    alpha, w, offs, mass, radius = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius
    locked = arr.locked
    n = q.shape[0]
    T, c, b, Mall, Lq, U, u = ws.T, ws.c, ws.Q, ws.M_xi, ws.Lq, ws.U, ws.u
    o = 0
    xi, o = take1(sc, o, 9)
    z9, o = take1(sc, o, 9)
    z9[:] = 0.0
    V, o = take1(sc, o, 6)
    for r in range(6):
        V[r] = V0[r]
    IA, o = take2(sc, o, 6, 6)
    pA, o = take1(sc, o, 6)
    DiUt, o = take2(sc, o, 3, 6)
    IAT, o = take2(sc, o, 6, 9)
    Mh, o = take2(sc, o, 9, 9)
    bh, o = take1(sc, o, 9)
    pc, o = take1(sc, o, 6)
    col, o = take1(sc, o, 3)
    A, o = take1(sc, o, 6)
    L6, o = take2(sc, o, 6, 6)
    xid, o = take1(sc, o, 9)
    # pass 1: velocities, segment blocks and biases
    for j in range(n):
        _load_xi(xi, V, qd[j])
        _segment_slices(alpha[offs[j] : offs[j + 1]], w[offs[j] : offs[j + 1]], mass[j], radius[j], q[j], xi, z9,
                        True, Mall[j], b[j], sc[o:])
        _tip(q[j], qd[j], xi, T[j], c[j], sc[o:])
        _matvec(T[j], xi, V)
    # pass 2: articulated inertias, backwards, from the payload's (V: the tip twist)
    for r in range(6):
        for s in range(6):
            IA[r, s] = arr.payload[r, s]
    payload_wrench(arr.payload, V, z9[:6], pc, pA)  # bias force V x* (P V); z9 is zero
    for j in range(n - 1, -1, -1):
        for r in range(6):
            acc = pA[r]
            for s in range(6):
                acc += IA[r, s] * c[j, s]
            pc[r] = acc
        _project(Mall[j], T[j], IA, IAT, Mh)
        for a in range(9):
            acc = b[j, a]
            for r in range(6):
                acc += T[j, r, a] * pc[r]
            bh[a] = acc
        for a in range(3):
            for e in range(3):
                Lq[j, a, e] = Mh[6 + a, 6 + e]
            u[j, a] = tau[j, a] - bh[6 + a]
        for r in range(6):
            for a in range(3):
                U[j, r, a] = Mh[r, 6 + a]
        for a in range(3):
            if locked[j, a]:  # qdd_a = 0: decouple the row and column
                for e in range(3):
                    Lq[j, a, e] = 0.0
                    Lq[j, e, a] = 0.0
                Lq[j, a, a] = 1.0
                u[j, a] = 0.0
                for r in range(6):
                    U[j, r, a] = 0.0
        if not _spd3_inverse(Lq[j]):  # Lq[j] holds D^-1 from here on
            return False
        Di = Lq[j]
        # IA = Mh_VV - U D^-1 U^T (symmetric: the upper triangle, mirrored); pA = bh_V + U D^-1 u
        for r in range(6):
            for a in range(3):
                DiUt[a, r] = Di[a, 0] * U[j, r, 0] + Di[a, 1] * U[j, r, 1] + Di[a, 2] * U[j, r, 2]
        for a in range(3):
            col[a] = Di[a, 0] * u[j, 0] + Di[a, 1] * u[j, 1] + Di[a, 2] * u[j, 2]
        for r in range(6):
            pA[r] = bh[r] + U[j, r, 0] * col[0] + U[j, r, 1] * col[1] + U[j, r, 2] * col[2]
            for s in range(r, 6):
                acc = Mh[r, s] - U[j, r, 0] * DiUt[0, s] - U[j, r, 1] * DiUt[1, s] - U[j, r, 2] * DiUt[2, s]
                IA[r, s] = acc
                IA[s, r] = acc
    # pass 3: accelerations, forwards
    if floating:
        for r in range(6):
            for s in range(6):
                L6[r, s] = IA[r, s]
        if not _chol(L6, 6):
            return False
        for r in range(6):
            A[r] = F0[r] - pA[r]
        _chol_solve(L6, 6, A)
    else:
        for r in range(6):
            A[r] = A0[r]
    for r in range(6):
        A0_out[r] = A[r]
    for j in range(n):
        for a in range(3):
            acc = u[j, a]
            for r in range(6):
                acc -= U[j, r, a] * A[r]
            col[a] = acc
        Di = Lq[j]
        for a in range(3):
            qdd[j, a] = Di[a, 0] * col[0] + Di[a, 1] * col[1] + Di[a, 2] * col[2]
        _load_xi(xid, A, qdd[j])
        _matvec(T[j], xid, A)
        for r in range(6):
            A[r] += c[j, r]
    return True


@jit_pass
def forward_dynamics(arr, floating, q, v, p, tau, V0, A_B, g_B, f, a, ws, sc):
    """``a`` (nv,) of ``M a + C v + g + D v + dU_el/dq = B p + tau`` in one compiled call: the
    material law's forces (:func:`internal_forces`), the external ``tau`` and :func:`aba`. The
    ``skip_checks`` path of ``Chain.forward_dynamics`` (curvature coordinates, the material law),
    whose Python would otherwise cost a third of the call at ten segments.

    ``q`` (nq,), ``v`` (nv,): the chain's whole configuration and velocity (the base's 7 and 6
    first for a ``floating`` base); ``p`` (3 n,) Pa; ``tau`` (nv,) or empty (none; a floating
    base's ``tau[:6]`` is the wrench on the base); ``V0`` (6,) the base twist, ``A_B`` (6,) the
    base's own acceleration (zeros but for a prescribed base), ``g_B`` (3,) gravity in the base
    frame; ``f`` (n, 3) receives the segments' generalised forces, ``a`` the accelerations
    (a floating base's first six: its own, gravity included). ``ws``, ``sc``: as :func:`aba`.
    Returns 0; 1 where :func:`aba` returns False (``a`` is then not defined); 2 where an
    entry of ``a`` is not finite.
    """
    n = f.shape[0]
    qoff = 7 if floating else 0
    voff = 6 if floating else 0
    q_c = q[qoff:].reshape((n, 3))
    v_c = v[voff:].reshape((n, 3))
    internal_forces(arr, q_c, v_c, p.reshape((n, 3)), f, sc)
    o = 0
    F0, o = take1(sc, o, 6)
    A0, o = take1(sc, o, 6)
    for r in range(6):
        F0[r] = 0.0
        A0[r] = A_B[r]
    for r in range(3):
        A0[r] -= g_B[r]
    if tau.shape[0] > 0:
        for j in range(n):
            for b in range(3):
                f[j, b] += tau[voff + 3 * j + b]
        if floating:
            for r in range(6):
                F0[r] = tau[r]
    A_out, o = take1(sc, o, 6)
    if not aba(arr, q_c, v_c, f, V0, A0, floating, F0, a[voff:].reshape((n, 3)), A_out, ws, sc[o:]):
        return 1
    if floating:
        for r in range(6):
            a[r] = A_out[r]
        for r in range(3):
            a[r] += g_B[r]
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return 2
    return 0


@jit_helper
def _quaternion(R, out):
    """Unit quaternion ``(x, y, z, w)`` of the rotation ``R`` (3, 3) into ``out`` (4,), with
    ``w >= 0`` (Pinocchio's ``Quaternion(R).coeffs()`` up to that sign); each entry from the
    largest of ``1 + trace`` and ``1 + 2 R_ii - trace``, the well-conditioned branch."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    k = 0
    best = 1.0 + tr
    for i in range(3):
        c = 1.0 + 2.0 * R[i, i] - tr
        if c > best:
            best = c
            k = i + 1
    s = 2.0 * np.sqrt(best)  # 4 |component k|
    a = R[2, 1] - R[1, 2]  # 4 w x
    b = R[0, 2] - R[2, 0]  # 4 w y
    c = R[1, 0] - R[0, 1]  # 4 w z
    d = R[0, 1] + R[1, 0]  # 4 x y
    e = R[0, 2] + R[2, 0]  # 4 x z
    f = R[1, 2] + R[2, 1]  # 4 y z
    h = 0.25 * s * s
    if k == 0:
        x, y, z, w = a, b, c, h
    elif k == 1:
        x, y, z, w = h, d, e, a
    elif k == 2:
        x, y, z, w = d, h, f, b
    else:
        x, y, z, w = e, f, h, c
    sign = -1.0 if w < 0.0 else 1.0
    out[0] = sign * x / s
    out[1] = sign * y / s
    out[2] = sign * z / s
    out[3] = sign * w / s


@jit
def frames(q, paper, R0, o0, alpha, R, o, quat, points):
    """World frames of ``K`` configurations of an ``n``-segment chain in one call.

    Parameters
    ----------
    q : (K, n, 3)            segment configurations: ``(l, ux, uy)``, or the paper's
                             ``(l, psi, kappa)`` where ``paper`` is set.
    paper : (n,) bool        segments in the paper's coordinates.
    R0 : (K, 3, 3)           rotation of the first root (the base) in the world (or
                             (1, 3, 3): the same for all).
    o0 : (K, 3)              origin of the first root in the world (m) (or (1, 3)).
    alpha : (P,)             slice coordinates in [0, 1] of the backbone points (P may be 0).
    R : (K, n + 1, 3, 3) out world rotations of roots ``0..n-1`` and of the tip (index ``n``).
    o : (K, n + 1, 3) out    their world origins (m).
    quat : (K, n + 1, 4) out their rotations as unit quaternions ``(x, y, z, w)``, ``w >= 0``.
    points : (K, n, P, 3) out world backbone points of each segment at ``alpha`` (m).
    """
    K = q.shape[0]
    n = q.shape[1]
    P = alpha.shape[0]
    Rs = np.empty((3, 3))
    ps = np.empty(3)
    # Evenly spaced points from 0 to 1 (a drawn backbone's) follow one another by the same
    # rigid step g(d), a constant-curvature arc's: one arc_pose a segment instead of one a
    # point (the tip's end point is the tip frame's origin itself).
    even = P >= 3 and alpha[0] == 0.0 and alpha[P - 1] == 1.0
    d = alpha[1] if P >= 2 else 0.0
    for i in range(P):
        if even and abs(alpha[i] - i * d) > 4e-16:
            even = False
    Rd = np.empty((3, 3))
    pd = np.empty(3)
    Rw = np.empty((3, 3))
    ow = np.empty(3)
    for k in range(K):
        k0 = min(k, R0.shape[0] - 1)
        k1 = min(k, o0.shape[0] - 1)
        for r in range(3):
            o[k, 0, r] = o0[k1, r]
            for c in range(3):
                R[k, 0, r, c] = R0[k0, r, c]
        for j in range(n):
            l = q[k, j, 0]
            if paper[j]:
                ux = q[k, j, 2] * np.cos(q[k, j, 1])
                uy = q[k, j, 2] * np.sin(q[k, j, 1])
            else:
                ux = q[k, j, 1]
                uy = q[k, j, 2]
            Rj = R[k, j]
            oj = o[k, j]
            arc_pose(1.0, l, ux, uy, Rs, ps)
            for r in range(3):
                o[k, j + 1, r] = oj[r] + Rj[r, 0] * ps[0] + Rj[r, 1] * ps[1] + Rj[r, 2] * ps[2]
                for c in range(3):
                    R[k, j + 1, r, c] = Rj[r, 0] * Rs[0, c] + Rj[r, 1] * Rs[1, c] + Rj[r, 2] * Rs[2, c]
            if even:
                arc_pose(d, l, ux, uy, Rd, pd)
                for r in range(3):
                    ow[r] = oj[r]
                    points[k, j, 0, r] = oj[r]
                    points[k, j, P - 1, r] = o[k, j + 1, r]
                    for c in range(3):
                        Rw[r, c] = Rj[r, c]
                for i in range(1, P - 1):
                    for r in range(3):
                        ow[r] += Rw[r, 0] * pd[0] + Rw[r, 1] * pd[1] + Rw[r, 2] * pd[2]
                        points[k, j, i, r] = ow[r]
                    for r in range(3):
                        a0, a1, a2 = Rw[r, 0], Rw[r, 1], Rw[r, 2]
                        for c in range(3):
                            Rw[r, c] = a0 * Rd[0, c] + a1 * Rd[1, c] + a2 * Rd[2, c]
            else:
                for i in range(P):
                    arc_pose(alpha[i], l, ux, uy, Rs, ps)
                    for r in range(3):
                        points[k, j, i, r] = oj[r] + Rj[r, 0] * ps[0] + Rj[r, 1] * ps[1] + Rj[r, 2] * ps[2]
        for j in range(n + 1):
            _quaternion(R[k, j], quat[k, j])


@jit_pass
def internal_forces(arr, q, qd, p, out, sc):
    """``out = B p - D qd - dU_el/dq`` (n, 3), curvature coordinates: ``B`` of
    :func:`qchain.model.slices.input_matrix_c`, each segment's constant dissipation matrix
    ``arr.D`` and its elastic law (:func:`qchain.model.slices.law_gradient_c`: the material law
    or the linear ``K_e (q - q_e0)``). These terms are coordinate-free: paper coordinates get
    ``J^T`` of them. ``arr``: the model's :class:`~qchain.algorithms.arrays.ChainArrays`.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    l0, EI, EA, A_ch, r_ch, paper_act = arr.l0, arr.EI, arr.EA, arr.A_ch, arr.r_ch, arr.paper_act
    Dall = arr.D
    o = 0
    B, o = take2(sc, o, 3, 3)
    g, o = take1(sc, o, 3)
    for j in range(q.shape[0]):
        input_matrix_c(q[j], A_ch[j], r_ch[j], paper_act[j], B, sc[o:])
        law_gradient_c(q[j], l0[j], EI[j], EA[j], arr.linear_law[j], arr.K[j], arr.q_rest[j], g)
        D = Dall[j]
        for a in range(3):
            out[j, a] = -g[a] - D[a, 0] * qd[j, 0] - D[a, 1] * qd[j, 1] - D[a, 2] * qd[j, 2]
            out[j, a] += B[a, 0] * p[j, 0] + B[a, 1] * p[j, 1] + B[a, 2] * p[j, 2]


@jit_pass
def first_invalid_of(x0, x1, x2, x3, q, radius, paper):
    """:func:`first_invalid` for four arrays checked alongside in one call (empty ones for
    fewer): ``-2 - k`` where ``x_k`` is the first with a non-finite entry, else the index of
    the first segment outside the model, or -1."""
    xs = (x0, x1, x2, x3)
    for k in range(4):
        x = xs[k]
        for i in range(x.shape[0]):
            if not np.isfinite(x[i]):
                return -2 - k
    return first_invalid(q[:0, 0], q, radius, paper)


@jit
def first_invalid(x, q, radius, paper):
    """Index of the first segment whose configuration is outside the model, or -1.

    Also -2 if ``x`` (any array checked alongside, e.g. the full q and v) has a
    non-finite entry. ``q`` (n, 3) segment coordinates, or (K n, 3) for ``K``
    configurations (row ``j`` is segment ``j % n``); ``radius`` (n,); ``paper`` (n,) bool.
    """
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return -2
    n = radius.shape[0]
    for jk in range(q.shape[0]):
        j = jk % n
        if domain_violation(q[jk, 0], q[jk, 1], q[jk, 2], radius[j], paper[j]):
            return jk
    return -1


@jit
def aba_workspace(n, nv):
    """Fresh arrays for :func:`aba`, :func:`rnea` and :func:`crba` (``Data.aba_workspace``):
    root twists (n + 1, 6), tip maps (n, 6, 9), tip biases (n, 6), segment forces (n, 9),
    segment blocks (n, 9, 9), the articulated factors (n, 3, 3), (n, 6, 3), (n, 3) and the
    scratch (:data:`qchain.model.arc.SCRATCH`,) the passes carve their small temporaries from."""
    return AbaWorkspace(np.zeros((n + 1, 6)), np.zeros((n, 6, 9)), np.zeros((n, 6)), np.zeros((n, 9)),
                        np.zeros((n, 9, 9)), np.zeros((n, 3, 3)), np.zeros((n, 6, 3)), np.zeros((n, 3)),
                        np.zeros(SCRATCH))
