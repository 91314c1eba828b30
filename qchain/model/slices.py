"""Integrals over the slices of one segment (numba): M_xi and the slice Newton-Euler force.

A segment is a continuum of rigid uniform disks (docs/model.md sections 3 and 4): with
``Phi(alpha) = [Ad(g(alpha))^-1, S(alpha)]`` (6 x 9), ``M_xi = int_0^1 Phi^T I Phi dalpha``
(:func:`segment_mass`) and ``Q = M_xi xidot + C_xi xi`` (:func:`segment_newton_euler`); the
input matrix and the elastic and damping laws: sections 5 and 9. Everything is in curvature
coordinates ``q = (l, ux, uy)``; integrals use the Gauss-Legendre nodes ``alpha`` with
weights ``w`` (summing to 1).

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): call the checked API.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit, jit_helper, jit_inline
from .arc import SCRATCH, arc_node, arc_node_bias, arc_node_derivatives, take1, take2, take3
from .spatial_kernels import ad_force, ad_inv_twist, column_dot6, matvec63, motion_cross, put6, sub6, vadd

__all__ = ["CHAMBER_ANGLES", "input_matrix_c", "pressure_jacobian_c", "elastic_gradient_c", "elastic_hessian_c",
           "law_gradient_c", "law_hessian_c", "law_energy_c", "rest_damping_c", "domain_violation", "segment_slices", "segment_mass", "segment_newton_euler", "phi_transpose_force", "phi_matrix", "slice_twist"]


# The node loops' small helpers (slice_twist, phi_transpose_force, mass_node, mass_finish) are
# inlined into their callers (``jit_inline``): as calls, passing their array arguments cost about
# a fifth of a forward-dynamics call (docs/benchmarks/README.md, "Speed of a chain").
@jit_inline
def slice_twist(R, p, S, V0, qd, out):
    """``out = Ad(g)^-1 V0 + S qd``: the slice body twist (6,) (docs/model.md section 2)."""
    put6(out, vadd(ad_inv_twist(R, p, V0), matvec63(S, qd)))


@jit_helper
def disk_diagonal(mass, radius):
    """``(m, m, m, ixx, ixx, izz)``: the diagonal of a uniform disk's spatial inertia in its own
    frame, ``ixx = m r^2 / 4``, ``izz = m r^2 / 2`` (docs/model.md section 3; compiled code)."""
    ixx = 0.25 * mass * radius * radius
    return (mass, mass, mass, ixx, ixx, 2.0 * ixx)


@jit_inline
def phi_transpose_force(R, p, S, f, wgt, out):
    """``out += wgt * Phi^T f``: ``(Ad(g)^-T f, S^T f)`` with ``Ad^-T (fl, fa) = (R fl, p x R fl + R fa)``."""
    # every entry read before any is written: ``out`` may share memory with the arguments as
    # far as the compiler knows, and a store between the reads would make it load them again
    h = ad_force(R, p, f)
    s0 = column_dot6(S, 0, f)
    s1 = column_dot6(S, 1, f)
    s2 = column_dot6(S, 2, f)
    out[0] += wgt * h[0]
    out[1] += wgt * h[1]
    out[2] += wgt * h[2]
    out[3] += wgt * h[3]
    out[4] += wgt * h[4]
    out[5] += wgt * h[5]
    out[6] += wgt * s0
    out[7] += wgt * s1
    out[8] += wgt * s2


@jit
def phi_matrix(R, p, S, Phi):
    """``Phi = [Ad(g)^-1, S]`` (6, 9) (docs/model.md section 2)."""
    for r in range(3):
        for c in range(3):
            Phi[r, c] = R[c, r]
            Phi[3 + r, 3 + c] = R[c, r]
            Phi[3 + r, c] = 0.0
    # -R^T [p]
    for r in range(3):
        Phi[r, 3] = R[2, r] * p[1] - R[1, r] * p[2]
        Phi[r, 4] = R[0, r] * p[2] - R[2, r] * p[0]
        Phi[r, 5] = R[1, r] * p[0] - R[0, r] * p[1]
    for r in range(6):
        for c in range(3):
            Phi[r, 6 + c] = S[r, c]


@jit
def segment_slices(alpha, w, mass, radius, q, xi, xid, want_mass, M, Q, sc):
    """One pass over the nodes of a segment (curvature coordinates).

    ``Q[:] = int Phi^T (I a + V x* I V) dalpha`` (9,) ``= M_xi xid + C_xi xi``; with
    ``want_mass`` also ``M[:] = M_xi`` (9, 9), the paper's eq. (6) (docs/model.md section 4). ``xi = (V_root, qdot)``, ``xid = (A_root, qddot)``;
    ``sc`` is scratch (:data:`qchain.model.arc.SCRATCH`).
    """
    _segment_slices(alpha, w, mass, radius, q, xi, xid, want_mass, M, Q, sc)


@jit_helper
def _segment_slices(alpha, w, mass, radius, q, xi, xid, want_mass, M, Q, sc):
    """:func:`segment_slices`, for the kernels: compiled once for both values of ``want_mass``
    (a ``jit`` function is compiled once per constant ``True``/``False`` its callers pass)."""
    o = 0
    R, o = take2(sc, o, 3, 3)
    p, o = take1(sc, o, 3)
    S, o = take2(sc, o, 6, 3)
    sd, o = take1(sc, o, 6)
    V, o = take1(sc, o, 6)
    V0 = xi[:6]
    qd = xi[6:]
    A0 = xid[:6]
    qdd = xid[6:]
    Vr, o = take1(sc, o, 6)  # Ad^-1 V0
    a, o = take1(sc, o, 6)
    rel, o = take1(sc, o, 6)
    f, o = take1(sc, o, 6)
    zero3, o = take1(sc, o, 3)
    zero3[:] = 0.0
    m, _, _, ixx, _, izz = disk_diagonal(mass, radius)
    Id, o = take1(sc, o, 6)
    Id[0] = Id[1] = Id[2] = m
    Id[3] = Id[4] = ixx
    Id[5] = izz
    Q[:] = 0.0
    if want_mass:
        M[:, :] = 0.0
    wsum = 0.0
    mp, o = take1(sc, o, 3)  # sum w m p
    mp[:] = 0.0
    Irot, o = take2(sc, o, 3, 3)  # sum w (R I_d R^T - m [p]^2)
    Irot[:, :] = 0.0
    fc, o = take1(sc, o, 6)
    accelerating = False  # the mass matrix's and the bias force's passes have xid = 0
    for r in range(9):
        if xid[r] != 0.0:
            accelerating = True
    for k in range(alpha.shape[0]):
        arc_node_bias(alpha[k], q[0], q[1], q[2], qd[0], qd[1], qd[2], R, p, S, sd)
        if want_mass:
            wsum += w[k]
            mass_node(R, p, S, Id, w[k], M, mp, Irot, fc)
        slice_twist(R, p, S, V0, zero3, Vr)
        for r in range(6):
            rel[r] = S[r, 0] * qd[0] + S[r, 1] * qd[1] + S[r, 2] * qd[2]
            V[r] = Vr[r] + rel[r]
        # a = Ad^-1 A0 + S qdd + Sd qd - rel x Vr
        if accelerating:
            slice_twist(R, p, S, A0, qdd, a)
            for r in range(6):
                a[r] += sd[r]
        else:
            for r in range(6):
                a[r] = sd[r]
        sub6(a, motion_cross(rel, Vr))
        # h = I V; f = I a + V x* h, V x* h = (w x hl, v x hl + w x ha)
        hl0, hl1, hl2 = m * V[0], m * V[1], m * V[2]
        ha0, ha1, ha2 = ixx * V[3], ixx * V[4], izz * V[5]
        f[0] = m * a[0] + V[4] * hl2 - V[5] * hl1
        f[1] = m * a[1] + V[5] * hl0 - V[3] * hl2
        f[2] = m * a[2] + V[3] * hl1 - V[4] * hl0
        f[3] = ixx * a[3] + V[1] * hl2 - V[2] * hl1 + V[4] * ha2 - V[5] * ha1
        f[4] = ixx * a[4] + V[2] * hl0 - V[0] * hl2 + V[5] * ha0 - V[3] * ha2
        f[5] = izz * a[5] + V[0] * hl1 - V[1] * hl0 + V[3] * ha1 - V[4] * ha0
        phi_transpose_force(R, p, S, f, w[k], Q)
    if want_mass:
        mass_finish(M, mp, Irot, m * wsum)


@jit_inline
def mass_node(R, p, S, Id, wk, M, mp, Irot, fc):
    """One node's share of ``M_xi = int Phi^T I Phi`` (weight ``wk``): the root block is the
    disk's spatial inertia moved to the root (``[[m, -m[p]], [m[p], R I_d R^T - m[p]^2]]``),
    gathered in ``mp`` (3,) and ``Irot`` (3, 3); the q columns ``Phi^T (I S_c)`` go to
    ``M[:, 6:]``. ``Id`` (6,) is the disk's diagonal inertia, ``fc`` (6,) scratch."""
    m = Id[0]
    ixx = Id[3]
    izz = Id[5]
    pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
    for ia in range(3):
        mp[ia] += wk * m * p[ia]
        for ib in range(3):
            Irot[ia, ib] += wk * ((izz - ixx) * R[ia, 2] * R[ib, 2] - m * p[ia] * p[ib])
        Irot[ia, ia] += wk * (ixx + m * pp)
    for cc in range(3):
        for r in range(6):
            fc[r] = Id[r] * S[r, cc]
        # M[:, 6 + cc] += wk * Phi^T fc: phi_transpose_force written out, as a column view of M
        # (non-contiguous) would compile phi_transpose_force a second time
        k = 6 + cc
        l0 = R[0, 0] * fc[0] + R[0, 1] * fc[1] + R[0, 2] * fc[2]
        l1 = R[1, 0] * fc[0] + R[1, 1] * fc[1] + R[1, 2] * fc[2]
        l2 = R[2, 0] * fc[0] + R[2, 1] * fc[1] + R[2, 2] * fc[2]
        M[0, k] += wk * l0
        M[1, k] += wk * l1
        M[2, k] += wk * l2
        M[3, k] += wk * (p[1] * l2 - p[2] * l1 + R[0, 0] * fc[3] + R[0, 1] * fc[4] + R[0, 2] * fc[5])
        M[4, k] += wk * (p[2] * l0 - p[0] * l2 + R[1, 0] * fc[3] + R[1, 1] * fc[4] + R[1, 2] * fc[5])
        M[5, k] += wk * (p[0] * l1 - p[1] * l0 + R[2, 0] * fc[3] + R[2, 1] * fc[4] + R[2, 2] * fc[5])
        for c in range(3):
            acc = 0.0
            for r in range(6):
                acc += S[r, c] * fc[r]
            M[6 + c, k] += wk * acc


@jit_inline
def mass_finish(M, mp, Irot, mtot):
    """Complete ``M_xi`` from the sums of :func:`mass_node` (``mtot`` the weighted mass)."""
    for ia in range(3):
        M[ia, ia] = mtot
        for ib in range(3):
            M[3 + ia, 3 + ib] = Irot[ia, ib]
    M[0, 4] = mp[2]  # -[m p]
    M[0, 5] = -mp[1]
    M[1, 3] = -mp[2]
    M[1, 5] = mp[0]
    M[2, 3] = mp[1]
    M[2, 4] = -mp[0]
    for ia in range(3):
        for ib in range(3):
            M[3 + ia, ib] = M[ib, 3 + ia]
    for r in range(6):
        for cc in range(3):
            M[6 + cc, r] = M[r, 6 + cc]


@jit
def segment_mass(alpha, w, mass, radius, q, M):
    """``M[:] = M_xi(q)`` (9, 9) in curvature coordinates, by quadrature over the nodes: the
    paper's eq. (6) (docs/model.md section 4)."""
    Q = np.empty(9)
    z = np.zeros(9)
    # copies: a Segment's nodes are read-only arrays, which numba types apart from the writable
    # ones of the kernels (one more compile of _segment_slices)
    _segment_slices(alpha.copy(), w.copy(), mass, radius, q.copy(), z, z, True, M, Q, np.empty(SCRATCH))


@jit
def segment_newton_euler(alpha, w, mass, radius, q, xi, xid, Q):
    """``Q[:] = M_xi xid + C_xi xi`` (9,), curvature coordinates (see :func:`segment_slices`;
    docs/model.md section 4)."""
    M = np.empty((1, 1))
    _segment_slices(alpha.copy(), w.copy(), mass, radius, q.copy(), xi.copy(), xid.copy(), False, M, Q,
                    np.empty(SCRATCH))


# --------------------------------------------------------------------------- segment forces
#: Chamber angles phi_i about the root z axis (rad): chamber 1 on +x (the paper's
#: ``phi_i = 0, 2pi/3, -2pi/3``, section IV-B; docs/model.md section 1).
CHAMBER_ANGLES = np.array([0.0, 2.0 * np.pi / 3.0, -2.0 * np.pi / 3.0])
_COS_PHI = np.cos(CHAMBER_ANGLES)
_SIN_PHI = np.sin(CHAMBER_ANGLES)


@jit
def input_matrix_c(q, A_ch, r_ch, paper_act, B, sc):
    """``B[:] =`` the input matrix (3, 3) in curvature coordinates, column i = chamber i:
    the ``B`` of the paper's eq. (8) (docs/model.md section 5, which derives both models).

    Volume model: ``A_ch d l_i/dq`` with ``l_i = l (1 - r_ch (ux cos phi_i + uy sin phi_i))``.
    Paper model (``paper_act``): ``A_ch (S_z(1) + S_w(1) . (r_ch sin phi_i, -r_ch cos phi_i, 0))``,
    the tip-plate force at the chamber centre along the tip normal, through the tip Jacobian.
    """
    l, ux, uy = q[0], q[1], q[2]
    if paper_act:
        o = 0
        R, o = take2(sc, o, 3, 3)
        pt, o = take1(sc, o, 3)
        S, o = take2(sc, o, 6, 3)
        Sd, o = take2(sc, o, 6, 3)
        arc_node(1.0, l, ux, uy, 0.0, 0.0, 0.0, R, pt, S, Sd)
        for i in range(3):
            for a in range(3):
                B[a, i] = A_ch * (S[2, a] + S[3, a] * r_ch * _SIN_PHI[i] - S[4, a] * r_ch * _COS_PHI[i])
    else:
        for i in range(3):
            B[0, i] = A_ch * (1.0 - r_ch * (ux * _COS_PHI[i] + uy * _SIN_PHI[i]))
            B[1, i] = -A_ch * l * r_ch * _COS_PHI[i]
            B[2, i] = -A_ch * l * r_ch * _SIN_PHI[i]


@jit
def elastic_gradient_c(q, l0, EI, EA, g):
    """``g[:] = dU_el/dq`` (3,), ``U_el = 1/2 EI l^2 |u|^2 / l0 + 1/2 EA (l - l0)^2 / l0``
    (docs/model.md section 9)."""
    l, ux, uy = q[0], q[1], q[2]
    g[0] = EI * l * (ux * ux + uy * uy) / l0 + EA * (l - l0) / l0
    g[1] = EI * l * l * ux / l0
    g[2] = EI * l * l * uy / l0


@jit
def elastic_hessian_c(q, l0, EI, EA, H):
    """``H[:] = d^2 U_el/dq^2`` (3, 3) of the material law of :func:`elastic_gradient_c`
    (docs/model.md section 9)."""
    l, ux, uy = q[0], q[1], q[2]
    H[0, 0] = EI * (ux * ux + uy * uy) / l0 + EA / l0
    H[0, 1] = H[1, 0] = 2.0 * EI * l * ux / l0
    H[0, 2] = H[2, 0] = 2.0 * EI * l * uy / l0
    H[1, 1] = H[2, 2] = EI * l * l / l0
    H[1, 2] = H[2, 1] = 0.0


@jit
def law_gradient_c(q, l0, EI, EA, linear, K, q_rest, g):
    """``g[:] = dU_el/dq`` (3,) of a segment's elastic law: the linear law ``K (q - q_rest)``
    where ``linear``, else the material law (:func:`elastic_gradient_c`)."""
    if linear:
        for a in range(3):
            g[a] = K[a, 0] * (q[0] - q_rest[0]) + K[a, 1] * (q[1] - q_rest[1]) + K[a, 2] * (q[2] - q_rest[2])
    else:
        elastic_gradient_c(q, l0, EI, EA, g)


@jit
def law_hessian_c(q, l0, EI, EA, linear, K, H):
    """``H[:] = d^2 U_el/dq^2`` (3, 3) of a segment's elastic law: ``K`` where ``linear``, else
    :func:`elastic_hessian_c`."""
    if linear:
        for a in range(3):
            for b in range(3):
                H[a, b] = K[a, b]
    else:
        elastic_hessian_c(q, l0, EI, EA, H)


@jit
def law_energy_c(q, l0, EI, EA, linear, K, q_rest):
    """``U_el`` (J) of a segment's elastic law (:func:`law_gradient_c`)."""
    if linear:
        acc = 0.0
        for a in range(3):
            for b in range(3):
                acc += (q[a] - q_rest[a]) * K[a, b] * (q[b] - q_rest[b])
        return 0.5 * acc
    l, ux, uy = q[0], q[1], q[2]
    return 0.5 * EI * (ux * ux + uy * uy) * l * l / l0 + 0.5 * EA * (l - l0) ** 2 / l0


@jit
def rest_damping_c(l0, EI, EA, beta, D):
    """``D[:] = beta K(q0)`` (3, 3): stiffness-proportional damping, ``K(q0) = diag(EA/l0, EI l0,
    EI l0)`` the material law's stiffness at the straight rest pose (docs/model.md section 9)."""
    D[:, :] = 0.0
    D[0, 0] = beta * EA / l0
    D[1, 1] = beta * EI * l0
    D[2, 2] = beta * EI * l0


@jit
def pressure_jacobian_c(q, p, A_ch, r_ch, paper_act, Kp, sc):
    """``Kp[:] = d(B(q) p)/dq`` (3, 3), curvature coordinates, both actuation models of
    :func:`input_matrix_c` (the paper's through the tip Jacobian's exact derivative;
    docs/model.md section 5)."""
    Pc = 0.0
    Ps = 0.0
    P = 0.0
    for i in range(3):
        Pc += _COS_PHI[i] * p[i]
        Ps += _SIN_PHI[i] * p[i]
        P += p[i]
    if paper_act:
        o = 0
        dS, o = take3(sc, o, 3, 6, 3)
        K, o = take2(sc, o, 3, 6)
        arc_node_derivatives(1.0, q[0], q[1], q[2], 0.0, 0.0, 0.0, dS, K)
        for a in range(3):
            for c in range(3):
                Kp[a, c] = A_ch * (P * dS[c, 2, a] + r_ch * Ps * dS[c, 3, a] - r_ch * Pc * dS[c, 4, a])
    else:
        mx = A_ch * r_ch * Pc
        my = A_ch * r_ch * Ps
        Kp[0, 0] = 0.0
        Kp[0, 1] = Kp[1, 0] = -mx
        Kp[0, 2] = Kp[2, 0] = -my
        Kp[1, 1] = Kp[1, 2] = Kp[2, 1] = Kp[2, 2] = 0.0


@jit
def domain_violation(l, a, b, radius, paper):
    """The model's domain rule for one segment configuration, ``(l, ux, uy)`` or, with
    ``paper``, ``(l, psi, kappa)`` (``a, b``): 0 inside; 1 where ``l`` is not > 0; 2 where the
    paper's ``kappa < 0``; 3 where ``|kappa| r_s >= 1`` (the inner fibre length vanishes and the
    density field, eq. (5), diverges; docs/model.md sections 1 and 3)."""
    if not (l > 0.0):
        return 1
    if paper:
        k = b
        if k < 0.0:
            return 2
    else:
        k = np.sqrt(a * a + b * b)
    if not (abs(k) * radius < 1.0):
        return 3
    return 0
