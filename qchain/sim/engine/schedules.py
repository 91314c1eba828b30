"""Input schedules and prescribed base motions packed into arrays for compiled code.

:func:`pack_input` turns what :func:`qchain.sim.inputs.as_input` accepts (``None``, a constant
array, a :class:`~qchain.sim.inputs.Schedule`) into ``(ints, params)``, an int64 and a float64
array; :func:`input_eval` evaluates it at a time ``t`` (s) inside numba code. A Python
controller (or a Schedule subclass this module does not know) packs to ``None``: compiled
code cannot call it, the caller keeps the Python path.

Layouts (``m`` = size of the input, ``K`` = rows of a table, arrays concatenated in order):

============  ==================  =========================================================
kind          ``ints``            ``params``
============  ==================  =========================================================
CONSTANT  0   ``(0, m)``          ``value (m)``; also ``None`` (zeros) and constant arrays
STEP      1   ``(1, m)``          ``time (1), after (m), before (m)``
RAMP      2   ``(2, m)``          ``t0 (1), t1 (1), start (m), end (m)``
SINE      3   ``(3, m)``          ``amplitude (m), frequency (m) Hz, phase (m) rad, offset (m)``
TABLE     4   ``(4, m, K)``       ``times (K) s, values (K*m), row-major (time, input)``
============  ==================  =========================================================

:func:`pack_base_motion` packs a :class:`qchain.sim.inputs.SineMotion` (its docstring gives
the motion) and :func:`base_motion_eval` gives ``(R_WB, p_WB, V_B, A_B)`` at ``t``:
``ints = (kind,)``, TRANSLATION (0) or ROTATION (1); ``params`` (18,) = ``axis (3, mount
frame), amplitude (m or rad), frequency (Hz), phase (rad), R_0 (9, row-major), p_0 (3, m)``.

The evaluations repeat the float operations of the Python ``__call__`` in the same order,
so they are equal bit for bit except where the elementary functions differ: numpy's
vectorised ``np.sin`` (used by :class:`~qchain.sim.inputs.Sine`) against the scalar libm ``sin``
numba calls (last bit), and Pinocchio's ``exp3`` and SE3 product against the Rodrigues
formula here (~1e-16).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..._jit import jit
from ...checks.convert import as_vector
from ..inputs import Constant, Ramp, Schedule, Sine, SineMotion, Step, Table, sine_value

__all__ = [
    "pack_input", "pack_inputs", "values_at", "input_eval", "pack_base_motion", "base_motion_eval",
    "CONSTANT", "STEP", "RAMP", "SINE", "TABLE", "TRANSLATION", "ROTATION",
]

CONSTANT, STEP, RAMP, SINE, TABLE = 0, 1, 2, 3, 4
TRANSLATION, ROTATION = 0, 1
_TWO_PI = 2.0 * np.pi  # the constant Sine.__call__ forms first


def _packed(kind: int, size: int, *parts, extra=()) -> tuple[np.ndarray, np.ndarray]:
    ints = np.array((kind, size, *extra), dtype=np.int64)
    params = np.concatenate([np.ravel(np.asarray(p, dtype=np.float64)) for p in parts])
    return ints, np.ascontiguousarray(params)


def pack_input(u, size: int, name: str = "input") -> tuple[np.ndarray, np.ndarray] | None:
    """``(ints, params)`` for :func:`input_eval`, or None if compiled code cannot evaluate ``u``.

    Parameters
    ----------
    u : None, array_like (size,), Schedule or callable
        ``None`` means zeros; a constant array; a Constant, Step, Ramp, Sine or Table; a
        controller ``(t, q, v)`` or ``(t)`` (returns None, as does an unknown Schedule subclass).
    size : int
        Number of values the model needs.
    name : str
        Name of the input in error messages (as :func:`qchain.sim.inputs.as_input` takes it).

    Returns
    -------
    (ints (int64), params (float64)) or None
        Layouts in the module docstring.

    Raises
    ------
    ValueError
        A schedule of the wrong size or a constant of the wrong shape or with non-finite
        entries, with :func:`~qchain.sim.inputs.as_input`'s messages.
    """
    if u is None:
        return _packed(CONSTANT, size, np.zeros(size))
    if isinstance(u, Schedule):
        kind = type(u)  # exact types only: a subclass may override __call__
        if kind not in (Constant, Step, Ramp, Sine, Table):
            return None  # a schedule of the user's (maybe without a size): checked by as_input at each call
        if u.size != size:
            raise ValueError(f"{name} schedule gives {u.size} values, the model needs {size}")  # exact types only: a subclass may override __call__
        if kind is Constant:
            return _packed(CONSTANT, size, u.value)
        if kind is Step:
            return _packed(STEP, size, [u.time], u.after, u.before)
        if kind is Ramp:
            return _packed(RAMP, size, [u.t0, u.t1], u.start, u.end)
        if kind is Sine:
            return _packed(SINE, size, u.amplitude, u.frequency, u.phase, u.offset)
        if kind is Table:
            return _packed(TABLE, size, u.times, u.values, extra=(u.times.size,))
    if callable(u):
        return None
    return _packed(CONSTANT, size, as_vector(name, u, size))


#: the kinds whose params have one length for a given size: their batches are stacked
#: attribute by attribute (the order of :func:`pack_input`'s parts)
_FIXED = {Constant: (CONSTANT, ("value",)), Step: (STEP, ("time", "after", "before")),
          Ramp: (RAMP, ("t0", "t1", "start", "end")), Sine: (SINE, ("amplitude", "frequency", "phase", "offset"))}


def pack_inputs(us: Sequence, size: int, name: str = "input") -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`pack_input` of each of the B inputs ``us``, as the rows of ``ints`` (B, k) int64
    and ``params`` (B, w) float64, zero-padded to the longest; None if one cannot be packed.

    A batch of one of qchain's fixed-layout schedules (Constant, Step, Ramp, Sine), all of
    ``size`` values, or of finite constant arrays (size,), is packed at once, without a pack an
    entry; the rows are the same numbers. Otherwise (mixed kinds, tables, None) each is packed
    and checked by :func:`pack_input`, whose errors name ``name[i]``.
    """
    B = len(us)
    kind = type(us[0]) if B else None
    if kind in _FIXED and all(type(u) is kind and u.size == size for u in us):
        code, parts = _FIXED[kind]
        params = np.concatenate([np.array([getattr(u, a) for u in us], dtype=np.float64).reshape(B, -1)
                                 for a in parts], axis=1)
        ints = np.empty((B, 2), dtype=np.int64)
        ints[:, 0], ints[:, 1] = code, size
        return ints, params
    if B and all(type(u) is np.ndarray and u.shape == (size,) and u.dtype.kind in "fiu" for u in us):
        params = np.array(us, dtype=np.float64)
        if np.isfinite(params).all():  # (else pack_input's message, naming the entry)
            ints = np.empty((B, 2), dtype=np.int64)
            ints[:, 0], ints[:, 1] = CONSTANT, size
            return ints, params
    packs = [pack_input(u, size, f"{name}[{i}]") for i, u in enumerate(us)]
    if any(p is None for p in packs):
        return None
    out = []
    for col, dtype in ((0, np.int64), (1, np.float64)):
        rows = np.zeros((B, max(p[col].size for p in packs)), dtype=dtype)
        for i, p in enumerate(packs):
            rows[i, : p[col].size] = p[col]
        out.append(rows)
    return out[0], out[1]


def values_at(us: Sequence, t: float, size: int) -> np.ndarray:
    """The B inputs ``us`` (None: zeros, a checked constant array, or one of qchain's
    schedules) at time ``t`` (s), as the rows of a (B, size) array: what each gives there, bit
    for bit. A batch of sines is evaluated at once (:func:`qchain.sim.inputs.sine_value`)."""
    if us and all(type(u) is Sine for u in us):
        return sine_value(*(np.array([getattr(u, a) for u in us]) for a in ("offset", "amplitude", "frequency", "phase")),
                          t)
    out = np.zeros((len(us), size))
    for i, u in enumerate(us):
        if u is not None:
            out[i] = u if isinstance(u, np.ndarray) else u(t)
    return out


@jit
def input_eval(ints, params, t, out):
    """Write the packed schedule's value at ``t`` (s) into ``out`` (size,).

    Equal to the Python schedule's ``__call__(t)`` bit for bit, except SINE, where numpy's
    and libm's ``sin`` may differ in the last bit (relative error <= 1e-15 of
    ``|offset| + |amplitude|``). TABLE: ``i = searchsorted(times, t, side="right")``, held
    at the first row before ``times[0]`` and at the last from ``times[-1]`` on.
    """
    kind = ints[0]
    m = ints[1]
    if kind == CONSTANT:
        for i in range(m):
            out[i] = params[i]
    elif kind == STEP:
        off = 1 if t >= params[0] else 1 + m  # after, else before
        for i in range(m):
            out[i] = params[off + i]
    elif kind == RAMP:
        s = (t - params[0]) / (params[1] - params[0])
        if 0.0 > s:  # min(max(s, 0.0), 1.0) as Python evaluates it
            s = 0.0
        if 1.0 < s:
            s = 1.0
        for i in range(m):
            a = params[2 + i]
            out[i] = a + s * (params[2 + m + i] - a)
    elif kind == SINE:
        for i in range(m):
            arg = _TWO_PI * params[m + i] * t + params[2 * m + i]
            out[i] = params[3 * m + i] + params[i] * np.sin(arg)
    else:  # TABLE
        K = ints[2]
        lo = 0  # first index with times[lo] > t (side="right"); a NaN t gives K, like numpy
        hi = K
        while lo < hi:
            mid = (lo + hi) // 2
            if params[mid] > t:
                hi = mid
            else:
                lo = mid + 1
        v = K  # the values follow the K times
        if lo == 0:
            for i in range(m):
                out[i] = params[v + i]
        elif lo >= K:
            for i in range(m):
                out[i] = params[v + (K - 1) * m + i]
        else:
            t0 = params[lo - 1]
            s = (t - t0) / (params[lo] - t0)
            for i in range(m):
                out[i] = (1.0 - s) * params[v + (lo - 1) * m + i] + s * params[v + lo * m + i]


def pack_base_motion(motion) -> tuple[np.ndarray, np.ndarray] | None:
    """``(ints, params)`` for :func:`base_motion_eval` from a :class:`qchain.sim.inputs.SineMotion`;
    None for any other ``base_motion`` callable (the caller keeps the Python path).

    Raises
    ------
    ValueError
        A SineMotion whose kind is neither "translation" nor "rotation", or whose axis is
        not 3 finite numbers.
    """

    if type(motion) is not SineMotion:
        return None
    if motion.kind not in ("translation", "rotation"):
        raise ValueError(f"SineMotion kind must be 'translation' or 'rotation', got {motion.kind!r}")
    kind = TRANSLATION if motion.kind == "translation" else ROTATION
    axis = as_vector("SineMotion axis", motion.axis, 3)
    X0 = motion.mount
    params = np.concatenate([
        axis, [motion.amplitude, motion.frequency, motion.phase],
        np.ravel(X0.rotation), X0.translation,
    ]).astype(np.float64)
    return np.array([kind], dtype=np.int64), np.ascontiguousarray(params)


@jit
def _rodrigues(wx, wy, wz):
    """``exp3(w) = cos t I + sin t / t [w] + (1 - cos t)/t^2 w w^T``, ``t = |w|`` (rad), as a
    row-major 9-tuple."""
    t2 = wx * wx + wy * wy + wz * wz
    t = math.sqrt(t2)
    c = math.cos(t)
    if t < 1e-4:  # series: truncation t^4/120 < 1e-18
        a = 1.0 - t2 / 6.0
        b = 0.5 - t2 / 24.0
    else:
        a = math.sin(t) / t
        h = math.sin(0.5 * t) / t
        b = 2.0 * h * h  # (1 - cos t)/t^2 without the cancellation
    return (
        c + b * wx * wx, b * wx * wy - a * wz, b * wx * wz + a * wy,
        b * wx * wy + a * wz, c + b * wy * wy, b * wy * wz - a * wx,
        b * wx * wz - a * wy, b * wy * wz + a * wx, c + b * wz * wz,
    )


@jit
def base_motion_eval(ints, params, t, R_WB, p_WB, V_B, A_B):
    """The packed base motion at ``t`` (s), as :meth:`qchain.sim.inputs.SineMotion.__call__`.

    Parameters
    ----------
    ints, params
        From :func:`pack_base_motion`.
    t : float
        Time (s).
    R_WB : (3, 3) out
        Base orientation in the world.
    p_WB : (3,) out
        Base origin in the world (m).
    V_B, A_B : (6,) out
        Body twist and body acceleration ``[linear; angular]`` in the base frame
        (m/s, rad/s; m/s^2, rad/s^2).
    """
    ax, ay, az = params[0], params[1], params[2]
    amp, f, phase = params[3], params[4], params[5]
    w = 2.0 * math.pi * f
    arg = w * t + phase
    s = amp * math.sin(arg)
    sd = amp * w * math.cos(arg)
    sdd = -amp * w * w * math.sin(arg)
    for i in range(6):
        V_B[i] = 0.0
        A_B[i] = 0.0
    k = 0 if ints[0] == TRANSLATION else 3
    V_B[k], V_B[k + 1], V_B[k + 2] = sd * ax, sd * ay, sd * az
    A_B[k], A_B[k + 1], A_B[k + 2] = sdd * ax, sdd * ay, sdd * az
    # X_0 * M(s): R = R_0 R_M, p = R_0 p_M + p_0
    if ints[0] == TRANSLATION:
        mx, my, mz = s * ax, s * ay, s * az
        for i in range(3):
            r0, r1, r2 = params[6 + 3 * i], params[7 + 3 * i], params[8 + 3 * i]
            R_WB[i, 0], R_WB[i, 1], R_WB[i, 2] = r0, r1, r2
            p_WB[i] = r0 * mx + r1 * my + r2 * mz + params[15 + i]
    else:
        M = _rodrigues(s * ax, s * ay, s * az)
        for i in range(3):
            r0, r1, r2 = params[6 + 3 * i], params[7 + 3 * i], params[8 + 3 * i]
            for j in range(3):
                R_WB[i, j] = r0 * M[j] + r1 * M[3 + j] + r2 * M[6 + j]
            p_WB[i] = params[15 + i]
