"""Compiled passes over a horizon of held-input intervals (:class:`qchain.control.MPC`'s
discrete dynamics): the rollout and its exact linearisation, one compiled call each.

An interval ``F(s, u)`` is ``steps`` classical Runge-Kutta (RK4) steps of ``h / steps`` of
the engine's first-order system ``y = (delta, v_A)`` (:mod:`qchain.sim.engine.system`,
chart ``wk.q_chart`` with zeros at the free coordinates, so ``y`` is the free coordinates'
state ``s = (q_A, v_A)``) with the pressures ``p = scale u`` held: written into the packed
constant input ``m.p_params`` (:func:`qchain.sim.engine.schedules.pack_input`, CONSTANT) at
the interval's start; with ``tendons``, ``u`` are the tendons' tensions, written into
``m.tn_params`` (the chambers' constant input stays at zero). The right-hand side and its Jacobian are the engine's callbacks
``fs = (rhs, jacobian)`` (:func:`qchain.sim.engine.warmup.callbacks` of an implicit method).

:func:`rollout` steps the horizon (optionally applying the feedback law of a DDP forward
pass); :func:`linearise` gives every interval's ``A_k = dF/ds`` and ``B_k = dF/du`` by
differentiating the RK4 map itself (internal differentiation, as
:mod:`qchain.sim.engine.sensitivity`): for a stage ``Y_i = y + c_i dt k_{i-1}``,
``dY_i = D + c_i dt dk_{i-1}``, ``dk_i = f_y(Y_i) dY_i + [0; scale da_A/dp]`` (``da/dT =
M^-1 B_T(q)`` with tendons, ``B_T``'s columns ``-dL_k/dq`` of each tendon's length) with
``f_y = [[0, I], [Jq, Jv]]`` (exact, :func:`system.jacobian`) and ``D_new = D + dt/6 (dk_1 +
2 dk_2 + 2 dk_3 + dk_4)`` from ``D = [I | 0]``: exact derivatives of the numbers the rollout
computes, to rounding.

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): called by
:class:`qchain.control.MPC`, which validates the arguments.
"""

from __future__ import annotations

import numpy as np

from . import system
from .sensitivity import stage_tangent
from ..._jit import ejit, inline, view2

__all__ = ["rollout", "linearise"]


@inline
def _hold(m, U, j, scale, tendons):
    """The inputs of interval ``j``, ``scale U[j]``, into the packed constant input: the
    pressures (Pa), or with ``tendons`` the tensions (N)."""
    params = m.tn_params if tendons else m.p_params
    for i in range(U.shape[1]):
        params[i] = U[j, i] * scale


@inline
def _tendon_matrix(m, wk, Bt, g, Hs):
    """``Bt = B_T(q)`` (nv, nt) at the configuration ``wk.q`` of the last right-hand side:
    column ``k`` is ``-dL_k/dq`` (:func:`qchain.sim.engine.system.tendon_row_gradient`; the
    domain was checked by that right-hand side)."""
    n = m.arrays.mass.shape[0]
    q_c = view2(wk.q[m.nq - 3 * n:], n, 3)
    voff = m.nv - 3 * n
    for r in range(Bt.shape[0]):  # (loops: the engine's code allocates nothing, assigns no slices)
        for c in range(Bt.shape[1]):
            Bt[r, c] = 0.0
    for i in range(m.tendon_rows.shape[0]):
        k, j = system.tendon_row_gradient(m, i, q_c, False, g, Hs)
        for c in range(3):
            Bt[voff + 3 * j + c, k] -= g[c]


@ejit
def rollout(fs, m, wk, h, steps, scale, tendons, lo, hi, S_ref, U_ref, kff, Kfb, alpha, feedback, S, U, K, yt):
    """The states ``S`` (H + 1, N) from ``S[0]`` under the inputs ``U`` (H, nu) (scaled:
    ``p = scale U``; the tensions with ``tendons``). With ``feedback``, ``U[j] = clip(U_ref[j] + alpha kff[j] + Kfb[j] (S[j] -
    S_ref[j]), lo, hi)`` is formed on the way (a DDP forward pass; ``kff`` (H, nu), ``Kfb``
    (H, nu, N)); otherwise ``U`` is read as given. ``h`` (s) an interval, ``steps`` RK4 steps
    in it; scratch ``K`` (4, N), ``yt`` (N,). Returns the status (0, or the failing
    right-hand side's, :mod:`system`); ``wk.info[3]`` the interval it failed in."""
    H = U.shape[0]
    nu = U.shape[1]
    N = S.shape[1]
    dt = h / steps
    for j in range(H):
        wk.info[3] = j
        if feedback:
            for i in range(nu):
                acc = 0.0
                for c in range(N):
                    acc += Kfb[j, i, c] * (S[j, c] - S_ref[j, c])
                x = U_ref[j, i] + alpha * kff[j, i] + acc
                U[j, i] = min(max(x, lo), hi)
        _hold(m, U, j, scale, tendons)
        y = S[j + 1]
        for i in range(N):
            y[i] = S[j, i]
        for _ in range(steps):
            for s in range(4):
                if s == 0:
                    st = fs[0](m, wk, 0.0, y, K[0])
                else:
                    w = dt if s == 3 else 0.5 * dt
                    for i in range(N):
                        yt[i] = y[i] + w * K[s - 1, i]
                    st = fs[0](m, wk, 0.0, yt, K[s])
                if st != 0:
                    return st
            for i in range(N):
                y[i] = y[i] + dt / 6.0 * (K[0, i] + 2.0 * K[1, i] + 2.0 * K[2, i] + K[3, i])
        for i in range(N):
            if not np.isfinite(y[i]):
                wk.info[0] = system.NONFINITE
                return system.NONFINITE
    return system.OK


@ejit
def linearise(fs, m, wk, h, steps, scale, tendons, S, U, A, B, K, dK, y, yt, D, dY, Jq, Jv, Bt, da_du, g, Hs):
    """Every interval's ``A[j] = dF/ds`` (H, N, N) and ``B[j] = dF/du`` (H, N, nu) at the
    states ``S`` (H + 1, N) (``S[j]`` read) and inputs ``U`` (H, nu) of a rollout (module
    docstring; ``U`` the tensions with ``tendons``). Scratch: ``K`` (4, N), ``dK`` (4, N, N +
    nu), ``y``, ``yt`` (N,), ``D``, ``dY`` (N, N + nu), ``Jq``, ``Jv`` (nA, nA), ``Bt``,
    ``da_du`` (nv, nu), ``g`` (3,), ``Hs`` (3, 3). Returns the status; ``wk.info[3]`` the interval."""
    H = U.shape[0]
    nu = U.shape[1]
    N = S.shape[1]
    nA = N // 2
    ncol = N + nu
    idx = m.idx
    dt = h / steps
    wa = system.aba_derivatives_ws(m, wk)
    nv = m.nv
    for j in range(H):
        wk.info[3] = j
        _hold(m, U, j, scale, tendons)
        for i in range(N):
            y[i] = S[j, i]
            for c in range(ncol):
                D[i, c] = 1.0 if c == i else 0.0
        for _ in range(steps):
            for s in range(4):
                if s == 0:
                    for i in range(N):
                        yt[i] = y[i]
                        for c in range(ncol):
                            dY[i, c] = D[i, c]
                else:
                    w = dt if s == 3 else 0.5 * dt
                    for i in range(N):
                        yt[i] = y[i] + w * K[s - 1, i]
                        for c in range(ncol):
                            dY[i, c] = D[i, c] + w * dK[s - 1, i, c]
                st = fs[0](m, wk, 0.0, yt, K[s])
                if st != 0:
                    return st
                st = fs[1](m, wk, 0.0, yt, Jq, Jv)
                if st != 0:
                    return st
                if tendons:  # da/dT = M^-1 B_T(q), on the free rows
                    _tendon_matrix(m, wk, Bt, g, Hs)
                    Minv = wa.da_dtau
                    for r in range(nA):
                        for c in range(nu):
                            acc = 0.0
                            for k in range(nv):
                                acc += Minv[idx[r], k] * Bt[k, c]
                            da_du[idx[r], c] = acc
                    da_dp = da_du
                else:
                    da_dp = wa.da_dp
                stage_tangent(Jq, Jv, dY, da_dp, idx, N, scale, dK[s])
            for i in range(N):
                y[i] = y[i] + dt / 6.0 * (K[0, i] + 2.0 * K[1, i] + 2.0 * K[2, i] + K[3, i])
                for c in range(ncol):
                    D[i, c] = D[i, c] + dt / 6.0 * (dK[0, i, c] + 2.0 * dK[1, i, c] + 2.0 * dK[2, i, c] + dK[3, i, c])
        for i in range(N):
            for c in range(N):
                A[j, i, c] = D[i, c]
                if not np.isfinite(D[i, c]):
                    wk.info[0] = system.NONFINITE
                    return system.NONFINITE
            for c in range(nu):
                B[j, i, c] = D[i, N + c]
                if not np.isfinite(D[i, N + c]):
                    wk.info[0] = system.NONFINITE
                    return system.NONFINITE
    return system.OK
