"""Exact derivatives of the environment's generalised force (numba): ``d tau_env / dq`` and
``d tau_env / dv`` of :func:`qchain.contact.forces.contact_forces` and
:func:`~qchain.contact.forces.load_forces`, by forward (tangent) propagation through every
step of the passes, differentiated by hand (docs/contact.md, "Derivatives").

A direction ``(dq, dqd)`` of the segment coordinates and rates, with ``eta0`` the base's
pose variation (a body twist, what ``Chain.integrate`` adds for a floating base) and ``dV0``
its body twist's, moves

* a root by ``eta_{j+1} = Ad(g_tip)^-1 eta_j + S(1) dq_j`` and its twist by
  ``dV_{j+1} = Ad(g_tip)^-1 dV_j + S(1) dqd_j - ad(S(1) dq_j) Ad(g_tip)^-1 V_j + dS(1)[dq_j] qd_j``
  (``d Ad(g e^z)^-1 = -ad(z) Ad(g)^-1``), and a contact node likewise with ``S(alpha)``;
* a world point by ``R eta_lin``, a rotation by ``R [eta_ang]x``;
* a signed distance's normal by its Hessian (:func:`_normal_tangent`, shape by shape);
* the law's forces by the chain rule through ``d``, ``d'``, the sliding velocity and
  ``mu(s)`` (:func:`_law_tangent`);
* a generalised force ``Phi^T w`` by ``Phi^T dw`` plus ``Ad^-T (zeta x* w)`` on the root and
  ``dS[dq]^T w`` on the coordinates (``zeta = S dq``).

The result is the exact derivative of the smooth branch at the state: at the onset of a
contact (``d = 0``) and where ``1 + c d'`` changes sign it is one of the one-sided derivatives.
``tests/test_contact.py`` checks it against central differences. Curvature coordinates only.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit, view2, view3
from ..algorithms.arrays import ChainArrays
from ..model.arc import arc_node, arc_node_derivatives, arc_pose, take1, take2, take3
from ..model.slices import phi_transpose_force, slice_twist
from ..model.spatial_kernels import ad_force, add6, force_cross, motion_cross, put6, sub6
from .distance import CAPSULE, CYLINDER, HALFSPACE, SPHERE, signed_distance
from .forces import ROOT, _keep_root, _mat3, _near_segments, _point, _world_wrench_to_slice, power, start

#: a contact node kept for the self-contact tangent: world rotation (9), point (3), velocity
#: (3), angular velocity (3), the slice's R (9), p (3), S (18) in its root, then the changes of
#: the point (3), velocity (3), angular velocity (3), the pose variation (6), S dq (6), dS/dq (54)
NODE_T = 123

__all__ = ["environment_tangent", "environment_derivatives", "NODE_T"]


@jit
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@jit
def _rt(R, x, out):
    """``out = R^T x`` (3,)."""
    for r in range(3):
        out[r] = R[0, r] * x[0] + R[1, r] * x[1] + R[2, r] * x[2]


@jit
def _rx(R, x, out):
    """``out = R x`` (3,)."""
    for r in range(3):
        out[r] = R[r, 0] * x[0] + R[r, 1] * x[1] + R[r, 2] * x[2]


@jit
def _project_out(n, y, scale, out):
    """``out = (y - n (n . y)) / scale``: the derivative of a unit vector ``y / |y|`` at
    ``|y| = scale`` along ``y``'s change ``y`` (here passed as the change)."""
    d = n[0] * y[0] + n[1] * y[1] + n[2] * y[2]
    for r in range(3):
        out[r] = (y[r] - n[r] * d) / scale


@jit
def _normal_tangent(kind, prm, x, n, dx, dn, tmp):
    """``dn`` (3,): the change of the outward normal ``n`` at ``x`` along ``dx`` (the signed
    distance's Hessian times ``dx``; zero on flat faces)."""
    for r in range(3):
        dn[r] = 0.0
    if kind == HALFSPACE:
        return
    if kind == SPHERE:
        rho = np.sqrt((x[0] - prm[0]) ** 2 + (x[1] - prm[1]) ** 2 + (x[2] - prm[2]) ** 2)
        if rho > 0.0:
            _project_out(n, dx, rho, dn)
        return
    if kind == CAPSULE or kind == CYLINDER:
        ax, ay, az = prm[3] - prm[0], prm[4] - prm[1], prm[5] - prm[2]
        L = np.sqrt(ax * ax + ay * ay + az * az)
        ux, uy, uz = ax / L, ay / L, az / L
        s = (x[0] - prm[0]) * ux + (x[1] - prm[1]) * uy + (x[2] - prm[2]) * uz
        du = dx[0] * ux + dx[1] * uy + dx[2] * uz
        if kind == CAPSULE:
            sc = min(L, max(0.0, s))
            inner = 0.0 < s < L
            for r in range(3):  # x minus its nearest axis point, and its change
                tmp[r] = x[r] - prm[r] - sc * (ux, uy, uz)[r]
                tmp[3 + r] = dx[r] - (du * (ux, uy, uz)[r] if inner else 0.0)
            rho = np.sqrt(tmp[0] ** 2 + tmp[1] ** 2 + tmp[2] ** 2)
            if rho > 0.0:
                _project_out(n, tmp[3:6], rho, dn)
            return
        # cylinder: the radial direction e and its change
        for r in range(3):
            tmp[r] = x[r] - prm[r] - s * (ux, uy, uz)[r]
            tmp[3 + r] = dx[r] - du * (ux, uy, uz)[r]
        rho = np.sqrt(tmp[0] ** 2 + tmp[1] ** 2 + tmp[2] ** 2)
        if rho == 0.0:
            return
        for r in range(3):
            tmp[r] /= rho
        de = tmp[6:9]
        _project_out(tmp[0:3], tmp[3:6], rho, de)
        h = s - 0.5 * L
        dr = rho - prm[6]
        dh = abs(h) - 0.5 * L
        if dr > 0.0 and dh > 0.0:  # the rim: from the nearest rim point y = a + s_end u + R e
            d = np.sqrt(dr * dr + dh * dh)
            for r in range(3):
                tmp[3 + r] = dx[r] - prm[6] * de[r]
            _project_out(n, tmp[3:6], d, dn)
        elif dr > dh:  # the side: the radial direction's change
            for r in range(3):
                dn[r] = de[r]
        return
    # box: outside, from the nearest point (the clamped one); inside, a face's fixed normal
    out2 = 0.0
    for r in range(3):
        y = prm[6 + r] * (x[0] - prm[0]) + prm[9 + r] * (x[1] - prm[1]) + prm[12 + r] * (x[2] - prm[2])
        q = abs(y) - prm[3 + r]
        dyl = prm[6 + r] * dx[0] + prm[9 + r] * dx[1] + prm[12 + r] * dx[2]
        tmp[r] = dyl if q > 0.0 else 0.0  # the change of x - nearest, box frame
        if q > 0.0:
            out2 += q * q
    if out2 == 0.0:
        return
    _rx(view2(prm[6:15], 3, 3), tmp[0:3], tmp[3:6])
    _project_out(n, tmp[3:6], np.sqrt(out2), dn)


@jit
def _law_tangent(law, ell, d, dd, n, dn, vc, dvc, F, dF):
    """The law's force ``F`` (3,) and its change ``dF`` along the changes ``dd`` of the
    penetration, ``dn`` of the normal and ``dvc`` of the surface point's velocity."""
    k, e, c, mu_s, mu_d, eps, v_s = law[0], law[1], law[2], law[3], law[4], law[5], law[6]
    vn = vc[0] * n[0] + vc[1] * n[1] + vc[2] * n[2]
    dvn = dvc[0] * n[0] + dvc[1] * n[1] + dvc[2] * n[2] + vc[0] * dn[0] + vc[1] * dn[1] + vc[2] * dn[2]
    hdamp = 1.0 - c * vn
    dh = -c * dvn
    if hdamp < 0.0:
        hdamp = 0.0
        dh = 0.0
    de = power(d, e)
    fn = ell * k * de * hdamp
    dfn = ell * k * (e * power(d, e - 1.0) * dd * hdamp + de * dh)
    vt0, vt1, vt2 = vc[0] - vn * n[0], vc[1] - vn * n[1], vc[2] - vn * n[2]
    dvt0 = dvc[0] - dvn * n[0] - vn * dn[0]
    dvt1 = dvc[1] - dvn * n[1] - vn * dn[1]
    dvt2 = dvc[2] - dvn * n[2] - vn * dn[2]
    s2 = vt0 * vt0 + vt1 * vt1 + vt2 * vt2
    ds2 = 2.0 * (vt0 * dvt0 + vt1 * dvt1 + vt2 * dvt2)
    ex = np.exp(-s2 / (v_s * v_s))
    mu = mu_d + (mu_s - mu_d) * ex
    dmu = -(mu_s - mu_d) * ex * ds2 / (v_s * v_s)
    g = 1.0 / np.sqrt(s2 + eps * eps)
    dg = -0.5 * g * g * g * ds2
    ft = mu * fn * g
    dft = dmu * fn * g + mu * dfn * g + mu * fn * dg
    F[0] = fn * n[0] - ft * vt0
    F[1] = fn * n[1] - ft * vt1
    F[2] = fn * n[2] - ft * vt2
    dF[0] = dfn * n[0] + fn * dn[0] - dft * vt0 - ft * dvt0
    dF[1] = dfn * n[1] + fn * dn[1] - dft * vt1 - ft * dvt1
    dF[2] = dfn * n[2] + fn * dn[2] - dft * vt2 - ft * dvt2


@jit
def _frame_step(R, p, S, dS, q_d, qd, dq, dqd, V, eta, dV, AV, Vn, eta_n, dV_n, zeta):
    """A frame ``g = (R, p)`` (a node's or the tip's, relative to its root) with Jacobian ``S``
    (6, 3) and ``dS`` (3, 6, 3) ``= dS/dq``: its body twist ``Vn``, pose variation ``eta_n``
    and twist change ``dV_n`` from the root's ``V``, ``eta``, ``dV``; ``AV = Ad(g)^-1 V`` and
    ``zeta = S dq`` are left for the caller."""
    for r in range(3):
        q_d[r] = 0.0
    slice_twist(R, p, S, V, q_d, AV)
    slice_twist(R, p, S, eta, dq, eta_n)
    slice_twist(R, p, S, dV, dqd, dV_n)
    for r in range(6):
        zeta[r] = S[r, 0] * dq[0] + S[r, 1] * dq[1] + S[r, 2] * dq[2]
        Vn[r] = AV[r] + S[r, 0] * qd[0] + S[r, 1] * qd[1] + S[r, 2] * qd[2]
        acc = 0.0
        for c in range(3):
            acc += dq[c] * (dS[c, r, 0] * qd[0] + dS[c, r, 1] * qd[1] + dS[c, r, 2] * qd[2])
        dV_n[r] += acc
    sub6(dV_n, motion_cross(zeta, AV))


@jit
def _accumulate(R, p, S, dS, dq, w, dw, zeta, W, dW, dtau, g9, t6, t3):
    """``W += Ad^-T w``; ``dW += Ad^-T (dw + zeta x* w)``; ``dtau += S^T dw + dS[dq]^T w``."""
    add6(W, ad_force(R, p, w))
    for r in range(9):
        g9[r] = 0.0
    phi_transpose_force(R, p, S, dw, 1.0, g9)
    for r in range(6):
        dW[r] += g9[r]
    for c in range(3):
        dtau[c] += g9[6 + c]
    put6(t6, force_cross(zeta, w))
    add6(dW, ad_force(R, p, t6))
    for i in range(3):
        acc = 0.0
        for c in range(3):
            for r in range(6):
                acc += dq[c] * dS[c, r, i] * w[r]
        dtau[i] += acc


@jit
def _wrench_tangent(Rs, F, dF, arm, darm, eta, w, dw, t3, u3):
    """The slice wrench ``w = (Rs^T F, Rs^T (arm x F))`` and its change ``dw`` along ``dF``,
    ``darm`` and the frame's rotation ``Rs [eta_ang]x``."""
    _world_wrench_to_slice(Rs, F, arm, w)
    _rt(Rs, dF, t3)
    for r in range(3):
        dw[r] = t3[r]
    _cross(darm, F, t3)
    _cross(arm, dF, u3)
    for r in range(3):
        u3[r] += t3[r]
    _rt(Rs, u3, t3)
    for r in range(3):
        dw[3 + r] = t3[r]
    ea = eta[3:6]
    _cross(ea, w[0:3], t3)
    _cross(ea, w[3:6], u3)
    for r in range(3):
        dw[r] -= t3[r]
        dw[3 + r] -= u3[r]


@jit
def _contact_point(kind, prm, vel, law, ell, r_s, x, dx, Rs, Vs, dVs, eta, w, dw, t):
    """The slice wrench ``w`` (6,) of a contact point's force and its change ``dw`` along the
    point's pose variation ``eta`` (its backbone point moving by ``dx``) and twist change
    ``dVs``; False where the point does not touch the obstacle. ``vel`` (3,) the obstacle's
    velocity. ``t`` scratch (45,)."""
    nrm, dn, arm, darm = t[0:3], t[3:6], t[6:9], t[9:12]
    vc, dvc, om, dom = t[12:15], t[15:18], t[18:21], t[21:24]
    F, dF, t3, u3 = t[24:27], t[27:30], t[30:33], t[33:36]
    d = r_s - signed_distance(kind, prm, x, nrm)
    if d <= 0.0:
        return False
    _normal_tangent(kind, prm, x, nrm, dx, dn, t[36:45])
    dd = -(nrm[0] * dx[0] + nrm[1] * dx[1] + nrm[2] * dx[2])
    for r in range(3):
        arm[r] = -r_s * nrm[r]
        darm[r] = -r_s * dn[r]
    # world velocities of the backbone point and the frame, and their changes
    _rx(Rs, Vs[0:3], vc)
    _rx(Rs, Vs[3:6], om)
    _cross(eta[3:6], Vs[0:3], t3)
    for r in range(3):
        t3[r] += dVs[r]
    _rx(Rs, t3, dvc)
    _cross(eta[3:6], Vs[3:6], t3)
    for r in range(3):
        t3[r] += dVs[3 + r]
    _rx(Rs, t3, dom)
    # the surface point's velocity v + w x arm, and its change
    _cross(om, arm, t3)
    _cross(dom, arm, u3)
    for r in range(3):
        vc[r] += t3[r] - vel[r]  # relative to the obstacle (whose motion does not depend on the arm's)
        dvc[r] += u3[r]
    _cross(om, darm, t3)
    for r in range(3):
        dvc[r] += t3[r]
    _law_tangent(law, ell, d, dd, nrm, dn, vc, dvc, F, dF)
    _wrench_tangent(Rs, F, dF, arm, darm, eta, w, dw, t3, u3)
    return True


@jit
def environment_tangent(arr, kind, prm, vel, law, calpha, seg, lalpha, wrench, local, q, qd, dq, dqd, R_WB, p_WB,
                        V0, eta0, dV0, dtau, dF0, W, dW, roots, P, sc):
    """The change ``dtau`` (n, 3) of the environment's generalised force on the segment
    coordinates and ``dF0`` (6,) of its wrench on the base along the direction ``(dq, dqd)``
    (n, 3) of the coordinates and rates, ``eta0`` (6,) of the base pose (body twist) and
    ``dV0`` (6,) of the base twist. Arguments as :func:`qchain.contact.forces.contact_forces`
    and :func:`~qchain.contact.forces.load_forces` together; ``W``, ``dW`` (n + 1, 6),
    ``roots`` (n, ROOT + 12) and ``P`` (2, K, NODE_T) work arrays (the last two for
    self-contact, ``law[7]`` set); ``sc`` scratch."""
    arr = ChainArrays(*arr)
    n = q.shape[0]
    m = kind.shape[0]
    K = calpha.shape[0]
    L = seg.shape[0]
    o = 0
    Rj, o = take2(sc, o, 3, 3)
    oj, o = take1(sc, o, 3)
    Vj, o = take1(sc, o, 6)
    eta, o = take1(sc, o, 6)
    dV, o = take1(sc, o, 6)
    Rn, o = take2(sc, o, 3, 3)
    pn, o = take1(sc, o, 3)
    Sn, o = take2(sc, o, 6, 3)
    Sdn, o = take2(sc, o, 6, 3)
    dS, o = take3(sc, o, 3, 6, 3)
    Kn, o = take2(sc, o, 3, 6)
    AV, o = take1(sc, o, 6)
    Vs, o = take1(sc, o, 6)
    eta_s, o = take1(sc, o, 6)
    dVs, o = take1(sc, o, 6)
    zeta, o = take1(sc, o, 6)
    Rs, o = take2(sc, o, 3, 3)
    x, o = take1(sc, o, 3)
    dx, o = take1(sc, o, 3)
    w, o = take1(sc, o, 6)
    dw, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    t6, o = take1(sc, o, 6)
    t3, o = take1(sc, o, 3)
    u3, o = take1(sc, o, 3)
    z3, o = take1(sc, o, 3)
    tmp, o = take1(sc, o, 45)
    near, o = take1(sc, o, m)
    start(R_WB, p_WB, V0, Rj, oj, Vj, W)
    start(R_WB, p_WB, V0, Rj, oj, Vj, dW)
    for r in range(6):
        eta[r] = eta0[r]
        dV[r] = dV0[r]
    for j in range(n):
        for c in range(3):
            dtau[j, c] = 0.0
    for j in range(n):
        l, ux, uy = q[j, 0], q[j, 1], q[j, 2]
        r_s = arr.radius[j]
        any_near = False
        if law[7] > 0.0:  # self-contact: keep the root, its tangent and the segment's ball
            arc_pose(0.5, l, ux, uy, Rn, pn)
            _point(Rj, oj, pn, x)
            _keep_root(roots[j], Rj, oj, Vj, x, 0.5 * abs(l) + r_s)
            for r in range(6):
                roots[j, ROOT + r] = eta[r]
                roots[j, ROOT + 6 + r] = dV[r]
        if m > 0:
            arc_pose(0.5, l, ux, uy, Rn, pn)
            _point(Rj, oj, pn, x)
            reach = 0.5 * abs(l) + r_s
            for b in range(m):
                near[b] = 1.0 if signed_distance(kind[b], prm[b], x, tmp) < reach else 0.0
                any_near = any_near or near[b] > 0.0
        nodes = K if any_near else 0
        ell = arr.l0[j] / K
        for i in range(nodes + L):
            if i < nodes:
                a = calpha[i]
            else:
                if seg[i - nodes] != j:
                    continue
                a = lalpha[i - nodes]
            arc_node(a, l, ux, uy, qd[j, 0], qd[j, 1], qd[j, 2], Rn, pn, Sn, Sdn)
            arc_node_derivatives(a, l, ux, uy, qd[j, 0], qd[j, 1], qd[j, 2], dS, Kn)
            _frame_step(Rn, pn, Sn, dS, z3, qd[j], dq[j], dqd[j], Vj, eta, dV, AV, Vs, eta_s, dVs, zeta)
            _mat3(Rj, Rn, Rs)
            if i >= nodes:  # a point load: world (the frame turns under it) or local
                k = i - nodes
                for r in range(6):
                    dw[r] = 0.0
                if local[k]:
                    for r in range(6):
                        w[r] = wrench[k, r]
                else:
                    _rt(Rs, wrench[k, 0:3], t3)
                    _rt(Rs, wrench[k, 3:6], u3)
                    for r in range(3):
                        w[r] = t3[r]
                        w[3 + r] = u3[r]
                    _cross(eta_s[3:6], w[0:3], t3)
                    _cross(eta_s[3:6], w[3:6], u3)
                    for r in range(3):
                        dw[r] = -t3[r]
                        dw[3 + r] = -u3[r]
                _accumulate(Rn, pn, Sn, dS, dq[j], w, dw, zeta, W[j], dW[j], dtau[j], g9, t6, t3)
                continue
            _point(Rj, oj, pn, x)
            _rx(Rs, eta_s[0:3], dx)
            for b in range(m):
                if near[b] == 0.0:
                    continue
                if _contact_point(kind[b], prm[b], vel[b], law, ell, r_s, x, dx, Rs, Vs, dVs, eta_s, w, dw, tmp):
                    _accumulate(Rn, pn, Sn, dS, dq[j], w, dw, zeta, W[j], dW[j], dtau[j], g9, t6, t3)
        # to the next root
        arc_node(1.0, l, ux, uy, qd[j, 0], qd[j, 1], qd[j, 2], Rn, pn, Sn, Sdn)
        arc_node_derivatives(1.0, l, ux, uy, qd[j, 0], qd[j, 1], qd[j, 2], dS, Kn)
        _frame_step(Rn, pn, Sn, dS, z3, qd[j], dq[j], dqd[j], Vj, eta, dV, AV, Vs, eta_s, dVs, zeta)
        for r in range(6):
            Vj[r] = Vs[r]
            eta[r] = eta_s[r]
            dV[r] = dVs[r]
        for r in range(3):
            oj[r] += Rj[r, 0] * pn[0] + Rj[r, 1] * pn[1] + Rj[r, 2] * pn[2]
        _mat3(Rj, Rn, Rs)
        for r in range(3):
            for c in range(3):
                Rj[r, c] = Rs[r, c]
    if law[7] > 0.0:
        _self_contact_tangent(arr, law, calpha, q, qd, dq, dqd, roots, P, W, dW, dtau, sc[o:])
    for j in range(n - 1, -1, -1):
        arc_node(1.0, q[j, 0], q[j, 1], q[j, 2], 0.0, 0.0, 0.0, Rn, pn, Sn, Sdn)
        arc_node_derivatives(1.0, q[j, 0], q[j, 1], q[j, 2], 0.0, 0.0, 0.0, dS, Kn)
        for r in range(6):
            zeta[r] = Sn[r, 0] * dq[j, 0] + Sn[r, 1] * dq[j, 1] + Sn[r, 2] * dq[j, 2]
        _accumulate(Rn, pn, Sn, dS, dq[j], W[j + 1], dW[j + 1], zeta, W[j], dW[j], dtau[j], g9, t6, t3)
    for r in range(6):
        dF0[r] = dW[0, r]


@jit
def environment_derivatives(arr, kind, prm, vel, law, calpha, seg, lalpha, wrench, local, floating, q, qd, R_WB, p_WB,
                            V0, dtau_dq, dtau_dv, W, dW, D, E, roots, P, sc):
    """``dtau_dq``, ``dtau_dv`` (nv, nv): the derivatives of the environment's generalised force
    (the chain's order: a floating base's wrench first) with respect to the configuration
    (along ``integrate``: a floating base's pose by a body twist) and the velocity, one
    tangent pass (:func:`environment_tangent`) per coordinate. ``D`` (3, n, 3) and ``E``
    (3, 6) work arrays (directions and results); the rest as :func:`environment_tangent`."""
    n = q.shape[0]
    off = 6 if floating else 0
    nv = off + 3 * n
    dq, dqd, dtau = D[0], D[1], D[2]
    eta0, dV0, dF0 = E[0], E[1], E[2]
    for which in range(2):
        out = dtau_dq if which == 0 else dtau_dv
        for i in range(nv):
            for j in range(n):
                for c in range(3):
                    dq[j, c] = 0.0
                    dqd[j, c] = 0.0
            for r in range(6):
                eta0[r] = 0.0
                dV0[r] = 0.0
            if i < off:
                if which == 0:
                    eta0[i] = 1.0
                else:
                    dV0[i] = 1.0
            else:
                k = i - off
                if which == 0:
                    dq[k // 3, k % 3] = 1.0
                else:
                    dqd[k // 3, k % 3] = 1.0
            environment_tangent(arr, kind, prm, vel, law, calpha, seg, lalpha, wrench, local, q, qd, dq, dqd, R_WB, p_WB,
                                V0, eta0, dV0, dtau, dF0, W, dW, roots, P, sc)
            for r in range(off):
                out[r, i] = dF0[r]
            for j in range(n):
                for c in range(3):
                    out[off + 3 * j + c, i] = dtau[j, c]


@jit
def _keep_node_tangents(root, q, qd, dq, dqd, calpha, out, t):
    """Every contact node of a segment with its tangent, into ``out`` (K, NODE_T) (layout:
    :data:`NODE_T`); ``root`` (ROOT + 12,) the kept root and its ``eta``, ``dV``; ``t`` scratch."""
    Rj = view2(root[0:9], 3, 3)
    for i in range(calpha.shape[0]):
        row = out[i]
        Rs = view2(row[0:9], 3, 3)
        Rn = view2(row[18:27], 3, 3)
        pn = row[27:30]
        Sn = view2(row[30:48], 6, 3)
        dS = view3(row[69:123], 3, 6, 3)
        a = calpha[i]
        arc_node(a, q[0], q[1], q[2], qd[0], qd[1], qd[2], Rn, pn, Sn, view2(t[0:18], 6, 3))
        arc_node_derivatives(a, q[0], q[1], q[2], qd[0], qd[1], qd[2], dS, view2(t[18:36], 3, 6))
        Vs, dVs = t[36:42], t[42:48]
        _frame_step(Rn, pn, Sn, dS, t[48:51], qd, dq, dqd, root[12:18], root[ROOT:ROOT + 6], root[ROOT + 6:ROOT + 12],
                    t[51:57], Vs, row[57:63], dVs, row[63:69])
        _mat3(Rj, Rn, Rs)
        _point(Rj, root[9:12], pn, row[9:12])
        _rx(Rs, Vs[0:3], row[12:15])
        _rx(Rs, Vs[3:6], row[15:18])
        _rx(Rs, row[57:60], row[48:51])
        eta = row[57:63]
        _cross(eta[3:6], Vs[0:3], t[51:54])
        _cross(eta[3:6], Vs[3:6], t[54:57])
        for r in range(3):
            t[51 + r] += dVs[r]
            t[54 + r] += dVs[3 + r]
        _rx(Rs, t[51:54], row[51:54])
        _rx(Rs, t[54:57], row[54:57])


@jit
def _pair_side(row, F, dF, arm, darm, dq_j, W_j, dW_j, dtau_j, t):
    """One side of a self-contact pair: its slice wrench and change, accumulated."""
    w, dw = t[0:6], t[6:12]
    _wrench_tangent(view2(row[0:9], 3, 3), F, dF, arm, darm, row[57:63], w, dw, t[12:15], t[15:18])
    _accumulate(view2(row[18:27], 3, 3), row[27:30], view2(row[30:48], 6, 3), view3(row[69:123], 3, 6, 3),
                dq_j, w, dw, row[63:69], W_j, dW_j, dtau_j, t[18:27], t[27:33], t[33:36])


@jit
def _self_contact_tangent(arr, law, calpha, q, qd, dq, dqd, roots, P, W, dW, dtau, sc):
    """The self-contact pairs of :func:`qchain.contact.forces._self_contact` and their changes,
    accumulated into ``W``, ``dW``, ``dtau``."""
    n = q.shape[0]
    K = calpha.shape[0]
    t = sc[0:64]
    u = sc[64:100]
    nrm, dn, arm_a, arm_b, darm_a, darm_b = u[0:3], u[3:6], u[6:9], u[9:12], u[12:15], u[15:18]
    vc, dvc, F, dF, dr, v3 = u[18:21], u[21:24], u[24:27], u[27:30], u[30:33], u[33:36]
    for i in range(n):
        for j in range(i + 2, n):
            if not _near_segments(roots[i], roots[j]):
                continue
            _keep_node_tangents(roots[i], q[i], qd[i], dq[i], dqd[i], calpha, P[0], t)
            _keep_node_tangents(roots[j], q[j], qd[j], dq[j], dqd[j], calpha, P[1], t)
            ri, rj = arr.radius[i], arr.radius[j]
            ell = 0.5 * (arr.l0[i] + arr.l0[j]) / K
            for a in range(K):
                A = P[0, a]
                for b in range(K):
                    B = P[1, b]
                    for r in range(3):
                        nrm[r] = A[9 + r] - B[9 + r]
                        dr[r] = A[48 + r] - B[48 + r]
                    dist = np.sqrt(nrm[0] ** 2 + nrm[1] ** 2 + nrm[2] ** 2)
                    d = ri + rj - dist
                    if d <= 0.0 or dist == 0.0:
                        continue
                    for r in range(3):
                        nrm[r] /= dist
                    ddist = nrm[0] * dr[0] + nrm[1] * dr[1] + nrm[2] * dr[2]
                    _project_out(nrm, dr, dist, dn)
                    ha, hb = 0.5 * (ri + dist - rj), 0.5 * (dist - ri + rj)
                    for r in range(3):
                        arm_a[r] = -ha * nrm[r]
                        arm_b[r] = hb * nrm[r]
                        darm_a[r] = -0.5 * ddist * nrm[r] - ha * dn[r]
                        darm_b[r] = 0.5 * ddist * nrm[r] + hb * dn[r]
                    # the relative velocity of the two surface points, and its change
                    _cross(A[15:18], arm_a, vc)
                    _cross(B[15:18], arm_b, v3)
                    for r in range(3):
                        vc[r] += A[12 + r] - B[12 + r] - v3[r]
                    _cross(A[54:57], arm_a, dvc)
                    _cross(A[15:18], darm_a, v3)
                    for r in range(3):
                        dvc[r] += v3[r] + A[51 + r] - B[51 + r]
                    _cross(B[54:57], arm_b, v3)
                    for r in range(3):
                        dvc[r] -= v3[r]
                    _cross(B[15:18], darm_b, v3)
                    for r in range(3):
                        dvc[r] -= v3[r]
                    _law_tangent(law, ell, d, -ddist, nrm, dn, vc, dvc, F, dF)
                    _pair_side(A, F, dF, arm_a, darm_a, dq[i], W[i], dW[i], dtau[i], t)
                    for r in range(3):
                        F[r] = -F[r]
                        dF[r] = -dF[r]
                    _pair_side(B, F, dF, arm_b, darm_b, dq[j], W[j], dW[j], dtau[j], t)
