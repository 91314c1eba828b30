"""Planar articulated-body forward dynamics (numba): a ``planar=True`` chain at 2-D cost.

A chain built with ``planar=True`` holds ``uy = 0`` in every segment. :func:`planar_aba`
gives what :func:`qchain.algorithms.recursive.aba` gives for such a chain on a fixed base
(:func:`planar_aba_moving`: a prescribed base moving in its x-z plane), to rounding, but
works on 3-vectors instead of 6-vectors, 5 x 5 segment blocks instead of 9 x 9, 3 x 5 tip
maps instead of 6 x 9, 3 x 3 articulated inertias instead of 6 x 6, and a scalar node loop
instead of 6 x 3 slice Jacobians: about 7 to 10 times faster than ``aba`` (n = 1 to 30,
``benchmarks/bench_planar.py``), as fast as ``pinocchio.aba`` on a rigid chain of as many
free coordinates. :func:`planar_rnea` is the matching inverse dynamics.

The node loop is bound by the latency of ``_bend``'s series (about half of the time);
``fastmath`` does not change the time measurably and is off.

Why the reduction is exact
--------------------------
Split spatial vectors ``[v; w]`` (Pinocchio's ``[linear; angular]``) into the *in-plane*
components ``(vx, vz, wy)`` (indices 0, 2, 4) and the *out-of-plane* ones ``(vy, wx, wz)``
(indices 1, 3, 5). The reflection ``P: y -> -y`` of the base frame maps a motion or force
vector to ``diag(1, -1, 1, -1, 1, -1)`` of it (``w`` is a pseudovector: ``w -> -P w``), so
in-plane components are even under it and out-of-plane ones odd. With ``uy = 0``:

* the strain twist ``xi_u = (0, 0, 1, -uy, ux, 0) = (0, 0, 1, 0, ux, 0)`` is even, so every
  slice placement ``g(alpha) = exp6(alpha l xi_u)`` commutes with ``P``: ``R`` is the
  rotation about ``y`` by ``theta = alpha l ux``, ``p`` lies in the x-z plane, and
  ``Ad(g)^-1`` maps even vectors to even vectors and odd to odd (it is block diagonal in
  the even/odd split);
* the slice Jacobian's ``l`` and ``ux`` columns ``alpha xi_u`` and ``F(s) d xi_u/d ux`` are even
  (``F(s)`` is a polynomial in ``ad(xi_u)``, which preserves parity); its ``uy`` column is
  odd. With ``uy_dot = 0`` the time derivative ``Sdot`` of the even columns is even;
* the disk inertia ``diag(m, m, m, m r^2/4, m r^2/4, m r^2/2)`` commutes with ``P``; the
  motion cross product of two even twists is even, and ``V x* (I V)`` of an even ``V`` is
  an even force;
* hence every segment block ``M_xi = int Phi^T I Phi`` and every tip map ``T = Phi(1)`` is
  block diagonal in (even, odd); with an even base twist ``V0`` all twists, tip biases ``c``
  and slice forces are even, so the segment forces ``Q`` are even; the articulated inertias
  ``IA = Mh_VV - U D^-1 U^T`` stay block diagonal and the bias forces ``pA`` even, because
  ``D`` couples the even ``(l, ux)`` and the (locked) odd ``uy`` coordinate only through
  blocks that vanish.

So the odd components form a decoupled subsystem that, driven only by the odd part of the
base acceleration ``A0`` (out-of-plane gravity, say), moves only the locked ``uy``; its
forces are constraint forces. The even subsystem is closed: it is this module, and its
accelerations ``qdd[:, 0:2]`` are exactly ``recursive.aba``'s. (The base twist must be
in-plane -- zero for a fixed base; an out-of-plane base twist would feed odd x odd products
into the even equations.)

Planar slice kinematics
-----------------------
Planar twists and accelerations are ``(vx, vz, wy)``, planar forces ``(fx, fz, ny)``. With
``s = alpha l``, ``x = s |ux|`` and the entire functions ``f0, f1, f2, g1, g2`` of
:func:`qchain.model.arc._bend` (regular at ``x = 0``, so nothing divides by ``ux``),
``a1 = s f0 = sin(theta)/ux``, ``a2 = s^2 f1 = (1 - cos theta)/ux^2``, ``a3 = s^3 f2``:

* ``cos theta = 1 - a2 ux^2``, ``sin theta = a1 ux``; ``R`` maps slice ``(x, z)`` to root
  ``(c x + sn z, -sn x + c z)``; ``p = (a2 ux, a1)``;
* ``Ad(g)^-1 (vx, vz, wy) = (c tx - sn tz, sn tx + c tz, wy)``, ``t = (vx + pz wy, vz - px wy)``;
  its ``wy`` column is ``(c pz + sn px, sn pz - c px, 1) = (a1, a2 ux, 1)``;
* ``S_l = alpha (0, 1, ux)``, ``S_ux = (a2, a3 ux, s)``;
* ``Sdot qd`` (with ``qd = (ld, uxd)``, using ``dS_ux/ds = (a1, a2 ux, 1)``,
  ``d a2/d ux = s^4 g1 ux``, ``d a3/d ux = s^5 g2 ux``):
  ``uxd (alpha ld a1 + uxd s^4 g1 ux,  alpha ld a2 ux + uxd (a3 + s^5 g2 ux^2),  2 alpha ld)``;
* the planar motion cross product ``a x b = (a_w b_z - b_w a_z, a_x b_w - a_w b_x, 0)`` and
  the force ``I a + V x* (I V) = (m (a_x + w v_z), m (a_z - w v_x), (m r^2/4) a_w)``;
* ``Phi^T f = (R f_lin, pz (R f)_x - px (R f)_z + n_y, alpha (f_z + ux n_y),
  a2 f_x + a3 ux f_z + s n_y)``.

A tip payload (``arr.payload``) enters by its in-plane block (rows and columns 0, 2, 4) and
in-plane force; the reduction stays exact when it is symmetric about the x-z plane
(``c_y = 0``, ``y`` a principal axis), which :class:`qchain.Chain` requires of a planar chain's.

The segment block (5 x 5 over ``(V_root planar, ld, uxd)``) has the root block of the
disks moved to the root, ``[[m, 0, m pz], [0, m, -m px], [m pz, -m px, Iyy + m |p|^2]]``
summed over the nodes, and the q columns ``Phi^T I S_c``.

``tests/test_planar.py`` holds :func:`planar_aba` equal to :func:`qchain.algorithms.recursive.aba` (and
:func:`planar_rnea` to :func:`qchain.algorithms.recursive.rnea`) on ``planar=True`` chains to 1e-12
(measured: 1e-16 to 5e-14); ``benchmarks/bench_planar.py`` times them.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

import numpy as np

from .arrays import ChainArrays, PlanarWorkspace
from .._jit import jit, jit_inline as _inline, jit_pass
from ..model.arc import SCRATCH, _bend

__all__ = ["planar_aba", "planar_aba_moving", "planar_rnea", "planar_workspace"]

@_inline
def _node(alpha, l, ux):
    """Slice ``alpha`` of a planar segment: ``(s, a1, a2, a3, g1, g2, c, sn)``."""
    s = alpha * l
    f0, f1, f2, _, g1, g2 = _bend(s * abs(ux))
    s2 = s * s
    a1 = s * f0
    a2 = s2 * f1
    a3 = s2 * s * f2
    return s, a1, a2, a3, g1, g2, 1.0 - a2 * ux * ux, a1 * ux


@_inline
def _segment(alpha, w, k0, k1, m, iyy, l, ux, ld, uxd, vx, vz, vw, M, b, j):
    """Segment block ``M[j]`` (5, 5) and bias force ``b[j]`` (5,) (``M_xi`` and ``C_xi xi`` over
    the planar quasi-velocity ``xi = (vx, vz, wy, ld, uxd)``), by the nodes ``k0:k1``."""
    sw = 0.0  # sum w
    spx = 0.0  # sum w px
    spz = 0.0  # sum w pz
    sp2 = 0.0  # sum w |p|^2
    m0l = 0.0
    m1l = 0.0
    m2l = 0.0
    m0u = 0.0
    m1u = 0.0
    m2u = 0.0
    mll = 0.0
    mlu = 0.0
    muu = 0.0
    b0 = 0.0
    b1 = 0.0
    b2 = 0.0
    bl = 0.0
    bu = 0.0
    ux2 = ux * ux
    for k in range(k0, k1):
        al = alpha[k]
        wk = w[k]
        s, a1, a2, a3, g1, g2, c, sn = _node(al, l, ux)
        px = a2 * ux
        pz = a1
        a3u = a3 * ux
        # mass: root block sums and the q columns Phi^T I S
        sw += wk
        spx += wk * px
        spz += wk * pz
        sp2 += wk * (px * px + pz * pz)
        wa = wk * al
        m0l += wa * sn
        m1l += wa * c
        m2l += wa * ux * (m * a2 + iyy)  # m (pz sn - px c) + iyy ux, pz sn - px c = a2 ux
        fx = m * a2
        fz = m * a3u
        fw = iyy * s
        lx = c * fx + sn * fz
        lz = c * fz - sn * fx
        m0u += wk * lx
        m1u += wk * lz
        m2u += wk * (pz * lx - px * lz + fw)
        mll += wa * al * (m + iyy * ux2)
        mlu += wa * ux * (m * a3 + iyy * s)
        muu += wk * (m * (a2 * a2 + a3u * a3u) + iyy * s * s)
        # bias: slice twist V = Ad^-1 V_root + S qd, acceleration a = Sdot qd - (S qd) x (Ad^-1 V_root)
        tx = vx + pz * vw
        tz = vz - px * vw
        rx = c * tx - sn * tz
        rz = sn * tx + c * tz
        ex = a2 * uxd
        ez = al * ld + a3u * uxd
        ew = al * ux * ld + s * uxd
        s4 = s * s * s * s
        alx = uxd * (al * ld * a1 + uxd * s4 * g1 * ux)
        alz = uxd * (al * ld * px + uxd * (a3 + s4 * s * g2 * ux2))
        alw = 2.0 * al * ld * uxd
        alx -= ew * rz - vw * ez
        alz -= ex * vw - ew * rx
        Vx = rx + ex
        Vz = rz + ez
        Vw = vw + ew
        fx = m * (alx + Vw * Vz)
        fz = m * (alz - Vw * Vx)
        fw = iyy * alw
        lx = c * fx + sn * fz
        lz = c * fz - sn * fx
        b0 += wk * lx
        b1 += wk * lz
        b2 += wk * (pz * lx - px * lz + fw)
        bl += wa * (fz + ux * fw)
        bu += wk * (a2 * fx + a3u * fz + s * fw)
    M[j, 0, 0] = m * sw
    M[j, 0, 1] = 0.0
    M[j, 0, 2] = m * spz
    M[j, 1, 1] = m * sw
    M[j, 1, 2] = -m * spx
    M[j, 2, 2] = iyy * sw + m * sp2
    M[j, 0, 3] = m * m0l
    M[j, 1, 3] = m * m1l
    M[j, 2, 3] = m2l
    M[j, 0, 4] = m0u
    M[j, 1, 4] = m1u
    M[j, 2, 4] = m2u
    M[j, 3, 3] = mll
    M[j, 3, 4] = mlu
    M[j, 4, 4] = muu
    for r in range(5):
        for k in range(r):
            M[j, r, k] = M[j, k, r]
    b[j, 0] = b0
    b[j, 1] = b1
    b[j, 2] = b2
    b[j, 3] = bl
    b[j, 4] = bu


@_inline
def _tip(l, ux, ld, uxd, vx, vz, vw, T, c, j):
    """Tip map ``T[j] = Phi(1)`` (3, 5), tip bias ``c[j] = Phidot(1) xi`` (3,); returns the next
    root's planar twist ``T xi``."""
    s, a1, a2, a3, g1, g2, cs, sn = _node(1.0, l, ux)
    px = a2 * ux
    pz = a1
    a3u = a3 * ux
    T[j, 0, 0] = cs
    T[j, 0, 1] = -sn
    T[j, 0, 2] = a1  # c pz + sn px
    T[j, 1, 0] = sn
    T[j, 1, 1] = cs
    T[j, 1, 2] = px  # sn pz - c px
    T[j, 2, 0] = 0.0
    T[j, 2, 1] = 0.0
    T[j, 2, 2] = 1.0
    T[j, 0, 3] = 0.0
    T[j, 1, 3] = 1.0
    T[j, 2, 3] = ux
    T[j, 0, 4] = a2
    T[j, 1, 4] = a3u
    T[j, 2, 4] = s
    tx = vx + pz * vw
    tz = vz - px * vw
    rx = cs * tx - sn * tz
    rz = sn * tx + cs * tz
    ex = a2 * uxd
    ez = ld + a3u * uxd
    ew = ux * ld + s * uxd
    s4 = s * s * s * s
    c[j, 0] = uxd * (ld * a1 + uxd * s4 * g1 * ux) - (ew * rz - vw * ez)
    c[j, 1] = uxd * (ld * px + uxd * (a3 + s4 * s * g2 * ux * ux)) - (ex * vw - ew * rx)
    c[j, 2] = 2.0 * ld * uxd
    return rx + ex, rz + ez, vw + ew


@_inline
def _payload_inertia(P):
    """The in-plane block (rows and columns 0, 2, 4) of the payload's spatial inertia ``P``
    (6, 6), upper triangle ``(i00, i01, i02, i11, i12, i22)``; exact for a payload symmetric
    about the x-z plane (``c_y = 0``, ``y`` a principal axis of ``I_c``: ``qchain.Chain``
    refuses another on a planar chain)."""
    return P[0, 0], P[0, 2], P[0, 4], P[2, 2], P[2, 4], P[4, 4]


@_inline
def _payload_force(P, vx, vz, vw, ax, az, aw):
    """In-plane ``P A + V x* (P V)`` (the planar force of :func:`recursive.payload_wrench`) for
    the planar twist ``(vx, vz, vw)`` and acceleration ``(ax, az, aw)``."""
    hx = P[0, 0] * vx + P[0, 2] * vz + P[0, 4] * vw
    hz = P[2, 0] * vx + P[2, 2] * vz + P[2, 4] * vw
    fx = P[0, 0] * ax + P[0, 2] * az + P[0, 4] * aw + vw * hz
    fz = P[2, 0] * ax + P[2, 2] * az + P[2, 4] * aw - vw * hx
    fw = P[4, 0] * ax + P[4, 2] * az + P[4, 4] * aw + vz * hx - vx * hz
    return fx, fz, fw


@_inline
def _planar_aba(arr, q, qd, tau, v0x, v0z, v0w, A0, qdd, ws, sc):
    alpha, w, offs, mass, radius, locked = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius, arr.locked
    n = q.shape[0]
    T, c, b, M, Di, U, u = ws.pT, ws.pc, ws.pb, ws.pM, ws.pDinv, ws.pU, ws.pu
    # pass 1: segment blocks, biases and tip maps, forwards
    vx, vz, vw = v0x, v0z, v0w
    for j in range(n):
        m = mass[j]
        iyy = 0.25 * m * radius[j] * radius[j]
        l = q[j, 0]
        ux = q[j, 1]
        ld = qd[j, 0]
        uxd = qd[j, 1]
        _segment(alpha, w, offs[j], offs[j + 1], m, iyy, l, ux, ld, uxd, vx, vz, vw, M, b, j)
        vx, vz, vw = _tip(l, ux, ld, uxd, vx, vz, vw, T, c, j)
    # pass 2: articulated inertias, backwards. IA (symmetric 3 x 3) and pA in scalars;
    # the scratch holds IA T (3, 5) at sc[0:15] and Mh (5, 5, upper triangle) at sc[15:40]
    # from the payload's in-plane inertia and bias force (vx, vz, vw: the tip's twist)
    i00, i01, i02, i11, i12, i22 = _payload_inertia(arr.payload)
    p0, p1, p2 = _payload_force(arr.payload, vx, vz, vw, 0.0, 0.0, 0.0)
    for j in range(n - 1, -1, -1):
        c0 = c[j, 0]
        c1 = c[j, 1]
        c2 = c[j, 2]
        pc0 = p0 + i00 * c0 + i01 * c1 + i02 * c2
        pc1 = p1 + i01 * c0 + i11 * c1 + i12 * c2
        pc2 = p2 + i02 * c0 + i12 * c1 + i22 * c2
        for k in range(5):
            t0 = T[j, 0, k]
            t1 = T[j, 1, k]
            t2 = T[j, 2, k]
            sc[k] = i00 * t0 + i01 * t1 + i02 * t2
            sc[5 + k] = i01 * t0 + i11 * t1 + i12 * t2
            sc[10 + k] = i02 * t0 + i12 * t1 + i22 * t2
        for a in range(5):
            t0 = T[j, 0, a]
            t1 = T[j, 1, a]
            t2 = T[j, 2, a]
            for e in range(a, 5):
                sc[15 + 5 * a + e] = M[j, a, e] + t0 * sc[e] + t1 * sc[5 + e] + t2 * sc[10 + e]
        bh0 = b[j, 0] + T[j, 0, 0] * pc0 + T[j, 1, 0] * pc1 + T[j, 2, 0] * pc2
        bh1 = b[j, 1] + T[j, 0, 1] * pc0 + T[j, 1, 1] * pc1 + T[j, 2, 1] * pc2
        bh2 = b[j, 2] + T[j, 0, 2] * pc0 + T[j, 1, 2] * pc1 + T[j, 2, 2] * pc2
        bh3 = b[j, 3] + T[j, 0, 3] * pc0 + T[j, 1, 3] * pc1 + T[j, 2, 3] * pc2
        bh4 = b[j, 4] + T[j, 0, 4] * pc0 + T[j, 1, 4] * pc1 + T[j, 2, 4] * pc2
        d00 = sc[15 + 18]
        d01 = sc[15 + 19]
        d11 = sc[15 + 24]
        u0 = tau[j, 0] - bh3
        u1 = tau[j, 1] - bh4
        U00 = sc[15 + 3]
        U10 = sc[15 + 8]
        U20 = sc[15 + 13]
        U01 = sc[15 + 4]
        U11 = sc[15 + 9]
        U21 = sc[15 + 14]
        if locked[j, 0]:
            d00 = 1.0
            d01 = 0.0
            u0 = 0.0
            U00 = U10 = U20 = 0.0
        if locked[j, 1]:
            d11 = 1.0
            d01 = 0.0
            u1 = 0.0
            U01 = U11 = U21 = 0.0
        # D^-1 (False where D is not positive definite, as aba's Cholesky)
        if not d00 > 0.0:
            return False
        r = d01 / d00
        e = d11 - r * d01
        if not e > 0.0:
            return False
        e11 = 1.0 / e
        e01 = -r * e11
        e00 = 1.0 / d00 + r * r * e11
        Di[j, 0, 0] = e00
        Di[j, 0, 1] = e01
        Di[j, 1, 0] = e01
        Di[j, 1, 1] = e11
        U[j, 0, 0] = U00
        U[j, 1, 0] = U10
        U[j, 2, 0] = U20
        U[j, 0, 1] = U01
        U[j, 1, 1] = U11
        U[j, 2, 1] = U21
        u[j, 0] = u0
        u[j, 1] = u1
        # K = U D^-1 (3, 2); IA = Mh_VV - K U^T; pA = bh_V + K u
        k00 = U00 * e00 + U01 * e01
        k01 = U00 * e01 + U01 * e11
        k10 = U10 * e00 + U11 * e01
        k11 = U10 * e01 + U11 * e11
        k20 = U20 * e00 + U21 * e01
        k21 = U20 * e01 + U21 * e11
        i00 = sc[15] - (k00 * U00 + k01 * U01)
        i01 = sc[16] - (k00 * U10 + k01 * U11)
        i02 = sc[17] - (k00 * U20 + k01 * U21)
        i11 = sc[21] - (k10 * U10 + k11 * U11)
        i12 = sc[22] - (k10 * U20 + k11 * U21)
        i22 = sc[27] - (k20 * U20 + k21 * U21)
        p0 = bh0 + k00 * u0 + k01 * u1
        p1 = bh1 + k10 * u0 + k11 * u1
        p2 = bh2 + k20 * u0 + k21 * u1
    # pass 3: accelerations, forwards
    ax = A0[0]
    az = A0[2]
    aw = A0[4]
    for j in range(n):
        r0 = u[j, 0] - (U[j, 0, 0] * ax + U[j, 1, 0] * az + U[j, 2, 0] * aw)
        r1 = u[j, 1] - (U[j, 0, 1] * ax + U[j, 1, 1] * az + U[j, 2, 1] * aw)
        dl = Di[j, 0, 0] * r0 + Di[j, 0, 1] * r1
        du = Di[j, 1, 0] * r0 + Di[j, 1, 1] * r1
        qdd[j, 0] = dl
        qdd[j, 1] = du
        qdd[j, 2] = 0.0
        nx = T[j, 0, 0] * ax + T[j, 0, 1] * az + T[j, 0, 2] * aw + T[j, 0, 4] * du + c[j, 0]
        nz = T[j, 1, 0] * ax + T[j, 1, 1] * az + T[j, 1, 2] * aw + dl + T[j, 1, 4] * du + c[j, 1]
        nw = aw + T[j, 2, 3] * dl + T[j, 2, 4] * du + c[j, 2]
        ax, az, aw = nx, nz, nw
    return True


@jit_pass
def planar_aba(arr, q, qd, tau, A0, qdd, ws, sc):
    """Articulated-body forward dynamics of a planar chain: ``qdd`` (n, 3) from
    ``M qdd + C qd + g = tau``, equal to :func:`qchain.algorithms.recursive.aba` on a fixed base.

    Parameters are those of ``recursive.aba`` for a fixed (non-floating) base at rest:
    ``arr`` the model's :class:`~qchain.algorithms.arrays.ChainArrays` (of which ``alpha, w``
    (N,) nodes and weights, ``offs`` (n + 1,) int64, ``mass, radius`` (n,) and ``locked`` are read),
    ``q, qd`` (n, 3) in curvature coordinates with ``q[:, 2] == qd[:, 2] == 0``, ``tau`` (n, 3)
    generalised forces (column 2 ignored), ``A0`` (6,) the base's apparent acceleration
    (gravity included; only its in-plane components 0, 2, 4 matter), ``qdd`` (n, 3) out
    (``qdd[:, 2] = 0``), ``arr.locked`` (n, 3) bool (columns 0 and 1 honoured, column 2 locked by
    definition), ``ws`` from :func:`planar_workspace` and ``sc`` its scratch (``ws.pscratch``, or
    any float array of :data:`qchain.model.arc.SCRATCH`). Returns False where an articulated block
    is not positive definite.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = PlanarWorkspace(*ws)
    return _planar_aba(arr, q, qd, tau, 0.0, 0.0, 0.0, A0, qdd, ws, sc)


@jit_pass
def planar_aba_moving(arr, q, qd, tau, V0, A0, qdd, ws, sc):
    """:func:`planar_aba` for a base moving in its x-z plane (a prescribed base): ``V0`` (6,)
    is the base's body twist, of which only the in-plane components 0, 2, 4 are used (the
    reduction is exact only if the others are zero)."""
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = PlanarWorkspace(*ws)
    return _planar_aba(arr, q, qd, tau, V0[0], V0[2], V0[4], A0, qdd, ws, sc)


@jit_pass
def planar_rnea(arr, q, qd, qdd, A0, tau, F0, ws, sc):
    """Inverse dynamics of a planar chain on a fixed base: ``tau = M qdd + C qd + g`` (n, 3)
    and the base wrench ``F0`` (6,), equal to :func:`qchain.algorithms.recursive.rnea` with ``V0 = 0``.

    ``q, qd, qdd`` (n, 3) in curvature coordinates with zero ``uy`` column; ``A0`` (6,) the
    base's apparent acceleration (components 0, 2, 4 used). ``tau[:, 2]`` and the out-of-plane
    components of ``F0`` are set to zero (they vanish for a planar state, see the module
    docstring). ``arr`` the model's :class:`~qchain.algorithms.arrays.ChainArrays`; ``ws`` from
    :func:`planar_workspace`; ``sc`` is not used.
    """
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    ws = PlanarWorkspace(*ws)
    alpha, w, offs, mass, radius = arr.alpha, arr.w, arr.offs, arr.mass, arr.radius
    n = q.shape[0]
    T, c, b, M = ws.pT, ws.pc, ws.pb, ws.pM
    vx = vz = vw = 0.0
    ax = A0[0]
    az = A0[2]
    aw = A0[4]
    for j in range(n):
        m = mass[j]
        iyy = 0.25 * m * radius[j] * radius[j]
        l = q[j, 0]
        ux = q[j, 1]
        ld = qd[j, 0]
        uxd = qd[j, 1]
        _segment(alpha, w, offs[j], offs[j + 1], m, iyy, l, ux, ld, uxd, vx, vz, vw, M, b, j)
        vx, vz, vw = _tip(l, ux, ld, uxd, vx, vz, vw, T, c, j)
        dl = qdd[j, 0]
        du = qdd[j, 1]
        for a in range(5):  # Q = M (A, qdd) + b, kept in b
            b[j, a] += M[j, a, 0] * ax + M[j, a, 1] * az + M[j, a, 2] * aw + M[j, a, 3] * dl + M[j, a, 4] * du
        nx = T[j, 0, 0] * ax + T[j, 0, 1] * az + T[j, 0, 2] * aw + T[j, 0, 4] * du + c[j, 0]
        nz = T[j, 1, 0] * ax + T[j, 1, 1] * az + T[j, 1, 2] * aw + dl + T[j, 1, 4] * du + c[j, 1]
        nw = aw + T[j, 2, 3] * dl + T[j, 2, 4] * du + c[j, 2]
        ax, az, aw = nx, nz, nw
    # wrench on root j + 1 from what lies beyond: at the tip, the payload's
    fx, fz, fw = _payload_force(arr.payload, vx, vz, vw, ax, az, aw)
    for j in range(n - 1, -1, -1):
        gx = b[j, 0] + T[j, 0, 0] * fx + T[j, 1, 0] * fz
        gz = b[j, 1] + T[j, 0, 1] * fx + T[j, 1, 1] * fz
        gw = b[j, 2] + T[j, 0, 2] * fx + T[j, 1, 2] * fz + fw
        tau[j, 0] = b[j, 3] + fz + T[j, 2, 3] * fw
        tau[j, 1] = b[j, 4] + T[j, 0, 4] * fx + T[j, 1, 4] * fz + T[j, 2, 4] * fw
        tau[j, 2] = 0.0
        fx, fz, fw = gx, gz, gw
    F0[0] = fx
    F0[1] = 0.0
    F0[2] = fz
    F0[3] = 0.0
    F0[4] = fw
    F0[5] = 0.0


#: Names of :func:`planar_workspace`'s arrays (``qchain.arm.data.Data`` attributes), in order.
PLANAR_WORKSPACE = PlanarWorkspace._fields


@jit
def planar_workspace(n):
    """Fresh arrays for :func:`planar_aba`: tip maps (n, 3, 5), tip biases (n, 3), segment
    forces (n, 5), segment blocks (n, 5, 5), the articulated factors ``D^-1`` (n, 2, 2),
    ``U`` (n, 3, 2), ``u`` (n, 2), and the scratch (:data:`qchain.model.arc.SCRATCH`,)."""
    return PlanarWorkspace(np.zeros((n, 3, 5)), np.zeros((n, 3)), np.zeros((n, 5)), np.zeros((n, 5, 5)),
                           np.zeros((n, 2, 2)), np.zeros((n, 3, 2)), np.zeros((n, 2)), np.zeros(SCRATCH))
