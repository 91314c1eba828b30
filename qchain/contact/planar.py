"""The contact pass of a planar chain at 2-D cost (numba): what
:func:`qchain.contact.forces.contact_forces` gives for a ``planar=True`` chain, in-plane.

A planar chain (``uy = 0`` in every segment, its base moving in its own x-z plane) among
obstacles symmetric about that plane (what :mod:`qchain.scene` requires before it reduces a
scene to the planar model) has every contact point, normal, velocity and force in the plane:
:mod:`qchain.algorithms.planar` gives the argument. So this pass works on the base frame's
``(x, z)`` components and the angle about ``y``: a slice is ``(s, a1, a2, a3)`` of
:func:`qchain.algorithms.planar._node` (``p = (a2 ux, a1)``, rotation by ``alpha l ux``),
its twist ``(vx, vz, wy)``, a force ``(fx, fz, ny)``, and ``Phi^T f`` is
``(R f, pz (R f)_x - px (R f)_z + ny, alpha (f_z + ux ny), a2 f_x + a3 ux f_z + s ny)``
(planar.py's docstring). Only the signed distances are taken in the world, at the point
``p_WB + R_WB (X, 0, Z)``. The law is :func:`qchain.contact.forces.law_force` itself.

The engine's planar kernel calls it (self-contact excepted, which takes the spatial pass);
``tests/test_contact.py`` holds it equal to the spatial pass on planar chains.
"""

from __future__ import annotations

from ..algorithms.arrays import ChainArrays
from ..algorithms.planar import _node
from .._jit import jit
from ..model.arc import take1
from .distance import signed_distance
from .forces import beyond_reach, law_force

__all__ = ["planar_contact_forces"]


@jit
def planar_contact_forces(arr, kind, prm, vel, law, calpha, q, qd, R_WB, p_WB, V0, tau, F0, W, sc):
    """Add the contact forces' generalised forces to ``tau[:, 0:2]`` (n, 3; the locked ``uy``
    column untouched) and their wrench on the base (base frame, in-plane components) to ``F0``
    (6,); returns the number of active contacts. Arguments as
    :func:`qchain.contact.forces.contact_forces`' (``V0``: only its in-plane components 0, 2, 4
    are read; ``W`` (n + 1, >= 3) work array; no records, no self-contact)."""
    arr = ChainArrays(*arr)  # a plain tuple from Python (algorithms/arrays.py), named here
    n = q.shape[0]
    m = kind.shape[0]
    K = calpha.shape[0]
    o = 0
    x, o = take1(sc, o, 3)
    nrm, o = take1(sc, o, 3)
    nb, o = take1(sc, o, 3)
    vc, o = take1(sc, o, 3)
    F, o = take1(sc, o, 3)
    near, o = take1(sc, o, m)
    if beyond_reach(arr.radius, q, kind, prm, p_WB, nrm):
        return 0
    for j in range(n + 1):
        W[j, 0] = 0.0
        W[j, 1] = 0.0
        W[j, 2] = 0.0
    # the base frame's x and z axes in the world: a planar point (X, Z) is p_WB + X ex + Z ez
    ex0, ex1, ex2 = R_WB[0, 0], R_WB[1, 0], R_WB[2, 0]
    ez0, ez1, ez2 = R_WB[0, 2], R_WB[1, 2], R_WB[2, 2]
    # root j: rotation (cj, sj) (root (x, z) -> base: (cj x + sj z, -sj x + cj z)), origin, twist
    cj, sj, oX, oZ = 1.0, 0.0, 0.0, 0.0
    vx, vz, vw = V0[0], V0[2], V0[4]
    count = 0
    for j in range(n):
        l, ux, ld, uxd = q[j, 0], q[j, 1], qd[j, 0], qd[j, 1]
        r_s = arr.radius[j]
        # broad phase (contact_forces'): the arc lies within l / 2 of its middle
        s, a1, a2, a3, g1, g2, c, sn = _node(0.5, l, ux)
        px, pz = a2 * ux, a1
        X = oX + cj * px + sj * pz
        Z = oZ - sj * px + cj * pz
        for r in range(3):
            x[r] = p_WB[r] + X * R_WB[r, 0] + Z * R_WB[r, 2]
        reach = 0.5 * abs(l) + r_s
        any_near = False
        for b in range(m):
            near[b] = 1.0 if signed_distance(kind[b], prm[b], x, nrm) < reach else 0.0
            any_near = any_near or near[b] > 0.0
        if any_near:
            ell = arr.l0[j] / K
            for i in range(K):
                a = calpha[i]
                s, a1, a2, a3, g1, g2, c, sn = _node(a, l, ux)
                px, pz = a2 * ux, a1
                X = oX + cj * px + sj * pz
                Z = oZ - sj * px + cj * pz
                for r in range(3):
                    x[r] = p_WB[r] + X * R_WB[r, 0] + Z * R_WB[r, 2]
                moving = False
                for b in range(m):
                    if near[b] == 0.0:
                        continue
                    d = r_s - signed_distance(kind[b], prm[b], x, nrm)
                    if d <= 0.0:
                        continue
                    if not moving:
                        # the slice's rotation in the base (C, S) and its twist: Ad(g)^-1 V + S qd
                        C = cj * c - sj * sn
                        S = cj * sn + sj * c
                        tx = vx + pz * vw
                        tz = vz - px * vw
                        wsx = c * tx - sn * tz + a2 * uxd
                        wsz = sn * tx + c * tz + a * ld + a3 * ux * uxd
                        wy = vw + a * ux * ld + s * uxd
                        vX = C * wsx + S * wsz  # the slice centre's velocity, base frame
                        vZ = -S * wsx + C * wsz
                        moving = True
                    # the normal and the obstacle's velocity in the base frame; the surface point
                    # x - r_s n moves with v + w x arm, w = (0, wy, 0)
                    nX = ex0 * nrm[0] + ex1 * nrm[1] + ex2 * nrm[2]
                    nZ = ez0 * nrm[0] + ez1 * nrm[1] + ez2 * nrm[2]
                    aX, aZ = -r_s * nX, -r_s * nZ
                    nb[0], nb[1], nb[2] = nX, 0.0, nZ
                    vc[0] = vX + wy * aZ - (ex0 * vel[b, 0] + ex1 * vel[b, 1] + ex2 * vel[b, 2])
                    vc[1] = 0.0
                    vc[2] = vZ - wy * aX - (ez0 * vel[b, 0] + ez1 * vel[b, 1] + ez2 * vel[b, 2])
                    law_force(law, ell, d, nb, vc, F)
                    # the force at the surface point as a wrench at the slice, then Phi^T of it
                    ny = aZ * F[0] - aX * F[2]
                    frx = cj * F[0] - sj * F[2]  # root frame: R f_slice = Rj^T F
                    frz = sj * F[0] + cj * F[2]
                    W[j, 0] += frx
                    W[j, 1] += frz
                    W[j, 2] += pz * frx - px * frz + ny
                    fx = c * frx - sn * frz  # slice frame
                    fz = sn * frx + c * frz
                    tau[j, 0] += a * (fz + ux * ny)
                    tau[j, 1] += a2 * fx + a3 * ux * fz + s * ny
                    count += 1
        # the next root: the tip of segment j
        s, a1, a2, a3, g1, g2, c, sn = _node(1.0, l, ux)
        px, pz = a2 * ux, a1
        oX, oZ = oX + cj * px + sj * pz, oZ - sj * px + cj * pz
        tx = vx + pz * vw
        tz = vz - px * vw
        vx, vz, vw = c * tx - sn * tz + a2 * uxd, sn * tx + c * tz + ld + a3 * ux * uxd, vw + ux * ld + s * uxd
        cj, sj = cj * c - sj * sn, cj * sn + sj * c
    if count == 0:
        return 0
    # backward: W[j] (root j's frame) is the tip wrench of segment j - 1: Phi(1)^T of it
    for j in range(n - 1, -1, -1):
        l, ux = q[j, 0], q[j, 1]
        s, a1, a2, a3, g1, g2, c, sn = _node(1.0, l, ux)
        px, pz = a2 * ux, a1
        fx, fz, ny = W[j + 1, 0], W[j + 1, 1], W[j + 1, 2]
        rx = c * fx + sn * fz
        rz = -sn * fx + c * fz
        W[j, 0] += rx
        W[j, 1] += rz
        W[j, 2] += pz * rx - px * rz + ny
        tau[j, 0] += fz + ux * ny
        tau[j, 1] += a2 * fx + a3 * ux * fz + s * ny
    F0[0] += W[0, 0]
    F0[2] += W[0, 1]
    F0[4] += W[0, 2]
    return count
