"""Compiled time steppers: whole stretches of a run without returning to Python.

Each ``advance_<method>(m, wk, it, out, c, t_stop, max_out, max_steps)`` takes steps of the
system of :mod:`qchain.sim.engine.system` (the model ``m``, an :class:`~qchain.sim.engine.system.EngineModel`,
and the workspace ``wk``) from the integrator state ``it`` (an :class:`Integrator`) until

* it reaches ``t_stop`` exactly (the last step is cut to end there: the span's end, a
  controller instant) -> :data:`AT_STOP`;
* it has written ``max_out`` output samples this call -> :data:`OUTPUT` (the driver hands
  them to ``on_sample``, then calls again);
* it has taken ``max_steps`` steps -> :data:`STEPS` (the driver checks events, progress,
  Ctrl-C and the wall-clock limit between calls);
* it fails -> :data:`FAILED` (``it.cnt[STATUS]`` says why: a system status of
  :mod:`qchain.sim.engine.system`, or :data:`TOO_SMALL`, :data:`NEWTON`).

Output samples at the times ``out[0]`` (K,) are written into ``out[1:]`` (q (K, nq),
v (K, nv), p (K, nu)) from each accepted step's dense output, so outputs never shorten a step.

The methods (``rk4``, ``midpoint``, ``dopri5``, ``radau5``), their step control and Newton
matrices, and the tolerances (on ``y = (delta, v)``, as scipy's): docs/engine.md, "Methods".

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): call the checked API.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import system
from . import tableaus as T_
from ..._jit import ejit, ejit_inner  # helpers compiled once, not inlined: each inlined copy is typed again
from .linalg import lu_factor, lu_solve

__all__ = ["Integrator", "integrator", "constants", "dense", "CODES", "advance_rk4", "advance_midpoint", "advance_dopri5", "advance_radau5",
           "ADVANCE", "AT_STOP", "OUTPUT", "STEPS", "FAILED", "TOO_SMALL", "NEWTON", "SAMPLE"]

AT_STOP, OUTPUT, STEPS, FAILED = 0, 1, 2, 3
TOO_SMALL, NEWTON, SAMPLE = 10, 11, 12  # failure reasons beside the system's statuses (SAMPLE: an output
# sample interpolated inside an accepted step failed the domain check; wk.q holds it, tf[T_FAIL] its time)

# tf: the integrator's floats (RATE: radau5's last Newton contraction as theta / (1 - theta))
T, H, T_OLD, H_LAST, RTOL, ATOL, MAX_STEP, DT, T0, H_ABS_OLD, ERR_OLD, NEWTON_TOL, RATE, JAC_T, H_LU, T_FAIL = range(16)
# cnt: its counters and flags
NSTEPS, NFEV, NJEV, NLU, NREJECT, JAC_CURRENT, LU_OK, F_OK, K_OUT, DENSE_OK, PRED_OK, STATUS, NNEWTON, LAST_ST, EVERY, \
    EMITTED = range(16)
# rows of the scratch it.tmp (one (12, N) array: numba's compile time grows with the number of
# arrays passed around), named by each method's use of them: the step's end state in the dense
# output's chart, an output sample, the right-hand side evaluated before a Jacobian (every method)
Y_END, Y_OUT, JAC_F = 10, 11, 9
SCALE, TRIAL = 0, 1  # radau5's error weights atol + rtol |y|; a trial state (midpoint: the unknown Y)
DP_NEW, DP_ERR = 2, 3  # dopri5: the trial step's end state, its error estimate
MP_F, MP_RES = 2, 4  # midpoint: the right-hand side at the midpoint, Newton's residual
# radau5: Newton's real-system increment, the step's end state, its error estimate, a solve's
# scratch, the error estimate's stage part
RD_NEWTON, RD_NEW, RD_ERR, RD_SOLVE, RD_ZE = 2, 3, 4, 5, 7

RK4, MIDPOINT, DOPRI5, RADAU5 = range(4)
CODES = {"rk4": RK4, "midpoint": MIDPOINT, "dopri5": DOPRI5, "radau5": RADAU5}
NEWTON_MAXITER = 6  # RADAU5's
EPS = float(np.finfo(float).eps)
MIDPOINT_MAXITER = 12
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0
#: radau5 keeps its step, and its Newton matrices, where the controller's next step after an
#: accepted one lies between these multiples of it (RADAU5's ``QUOT1``, ``QUOT2``): a
#: refactorisation costs O(nA^3). The lower end is scipy's (0: an accepted step is not
#: shrunk): RADAU5's 1.0 refactors for every shrink the controller asks after an accepted
#: step (more factorisations on the work-precision scenes), and took a step accepted just
#: above the floor of a coarse ``t`` below it (tests/test_simulate.py, late spans)
LU_BAND = (0.0, 1.2)
#: radau5 forms a new Jacobian after an accepted step whose Newton took more than two
#: iterations contracting slower than this (scipy's ``Radau``; RADAU5's ``THET``)
JAC_RATE = 1e-3
#: radau5 forms a new Jacobian after a step rejected on its error with a stale one (RADAU5)
REJECT_NEW_JAC = True


def constants(method: str) -> tuple:
    """The method's coefficient arrays (:mod:`qchain.sim.engine.tableaus`, scipy's numbers)."""
    if method == "dopri5":
        return (T_.DOPRI5_A.copy(), T_.DOPRI5_C.copy(), T_.DOPRI5_E.copy(), T_.DOPRI5_P.copy())
    if method == "radau5":
        return (T_.RADAU_C.copy(), T_.RADAU_E.copy(), T_.RADAU_T.copy(), T_.RADAU_TI.copy(), T_.RADAU_P.copy(),
                T_.RADAU_MU.copy())
    return (np.zeros((1, 1)),)


class Integrator(NamedTuple):
    """An integrator's state (:func:`integrator`) for ``nA`` free coordinates, state size
    ``N = 2 nA``: named arrays, which numba compiles with attribute access; the scalars it
    updates live in ``tf`` and ``cnt`` (a tuple's fields are not assignable).

    Attributes
    ----------
    y, y_old : (N,) float
        The state ``(delta, v_A)`` now and at the last step's start.
    f : (N,) float
        The right-hand side at ``y`` (first same as last; ``cnt[F_OK]`` says it is current).
    K : (15, N) float
        Stages, the dense output's coefficients, radau5's collocation values.
    tf : (16,) float
        The floats, indexed by :data:`T`, :data:`H`, ... (s, tolerances, rates).
    cnt : (16,) int64
        Counters and flags, indexed by :data:`NSTEPS`, :data:`NFEV`, ...
    Jq, Jv : (nA, nA) float
        The exact Jacobian blocks ``da_A/d(delta)`` (1/s^2) and ``da_A/dv_A`` (1/s).
    LUr, piv_r : (nA, nA) float, (nA,) int64
        The real Newton matrix's LU factors and pivots.
    LUc, piv_c : (nA, nA) complex, (nA,) int64
        radau5's complex Newton matrix's.
    tmp : (12, N) float
        Scratch rows (:data:`TRIAL`, :data:`Y_END`, ...).
    ctmp : (4, nA) complex
        radau5's complex scratch.
    qc : (nq,) float
        The chart the dense output is in.
    """

    y: np.ndarray
    y_old: np.ndarray
    f: np.ndarray
    K: np.ndarray
    tf: np.ndarray
    cnt: np.ndarray
    Jq: np.ndarray
    Jv: np.ndarray
    LUr: np.ndarray
    piv_r: np.ndarray
    LUc: np.ndarray
    piv_c: np.ndarray
    tmp: np.ndarray
    ctmp: np.ndarray
    qc: np.ndarray


def integrator(nA: int, nq: int) -> Integrator:
    """A fresh :class:`Integrator` for ``nA`` free coordinates and ``nq`` configuration ones."""
    N = 2 * nA
    tf = np.zeros(16)
    tf[JAC_T] = -1.0
    return Integrator(y=np.zeros(N), y_old=np.zeros(N), f=np.zeros(N), K=np.zeros((15, N)), tf=tf,
                      cnt=np.zeros(16, dtype=np.int64), Jq=np.zeros((nA, nA)), Jv=np.zeros((nA, nA)),
                      LUr=np.zeros((nA, nA)), piv_r=np.zeros(nA, dtype=np.int64),
                      LUc=np.zeros((nA, nA), dtype=np.complex128), piv_c=np.zeros(nA, dtype=np.int64),
                      tmp=np.zeros((12, N)), ctmp=np.zeros((4, nA), dtype=np.complex128), qc=np.zeros(nq))


# ------------------------------------------------------------------------------- shared


@ejit_inner
def _f(fs, m, wk, it, t, y, out):
    it.cnt[NFEV] += 1
    st = fs[0](m, wk, t, y, out)
    if st != 0:  # where and why the last evaluation failed, for the message if the run stops
        it.tf[T_FAIL] = t
        it.cnt[LAST_ST] = st
    return st


@ejit_inner
def _jacobian(fs, m, wk, it, t, y, Jq, Jv):
    """The exact Jacobian at ``(t, y)``: the right-hand side first (the Jacobian kernel reuses
    its forward pass; its result goes to a scratch row, not counted in ``nfev``)."""
    st = fs[0](m, wk, t, y, it.tmp[JAC_F])
    if st != 0:
        return st
    return fs[1](m, wk, t, y, Jq, Jv)


@ejit_inner
def _norm(e, y0, y1, rtol, atol):
    """RMS of ``e / (atol + rtol max(|y0|, |y1|))``."""
    acc = 0.0
    for i in range(e.shape[0]):
        sc = atol + rtol * max(abs(y0[i]), abs(y1[i]))
        acc += (e[i] / sc) ** 2
    return np.sqrt(acc / e.shape[0])


@ejit  # also called from Python (events root-find on the dense output)
def dense(method, it, c, s, yout):
    """The last step's dense output at time ``s`` into ``yout`` (N,)."""
    y, yold, K, tf = it.tmp[Y_END], it.y_old, it.K, it.tf
    hl = tf[H_LAST]
    x = (s - tf[T_OLD]) / hl if hl > 0.0 else 1.0
    N = y.shape[0]
    nA = N // 2
    if method == DOPRI5:
        for i in range(N):
            yout[i] = yold[i] + hl * x * (K[7, i] + x * (K[8, i] + x * (K[9, i] + x * K[10, i])))
    elif method == RADAU5:
        for i in range(N):
            yout[i] = yold[i] + x * (K[9, i] + x * (K[10, i] + x * K[11, i]))
    else:  # cubic Hermite of the positions on their rates at both ends; velocities linear
        h00 = (1.0 + 2.0 * x) * (1.0 - x) ** 2
        h10 = x * (1.0 - x) ** 2
        h01 = x * x * (3.0 - 2.0 * x)
        h11 = x * x * (x - 1.0)
        for i in range(nA):
            yout[i] = h00 * yold[i] + h01 * y[i] + hl * (h10 * K[8, i] + h11 * K[9, i])
            yout[nA + i] = (1.0 - x) * yold[nA + i] + x * y[nA + i]


@ejit_inner
def _emit(method, m, wk, it, out, c, budget):
    """Write the outputs that fall in the last accepted step (up to ``budget``); returns how
    many were written. A sample outside the model's domain (an interpolant can overshoot where a
    step ends near the domain's boundary) is not written: ``cnt[STATUS]`` becomes
    :data:`SAMPLE` and the run fails there."""
    t_out, Qo, Vo, Po = out
    cnt, tf = it.cnt, it.tf
    if cnt[DENSE_OK] == 0:
        return 0
    t = tf[T]
    ys = it.tmp[Y_OUT]
    k = cnt[K_OUT]
    wrote = 0
    if cnt[EVERY] == 1:  # a sample at the end of every step (no t_eval)
        if cnt[EMITTED] != cnt[NSTEPS] and budget > 0 and k < t_out.shape[0]:
            t_out[k] = t
            system.configuration(m, wk, it.qc, it.tmp[Y_END])
            system.copy(Qo[k], wk.q)
            system.copy(Vo[k], wk.v)
            system.inputs(m, wk, t)
            system.copy(Po[k], wk.p)
            cnt[K_OUT] = k + 1
            cnt[EMITTED] = cnt[NSTEPS]
            return 1
        return 0
    while k < t_out.shape[0] and wrote < budget and t_out[k] <= t:
        s = t_out[k]
        if s == t:
            system.copy(ys, it.tmp[Y_END])
        else:
            dense(method, it, c, s, ys)
        system.configuration(m, wk, it.qc, ys)
        if system.check(m, wk, wk.q) != 0:  # the interpolant left the domain the step's ends are in
            tf[T_FAIL] = s
            cnt[STATUS] = SAMPLE  # (the next _before_step fails the run: the samples before this one kept)
            break
        system.copy(Qo[k], wk.q)
        system.copy(Vo[k], wk.v)
        system.inputs(m, wk, s)
        system.copy(Po[k], wk.p)
        k += 1
        wrote += 1
    cnt[K_OUT] = k
    return wrote


@ejit_inner
def _accepted(m, wk, it, t, h, t_new, fixed):
    """After an accepted step from ``t`` to ``t_new`` (length ``h``): record it for the dense
    output, count it and move the chart where the base has turned far (every step for the
    fixed-step methods, whose steps start at ``delta = 0``)."""
    tf = it.tf
    tf[T_OLD] = t
    tf[H_LAST] = h
    tf[T] = t_new
    cnt = it.cnt
    cnt[NSTEPS] += 1
    cnt[DENSE_OK] = 1
    system.copy(it.qc, wk.q_chart)  # the chart the dense output is in
    y = it.y
    system.copy(it.tmp[Y_END], y)
    nA = y.shape[0] // 2
    move = fixed
    if m.base == system.FLOATING and not fixed:
        for i in range(6):
            if abs(y[i]) > system.RECENTER:
                move = True
    if move:
        system.configuration(m, wk, wk.q_chart, y)
        system.copy(wk.q_chart, wk.q)
        # the dense output stays valid in its own chart (it.qc); y restarts at delta = 0
        for i in range(nA):
            y[i] = 0.0
        cnt[F_OK] = 0
        cnt[PRED_OK] = 0


@ejit_inner
def _end_state(m, wk, it, t, y):
    """The status of the configuration at ``y`` at time ``t`` (a fixed step's end is checked
    before it is accepted, so a run stops on the last valid state: ``y`` is set back to
    ``it.y_old`` and the status recorded where it fails)."""
    system.configuration(m, wk, wk.q_chart, y)
    st = system.check(m, wk, wk.q)
    if st != 0:
        it.tf[T_FAIL] = t
        system.copy(y, it.y_old)
        it.cnt[STATUS] = st
    return st


@ejit_inner
def _trial_end(it, t, t_stop):
    """The end of an adaptive method's trial step from ``t``: the proposed step ``tf[H]``
    capped by ``max_step`` and cut to end at ``t_stop`` (never leaving a sliver under a
    hundredth of a step before it); NaN, with the reason in ``cnt[STATUS]``, where the step
    has shrunk below its floor (the last failed evaluation's status if one made it shrink)."""
    tf, cnt = it.tf, it.cnt
    h = tf[H]
    if h < 10.0 * abs(np.nextafter(t, np.inf) - t):
        cnt[STATUS] = cnt[LAST_ST] if cnt[LAST_ST] != 0 else TOO_SMALL
        return np.nan
    h = min(h, tf[MAX_STEP])
    if t + h >= t_stop or t_stop - (t + h) < 1e-2 * h:
        return t_stop
    return t + h


# ------------------------------------------------------------------------------- fixed step


@ejit_inner
def _fixed_next(tf, t_stop):
    """The next grid time ``t0 + k dt`` after ``t`` (no drift over long runs), cut at ``t_stop``."""
    t, t0, dt = tf[T], tf[T0], tf[DT]
    k = np.floor((t - t0) / dt + 1e-9) + 1.0
    t_new = t0 + k * dt
    if t_new - t < 1e-9 * dt:
        t_new += dt
    return min(t_new, t_stop)


@ejit_inner
def _before_step(fs, m, wk, it, t_stop, steps, max_steps, need_f):
    """What an ``advance`` does before a step: the code to return at ``t_stop`` or after
    ``max_steps``, :data:`FAILED` if ``f`` at the step's start (``need_f``) cannot be had,
    else -1 (take the step)."""
    tf, cnt = it.tf, it.cnt
    if cnt[STATUS] != 0:  # a sample failed its domain check (_emit)
        return FAILED
    if tf[T] >= t_stop:
        return AT_STOP
    if steps >= max_steps:
        return STEPS
    if need_f and cnt[F_OK] == 0:
        st = _f(fs, m, wk, it, tf[T], it.y, it.f)
        if st != 0:
            cnt[STATUS] = st
            return FAILED
        cnt[F_OK] = 1
    return -1


@ejit
def advance_rk4(fs, m, wk, it, out, c, t_stop, max_out, max_steps):
    y, yold, K, tf, cnt = it.y, it.y_old, it.K, it.tf, it.cnt
    N = y.shape[0]
    nA = N // 2
    yt = it.tmp[TRIAL]
    wrote = _emit(RK4, m, wk, it, out, c, max_out)
    steps = 0
    while wrote < max_out:
        code = _before_step(fs, m, wk, it, t_stop, steps, max_steps, False)
        if code >= 0:
            return code
        t = tf[T]
        t_new = _fixed_next(tf, t_stop)
        h = t_new - t
        st = _f(fs, m, wk, it, t, y, K[0])
        for i in range(N):
            yt[i] = y[i] + 0.5 * h * K[0, i]
        if st == 0:
            st = _f(fs, m, wk, it, t + 0.5 * h, yt, K[1])
        for i in range(N):
            yt[i] = y[i] + 0.5 * h * K[1, i]
        if st == 0:
            st = _f(fs, m, wk, it, t + 0.5 * h, yt, K[2])
        for i in range(N):
            yt[i] = y[i] + h * K[2, i]
        if st == 0:
            st = _f(fs, m, wk, it, t_new, yt, K[3])
        if st != 0:
            cnt[STATUS] = st
            return FAILED
        system.copy(yold, y)
        for i in range(N):
            y[i] = y[i] + h / 6.0 * (K[0, i] + 2.0 * K[1, i] + 2.0 * K[2, i] + K[3, i])
        if _end_state(m, wk, it, t_new, y) != 0:
            return FAILED
        system.copy(K[8, :nA], K[0, :nA])
        system.position_rate(m, y, K[9])
        steps += 1
        _accepted(m, wk, it, t, h, t_new, True)
        wrote += _emit(RK4, m, wk, it, out, c, max_out - wrote)
    return OUTPUT


@ejit_inner
def _same_step(h, h_lu):
    """Whether a factorisation for the step ``h_lu`` serves the step ``h``: equal but for the
    rounding of ``t + h - t`` (a fixed step's ``t0 + k dt`` grid, a step cut at ``t_stop``
    by a few ulp), which a comparison with ``!=`` took for a new step size and refactored."""
    return abs(h - h_lu) <= 1e-10 * h_lu


@ejit_inner
def _midpoint_matrix(fs, m, wk, it, t, y, h, new_jac):
    """Factor ``I - h/2 Jv - h^2/4 Jq``: with a new exact Jacobian at ``(t, y)`` if ``new_jac``
    (or none was formed yet), else with the one kept (the step changed, not the model)."""
    Jq, Jv, LU, piv, cnt = it.Jq, it.Jv, it.LUr, it.piv_r, it.cnt
    nA = Jq.shape[0]
    if new_jac or cnt[NJEV] == 0:
        cnt[NJEV] += 1
        st = _jacobian(fs, m, wk, it, t, y, Jq, Jv)
        if st != 0:
            return st
        it.tf[JAC_T] = t
    for r in range(nA):
        for k in range(nA):
            LU[r, k] = -0.5 * h * Jv[r, k] - 0.25 * h * h * Jq[r, k]
        LU[r, r] += 1.0
    cnt[NLU] += 1
    if not lu_factor(LU, piv):
        return system.SINGULAR
    it.tf[H_LU] = h  # the step the factorisation is for
    cnt[LU_OK] = 1
    return 0


@ejit
def advance_midpoint(fs, m, wk, it, out, c, t_stop, max_out, max_steps):
    """Implicit midpoint: ``Y = y + h/2 f(Y)``, ``y1 = 2 Y - y``; with ``Y = (h/2 V, V)`` from
    ``delta = 0`` the unknown is the midpoint velocity ``V``; ``q1 = q (+) h V``,
    ``v1 = 2 V - v``."""
    y, yold, K, tf, cnt = it.y, it.y_old, it.K, it.tf, it.cnt
    N = y.shape[0]
    nA = N // 2
    Y, F, R = it.tmp[TRIAL], it.tmp[MP_F], it.tmp[MP_RES]
    wrote = _emit(MIDPOINT, m, wk, it, out, c, max_out)
    steps = 0
    tol = 1e-10
    while wrote < max_out:
        code = _before_step(fs, m, wk, it, t_stop, steps, max_steps, False)
        if code >= 0:
            return code
        t = tf[T]
        t_new = _fixed_next(tf, t_stop)
        h = t_new - t
        tm = t + 0.5 * h
        if cnt[LU_OK] == 1 and not _same_step(h, tf[H_LU]):
            cnt[LU_OK] = 0
        # first guess: V = v + h/2 a_prev (the last step's midpoint acceleration)
        for i in range(nA):
            Y[nA + i] = y[nA + i] + 0.5 * h * K[1, nA + i]
        converged = False
        fresh = False  # the Jacobian was formed in this step
        itn_fresh = 0
        res_old = np.inf
        st = 0
        for itn in range(2 * MIDPOINT_MAXITER):
            for i in range(nA):
                Y[i] = 0.5 * h * Y[nA + i]
            st = _f(fs, m, wk, it, tm, Y, F)
            if st != 0:
                break
            vmax = 0.0
            res = 0.0
            for i in range(nA):
                R[i] = Y[nA + i] - y[nA + i] - 0.5 * h * F[nA + i]
                res = max(res, abs(R[i]))
                vmax = max(vmax, abs(Y[nA + i]))
            if not np.isfinite(res):
                st = system.NONFINITE
                break
            cnt[NNEWTON] += 1
            if res <= tol * (1.0 + vmax):
                converged = True
                break
            slow = not fresh and itn > 0 and res > 0.5 * res_old  # a stale Jacobian slows Newton
            if cnt[LU_OK] == 0 or slow:
                # none yet, or for another step (with the Jacobian kept), or a new Jacobian
                njev = cnt[NJEV]
                st = _midpoint_matrix(fs, m, wk, it, tm, Y, h, slow)
                if st != 0:
                    break
                if cnt[NJEV] != njev:
                    fresh = True
                    itn_fresh = itn
            elif fresh and itn - itn_fresh >= MIDPOINT_MAXITER:
                break
            res_old = res
            lu_solve(it.LUr, it.piv_r, R[:nA])
            for i in range(nA):
                Y[nA + i] -= R[i]
        if not converged:
            cnt[STATUS] = st if st != 0 else NEWTON
            return FAILED
        system.copy(yold, y)
        for i in range(nA):
            K[1, nA + i] = F[nA + i]
            y[i] = y[i] + h * Y[nA + i]
            y[nA + i] = 2.0 * Y[nA + i] - y[nA + i]
        if _end_state(m, wk, it, t_new, y) != 0:
            return FAILED
        system.position_rate(m, yold, K[8])
        system.position_rate(m, y, K[9])
        steps += 1
        _accepted(m, wk, it, t, h, t_new, True)
        cnt[F_OK] = 1
        wrote += _emit(MIDPOINT, m, wk, it, out, c, max_out - wrote)
    return OUTPUT


# ------------------------------------------------------------------------------- dopri5


@ejit
def advance_dopri5(fs, m, wk, it, out, c, t_stop, max_out, max_steps):
    A, C, E, P = c
    y, yold, f, K, tf, cnt = it.y, it.y_old, it.f, it.K, it.tf, it.cnt
    N = y.shape[0]
    yt, yn, err = it.tmp[TRIAL], it.tmp[DP_NEW], it.tmp[DP_ERR]
    wrote = _emit(DOPRI5, m, wk, it, out, c, max_out)
    steps = 0
    rtol, atol = tf[RTOL], tf[ATOL]
    while wrote < max_out:
        code = _before_step(fs, m, wk, it, t_stop, steps, max_steps, True)
        if code >= 0:
            return code
        t = tf[T]
        rejected = False
        while True:
            h = tf[H]
            t_new = _trial_end(it, t, t_stop)
            if not t_new == t_new:
                return FAILED
            trial = h
            h = t_new - t
            system.copy(K[0], f)
            st = 0
            for s in range(1, 6):
                for i in range(N):
                    acc = 0.0
                    for k in range(s):
                        acc += A[s, k] * K[k, i]
                    yt[i] = y[i] + h * acc
                st = _f(fs, m, wk, it, t + C[s] * h, yt, K[s])
                if st != 0:
                    break
            if st == 0:
                for i in range(N):
                    acc = 0.0
                    for k in range(6):
                        acc += A[6, k] * K[k, i]
                    yn[i] = y[i] + h * acc
                st = _f(fs, m, wk, it, t_new, yn, K[6])
            if st == 0:
                for i in range(N):
                    acc = 0.0
                    for k in range(7):
                        acc += E[k] * K[k, i]
                    err[i] = h * acc
                en = _norm(err, y, yn, rtol, atol)
            else:
                en = np.inf  # a stage left the model's domain: a smaller step
            if en < 1.0:
                fac = MAX_FACTOR if en == 0.0 else min(MAX_FACTOR, SAFETY * en ** -0.2)
                if rejected:
                    fac = min(1.0, fac)
                # a step cut short at t_stop does not shrink the next one
                tf[H] = max(h * fac, trial) if h < trial and not rejected else h * fac
                break
            cnt[NREJECT] += 1
            if st != 0:
                cnt[LAST_ST] = st
                tf[H] = 0.25 * h
            else:
                tf[H] = h * max(MIN_FACTOR, SAFETY * en ** -0.2)
            rejected = True
        cnt[LAST_ST] = 0
        system.copy(yold, y)
        system.copy(y, yn)
        system.copy(f, K[6])
        for r in range(4):
            for i in range(N):
                acc = 0.0
                for k in range(7):
                    acc += K[k, i] * P[k, r]
                K[7 + r, i] = acc
        steps += 1
        _accepted(m, wk, it, t, h, t_new, False)
        wrote += _emit(DOPRI5, m, wk, it, out, c, max_out - wrote)
    return OUTPUT


# ------------------------------------------------------------------------------- radau5


@ejit_inner
def _radau_factor(it, h, mu):
    """Factor the real and complex Newton matrices of half size at step ``h``:
    ``c^2 I - c Jv - Jq`` with ``c = mu_real / h`` and ``c = mu_complex / h``."""
    Jq, Jv, LUr, pr, LUc, pc, cnt = it.Jq, it.Jv, it.LUr, it.piv_r, it.LUc, it.piv_c, it.cnt
    nA = Jq.shape[0]
    cr = mu[0] / h
    cc = complex(mu[1], mu[2]) / h
    for r in range(nA):
        for k in range(nA):
            LUr[r, k] = -cr * Jv[r, k] - Jq[r, k]
            LUc[r, k] = -cc * Jv[r, k] - Jq[r, k]
        LUr[r, r] += cr * cr
        LUc[r, r] += cc * cc
    cnt[NLU] += 2
    ok = lu_factor(LUr, pr) and lu_factor(LUc, pc)
    cnt[LU_OK] = 1 if ok else 0
    return ok


@ejit_inner
def _radau_solve(it, c_, LU, piv, rx, rv, Jq, tmpv):
    """Solve ``(c I - J) (dx, dv) = (rx, rv)`` in place through the half-size factor:
    ``dv = LU^-1 (c rv + Jq rx)``, ``dx = (rx + dv) / c``."""
    nA = rx.shape[0]
    for r in range(nA):
        acc = c_ * rv[r]
        for k in range(nA):
            acc += Jq[r, k] * rx[k]
        tmpv[r] = acc
    lu_solve(LU, piv, tmpv)
    for r in range(nA):
        rv[r] = tmpv[r]
        rx[r] = (rx[r] + tmpv[r]) / c_


@ejit_inner
def _radau_newton(fs, m, wk, it, c, t, h, scale):
    """Simplified Newton for the collocation system (Hairer and Wanner IV.8): returns
    ``(converged, iterations, rate)``; ``Z = K[0:3]``, ``F = K[3:6]``, ``W = K[6:9]``."""
    C, E, Tm, TI, P, mu = c
    y, K, tf = it.y, it.K, it.tf
    N = y.shape[0]
    nA = N // 2
    Z, F, W = K[0:3], K[3:6], K[6:9]
    yt = it.tmp[TRIAL]
    fr = it.tmp[RD_NEWTON]
    ct = it.ctmp
    Jq = it.Jq
    cr = mu[0] / h
    cc = complex(mu[1], mu[2]) / h
    tol = tf[NEWTON_TOL]
    # RADAU5's FACCON: the last converged Newton's theta / (1 - theta), relaxed at each
    # attempt, judges a first iteration from the predictor; without a predictor (the first
    # step, a moved chart) a first iteration is never judged converged
    faccon = max(tf[RATE], EPS) ** 0.8 if it.cnt[PRED_OK] == 1 else 1e300
    for i in range(N):  # W = TI Z
        for a in range(3):
            W[a, i] = TI[a, 0] * Z[0, i] + TI[a, 1] * Z[1, i] + TI[a, 2] * Z[2, i]
    dw_old = 0.0
    rate = -1.0
    for k in range(NEWTON_MAXITER):
        for s in range(3):
            for i in range(N):
                yt[i] = y[i] + Z[s, i]
            st = _f(fs, m, wk, it, t + C[s] * h, yt, F[s])
            if st != 0:
                return False, k + 1, rate
        # real part: TI[0] F - cr W0 ; complex part: (TI[1] + i TI[2]) F - cc (W1 + i W2)
        for i in range(N):
            fr[i] = TI[0, 0] * F[0, i] + TI[0, 1] * F[1, i] + TI[0, 2] * F[2, i] - cr * W[0, i]
        for i in range(nA):
            for part in range(2):
                j = i + part * nA
                g = complex(TI[1, 0] * F[0, j] + TI[1, 1] * F[1, j] + TI[1, 2] * F[2, j],
                            TI[2, 0] * F[0, j] + TI[2, 1] * F[1, j] + TI[2, 2] * F[2, j])
                ct[part, i] = g - cc * complex(W[1, j], W[2, j])
        _radau_solve(it, cr, it.LUr, it.piv_r, fr[:nA], fr[nA:], Jq, it.tmp[RD_SOLVE][:nA])
        _radau_solve(it, cc, it.LUc, it.piv_c, ct[0], ct[1], Jq, ct[2])
        acc = 0.0
        for i in range(N):
            part = i // nA
            cz = ct[part, i - part * nA]
            acc += (fr[i] / scale[i]) ** 2 + (cz.real / scale[i]) ** 2 + (cz.imag / scale[i]) ** 2
        dw = np.sqrt(acc / (3 * N))
        if not np.isfinite(dw):
            return False, k + 1, rate
        if k > 0:
            rate = dw / dw_old
            if rate >= 1.0 or rate ** (NEWTON_MAXITER - k) / (1.0 - rate) * dw > tol:
                return False, k + 1, rate
            faccon = rate / (1.0 - rate)
        for i in range(N):
            part = i // nA
            cz = ct[part, i - part * nA]
            W[0, i] += fr[i]
            W[1, i] += cz.real
            W[2, i] += cz.imag
        for i in range(N):
            for a in range(3):
                Z[a, i] = Tm[a, 0] * W[0, i] + Tm[a, 1] * W[1, i] + Tm[a, 2] * W[2, i]
        if dw == 0.0 or faccon * dw < tol:
            tf[RATE] = faccon
            return True, k + 1, rate
        dw_old = dw
    return False, NEWTON_MAXITER, rate


@ejit_inner
def _radau_jacobian(fs, m, wk, it, t):
    """The exact Jacobian at the step's start ``(t, it.y)``; the factorisations go stale."""
    it.cnt[NJEV] += 1
    st = _jacobian(fs, m, wk, it, t, it.y, it.Jq, it.Jv)
    it.tf[JAC_T] = t
    it.cnt[JAC_CURRENT] = 1
    it.cnt[LU_OK] = 0
    return st


@ejit
def advance_radau5(fs, m, wk, it, out, c, t_stop, max_out, max_steps):
    C, E, Tm, TI, P, mu = c
    y, yold, f, K, tf, cnt = it.y, it.y_old, it.f, it.K, it.tf, it.cnt
    N = y.shape[0]
    nA = N // 2
    Z, Q, Z0 = K[0:3], K[9:12], K[12:15]
    scale, yn, err, yt = it.tmp[SCALE], it.tmp[RD_NEW], it.tmp[RD_ERR], it.tmp[TRIAL]
    Jq = it.Jq
    rtol, atol = tf[RTOL], tf[ATOL]
    wrote = _emit(RADAU5, m, wk, it, out, c, max_out)
    steps = 0
    while wrote < max_out:
        code = _before_step(fs, m, wk, it, t_stop, steps, max_steps, True)
        if code >= 0:
            return code
        t = tf[T]
        if cnt[NJEV] == 0:  # the first step: a Jacobian at the start
            st = _radau_jacobian(fs, m, wk, it, t)
            if st != 0:
                cnt[STATUS] = st
                return FAILED
        rejected = False
        while True:
            h = tf[H]
            t_new = _trial_end(it, t, t_stop)
            if not t_new == t_new:
                return FAILED
            if not _same_step(t_new - t, tf[H_LU]):
                cnt[LU_OK] = 0
            trial = h
            h = t_new - t
            # predictor: the last step's collocation polynomial, extrapolated
            if cnt[PRED_OK] == 1:
                hl = tf[H_LAST]
                for s in range(3):
                    x = 1.0 + C[s] * h / hl
                    for i in range(N):
                        Z0[s, i] = yold[i] + x * (Q[0, i] + x * (Q[1, i] + x * Q[2, i])) - y[i]
            else:
                Z0[:, :] = 0.0
            for i in range(N):
                scale[i] = atol + rtol * abs(y[i])
            converged = False
            n_iter = 0
            rate = -1.0
            while not converged:
                if cnt[LU_OK] == 0:
                    if not _radau_factor(it, h, mu):
                        break
                    tf[H_LU] = h
                for s in range(3):
                    system.copy(Z[s], Z0[s])
                converged, n_iter, rate = _radau_newton(fs, m, wk, it, c, t, h, scale)
                cnt[NNEWTON] += n_iter
                if not converged:
                    if cnt[JAC_CURRENT] == 1:
                        break
                    st = _radau_jacobian(fs, m, wk, it, t)
                    if st != 0:
                        cnt[LAST_ST] = st
                        break
            if not converged:
                cnt[NREJECT] += 1
                tf[H] = 0.5 * h
                cnt[LU_OK] = 0
                rejected = True
                continue
            for i in range(N):
                yn[i] = y[i] + Z[2, i]
                scale[i] = atol + rtol * max(abs(y[i]), abs(yn[i]))
            # error estimate: (mu_real/h - J)^-1 (f + (E . Z) / h)
            for i in range(N):
                err[i] = f[i] + (E[0] * Z[0, i] + E[1] * Z[1, i] + E[2] * Z[2, i]) / h
            ze = it.tmp[RD_ZE]
            for i in range(N):
                ze[i] = err[i] - f[i]
            _radau_solve(it, mu[0] / h, it.LUr, it.piv_r, err[:nA], err[nA:], Jq, it.tmp[RD_SOLVE][:nA])
            acc = 0.0
            for i in range(N):
                acc += (err[i] / scale[i]) ** 2
            en = np.sqrt(acc / N)
            safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + n_iter)
            if rejected and en > 1.0:  # the estimate filtered once more (Hairer and Wanner)
                for i in range(N):
                    yt[i] = y[i] + err[i]
                if _f(fs, m, wk, it, t, yt, err) == 0:
                    for i in range(N):
                        err[i] += ze[i]
                    _radau_solve(it, mu[0] / h, it.LUr, it.piv_r, err[:nA], err[nA:], Jq, it.tmp[RD_SOLVE][:nA])
                    acc = 0.0
                    for i in range(N):
                        acc += (err[i] / scale[i]) ** 2
                    en = np.sqrt(acc / N)
            if en > 1.0:
                fac = _predict(h, tf, en)
                tf[H] = h * max(MIN_FACTOR, safety * fac)
                cnt[NREJECT] += 1
                cnt[LU_OK] = 0
                rejected = True
                if cnt[JAC_CURRENT] == 0 and REJECT_NEW_JAC:
                    # a stale Jacobian also filters the error estimate: Hairer and Wanner
                    # retry a rejected step with a new one (their RADAU5, "step is rejected")
                    st = _radau_jacobian(fs, m, wk, it, t)
                    if st != 0:
                        cnt[STATUS] = st
                        return FAILED
                continue
            break
        # accepted
        cnt[LAST_ST] = 0
        # a new Jacobian after a slow Newton (scipy's rule: more than two iterations at a
        # contraction rate above JAC_RATE); else the factorised step and its matrices kept
        # where the controller's next one, max_step counted, lies in LU_BAND of it
        recompute_jac = n_iter > 2 and rate > JAC_RATE
        fac = min(MAX_FACTOR, safety * _predict(h, tf, en))
        if rejected:  # no growth right after a rejection, on the error or Newton's (RADAU5)
            fac = min(1.0, fac)
        h_next = max(h * fac, trial) if h < trial and not rejected else h * fac
        h_lu = tf[H_LU]
        if (not recompute_jac and cnt[LU_OK] == 1 and h_next >= LU_BAND[0] * h_lu
                and min(h_next, tf[MAX_STEP]) <= LU_BAND[1] * h_lu):
            h_next = h_lu
        tf[H_ABS_OLD] = h
        tf[ERR_OLD] = en
        tf[H] = h_next
        system.copy(yold, y)
        system.copy(y, yn)
        for i in range(N):  # the collocation polynomial: Q = Z^T P
            for r in range(3):
                Q[r, i] = Z[0, i] * P[0, r] + Z[1, i] * P[1, r] + Z[2, i] * P[2, r]
        cnt[PRED_OK] = 1
        steps += 1
        _accepted(m, wk, it, t, h, t_new, False)
        st = _f(fs, m, wk, it, t_new, y, f)
        if st != 0:
            cnt[STATUS] = st
            return FAILED
        cnt[F_OK] = 1
        if recompute_jac:
            st = _radau_jacobian(fs, m, wk, it, t_new)
            if st != 0:
                cnt[STATUS] = st
                return FAILED
        else:
            cnt[JAC_CURRENT] = 0
        wrote += _emit(RADAU5, m, wk, it, out, c, max_out - wrote)
    return OUTPUT


@ejit_inner
def _predict(h, tf, en):
    """Gustafsson's predictive step factor (before the safety factor)."""
    if tf[H_ABS_OLD] <= 0.0 or tf[ERR_OLD] <= 0.0 or en == 0.0:
        mult = 1.0
    else:
        mult = h / tf[H_ABS_OLD] * (tf[ERR_OLD] / en) ** 0.25
    if en == 0.0:
        return MAX_FACTOR
    return min(1.0, mult) * en ** -0.25


ADVANCE = {"rk4": advance_rk4, "midpoint": advance_midpoint, "dopri5": advance_dopri5, "radau5": advance_radau5}
