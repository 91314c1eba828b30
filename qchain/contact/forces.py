"""Contact and load forces on a chain as generalised forces (numba): the compiled passes
behind :class:`qchain.contact.Environment`.

The arm's body is the tube of radius ``r_s`` around the backbone. Each segment carries
``K`` contact points at the slice coordinates ``calpha`` (midpoints, ``(i + 1/2) / K``); each
stands for ``l0 / K`` of rest length, as a ball of radius ``r_s`` (the tube as a chain of
balls: a flat obstacle meets it within ``r_s (1 - cos(l0 / (2 K r_s)))``-deep ripples, a
fraction of the penetration at rest for ``K`` as :mod:`qchain.contact.environment` picks it).

**Law** (``law`` (8,): ``k, e, c, mu_s, mu_d, eps, v_s, 0``; docs/contact.md). A point with
backbone position ``x`` at signed distance ``phi(x)`` from an obstacle with outward normal
``n`` penetrates by ``d = r_s - phi`` and, where ``d > 0``, takes at its surface point
``x_c = x - r_s n``

* the normal force ``f_n = l k d^e max(0, 1 + c d')`` (Hunt and Crossley's, per rest length
  ``l`` of tube: N), ``d' = -n . v_c`` the rate of penetration;
* the friction force ``f_t = -mu(s) f_n v_t / sqrt(s^2 + eps^2)``, ``v_t`` the sliding velocity
  of the surface point relative to the obstacle (``s = |v_t|``), ``mu(s) = mu_d + (mu_s - mu_d) exp(-(s / v_s)^2)``:
  Coulomb's law regularised below the speed ``eps`` (m/s), static to dynamic over ``v_s``.

**Generalised forces.** A world force ``F`` at ``x_c`` is the slice wrench
``w = (R^T F, R^T ((x_c - x) x F))`` (slice frame, ``[linear; angular]``); the segment's
coordinates get ``S(alpha)^T w`` and its root the wrench ``Ad(g(alpha))^-T w``
(:func:`qchain.model.slices.phi_transpose_force`), which a backward pass carries root to root
by the tip maps, as in :func:`qchain.algorithms.recursive.rnea`. The result is ``J^T F`` for
the Jacobian ``J`` of the material point at ``x_c``: exactly the virtual work of ``F``.

Unchecked kernels (:mod:`qchain.contact.environment` checks what enters); no allocation, so
the engine calls them without reference counting.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit, view2
from ..algorithms.arrays import ChainArrays
from ..model.arc import arc_node, arc_pose, take1, take2
from ..model.slices import phi_transpose_force, slice_twist
from .distance import PARAMS, signed_distance

__all__ = ["LAW", "RECORD", "ROOT", "NODE", "beyond_reach", "contact_forces", "law_force", "load_forces", "power"]

#: entries of the packed contact law
LAW = 8
#: columns of a contact record: segment, alpha, obstacle, penetration (m), point (3, m, world),
#: normal (3, world), force on the arm (3, N, world), sliding speed (m/s); a self-contact's
#: obstacle is ``-1 - k``, ``k`` the other segment
RECORD = 15
#: a root kept for self-contact: rotation (9), origin (3), body twist (6), the segment's middle
#: point (3) and its reach (1)
ROOT = 22
#: a contact node kept for self-contact: world rotation (9), point (3), velocity (3), angular
#: velocity (3), and its slice map's R (9), p (3), S (18)
NODE = 48


@jit
def _root_step(q, qd, Rj, oj, Vj, R1, p1, S1, Sd1, tmp):
    """Root ``j`` -> root ``j + 1`` in place: world rotation ``Rj``, origin ``oj`` and body twist
    ``Vj`` of the next root (the tip of segment ``j`` at ``q``, ``qd``)."""
    arc_node(1.0, q[0], q[1], q[2], 0.0, 0.0, 0.0, R1, p1, S1, Sd1)  # (Sd1 not needed: no rates)
    slice_twist(R1, p1, S1, Vj, qd, tmp)
    for r in range(6):
        Vj[r] = tmp[r]
    for r in range(3):
        oj[r] += Rj[r, 0] * p1[0] + Rj[r, 1] * p1[1] + Rj[r, 2] * p1[2]
    for r in range(3):
        a0, a1, a2 = Rj[r, 0], Rj[r, 1], Rj[r, 2]
        for c in range(3):
            Rj[r, c] = a0 * R1[0, c] + a1 * R1[1, c] + a2 * R1[2, c]


@jit
def start(R_WB, p_WB, V0, Rj, oj, Vj, W):
    """The first root's world rotation ``Rj``, origin ``oj`` and body twist ``Vj`` from the
    base's; the root wrenches ``W`` (n + 1, 6) zeroed."""
    for r in range(3):
        oj[r] = p_WB[r]
        for c in range(3):
            Rj[r, c] = R_WB[r, c]
    for r in range(6):
        Vj[r] = V0[r]
    for j in range(W.shape[0]):
        for r in range(6):
            W[j, r] = 0.0


@jit
def _add_phi_t(R, p, S, f, wgt, W_root, tau_j, g9):
    """``(W_root, tau_j) += wgt Phi^T f``: the root wrench (6,) and the segment's generalised
    force (3,) of the slice wrench ``f`` (6,) (``g9`` (9,) scratch)."""
    for r in range(9):
        g9[r] = 0.0
    phi_transpose_force(R, p, S, f, wgt, g9)
    for r in range(6):
        W_root[r] += g9[r]
    for c in range(3):
        tau_j[c] += g9[6 + c]


@jit
def _backward(q, W, tau, F0, R1, p1, S1, Sd1, g9):
    """Carry the root wrenches ``W`` (n + 1, 6) inwards by the tip maps ``Phi_j(1)^T``:
    ``tau[j] += S_j(1)^T W[j + 1]``, ``W[j] += Ad(g_j(1))^-T W[j + 1]``; then ``F0 += W[0]``
    (the wrench on the base, base frame)."""
    n = q.shape[0]
    for j in range(n - 1, -1, -1):
        arc_node(1.0, q[j, 0], q[j, 1], q[j, 2], 0.0, 0.0, 0.0, R1, p1, S1, Sd1)
        _add_phi_t(R1, p1, S1, W[j + 1], 1.0, W[j], tau[j], g9)
    for r in range(6):
        F0[r] += W[0, r]


@jit
def _mat3(A, B, out):
    """``out = A B`` (3, 3)."""
    for r in range(3):
        for c in range(3):
            out[r, c] = A[r, 0] * B[0, c] + A[r, 1] * B[1, c] + A[r, 2] * B[2, c]


@jit
def _point(Rj, oj, p, x):
    """``x = oj + Rj p``: a point of the root frame ``(Rj, oj)`` in the world."""
    for r in range(3):
        x[r] = oj[r] + Rj[r, 0] * p[0] + Rj[r, 1] * p[1] + Rj[r, 2] * p[2]


@jit
def _world_wrench_to_slice(Rs, F, arm, f6):
    """``f6 = (Rs^T F, Rs^T (arm x F))``: the world force ``F`` (3,) at ``x + arm`` as a wrench
    at the slice origin ``x``, slice frame ``Rs`` (3, 3)."""
    mx = arm[1] * F[2] - arm[2] * F[1]
    my = arm[2] * F[0] - arm[0] * F[2]
    mz = arm[0] * F[1] - arm[1] * F[0]
    for r in range(3):
        f6[r] = Rs[0, r] * F[0] + Rs[1, r] * F[1] + Rs[2, r] * F[2]
        f6[3 + r] = Rs[0, r] * mx + Rs[1, r] * my + Rs[2, r] * mz


@jit
def power(d, e):
    """``d ** e`` for ``d >= 0``, without the general power where the exponent is the law's
    usual 1, 3/2 (Hertz) or 2, or their derivatives' 0 and 1/2: equal to rounding, several
    times cheaper."""
    if e == 1.5:
        return d * np.sqrt(d)
    if e == 1.0:
        return d
    if e == 0.5:
        return np.sqrt(d)
    if e == 2.0:
        return d * d
    if e == 0.0:
        return 1.0
    return d ** e


@jit
def law_force(law, ell, d, nrm, vc, F):
    """The world force ``F`` (3,) on the arm from a contact of penetration ``d > 0`` (m), outward
    normal ``nrm`` (3,), surface-point velocity ``vc`` (3, m/s) and rest length ``ell`` (m);
    returns the sliding speed (m/s). The law is the module docstring's."""
    k, e, c, mu_s, mu_d, eps, v_s = law[0], law[1], law[2], law[3], law[4], law[5], law[6]
    vn = vc[0] * nrm[0] + vc[1] * nrm[1] + vc[2] * nrm[2]
    fn = ell * k * power(d, e) * max(0.0, 1.0 - c * vn)  # d' = -vn
    vt0, vt1, vt2 = vc[0] - vn * nrm[0], vc[1] - vn * nrm[1], vc[2] - vn * nrm[2]
    s2 = vt0 * vt0 + vt1 * vt1 + vt2 * vt2
    s = np.sqrt(s2)
    # the transcendental calls only where they change the result (a point's cost is a few of them)
    mu = mu_d if mu_s == mu_d else mu_d + (mu_s - mu_d) * np.exp(-s2 / (v_s * v_s))
    ft = 0.0 if mu == 0.0 else mu * fn / np.sqrt(s2 + eps * eps)
    F[0] = fn * nrm[0] - ft * vt0
    F[1] = fn * nrm[1] - ft * vt1
    F[2] = fn * nrm[2] - ft * vt2
    return s


@jit
def contact_forces(arr, kind, prm, vel, law, calpha, q, qd, R_WB, p_WB, V0, tau, F0, W, roots, P, rec, sc):
    """Add the contact forces' generalised forces to ``tau`` (n, 3) and their wrench on the
    base (base frame) to ``F0`` (6,); returns the number of active contacts.

    Parameters
    ----------
    arr : ChainArrays (or the plain tuple of its fields)
    kind : (m,) int64, prm : (m, PARAMS)   the obstacles at this time (:mod:`qchain.contact.distance`).
    vel : (m, 3)                           their velocities (m/s, world; :func:`~qchain.contact.distance.move`).
    law : (LAW,)                           the packed law (module docstring).
    calpha : (K,)                          contact points' slice coordinates in (0, 1).
    q, qd : (n, 3)                         curvature coordinates and their rates.
    R_WB, p_WB : (3, 3), (3,)              the base (first root) placement in the world.
    V0 : (6,)                              the base's body twist.
    W : (n + 1, 6)                         work array (root wrenches).
    roots : (n, >= ROOT), P : (2, K, >= NODE) work arrays of self-contact (``law[7]`` set; else any).
    rec : (cap, RECORD)                    the first ``cap`` contacts are written here (cap may be 0).
    sc : scratch (``SCRATCH``).
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (algorithms/arrays.py), named here
    n = q.shape[0]
    m = kind.shape[0]
    K = calpha.shape[0]
    o = 0
    Rj, o = take2(sc, o, 3, 3)
    oj, o = take1(sc, o, 3)
    Vj, o = take1(sc, o, 6)
    R1, o = take2(sc, o, 3, 3)
    p1, o = take1(sc, o, 3)
    S1, o = take2(sc, o, 6, 3)
    Sd1, o = take2(sc, o, 6, 3)
    Rs, o = take2(sc, o, 3, 3)
    x, o = take1(sc, o, 3)
    nrm, o = take1(sc, o, 3)
    Vs, o = take1(sc, o, 6)
    vc, o = take1(sc, o, 3)
    arm, o = take1(sc, o, 3)
    F, o = take1(sc, o, 3)
    f6, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    tmp, o = take1(sc, o, 6)
    near, o = take1(sc, o, m)
    self_contact = law[7] > 0.0
    if not self_contact and beyond_reach(arr.radius, q, kind, prm, p_WB, nrm):
        return 0
    start(R_WB, p_WB, V0, Rj, oj, Vj, W)
    count = 0
    for j in range(n):
        l, ux, uy = q[j, 0], q[j, 1], q[j, 2]
        r_s = arr.radius[j]
        # broad phase: every point of the arc lies within l / 2 of its middle, and a signed
        # distance is 1-Lipschitz, so an obstacle farther than l / 2 + r_s from it is not touched
        arc_pose(0.5, l, ux, uy, R1, p1)
        _point(Rj, oj, p1, x)
        reach = 0.5 * abs(l) + r_s
        if self_contact:
            _keep_root(roots[j], Rj, oj, Vj, x, reach)
        any_near = False
        for b in range(m):
            near[b] = 1.0 if signed_distance(kind[b], prm[b], x, nrm) < reach else 0.0
            any_near = any_near or near[b] > 0.0
        if any_near:
            ell = arr.l0[j] / K
            for i in range(K):
                a = calpha[i]
                arc_node(a, l, ux, uy, 0.0, 0.0, 0.0, R1, p1, S1, Sd1)
                _point(Rj, oj, p1, x)
                moving = False  # the slice's world rotation and twist, made at its first contact
                for b in range(m):
                    if near[b] == 0.0:
                        continue
                    d = r_s - signed_distance(kind[b], prm[b], x, nrm)
                    if d <= 0.0:
                        continue
                    if not moving:
                        _mat3(Rj, R1, Rs)
                        slice_twist(R1, p1, S1, Vj, qd[j], Vs)
                        moving = True
                    # the surface point x - r_s n: its world velocity v + w x arm
                    for r in range(3):
                        arm[r] = -r_s * nrm[r]
                    for r in range(3):
                        vc[r] = Rs[r, 0] * Vs[0] + Rs[r, 1] * Vs[1] + Rs[r, 2] * Vs[2]
                        tmp[r] = Rs[r, 0] * Vs[3] + Rs[r, 1] * Vs[4] + Rs[r, 2] * Vs[5]
                    vc[0] += tmp[1] * arm[2] - tmp[2] * arm[1] - vel[b, 0]  # relative to the obstacle
                    vc[1] += tmp[2] * arm[0] - tmp[0] * arm[2] - vel[b, 1]
                    vc[2] += tmp[0] * arm[1] - tmp[1] * arm[0] - vel[b, 2]
                    slide = law_force(law, ell, d, nrm, vc, F)
                    _world_wrench_to_slice(Rs, F, arm, f6)
                    _add_phi_t(R1, p1, S1, f6, 1.0, W[j], tau[j], g9)
                    if count < rec.shape[0]:
                        row = rec[count]
                        row[0], row[1], row[2], row[3] = j, a, b, d
                        for r in range(3):
                            row[4 + r] = x[r] + arm[r]
                            row[7 + r] = nrm[r]
                            row[10 + r] = F[r]
                        row[13] = slide
                        row[14] = 0.0
                    count += 1
        _root_step(q[j], qd[j], Rj, oj, Vj, R1, p1, S1, Sd1, tmp)
    if self_contact:
        count = _self_contact(arr, law, calpha, q, qd, roots, P, W, tau, rec, count, sc[o:])
    if count > 0:  # (no contact: every root wrench is zero)
        _backward(q, W, tau, F0, R1, p1, S1, Sd1, g9)
    return count


@jit
def beyond_reach(radius, q, kind, prm, p_WB, nrm):
    """Whether every obstacle (``kind``, ``prm``) lies beyond the arm's reach: the whole arm
    lies within its length ``sum |l_j|`` plus its widest radius of the base origin ``p_WB``, and
    a signed distance is 1-Lipschitz; so an environment beyond that costs one distance per
    obstacle. ``radius`` (n,) m, ``q`` (n, 3) curvature coordinates, ``nrm`` (3,) scratch."""
    reach = 0.0
    widest = 0.0
    for j in range(q.shape[0]):
        reach += abs(q[j, 0])
        widest = max(widest, radius[j])
    for b in range(kind.shape[0]):
        if signed_distance(kind[b], prm[b], p_WB, nrm) <= reach + widest:
            return False
    return True


@jit
def load_forces(seg, alpha, wrench, local, q, R_WB, p_WB, tau, F0, W, sc):
    """Add the generalised forces of point loads to ``tau`` (n, 3) and their base wrench to
    ``F0`` (6,).

    Load ``i`` is the wrench ``wrench[i]`` (6,: force N, moment N m) at the backbone point
    ``alpha[i]`` of segment ``seg[i]``, in the world frame, or in the slice's own frame
    where ``local[i]`` (a follower load). ``q`` (n, 3) curvature coordinates; ``W`` (n + 1, 6)
    work array; ``sc`` scratch.
    """
    n = q.shape[0]
    L = seg.shape[0]
    o = 0
    Rj, o = take2(sc, o, 3, 3)
    oj, o = take1(sc, o, 3)
    Vj, o = take1(sc, o, 6)
    R1, o = take2(sc, o, 3, 3)
    p1, o = take1(sc, o, 3)
    S1, o = take2(sc, o, 6, 3)
    Sd1, o = take2(sc, o, 6, 3)
    Rs, o = take2(sc, o, 3, 3)
    f6, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    tmp, o = take1(sc, o, 6)
    zero3, o = take1(sc, o, 3)
    for r in range(6):
        tmp[r] = 0.0
    for r in range(3):
        zero3[r] = 0.0
    start(R_WB, p_WB, tmp, Rj, oj, Vj, W)  # loads need no twists
    for j in range(n):
        for i in range(L):
            if seg[i] != j:
                continue
            arc_node(alpha[i], q[j, 0], q[j, 1], q[j, 2], 0.0, 0.0, 0.0, R1, p1, S1, Sd1)
            if local[i]:
                for r in range(6):
                    f6[r] = wrench[i, r]
            else:
                _mat3(Rj, R1, Rs)
                _world_wrench_to_slice(Rs, wrench[i, :3], zero3, f6)
                for r in range(3):
                    f6[3 + r] += Rs[0, r] * wrench[i, 3] + Rs[1, r] * wrench[i, 4] + Rs[2, r] * wrench[i, 5]
            _add_phi_t(R1, p1, S1, f6, 1.0, W[j], tau[j], g9)
        _root_step(q[j], zero3, Rj, oj, Vj, R1, p1, S1, Sd1, tmp)
    _backward(q, W, tau, F0, R1, p1, S1, Sd1, g9)


@jit
def _keep_root(row, Rj, oj, Vj, mid, reach):
    """Keep a root's frame, twist and its segment's bounding ball in ``row`` (ROOT,)."""
    for r in range(3):
        for c in range(3):
            row[3 * r + c] = Rj[r, c]
        row[9 + r] = oj[r]
        row[18 + r] = mid[r]
    for r in range(6):
        row[12 + r] = Vj[r]
    row[21] = reach


@jit
def _keep_nodes(root, q, qd, calpha, out, tmp):
    """Every contact node of a segment (its root row ``root``, coordinates ``q``, rates ``qd``)
    into ``out`` (K, NODE): ``[0:9]`` world rotation, ``[9:12]`` point, ``[12:15]`` velocity,
    ``[15:18]`` angular velocity (world), ``[18:27]``, ``[27:30]``, ``[30:48]`` the slice's
    ``R``, ``p``, ``S`` in its root (for ``Phi^T``). ``tmp`` (24,) scratch."""
    Rj = view2(root[0:9], 3, 3)
    for i in range(calpha.shape[0]):
        row = out[i]
        Rs = view2(row[0:9], 3, 3)
        Rn = view2(row[18:27], 3, 3)
        pn = row[27:30]
        Sn = view2(row[30:48], 6, 3)
        arc_node(calpha[i], q[0], q[1], q[2], qd[0], qd[1], qd[2], Rn, pn, Sn, view2(tmp[0:18], 6, 3))
        slice_twist(Rn, pn, Sn, root[12:18], qd, tmp[18:24])
        _mat3(Rj, Rn, Rs)
        _point(Rj, root[9:12], pn, row[9:12])
        for r in range(3):
            row[12 + r] = Rs[r, 0] * tmp[18] + Rs[r, 1] * tmp[19] + Rs[r, 2] * tmp[20]
            row[15 + r] = Rs[r, 0] * tmp[21] + Rs[r, 1] * tmp[22] + Rs[r, 2] * tmp[23]


@jit
def _near_segments(ra, rb):
    """Whether two segments' bounding balls (root rows ``ra``, ``rb``) overlap."""
    d2 = (ra[18] - rb[18]) ** 2 + (ra[19] - rb[19]) ** 2 + (ra[20] - rb[20]) ** 2
    return d2 < (ra[21] + rb[21]) ** 2


@jit
def _self_contact(arr, law, calpha, q, qd, roots, P, W, tau, rec, count, sc):
    """Add the contact forces between the balls of segments at least two apart (equal and
    opposite, the law on the surface points' relative velocity) to ``W`` and ``tau``; returns
    the contact count. ``roots`` (n, ROOT) as the forward loop kept them; ``P`` (2, K, NODE)."""
    n = q.shape[0]
    K = calpha.shape[0]
    o = 0
    nrm, o = take1(sc, o, 3)
    arm_a, o = take1(sc, o, 3)
    arm_b, o = take1(sc, o, 3)
    vc, o = take1(sc, o, 3)
    F, o = take1(sc, o, 3)
    f6, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    tmp, o = take1(sc, o, 24)
    for i in range(n):
        for j in range(i + 2, n):
            if not _near_segments(roots[i], roots[j]):
                continue
            _keep_nodes(roots[i], q[i], qd[i], calpha, P[0], tmp)
            _keep_nodes(roots[j], q[j], qd[j], calpha, P[1], tmp)
            ri, rj = arr.radius[i], arr.radius[j]
            ell = 0.5 * (arr.l0[i] + arr.l0[j]) / K
            for a in range(K):
                A = P[0, a]
                for b in range(K):
                    B = P[1, b]
                    dx, dy, dz = A[9] - B[9], A[10] - B[10], A[11] - B[11]
                    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                    d = ri + rj - dist
                    if d <= 0.0 or dist == 0.0:
                        continue
                    nrm[0], nrm[1], nrm[2] = dx / dist, dy / dist, dz / dist  # from b to a
                    # both forces act at the point midway between the two surfaces, so that
                    # the pair's net force and moment vanish (momentum is kept)
                    ha = 0.5 * (ri + dist - rj)
                    hb = 0.5 * (dist - ri + rj)
                    for r in range(3):
                        arm_a[r] = -ha * nrm[r]
                        arm_b[r] = hb * nrm[r]
                    vc[0] = (A[12] + A[16] * arm_a[2] - A[17] * arm_a[1]) - (B[12] + B[16] * arm_b[2] - B[17] * arm_b[1])
                    vc[1] = (A[13] + A[17] * arm_a[0] - A[15] * arm_a[2]) - (B[13] + B[17] * arm_b[0] - B[15] * arm_b[2])
                    vc[2] = (A[14] + A[15] * arm_a[1] - A[16] * arm_a[0]) - (B[14] + B[15] * arm_b[1] - B[16] * arm_b[0])
                    slide = law_force(law, ell, d, nrm, vc, F)
                    _world_wrench_to_slice(view2(A[0:9], 3, 3), F, arm_a, f6)
                    _add_phi_t(view2(A[18:27], 3, 3), A[27:30], view2(A[30:48], 6, 3), f6, 1.0, W[i], tau[i], g9)
                    for r in range(3):
                        F[r] = -F[r]
                    _world_wrench_to_slice(view2(B[0:9], 3, 3), F, arm_b, f6)
                    _add_phi_t(view2(B[18:27], 3, 3), B[27:30], view2(B[30:48], 6, 3), f6, 1.0, W[j], tau[j], g9)
                    if count < rec.shape[0]:
                        row = rec[count]
                        row[0], row[1], row[2], row[3] = i, calpha[a], -1 - j, d
                        for r in range(3):
                            row[4 + r] = A[9 + r] + arm_a[r]
                            row[7 + r] = nrm[r]
                            row[10 + r] = -F[r]
                        row[13] = slide
                        row[14] = 0.0
                    count += 1
    return count
