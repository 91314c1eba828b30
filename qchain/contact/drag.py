"""The drag of a still medium (air, water) on the backbone as generalised forces (numba), and
their exact derivatives.

**Law** (``ChainArrays.drag`` (n, 2): ``c_1``, ``c_2`` of each segment; docs/model.md
section 9). Each backbone point ``s`` of segment ``j`` moving at ``v(s)`` (its velocity
relative to the medium, at rest in the world) takes the force per unit length

    f(s) = -(c_1 + c_2 |v(s)|) v(s)

(linear: a viscous, Stokes-like medium; quadratic: ``c_2 = 1/2 rho C_d 2 r_s``, the pressure
drag of a fluid of density ``rho``), isotropic. Its generalised force is the virtual work

    tau_drag = int_0^l J(s)^T f(s) ds = l sum_k w_k J(alpha_k)^T f(alpha_k)

over the segment's Gauss-Legendre nodes ``alpha_k`` (``ds = l dalpha``, ``l`` the current
length), ``J`` the Jacobian of the backbone point: on the segment's own coordinates and on
every parent's (and a floating base's wrench). Its power ``v^T tau_drag = -int (c_1 + c_2
|v|) |v|^2 ds`` is never positive.

The velocity ``v`` and ``f`` are taken in the slice's own frame (the force is frame
independent); the slice wrench ``(f, 0)`` goes to the segment by ``S^T`` and to its root by
``Ad(g)^-T``, then root to root inwards (:func:`qchain.contact.forces._backward`), as the
contact forces and point loads do. The derivatives are tangent passes through the same steps
(:func:`qchain.contact.derivatives._frame_step`, ``_accumulate``), one a coordinate, on the
nodes' frames and their configuration derivatives computed once (:func:`drag_frames`); the
velocity derivative in closed form, ``-sum_k w_k l J_k^T G_k J_k`` with the nodes' velocity
Jacobians ``J_k``:
``d tau/dq`` and ``d tau/dv`` exact to rounding, with ``d(|v| v)/dv = |v| I + v v^T / |v|``
(zero at ``v = 0``, where it is continuous).

Unchecked kernels: called by :class:`qchain.Chain` and the engine with validated arrays.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit, view2, view3
from ..algorithms.arrays import ChainArrays
from ..model.arc import arc_node, arc_node_derivatives, take1, take2
from ..model.slices import slice_twist
from .derivatives import _accumulate, _frame_step
from .forces import _add_phi_t, _backward, _root_step

__all__ = ["DRAG_FRAME", "drag_forces", "drag_frames", "drag_tangent", "drag_derivatives"]

#: columns of a node's row in the frames table of :func:`drag_frames`: its rotation ``R`` (9)
#: and origin ``p`` (3) in the segment's root frame, ``S`` (18) and ``dS/dq`` (54)
DRAG_FRAME = 84


@jit
def drag_forces(arr, q, qd, V0, tau, F0, W, sc):
    """Add the drag's generalised forces to ``tau`` (n, 3) and its wrench on the base (base
    frame) to ``F0`` (6,). ``arr`` the model's :class:`~qchain.algorithms.arrays.ChainArrays`
    (a plain tuple or named), ``q``, ``qd`` (n, 3) curvature coordinates and rates, ``V0``
    (6,) the base's body twist; ``W`` (n + 1, 6) work array; ``sc`` scratch."""
    arr = ChainArrays(*arr)
    n = q.shape[0]
    o = 0
    Rj, o = take2(sc, o, 3, 3)
    oj, o = take1(sc, o, 3)
    Vj, o = take1(sc, o, 6)
    Rn, o = take2(sc, o, 3, 3)
    pn, o = take1(sc, o, 3)
    Sn, o = take2(sc, o, 6, 3)
    Sdn, o = take2(sc, o, 6, 3)
    Vs, o = take1(sc, o, 6)
    f6, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    tmp, o = take1(sc, o, 6)
    for r in range(3):
        oj[r] = 0.0
        for c in range(3):
            Rj[r, c] = 1.0 if r == c else 0.0  # (the world placement is not needed: the medium is still)
    for r in range(6):
        Vj[r] = V0[r]
        f6[r] = 0.0
    for j in range(W.shape[0]):
        for r in range(6):
            W[j, r] = 0.0
    for j in range(n):
        c1, c2 = arr.drag[j, 0], arr.drag[j, 1]
        l = q[j, 0]
        if c1 != 0.0 or c2 != 0.0:
            for k in range(arr.offs[j], arr.offs[j + 1]):
                arc_node(arr.alpha[k], l, q[j, 1], q[j, 2], 0.0, 0.0, 0.0, Rn, pn, Sn, Sdn)
                slice_twist(Rn, pn, Sn, Vj, qd[j], Vs)
                s = np.sqrt(Vs[0] * Vs[0] + Vs[1] * Vs[1] + Vs[2] * Vs[2])
                c = -arr.w[k] * l * (c1 + c2 * s)
                for r in range(3):
                    f6[r] = c * Vs[r]
                _add_phi_t(Rn, pn, Sn, f6, 1.0, W[j], tau[j], g9)
        _root_step(q[j], qd[j], Rj, oj, Vj, Rn, pn, Sn, Sdn, tmp)
    _backward(q, W, tau, F0, Rn, pn, Sn, Sdn, g9)


@jit
def drag_frames(arr, q, frames, sc):
    """Fill ``frames`` (N + n, :data:`DRAG_FRAME`): row ``k`` node ``k``'s (of the segments with
    drag), row ``N + j`` segment ``j``'s tip: ``R``, ``p``, ``S``, ``dS/dq`` at ``q`` (n, 3), which
    every tangent pass of :func:`drag_derivatives` reads instead of computing them again."""
    arr = ChainArrays(*arr)
    n = q.shape[0]
    N = arr.alpha.shape[0]
    o = 0
    Sd, o = take2(sc, o, 6, 3)
    Kn, o = take2(sc, o, 3, 6)
    for j in range(n):
        l, ux, uy = q[j, 0], q[j, 1], q[j, 2]
        has = arr.drag[j, 0] != 0.0 or arr.drag[j, 1] != 0.0
        for k in range(arr.offs[j], arr.offs[j + 1] + 1):
            row = N + j if k == arr.offs[j + 1] else k
            if row < N and not has:
                continue
            a = 1.0 if row >= N else arr.alpha[k]
            f = frames[row]
            arc_node(a, l, ux, uy, 0.0, 0.0, 0.0, view2(f[0:9], 3, 3), f[9:12], view2(f[12:30], 6, 3), Sd)
            arc_node_derivatives(a, l, ux, uy, 0.0, 0.0, 0.0, view3(f[30:84], 3, 6, 3), Kn)


@jit
def drag_tangent(arr, q, qd, dq, dqd, V0, eta0, dV0, dtau, dF0, W, dW, frames, sc):
    """The change ``dtau`` (n, 3) of the drag's generalised force and ``dF0`` (6,) of its
    wrench on the base along the direction ``(dq, dqd)`` (n, 3) of the coordinates and rates,
    ``eta0`` (6,) of the base pose (body twist) and ``dV0`` (6,) of the base twist; arguments
    as :func:`drag_forces`, ``W``, ``dW`` (n + 1, 6) work arrays, ``frames`` the nodes' frames
    at ``q`` (:func:`drag_frames`)."""
    arr = ChainArrays(*arr)
    n = q.shape[0]
    N = arr.alpha.shape[0]
    o = 0
    Vj, o = take1(sc, o, 6)
    eta, o = take1(sc, o, 6)
    dV, o = take1(sc, o, 6)
    AV, o = take1(sc, o, 6)
    Vs, o = take1(sc, o, 6)
    eta_s, o = take1(sc, o, 6)
    dVs, o = take1(sc, o, 6)
    zeta, o = take1(sc, o, 6)
    w, o = take1(sc, o, 6)
    dw, o = take1(sc, o, 6)
    g9, o = take1(sc, o, 9)
    t6, o = take1(sc, o, 6)
    t3, o = take1(sc, o, 3)
    z3, o = take1(sc, o, 3)
    for r in range(6):
        Vj[r] = V0[r]
        eta[r] = eta0[r]
        dV[r] = dV0[r]
        w[r] = 0.0
        dw[r] = 0.0
    for j in range(W.shape[0]):
        for r in range(6):
            W[j, r] = 0.0
            dW[j, r] = 0.0
    for j in range(n):
        for c in range(3):
            dtau[j, c] = 0.0
    for j in range(n):
        l = q[j, 0]
        c1, c2 = arr.drag[j, 0], arr.drag[j, 1]
        if c1 != 0.0 or c2 != 0.0:
            for k in range(arr.offs[j], arr.offs[j + 1]):
                f = frames[k]
                Rn, pn, Sn, dS = view2(f[0:9], 3, 3), f[9:12], view2(f[12:30], 6, 3), view3(f[30:84], 3, 6, 3)
                _frame_step(Rn, pn, Sn, dS, z3, qd[j], dq[j], dqd[j], Vj, eta, dV, AV, Vs, eta_s, dVs, zeta)
                # f = -w_k l (c1 + c2 |v|) v and its change: d|v| = v . dv / |v| (0 at v = 0)
                s = np.sqrt(Vs[0] * Vs[0] + Vs[1] * Vs[1] + Vs[2] * Vs[2])
                ds = (Vs[0] * dVs[0] + Vs[1] * dVs[1] + Vs[2] * dVs[2]) / s if s > 0.0 else 0.0
                c = -arr.w[k] * l * (c1 + c2 * s)
                dc = -arr.w[k] * (dq[j, 0] * (c1 + c2 * s) + l * c2 * ds)
                for r in range(3):
                    w[r] = c * Vs[r]
                    dw[r] = dc * Vs[r] + c * dVs[r]
                _accumulate(Rn, pn, Sn, dS, dq[j], w, dw, zeta, W[j], dW[j], dtau[j], g9, t6, t3)
        # to the next root
        f = frames[N + j]
        Rn, pn, Sn, dS = view2(f[0:9], 3, 3), f[9:12], view2(f[12:30], 6, 3), view3(f[30:84], 3, 6, 3)
        _frame_step(Rn, pn, Sn, dS, z3, qd[j], dq[j], dqd[j], Vj, eta, dV, AV, Vs, eta_s, dVs, zeta)
        for r in range(6):
            Vj[r] = Vs[r]
            eta[r] = eta_s[r]
            dV[r] = dVs[r]
    for j in range(n - 1, -1, -1):
        f = frames[N + j]
        Rn, pn, Sn, dS = view2(f[0:9], 3, 3), f[9:12], view2(f[12:30], 6, 3), view3(f[30:84], 3, 6, 3)
        for r in range(6):
            zeta[r] = Sn[r, 0] * dq[j, 0] + Sn[r, 1] * dq[j, 1] + Sn[r, 2] * dq[j, 2]
        _accumulate(Rn, pn, Sn, dS, dq[j], W[j + 1], dW[j + 1], zeta, W[j], dW[j], dtau[j], g9, t6, t3)
    for r in range(6):
        dF0[r] = dW[0, r]


@jit
def _velocity_jacobian(arr, floating, q, qd, V0, frames, out, sc):
    """``out = d tau_drag/dv`` (nv, nv) in closed form: ``tau_drag = sum_k J_k^T f_k`` with ``J_k``
    (3, nv) the map from ``v`` to node ``k``'s linear velocity (slice frame) and
    ``f_k = -w_k l phi(J_k v)``, ``phi(v) = (c_1 + c_2 |v|) v``, so
    ``d tau/dv = -sum_k w_k l J_k^T (c_1 I + c_2 (|v| I + v v^T / |v|)) J_k``, symmetric. The root
    Jacobians go root to root by the tip maps; ``sc`` holds ``Jr`` (6, nv), ``J``, ``GJ`` (3, nv)
    (the caller checks it has room)."""
    arr = ChainArrays(*arr)
    n = q.shape[0]
    N = arr.alpha.shape[0]
    off = 6 if floating else 0
    nv = off + 3 * n
    o = 0
    Jr, o = take2(sc, o, 6, nv)
    J, o = take2(sc, o, 3, nv)
    GJ, o = take2(sc, o, 3, nv)
    Jn, o = take2(sc, o, 6, nv)
    Vj, o = take1(sc, o, 6)
    Vs, o = take1(sc, o, 6)
    for r in range(nv):
        for c in range(nv):
            out[r, c] = 0.0
    for r in range(6):
        Vj[r] = V0[r]
        for c in range(nv):
            Jr[r, c] = 1.0 if (floating and r == c) else 0.0
    for j in range(n):
        l = q[j, 0]
        c1, c2 = arr.drag[j, 0], arr.drag[j, 1]
        cols = off + 3 * j + 3  # the columns of segment j and its parents: the others are zero
        for k in range(arr.offs[j], arr.offs[j + 1] + 1):
            tip = k == arr.offs[j + 1]
            if not tip and c1 == 0.0 and c2 == 0.0:
                continue
            f = frames[N + j] if tip else frames[k]
            R, p, S = view2(f[0:9], 3, 3), f[9:12], view2(f[12:30], 6, 3)
            # Jn = Ad(g)^-1 Jr + S on segment j's columns: (R^T (jv - p x jw), R^T jw)
            for c in range(cols):
                a0 = Jr[0, c] - (p[1] * Jr[5, c] - p[2] * Jr[4, c])
                a1 = Jr[1, c] - (p[2] * Jr[3, c] - p[0] * Jr[5, c])
                a2 = Jr[2, c] - (p[0] * Jr[4, c] - p[1] * Jr[3, c])
                for r in range(3):
                    Jn[r, c] = R[0, r] * a0 + R[1, r] * a1 + R[2, r] * a2
                    Jn[3 + r, c] = R[0, r] * Jr[3, c] + R[1, r] * Jr[4, c] + R[2, r] * Jr[5, c]
            for r in range(6):
                for b in range(3):
                    Jn[r, off + 3 * j + b] += S[r, b]
            slice_twist(R, p, S, Vj, qd[j], Vs)
            if tip:
                for r in range(6):
                    Vj[r] = Vs[r]
                    for c in range(cols):
                        Jr[r, c] = Jn[r, c]
                continue
            sp = np.sqrt(Vs[0] * Vs[0] + Vs[1] * Vs[1] + Vs[2] * Vs[2])
            wl = arr.w[k] * l
            g = c1 + c2 * sp
            h = c2 / sp if sp > 0.0 else 0.0
            for c in range(cols):
                vj = Vs[0] * Jn[0, c] + Vs[1] * Jn[1, c] + Vs[2] * Jn[2, c]
                for r in range(3):
                    GJ[r, c] = wl * (g * Jn[r, c] + h * Vs[r] * vj)
            for r in range(cols):
                for c in range(cols):
                    out[r, c] -= Jn[0, r] * GJ[0, c] + Jn[1, r] * GJ[1, c] + Jn[2, r] * GJ[2, c]


@jit
def drag_derivatives(arr, floating, q, qd, V0, dtau_dq, dtau_dv, W, dW, D, E, frames, sc):
    """``dtau_dq``, ``dtau_dv`` (nv, nv): the exact derivatives of the drag's generalised
    force (the chain's order: a floating base's wrench first) with respect to the
    configuration (along ``integrate``; zero along a floating base's pose: the medium is still
    and isotropic) and the velocity: one :func:`drag_tangent` a coordinate, ``d/dv`` in closed
    form (:func:`_velocity_jacobian`) where the scratch has room. ``D`` (3, n, 3) and ``E`` (3, 6) work arrays, ``frames`` (N + n,
    :data:`DRAG_FRAME`) (:func:`drag_frames` fills it here); the rest as :func:`drag_tangent`."""
    drag_frames(arr, q, frames, sc)
    n = q.shape[0]
    off = 6 if floating else 0
    nv = off + 3 * n
    dq, dqd, dtau = D[0], D[1], D[2]
    eta0, dV0, dF0 = E[0], E[1], E[2]
    closed = 18 * nv + 12 <= sc.shape[0]  # room for d tau/dv in closed form (else its tangent passes)
    if closed:
        _velocity_jacobian(arr, floating, q, qd, V0, frames, dtau_dv, sc)
    for which in range(1 if closed else 2):
        out = dtau_dq if which == 0 else dtau_dv
        for i in range(nv):
            if i < off and which == 0:  # the base's pose: the medium is still and isotropic, nothing changes
                for r in range(nv):
                    out[r, i] = 0.0
                continue
            for j in range(n):
                for c in range(3):
                    dq[j, c] = 0.0
                    dqd[j, c] = 0.0
            for r in range(6):
                eta0[r] = 0.0
                dV0[r] = 0.0
            if i < off:
                dV0[i] = 1.0
            else:
                k = i - off
                if which == 0:
                    dq[k // 3, k % 3] = 1.0
                else:
                    dqd[k // 3, k % 3] = 1.0
            drag_tangent(arr, q, qd, dq, dqd, V0, eta0, dV0, dtau, dF0, W, dW, frames, sc)
            for r in range(off):
                out[r, i] = dF0[r]
            for j in range(n):
                for c in range(3):
                    out[off + 3 * j + c, i] = dtau[j, c]
