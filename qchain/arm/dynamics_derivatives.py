"""Derivatives of a chain's dynamics in its own coordinates (what :class:`qchain.Chain`'s
``*_derivatives`` methods return).

The compiled passes (:mod:`~qchain.algorithms.rnea_derivatives`) work in curvature coordinates. Segments in
the paper's ``(l, psi, kappa)`` get the chain rule through ``q_c = phi(q_e)``,
``v_c = J v_e``, ``a_c = J a_e + Jdot v_e``, ``tau_e = J^T tau_c`` (closed-form ``dJ/dq`` and
``d(Jdot v)/dq`` of :mod:`qchain.model.segment`). Forward-dynamics derivatives follow from the
inverse ones (Carpentier and Mansard): with ``f = B p - D v - dU_el/dq + tau``,

    da/dq = M^-1 (df/dq - dID/dq),  da/dv = M^-1 (df/dv - dID/dv),  da/dtau = M^-1,  da/dp = M^-1 B,

the inverse dynamics ``ID`` taken at the solved ``a``. Locked coordinates (``Chain.active``)
have zero rows (their acceleration is held at zero) and zero columns (they admit no
variation); ``M^-1`` is then the inverse of the free block.

A floating base's configuration derivative is taken along the Lie group:
``d/de f(integrate(q, e))`` at ``e = 0`` (Pinocchio's tangent convention), ``nv`` columns.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..algorithms import aba_derivatives, recursive, rnea_derivatives
from ..model.arc import SCRATCH
from ..errors import QchainError
from ..model.segment import _paper_bias_derivative as paper_bias_derivative
from ..model.segment import (
    _paper_jacobian_derivative as paper_jacobian_derivative, _paper_jacobian_dot as paper_jacobian_dot)

if TYPE_CHECKING:
    from .chain import Chain, _State
    from .data import Data

__all__ = ["InverseDynamicsDerivatives", "ForwardDynamicsDerivatives"]

# A still base's twist or acceleration, shared and only ever read (the kernels read V0, F0,
# A_B). Writable on purpose: numba types a read-only array apart from a writable one, so a
# read-only zero here compiled a second specialisation of every kernel it reaches (aba,
# aba_derivatives, rnea_derivatives: ~15 s of the first run's compile).
_ZERO6 = np.zeros(6)
_EMPTY = np.zeros(0)  # no tau on the compiled paths (one array type)


class InverseDynamicsDerivatives(NamedTuple):
    """:meth:`Chain.inverse_dynamics_derivatives`.

    Attributes
    ----------
    tau : (nv,)            ``inverse_dynamics(q, v, a)`` (N, N m; a floating base's wrench first).
    dtau_dq : (nv, nv)     along ``integrate(q, dq)``.
    dtau_dv : (nv, nv)
    dtau_da : (nv, nv)     ``= M(q)``.
    """

    tau: np.ndarray
    dtau_dq: np.ndarray
    dtau_dv: np.ndarray
    dtau_da: np.ndarray


class ForwardDynamicsDerivatives(NamedTuple):
    """:meth:`Chain.forward_dynamics_derivatives`.

    Attributes
    ----------
    a : (nv,)              ``forward_dynamics(q, v, p, tau)``.
    da_dq : (nv, nv)       along ``integrate(q, dq)``.
    da_dv : (nv, nv)
    da_dp : (nv, 3 n)      per pascal.
    da_dtau : (nv, nv)     ``= M^-1`` (of the free block where coordinates are locked).
    """

    a: np.ndarray
    da_dq: np.ndarray
    da_dv: np.ndarray
    da_dp: np.ndarray
    da_dtau: np.ndarray


# ---------------------------------------------------------------------------- inverse


def _curvature_id_derivatives(ch: Chain, st: _State, qdd_c: np.ndarray, A0: np.ndarray, g_B: np.ndarray,
                              data: Data | None):
    """The compiled pass: ``(tau_c (nv,), dq_c, dv_c, M_c)`` in curvature coordinates (views
    into ``data`` where given, except ``tau_c``)."""
    V0 = _ZERO6 if st.V0 is None else st.V0
    args = (ch._arrays, st.q_c, np.ascontiguousarray(st.v_c),
            np.ascontiguousarray(qdd_c), V0, A0, ch.floating, g_B)
    d = ch._workspace(data)  # without data: the thread's own, whose results are copied out
    rnea_derivatives.rnea_derivatives(*args, tuple(d.aba_workspace()), tuple(d.rnea_workspace()), d.scratch)
    tau, F0, dq, dv, M = d.tau_c, d.F0, d.dtau_dq, d.dtau_dv, d.M
    if data is None:
        dq, dv, M = dq.copy(), dv.copy(), M.copy()
    tau = tau.ravel()
    full = np.concatenate([F0, tau]) if ch.floating else tau.copy()
    return full, dq, dv, M


def _paper_blocks(ch: Chain, st: _State, fn) -> np.ndarray:
    """(nv, nv) block-diagonal, block ``j`` = ``fn(j)`` (3, 3) for paper-coordinate segments."""
    out = np.zeros((ch.nv, ch.nv))
    for j in np.flatnonzero(ch._paper):
        sl = ch.v_slice(j)
        out[sl, sl] = fn(j)
    return out


def _dT(ch: Chain, st: _State, x: np.ndarray, transpose: bool = False) -> np.ndarray:
    """Column ``k`` = ``(dT/dq_k) x`` (or ``(dT/dq_k)^T x``), ``T = blockdiag(I, J_1, ..., J_n)``."""

    def block(j):
        dJ = paper_jacobian_derivative(st.q_e[j])
        xj = x[ch.v_slice(j)]
        return np.stack([(dJ[c].T if transpose else dJ[c]) @ xj for c in range(3)], axis=1)

    return _paper_blocks(ch, st, block)


def inverse_dynamics_derivatives(ch: Chain, st: _State, a: np.ndarray,
                                 data: Data | None) -> InverseDynamicsDerivatives:
    """On a validated state; ``a`` (nv,) in the chain's coordinates."""
    a_e = a[ch._voff :].reshape(ch.n, 3)
    A0 = ch._A0(st, a[:6] if ch.floating else None)
    tau_c, dq_c, dv_c, M_c = _curvature_id_derivatives(ch, st, ch._acc_c(st, a_e), A0, st.g_B, data)
    if st.J is None:
        return InverseDynamicsDerivatives(tau_c, dq_c, dv_c, M_c)
    T = ch._lift(st)
    v = np.concatenate([st.V0, st.v_e.ravel()]) if ch.floating else st.v_e.ravel()
    Td = _paper_blocks(ch, st, lambda j: paper_jacobian_dot(st.q_e[j], st.v_e[j]))
    dbias = _paper_blocks(ch, st, lambda j: paper_bias_derivative(st.q_e[j], st.v_e[j]))
    tau = T.T @ tau_c
    dtau_da = T.T @ M_c @ T
    dtau_dv = T.T @ (dv_c @ T + 2.0 * M_c @ Td)
    dtau_dq = _dT(ch, st, tau_c, transpose=True) + T.T @ (
        dq_c @ T + dv_c @ _dT(ch, st, v) + M_c @ (_dT(ch, st, a) + dbias)
    )
    return InverseDynamicsDerivatives(tau, dtau_dq, dtau_dv, dtau_da)


# ---------------------------------------------------------------------------- internal forces


def _internal_derivatives(ch: Chain, st: _State, p3: np.ndarray):
    """``df/dq``, ``df/dv`` (nv, nv) and ``B`` (nv, 3 n) of the internal forces ``B p - D v -
    dU_el/dq`` in the chain's coordinates (zero on the base)."""
    n, nv = ch.n, ch.nv
    dfq_c, dfv_c = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    rnea_derivatives.internal_forces_derivatives(ch._arrays, st.q_c, p3, dfq_c, dfv_c, np.empty(SCRATCH))
    Bc = np.empty((n, 3, 3))
    aba_derivatives.input_matrices(ch._arrays, st.q_c, Bc, np.empty(SCRATCH))
    f_c = None
    if ch._any_paper:
        f_c = np.empty((n, 3))
        recursive.internal_forces(ch._arrays, st.q_c, np.ascontiguousarray(st.v_c), p3, f_c, np.empty(SCRATCH))
    dfq, dfv, B = np.zeros((nv, nv)), np.zeros((nv, nv)), np.zeros((nv, ch.nu))
    for j, s in enumerate(ch.segments):
        sl = ch.v_slice(j)
        qe = st.q_e[j]
        if ch._linear[j]:
            # the paper's literal linear law: constant K_e and D in the segment's coordinates
            dfq[sl, sl] = s.pressure_stiffness(qe, p3[j]) - s.elastic_stiffness(qe)
            dfv[sl, sl] = -s.dissipation_matrix(qe)
            B[sl, 3 * j : 3 * j + 3] = s.input_matrix(qe)
        elif ch._paper[j]:
            J = st.J[j]
            dJ = paper_jacobian_derivative(qe)
            dJv = np.stack([dJ[c] @ st.v_e[j] for c in range(3)], axis=1)
            dJf = np.stack([dJ[c].T @ f_c[j] for c in range(3)], axis=1)
            dfq[sl, sl] = dJf + J.T @ (dfq_c[j] @ J + dfv_c[j] @ dJv)
            dfv[sl, sl] = J.T @ dfv_c[j] @ J
            B[sl, 3 * j : 3 * j + 3] = J.T @ Bc[j]
        else:
            dfq[sl, sl] = dfq_c[j]
            dfv[sl, sl] = dfv_c[j]
            B[sl, 3 * j : 3 * j + 3] = Bc[j]
    return dfq, dfv, B


# ---------------------------------------------------------------------------- forward


def forward_dynamics_derivatives(ch: Chain, st: _State, p3: np.ndarray, tau, t: float,
                                 data: Data | None) -> ForwardDynamicsDerivatives:
    """On a validated state (locks checked)."""
    if not (ch._any_paper or ch._has_linear):
        return compiled_forward_dynamics_derivatives(ch, st.q, st.v, p3.reshape(-1), tau, st.V0, st.A_B, st.g_B, t,
                                                     data)
    a = ch._forward_dynamics(st, p3, tau, t, data)
    idd = inverse_dynamics_derivatives(ch, st, a, data)
    dfq, dfv, B = _internal_derivatives(ch, st, p3)
    nv = ch.nv
    from scipy.linalg import cho_factor, cho_solve  # here: scipy's import is a third of qchain's

    free = ch.active
    ix = np.ix_(free, free)
    try:
        c = cho_factor(idd.dtau_da[ix], lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise ch.indefinite_error("forward_dynamics_derivatives", st.q_e, t) from None
    Minv = cho_solve(c, np.eye(int(free.sum())), check_finite=False)
    da_dq, da_dv, da_dtau = np.zeros((nv, nv)), np.zeros((nv, nv)), np.zeros((nv, nv))
    da_dq[ix] = Minv @ (dfq - idd.dtau_dq)[ix]
    da_dv[ix] = Minv @ (dfv - idd.dtau_dv)[ix]
    da_dtau[ix] = Minv
    return _checked(ForwardDynamicsDerivatives(a, da_dq, da_dv, da_dtau @ B, da_dtau), t)


def _checked(out: ForwardDynamicsDerivatives, t: float) -> ForwardDynamicsDerivatives:
    for name, x in zip(out._fields, out):
        if not np.all(np.isfinite(x)):
            raise QchainError(f"forward_dynamics_derivatives produced non-finite entries in {name} at t = {t}")
    return out


def compiled_forward_dynamics_derivatives(ch: Chain, q, v, p, tau, V0, A_B, g_B, t, data: Data | None,
                                          check: bool = True) -> ForwardDynamicsDerivatives:
    """The one compiled call (:func:`qchain.algorithms.aba_derivatives.forward_dynamics_derivatives`)
    for chains in curvature coordinates: ``q`` (nq,), ``v`` (nv,), ``p`` (3 n,), ``tau`` (nv,)
    or None. The result's arrays are ``data``'s where it is given (the same tuple each call)."""
    d = ch._workspace(data)  # without data: the thread's own, whose results are copied out
    status = aba_derivatives.forward_dynamics_derivatives(ch._arrays, ch.floating, q, v, p,
                                                          _EMPTY if tau is None else tau, V0,
                                                          _ZERO6 if A_B is None else A_B, g_B, d.kernel_buffer,
                                                          d.kernel_layout)
    out = d._tuple("_fdd", ForwardDynamicsDerivatives)
    if data is None:
        out = ForwardDynamicsDerivatives(*(x.copy() for x in out))
    if status and check:
        if status in (1, 2):  # name the segment whose inertia is singular, and its coordinates
            raise ch.indefinite_error("forward_dynamics_derivatives", q[ch._qoff :].reshape(ch.n, 3), t)
        raise ch.nonfinite_error("forward_dynamics_derivatives", "accelerations or their derivatives",
                                 np.concatenate([np.zeros(ch._qoff), q[ch._qoff :]]),
                                 np.concatenate([np.zeros(ch._voff), v[ch._voff :]]), t)
    return out


# ---------------------------------------------------------------------------- mass matrix


def mass_matrix_derivative(ch: Chain, st: _State, data: Data | None) -> np.ndarray:
    """``dM[:, :, k] = dM/dq_k`` (nv, nv, nv) along ``integrate``: column ``i`` of ``dM/dq`` is the
    configuration derivative of ``M e_i``, the inverse dynamics of a unit acceleration with no
    velocity and no gravity (one compiled pass per column)."""
    nv, n = ch.nv, ch.n
    st0 = type(st)(X_WB=st.X_WB, q_e=st.q_e, q_c=st.q_c, J=st.J, v_e=np.zeros((n, 3)), v_c=np.zeros((n, 3)),
                   V0=np.zeros(6), A_B=None, g_B=np.zeros(3))
    T = ch._lift(st)
    M_c = None
    dMc = np.empty((nv, nv, nv))
    z = np.zeros(3)
    for i in range(nv):
        e = np.zeros(nv)
        e[i] = 1.0
        qdd_c = e[ch._voff :].reshape(n, 3)
        A0 = e[:6].copy() if ch.floating else np.zeros(6)
        _, dq_c, _, M_c = _curvature_id_derivatives(ch, st0, qdd_c, A0, z, data)
        dMc[:, i, :] = dq_c
    M_c = M_c.copy()
    if T is None:
        return dMc
    # M_e = T^T M_c T; d/dq_k = dT_k^T M_c T + T^T M_c dT_k + T^T (sum_l dM_c/dq_l T_lk) T
    dT = np.zeros((nv, nv, nv))  # dT[:, :, k] = dT/dq_k
    for j in np.flatnonzero(ch._paper):
        sl = ch.v_slice(j)
        dJ = paper_jacobian_derivative(st.q_e[j])
        for c in range(3):
            dT[sl, sl, sl.start + c] = dJ[c]
    dMc_e = np.einsum("abl,lk->abk", dMc, T)
    MT = M_c @ T
    out = np.einsum("ai,abk,bj->ijk", T, dMc_e, T)
    out += np.einsum("aik,aj->ijk", dT, MT) + np.einsum("ai,ajk->ijk", MT, dT)
    return out

