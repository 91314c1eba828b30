"""Exact derivatives of the chain's forward dynamics (numba), as Pinocchio's ``aba-derivatives``:
one compiled call solves the accelerations (:func:`qchain.algorithms.recursive.aba`) and
differentiates them through the inverse-dynamics derivatives at the solved accelerations
(:mod:`qchain.algorithms.rnea_derivatives`), ``da/dq = M^-1 (df/dq - dID/dq)``,
``da/dv = M^-1 (df/dv - dID/dv)``, ``da/dtau = M^-1``, ``da/dp = M^-1 B``, with the derivatives
of the internal forces ``f`` (:func:`~qchain.algorithms.rnea_derivatives.internal_forces_derivatives`)
and the input matrices ``B`` (:func:`input_matrices`). Curvature coordinates and the layout of
:mod:`qchain.algorithms.recursive`.

``tests/test_derivatives.py`` holds every output to central differences of the model.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

import numpy as np

from .._blas import gemm
from .._jit import jit, jit_helper, jit_inline, jit_pass, jit_sums, view2
from ..model.arc import take1
from .arrays import (
    AbaDerivativesWorkspace, AbaWorkspace, ChainArrays, RneaWorkspace, carve_aba, carve_aba_derivatives, carve_rnea)
from ..model.slices import input_matrix_c
from .recursive import _chol as recursive_chol
from .recursive import aba as recursive_aba
from .recursive import internal_forces as recursive_internal_forces
from .rnea_derivatives import _internal_forces_derivatives, _rnea_derivatives

__all__ = ["aba_derivatives", "forward_dynamics_derivatives", "aba_derivatives_workspace", "input_matrices"]



@jit_pass
def input_matrices(arr, q, B, sc):
    """``B[j]`` (3, 3) the input matrix of every segment (:func:`qchain.model.slices.input_matrix_c`);
    ``arr`` the model's :class:`~qchain.algorithms.arrays.ChainArrays`."""
    arr = ChainArrays(*arr)  # a plain tuple from Python (arrays.py), named here
    _input_matrices(q, arr.A_ch, arr.r_ch, arr.paper_act, B, sc)


@jit_helper
def _input_matrices(q, A_ch, r_ch, paper_act, B, sc):
    """:func:`input_matrices`, the body the kernels call: compiled into them, without a
    Python entry point (:data:`qchain._jit.jit_helper`)."""
    for j in range(q.shape[0]):
        input_matrix_c(q[j], A_ch[j], r_ch[j], paper_act[j], B[j], sc)


#: Names of :func:`aba_derivatives_workspace`'s arrays (``Data`` attributes), in order.
ABA_DERIVATIVES_WORKSPACE = AbaDerivativesWorkspace._fields


@jit
def aba_derivatives_workspace(n, nv):
    """Fresh arrays for :func:`aba_derivatives` (shapes in :mod:`qchain.arm.data`)."""
    return AbaDerivativesWorkspace(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(6), np.zeros(nv), np.zeros((nv, nv)),
                                   np.zeros((nv, nv)), np.zeros((nv, nv)), np.zeros((nv, nv)), np.zeros((nv, 3 * n)),
                                   np.zeros((n, 3, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3, 3)))


@jit_helper
def _zero_locked(locked, off, X, rows, cols):
    """Zero the rows and/or columns of ``X`` (nv, nv) at the locked coordinates ``locked``
    (n, 3) (indices ``off + 3 j + b``)."""
    nv = X.shape[0]
    for k in range(off, nv):
        if locked[(k - off) // 3, (k - off) % 3]:
            for r in range(nv):
                if rows:
                    X[k, r] = 0.0
                if cols:
                    X[r, k] = 0.0


@jit_inline
def _chol_inverse(L, k, Minv):
    """``Minv = (L L^T)^-1`` (k, k) from the lower Cholesky factor ``L``, which is overwritten
    by its own inverse (lower; zeros above). Row by row, as sums of scaled rows (the inner loops
    run along contiguous rows, which the compiler vectorises; the dot-product form ran along
    columns): row ``i`` of ``L^-1`` from the rows above it, then ``Minv = sum_s x_s x_s^T`` over
    the rows ``x_s`` of ``L^-1``. Row ``i`` of ``Minv`` holds row ``i`` of ``L`` meanwhile."""
    for i in range(k):
        t = Minv[i]
        for s in range(i):
            t[s] = L[i, s]
            L[i, s] = 0.0
        for s in range(i):
            a = t[s]
            if a != 0.0:
                for j in range(s + 1):
                    L[i, j] += a * L[s, j]
        d = 1.0 / L[i, i]
        for j in range(i):
            L[i, j] *= -d
        L[i, i] = d
        for j in range(i + 1, k):
            L[i, j] = 0.0
    for i in range(k):
        for j in range(k):
            Minv[i, j] = 0.0
    for s in range(k):
        for i in range(s + 1):
            a = L[s, i]
            for j in range(i + 1):
                Minv[i, j] += a * L[s, j]
    for i in range(k):
        for j in range(i):
            Minv[j, i] = Minv[i, j]


@jit_sums
def _inverse_spd(L, k, Minv):
    """``Minv = (L L^T)^-1`` (k, k) of the symmetric ``L`` (its lower triangle read), through
    its Cholesky factor (:func:`qchain.algorithms.recursive._chol`, then
    :func:`_chol_inverse`; ``L`` is overwritten). False where a pivot is not positive (``L``
    not positive definite; ``Minv`` is then not written). Compiled with reordered sums
    (:data:`qchain._jit.jit_sums`): the factor's and the inverse's inner products vectorise."""
    if not recursive_chol(L, k):
        return False
    _chol_inverse(L, k, Minv)
    return True


@jit_sums
def _all_finite(a, X1, X2, X3, X4):
    """Whether every entry of ``a`` (k,) and of the C-ordered matrices ``X1 .. X4`` is finite:
    ``x * 0`` is 0 for a finite ``x`` and NaN otherwise, and a sum holding a NaN is NaN. Each
    array summed as one flat run, reordered and vectorised (:data:`qchain._jit.jit_sums`),
    with no branch an entry."""
    z = 0.0
    for x in (a, X1.reshape(X1.size), X2.reshape(X2.size), X3.reshape(X3.size), X4.reshape(X4.size)):
        zx = 0.0
        for i in range(x.shape[0]):
            zx += x[i] * 0.0
        z += zx
    return np.isfinite(z)


@jit_pass
def aba_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, ws, wd, wa, sc):
    """Forward dynamics and its exact derivatives in one compiled call (curvature coordinates,
    the material law).

    ``a`` solves ``M a + C v + g + D v + dU_el/dq = B p + tau_ext`` (:func:`qchain.algorithms.recursive.aba`);
    then ``da/dq = M^-1 (df/dq - dID/dq)``, ``da/dv = M^-1 (df/dv - dID/dv)``, ``da/dtau = M^-1``,
    ``da/dp = M^-1 B`` with the inverse-dynamics derivatives of
    :func:`qchain.algorithms.rnea_derivatives.rnea_derivatives` at the
    solved ``a``. ``arr`` is the model's :class:`~qchain.algorithms.arrays.ChainArrays`, whose
    ``locked`` (n, 3) coordinates get zero rows and columns. ``q, qd, p`` (n, 3);
    ``tau_ext`` (nv,) or empty (none); ``V0`` (6,) the base twist, ``A_B`` (6,) the base's own
    acceleration (a prescribed base; zeros otherwise), ``g_B`` (3,) gravity in the base frame. ``ws``, ``wd``,
    ``wa``: :class:`qchain.arm.data.Data`'s aba, rnea-derivative and aba-derivative workspaces.
    Returns 0, or 1 where an articulated block is not positive definite, 2 where ``M`` is not,
    3 where ``a`` or a derivative is not finite.
    """
    # plain tuples from Python (arrays.py), named here
    return _aba_derivatives(ChainArrays(*arr), floating, q, qd, p, tau_ext, V0, A_B, g_B, AbaWorkspace(*ws),
                            RneaWorkspace(*wd), AbaDerivativesWorkspace(*wa), sc)


@jit_pass
def forward_dynamics_derivatives(arr, floating, q, v, p, tau, V0, A_B, g_B, buf, layout):
    """:func:`aba_derivatives` from the chain's whole state, its workspaces in one buffer: the
    ``skip_checks`` path of ``Chain.forward_dynamics_derivatives``, whose Python would otherwise
    cost a tenth of the call at ten segments (dozens of arrays to unbox).

    ``q`` (nq,), ``v`` (nv,): the chain's configuration and velocity (a floating base's 7 and
    6 first); ``p`` (3 n,) Pa; ``tau`` (nv,) or empty (none); ``V0``, ``A_B``, ``g_B`` as
    :func:`aba_derivatives`. ``buf``, ``layout``: :class:`qchain.arm.data.Data`'s
    ``kernel_buffer`` and its table (:func:`qchain.algorithms.layout.kernel_layout`), in which
    the aba, rnea-derivative and aba-derivative workspaces lie (the results ``a``, ``da_dq``,
    ... among them). Returns :func:`aba_derivatives`' status.
    """
    n = p.shape[0] // 3
    qoff = 7 if floating else 0
    voff = 6 if floating else 0
    ws = carve_aba(buf, layout)
    return _aba_derivatives(ChainArrays(*arr), floating, view2(q[qoff:], n, 3), view2(v[voff:], n, 3), view2(p, n, 3),
                            tau, V0, A_B, g_B, ws, carve_rnea(buf, layout), carve_aba_derivatives(buf, layout),
                            ws.scratch)


@jit_helper
def _aba_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, ws, wd, wa, sc):
    """:func:`aba_derivatives` on named structures; ``tau_ext`` (nv,) or empty (none)."""
    n = q.shape[0]
    off = 6 if floating else 0
    f, qdd, A0, a = wa.f, wa.a_c, wa.A0, wa.a
    recursive_internal_forces(arr, q, qd, p, f, sc)
    given = tau_ext.shape[0] > 0
    if given:
        for j in range(n):
            for b in range(3):
                f[j, b] += tau_ext[off + 3 * j + b]
    o = 0
    F0, o = take1(sc, o, 6)
    F0[:] = 0.0
    Aa, o = take1(sc, o, 6)
    for r in range(6):
        Aa[r] = A_B[r]
        if floating and given:
            F0[r] = tau_ext[r]
    for r in range(3):
        Aa[r] -= g_B[r]
    if not recursive_aba(arr, q, qd, f, V0, Aa, floating, F0, qdd, A0, ws, sc[o:]):
        return 1
    if floating:
        for r in range(6):
            a[r] = A0[r]
        for r in range(3):
            a[r] += g_B[r]
    for j in range(n):
        for b in range(3):
            a[off + 3 * j + b] = qdd[j, b]
    # the articulated-body pass has just written every segment's M_xi and bias force into ws
    return _derivatives_after(arr, floating, q, qd, p, qdd, A0, a, V0, g_B, ws, wd, wa, sc, True)


@jit_helper
def _aba_derivatives_at(arr, floating, q, qd, p, qdd, A0, a, V0, g_B, ws, wd, wa, sc):
    """:func:`aba_derivatives` after its forward pass: the derivatives at the solved
    accelerations ``qdd`` (n, 3), ``A0`` (6,) (the base's apparent acceleration: solved for a
    floating base, the given one otherwise) and ``a`` (nv,). The compiled engine calls it
    after its own right-hand side at the same state (:func:`qchain.sim.engine.system.jacobian`),
    so the forward pass is neither computed nor compiled twice."""
    return _derivatives_after(arr, floating, q, qd, p, qdd, A0, a, V0, g_B, ws, wd, wa, sc, False)


@jit_helper
def _derivatives_after(arr, floating, q, qd, p, qdd, A0, a, V0, g_B, ws, wd, wa, sc, blocks_known):
    """:func:`_aba_derivatives_at`; ``blocks_known``: ``ws.M_xi`` and ``ws.Q`` hold the segment
    blocks and bias forces at this state (:func:`aba_derivatives`' own forward pass wrote them),
    which the slice pass then does not integrate again."""
    A_ch, r_ch, paper_act, locked = arr.A_ch, arr.r_ch, arr.paper_act, arr.locked
    n = q.shape[0]
    off = 6 if floating else 0
    nv = off + 3 * n
    L, da_dq, da_dv, da_dtau, da_dp = wa.L, wa.da_dq, wa.da_dv, wa.da_dtau, wa.da_dp
    dfq, dfv, B = wa.dfq, wa.dfv, wa.B
    M, dq, dv = wd.M, wd.dtau_dq, wd.dtau_dv
    _rnea_derivatives(arr, q, qd, qdd, V0, A0, floating, g_B, ws, wd, sc, blocks_known)
    _internal_forces_derivatives(arr, q, p, dfq, dfv, sc)
    _input_matrices(q, A_ch, r_ch, paper_act, B, sc)
    # the right-hand sides df - dID: the configuration's in da_dv until its product is formed
    # (dtau_dq stays: the parameter derivatives read it), the rate's in place of dtau_dv; the
    # free block of M in L with locked coordinates decoupled
    for r in range(nv):
        for c in range(nv):
            da_dv[r, c] = -dq[r, c]
            dv[r, c] = -dv[r, c]
            L[r, c] = M[r, c]
    for j in range(n):
        i0 = off + 3 * j
        for a_ in range(3):
            for b in range(3):
                da_dv[i0 + a_, i0 + b] += dfq[j, a_, b]
                dv[i0 + a_, i0 + b] += dfv[j, a_, b]
    # locked coordinates: decoupled in M (unit diagonal), zero rows and columns in the results
    _zero_locked(locked, off, L, True, True)
    for k in range(off, nv):
        if locked[(k - off) // 3, (k - off) % 3]:
            L[k, k] = 1.0
    if not _inverse_spd(L, nv, da_dtau):
        return 2
    _zero_locked(locked, off, da_dtau, True, True)
    gemm(da_dtau, da_dv, da_dq)  # the products by BLAS (qchain._blas)
    gemm(da_dtau, dv, da_dv)
    _zero_locked(locked, off, da_dq, False, True)
    _zero_locked(locked, off, da_dv, False, True)
    # da_dp = M^-1 B, B block diagonal: its transpose first, row c = 3 j + i a sum of the rows
    # i0 + b of the symmetric M^-1 (long rows, which the compiler vectorises), in L (free now)
    for j in range(n):
        i0 = off + 3 * j
        x0, x1, x2 = da_dtau[i0], da_dtau[i0 + 1], da_dtau[i0 + 2]
        for i in range(3):
            b0, b1, b2 = B[j, 0, i], B[j, 1, i], B[j, 2, i]
            t = L[3 * j + i]
            for r in range(nv):
                t[r] = b0 * x0[r] + b1 * x1[r] + b2 * x2[r]
    for r in range(nv):
        for c in range(3 * n):
            da_dp[r, c] = L[c, r]
    # a non-finite entry anywhere (a blow-up) is reported, never returned silently
    if not _all_finite(a, da_dq, da_dv, da_dtau, da_dp):
        return 3
    return 0
