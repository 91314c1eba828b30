"""The 6D algebra of the compiled passes (numba), each formula written once: cross products of
twists and wrenches and the adjoint actions of a placement, in Pinocchio's conventions
(spatial vectors ``[linear; angular]``; a placement ``X = (R, p)`` maps its own frame into its
parent's). :mod:`qchain.model.spatial` holds the same algebra for numpy arrays (checked,
batched); ``tests/test_spatial.py`` holds these equal to it and to Pinocchio.

Each function takes anything indexable (arrays, rows of arrays, tuples; a rotation ``R`` as a
(3, 3) array or three row 3-tuples, read as ``R[r][c]``) and returns a 6-tuple,
which the caller combines (:func:`vadd`, :func:`vsub`, :func:`vmul`) and stores with
:func:`put6`, :func:`add6` or :func:`sub6`. The tuples live in registers once numba has compiled
the helpers into their callers (:data:`qchain._jit.jit_helper`); small arrays carved from one
scratch buffer do not: the compiler cannot tell that they do not overlap, so it stores and loads
them again around every write. The derivative pass written with tuples costs about a sixth less
(docs/benchmarks/README.md, "Cost of the derivatives"). A result never overwrites an argument
while it is read (``put6(a, motion_cross(a, b))`` is safe).

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): compiled code calls them on
values it has validated.
"""

from __future__ import annotations

from .._jit import jit_helper

__all__ = ["motion_cross", "force_cross", "ad_twist", "ad_inv_twist", "ad_force", "put6", "add6", "sub6", "vadd",
           "vsub", "vmul", "vscale", "columns_times", "column6", "column_dot6", "matvec63", "matvec66"]


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
    w0 = R[0][0] * v[3] + R[0][1] * v[4] + R[0][2] * v[5]
    w1 = R[1][0] * v[3] + R[1][1] * v[4] + R[1][2] * v[5]
    w2 = R[2][0] * v[3] + R[2][1] * v[4] + R[2][2] * v[5]
    return (
        R[0][0] * v[0] + R[0][1] * v[1] + R[0][2] * v[2] + (p[1] * w2 - p[2] * w1),
        R[1][0] * v[0] + R[1][1] * v[1] + R[1][2] * v[2] + (p[2] * w0 - p[0] * w2),
        R[2][0] * v[0] + R[2][1] * v[1] + R[2][2] * v[2] + (p[0] * w1 - p[1] * w0),
        w0,
        w1,
        w2,
    )


@jit_helper
def ad_inv_twist(R, p, v):
    """``Ad(X)^-1 v``: a twist (6,) of ``X``'s parent frame expressed in ``X = (R, p)``'s own,
    ``(R^T (v_l - p x v_a), R^T v_a)`` (Pinocchio's ``SE3.actInv(Motion)``)."""
    v0 = v[0] - (p[1] * v[5] - p[2] * v[4])
    v1 = v[1] - (p[2] * v[3] - p[0] * v[5])
    v2 = v[2] - (p[0] * v[4] - p[1] * v[3])
    return (
        R[0][0] * v0 + R[1][0] * v1 + R[2][0] * v2,
        R[0][1] * v0 + R[1][1] * v1 + R[2][1] * v2,
        R[0][2] * v0 + R[1][2] * v1 + R[2][2] * v2,
        R[0][0] * v[3] + R[1][0] * v[4] + R[2][0] * v[5],
        R[0][1] * v[3] + R[1][1] * v[4] + R[2][1] * v[5],
        R[0][2] * v[3] + R[1][2] * v[4] + R[2][2] * v[5],
    )


@jit_helper
def ad_force(R, p, f):
    """``Ad(X)^-T f``: a wrench (6,) in the frame of ``X = (R, p)`` expressed in its parent,
    ``(R f_l, p x R f_l + R f_a)`` (Pinocchio's ``SE3.act(Force)``)."""
    l0 = R[0][0] * f[0] + R[0][1] * f[1] + R[0][2] * f[2]
    l1 = R[1][0] * f[0] + R[1][1] * f[1] + R[1][2] * f[2]
    l2 = R[2][0] * f[0] + R[2][1] * f[1] + R[2][2] * f[2]
    return (
        l0,
        l1,
        l2,
        p[1] * l2 - p[2] * l1 + R[0][0] * f[3] + R[0][1] * f[4] + R[0][2] * f[5],
        p[2] * l0 - p[0] * l2 + R[1][0] * f[3] + R[1][1] * f[4] + R[1][2] * f[5],
        p[0] * l1 - p[1] * l0 + R[2][0] * f[3] + R[2][1] * f[4] + R[2][2] * f[5],
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


# -- 6-tuples from arrays, and their arithmetic (element by element)

@jit_helper
def vadd(a, b):
    """``a + b``."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5])


@jit_helper
def vsub(a, b):
    """``a - b``."""
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4], a[5] - b[5])


@jit_helper
def vmul(d, a):
    """``diag(d) a``: element by element (a diagonal inertia times a twist)."""
    return (d[0] * a[0], d[1] * a[1], d[2] * a[2], d[3] * a[3], d[4] * a[4], d[5] * a[5])


@jit_helper
def vscale(a, s):
    """``s a`` of a 6-tuple and a number."""
    return (a[0] * s, a[1] * s, a[2] * s, a[3] * s, a[4] * s, a[5] * s)


@jit_helper
def columns_times(cols, x):
    """``cols[0] x[0] + cols[1] x[1] + cols[2] x[2]``: a (6, 3) matrix given as its three
    columns (6-tuples) times a 3-vector (a slice Jacobian times coordinate rates)."""
    c0, c1, c2 = cols[0], cols[1], cols[2]
    x0, x1, x2 = x[0], x[1], x[2]
    return (c0[0] * x0 + c1[0] * x1 + c2[0] * x2, c0[1] * x0 + c1[1] * x1 + c2[1] * x2,
            c0[2] * x0 + c1[2] * x1 + c2[2] * x2, c0[3] * x0 + c1[3] * x1 + c2[3] * x2,
            c0[4] * x0 + c1[4] * x1 + c2[4] * x2, c0[5] * x0 + c1[5] * x1 + c2[5] * x2)


@jit_helper
def column6(M, c):
    """Column ``c`` of a (6, k) array."""
    return (M[0, c], M[1, c], M[2, c], M[3, c], M[4, c], M[5, c])


@jit_helper
def column_dot6(M, c, t):
    """``M[:, c] . t`` of a (6, k) array and a 6-vector (a column of ``S`` or ``E`` against a
    wrench)."""
    return M[0, c] * t[0] + M[1, c] * t[1] + M[2, c] * t[2] + M[3, c] * t[3] + M[4, c] * t[4] + M[5, c] * t[5]


@jit_helper
def matvec63(M, x):
    """``M x`` of a (6, 3) array and a 3-vector (a slice Jacobian times coordinate rates)."""
    return (
        M[0, 0] * x[0] + M[0, 1] * x[1] + M[0, 2] * x[2],
        M[1, 0] * x[0] + M[1, 1] * x[1] + M[1, 2] * x[2],
        M[2, 0] * x[0] + M[2, 1] * x[1] + M[2, 2] * x[2],
        M[3, 0] * x[0] + M[3, 1] * x[1] + M[3, 2] * x[2],
        M[4, 0] * x[0] + M[4, 1] * x[1] + M[4, 2] * x[2],
        M[5, 0] * x[0] + M[5, 1] * x[1] + M[5, 2] * x[2],
    )


@jit_helper
def _row66(M, r, x):
    return M[r, 0] * x[0] + M[r, 1] * x[1] + M[r, 2] * x[2] + M[r, 3] * x[3] + M[r, 4] * x[4] + M[r, 5] * x[5]


@jit_helper
def matvec66(M, x):
    """``M x`` of a (6, 6) array and a 6-vector."""
    return (_row66(M, 0, x), _row66(M, 1, x), _row66(M, 2, x), _row66(M, 3, x), _row66(M, 4, x), _row66(M, 5, x))
