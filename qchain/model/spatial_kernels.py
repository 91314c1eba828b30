"""The 6D algebra of the compiled passes (numba), each formula written once: cross products of
twists and wrenches and the adjoint actions of a placement, in Pinocchio's conventions
(spatial vectors ``[linear; angular]``; a placement ``X = (R, p)`` maps its own frame into its
parent's). :mod:`qchain.model.spatial` holds the same algebra for numpy arrays (checked,
batched); ``tests/test_spatial.py`` holds these equal to it and to Pinocchio.

Each function takes anything indexable (arrays, rows of arrays, tuples) and returns a 6-tuple,
which the caller stores with :func:`put6`, :func:`add6` or :func:`sub6`: the tuple lives in
registers once numba has compiled the helpers into their callers (:data:`qchain._jit.jit_helper`),
and a result never overwrites an argument while it is read (``put6(a, motion_cross(a, b))`` is
safe).

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): compiled code calls them on
values it has validated.
"""

from __future__ import annotations

from .._jit import jit_helper

__all__ = ["motion_cross", "force_cross", "ad_twist", "ad_force", "put6", "add6", "sub6"]


@jit_helper
def motion_cross(a, b):
    """``a x b = ad(a) b`` of twists ``a = (v, w)``, ``b = (u, x)``: ``(w x u + v x x, w x x)``
    (Pinocchio's ``Motion.cross(Motion)``)."""
    return (
        a[4] * b[2] - a[5] * b[1] + a[1] * b[5] - a[2] * b[4],
        a[5] * b[0] - a[3] * b[2] + a[2] * b[3] - a[0] * b[5],
        a[3] * b[1] - a[4] * b[0] + a[0] * b[4] - a[1] * b[3],
        a[4] * b[5] - a[5] * b[4],
        a[5] * b[3] - a[3] * b[5],
        a[3] * b[4] - a[4] * b[3],
    )


@jit_helper
def force_cross(a, h):
    """``a x* h = -ad(a)^T h`` of a twist ``a = (v, w)`` and a wrench ``h = (f, n)``:
    ``(w x f, v x f + w x n)`` (Pinocchio's ``Motion.cross(Force)``)."""
    return (
        a[4] * h[2] - a[5] * h[1],
        a[5] * h[0] - a[3] * h[2],
        a[3] * h[1] - a[4] * h[0],
        a[1] * h[2] - a[2] * h[1] + a[4] * h[5] - a[5] * h[4],
        a[2] * h[0] - a[0] * h[2] + a[5] * h[3] - a[3] * h[5],
        a[0] * h[1] - a[1] * h[0] + a[3] * h[4] - a[4] * h[3],
    )


@jit_helper
def ad_twist(R, p, v):
    """``Ad(X) v``: a twist (6,) in the frame of ``X = (R, p)`` (``R`` (3, 3), ``p`` (3,) m)
    expressed in its parent, ``(R v_l + p x R v_a, R v_a)`` (Pinocchio's ``SE3.act(Motion)``)."""
    w0 = R[0, 0] * v[3] + R[0, 1] * v[4] + R[0, 2] * v[5]
    w1 = R[1, 0] * v[3] + R[1, 1] * v[4] + R[1, 2] * v[5]
    w2 = R[2, 0] * v[3] + R[2, 1] * v[4] + R[2, 2] * v[5]
    return (
        R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2] + (p[1] * w2 - p[2] * w1),
        R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2] + (p[2] * w0 - p[0] * w2),
        R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2] + (p[0] * w1 - p[1] * w0),
        w0,
        w1,
        w2,
    )


@jit_helper
def ad_force(R, p, f):
    """``Ad(X)^-T f``: a wrench (6,) in the frame of ``X = (R, p)`` expressed in its parent,
    ``(R f_l, p x R f_l + R f_a)`` (Pinocchio's ``SE3.act(Force)``)."""
    l0 = R[0, 0] * f[0] + R[0, 1] * f[1] + R[0, 2] * f[2]
    l1 = R[1, 0] * f[0] + R[1, 1] * f[1] + R[1, 2] * f[2]
    l2 = R[2, 0] * f[0] + R[2, 1] * f[1] + R[2, 2] * f[2]
    return (
        l0,
        l1,
        l2,
        p[1] * l2 - p[2] * l1 + R[0, 0] * f[3] + R[0, 1] * f[4] + R[0, 2] * f[5],
        p[2] * l0 - p[0] * l2 + R[1, 0] * f[3] + R[1, 1] * f[4] + R[1, 2] * f[5],
        p[0] * l1 - p[1] * l0 + R[2, 0] * f[3] + R[2, 1] * f[4] + R[2, 2] * f[5],
    )


@jit_helper
def put6(out, t):
    """``out[:6] = t``."""
    out[0] = t[0]
    out[1] = t[1]
    out[2] = t[2]
    out[3] = t[3]
    out[4] = t[4]
    out[5] = t[5]


@jit_helper
def add6(out, t):
    """``out[:6] += t``."""
    out[0] += t[0]
    out[1] += t[1]
    out[2] += t[2]
    out[3] += t[3]
    out[4] += t[4]
    out[5] += t[5]


@jit_helper
def sub6(out, t):
    """``out[:6] -= t``."""
    out[0] -= t[0]
    out[1] -= t[1]
    out[2] -= t[2]
    out[3] -= t[3]
    out[4] -= t[4]
    out[5] -= t[5]
