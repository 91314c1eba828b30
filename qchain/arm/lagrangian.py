"""The paper's Lagrangian form of a chain: coordinates ``q_L = (d, theta, q_e)``.

A :class:`qchain.Chain` integrates the quasi-Lagrangian model, eq. (9) of Olguin-Diaz et al.,
with the base's velocity as the twist ``xi_B = (v, w)`` in the base frame and its attitude as
a unit quaternion. The paper writes the same model a second time in Lagrangian coordinates
(``docs/model.md, "Lagrangian form"``)::

    q_L  = (d, theta, q_e1, ..., q_en)          (nv,)  m, rad, segment coordinates
    xi   = T(theta) qd_L,  T = diag(R^T, lJ_theta, I)                      eq. (3)
    H(q_L) qdd_L + C(q_L, qd_L) qd_L + g(q_L) + D qd_L + dU_el/dq = tau     eq. (7)
    H = T^T M_xi T,  g = T^T g_xi,  tau = T^T tau_xi
    C_xi = T^-T C T^-1 - M_xi Tdot T^-1                                      after eq. (9)

with ``d`` the base origin in the world (m), ``theta`` a minimal attitude of the base and
``R(theta)`` its rotation (base to world). :class:`LagrangianChain` evaluates every term of
eq. (7) for a chain on a floating base (``Chain(..., base="floating")``); on a fixed base
``q_L`` is the chain's own ``q``, ``T`` the identity and the two forms coincide.

Attitude ``"rpy"``: ``theta = (roll, pitch, yaw)`` (rad) as in ``pinocchio.rpy``,
``R = Rz(yaw) Ry(pitch) Rx(roll)``, ``lJ_theta = pinocchio.rpy.computeRpyJacobian(theta,
pinocchio.LOCAL)`` (angular velocity in the base frame ``w = lJ_theta thetadot``). Its
determinant is ``cos(pitch)``: at ``|pitch| = pi/2`` ``T`` is not invertible and ``H`` loses
rank, a singularity of the coordinates, not of the arm. Methods that need ``T^-1`` or a
positive definite ``H`` raise :class:`qchain.SingularConfigurationError` where
``|cos(pitch)| < ATTITUDE_SINGULAR_COS``; the chain's quaternion free-flyer has no such
singularity.

Every derivative is exact: ``dH/dq_L`` from :meth:`qchain.Chain.mass_matrix_derivative` and
the closed-form derivatives of ``R(theta)^T`` and ``lJ_theta`` (no finite differences).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pinocchio as pin

from .chain import Chain
from ..checks.convert import as_vector
from ..errors import QchainError, SingularConfigurationError
from ..model.segment import PAPER_SINGULAR_ANGLE
from ..model.spatial import quaternion_to_rotation, skew

__all__ = ["LagrangianChain", "ATTITUDES", "ATTITUDE_SINGULAR_COS"]

#: Minimal attitude parametrisations of the base: ``"rpy"`` (roll, pitch, yaw), Pinocchio's.
ATTITUDES = ("rpy",)

#: Configurations with ``|cos(pitch)| < ATTITUDE_SINGULAR_COS`` (``|pitch|`` within 1e-6 rad of
#: ``pi/2``) raise :class:`SingularConfigurationError`: ``det lJ_theta = cos(pitch)``, so
#: ``T^-1`` grows like ``1 / |cos(pitch)|`` (beyond 1e6 here) and the condition number of
#: ``H = T^T M_xi T`` like ``1 / cos(pitch)^2`` (beyond 1e12 times its value at ``pitch = 0``).
ATTITUDE_SINGULAR_COS = 1e-6

_LOCAL = pin.ReferenceFrame.LOCAL
_UNIT = np.eye(3)


class _Pose(NamedTuple):
    """One validated Lagrangian configuration and what its base gives."""

    q_L: np.ndarray  # (nv,) Lagrangian coordinates
    q: np.ndarray  # (nq,) the chain's configuration
    theta: np.ndarray | None  # (3,) roll, pitch, yaw (floating base)
    R: np.ndarray | None  # (3, 3) base rotation, base to world
    lJ: np.ndarray | None  # (3, 3) d(omega_local)/d(thetadot)
    T: np.ndarray  # (nv, nv) xi = T qd_L


def _rpy_quaternion(theta: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` of ``R = Rz(yaw) Ry(pitch) Rx(roll)``, closed form."""
    cr, sr = np.cos(0.5 * theta[0]), np.sin(0.5 * theta[0])
    cp, sp = np.cos(0.5 * theta[1]), np.sin(0.5 * theta[1])
    cy, sy = np.cos(0.5 * theta[2]), np.sin(0.5 * theta[2])
    return np.array([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


class LagrangianChain:
    """The Lagrangian form, eq. (7), of a chain on a floating (or fixed) base.

    Parameters
    ----------
    chain : Chain
        ``base="floating"`` (``q_L = (d, theta, q_e...)``, nv = 6 + 3 n) or ``base="fixed"``
        (``q_L = q = (q_e...)``, nv = 3 n, ``T = I``). A prescribed base has no base
        coordinates to write in Lagrangian form and is refused.
    attitude : {"rpy"}
        The minimal attitude ``theta`` of the base: Pinocchio's roll-pitch-yaw,
        ``R = Rz(yaw) Ry(pitch) Rx(roll)``, rad.

    Attributes
    ----------
    chain : Chain
    nq, nv : int
        Sizes of ``q_L`` and ``qd_L``, both ``chain.nv``.
    nu : int
        Pressure inputs (3 n), Pa.

    Notes
    -----
    Layout of ``q_L`` (floating base): ``q_L[0:3] = d`` (m, world), ``q_L[3:6] = theta = (roll,
    pitch, yaw)`` (rad), then each segment's ``q_e`` in its own coordinates; ``qd_L`` holds
    their time derivatives. The chain's state is ``q = (d, quat(R(theta)), q_e)`` and ``v = T
    qd_L = (R^T ddot, lJ_theta thetadot, qd_e)``: linear and angular velocity of the base in
    the base frame (Pinocchio's free-flyer convention, the paper's ``xi``).

    Generalised forces follow the paper: ``tau = (tau_d, tau_theta, tau_p)``. ``tau_d`` (N)
    and ``tau_theta`` (N m per rad) act on the base's pose, ``tau_p`` on the segments. A
    generalised force ``tau_xi`` of the chain -- a wrench ``(f, n)`` (N, N m) on the base in
    the base frame, then segment forces -- is ``tau = T^T tau_xi`` (:meth:`lagrangian_force`);
    as the paper remarks, ``tau_theta`` alone has no physical meaning: it is the torque ``n``
    seen through ``lJ_theta^T``, and depends on the attitude.

    Every ``q_L`` entering a method other than :meth:`velocity_transform` and
    :meth:`to_chain_state` (the forward maps, defined everywhere) is checked against the
    attitude singularity, ``|cos(pitch)| < ATTITUDE_SINGULAR_COS``.
    """

    def __init__(self, chain: Chain, attitude: str = "rpy"):
        if not isinstance(chain, Chain):
            raise TypeError(f"chain must be a qchain.Chain, got {type(chain).__name__}")
        if chain.base not in ("fixed", "floating"):
            raise ValueError(
                f"LagrangianChain needs a chain with base='floating' or 'fixed', got base={chain.base!r} "
                "(a prescribed base has no coordinates of its own)"
            )
        if attitude not in ATTITUDES:
            raise ValueError(f"attitude must be one of {ATTITUDES}, got {attitude!r}")
        self.chain = chain
        self.attitude = attitude
        self.floating = chain.floating
        self.n = chain.n
        self.nq = chain.nv
        self.nv = chain.nv
        self.nu = chain.nu
        self._off = 6 if self.floating else 0
        locked = ~np.asarray(chain.active)
        self._locked = np.flatnonzero(locked)  # indices in q_L and qd_L (same layout as v)
        self._lock_values = chain.neutral()[7 if self.floating else 0 :][locked[self._off :]]

    def __repr__(self) -> str:
        return f"LagrangianChain({self.chain!r}, attitude={self.attitude!r})"

    # ------------------------------------------------------------------ inputs

    def _check_attitude(self, pitch: float, where: str) -> None:
        c = abs(float(np.cos(pitch)))
        if c < ATTITUDE_SINGULAR_COS:
            raise SingularConfigurationError(
                f"{where}: pitch = {pitch:.9g} rad gives |cos(pitch)| = {c:.3e}, below ATTITUDE_SINGULAR_COS = "
                f"{ATTITUDE_SINGULAR_COS:g}: the roll-pitch-yaw attitude is singular at |pitch| = pi/2 "
                "(T(theta) is not invertible there); use the quaternion free-flyer, Chain(base='floating') "
                "with its (q, v), which has no attitude singularity"
            )

    def _check_segments(self, q_e: np.ndarray, name: str, start: int, nonsingular: bool) -> None:
        """Model domain of every segment, errors naming ``name[a:b]``."""
        for j, s in enumerate(self.chain.segments):
            a = start + 3 * j
            where = f"segment {j} ({name}[{a}:{a + 3}])"
            qe = s.check_configuration(q_e[3 * j : 3 * j + 3], name=where)
            if nonsingular and s.coords == "paper" and qe[2] * qe[0] < PAPER_SINGULAR_ANGLE:
                raise SingularConfigurationError(
                    f"{where}: bending angle kappa*l = {qe[2] * qe[0]:.3e} rad is below {PAPER_SINGULAR_ANGLE:g} "
                    "rad, where the paper's (l, psi, kappa) coordinates are singular; use coords='curvature' "
                    "for this segment"
                )

    def _pose(self, q_L, name: str = "q_L", nonsingular: bool = True) -> _Pose:
        """Validate ``q_L`` (shape, finite, model domain, attitude singularity if
        ``nonsingular``) and build the chain configuration and ``T``."""
        q_L = as_vector(name, q_L, self.nq)
        self._check_segments(q_L[self._off :], name, self._off, nonsingular)
        if not self.floating:
            return _Pose(q_L, q_L, None, None, None, np.eye(self.nv))
        theta = q_L[3:6]
        if nonsingular:
            self._check_attitude(theta[1], f"{name}[4]")
        R = pin.rpy.rpyToMatrix(theta)
        lJ = pin.rpy.computeRpyJacobian(theta, _LOCAL)
        q = np.concatenate([q_L[:3], _rpy_quaternion(theta), q_L[6:]])
        T = np.eye(self.nv)
        T[:3, :3] = R.T
        T[3:6, 3:6] = lJ
        return _Pose(q_L, q, theta, R, lJ, T)

    def _qd(self, qd_L, name: str = "qd_L") -> np.ndarray:
        return as_vector(name, qd_L, self.nv)

    def _check_locks(self, q_L: np.ndarray, qd_L: np.ndarray) -> None:
        """Locked coordinates (:attr:`Chain.active`) at their values, with zero velocity."""
        if self._locked.size == 0:
            return
        val = q_L[self._locked]
        bad = np.abs(val - self._lock_values) > 1e-12 * np.maximum(1.0, np.abs(self._lock_values))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"q_L[{self._locked[k]}] is locked at {self._lock_values[k]:.9g}, got {val[k]:.9g}"
            )
        vd = qd_L[self._locked]
        if np.any(vd != 0.0):
            k = int(np.flatnonzero(vd != 0.0)[0])
            raise ValueError(f"qd_L[{self._locked[k]}] is locked and must be 0, got {vd[k]:.9g}")

    # ------------------------------------------------------------------ kinematics

    def velocity_transform(self, q_L) -> np.ndarray:
        """``T(theta)`` (nv, nv) of eq. (3), ``xi = T qd_L``.

        ``T = diag(R^T, lJ_theta, I)``: ``R^T ddot`` is the base's linear velocity (m/s) and
        ``lJ_theta thetadot`` its angular velocity (rad/s), both in the base frame
        (Pinocchio ``[linear; angular]`` LOCAL). The identity for a fixed base. Defined at
        the attitude singularity too (it is singular there).
        """
        return self._pose(q_L, nonsingular=False).T

    def _dT_base(self, pose: _Pose) -> np.ndarray:
        """``dT/dtheta_k`` on the base block (3, 6, 6), closed form:
        ``d(R^T)/dtheta_k = -[lJ e_k]x R^T`` (from ``dR = R [lJ dtheta]x``) and
        ``dlJ/dtheta_k = computeRpyJacobianTimeDerivative(theta, e_k)`` (exact: ``lJdot`` is
        linear in ``thetadot``)."""
        dT = np.zeros((3, 6, 6))
        for k in range(3):
            dT[k, :3, :3] = -skew(pose.lJ[:, k]) @ pose.R.T
            dT[k, 3:, 3:] = pin.rpy.computeRpyJacobianTimeDerivative(pose.theta, _UNIT[k], _LOCAL)
        return dT

    def _Tdot(self, pose: _Pose, qd: np.ndarray) -> np.ndarray:
        Td = np.zeros((self.nv, self.nv))
        if self.floating:
            w = pose.lJ @ qd[3:6]
            Td[:3, :3] = -skew(w) @ pose.R.T
            Td[3:6, 3:6] = pin.rpy.computeRpyJacobianTimeDerivative(pose.theta, qd[3:6], _LOCAL)
        return Td

    def velocity_transform_dot(self, q_L, qd_L) -> np.ndarray:
        """``Tdot = dT/dt`` (nv, nv) along ``qd_L``, closed form: ``d(R^T)/dt = -[w]x R^T``
        with ``w = lJ_theta thetadot`` (rad/s, base frame), ``d(lJ_theta)/dt`` from
        ``pinocchio.rpy.computeRpyJacobianTimeDerivative``. Zero for a fixed base."""
        return self._Tdot(self._pose(q_L, nonsingular=False), self._qd(qd_L))

    def _Tinv(self, pose: _Pose) -> np.ndarray:
        Ti = np.eye(self.nv)
        if self.floating:
            Ti[:3, :3] = pose.R
            Ti[3:6, 3:6] = pin.rpy.computeRpyJacobianInverse(pose.theta, _LOCAL)
        return Ti

    def to_chain_state(self, q_L, qd_L) -> tuple[np.ndarray, np.ndarray]:
        """The chain's ``(q (nq,), v (nv,))`` of a Lagrangian state.

        ``q = (d, quaternion (x, y, z, w) of R(theta), q_e)`` and ``v = T qd_L`` (eq. (3)).
        Defined everywhere, the attitude singularity included. For a fixed base ``q = q_L``,
        ``v = qd_L``.
        """
        pose = self._pose(q_L, nonsingular=False)
        return pose.q.copy(), pose.T @ self._qd(qd_L)

    def from_chain_state(self, q, v) -> tuple[np.ndarray, np.ndarray]:
        """The Lagrangian ``(q_L (nv,), qd_L (nv,))`` of a chain state ``(q (nq,), v (nv,))``.

        ``theta = pinocchio.rpy.matrixToRpy(R)`` (roll and yaw in [-pi, pi], pitch in
        [-pi/2, pi/2]), ``ddot = R v_B`` (m/s, world), ``thetadot = lJ_theta^-1 w_B``.

        Raises
        ------
        SingularConfigurationError
            where ``|cos(pitch)| < ATTITUDE_SINGULAR_COS`` (``thetadot`` is undefined there).
        """
        ch = self.chain
        q = ch._q(q)
        as_vector("q", q, ch.nq)
        v = as_vector("v", v, ch.nv)
        qoff = 7 if self.floating else 0
        self._check_segments(q[qoff:], "q", qoff, nonsingular=False)
        if not self.floating:
            return q.copy(), v.copy()
        R = quaternion_to_rotation(q[3:7])
        theta = pin.rpy.matrixToRpy(R)
        self._check_attitude(theta[1], "q[3:7]")
        q_L = np.concatenate([q[:3], theta, q[7:]])
        qd_L = v.copy()
        qd_L[:3] = R @ v[:3]
        qd_L[3:6] = pin.rpy.computeRpyJacobianInverse(theta, _LOCAL) @ v[3:6]
        return q_L, qd_L

    # ------------------------------------------------------------------ inertia

    def _inertia(self, pose: _Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M_xi, H, dH)`` at ``pose``; ``dH[:, :, k] = dH/dq_L[k]``."""
        ch = self.chain
        M = ch.mass_matrix(pose.q)
        T = pose.T
        # dM/dq_L[k] = sum_l dM/dq[l] T[l, k]: the chain differentiates along its tangent space
        # (integrate), whose first-order displacement along dq_L is T dq_L
        dM = ch.mass_matrix_derivative(pose.q) @ T
        dH = np.moveaxis(T.T @ np.moveaxis(dM, 2, 0) @ T, 0, 2)
        if self.floating:
            TMT = T.T @ M  # (T^T M) dT_k + dT_k^T (M T)
            for k, dTk in enumerate(self._dT_base(pose)):
                A = TMT[:, :6] @ dTk
                dH[:, :6, 3 + k] += A
                dH[:6, :, 3 + k] += A.T
        return M, T.T @ M @ T, dH

    def mass_matrix(self, q_L) -> np.ndarray:
        """``H(q_L) = T^T M_xi T`` (nv, nv), the inertia of eq. (7) (kg, kg m, kg m^2 blocks
        per unit of ``d``, ``theta`` and the segments' coordinates); ``1/2 qd_L^T H qd_L``
        is the kinetic energy, eq. (4)."""
        pose = self._pose(q_L)
        T = pose.T
        return T.T @ self.chain.mass_matrix(pose.q) @ T

    def mass_matrix_derivative(self, q_L) -> np.ndarray:
        """``dH[:, :, k] = dH/dq_L[k]`` (nv, nv, nv), exact.

        ``dH_k = dT_k^T M T + T^T M dT_k + T^T (dM/dq_L[k]) T``, with ``dM/dq_L[k] = sum_l
        dM/dq[l] T[l, k]`` from :meth:`Chain.mass_matrix_derivative` (taken along the chain's
        tangent space, to which ``dq_L`` maps through ``T``) and closed-form ``dT_k``.
        """
        return self._inertia(self._pose(q_L))[2]

    @staticmethod
    def _christoffel(dH: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``C_ij = sum_k c_ijk qd_k``, ``c_ijk = 1/2 (dH_ij/dq_k + dH_ik/dq_j - dH_jk/dq_i)``."""
        return 0.5 * (dH @ qd + np.einsum("ikj,k->ij", dH, qd) - np.einsum("jki,k->ij", dH, qd))

    @staticmethod
    def _christoffel_product(dH: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``C(q, qd) qd = Hdot qd - 1/2 d(qd^T H qd)/dq`` without forming ``C``."""
        return (dH @ qd) @ qd - 0.5 * np.einsum("jki,j,k->i", dH, qd, qd)

    def coriolis_matrix(self, q_L, qd_L) -> np.ndarray:
        """``C(q_L, qd_L)`` (nv, nv) of eq. (7) from the Christoffel symbols of the first kind of
        ``H``, so ``dH/dt - 2 C`` is skew-symmetric.

        ``C_ij = 1/2 sum_k (dH_ij/dq_k + dH_ik/dq_j - dH_jk/dq_i) qd_k`` with the exact
        :meth:`mass_matrix_derivative`. ``C qd_L = T^T (M_xi Tdot qd_L + C_xi xi)``.
        """
        pose = self._pose(q_L)
        return self._christoffel(self._inertia(pose)[2], self._qd(qd_L))

    def quasi_coriolis_matrix(self, q_L, qd_L) -> np.ndarray:
        """The paper's ``C_xi = T^-T C T^-1 - M_xi Tdot T^-1`` (nv, nv), after eq. (9).

        It acts on ``xi = T qd_L`` (the chain's ``v``): ``C_xi xi`` is the chain's
        velocity-product force (``nonlinear_effects - generalized_gravity``) and
        ``C_xi + C_xi^T = dM_xi/dt``. It is one Coriolis matrix of eq. (9), not in general
        :meth:`Chain.coriolis_matrix` (a Coriolis matrix is not unique).
        """
        pose = self._pose(q_L)
        qd = self._qd(qd_L)
        M, _, dH = self._inertia(pose)
        Ti = self._Tinv(pose)
        return Ti.T @ self._christoffel(dH, qd) @ Ti - M @ self._Tdot(pose, qd) @ Ti

    # ------------------------------------------------------------------ forces

    def generalized_gravity(self, q_L) -> np.ndarray:
        """``g(q_L) = dU_g/dq_L = T^T g_xi`` (nv,) of eq. (7), ``g_xi`` the chain's
        :meth:`Chain.generalized_gravity` (N on ``d``, N m per rad on ``theta``)."""
        pose = self._pose(q_L)
        return pose.T.T @ self.chain.generalized_gravity(pose.q)

    def internal_forces(self, q_L, qd_L, p=None) -> np.ndarray:
        """``B p - D qd_L - dU_el/dq`` (nv,): the segments' own forces of eq. (7), zero on the
        base (pressure is internal: no net force on ``(d, theta)``). ``p`` (3 n,) Pa, segment
        by segment, chambers 1..3, default zero."""
        pose = self._pose(q_L)
        # T = I on the segment block and the chain's internal forces vanish on the base
        return self.chain.internal_forces(pose.q, pose.T @ self._qd(qd_L), p)

    def lagrangian_force(self, q_L, tau_xi) -> np.ndarray:
        """``tau = T^T tau_xi`` (nv,): a generalised force of the chain in Lagrangian form.

        ``tau_xi`` (nv,): for a floating base ``tau_xi[:3]`` a force (N) and ``tau_xi[3:6]`` a
        torque (N m) applied at the base origin, in the base frame, then segment forces. The
        result is ``(tau_d, tau_theta, tau_p)`` of eq. (7): ``tau_d = R f`` (N, world),
        ``tau_theta = lJ_theta^T n`` (no physical meaning on its own, as the paper remarks: it
        depends on the attitude parametrisation), ``tau_p`` unchanged. Power is preserved,
        ``qd_L . tau = xi . tau_xi``.
        """
        pose = self._pose(q_L, nonsingular=False)
        return pose.T.T @ as_vector("tau_xi", tau_xi, self.nv)

    # ------------------------------------------------------------------ dynamics

    def forward_dynamics(self, q_L, qd_L, p=None, tau=None) -> np.ndarray:
        """``qdd_L`` (nv,) of eq. (7), ``H qdd + C qd + g + D qd + dU_el/dq = B p + tau``.

        Parameters
        ----------
        q_L, qd_L : (nv,)
            Lagrangian state (m, rad, segment coordinates; their rates).
        p : (3 n,) Pa, optional
            Chamber pressures, default zero.
        tau : (nv,), optional
            External generalised force ``(tau_d, tau_theta, tau_p)`` in Lagrangian
            coordinates: ``tau_d`` (N, world axes) on ``d``, ``tau_theta`` on ``theta`` --
            which has no physical meaning on its own, as the paper remarks -- and
            ``tau_p`` on the segments. A wrench on the base in the base frame, or any chain
            generalised force ``tau_xi``, enters as ``tau = T^T tau_xi``
            (:meth:`lagrangian_force`).

        Returns
        -------
        (nv,)
            ``qdd_L``; zero on locked coordinates (:attr:`Chain.active`), held by ideal
            constraints as in :meth:`Chain.forward_dynamics`.

        Notes
        -----
        Solves eq. (7) itself: ``H`` and the Christoffel ``C qd`` from the exact ``dH/dq_L``,
        ``g = T^T g_xi``, O(nv^3). Its motion equals the chain's, mapped through
        ``xidot = T qdd_L + Tdot qd_L``, away from the attitude singularity.
        """
        pose = self._pose(q_L)
        qd = self._qd(qd_L)
        if tau is not None:
            tau = as_vector("tau", tau, self.nv)
        if p is not None:
            p = as_vector("p", p, self.nu)
        self._check_locks(pose.q_L, qd)
        ch = self.chain
        _, H, dH = self._inertia(pose)
        T = pose.T
        rhs = ch.internal_forces(pose.q, T @ qd, p) - T.T @ ch.generalized_gravity(pose.q)
        rhs -= self._christoffel_product(dH, qd)
        if tau is not None:
            rhs += tau
        qdd = np.zeros(self.nv)
        act = np.asarray(ch.active)
        qdd[act] = np.linalg.solve(H[np.ix_(act, act)], rhs[act])
        if not np.all(np.isfinite(qdd)):
            raise QchainError("LagrangianChain.forward_dynamics produced non-finite accelerations")
        return qdd
