"""References a controller follows: a configuration ``q_d(t)`` with its rates, a tip
position ``x_d(t)`` with its rate, and a tip path turned into a configuration reference by
inverse kinematics.

Every reference is a callable of time; its output is checked at every call (shape, finite),
so a NaN in a user's reference is refused where it enters, naming the reference.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.interpolate import CubicSpline

from ..arm.chain import Chain
from ..checks.bounds import DURATION, SAMPLE_RATE
from ..checks.convert import as_real, as_vector, describe_value
from ..errors import DomainError

__all__ = ["ConfigurationReference", "TipReference", "TipPathReference", "tip_inverse_kinematics", "path_point"]


def path_point(path: Callable, t: float) -> np.ndarray:
    """A tip path's point (3,) m at ``t``, world frame: ``path(t)`` is the point or
    ``(x, xdot)`` (the first is used); checked (shape, finite), naming ``path(t=...)``."""
    out = path(t)
    return as_vector(f"path(t={t:g})", out[0] if isinstance(out, tuple) else out, 3)


class ConfigurationReference:
    """``t -> (q_d (nq,), qd_dot (nv,), qd_ddot (nv,))``: a fixed configuration (an array,
    zero rates) or a user's callable returning the three arrays, checked at every call."""

    def __init__(self, chain: Chain, reference, name: str = "q_d"):
        self.nq, self.nv, self.name = chain.nq, chain.nv, name
        if callable(reference):
            self._f = reference
            self.fixed = None
        else:
            self.fixed = as_vector(name, reference, chain.nq)
            self._zero = np.zeros(chain.nv)

    def __call__(self, t: float):
        if self.fixed is not None:
            return self.fixed, self._zero, self._zero
        out = self._f(t)
        if not isinstance(out, tuple) or len(out) != 3:
            raise TypeError(f"{self.name}(t) must return (q_d (nq,), qd_dot (nv,), qd_ddot (nv,)), got "
                            f"{describe_value(out)}")
        return (as_vector(f"{self.name}(t={t:g})", out[0], self.nq),
                as_vector(f"{self.name}_dot(t={t:g})", out[1], self.nv),
                as_vector(f"{self.name}_ddot(t={t:g})", out[2], self.nv))


class TipReference:
    """``t -> (x_d (3,) m, xd_dot (3,) m/s)``, world frame: a fixed point (an array, zero
    rate) or a user's callable returning the two arrays, checked at every call."""

    def __init__(self, reference, name: str = "x_d"):
        self.name = name
        if callable(reference):
            self._f = reference
            self.fixed = None
        else:
            self.fixed = as_vector(name, reference, 3)
            self._zero = np.zeros(3)

    def __call__(self, t: float):
        if self.fixed is not None:
            return self.fixed, self._zero
        out = self._f(t)
        if not isinstance(out, tuple) or len(out) != 2:
            raise TypeError(f"{self.name}(t) must return (x_d (3,), xd_dot (3,)), got {describe_value(out)}")
        return as_vector(f"{self.name}(t={t:g})", out[0], 3), as_vector(f"{self.name}_dot(t={t:g})", out[1], 3)


def tip_inverse_kinematics(chain: Chain, x: np.ndarray, q_start: np.ndarray, tol: float = 1e-12,
                           max_iter: int = 50) -> np.ndarray:
    """A configuration (nq,) near ``q_start`` whose tip origin is at ``x`` (3,) m, world frame.

    Newton steps of least norm from ``q_start``: ``dq = J^+ (x - tip(q))`` (``J`` the tip
    position's Jacobian on the free coordinates, world axes; ``J^+`` its pseudo-inverse), so
    the configuration changes as little as it must (resolved-rate inverse kinematics: for
    a nearby ``x`` the step is ``J^+ dx``). A step that would leave the model's domain
    (``|kappa| r_s >= 1``, ``l <= 0``) or move the tip away from ``x`` is halved until it
    does neither (at most :data:`_HALVINGS` times), so a far target is approached without
    jumping out of the model. Converged when the tip is within ``tol`` (m) of ``x``; raises
    ``ValueError`` naming ``x`` otherwise (out of reach, ``J`` loses rank, or the iteration
    stops at a configuration nearest ``x`` locally: the problem is not convex, and a far
    target may need another ``q_start``).
    """
    x = as_vector("x", x, 3)
    idx = np.flatnonzero(chain.active)
    q = as_vector("q_start", q_start, chain.nq).copy()
    err = np.linalg.norm(x - chain.tip_placement(q).translation)
    for _ in range(max_iter):
        if err < tol:
            return q
        J = chain.tip_jacobian(q, "local_world_aligned")[:3, idx]
        dq = np.linalg.lstsq(J, x - chain.tip_placement(q).translation, rcond=None)[0]
        for k in range(_HALVINGS + 1):
            trial = q.copy()
            trial[idx] += dq / 2.0**k
            try:
                e_trial = np.linalg.norm(x - chain.tip_placement(trial).translation)
            except DomainError:  # (the step leaves the model: a shorter one)
                continue
            if e_trial < err:
                q, err = trial, e_trial
                break
        else:
            raise ValueError(f"x = {np.array2string(x, precision=4)} m: no configuration reaches it from q_start "
                             f"(no step of inverse kinematics brings the tip nearer than {err:.3g} m: out of reach, or "
                             f"the tip Jacobian loses rank, or a nearest configuration from this q_start that is not the target: "
                             f"start from another)")
    if err < tol:
        return q
    raise ValueError(f"x = {np.array2string(x, precision=4)} m: no configuration reaches it from q_start "
                     f"(inverse kinematics did not converge in {max_iter} steps: tip {err:.3g} m away)")


#: How many times :func:`tip_inverse_kinematics` halves a step before it gives up.
_HALVINGS = 30


class TipPathReference:
    """A tip path ``x_d(t)`` over ``[t0, t0 + duration]`` as a configuration reference
    ``t -> (q_d, qd_dot, qd_ddot)``.

    ``q_d`` is :func:`tip_inverse_kinematics` of ``x_d`` at ``samples_per_second`` times a
    second, each solve from the previous one (the first from the posture ``q_home``): the
    least-norm change of configuration that keeps the tip on the path, interpolated by a cubic spline in time
    (``scipy.interpolate.CubicSpline``, not-a-knot ends); ``qd_dot`` and ``qd_ddot`` are the
    spline's own derivatives, so the three are consistent. Outside the span it raises
    ``ValueError`` naming ``t``.

    Parameters
    ----------
    chain : Chain
    path : callable ``t -> (3,)`` m, world frame (or ``(x, xdot)``: the first is used)
    duration : float, s
    q_home : (nq,) the posture the first solve starts from (e.g. a static shape near the path)
    t0 : float, s
    samples_per_second : float, Hz
        Inverse-kinematics solutions a second (default 100; a path must be smooth on that scale).
    """

    def __init__(self, chain: Chain, path: Callable, duration: float, q_home, t0: float = 0.0,
                 samples_per_second: float = 100.0):
        if not callable(path):
            raise TypeError(f"path must be a callable t -> (3,), got {describe_value(path)}")
        duration = DURATION.check("duration", duration)
        self.t0 = as_real("t0", t0)
        self.t1 = self.t0 + duration
        rate = SAMPLE_RATE.check("samples_per_second", samples_per_second)
        q_home = as_vector("q_home", q_home, chain.nq)
        K = max(4, int(np.ceil(duration * rate)) + 1)
        ts = np.linspace(self.t0, self.t1, K)
        Q = np.empty((K, chain.nq))
        for k, t in enumerate(ts):
            Q[k] = tip_inverse_kinematics(chain, path_point(path, t), Q[k - 1] if k else q_home)
        self.times, self.configurations = ts, Q
        self._spline = CubicSpline(ts, Q, axis=0)
        self._d1, self._d2 = self._spline.derivative(1), self._spline.derivative(2)

    def __call__(self, t: float):
        if not self.t0 - 1e-9 <= t <= self.t1 + 1e-9:
            raise ValueError(f"t must be within the reference's span [{self.t0:g}, {self.t1:g}] s, got {t:g} s")
        return self._spline(t), self._d1(t), self._d2(t)
