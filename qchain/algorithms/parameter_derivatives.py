"""Exact derivatives of the dynamics with respect to the model's parameters (numba).

With the internal forces ``f = B p - D v - dU_el/dq`` and the inverse dynamics
``ID = M a + C v + g`` (Pinocchio's ``rnea``), the forward dynamics solve ``ID(q, v, a; theta)
= f(q, v, p; theta) + tau``, so at the solved ``a``

    da/dtheta = M^-1 (df/dtheta - dID/dtheta),

one column a parameter (docs/derivatives.md, "Parameter derivatives"). Each kind of parameter
enters one term, in closed form:

* ``KIND_YOUNGS`` (segment ``j``'s ``E``, Pa): ``EI = E pi r^4 / 4`` and ``EA = E pi r^2``
  scale together, and ``f`` is linear in them (the elastic gradient and the rest damping
  ``beta K(q0)``): ``df/dE = -(g_el + D v)(EI/E, EA/E)``.
* ``KIND_DAMPING`` (``beta``, s): ``df/dbeta = -K(q0) v``.
* ``KIND_AREA`` (``A_ch``, m^2): ``B`` is linear in it (both actuation models):
  ``df/dA_ch = B(A_ch = 1) p``.
* ``KIND_LENGTH`` (rest length ``l0``, m): the elastic law and ``K(q0)``:
  ``d g_el/dl0 = -(EI l |u|^2 + EA l, EI l^2 ux, EI l^2 uy) / l0^2`` and
  ``dK(q0)/dl0 = diag(-EA/l0^2, EI, EI)``. The inertia does not depend on it (a segment's mass
  is a parameter of its own, spread over the current length). Where the segment is
  inextensible (``arr.locked[j, 0]``) ``l0`` is also the held length, so the column is the
  total derivative along ``(l0, q_l)``: it adds the configuration column ``df/dq_l - dID/dq_l``.
* ``KIND_MASS`` (segment mass ``m``, kg): the slice inertias are linear in it, gravity's
  force too (it enters as the base's apparent acceleration), so ``dID/dm_j`` is the inverse
  dynamics of segment ``j`` alone with unit mass, at the chain's own twists and
  accelerations: one forward sweep for all segments (the slices of each segment once, with
  unit mass), then each segment's force carried inwards through the tip maps, O(n^2).
* ``KIND_GRAVITY`` (world gravity component ``k``, m/s^2): gravity is the base's apparent
  acceleration ``A0 = a_B - (R_WB^T g, 0)``, and ``ID`` is linear in ``A0`` with the mass
  matrix's base columns (a floating base's ``M[:, :6]``, else the composite-body pass of a
  floating copy): ``dID/dg = -M_b[:, :3] R_WB^T``.
* ``KIND_BASE`` (a fixed base's placement, component ``k`` of a right (local) perturbation
  ``X_WB exp6(delta)``, ``delta = (translation; rotation)`` in the base frame): the dynamics
  see the base only through ``g_B = R_WB^T g``; ``dg_B/d rot = [g_B]x`` and translation does
  nothing (zero columns).

Curvature coordinates and the layout of :mod:`qchain.algorithms.recursive`; the checked API is
:mod:`qchain.arm.parameter_derivatives`. Unchecked by design: compiled kernels whose
arguments the checked API has validated (``docs/engine.md``, "Unchecked kernels").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._jit import ejit, jit, jit_helper
from ..model.arc import take1, take2
from ..model.slices import _segment_slices, elastic_gradient_c, input_matrix_c, rest_damping_c
from .aba_derivatives import _aba_derivatives_at, aba_derivatives, aba_derivatives_workspace
from .arrays import AbaDerivativesWorkspace, AbaWorkspace, ChainArrays, RneaWorkspace
from .recursive import _load_xi, _matvec, _tip, aba_workspace, crba
from .rnea_derivatives import _rnea_derivatives, rnea_workspace

__all__ = ["KIND_YOUNGS", "KIND_DAMPING", "KIND_MASS", "KIND_LENGTH", "KIND_AREA", "KIND_GRAVITY", "KIND_BASE",
           "ParameterWorkspace", "parameter_workspace", "parameter_derivatives", "parameter_derivatives_at",
           "inverse_parameter_derivatives", "first_order_parameter_derivatives", "fresh_workspaces"]

KIND_YOUNGS, KIND_DAMPING, KIND_MASS, KIND_LENGTH, KIND_AREA, KIND_GRAVITY, KIND_BASE = range(7)


class ParameterWorkspace(NamedTuple):
    """What the parameter passes write besides their outputs: the unit-mass segment forces
    ``Qu`` (n, 9), tip maps ``T`` (n, 6, 9) and biases ``c`` (n, 6) of their own sweep, the
    floating-base mass matrix ``Hf`` (6 + 3n, 6 + 3n) of a fixed or prescribed base (its base
    columns carry gravity), ``Mb`` (nv, 3) the base columns used, ``rhs`` (nv, n_theta)
    ``df/dtheta - dID/dtheta``."""

    Qu: np.ndarray
    T: np.ndarray
    c: np.ndarray
    Hf: np.ndarray
    Mb: np.ndarray
    rhs: np.ndarray


@jit
def parameter_workspace(n, nv, ntheta):
    """Fresh arrays for the parameter passes (:class:`ParameterWorkspace`)."""
    return ParameterWorkspace(np.zeros((n, 9)), np.zeros((n, 6, 9)), np.zeros((n, 6)),
                              np.zeros((6 + 3 * n, 6 + 3 * n)), np.zeros((nv, 3)), np.zeros((nv, ntheta)))


@jit_helper
def _unit_mass_forces(arr, q, qd, qdd, V0, A0, wq, sc):
    """``wq.Qu[j]`` (9,): segment ``j``'s slice Newton-Euler force with unit mass at the chain's
    root twists and apparent accelerations (rnea's forward sweep, gravity included through
    ``A0``); ``wq.T``, ``wq.c`` its tip maps and biases."""
    n = q.shape[0]
    o = 0
    xi, o = take1(sc, o, 9)
    xid, o = take1(sc, o, 9)
    V, o = take1(sc, o, 6)
    A, o = take1(sc, o, 6)
    Md, o = take2(sc, o, 1, 1)
    for r in range(6):
        V[r] = V0[r]
        A[r] = A0[r]
    for j in range(n):
        _load_xi(xi, V, qd[j])
        _load_xi(xid, A, qdd[j])
        _segment_slices(arr.alpha[arr.offs[j] : arr.offs[j + 1]], arr.w[arr.offs[j] : arr.offs[j + 1]], 1.0,
                        arr.radius[j], q[j], xi, xid, False, Md, wq.Qu[j], sc[o:])
        _tip(q[j], qd[j], xi, wq.T[j], wq.c[j], sc[o:])
        _matvec(wq.T[j], xi, V)
        _matvec(wq.T[j], xid, A)
        for r in range(6):
            A[r] += wq.c[j, r]


@jit_helper
def _carry_inwards(Qu, T, j, off, col, sc):
    """``col`` (nv,) = the generalised force of the wrench-and-force ``Qu`` (9,) of segment
    ``j`` alone: its own rows, then carried inwards by ``T_i^T`` (the base's six rows last)."""
    for r in range(col.shape[0]):
        col[r] = 0.0
    o = 0
    F, o = take1(sc, o, 6)
    out, o = take1(sc, o, 9)
    for b in range(3):
        col[off + 3 * j + b] = Qu[6 + b]
    for r in range(6):
        F[r] = Qu[r]
    for i in range(j - 1, -1, -1):
        for k in range(9):
            acc = 0.0
            for r in range(6):
                acc += T[i, r, k] * F[r]
            out[k] = acc
        for b in range(3):
            col[off + 3 * i + b] = out[6 + b]
        for r in range(6):
            F[r] = out[r]
    if off == 6:
        for r in range(6):
            col[r] = F[r]


@jit_helper
def _base_columns(arr, floating, q, M, ws, wq, sc):
    """``wq.Mb`` (nv, 3) = ``dID/dA0[:, :3]``, the mass matrix's linear base columns: a
    floating base's own ``M[:, :3]``; else the composite-body pass of a floating copy
    (:func:`qchain.algorithms.recursive.crba`, writing its tip maps into ``wq.T``)."""
    nv = wq.Mb.shape[0]
    if floating:
        for r in range(nv):
            for k in range(3):
                wq.Mb[r, k] = M[r, k]
        return
    wc = AbaWorkspace(ws.V, wq.T, ws.c, ws.Q, ws.M_xi, ws.Lq, ws.U, ws.u, ws.scratch)
    crba(arr, q, True, wq.Hf, wc, sc)
    for r in range(nv):
        for k in range(3):
            wq.Mb[r, k] = wq.Hf[6 + r, k]


@jit_helper
def _inverse_columns(arr, floating, q, qd, qdd, A0, V0, g_B, R_WB, kinds, index, M, dtau_dq, ws, wq, sc, dID):
    """``dID`` (nv, n_theta) = ``d(M a + C v + g)/dtheta`` at fixed ``(q, v, a)``: mass, gravity
    and base columns; a locked rest length's is the configuration column ``dID/dq_l``; the
    other kinds do not enter the inverse dynamics (zero columns). ``M``, ``dtau_dq`` (nv, nv):
    the inverse-dynamics pass's mass matrix and configuration derivative at the same state."""
    n = q.shape[0]
    nv = dID.shape[0]
    off = 6 if floating else 0
    need_mass = False
    need_base = False
    for k in range(kinds.shape[0]):
        if kinds[k] == KIND_MASS:
            need_mass = True
        if kinds[k] == KIND_GRAVITY or kinds[k] == KIND_BASE:
            need_base = True
    if need_mass:
        _unit_mass_forces(arr, q, qd, qdd, V0, A0, wq, sc)
    if need_base:
        _base_columns(arr, floating, q, M, ws, wq, sc)
    o = 0
    e, o = take1(sc, o, 3)
    for k in range(kinds.shape[0]):
        kind = kinds[k]
        j = index[k]
        col = dID[:, k]
        for r in range(nv):
            col[r] = 0.0
        if kind == KIND_MASS:
            _carry_inwards(wq.Qu[j], wq.T, j, off, col, sc[o:])
        elif kind == KIND_LENGTH and arr.locked[j, 0]:
            for r in range(nv):
                col[r] = dtau_dq[r, off + 3 * j]
        elif kind == KIND_GRAVITY or (kind == KIND_BASE and j >= 3):
            # dg_B = R_WB^T e_j (gravity), [g_B]x e_(j-3) = g_B x e (base rotation)
            for c in range(3):
                e[c] = R_WB[j, c] if kind == KIND_GRAVITY else 0.0
            if kind == KIND_BASE:
                i = j - 3
                e[(i + 1) % 3] = g_B[(i + 2) % 3]
                e[(i + 2) % 3] = -g_B[(i + 1) % 3]
            for r in range(nv):
                col[r] = -(wq.Mb[r, 0] * e[0] + wq.Mb[r, 1] * e[1] + wq.Mb[r, 2] * e[2])


@jit_helper
def _force_columns(arr, floating, q, qd, p, E, kinds, index, dfq, rhs, sc):
    """``rhs`` (nv, n_theta) = ``df/dtheta`` of the internal forces ``B p - D v - dU_el/dq``
    (segment ``index[k]``'s own rows), a locked rest length's with ``df/dq_l`` added; zero for
    the kinds that do not enter ``f``. ``dfq`` (n, 3, 3): ``df/dq`` per segment."""
    nv = rhs.shape[0]
    off = 6 if floating else 0
    o = 0
    g, o = take1(sc, o, 3)
    D, o = take2(sc, o, 3, 3)
    B, o = take2(sc, o, 3, 3)
    h, o = take1(sc, o, 3)
    for k in range(kinds.shape[0]):
        kind = kinds[k]
        j = index[k]
        for r in range(nv):
            rhs[r, k] = 0.0
        if kind == KIND_MASS or kind == KIND_GRAVITY or kind == KIND_BASE:
            continue
        l, ux, uy = q[j, 0], q[j, 1], q[j, 2]
        l0, EI, EA = arr.l0[j], arr.EI[j], arr.EA[j]
        for b in range(3):
            h[b] = 0.0
        if kind == KIND_YOUNGS:
            elastic_gradient_c(q[j], l0, EI / E[j], EA / E[j], g)
            rest_damping_c(l0, EI / E[j], EA / E[j], arr.beta[j], D)
            for b in range(3):
                h[b] = -g[b] - D[b, 0] * qd[j, 0] - D[b, 1] * qd[j, 1] - D[b, 2] * qd[j, 2]
        elif kind == KIND_DAMPING:
            rest_damping_c(l0, EI, EA, 1.0, D)
            for b in range(3):
                h[b] = -D[b, 0] * qd[j, 0] - D[b, 1] * qd[j, 1] - D[b, 2] * qd[j, 2]
        elif kind == KIND_AREA:
            input_matrix_c(q[j], 1.0, arr.r_ch[j], arr.paper_act[j], B, sc[o:])
            for b in range(3):
                h[b] = B[b, 0] * p[j, 0] + B[b, 1] * p[j, 1] + B[b, 2] * p[j, 2]
        elif kind == KIND_LENGTH:
            s = 1.0 / (l0 * l0)
            beta = arr.beta[j]
            # -d(g_el)/dl0 - d(beta K(q0))/dl0 qd
            h[0] = s * (EI * l * (ux * ux + uy * uy) + EA * l) + beta * EA * s * qd[j, 0]
            h[1] = s * EI * l * l * ux - beta * EI * qd[j, 1]
            h[2] = s * EI * l * l * uy - beta * EI * qd[j, 2]
            if arr.locked[j, 0]:  # the held length moves with l0: add df/dq_l
                for b in range(3):
                    h[b] += dfq[j, b, 0]
        for b in range(3):
            rhs[off + 3 * j + b, k] = h[b]


@jit_helper
def _parameter_derivatives_at(arr, floating, q, qd, p, qdd, A0, V0, g_B, R_WB, E, kinds, index, ws, wd, wa, wq,
                              sc, da, dID):
    """The parameter derivatives after :func:`qchain.algorithms.aba_derivatives._aba_derivatives_at`
    at the same state, whose outputs it reads (``wa.da_dtau = M^-1`` of the free block,
    ``wa.dfq``, ``wd.M``, ``wd.dtau_dq``): ``dID`` (nv, n_theta) = ``dID/dtheta`` and
    ``da`` (nv, n_theta) = ``M^-1 (df/dtheta - dID/dtheta)`` (locked rows zero). ``qdd`` (n, 3),
    ``A0`` (6,): the solved segment accelerations and base apparent acceleration."""
    nv = da.shape[0]
    _inverse_columns(arr, floating, q, qd, qdd, A0, V0, g_B, R_WB, kinds, index, wd.M, wd.dtau_dq, ws, wq, sc, dID)
    rhs = wq.rhs
    _force_columns(arr, floating, q, qd, p, E, kinds, index, wa.dfq, rhs, sc)
    Minv = wa.da_dtau
    for r in range(nv):
        for k in range(kinds.shape[0]):
            rhs[r, k] -= dID[r, k]
    for r in range(nv):
        for k in range(kinds.shape[0]):
            da[r, k] = 0.0
        for c in range(nv):
            m = Minv[r, c]
            if m != 0.0:
                for k in range(kinds.shape[0]):
                    da[r, k] += m * rhs[c, k]
    for r in range(nv):
        for k in range(kinds.shape[0]):
            if not (np.isfinite(da[r, k]) and np.isfinite(dID[r, k])):
                return 3
    return 0


@jit
def parameter_derivatives_at(arr, floating, q, qd, p, qdd, A0, V0, g_B, R_WB, E, kinds, index, ws, wd, wa, wq, sc,
                             da, dID):
    """:func:`_parameter_derivatives_at` with a Python entry (the structures as plain tuples)."""
    arr = ChainArrays(*arr)
    return _parameter_derivatives_at(arr, floating, q, qd, p, qdd, A0, V0, g_B, R_WB, E, kinds, index,
                                     AbaWorkspace(*ws), RneaWorkspace(*wd), AbaDerivativesWorkspace(*wa),
                                     ParameterWorkspace(*wq), sc, da, dID)


@ejit
def parameter_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, R_WB, E, kinds, index, ws, wd, wa, wq,
                          sc, da, dID):
    """Forward dynamics, their state derivatives and their parameter derivatives in one
    compiled call (no reference counting, Python's lock released): the arguments of
    :func:`qchain.algorithms.aba_derivatives.aba_derivatives`, then ``R_WB`` (3, 3) the base's
    world rotation, ``E`` (n,) Young's moduli (Pa), the parameters ``kinds``, ``index``
    (n_theta,) int64 (a ``KIND_*`` and its segment or component), the workspaces and the
    outputs ``da``, ``dID`` (nv, n_theta). Returns :func:`aba_derivatives`' status (0: done)."""
    arr = ChainArrays(*arr)
    ws = AbaWorkspace(*ws)
    wd = RneaWorkspace(*wd)
    wa = AbaDerivativesWorkspace(*wa)
    wq = ParameterWorkspace(*wq)
    status = aba_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, ws, wd, wa, sc)
    if status != 0:
        return status
    return _parameter_derivatives_at(arr, floating, q, qd, p, wa.a_c, wa.A0, V0, g_B, R_WB, E, kinds, index, ws, wd,
                                     wa, wq, sc, da, dID)


@ejit
def first_order_parameter_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, R_WB, E, kinds, index, ws, wd,
                                      wa, wq, sc, dID, dx):
    """``dx`` (2 nv, n_theta) = ``d(v, a)/dtheta`` of the first-order system ``x' = (v, a)``
    (the top half zero), by :func:`parameter_derivatives`; the same status."""
    nv = dID.shape[0]
    for r in range(nv):
        for k in range(kinds.shape[0]):
            dx[r, k] = 0.0
    return parameter_derivatives(arr, floating, q, qd, p, tau_ext, V0, A_B, g_B, R_WB, E, kinds, index, ws, wd, wa,
                                 wq, sc, dx[nv:], dID)


@jit
def inverse_parameter_derivatives(arr, floating, q, qd, qdd, V0, A0, g_B, R_WB, kinds, index, ws, wd, wq, sc, dID):
    """``dID/dtheta`` (nv, n_theta) of the inverse dynamics ``M a + C v + g`` at ``qdd`` (n, 3) and
    the base's apparent acceleration ``A0`` (6,), after the inverse-dynamics derivatives
    (:func:`qchain.algorithms.rnea_derivatives.rnea_derivatives`, whose outputs ``wd`` holds:
    ``tau_c``, ``F0``, ``M``, ``dtau_dq``)."""
    arr = ChainArrays(*arr)
    ws = AbaWorkspace(*ws)
    wd = RneaWorkspace(*wd)
    wq = ParameterWorkspace(*wq)
    _rnea_derivatives(arr, q, qd, qdd, V0, A0, floating, g_B, ws, wd, sc)
    _inverse_columns(arr, floating, q, qd, qdd, A0, V0, g_B, R_WB, kinds, index, wd.M, wd.dtau_dq, ws, wq, sc, dID)


def fresh_workspaces(n: int, nv: int, ntheta: int):
    """``(ws, wd, wa, wq)``: the workspaces of :func:`parameter_derivatives` for one call."""
    return (aba_workspace(n, nv), rnea_workspace(n, nv), aba_derivatives_workspace(n, nv),
            parameter_workspace(n, nv, ntheta))
