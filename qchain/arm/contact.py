"""Contact and point loads on a :class:`qchain.arm.chain.Chain` (:class:`ChainContact`, a base
class of ``Chain``): the generalised force an :class:`qchain.contact.Environment` exerts at a
state, and which contacts are active (:mod:`qchain.contact.forces` computes both); the drag of
the still medium the arm moves in (the segments' ``drag_linear``, ``drag_quadratic``;
:mod:`qchain.contact.drag`)."""

from __future__ import annotations

import numpy as np

from ..contact.derivatives import NODE_T, environment_derivatives
from ..contact.drag import DRAG_FRAME, drag_derivatives, drag_forces
from ..contact.environment import Contacts, Environment
from ..contact.distance import move
from ..contact.forces import RECORD, ROOT, contact_forces, load_forces
from ..model.arc import SCRATCH

__all__ = ["ChainContact"]


def _moved(pk, t: float):
    """The packed obstacles at time ``t``: ``(prm (m, PARAMS), vel (m, 3))``."""
    prm, vel = np.empty_like(pk.prm), np.empty((pk.kind.size, 3))
    move(pk.kind, pk.prm, pk.motion, float(t), prm, vel)
    return prm, vel


def _self_contact_work(n: int, pk):
    """The self-contact passes' work arrays ``(roots (n, ROOT + 12), P (2, K, NODE_T))``, for the
    forces and their tangents (empty without self-contact)."""
    if pk.law[7]:
        return np.zeros((n, ROOT + 12)), np.zeros((2, pk.calpha.size, NODE_T))
    return np.zeros((0, ROOT + 12)), np.zeros((2, 0, NODE_T))


def _plus_drag(out, dq, dv):
    """Forward-dynamics derivatives ``out`` plus the drag's: ``da/dx += M^-1 d tau_drag/dx``."""
    return out._replace(da_dq=out.da_dq + out.da_dtau @ dq, da_dv=out.da_dv + out.da_dtau @ dv)


def _check_env(env) -> Environment:
    if not isinstance(env, Environment):
        raise TypeError(f"env must be a qchain.contact.Environment, got {type(env).__name__}")
    return env


class ChainContact:
    """The :class:`~qchain.contact.Environment` and drag methods of :class:`~qchain.arm.chain.Chain`."""

    def drag_force(self, q, v, t: float = 0.0) -> np.ndarray:
        """The generalised force (nv,) of the medium's drag on the backbone at ``(q, v)``
        (the segments' ``drag_linear``, ``drag_quadratic``; zero without them):
        ``-sum_j int_0^l_j J(s)^T (c_1 + c_2 |v(s)|) v(s) ds``, ``v(s)`` each backbone point's
        velocity (a moving base's included); a floating base's part is the wrench on the base
        (base frame). It enters :meth:`forward_dynamics` and the engine beside ``tau``
        (docs/model.md section 9)."""
        st = self._state(q, v, t=t)
        return self._drag_terms(st.q_c, st.v_c, st.V0, False)[0]

    def drag_force_derivatives(self, q, v, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Exact ``(d tau_drag/dq, d tau_drag/dv)`` (nv, nv) of :meth:`drag_force` (q along
        :meth:`integrate`), by tangent passes (:mod:`qchain.contact.drag`)."""
        st = self._state(q, v, t=t)
        return self._drag_terms(st.q_c, st.v_c, st.V0, True)[1:]

    def _with_drag(self, tau, q_c, v_c, V0, derivatives: bool = False):
        """``tau + tau_drag`` (``tau`` None: zero) at ``(q_c, v_c)`` (n, 3) curvature coordinates
        and the base twist ``V0``, and with ``derivatives`` the drag's ``(d/dq, d/dv)`` too."""
        td, dq, dv = self._drag_terms(q_c, v_c, V0, derivatives)
        tau = td if tau is None else tau + td
        return (tau, dq, dv) if derivatives else tau

    def _drag_unchecked(self, q, v, t, tau, derivatives: bool = False):
        """:meth:`_with_drag` on the ``skip_checks`` paths (a chain with drag is in curvature
        coordinates)."""
        V0 = v[:6] if self.floating else self.base_state(t)[1] if self.base == "prescribed" else np.zeros(6)
        return self._with_drag(tau, q[self._qoff :].reshape(self.n, 3), v[self._voff :].reshape(self.n, 3), V0,
                               derivatives)

    def _drag_terms(self, q_c, v_c, V0, derivatives: bool):
        """``(tau (nv,), d tau/dq, d tau/dv)`` of the drag (the derivatives None unless asked for)."""
        n, nv = self.n, self.nv
        q_c, v_c, V0 = np.ascontiguousarray(q_c), np.ascontiguousarray(v_c), np.ascontiguousarray(V0)
        tau_c, F0 = np.zeros((n, 3)), np.zeros(6)
        dq = dv = None
        if self._has_drag:
            drag_forces(self._arrays, q_c, v_c, V0, tau_c, F0, np.zeros((n + 1, 6)), np.empty(SCRATCH))
        tau = np.concatenate([F0, tau_c.ravel()]) if self.floating else tau_c.ravel()
        if derivatives:
            dq, dv = np.zeros((nv, nv)), np.zeros((nv, nv))
            if self._has_drag:
                drag_derivatives(self._arrays, self.floating, q_c, v_c, V0, dq, dv, np.zeros((n + 1, 6)),
                                 np.zeros((n + 1, 6)), np.zeros((3, n, 3)), np.zeros((3, 6)),
                                 np.zeros((self._alpha.size + n, DRAG_FRAME)), np.empty(SCRATCH))
        return tau, dq, dv

    def _environment_force(self, st, env: Environment, cap: int = 0, t: float = 0.0):
        """``(tau (nv,), records (c, RECORD))``: the environment's generalised force at the
        validated state ``st`` (with velocity) and its first ``cap`` contact records."""
        env.check_segments(self.n)
        pk = env.packed()
        tau_c = np.zeros((self.n, 3))
        F0 = np.zeros(6)
        W = np.zeros((self.n + 1, 6))
        sc = np.empty(SCRATCH)
        R_WB = np.ascontiguousarray(st.X_WB.rotation)
        p_WB = np.ascontiguousarray(st.X_WB.translation)
        rec = np.zeros((cap, RECORD))
        count = 0
        if pk.kind.size or pk.law[7]:
            v_c = np.ascontiguousarray(st.v_c)
            prm, vel = _moved(pk, t)
            roots, P = _self_contact_work(self.n, pk)
            count = contact_forces(self._arrays, pk.kind, prm, vel, pk.law, pk.calpha, st.q_c, v_c, R_WB, p_WB,
                                   np.ascontiguousarray(st.V0), tau_c, F0, W, roots, P, rec, sc)
        if pk.seg.size:
            load_forces(pk.seg, pk.alpha, pk.wrench, pk.local, st.q_c, R_WB, p_WB, tau_c, F0, W, sc)
        tau = self._force_e(st, tau_c).ravel()
        if self.floating:
            tau = np.concatenate([F0, tau])
        return tau, rec[: min(count, cap)], count

    def environment_force(self, q, v, env: Environment, t: float = 0.0) -> np.ndarray:
        """The generalised force (nv,) of the environment ``env`` on the arm at ``(q, v)``: its
        contact forces and point loads, ``sum J_i^T F_i`` over the points they act at (the
        chain's coordinates; a floating base's part is the wrench on the base, base frame)."""
        env = _check_env(env)
        return self._environment_force(self._state(q, v, t=t), env, 0, t)[0]

    def environment_force_derivatives(self, q, v, env: Environment, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Exact ``(d tau_env/dq, d tau_env/dv)`` (nv, nv) of :meth:`environment_force` (q along
        :meth:`integrate`), by tangent passes through the contact and load passes
        (:mod:`qchain.contact.derivatives`). At a contact's onset and where its damping term
        reaches zero the law has a kink: the result is the derivative of the branch the state
        is on. Chains in curvature coordinates (the paper's ``(l, psi, kappa)`` are refused)."""
        return self.environment_terms(q, v, env, t)[1:]

    def environment_terms(self, q, v, env: Environment, t: float = 0.0):
        """``(tau, d tau/dq, d tau/dv)``: :meth:`environment_force` and
        :meth:`environment_force_derivatives` from one validated state."""
        env = _check_env(env)
        if self._any_paper:
            raise ValueError("environment_force_derivatives needs every segment in curvature coordinates "
                             "(coords='curvature'); the paper's (l, psi, kappa) are not supported here")
        st = self._state(q, v, t=t)
        tau = self._environment_force(st, env, 0, t)[0]
        return (tau, *self._environment_derivatives(st, env.packed(), t))

    def _environment_derivatives(self, st, pk, t: float) -> tuple[np.ndarray, np.ndarray]:
        nv, n = self.nv, self.n
        dq, dv = np.zeros((nv, nv)), np.zeros((nv, nv))
        if pk.kind.size or pk.seg.size or pk.law[7]:
            prm, vel = _moved(pk, t)
            environment_derivatives(self._arrays, pk.kind, prm, vel, pk.law, pk.calpha, pk.seg, pk.alpha, pk.wrench,
                                    pk.local, self.floating, st.q_c, np.ascontiguousarray(st.v_c),
                                    np.ascontiguousarray(st.X_WB.rotation), np.ascontiguousarray(st.X_WB.translation),
                                    np.ascontiguousarray(st.V0), dq, dv, np.zeros((n + 1, 6)), np.zeros((n + 1, 6)),
                                    np.zeros((3, n, 3)), np.zeros((3, 6)), *_self_contact_work(n, pk), np.empty(SCRATCH))
        return dq, dv

    def contacts(self, q, v, env: Environment, t: float = 0.0) -> Contacts:
        """The active contacts of the arm with ``env``'s obstacles at ``(q, v)``: where, how
        deep, which obstacle, the force on the arm (:class:`qchain.contact.Contacts`), and
        their generalised force with the loads'."""
        env = _check_env(env)
        st = self._state(q, v, t=t)
        cap = self.n * env.nodes * max(1, len(env.obstacles)) + (self.n * env.nodes) ** 2 * env.self_contact
        tau, rec, _ = self._environment_force(st, env, cap, t)
        return Contacts.from_records(rec, tau)
