"""A slice's force variations and every segment's derivative columns, many nodes at once
(numba): the node part of :mod:`qchain.algorithms.rnea_derivatives`.

A slice at node ``alpha`` of segment ``j`` moves with the root's twist ``V0`` and apparent
acceleration ``A0`` (its own root frame) and with the segment's ``q, qdot, qddot``: its twist
``V = Ad^-1 V0 + S qdot`` and acceleration ``a = Ad^-1 A0 + S qddot + Sd qdot - (S qdot) x
(Ad^-1 V0)`` (docs/model.md section 2). Its inertial force ``f = I a + V x* I V`` enters the
segment's generalised force ``Q = sum_k w_k Phi_k^T f_k`` (:mod:`qchain.model.slices`). This
module gives, per segment and at fixed ``V0, A0``:

* ``QqT[c] = dQ/dq_c`` (3, 9): the slices move (``dV = dS_c qdot - S_c x Vr``, ``da = rel x
  (S_c x Vr) + K_c + dS_c qddot - (dS_c qdot) x Vr - S_c x Ar``, :func:`q_variation`), and
  ``Phi`` with them (``d(Phi^T f) = Phi^T df + [Ad^-T (S_c x* f); dS_c^T f]``);
* ``QxT[6 + c] = dQ/dqdot_c`` (9,): ``dV = S_c``, ``da = 2 Sd_c - S_c x V`` (:func:`qd_variation`);
* ``QxT[:6] = dQ/dV0`` from the segment's ``M_xi``, the rate columns and five node sums, with
  no node visited (:func:`root_twist_columns`).

**Lanes.** Every node of the chain is independent once the roots' twists and accelerations are
known, so the nodes run as lanes of one loop (:func:`_lane_columns`): each lane's inputs are
one column of a (rows, :data:`LANES`) block and its twelve force columns one column of
another, and the compiler turns the loop into vector instructions (eight lanes at a time with
AVX-512). Written node by node, the same arithmetic ran in scalar instructions, several times
slower (docs/benchmarks/README.md, "Cost of the derivatives"). The compiler vectorises the
loop only as one body with a known trip count: every helper in it is inlined before typing
(:data:`qchain._jit.jit_inline`; a call stops it) and it runs over all :data:`LANES` lanes.
What cannot run as lanes stays outside the loop: the bend functions' series and closed forms (a branch per node,
:func:`_load_lanes`) and the sums over each segment's nodes (:func:`_add_lanes`).

``tests/test_derivatives.py`` holds every output to central differences of the model.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

from .._jit import jit_helper, jit_inline
from ..model.arc import bend_values, slice_kinematics
from ..model.slices import disk_diagonal
from ..model.spatial_kernels import (ad_force, ad_inv_twist, columns_times, force_cross, motion_cross, vadd, vmul,
                                     vscale, vsub)

__all__ = ["LANES", "LANE_SCRATCH", "force_variation", "node_state", "q_variation", "qd_variation",
           "segment_columns", "root_twist_columns"]

#: Lanes a block of nodes holds: the stride of the lane arrays (a constant, so that the
#: compiler sees the rows of a block at fixed distances and checks their overlap once), and
#: long enough that it vectorises the loop (LLVM leaves loops of under 16 known trips scalar).
LANES = 32
_IN = 34  # a lane's inputs (_load_lanes)
_OUT = 93  # a lane's outputs (_lane): QqT 27, QxT[6:] 27, Pd 3, Z 9, Pi 9, Mdt 18
#: Floats of scratch :func:`segment_columns` carves its two blocks and its node sums from.
LANE_SCRATCH = (_IN + _OUT) * LANES + 39


@jit_inline
def force_variation(Id, V, hV, dV, da):
    """``I da + dV x* (I V) + V x* (I dV)`` (6-tuple): the slice force's variation
    (``I = diag(Id)``, ``hV = I V``)."""
    return vadd(vadd(force_cross(dV, hV), vmul(Id, da)), force_cross(V, vmul(Id, dV)))


@jit_inline
def node_state(R, p, S, Sd, V0, A0, qd, qdd):
    """``(Vr, Ar, rel, V, a)`` (6-tuples) at a node whose kinematics ``R`` (rows), ``p``,
    ``S`` and ``Sd`` (three columns each) are known: ``Vr = Ad^-1 V0``, ``Ar = Ad^-1 A0``,
    ``rel = S qdot``, the slice twist ``V = Vr + rel`` and acceleration
    ``a = Ar + S qddot + Sd qdot - rel x Vr``."""
    Vr = ad_inv_twist(R, p, V0)
    Ar = ad_inv_twist(R, p, A0)
    rel = columns_times(S, qd)
    a = vsub(vadd(vadd(Ar, columns_times(S, qdd)), columns_times(Sd, qd)), motion_cross(rel, Vr))
    return Vr, Ar, rel, vadd(Vr, rel), a


@jit_inline
def q_variation(Sc, dSc, Kc, qd, qdd, Vr, Ar, rel):
    """``(dV, da)`` (6-tuples) of a slice for a unit change of ``q_c`` (fixed root twist and
    acceleration): ``dV = dS_c qdot - S_c x Vr``, ``da = rel x (S_c x Vr) + K_c + dS_c qddot -
    (dS_c qdot) x Vr - S_c x Ar``; ``Sc`` the column ``S_c``, ``dSc`` the three columns of
    ``dS/dq_c``, ``Kc = d(Sd qdot)/dq_c``."""
    dSq = columns_times(dSc, qd)
    t1 = motion_cross(Sc, Vr)
    da = vadd(vadd(motion_cross(rel, t1), Kc), columns_times(dSc, qdd))
    da = vsub(vsub(da, motion_cross(dSq, Vr)), motion_cross(Sc, Ar))
    return vsub(dSq, t1), da


@jit_inline
def qd_variation(Sc, Sdc, V):
    """``(dV, da)`` (6-tuples) of a slice for a unit change of ``qdot_c``: ``S_c`` and
    ``2 Sd_c - S_c x V``."""
    return Sc, vsub(vadd(Sdc, Sdc), motion_cross(Sc, V))


@jit_helper
def _in(X, r, i):
    """Input row ``r`` of lane ``i``."""
    return X[r * LANES + i]


@jit_helper
def _in6(X, r, i):
    """Input rows ``r .. r + 5`` of lane ``i`` (a 6-tuple)."""
    return (X[r * LANES + i], X[(r + 1) * LANES + i], X[(r + 2) * LANES + i], X[(r + 3) * LANES + i],
            X[(r + 4) * LANES + i], X[(r + 5) * LANES + i])


@jit_helper
def _out6(Y, r, i, t):
    """Output rows ``r .. r + 5`` of lane ``i`` from a 6-tuple."""
    Y[r * LANES + i] = t[0]
    Y[(r + 1) * LANES + i] = t[1]
    Y[(r + 2) * LANES + i] = t[2]
    Y[(r + 3) * LANES + i] = t[3]
    Y[(r + 4) * LANES + i] = t[4]
    Y[(r + 5) * LANES + i] = t[5]


@jit_helper
def _dot6(a, b):
    """``a . b`` of two 6-tuples."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


@jit_inline
def _q_column(Y, r, i, w, Id, R, p, S, Sc, dSc, Kc, qd, qdd, Vr, Ar, rel, V, hV, f):
    """Lane ``i``'s share of ``dQ/dq_c`` into rows ``r .. r + 8``: ``Phi^T (df + S_c x* f)
    + (0, dS_c^T f)``, with ``S^T (S_c x* f)`` left out of both slice rows' terms (they cancel)."""
    dV, da = q_variation(Sc, dSc, Kc, qd, qdd, Vr, Ar, rel)
    fv = force_variation(Id, V, hV, dV, da)
    _out6(Y, r, i, vscale(ad_force(R, p, vadd(fv, force_cross(Sc, f))), w))
    Y[(r + 6) * LANES + i] = w * (_dot6(S[0], fv) + _dot6(dSc[0], f))
    Y[(r + 7) * LANES + i] = w * (_dot6(S[1], fv) + _dot6(dSc[1], f))
    Y[(r + 8) * LANES + i] = w * (_dot6(S[2], fv) + _dot6(dSc[2], f))


@jit_inline
def _qd_column(Y, r, rm, i, w, Id, R, p, S, Sc, Sdc, rel, V, hV):
    """Lane ``i``'s share of ``dQ/dqdot_c`` into rows ``r .. r + 8`` and of ``d/dt M_xi[:6, 6 +
    c]``, ``Ad^-T (rel x* (I S_c) + I Sd_c)``, into rows ``rm .. rm + 5``."""
    dV, da = qd_variation(Sc, Sdc, V)
    fv = force_variation(Id, V, hV, dV, da)
    _out6(Y, r, i, vscale(ad_force(R, p, fv), w))
    Y[(r + 6) * LANES + i] = w * _dot6(S[0], fv)
    Y[(r + 7) * LANES + i] = w * _dot6(S[1], fv)
    Y[(r + 8) * LANES + i] = w * _dot6(S[2], fv)
    _out6(Y, rm, i, vscale(ad_force(R, p, vadd(force_cross(rel, vmul(Id, Sc)), vmul(Id, Sdc))), w))


@jit_inline
def _lane(X, Y, i):
    """One node (lane ``i`` of the blocks ``X``, ``Y``): its twelve force columns and sums."""
    alpha, w = _in(X, 0, i), _in(X, 1, i)
    l, ux, uy = _in(X, 2, i), _in(X, 3, i), _in(X, 4, i)
    qd = (_in(X, 5, i), _in(X, 6, i), _in(X, 7, i))
    qdd = (_in(X, 8, i), _in(X, 9, i), _in(X, 10, i))
    V0 = _in6(X, 11, i)
    A0 = _in6(X, 17, i)
    m, ixx, izz = _in(X, 23, i), _in(X, 24, i), _in(X, 25, i)
    bend = (_in(X, 26, i), _in(X, 27, i), _in(X, 28, i), _in(X, 29, i), _in(X, 30, i), _in(X, 31, i),
            _in(X, 32, i), _in(X, 33, i))
    Id = (m, m, m, ixx, ixx, izz)
    R, p, S, Sd, dS, K = slice_kinematics(alpha, l, ux, uy, qd[0], qd[1], qd[2], bend)
    Vr, Ar, rel, V, a = node_state(R, p, S, Sd, V0, A0, qd, qdd)
    hV = vmul(Id, V)
    f = vadd(force_cross(V, hV), vmul(Id, a))
    _q_column(Y, 0, i, w, Id, R, p, S, S[0], dS[0], K[0], qd, qdd, Vr, Ar, rel, V, hV, f)
    _q_column(Y, 9, i, w, Id, R, p, S, S[1], dS[1], K[1], qd, qdd, Vr, Ar, rel, V, hV, f)
    _q_column(Y, 18, i, w, Id, R, p, S, S[2], dS[2], K[2], qd, qdd, Vr, Ar, rel, V, hV, f)
    _qd_column(Y, 27, 75, i, w, Id, R, p, S, S[0], Sd[0], rel, V, hV)
    _qd_column(Y, 36, 81, i, w, Id, R, p, S, S[1], Sd[1], rel, V, hV)
    _qd_column(Y, 45, 87, i, w, Id, R, p, S, S[2], Sd[2], rel, V, hV)
    # the rates of the slice centre and axis in the root frame: pdot = R rel_l, zdot = R (w_rel x e_z)
    pd0 = w * (R[0][0] * rel[0] + R[0][1] * rel[1] + R[0][2] * rel[2])
    pd1 = w * (R[1][0] * rel[0] + R[1][1] * rel[1] + R[1][2] * rel[2])
    pd2 = w * (R[2][0] * rel[0] + R[2][1] * rel[1] + R[2][2] * rel[2])
    zd0 = w * (R[0][0] * rel[4] - R[0][1] * rel[3])
    zd1 = w * (R[1][0] * rel[4] - R[1][1] * rel[3])
    zd2 = w * (R[2][0] * rel[4] - R[2][1] * rel[3])
    Y[54 * LANES + i] = pd0
    Y[55 * LANES + i] = pd1
    Y[56 * LANES + i] = pd2
    z0, z1, z2 = R[0][2], R[1][2], R[2][2]
    _out6(Y, 57, i, (zd0 * z0, zd0 * z1, zd0 * z2, zd1 * z0, zd1 * z1, zd1 * z2))
    _out6(Y, 63, i, (zd2 * z0, zd2 * z1, zd2 * z2, pd0 * p[0], pd0 * p[1], pd0 * p[2]))
    _out6(Y, 69, i, (pd1 * p[0], pd1 * p[1], pd1 * p[2], pd2 * p[0], pd2 * p[1], pd2 * p[2]))


@jit_helper
def _lane_columns(X, Y):
    """:func:`_lane` for every lane: the loop the compiler vectorises (with a trip count it
    knows: with ``nl`` lanes it did not)."""
    for i in range(LANES):
        _lane(X, Y, i)


@jit_helper
def _load_lanes(alpha, w, offs, mass, radius, q, qd, qdd, V, A, k0, nl, j, X):
    """Lane inputs of nodes ``k0 .. k0 + nl - 1`` (node ``k0`` in segment ``j``) into ``X``;
    returns the segment of the last."""
    for i in range(nl):
        k = k0 + i
        while k >= offs[j + 1]:
            j += 1
        X[i] = alpha[k]
        X[LANES + i] = w[k]
        for b in range(3):
            X[(2 + b) * LANES + i] = q[j, b]
            X[(5 + b) * LANES + i] = qd[j, b]
            X[(8 + b) * LANES + i] = qdd[j, b]
        for r in range(6):
            X[(11 + r) * LANES + i] = V[j, r]
            X[(17 + r) * LANES + i] = A[j, r]
        Id = disk_diagonal(mass[j], radius[j])
        X[23 * LANES + i] = Id[0]
        X[24 * LANES + i] = Id[3]
        X[25 * LANES + i] = Id[5]
        bend = bend_values(alpha[k], q[j, 0], q[j, 1], q[j, 2])
        for r in range(8):
            X[(26 + r) * LANES + i] = bend[r]
    # the loop runs over every lane (a known trip count, which the compiler vectorises); the
    # lanes past the last node compute on a copy of the first, and nothing reads them
    for r in range(_IN):
        for i in range(nl, LANES):
            X[r * LANES + i] = X[r * LANES]
    return j


@jit_helper
def segment_columns(alpha, w, offs, mass, radius, q, qd, qdd, V, A, Mxi, QqT, QxT, sc):
    """Every segment's ``QqT[j]`` (3, 9) and ``QxT[j]`` (9, 9) of the module docstring, at the
    roots' twists ``V[j]`` and apparent accelerations ``A[j]`` (n + 1, 6) and with the segments'
    blocks ``Mxi[j] = M_xi`` (n, 9, 9) known; the nodes in blocks of :data:`LANES`. ``sc``
    scratch of at least :data:`LANE_SCRATCH` floats."""
    X = sc[: _IN * LANES]
    Y = sc[_IN * LANES: (_IN + _OUT) * LANES]
    acc = sc[(_IN + _OUT) * LANES: (_IN + _OUT) * LANES + 39]  # the open segment's node sums
    N = offs[q.shape[0]]
    j = 0
    for k0 in range(0, N, LANES):
        nl = min(LANES, N - k0)
        _load_lanes(alpha, w, offs, mass, radius, q, qd, qdd, V, A, k0, nl, j, X)
        _lane_columns(X, Y)
        j = _add_lanes(offs, mass, radius, qd, V, Mxi, QqT, QxT, k0, nl, j, Y, acc)


@jit_helper
def _add_lanes(offs, mass, radius, qd, V, Mxi, QqT, QxT, k0, nl, j, Y, acc):
    """Add the lanes ``0 .. nl - 1`` of ``Y`` (nodes ``k0 ..``, the first in segment ``j``) to
    their segments' columns; a segment's root twist columns once its last node is in. Returns
    the segment of the next node."""
    for i in range(nl):
        k = k0 + i
        while k >= offs[j + 1]:
            j += 1
        if k == offs[j]:
            for c in range(3):
                for r in range(9):
                    QqT[j, c, r] = 0.0
                    QxT[j, 6 + c, r] = 0.0
            acc[:] = 0.0
        for c in range(3):
            for r in range(9):
                QqT[j, c, r] += Y[(9 * c + r) * LANES + i]
                QxT[j, 6 + c, r] += Y[(27 + 9 * c + r) * LANES + i]
        for r in range(39):
            acc[r] += Y[(54 + r) * LANES + i]
        if k == offs[j + 1] - 1:
            root_twist_columns(Mxi[j], QxT[j], V[j], qd[j], disk_diagonal(mass[j], radius[j]), acc)
    return j


@jit_helper
def _row9(M, r, V0, qd):
    """``M[r] . (V0, qd)`` of a (9, 9) array."""
    return (M[r, 0] * V0[0] + M[r, 1] * V0[1] + M[r, 2] * V0[2] + M[r, 3] * V0[3] + M[r, 4] * V0[4] + M[r, 5] * V0[5]
            + M[r, 6] * qd[0] + M[r, 7] * qd[1] + M[r, 8] * qd[2])


@jit_helper
def root_twist_columns(M, QxT, V0, qd, Id, acc):
    """``QxT[:6] = dQ/dV0`` (6, 9) of a segment from its ``M = M_xi``, its rate columns
    ``QxT[6:]`` and the node sums ``acc`` (39,): ``Pd = sum w pdot`` (3), ``Z = sum w zdot z^T``
    (3, 3), ``Pi = sum w pdot p^T`` (3, 3) and ``Mdt = d/dt M_xi[:6, 6:]`` (three columns of 6),
    with ``p`` and ``z = R e_z`` each slice's centre and axis in the root frame.

    The slices are rigid bodies whose kinetic energy ``T = xi^T M_xi(q) xi / 2`` does not
    depend on the root's placement, so ``Q`` has the reduced Euler-Lagrange (Euler-Poincare)
    form ``Q = M_xi xid + dM_xi/dt xi - (0, dT/dq) + (V0 x* P, 0)``, ``P = M_xi[:6] xi`` the
    segment's momentum in the root frame. Its velocity Jacobian ``D = dQ/dxi`` is
    ``dM_xi/dt + N + Delta``, with ``N`` skew and zero in the root block and ``Delta =
    d(V0 x* P)/dxi`` in the root rows only, so

    * root block: ``D[:6, :6] = dIc/dt + [V0 x*] Ic + [. x* P]``, ``Ic = M_xi[:6, :6]``, whose
      rate is the disks' (``[[0, -m [Pd]], [m [Pd], (izz - ixx)(Z + Z^T) - m (Pi + Pi^T) +
      2 m tr(Pi)]]`` with ``I_disk = diag(ixx, ixx, izz)``);
    * slice rows: ``D[6 + c, :6] = 2 Mdt[:, c] + V0 x* M_xi[:6, 6 + c] - D[:6, 6 + c]`` (from
      ``D + D^T = 2 dM_xi/dt + Delta + Delta^T``), ``D[:6, 6 + c]`` the rate columns' root rows.

    ``Id`` (6,) the disks' diagonal inertia per unit weight.
    """
    m = Id[0]
    dz = Id[5] - Id[3]
    tr = acc[12] + acc[16] + acc[20]
    # P = M_xi[:6] xi, the segment's momentum
    P = (_row9(M, 0, V0, qd), _row9(M, 1, V0, qd), _row9(M, 2, V0, qd), _row9(M, 3, V0, qd), _row9(M, 4, V0, qd),
         _row9(M, 5, V0, qd))
    for k in range(6):
        col = vadd(force_cross(V0, (M[0, k], M[1, k], M[2, k], M[3, k], M[4, k], M[5, k])),
                   force_cross((1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0,
                                1.0 if k == 3 else 0.0, 1.0 if k == 4 else 0.0, 1.0 if k == 5 else 0.0), P))
        for r in range(6):
            QxT[k, r] = col[r]
    # dIc/dt: -m [Pd] above (the rate of -[m p]), its transpose below, the rotational block
    x0, x1, x2 = m * acc[0], m * acc[1], m * acc[2]
    QxT[4, 0] += x2
    QxT[5, 0] -= x1
    QxT[3, 1] -= x2
    QxT[5, 1] += x0
    QxT[3, 2] += x1
    QxT[4, 2] -= x0
    QxT[1, 3] -= x2
    QxT[2, 3] += x1
    QxT[0, 4] += x2
    QxT[2, 4] -= x0
    QxT[0, 5] -= x1
    QxT[1, 5] += x0
    for a in range(3):
        for b in range(3):
            QxT[3 + b, 3 + a] += (dz * (acc[3 + 3 * a + b] + acc[3 + 3 * b + a])
                                  - m * (acc[12 + 3 * a + b] + acc[12 + 3 * b + a]) + (2.0 * m * tr if a == b else 0.0))
    # the slice rows from the rate columns' root rows
    for c in range(3):
        h = force_cross(V0, (M[0, 6 + c], M[1, 6 + c], M[2, 6 + c], M[3, 6 + c], M[4, 6 + c], M[5, 6 + c]))
        for k in range(6):
            QxT[k, 6 + c] = 2.0 * acc[21 + 6 * c + k] + h[k] - QxT[6 + c, k]
