"""Compiled forward sensitivities: an explicit Runge-Kutta run and the exact derivative of its
numbers with respect to the initial state and parameters, in one compiled loop.

The state ``y = (delta, v_A)`` (N = 2 nA,) of :mod:`qchain.sim.engine.system` is stepped
along a given grid of step ends (``grid``, frozen steps) by ``rk4`` or ``dopri5`` with the
engine's own arithmetic, and beside it the sensitivity matrix ``S = dy/d(col)`` (N, ncol)
by differentiating the discrete map itself (internal differentiation): for a stage

    Y_i = y + h sum_j a_ij k_j,    k_i = f(t + c_i h, Y_i; theta)
    dY_i = S + h sum_j a_ij dk_j,  dk_i = f_y(Y_i) dY_i + f_theta(Y_i)

and ``S_new = S + h sum_i b_i dk_i``, so ``S`` is the derivative of the numbers the
integrator returns at those steps, to rounding. ``f_y = [[0, I], [Jq, Jv]]`` (no floating
base: the position rate is ``v_A``) from the engine's exact :func:`system.jacobian` at every
stage, ``f_theta = [0; da_A/dtheta]`` from a parameter kernel (:data:`PARAMETER_KERNEL`).
Samples at ``t_out`` come from the methods' dense output and their sensitivities from the
same formula applied to ``S`` and the stages' ``dk`` (it is linear in them).

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): call
:func:`qchain.sim.sensitivity.sensitivities`.
"""

from __future__ import annotations

import numpy as np

from . import system
from ..._jit import ejit, ejit_inner, inline, kernel, view2, view3
from ...algorithms import parameter_derivatives as pd
from ...algorithms.parameter_derivatives import ParameterWorkspace

__all__ = ["advance_sensitivities", "no_parameters", "chamber_area_derivatives", "model_parameter_derivatives",
           "parameter_buffer_size", "KIND_AREA", "RK4", "DOPRI5",
           "NFEV", "NJEV", "NPEV", "NSTEPS", "STATUS", "K_OUT", "T_FAIL_STEP"]

RK4, DOPRI5 = 0, 1
# cnt: counters, the failure status and the step it happened in, samples written
NFEV, NJEV, NPEV, NSTEPS, STATUS, K_OUT, T_FAIL_STEP = range(7)
#: the kind code of a chamber area (m^2) in ``kinds`` (the parameter derivatives' ``KIND_*``)
KIND_AREA = pd.KIND_AREA

#: The parameter kernel's contract (:func:`qchain._jit.kernel`), for every kernel passed as the
#: third callback: ``param(m, wk, t, y, kinds, index, pbuf, da) -> int64 status`` with
#: ``kinds``, ``index`` (P,) int64 (the kind of each parameter and its segment or component),
#: ``pbuf`` (size,) float64 a scratch buffer the caller sizes for the kernel, and ``da``
#: (nv, P) float64 to be written with ``da/dtheta`` over all velocity coordinates (locked rows
#: zero; rows ``m.idx`` are read). Called right after the right-hand side and the Jacobian at
#: the same ``(t, y)``: ``wk`` holds their forward pass (``wk.q``, ``wk.v``, ``wk.p``,
#: ``wk.qdd``, ``wk.A0``, ``wk.B``, ``wk.R_WB``) and the Jacobian's factors
#: (:func:`system.aba_derivatives_ws`: ``da_dtau = M^-1``, ``da_dp``, ...). 0 is OK; any other
#: value stops the run with that status.
PARAMETER_KERNEL = "param(m, wk, t, y, kinds, index, pbuf, da) -> int64"


@kernel
def no_parameters(m, wk, t, y, kinds, index, pbuf, da):
    """The parameter kernel of a run without parameters (never called with ``P > 0``)."""
    return system.OK


@kernel
def chamber_area_derivatives(m, wk, t, y, kinds, index, pbuf, da):
    """``da[:, k] = da/dA_ch`` of segment ``index[k]`` (every ``kinds[k] == KIND_AREA``): the
    input matrix is linear in the chamber area in both actuation models, so
    ``da/dA_ch_j = M^-1 B_j p_j / A_ch_j = sum_i (da/dp)[:, 3 j + i] p[3 j + i] / A_ch_j``, from
    the Jacobian's ``da/dp`` and the pressures of the last right-hand side."""
    wa = system.aba_derivatives_ws(m, wk)
    da_dp = wa.da_dp
    A_ch = m.arrays.A_ch
    p = wk.p
    for k in range(kinds.shape[0]):
        if kinds[k] != KIND_AREA:
            return -1
        j = index[k]
        for r in range(da.shape[0]):
            acc = 0.0
            for i in range(3):
                acc += da_dp[r, 3 * j + i] * p[3 * j + i]
            da[r, k] = acc / A_ch[j]
    return system.OK


def parameter_buffer_size(n: int, nv: int, P: int) -> int:
    """The floats :func:`model_parameter_derivatives` carves from ``pbuf``: Young's moduli (n,),
    then :class:`~qchain.algorithms.parameter_derivatives.ParameterWorkspace` (``Qu`` (n, 9),
    ``T`` (n, 6, 9), ``c`` (n, 6), ``Hf`` (6 + 3 n)^2, ``Mb`` (nv, 3), ``rhs`` (nv, P)) and
    ``dID`` (nv, P)."""
    return n + 9 * n + 54 * n + 6 * n + (6 + 3 * n) ** 2 + 3 * nv + 2 * nv * P


@kernel
def model_parameter_derivatives(m, wk, t, y, kinds, index, pbuf, da):
    """``da`` (nv, P) = ``da/dtheta`` of every kind of the parameter derivatives
    (:func:`qchain.algorithms.parameter_derivatives._parameter_derivatives_at`) after the
    Jacobian's pass at the same state, whose results it reads from ``wk``; ``pbuf``
    (:func:`parameter_buffer_size`) starts with the segments' Young's moduli (Pa)."""
    n = m.arrays.mass.shape[0]
    nv = m.nv
    P = kinds.shape[0]
    o = n
    E = pbuf[:n]
    Qu = view2(pbuf[o : o + 9 * n], n, 9)
    o += 9 * n
    T = view3(pbuf[o : o + 54 * n], n, 6, 9)
    o += 54 * n
    c = view2(pbuf[o : o + 6 * n], n, 6)
    o += 6 * n
    nf = 6 + 3 * n
    Hf = view2(pbuf[o : o + nf * nf], nf, nf)
    o += nf * nf
    Mb = view2(pbuf[o : o + 3 * nv], nv, 3)
    o += 3 * nv
    rhs = view2(pbuf[o : o + nv * P], nv, P)
    o += nv * P
    dID = view2(pbuf[o : o + nv * P], nv, P)
    q_c, v_c = system._segment_states(m, wk)
    st = pd._parameter_derivatives_at(m.arrays, m.base == system.FLOATING, q_c, v_c, view2(wk.p, n, 3), wk.qdd,
                                      wk.A0, wk.B[0], wk.B[2, :3], wk.R_WB, E, kinds, index, system.aba_ws(m, wk),
                                      system.rnea_ws(m, wk), system.aba_derivatives_ws(m, wk),
                                      ParameterWorkspace(Qu, T, c, Hf, Mb, rhs), wk.scratch, da, dID)
    return system.OK if st == 0 else (system.SINGULAR if st < 3 else system.NONFINITE)


@inline
def stage_tangent(Jq, Jv, dY, da, idx, first, scale, dk):
    """``dk = f_y dY + [0; scale da_A]`` (N, ncol) of one Runge-Kutta stage, ``f_y = [[0, I],
    [Jq, Jv]]`` the exact Jacobian at the stage (``Jq``, ``Jv`` (nA, nA)), ``dY`` (N, ncol) the
    stage state's derivative; the columns from ``first`` on add ``scale da[idx[r], c - first]``
    (the inputs' or the parameters' own ``da/dtheta`` (nv, ncol - first), rows ``idx`` the free
    coordinates). The one tangent of the compiled sensitivities and of
    :mod:`qchain.sim.engine.horizon`'s linearisation."""
    nA = Jq.shape[0]
    ncol = dY.shape[1]
    for i in range(nA):
        for c in range(ncol):
            dk[i, c] = dY[nA + i, c]
    for r in range(nA):
        for c in range(ncol):
            acc = 0.0
            for j in range(nA):
                acc += Jq[r, j] * dY[j, c] + Jv[r, j] * dY[nA + j, c]
            if c >= first:
                acc += da[idx[r], c - first] * scale
            dk[nA + r, c] = acc


@ejit_inner
def _stage(fs, m, wk, t, Y, dY, k, dk, Jq, Jv, da, kinds, index, pbuf, cnt):
    """``k = f(t, Y)`` (N,) and ``dk = f_y dY + f_theta`` (N, ncol), the parameter columns last;
    returns the status."""
    cnt[NFEV] += 1
    st = fs[0](m, wk, t, Y, k)
    if st != 0:
        return st
    cnt[NJEV] += 1
    st = fs[1](m, wk, t, Y, Jq, Jv)
    if st != 0:
        return st
    P = kinds.shape[0]
    if P > 0:
        cnt[NPEV] += 1
        st = fs[2](m, wk, t, Y, kinds, index, pbuf, da)
        if st != 0:
            return st
    stage_tangent(Jq, Jv, dY, da, m.idx, dY.shape[1] - P, 1.0, dk)
    return system.OK


@ejit_inner
def _emit_sample(m, wk, ys, Sk, dS, Qo, Vo, So, k):
    """Sample ``k``: ``q``, ``v`` of ``ys`` in the current chart and its sensitivity ``dS``."""
    system.configuration(m, wk, wk.q_chart, ys)
    system.copy(Qo[k], wk.q)
    system.copy(Vo[k], wk.v)
    N = ys.shape[0]
    for i in range(N):
        for c in range(dS.shape[1]):
            So[k, i, c] = dS[i, c]


@ejit
def advance_sensitivities(fs, m, wk, method, A, C, Pd, grid, y, S, K, dK, yt, dY, ys, dS, Jq, Jv, da, kinds, index,
                          pbuf, t_out, Qo, Vo, So, cnt):
    """Step ``y`` (N,) and ``S`` (N, ncol) from ``grid[0]`` along the step ends ``grid`` (M + 1,)
    with ``method`` (:data:`RK4` or :data:`DOPRI5`, tableau ``A``, ``C``, dense output ``Pd``,
    :mod:`qchain.sim.engine.tableaus`); write the samples at ``t_out`` (K,) into ``Qo``
    (K, nq), ``Vo`` (K, nv), ``So`` (K, N, ncol). ``fs``: the right-hand side, the Jacobian and
    the parameter kernel. Scratch: ``K`` (11, N), ``dK`` (11, N, ncol), ``yt``, ``ys`` (N,),
    ``dY``, ``dS`` (N, ncol), ``Jq``, ``Jv`` (nA, nA), ``da`` (nv, P), ``pbuf``. Returns the
    status (0, or the failing pass's; ``cnt[T_FAIL_STEP]`` the step it failed in)."""
    N = y.shape[0]
    nA = N // 2
    ncol = S.shape[1]
    nt = t_out.shape[0]
    ko = 0
    while ko < nt and t_out[ko] <= grid[0]:
        _emit_sample(m, wk, y, S, S, Qo, Vo, So, ko)
        ko += 1
    cnt[K_OUT] = ko
    yold = K[10]  # the step's start (stages use rows 0-6)
    for step in range(grid.shape[0] - 1):
        t = grid[step]
        t_new = grid[step + 1]
        h = t_new - t
        cnt[T_FAIL_STEP] = step
        st = 0
        if method == RK4:
            st = _stage(fs, m, wk, t, y, S, K[0], dK[0], Jq, Jv, da, kinds, index, pbuf, cnt)
            for s in range(1, 4):
                if st != 0:
                    break
                w = h if s == 3 else 0.5 * h
                for i in range(N):
                    yt[i] = y[i] + w * K[s - 1, i]
                    for c in range(ncol):
                        dY[i, c] = S[i, c] + w * dK[s - 1, i, c]
                st = _stage(fs, m, wk, t_new if s == 3 else t + 0.5 * h, yt, dY, K[s], dK[s], Jq, Jv, da, kinds,
                            index, pbuf, cnt)
            if st != 0:
                cnt[STATUS] = st
                return st
            for i in range(N):
                yold[i] = y[i]
                y[i] = y[i] + h / 6.0 * (K[0, i] + 2.0 * K[1, i] + 2.0 * K[2, i] + K[3, i])
                for c in range(ncol):
                    dK[9, i, c] = S[i, c]  # the step's start, for the dense output
                    S[i, c] = S[i, c] + h / 6.0 * (dK[0, i, c] + 2.0 * dK[1, i, c] + 2.0 * dK[2, i, c]
                                                   + dK[3, i, c])
        else:
            if step == 0:  # first same as last afterwards: stage 0 is the last step's stage 6
                st = _stage(fs, m, wk, t, y, S, K[0], dK[0], Jq, Jv, da, kinds, index, pbuf, cnt)
            else:
                for i in range(N):
                    K[0, i] = K[6, i]
                    for c in range(ncol):
                        dK[0, i, c] = dK[6, i, c]
            for s in range(1, 6):
                if st != 0:
                    break
                for i in range(N):
                    acc = 0.0
                    for k in range(s):
                        acc += A[s, k] * K[k, i]
                    yt[i] = y[i] + h * acc
                    for c in range(ncol):
                        acc = 0.0
                        for k in range(s):
                            acc += A[s, k] * dK[k, i, c]
                        dY[i, c] = S[i, c] + h * acc
                st = _stage(fs, m, wk, t + C[s] * h, yt, dY, K[s], dK[s], Jq, Jv, da, kinds, index, pbuf, cnt)
            if st == 0:
                for i in range(N):
                    acc = 0.0
                    for k in range(6):
                        acc += A[6, k] * K[k, i]
                    yt[i] = y[i] + h * acc
                    for c in range(ncol):
                        acc = 0.0
                        for k in range(6):
                            acc += A[6, k] * dK[k, i, c]
                        dY[i, c] = S[i, c] + h * acc
                st = _stage(fs, m, wk, t_new, yt, dY, K[6], dK[6], Jq, Jv, da, kinds, index, pbuf, cnt)
            if st != 0:
                cnt[STATUS] = st
                return st
            for i in range(N):
                yold[i] = y[i]
                y[i] = yt[i]
                for c in range(ncol):
                    dK[10, i, c] = S[i, c]  # the step's start, for the dense output
                    S[i, c] = dY[i, c]
        cnt[NSTEPS] += 1
        # the end state inside the model's domain (the next step's first stage checks it too)
        system.configuration(m, wk, wk.q_chart, y)
        st = system.check(m, wk, wk.q)
        if st != 0:
            cnt[STATUS] = st
            return st
        for i in range(N):
            for c in range(ncol):
                if not np.isfinite(S[i, c]):
                    cnt[STATUS] = system.NONFINITE
                    return system.NONFINITE
        while ko < nt and t_out[ko] <= t_new:
            sk = t_out[ko]
            if sk == t_new:
                _emit_sample(m, wk, y, S, S, Qo, Vo, So, ko)
            else:
                x = (sk - t) / h
                if method == RK4:
                    _rk4_dense(yold, y, K, dK, S, h, x, ys, dS)
                else:
                    _dopri5_dense(yold, K, dK, Pd, h, x, ys, dS)
                _emit_sample(m, wk, ys, dS, dS, Qo, Vo, So, ko)
            ko += 1
        cnt[K_OUT] = ko
        if method == RK4:  # the chart moves to the step's end, as the engine's fixed-step methods do
            idx = m.idx
            for i in range(nA):
                wk.q_chart[idx[i]] += y[i]
                y[i] = 0.0
    return system.OK


@ejit_inner
def _rk4_dense(yold, y, K, dK, S, h, x, ys, dS):
    """The fixed-step methods' dense output (cubic Hermite positions on their rates at both
    ends, linear velocities; :func:`qchain.sim.engine.steppers.dense`) and its derivative: the
    start's sensitivity in ``dK[9]``, the end's in ``S``."""
    N = y.shape[0]
    nA = N // 2
    ncol = S.shape[1]
    h00 = (1.0 + 2.0 * x) * (1.0 - x) ** 2
    h10 = x * (1.0 - x) ** 2
    h01 = x * x * (3.0 - 2.0 * x)
    h11 = x * x * (x - 1.0)
    for i in range(nA):
        ys[i] = h00 * yold[i] + h01 * y[i] + h * (h10 * K[0, i] + h11 * y[nA + i])
        ys[nA + i] = (1.0 - x) * yold[nA + i] + x * y[nA + i]
        for c in range(ncol):
            dS[i, c] = h00 * dK[9, i, c] + h01 * S[i, c] + h * (h10 * dK[0, i, c] + h11 * S[nA + i, c])
            dS[nA + i, c] = (1.0 - x) * dK[9, nA + i, c] + x * S[nA + i, c]


@ejit_inner
def _dopri5_dense(yold, K, dK, Pd, h, x, ys, dS):
    """dopri5's 4th-order continuous extension (:func:`qchain.sim.engine.steppers.dense`, the
    coefficients ``K[7 + r] = sum_k K[k] P[k, r]`` summed in the engine's order) and its
    derivative: the start's sensitivity in ``dK[10]``."""
    N = yold.shape[0]
    ncol = dK.shape[2]
    for i in range(N):
        b0 = 0.0
        b1 = 0.0
        b2 = 0.0
        b3 = 0.0
        for k in range(7):
            b0 += K[k, i] * Pd[k, 0]
            b1 += K[k, i] * Pd[k, 1]
            b2 += K[k, i] * Pd[k, 2]
            b3 += K[k, i] * Pd[k, 3]
        ys[i] = yold[i] + h * x * (b0 + x * (b1 + x * (b2 + x * b3)))
        for c in range(ncol):
            b0 = 0.0
            b1 = 0.0
            b2 = 0.0
            b3 = 0.0
            for k in range(7):
                b0 += dK[k, i, c] * Pd[k, 0]
                b1 += dK[k, i, c] * Pd[k, 1]
                b2 += dK[k, i, c] * Pd[k, 2]
                b3 += dK[k, i, c] * Pd[k, 3]
            dS[i, c] = dK[10, i, c] + h * x * (b0 + x * (b1 + x * (b2 + x * b3)))
