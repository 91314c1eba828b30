"""Configuration-space controllers: PD with gravity and elastic compensation, and
Slotine-Li passivity-based tracking.

Both act on the free coordinates of a fixed-base chain (``chain.active``; for the locked
ones ``v = 0`` and the reduced dynamics is the principal block of the full one), whose
dynamics are the paper's eq. (9) assembled over the chain (docs/model.md section 6):

    M(q) a + C(q, v) v + g(q) + D(q) v + dU_el/dq = B(q) p

with ``M`` positive definite, ``dM/dt - 2 C`` skew-symmetric (``C`` assembled from the
segments' ``C_xi``: :meth:`qchain.Chain.coriolis_matrix`) and the input ``B(q) p`` affine in
the pressures. The wanted force ``tau`` is realised by bounded least squares
(:mod:`qchain.control.allocation`); where the bounds bind, the properties below hold only
for the force realised.
"""

from __future__ import annotations

import numpy as np

from ..arm.chain import Chain
from .base import Controller, gain
from .references import ConfigurationReference

__all__ = ["PDCompensation", "SlotineLi"]


class PDCompensation(Controller):
    """PD in configuration space with gravity and elastic compensation.

        tau = g(q) + dU_el/dq(q) + K_p (q_d - q) + K_d (qd_dot - v)

    For a fixed ``q_d`` the storage function ``V = 1/2 v^T M v + 1/2 e^T K_p e``
    (``e = q - q_d``) has ``dV/dt = -v^T (K_d + D) v <= 0`` (the skew-symmetry of
    ``dM/dt - 2 C`` cancels the Coriolis term), and LaSalle's principle brings the arm to
    rest at ``q_d`` (where ``v = 0`` the only invariant set is ``e = 0``): no steady-state
    error, since gravity and elasticity are cancelled at the current ``q``.

    Parameters
    ----------
    chain : Chain
    q_d : (nq,) or callable ``t -> (q_d (nq,), qd_dot (nv,), qd_ddot (nv,))``
        The reference (the locked coordinates' entries are not used).
    Kp, Kd : float or (k,) > 0
        Stiffness and damping gains on the ``k`` free coordinates (generalised force per unit
        of the coordinate, and per unit rate).
    rate, p_max, p_min, penalty, tension_max
        :class:`~qchain.control.base.Controller`.

    Signals (besides the base's): ``q_d`` (K, nq), ``error`` (K, k) ``q - q_d`` on the free
    coordinates, ``storage`` (K,) J, the ``V`` above.
    """

    def __init__(self, chain: Chain, q_d, *, Kp, Kd, rate: float, p_max: float | None = None, p_min: float = 0.0,
                 penalty: float | None = None, tension_max: float | None = None):
        super().__init__(chain, rate=rate, p_max=p_max, p_min=p_min, penalty=penalty, tension_max=tension_max)
        self.reference = ConfigurationReference(chain, q_d)
        k = self.active.size
        self.Kp, self.Kd = gain("Kp", Kp, k), gain("Kd", Kd, k)

    def torque(self, t, q, v):
        ch, a = self.chain, self.active
        q_d, qd_dot, _ = self.reference(t)
        e = (q - q_d)[a]
        tau = (ch.generalized_gravity(q) + ch.elastic_force(q))[a] - self.Kp * e + self.Kd * (qd_dot - v)[a]
        va = v[a]
        V = 0.5 * va @ ch.mass_matrix(q)[self._ix] @ va + 0.5 * e @ (self.Kp * e)
        return tau, {"q_d": q_d, "error": e, "storage": V}


class SlotineLi(Controller):
    """Slotine-Li passivity-based tracking in configuration space.

        e = q - q_d,   v_r = qd_dot - Lambda e,   a_r = qd_ddot - Lambda (v - qd_dot),
        s = v - v_r,
        tau = M(q) a_r + C(q, v) v_r + g(q) + dU_el/dq(q) + D(q) v_r - K s

    (Slotine and Li 1987, on the paper's ``M_xi``, ``C_xi`` assembled over the chain). In
    closed loop ``M ds/dt + (C + D + K) s = 0``, so the storage function
    ``V = 1/2 s^T M s`` has

        dV/dt = s^T M ds/dt + 1/2 s^T (dM/dt) s = -s^T (K + D) s + 1/2 s^T (dM/dt - 2 C) s
              = -s^T (K + D) s <= 0

    (the paper's skew-symmetry of ``dM/dt - 2C``): ``s -> 0`` exponentially
    (``K + D >= K``, ``M`` bounded), and ``e`` follows ``de/dt = -Lambda e + s``, a stable
    filter, so ``e -> 0``. Compensating the material damping along the reference
    (``D v_r``, not ``D v``) keeps it as dissipation of ``s``. With the pressures sampled
    and held, ``dV/dt`` gains ``s^T (B p_held - tau(t))``: of the order of the sampling
    period times the change of ``tau`` over it.

    Parameters
    ----------
    chain : Chain
    q_d : (nq,) or callable ``t -> (q_d (nq,), qd_dot (nv,), qd_ddot (nv,))``
    K : float or (k,) > 0
        Damping gain on ``s`` (generalised force per unit rate).
    Lambda : float or (k,) > 0, 1/s
        Bandwidth of the error filter ``de/dt = -Lambda e``.
    rate, p_max, p_min, penalty, tension_max
        :class:`~qchain.control.base.Controller`.

    Signals (besides the base's): ``q_d`` (K, nq), ``error`` (K, k) ``q - q_d`` on the free
    coordinates, ``s`` (K, k), ``storage`` (K,) J, ``V = 1/2 s^T M s``.
    """

    def __init__(self, chain: Chain, q_d, *, K, Lambda, rate: float, p_max: float | None = None, p_min: float = 0.0,
                 penalty: float | None = None, tension_max: float | None = None):
        super().__init__(chain, rate=rate, p_max=p_max, p_min=p_min, penalty=penalty, tension_max=tension_max)
        self.reference = ConfigurationReference(chain, q_d) if not isinstance(q_d, ConfigurationReference) else q_d
        k = self.active.size
        self.K, self.Lambda = gain("K", K, k), gain("Lambda", Lambda, k)

    def torque(self, t, q, v):
        ch, a, ix = self.chain, self.active, self._ix
        q_d, qd_dot, qd_ddot = self.reference(t)
        e = (q - q_d)[a]
        va = v[a]
        v_r = qd_dot[a] - self.Lambda * e
        a_r = qd_ddot[a] - self.Lambda * (va - qd_dot[a])
        s = va - v_r
        M = ch.mass_matrix(q)[ix]
        C = ch.coriolis_matrix(q, v)[ix]
        D = ch.dissipation_matrix(q)[ix]
        tau = M @ a_r + (C + D) @ v_r + (ch.generalized_gravity(q) + ch.elastic_force(q))[a] - self.K * s
        return tau, {"q_d": q_d, "error": e, "s": s, "storage": 0.5 * s @ M @ s}
