"""Signed distances of the obstacles (numba): how far a point is outside a shape, and the
shape's outward normal there.

An obstacle is a kind (:data:`HALFSPACE`, :data:`SPHERE`, :data:`CAPSULE`, :data:`CYLINDER`,
:data:`BOX`) and a row of :data:`PARAMS` numbers, world frame, metres (the checked, user-facing
forms are in :mod:`qchain.contact.shapes`):

==========  ==================================================================
kind        parameters
==========  ==================================================================
HALFSPACE   ``c (3)`` a point of the surface, ``n (3)`` the unit outward normal
SPHERE      ``c (3)`` centre, ``R``
CAPSULE     ``a (3)``, ``b (3)`` the axis' end points, ``R`` (hemispherical ends)
CYLINDER    ``a (3)``, ``b (3)`` the axis' end points, ``R`` (flat ends)
BOX         ``c (3)`` centre, ``h (3)`` half-extents, ``R (9)`` box-to-world rotation, row-major
==========  ==================================================================

:func:`signed_distance` is exact (a 1-Lipschitz function: the broad phase of
:mod:`qchain.contact.forces` relies on it) and its normal is its gradient, where it has one;
on the medial set of a shape (a sphere's centre, a box's diagonals inside it) the normal is
one of the nearest faces'.
"""

from __future__ import annotations

import numpy as np

from .._jit import jit

__all__ = ["HALFSPACE", "SPHERE", "CAPSULE", "CYLINDER", "BOX", "PARAMS", "signed_distance"]

HALFSPACE, SPHERE, CAPSULE, CYLINDER, BOX = 0, 1, 2, 3, 4
#: numbers per obstacle row
PARAMS = 15


@jit
def _unit_or_up(x, y, z, n):
    """``n = (x, y, z) / |(x, y, z)|``, or ``(0, 0, 1)`` at the origin; returns the norm."""
    d = np.sqrt(x * x + y * y + z * z)
    if d > 0.0:
        n[0], n[1], n[2] = x / d, y / d, z / d
    else:
        n[0], n[1], n[2] = 0.0, 0.0, 1.0
    return d


@jit
def _segment_point(prm, x):
    """The point of the segment ``prm[0:3]``-``prm[3:6]`` nearest ``x``, and its axial
    parameter ``t`` in [0, 1] (unclamped as the second value)."""
    ax, ay, az = prm[3] - prm[0], prm[4] - prm[1], prm[5] - prm[2]
    L2 = ax * ax + ay * ay + az * az
    t = ((x[0] - prm[0]) * ax + (x[1] - prm[1]) * ay + (x[2] - prm[2]) * az) / L2
    tc = min(1.0, max(0.0, t))
    return prm[0] + tc * ax, prm[1] + tc * ay, prm[2] + tc * az, t


@jit
def _cylinder(prm, x, n):
    ax, ay, az = prm[3] - prm[0], prm[4] - prm[1], prm[5] - prm[2]
    L = np.sqrt(ax * ax + ay * ay + az * az)
    ux, uy, uz = ax / L, ay / L, az / L
    dx, dy, dz = x[0] - prm[0], x[1] - prm[1], x[2] - prm[2]
    s = dx * ux + dy * uy + dz * uz  # axial coordinate from a
    h = s - 0.5 * L  # from the middle
    rx, ry, rz = dx - s * ux, dy - s * uy, dz - s * uz
    rho = np.sqrt(rx * rx + ry * ry + rz * rz)
    if rho > 0.0:
        ex, ey, ez = rx / rho, ry / rho, rz / rho
    else:  # on the axis: any radial direction (u x a coordinate axis)
        if abs(uz) < 0.9:
            ex, ey, ez = -uy, ux, 0.0
        else:
            ex, ey, ez = 0.0, -uz, uy
        e = np.sqrt(ex * ex + ey * ey + ez * ez)
        ex, ey, ez = ex / e, ey / e, ez / e
    sg = 1.0 if h >= 0.0 else -1.0
    dr = rho - prm[6]
    dh = abs(h) - 0.5 * L
    if dr > 0.0 and dh > 0.0:  # beyond the rim: the nearest point is on the edge circle
        d = np.sqrt(dr * dr + dh * dh)
        n[0] = (dr * ex + dh * sg * ux) / d
        n[1] = (dr * ey + dh * sg * uy) / d
        n[2] = (dr * ez + dh * sg * uz) / d
        return d
    if dr > dh:
        n[0], n[1], n[2] = ex, ey, ez
        return dr
    n[0], n[1], n[2] = sg * ux, sg * uy, sg * uz
    return dh


@jit
def _box(prm, x, n):
    out2 = 0.0
    inside = -np.inf
    axis = 0
    sign_axis = 1.0
    nb0, nb1, nb2 = 0.0, 0.0, 0.0
    for r in range(3):  # box frame: y = R^T (x - c), R row-major in prm[6:15]
        y = (prm[6 + r] * (x[0] - prm[0]) + prm[9 + r] * (x[1] - prm[1]) + prm[12 + r] * (x[2] - prm[2]))
        sg = 1.0 if y >= 0.0 else -1.0
        qv = abs(y) - prm[3 + r]
        if qv > 0.0:
            out2 += qv * qv
            if r == 0:
                nb0 = sg * qv
            elif r == 1:
                nb1 = sg * qv
            else:
                nb2 = sg * qv
        if qv > inside:
            inside = qv
            axis = r
            sign_axis = sg
    if out2 > 0.0:
        d = np.sqrt(out2)
        nb0, nb1, nb2 = nb0 / d, nb1 / d, nb2 / d
    else:  # inside: the nearest face's normal
        d = inside
        nb0 = sign_axis if axis == 0 else 0.0
        nb1 = sign_axis if axis == 1 else 0.0
        nb2 = sign_axis if axis == 2 else 0.0
    for r in range(3):
        n[r] = prm[6 + 3 * r] * nb0 + prm[7 + 3 * r] * nb1 + prm[8 + 3 * r] * nb2
    return d


@jit
def signed_distance(kind, prm, x, n):
    """The signed distance (m) of the point ``x`` (3,) from the obstacle ``(kind, prm)``
    (positive outside), and its outward unit normal into ``n`` (3,)."""
    if kind == HALFSPACE:
        for r in range(3):
            n[r] = prm[3 + r]
        return (x[0] - prm[0]) * prm[3] + (x[1] - prm[1]) * prm[4] + (x[2] - prm[2]) * prm[5]
    if kind == SPHERE:
        return _unit_or_up(x[0] - prm[0], x[1] - prm[1], x[2] - prm[2], n) - prm[3]
    if kind == CAPSULE:
        px, py, pz, _ = _segment_point(prm, x)
        return _unit_or_up(x[0] - px, x[1] - py, x[2] - pz, n) - prm[6]
    if kind == CYLINDER:
        return _cylinder(prm, x, n)
    return _box(prm, x, n)


#: numbers per obstacle motion row: velocity (3, m/s), amplitude (3, m), frequency (Hz), phase (rad)
MOTION = 8


@jit
def move(kind, prm, motion, t, prm_t, vel):
    """The obstacles at time ``t`` (s): ``prm_t`` (m, PARAMS) their rows translated by
    ``u(t) = v t + A sin(2 pi f t + phase)`` and ``vel`` (m, 3) their velocity ``u'(t)``
    (world frame), from the motion rows ``motion`` (m, MOTION) (zeros: at rest)."""
    for b in range(kind.shape[0]):
        mo = motion[b]
        w = 2.0 * np.pi * mo[6]
        s, c = np.sin(w * t + mo[7]), np.cos(w * t + mo[7])
        for r in range(PARAMS):
            prm_t[b, r] = prm[b, r]
        for r in range(3):
            u = mo[r] * t + mo[3 + r] * s
            vel[b, r] = mo[r] + mo[3 + r] * w * c
            prm_t[b, r] += u  # the point, centre or first end point
            if kind[b] == CAPSULE or kind[b] == CYLINDER:
                prm_t[b, 3 + r] += u  # the second end point
