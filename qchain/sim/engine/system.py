"""The first-order system a compiled stepper integrates, packed for numba.

A run's state is ``y = (delta, v_A)`` (2 nA,) over the ``nA`` free velocity coordinates
``idx = flatnonzero(chain.active)``: locked coordinates (``planar``, inextensible segments)
are not in ``y`` at all, so every stepper works, factorises and controls errors on the free
coordinates only. The configuration is ``q = q_chart (+) delta``: additive for the segment
coordinates, ``ff_integrate`` (Pinocchio's free-flyer ``integrate``, on SE(3)) for a floating
base, whose chart is moved to the current placement when it has turned far
(:data:`RECENTER`); then

    d(delta)/dt = dexp^-1(delta_B) v_B (base),  v_A (segments),   dv_A/dt = a_A(t, q, v).

:func:`qchain.sim.engine.packing.pack` turns a :class:`qchain.Chain` and its inputs into an
:class:`EngineModel` ``m`` (never written by a pass) and :func:`workspace` a :class:`Workspace` ``wk`` (everything a
pass writes): named tuples of arrays, which numba compiles with attribute access, so that
one compiled specialisation serves every chain.

Status codes returned by every pass: :data:`OK`, :data:`DOMAIN` (a segment left the model's
domain: ``|kappa| r >= 1`` or ``l <= 0``; ``info[1]`` its index), :data:`SINGULAR` (an
articulated inertia not positive definite), :data:`NONFINITE`.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ...algorithms import aba_derivatives, planar, recursive
from ...contact.environment import PackedEnvironment
from ...contact.derivatives import NODE_T, environment_derivatives
from ...contact.drag import DRAG_FRAME, drag_derivatives, drag_forces
from ...contact.forces import ROOT
from ...contact.distance import PARAMS, move
from ...contact.forces import beyond_reach, contact_forces, load_forces
from ...contact.planar import planar_contact_forces
from ...algorithms.arrays import ChainArrays, carve_aba, carve_aba_derivatives, carve_planar, carve_rnea
from ...algorithms.layout import kernel_layout
from ...model.arc import SCRATCH, arc_node, take1, take2
from ...model.slices import law_energy_c, slice_twist
from ...model.tendon import tendon_length_c
from . import lie, schedules
from ..._jit import ejit, ejit_inner, inline, kernel, view2, view3, view4

__all__ = ["EngineModel", "Workspace", "workspace", "rhs", "rhs_planar", "rhs_spatial", "jacobian",
           "configuration", "energies", "energies_batch", "inputs", "RECENTER", "OK", "DOMAIN", "SINGULAR", "NONFINITE",
           "FIXED", "FLOATING", "PRESCRIBED"]

OK, DOMAIN, SINGULAR, NONFINITE = 0, 1, 2, 3
FIXED, FLOATING, PRESCRIBED = 0, 1, 2  #: :attr:`EngineModel.base`
RECENTER = 0.5  #: rad or m of base chart coordinates before the chart is moved


class EngineModel(NamedTuple):
    """The model a compiled pass reads, never writes (:func:`qchain.sim.engine.packing.pack`); ``N`` nodes over all
    segments, ``n`` segments, ``nA`` free velocity coordinates.

    Attributes
    ----------
    arrays : ChainArrays
        The chain's per-node and per-segment arrays (:meth:`qchain.Chain.kernel_arrays`, a
        :class:`qchain.algorithms.arrays.ChainArrays`: ``alpha, w, offs, mass, radius, l0, EI, EA,
        beta, A_ch, r_ch, paper_act, locked, payload, D, K, q_rest, linear_law, drag``), the first argument of every pass.
    idx : (nA,) int64
        The free velocity coordinates, ``flatnonzero(chain.active)``.
    base : int
        :data:`FIXED`, :data:`FLOATING` or :data:`PRESCRIBED`.
    planar_kernel : int
        1: the forward dynamics run on :func:`qchain.algorithms.planar.planar_aba_moving`.
    nq, nv : int
        Configuration and velocity sizes.
    g_W : (3,) float
        World gravity (m/s^2).
    R_WB0, p_WB0 : (3, 3), (3,) float
        A fixed base's placement in the world (m).
    bm_ints, bm_params : (k,) int64, (k',) float
        A prescribed base's motion (:func:`qchain.sim.engine.schedules.pack_base_motion`).
    p_ints, p_params : (k,) int64, (k',) float
        The pressure input (Pa; :func:`qchain.sim.engine.schedules.pack_input`); a held
        controller's output is written into ``p_params`` at its instants.
    tau_ints, tau_params : (k,) int64, (k',) float
        The generalised-force input, likewise.
    layout : (K + 1, 5) int64
        Where the kernel workspaces lie in :attr:`Workspace.buf` (:func:`qchain.algorithms.layout.kernel_layout`).
    env : PackedEnvironment
        Obstacles, contact law and point loads (:meth:`qchain.contact.Environment.packed`);
        none of either costs nothing.
    tendon_rows, tendon_nodes, tendon_weights : (R, 7), (K,), (K,) float
        The tendons' routing (:func:`qchain.arm.tendons.tendon_table`; none: ``R = 0``).
    tn_ints, tn_params : (k,) int64, (k',) float
        The tension input (N), as the pressure input.
    """

    arrays: ChainArrays
    idx: np.ndarray
    base: int
    planar_kernel: int
    nq: int
    nv: int
    g_W: np.ndarray
    R_WB0: np.ndarray
    p_WB0: np.ndarray
    bm_ints: np.ndarray
    bm_params: np.ndarray
    p_ints: np.ndarray
    p_params: np.ndarray
    tau_ints: np.ndarray
    tau_params: np.ndarray
    layout: np.ndarray
    env: PackedEnvironment
    tendon_rows: np.ndarray
    tendon_nodes: np.ndarray
    tendon_weights: np.ndarray
    tn_ints: np.ndarray
    tn_params: np.ndarray


class Workspace(NamedTuple):
    """The arrays the passes write (:func:`workspace`; one run, one thread). Few arrays:
    numba's compile time grows with the number of arrays a compiled function passes around.

    Attributes
    ----------
    q, v : (nq,), (nv,) float
        The configuration and velocity of the last evaluation.
    q_chart : (nq,) float
        The chart's centre: ``q = q_chart (+) delta``.
    p : (nu,) float
        Pressures (Pa).
    tau : (nv,) float
        Generalised force input.
    tension : (nt,) float
        Tendon tensions (N).
    f : (n, 3) float
        Internal plus external generalised forces on the segment coordinates.
    A0 : (6,) float
        The apparent base acceleration (gravity folded in).
    a : (nv,) float
        The acceleration.
    qdd : (n, 3) float
        The segment coordinates' acceleration.
    B : (4, 6) float
        The base's state (:func:`_base_state`).
    info : (4,) int64
        Status and the segment it concerns; ``info[2]``: the most contacts any right-hand side
        of the run found active (a run's ``meta["max_active_contacts"]``).
    buf : (size,) float
        The kernels' workspaces in one buffer (:data:`qchain.algorithms.arrays.KERNEL_NDIM`, carved by
        :func:`aba_ws` and its siblings).
    scratch : (SCRATCH,) float
        The model passes' scratch.
    R_WB : (3, 3) float
        The base's rotation in the world.
    W : (2, n + 2, 6) float
        The environment pass's root wrenches (``W[0, 0..n]``) and its wrench on the base
        (``W[0, n + 1]``, base frame); ``W[1]`` their changes in a tangent pass.
    Jenv : (2, nv, nv) float
        The environment's ``d tau/dq`` and ``d tau/dv`` (:mod:`qchain.contact.derivatives`).
    Denv : (3, n, 3), Eenv : (3, 6) float
        The tangent passes' directions and results.
    prm_t, vel : (m, PARAMS), (m, 3) float
        The obstacles at the time of the last evaluation and their velocities
        (:func:`qchain.contact.distance.move`).
    roots, nodes : (n, ROOT + 12), (2, K, NODE_T) float
        The self-contact passes' roots and contact nodes (empty without self-contact).
    drag_frames : (N + n, DRAG_FRAME) float
        The nodes' frames the drag's tangent passes read (:func:`qchain.contact.drag.drag_frames`;
        empty without drag).
    """

    q: np.ndarray
    v: np.ndarray
    q_chart: np.ndarray
    p: np.ndarray
    tau: np.ndarray
    tension: np.ndarray
    f: np.ndarray
    A0: np.ndarray
    a: np.ndarray
    qdd: np.ndarray
    B: np.ndarray
    info: np.ndarray
    buf: np.ndarray
    scratch: np.ndarray
    R_WB: np.ndarray
    W: np.ndarray
    Jenv: np.ndarray
    Denv: np.ndarray
    Eenv: np.ndarray
    prm_t: np.ndarray
    vel: np.ndarray
    roots: np.ndarray
    nodes: np.ndarray
    drag_frames: np.ndarray


def workspace(chain, m: EngineModel | None = None) -> Workspace:
    """A fresh :class:`Workspace` for ``chain`` (and the obstacles of its packed model ``m``), zeros."""
    n, nv, nq = chain.n, chain.nv, chain.nq
    k = 0 if m is None else m.env.kind.shape[0]
    selfc = m is not None and m.env.law[7] > 0.0
    K = m.env.calpha.shape[0] if selfc else 0
    return Workspace(q=np.zeros(nq), v=np.zeros(nv), q_chart=np.zeros(nq), p=np.zeros(3 * n), tau=np.zeros(nv),
                     tension=np.zeros(chain.nt),
                     f=np.zeros((n, 3)), A0=np.zeros(6), a=np.zeros(nv), qdd=np.zeros((n, 3)), B=np.zeros((4, 6)),
                     info=np.zeros(4, dtype=np.int64), buf=np.zeros(kernel_layout(n, nv)[-1, 0]),
                     scratch=np.zeros(SCRATCH),
                     R_WB=np.zeros((3, 3)), W=np.zeros((2, n + 2, 6)),
                     Jenv=np.zeros((2, nv, nv)), Denv=np.zeros((3, n, 3)), Eenv=np.zeros((3, 6)),
                     prm_t=np.zeros((k, PARAMS)), vel=np.zeros((k, 3)), roots=np.zeros((n if selfc else 0, ROOT + 12)),
                     nodes=np.zeros((2, K, NODE_T)),
                     drag_frames=np.zeros((chain._alpha.size + n if chain._has_drag else 0, DRAG_FRAME)))


@inline
def aba_ws(m, wk):
    """The aba workspace (:func:`qchain.algorithms.recursive.aba_workspace`) carved from ``wk``'s buffer."""
    return carve_aba(wk.buf, m.layout)


@inline
def rnea_ws(m, wk):
    """The rnea-derivative workspace (:func:`qchain.algorithms.rnea_derivatives.rnea_workspace`), carved."""
    return carve_rnea(wk.buf, m.layout)


@inline
def aba_derivatives_ws(m, wk):
    """The aba-derivative workspace (:func:`qchain.algorithms.aba_derivatives.aba_derivatives_workspace`), carved."""
    return carve_aba_derivatives(wk.buf, m.layout)


@inline
def planar_ws(m, wk):
    """The planar kernel's workspace (:func:`qchain.algorithms.planar.planar_workspace`), carved."""
    return carve_planar(wk.buf, m.layout)


@inline
def copy(dst, src):
    """``dst[:] = src`` (1-D) as a loop: the engine runs without numba's reference counting
    (``_nrt=False``: no atomic count per array view, most of a call's cost otherwise), which
    has no array-to-array assignment."""
    for i in range(dst.shape[0]):
        dst[i] = src[i]


@inline
def _base_state(m, wk, t, q, v):
    """Fill ``B = wk.B`` (4, 6): ``B[0]`` the base twist ``V0``, ``B[1]`` its own acceleration
    ``A_B`` (prescribed), ``B[2, :3]`` gravity in the base frame ``g_B``, ``B[3, :3]`` the base
    origin in the world; ``R = wk.R_WB`` the base rotation ``R_WB``."""
    g_W = m.g_W
    B = wk.B
    R = wk.R_WB
    B[1, :] = 0.0
    if m.base == FIXED:
        B[0, :] = 0.0
        for r in range(3):
            copy(R[r], m.R_WB0[r])
        copy(B[3, :3], m.p_WB0)
    elif m.base == FLOATING:
        copy(B[0], v[:6])
        _rotation(q[3:7], R)
        copy(B[3, :3], q[:3])
    else:
        schedules.base_motion_eval(m.bm_ints, m.bm_params, t, R, B[3, :3], B[0], B[1])
    for r in range(3):
        B[2, r] = R[0, r] * g_W[0] + R[1, r] * g_W[1] + R[2, r] * g_W[2]


@inline
def _rotation(quat, R):
    """``R`` (3, 3) of the unit quaternion ``(x, y, z, w)``."""
    x, y, z, w = quat[0], quat[1], quat[2], quat[3]
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - z * w)
    R[0, 2] = 2.0 * (x * z + y * w)
    R[1, 0] = 2.0 * (x * y + z * w)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - x * w)
    R[2, 0] = 2.0 * (x * z - y * w)
    R[2, 1] = 2.0 * (y * z + x * w)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@inline
def configuration(m, wk, qc, y):
    """``q = qc (+) delta`` into ``wk.q`` and the full ``v`` into ``wk.v`` from ``y``, with
    ``qc`` (nq,) the chart's centre."""
    idx = m.idx
    nA = idx.shape[0]
    q, v = wk.q, wk.v
    v[:] = 0.0
    for i in range(nA):
        v[idx[i]] = y[nA + i]
    if m.base == FLOATING:
        lie.ff_integrate(qc[:7], y[:6], q[:7])
        for i in range(7, q.shape[0]):
            q[i] = qc[i]
        for i in range(6, nA):
            q[idx[i] + 1] = qc[idx[i] + 1] + y[i]
    else:
        copy(q, qc)
        for i in range(nA):
            q[idx[i]] += y[i]


@inline
def check(m, wk, q):
    """Domain check of the segment coordinates; sets ``info`` and returns the status."""
    info = wk.info
    n = m.arrays.radius.shape[0]
    off = m.nq - 3 * n
    for i in range(q.shape[0]):
        if not np.isfinite(q[i]):
            info[0] = NONFINITE
            return NONFINITE
    qe = view2(q[off:], n, 3)
    j = recursive.first_invalid(m.arrays.radius[:0], qe, m.arrays.radius, m.arrays.paper_act)  # a contiguous empty first argument: one type
    if j >= 0:
        info[0] = DOMAIN
        info[1] = j
        return DOMAIN
    return OK


@inline
def inputs(m, wk, t):
    """Pressure ``wk.p``, generalised force ``wk.tau`` and tensions ``wk.tension`` at ``t``."""
    schedules.input_eval(m.p_ints, m.p_params, t, wk.p)
    schedules.input_eval(m.tau_ints, m.tau_params, t, wk.tau)
    if wk.tension.shape[0] > 0:
        schedules.input_eval(m.tn_ints, m.tn_params, t, wk.tension)


@inline
def tendon_row_gradient(m, i, q_c, hessian, g, H):
    """``g = dL/dq_j`` (3,) of row ``i`` of ``m.tendon_rows`` (a tendon's pass through segment
    ``j``; :func:`qchain.model.tendon.tendon_length_c`) at the segment coordinates ``q_c``
    (n, 3), and with ``hessian`` ``H = d2L/dq_j^2`` (3, 3; else scratch); returns ``(k, j)``,
    the tendon and the segment. The domain is the caller's to check. ``-g`` is segment ``j``'s
    block of ``B_T(q)``'s column ``k``."""
    rows = m.tendon_rows
    k = int(rows[i, 0])
    j = int(rows[i, 1])
    a, b = int(rows[i, 5]), int(rows[i, 6])
    tendon_length_c(q_c[j], rows[i, 2], rows[i, 3], rows[i, 4], m.tendon_nodes[a:b], m.tendon_weights[a:b], hessian,
                    g, H)
    return k, j


@inline
def _tendon_forces(m, wk, q_c, f):
    """``f += B_T(q) T`` (n, 3): each tendon's ``-T dL/dq`` on the segments it passes
    (:func:`qchain.model.tendon.tendon_length_c`); returns the status (DOMAIN where a fibre
    would have no length, ``kappa r >= 1``, ``info[1]`` the segment)."""
    rows = m.tendon_rows
    sc = wk.scratch
    g, o = take1(sc, 0, 3)
    H, o = take2(sc, o, 3, 3)
    for i in range(rows.shape[0]):
        k = int(rows[i, 0])
        j = int(rows[i, 1])
        r = rows[i, 2]
        if (q_c[j, 1] * q_c[j, 1] + q_c[j, 2] * q_c[j, 2]) * r * r >= 1.0:
            wk.info[0] = DOMAIN
            wk.info[1] = j
            return DOMAIN
        tendon_row_gradient(m, i, q_c, False, g, H)
        T = wk.tension[k]
        for c in range(3):
            f[j, c] -= T * g[c]
    return OK


@inline
def _tendon_jacobian(m, wk, q_c, Minv, da_dq):
    """``da_dq += M^-1 d(B_T T)/dq`` (nv, nv): the tendons' exact stiffness ``-T d^2 L/dq^2``,
    block-diagonal on the segments (written in ``wk.Jenv[0]``'s first rows: the environment's
    pass is done with it by now)."""
    rows = m.tendon_rows
    n = q_c.shape[0]
    voff = m.nv - 3 * n
    nv = m.nv
    sc = wk.scratch
    g, o = take1(sc, 0, 3)
    H, o = take2(sc, o, 3, 3)
    K = wk.Jenv[0]  # (nv, nv); only the (3, 3) blocks are written, each column block at a time
    for j in range(n):
        for a in range(3):
            for c in range(3):
                K[a, c] = 0.0
        touched = False
        for i in range(rows.shape[0]):
            if int(rows[i, 1]) != j:
                continue
            touched = True
            k, _ = tendon_row_gradient(m, i, q_c, True, g, H)
            T = wk.tension[k]
            for a in range(3):
                for c in range(3):
                    K[a, c] -= T * H[a, c]
        if not touched:
            continue
        # da_dq[:, block j] += Minv[:, block j] K_j
        for r in range(nv):
            for c in range(3):
                acc = 0.0
                for a in range(3):
                    acc += Minv[r, voff + 3 * j + a] * K[a, c]
                da_dq[r, voff + 3 * j + c] += acc


@inline
def _forces(m, wk, t):
    """What the forward dynamics at ``(t, wk.q, wk.v)`` needs before the articulated-body
    pass: the domain check, the inputs, the base's state, the internal plus external forces
    ``f = wk.f`` and the apparent base acceleration ``A0 = wk.A0`` (gravity folded in), the
    base wrench in ``wk.B[3]``; returns the status."""
    q, v = wk.q, wk.v
    p, tau, f, A0, B = wk.p, wk.tau, wk.f, wk.A0, wk.B
    n = m.arrays.mass.shape[0]
    qoff = m.nq - 3 * n
    voff = m.nv - 3 * n
    status = check(m, wk, q)
    if status != OK:
        return status
    inputs(m, wk, t)
    _base_state(m, wk, t, q, v)
    recursive.internal_forces(m.arrays, view2(q[qoff:], n, 3), view2(v[voff:], n, 3), view2(p, n, 3), f,
                              wk.scratch)
    for j in range(n):
        for b in range(3):
            f[j, b] += tau[voff + 3 * j + b]
    if m.tendon_rows.shape[0] > 0:
        status = _tendon_forces(m, wk, view2(q[qoff:], n, 3), f)
        if status != OK:
            return status
    _environment(m, wk, t, view2(q[qoff:], n, 3), view2(v[voff:], n, 3), f)
    if _any_drag(m.arrays):  # the medium's drag: beside the environment's forces, its base wrench with theirs
        drag_forces(m.arrays, view2(q[qoff:], n, 3), view2(v[voff:], n, 3), B[0], f, wk.W[0, n + 1],
                    wk.W[0, : n + 1], wk.scratch)
    F0 = B[3]  # reused: the base wrench (floating); the origin row is not needed past here
    F_env = wk.W[0, n + 1]
    for r in range(6):
        A0[r] = B[1, r]
        F0[r] = tau[r] + F_env[r] if m.base == FLOATING else 0.0
    for r in range(3):
        A0[r] -= B[2, r]
    return OK


@inline
def _environment(m, wk, t, q_c, v_c, f):
    """Add the environment's generalised forces to ``f`` (n, 3) and its wrench on the base to
    ``wk.W[n + 1]`` (zeroed first), and raise ``wk.info[2]`` to the active contacts' count;
    nothing to do without obstacles or loads."""
    env = m.env
    n = q_c.shape[0]
    W = wk.W[0]
    F_env = W[n + 1]
    for r in range(6):
        F_env[r] = 0.0
    if env.kind.shape[0] > 0 or env.law[7] > 0.0:
        move(env.kind, env.prm, env.motion, t, wk.prm_t, wk.vel)
        # the far test before the call: the call's arguments (the model's arrays) cost more than it
        if env.law[7] > 0.0 or not beyond_reach(m.arrays.radius, q_c, env.kind, wk.prm_t, wk.B[3, :3], wk.scratch):
            if m.planar_kernel == 1 and env.law[7] == 0.0:  # in-plane at 2-D cost (self-contact: the spatial pass)
                count = planar_contact_forces(m.arrays, env.kind, wk.prm_t, wk.vel, env.law, env.calpha, q_c, v_c,
                                              wk.R_WB, wk.B[3, :3], wk.B[0], f, F_env, W[: n + 1], wk.scratch)
            else:
                count = contact_forces(m.arrays, env.kind, wk.prm_t, wk.vel, env.law, env.calpha, q_c, v_c, wk.R_WB,
                                       wk.B[3, :3], wk.B[0], f, F_env, W[: n + 1], wk.roots, wk.nodes, W[:0],
                                       wk.scratch)
            if count > wk.info[2]:
                wk.info[2] = count
    if env.seg.shape[0] > 0:
        load_forces(env.seg, env.alpha, env.wrench, env.local, q_c, wk.R_WB, wk.B[3, :3], f, F_env, W[: n + 1],
                    wk.scratch)


@inline
def _any_drag(arr):
    """Whether some segment has drag (``ChainArrays.drag``)."""
    for j in range(arr.drag.shape[0]):
        if arr.drag[j, 0] != 0.0 or arr.drag[j, 1] != 0.0:
            return True
    return False


@inline
def _drag_jacobian(m, wk, q_c, v_c, Minv, da_dq, da_dv):
    """``da_dq += M^-1 d tau_drag/dq`` and ``da_dv += M^-1 d tau_drag/dv`` (nv, nv), the drag's
    exact derivatives (:func:`qchain.contact.drag.drag_derivatives`; the environment's work
    arrays, free by now) at the state of the last right-hand side (``wk.B[0]``: its base twist)."""
    n = q_c.shape[0]
    nv = m.nv
    Jq, Jv = wk.Jenv[0], wk.Jenv[1]
    drag_derivatives(m.arrays, m.base == FLOATING, q_c, v_c, wk.B[0], Jq, Jv, wk.W[0, : n + 1], wk.W[1, : n + 1],
                     wk.Denv, wk.Eenv, wk.drag_frames, wk.scratch)
    _add_Minv_times(Minv, Jq, Jv, nv, da_dq, da_dv)


@inline
def _add_Minv_times(Minv, Jq, Jv, nv, da_dq, da_dv):
    """``da_dq += M^-1 Jq`` and ``da_dv += M^-1 Jv`` over the leading ``nv`` rows and columns:
    an external force's derivatives ``Jq``, ``Jv`` (nv, nv) turned into the accelerations'."""
    for r in range(nv):
        for c in range(nv):
            aq = 0.0
            av = 0.0
            for k in range(nv):
                aq += Minv[r, k] * Jq[k, c]
                av += Minv[r, k] * Jv[k, c]
            da_dq[r, c] += aq
            da_dv[r, c] += av


@inline
def _environment_jacobian(m, wk, t, q_c, v_c, Minv, da_dq, da_dv):
    """``da_dq += M^-1 d tau_env/dq`` and ``da_dv += M^-1 d tau_env/dv`` (nv, nv), the
    environment's exact derivatives (:func:`qchain.contact.derivatives.environment_derivatives`)
    at the state of the last right-hand side (whose base origin row ``B[3]`` holds the base
    wrench by now: the base's state is made again)."""
    _base_state(m, wk, t, wk.q, wk.v)
    env = m.env
    n = q_c.shape[0]
    nv = m.nv
    Jq, Jv = wk.Jenv[0], wk.Jenv[1]
    move(env.kind, env.prm, env.motion, t, wk.prm_t, wk.vel)
    environment_derivatives(m.arrays, env.kind, wk.prm_t, wk.vel, env.law, env.calpha, env.seg, env.alpha, env.wrench,
                            env.local, m.base == FLOATING, q_c, v_c, wk.R_WB, wk.B[3, :3], wk.B[0], Jq, Jv,
                            wk.W[0, : n + 1], wk.W[1, : n + 1], wk.Denv, wk.Eenv, wk.roots, wk.nodes, wk.scratch)
    _add_Minv_times(Minv, Jq, Jv, nv, da_dq, da_dv)


@inline
def _rates(m, wk, y, out, ok):
    """After the articulated-body pass (``ok``: it succeeded): ``a = wk.a`` (nv,) and
    ``out = dy/dt``; returns the status."""
    idx = m.idx
    a, qdd, B = wk.a, wk.qdd, wk.B
    A0 = wk.A0
    n = m.arrays.mass.shape[0]
    voff = m.nv - 3 * n
    if not ok:
        wk.info[0] = SINGULAR
        return SINGULAR
    if m.base == FLOATING:
        for r in range(6):
            a[r] = A0[r]
        for r in range(3):
            a[r] += B[2, r]
    for j in range(n):
        for b in range(3):
            a[voff + 3 * j + b] = qdd[j, b]
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            wk.info[0] = NONFINITE
            return NONFINITE
    nA = idx.shape[0]
    for i in range(nA):
        out[nA + i] = a[idx[i]]
    position_rate(m, y, out)
    return OK


@inline
def _segment_states(m, wk):
    """The segment coordinates and velocities of ``wk.q``, ``wk.v`` as ``(n, 3)`` views."""
    n = m.arrays.mass.shape[0]
    return view2(wk.q[m.nq - 3 * n:], n, 3), view2(wk.v[m.nv - 3 * n:], n, 3)


@kernel
def rhs_planar(m, wk, t, y, out):
    """``out = dy/dt`` (2 nA,) at ``(t, y)`` of a chain on the planar kernel (``m.planar_kernel == 1``,
    :func:`qchain.algorithms.planar.planar_aba_moving`); returns the status (``out`` undefined unless OK).
    A C callback (:func:`~qchain._jit.kernel`)."""
    configuration(m, wk, wk.q_chart, y)
    status = _forces(m, wk, t)
    if status != OK:
        return status
    q_c, v_c = _segment_states(m, wk)
    pw = planar_ws(m, wk)
    ok = planar.planar_aba_moving(m.arrays, q_c, v_c, wk.f, wk.B[0], wk.A0, wk.qdd, pw, pw.pscratch)
    return _rates(m, wk, y, out, ok)


@kernel
def rhs_spatial(m, wk, t, y, out):
    """``out = dy/dt`` (2 nA,) at ``(t, y)`` on the 3-D articulated-body pass
    (:func:`qchain.algorithms.recursive.aba`); as :func:`rhs_planar`."""
    configuration(m, wk, wk.q_chart, y)
    status = _forces(m, wk, t)
    if status != OK:
        return status
    q_c, v_c = _segment_states(m, wk)
    A0 = wk.A0
    ok = recursive.aba(m.arrays, q_c, v_c, wk.f, wk.B[0], A0, m.base == FLOATING, wk.B[3], wk.qdd, A0, aba_ws(m, wk),
                       wk.scratch)
    return _rates(m, wk, y, out, ok)


def rhs(m):
    """The right-hand side :class:`~qchain._jit.Kernel` for the model ``m``
    (:class:`EngineModel`)."""
    return rhs_planar if m.planar_kernel == 1 else rhs_spatial


@inline
def position_rate(m, y, out):
    """The kinematic rows ``out[:nA] = d(delta)/dt``: ``v_A``, with ``dexp^-1(delta_B) v_B`` for a
    floating base's six."""
    nA = y.shape[0] // 2
    for i in range(nA):
        out[i] = y[nA + i]
    if m.base == FLOATING:
        lie.dexp_inv_apply(y[:6], y[nA : nA + 6], out[:6])


@kernel
def jacobian(m, wk, t, y, Jq, Jv):
    """The exact Jacobian blocks of ``dv_A/dt``: ``Jq = da_A/d(delta)`` and ``Jv = da_A/dv_A``
    (nA, nA) at ``(t, y)`` (configuration derivatives along ``integrate``, exact at
    ``delta_B = 0``); returns the status. Called right after the right-hand side at the same
    ``(t, y)``, whose forward pass it reuses from ``wk`` (:func:`qchain.algorithms.aba_derivatives._aba_derivatives_at`):
    the forward dynamics are neither computed nor compiled a second time. A C callback
    (:func:`~qchain._jit.kernel`)."""
    idx = m.idx
    nA = idx.shape[0]
    B = wk.B
    wa = aba_derivatives_ws(m, wk)
    n = m.arrays.mass.shape[0]
    q_c, v_c = _segment_states(m, wk)
    a = wa.a
    copy(a, wk.a)
    status = aba_derivatives._aba_derivatives_at(m.arrays, m.base == FLOATING, q_c, v_c, view2(wk.p, n, 3), wk.qdd,
                                                 wk.A0, a, B[0], B[2, :3], aba_ws(m, wk), rnea_ws(m, wk), wa,
                                                 wk.scratch)
    if status != 0:
        wk.info[0] = SINGULAR if status < 3 else NONFINITE
        return wk.info[0]
    da_dq, da_dv = wa.da_dq, wa.da_dv
    if m.env.kind.shape[0] > 0 or m.env.seg.shape[0] > 0 or m.env.law[7] > 0.0:
        _environment_jacobian(m, wk, t, q_c, v_c, wa.da_dtau, da_dq, da_dv)
    if m.tendon_rows.shape[0] > 0:
        _tendon_jacobian(m, wk, q_c, wa.da_dtau, da_dq)
    if _any_drag(m.arrays):
        _drag_jacobian(m, wk, q_c, v_c, wa.da_dtau, da_dq, da_dv)
    for r in range(nA):
        for c in range(nA):
            Jq[r, c] = da_dq[idx[r], idx[c]]
            Jv[r, c] = da_dv[idx[r], idx[c]]
    return OK


@ejit_inner
def energies(m, wk, t, q, v):
    """``(kinetic, potential)`` (J) at ``(t, q, v)``: ``1/2 sum_j xi_j^T M_xi_j xi_j`` (the
    base's own motion included), gravity about the world origin plus the elastic energy.
    One pass over the segments' nodes: the kinetic energy as the quadrature of eq. (6)'s
    integrand itself, ``1/2 sum_k w_k V_k^T I_d V_k`` with the slice twists ``V_k = Phi_k xi``
    (equal to ``1/2 xi^T M_xi xi`` without forming the 9 x 9 ``M_xi``), the node positions
    for gravity, the tip twist and frame for the next segment's root. ``q``, ``v`` full
    (nq,), (nv,). Compiled callers only (no CPython wrapper): from Python,
    :func:`energies_batch`."""
    ar = m.arrays
    alpha, w, offs, mass, radius, l0, EI, EA = ar.alpha, ar.w, ar.offs, ar.mass, ar.radius, ar.l0, ar.EI, ar.EA
    g_W = m.g_W
    n = mass.shape[0]
    qoff = m.nq - 3 * n
    voff = m.nv - 3 * n
    B = wk.B
    sc = wk.scratch
    _base_state(m, wk, t, q, v)
    o = 0
    V, o = take1(sc, o, 6)
    Vn, o = take1(sc, o, 6)
    qd, o = take1(sc, o, 3)
    R, o = take2(sc, o, 3, 3)
    p, o = take1(sc, o, 3)
    S, o = take2(sc, o, 6, 3)
    Sd, o = take2(sc, o, 6, 3)
    Rj, o = take2(sc, o, 3, 3)
    oj, o = take1(sc, o, 3)
    Rn, o = take2(sc, o, 3, 3)
    copy(V, B[0])
    for r in range(3):
        copy(Rj[r], wk.R_WB[r])
    copy(oj, B[3, :3])
    kin = 0.0
    pot = 0.0
    for j in range(n):
        l = q[qoff + 3 * j]
        ux = q[qoff + 3 * j + 1]
        uy = q[qoff + 3 * j + 2]
        for b in range(3):
            qd[b] = v[voff + 3 * j + b]
        mj = mass[j]
        ixx = 0.25 * mj * radius[j] * radius[j]
        izz = 0.5 * mj * radius[j] * radius[j]
        gx = g_W[0] * Rj[0, 0] + g_W[1] * Rj[1, 0] + g_W[2] * Rj[2, 0]  # gravity in the root frame
        gy = g_W[0] * Rj[0, 1] + g_W[1] * Rj[1, 1] + g_W[2] * Rj[2, 1]
        gz = g_W[0] * Rj[0, 2] + g_W[1] * Rj[1, 2] + g_W[2] * Rj[2, 2]
        go = g_W[0] * oj[0] + g_W[1] * oj[1] + g_W[2] * oj[2]
        for k in range(offs[j], offs[j + 1]):
            arc_node(alpha[k], l, ux, uy, 0.0, 0.0, 0.0, R, p, S, Sd)
            slice_twist(R, p, S, V, qd, Vn)
            kin += 0.5 * w[k] * (mj * (Vn[0] * Vn[0] + Vn[1] * Vn[1] + Vn[2] * Vn[2])
                                 + ixx * (Vn[3] * Vn[3] + Vn[4] * Vn[4]) + izz * Vn[5] * Vn[5])
            pot -= mj * w[k] * (go + gx * p[0] + gy * p[1] + gz * p[2])
        pot += law_energy_c(q[qoff + 3 * j : qoff + 3 * j + 3], l0[j], EI[j], EA[j], ar.linear_law[j], ar.K[j],
                            ar.q_rest[j])
        # the tip: the next segment's root twist (its body frame) and frame
        arc_node(1.0, l, ux, uy, 0.0, 0.0, 0.0, R, p, S, Sd)
        slice_twist(R, p, S, V, qd, Vn)
        copy(V, Vn)
        for r in range(3):
            oj[r] += Rj[r, 0] * p[0] + Rj[r, 1] * p[1] + Rj[r, 2] * p[2]
        for r in range(3):
            for cc in range(3):
                Rn[r, cc] = Rj[r, 0] * R[0, cc] + Rj[r, 1] * R[1, cc] + Rj[r, 2] * R[2, cc]
        for r in range(3):
            copy(Rj[r], Rn[r])
    # the tip payload (ChainArrays.payload, its spatial inertia at the tip): 1/2 V^T P V and the
    # gravity of its mass m at its centre oj + Rj c (m c from P's m [c]x block)
    P = ar.payload
    for r in range(6):
        acc = 0.0
        for c in range(6):
            acc += P[r, c] * V[c]
        kin += 0.5 * V[r] * acc
    for r in range(3):
        pot -= g_W[r] * (P[0, 0] * oj[r] + Rj[r, 0] * P[5, 1] + Rj[r, 1] * P[3, 2] + Rj[r, 2] * P[4, 0])
    return kin, pot


@ejit
def energies_batch(m, wk, t, q, v, kinetic, potential):
    """:func:`energies` of ``K`` samples: ``t (K,)``, ``q (K, nq)``, ``v (K, nv)`` into
    ``kinetic``, ``potential`` (K,) (J)."""
    for k in range(t.shape[0]):
        kinetic[k], potential[k] = energies(m, wk, t[k], q[k], v[k])
