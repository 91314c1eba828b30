"""Task-space (tip) controllers: PD on the tip position with compensation, and tip tracking
by passivity-based control on an inverse-kinematics reference.

The tip position is the origin of the tip frame in world coordinates,
``x = chain.tip_placement(q).translation``; its Jacobian on the free coordinates is
``J = chain.tip_jacobian(q, "local_world_aligned")[:3]`` (``dx/dt = J v``).
"""

from __future__ import annotations

from collections.abc import Callable

from ..arm.chain import Chain
from ..checks.convert import as_real
from .base import Controller
from .configuration import SlotineLi
from .references import TipPathReference, TipReference, path_point

__all__ = ["TipPD", "TipTracking"]


class TipPD(Controller):
    """Operational-space PD on the tip position with gravity and elastic compensation.

        tau = g(q) + dU_el/dq(q) + J^T (K_p (x_d - x) + K_d (xd_dot - J v)) - c v

    on the free coordinates: gravity and elasticity are cancelled, the tip is pulled to
    ``x_d`` by a spring ``K_p`` with a damper ``K_d``, and ``c v`` damps the motions the tip
    does not see (the null space of ``J``). For a fixed ``x_d`` the storage function
    ``V = 1/2 v^T M v + 1/2 K_p |x - x_d|^2`` has
    ``dV/dt = -K_d |J v|^2 - c |v|^2 - v^T D v <= 0`` (the skew-symmetry of
    ``dM/dt - 2C``), so the arm comes to rest with ``J^T K_p (x - x_d) = 0``: on the
    target where ``J`` has full row rank. A moving ``x_d`` is followed with a lag (no
    feed-forward of the arm's inertia): :class:`TipTracking` follows one.

    Parameters
    ----------
    chain : Chain
    x_d : (3,) m or callable ``t -> (x_d (3,) m, xd_dot (3,) m/s)``, world frame
    Kp : float > 0, N/m;  Kd : float > 0, N s/m
    c : float >= 0
        Damping of the free coordinates (generalised force per unit rate), default 0.
    rate, p_max, p_min, penalty, tension_max
        :class:`~qchain.control.base.Controller`.

    Signals (besides the base's): ``x_d``, ``x`` (K, 3) m, ``error`` (K, 3) m ``x - x_d``,
    ``storage`` (K,) J, the ``V`` above.
    """

    def __init__(self, chain: Chain, x_d, *, Kp: float, Kd: float, c: float = 0.0, rate: float, p_max: float | None = None,
                 p_min: float = 0.0, penalty: float | None = None, tension_max: float | None = None):
        super().__init__(chain, rate=rate, p_max=p_max, p_min=p_min, penalty=penalty, tension_max=tension_max)
        self.reference = TipReference(x_d)
        self.Kp, self.Kd, self.c = (as_real(n, x) for n, x in (("Kp", Kp), ("Kd", Kd), ("c", c)))
        for name, x in (("Kp", self.Kp), ("Kd", self.Kd)):
            if not x > 0:
                raise ValueError(f"{name} must be a number > 0, got {x:g}")
        if not self.c >= 0:
            raise ValueError(f"c must be a number >= 0, got {self.c:g}")

    def torque(self, t, q, v):
        ch, a = self.chain, self.active
        x_d, xd_dot = self.reference(t)
        J = ch.tip_jacobian(q, "local_world_aligned")[:3]
        x = ch.tip_placement(q).translation
        e = x - x_d
        tau = (ch.generalized_gravity(q) + ch.elastic_force(q) + J.T @ (-self.Kp * e + self.Kd * (xd_dot - J @ v))
               - self.c * v)[a]
        va = v[a]
        V = 0.5 * va @ ch.mass_matrix(q)[self._ix] @ va + 0.5 * self.Kp * e @ e
        return tau, {"x_d": x_d, "x": x, "error": e, "storage": V}


class TipTracking(SlotineLi):
    """Tip tracking: a tip path ``x_d(t)`` mapped to a configuration reference by inverse
    kinematics, followed by :class:`~qchain.control.configuration.SlotineLi`.

    ``q_d(t)`` puts the tip at ``x_d(t)`` with the least-norm change of configuration from
    sample to sample, starting from the posture ``q_home``
    (:class:`~qchain.control.references.TipPathReference`: resolved-rate inverse kinematics
    on a time grid before the run, a cubic spline in time between, whose derivatives give ``qd_dot`` and
    ``qd_ddot``). The tip error then inherits Slotine-Li's convergence, ``x - x_d ~ J e``,
    and the feed-forward ``M a_r`` carries the path's accelerations (which :class:`TipPD`
    lacks). The storage function is Slotine-Li's ``V = 1/2 s^T M s``.

    Parameters
    ----------
    chain : Chain
    path : callable ``t -> (3,)`` m (or ``(x_d, xd_dot)``), world frame
    duration : float, s
        The span ``[t0, t0 + duration]`` the reference is made for.
    q_home : (nq,)
        The posture the inverse kinematics starts from (e.g. a static shape near the path).
    K, Lambda, rate, p_max, p_min, penalty
        :class:`~qchain.control.configuration.SlotineLi`.
    t0 : float, s
    samples_per_second : float, Hz
        Inverse-kinematics solutions a second of the path (default 100).

    Signals: Slotine-Li's, and ``x_d``, ``x`` (K, 3) m the tip's target and position.
    """

    def __init__(self, chain: Chain, path: Callable, duration: float, q_home, *, K, Lambda, rate: float,
                 p_max: float | None = None, p_min: float = 0.0, penalty: float | None = None, t0: float = 0.0,
                 samples_per_second: float = 100.0, tension_max: float | None = None):
        ref = TipPathReference(chain, path, duration, q_home, t0=t0, samples_per_second=samples_per_second)
        super().__init__(chain, ref, K=K, Lambda=Lambda, rate=rate, p_max=p_max, p_min=p_min, penalty=penalty,
                         tension_max=tension_max)
        self.path = path

    def torque(self, t, q, v):
        tau, sig = super().torque(t, q, v)
        sig["x_d"] = path_point(self.path, t)
        sig["x"] = self.chain.tip_placement(q).translation
        return tau, sig
