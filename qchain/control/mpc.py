"""Model-predictive control of the tip: box-constrained iterative LQR (box-DDP, Tassa, Mansard
and Todorov 2014) over a horizon of control intervals, on the exact derivatives of the model.

At every sample ``t`` the controller plans the pressures of the next ``H`` control intervals
(``h = 1 / rate`` each, held over the interval as :meth:`Controller.run` holds them) that
minimise

    J(P) = sum_{k=1}^{H-1} 1/2 Q |x(q_k) - x_d(t + k h)|^2 + 1/2 Q_f |x(q_H) - x_d(t + H h)|^2
           + sum_{k=0}^{H-1} 1/2 R |p_k|^2,           p_min <= p_k <= p_max,

``x(q)`` the tip position (world frame), ``(q_k, v_k)`` the state after ``k`` intervals of the
discrete dynamics below from the measured ``(q, v)``, and applies ``p_0``. The state is the
free coordinates' ``s = (q_a, v_a)`` (``a = chain.active``; locked coordinates keep their
values).

The discrete dynamics ``s_{k+1} = F(s_k, p_k)`` are ``steps`` classical Runge-Kutta (RK4)
steps of ``h / steps`` over the interval with the pressures held, on
``q_a' = v_a``, ``v_a' = a(q, v, p)_a`` (:meth:`Chain.forward_dynamics`, compiled). Their
Jacobians ``A_k = dF/ds`` and ``B_k = dF/dp`` are exact: the chain rule through the four
stages of each step, with each stage's ``da/dq``, ``da/dv``, ``da/dp`` from
:meth:`Chain.forward_dynamics_derivatives` (analytic, compiled). The tip's gradient is
``J^T Q (x - x_d)`` with ``J`` the exact tip Jacobian; its Hessian is taken as the
Gauss-Newton ``Q J^T J`` (iLQR: the dynamics' second derivatives are dropped too), so the
gradient of ``J(P)`` is exact and the Newton model an approximation.

The bounds enter the backward pass (box-DDP): at each stage the feed-forward step solves the
box-constrained quadratic ``min 1/2 du^T Q_uu du + Q_u^T du`` subject to
``p_min <= p_k + du <= p_max`` (bounded least squares on the Cholesky factor of ``Q_uu``,
``scipy.optimize.lsq_linear``), and the feedback gain acts only on the chambers left free
by it (the clamped rows of ``K`` are zero). The forward pass
``p_k' = clip(p_k + alpha k_k + K_k (s_k' - s_k))`` with a backtracking line search on
``alpha`` keeps every iterate within the bounds. Between samples the plan is shifted by one
interval (warm start), its last pressures repeated.

Where the compiled engine serves the chain (:meth:`Chain.kernel_arrays`), a rollout of the
horizon (a forward pass with its feedback law included) is one compiled call and so is the
linearisation of the whole horizon (:mod:`qchain.sim.engine.horizon`: the engine's own
right-hand side and exact Jacobian ``f_y``, the RK4 map differentiated stage by stage); the
tip positions of the accepted rollout are reused by the linearisation. ``compiled=False``
keeps the Python path (per-stage :meth:`Chain.forward_dynamics` /
:meth:`Chain.forward_dynamics_derivatives` calls, the chain rule in numpy): equal to
rounding.

Given ``tension_max`` instead of ``p_max``, the inputs ``p_k`` are the tensions ``T_k`` (nt,) N
of the chain's tendons, ``0 <= T_k <= tension_max`` (a tendon pulls), the chambers held at zero:
the same cost and solver, with ``da/dT = M^-1 B_T(q)`` and the tendons' exact stiffness
``M^-1 d(B_T T)/dq`` in ``da/dq`` (docs/tendons.md).

docs/control.md ("Model-predictive control") gives the equations, the accuracy of the
discrete dynamics and the measured solve times.
"""

from __future__ import annotations

import time
import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.optimize import lsq_linear

from ..arm.chain import Chain
from ..checks.bounds import HORIZON, ITERATIONS, PRESSURE_WEIGHT, RTOL, STEP, TENSION_WEIGHT, TIP_WEIGHT
from ..checks.convert import as_vector
from .._jit import Address, first_class_functions
from ..errors import DomainError, NonFiniteError
from ..sim.engine import horizon as compiled_horizon
from ..sim.engine import packing, system
from .base import Controller
from .references import path_point

__all__ = ["MPC"]

#: step sizes of the forward pass's backtracking line search
_ALPHAS = (1.0, 0.5, 0.25, 0.1, 0.03, 0.01)
#: the first call (no plan to start from) may iterate this many times max_iter
_COLD_FACTOR = 10


class MPC(Controller):
    """Model-predictive tip tracking by box-DDP (see the module docstring for the method).

    Parameters
    ----------
    chain : Chain
        The model the controller plans with (base ``"fixed"``).
    path : callable ``t -> (3,)`` m (or ``(x_d, xd_dot)``: the first is used), or a (3,)
        array (a fixed target), world frame. Evaluated up to ``H / rate`` s ahead of each
        sample.
    horizon : int
        ``H``, control intervals planned over, 1 to 10000 (default 20).
    Q : float, 1/m^2
        Weight of the squared tip error at the intermediate knots (default ``1e6``: a 1 mm
        error costs 0.5).
    R : float, 1/Pa^2 (1/N^2 with tendons)
        Weight of the squared pressures, > 0 (default ``1e-12``: 100 kPa in one chamber over
        one interval costs 0.005); of the squared tensions with ``tension_max`` (default
        ``1e-3``: 2 N in one tendon over one interval costs 0.002).
    Q_terminal : float, 1/m^2, optional
        ``Q_f``, weight of the squared tip error at the horizon's end (default ``Q``).
    rate : float, Hz
        The control rate; ``h = 1 / rate`` is an interval of the plan.
    p_max, p_min : float, Pa
        The pressure bounds (:class:`~qchain.control.base.Controller`).
    tension_max : float, N, optional
        Plan the tensions of the chain's tendons in ``[0, tension_max]`` instead of pressures
        (then ``p_max``, ``p_min`` are not given; :class:`~qchain.control.base.Controller`).
    max_iter : int
        Box-DDP iterations a sample (default 5); the first sample, cold, up to 10 times more.
    tol : float
        Stop iterating when an iteration lowers the cost by less than ``tol`` times it
        (default ``1e-4``).
    max_step : float, s
        Largest RK4 step of the discrete dynamics (default 0.01 s): ``steps =
        ceil(h / max_step)`` steps an interval.
    compiled : bool
        Roll out and linearise the horizon in compiled code where the engine serves the chain
        (default True); False: the Python path (same results to rounding, slower).

    Attributes
    ----------
    horizon, Q, R, Q_terminal, max_iter, tol, steps
    plan : (H, 3 n) Pa, (H, nt) N with tendons, or None
        The last solution, ``plan[0]`` applied at the last sample.

    Signals (besides ``t``, ``p``, ``compute_s``): ``solve_s`` (K,) the CPU time (s) of the
    sample's optimisation, ``solve_wall_s`` (K,) its wall time, ``iterations`` (K,),
    ``cost`` (K,) the plan's ``J``, ``x``, ``x_d``, ``error`` (K, 3) m the tip, its target
    and ``x - x_d``; ``tau`` = ``tau_realised`` (K, k) ``B(q) p`` on the free coordinates,
    ``residual`` (K,) zero (nothing is allocated), ``saturated`` (K,) whether a chamber is at a
    bound, ``at_upper`` (K,) the chambers at ``p_max``. With tendons ``tension`` (K, nt) N
    takes the place of ``p``, ``tau`` is ``B_T(q) T`` and the bounds are ``[0, tension_max]``.
    """

    def __init__(self, chain: Chain, path, *, horizon: int = 20, Q: float = 1e6, R: float | None = None,
                 Q_terminal: float | None = None, rate: float, p_max: float | None = None, p_min: float = 0.0,
                 tension_max: float | None = None, max_iter: int = 5, tol: float = 1e-4, max_step: float = 0.01,
                 compiled: bool = True):
        super().__init__(chain, rate=rate, p_max=p_max, p_min=p_min, tension_max=tension_max)
        self._tendons = self.input == "tension"
        self._nu = chain.nt if self._tendons else chain.nu  # the inputs planned: tensions or pressures
        self._unit = "N" if self._tendons else "Pa"
        if callable(path):
            self.path = path
        else:
            target = as_vector("path", path, 3)
            self.path = lambda t: target
        self.horizon = HORIZON.check("horizon", horizon)
        self.Q = TIP_WEIGHT.check("Q", Q)
        if self._tendons:
            self.R = TENSION_WEIGHT.check("R", 1e-3 if R is None else R)
        else:
            self.R = PRESSURE_WEIGHT.check("R", 1e-12 if R is None else R)
        if not self.R > 0:
            raise ValueError(f"R must be > 0 (it makes each stage's Hessian in the inputs positive definite), "
                             f"got {self.R:g} 1/{self._unit}^2")
        self.Q_terminal = self.Q if Q_terminal is None else TIP_WEIGHT.check("Q_terminal", Q_terminal)
        if self.Q == 0 and self.Q_terminal == 0:
            raise ValueError("Q and Q_terminal must not both be 0 1/m^2 (nothing would be tracked)")
        self.max_iter = ITERATIONS.check("max_iter", max_iter)
        self.tol = RTOL.check("tol", tol)
        max_step = STEP.check("max_step", max_step)
        self.h = 1.0 / self.rate
        self.steps = int(np.ceil(self.h / max_step - 1e-12))
        self.plan: np.ndarray | None = None
        self._t_plan: float | None = None
        k = self.active.size
        self._k, self._nx = k, 2 * k
        lo, hi = self._bounds
        self._scale = max(abs(lo), abs(hi))  # the solver's inputs are p / scale
        self._lo, self._hi = lo / self._scale, hi / self._scale
        self._data = chain.create_data()
        self._fast = chain.kernel_arrays() is not None  # compiled unchecked passes (results checked below)
        self._q = chain.neutral()  # the locked coordinates' values, taken from each sample's q
        self._fs0 = np.zeros((2 * k, 2 * k))
        self._fs0[:k, k:] = np.eye(k)
        self._engine = self._pack_engine() if compiled else None

    # -- the discrete dynamics
    def _full(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = self._q.copy()
        q[self.active] = s[: self._k]
        v = np.zeros(self.chain.nv)
        v[self.active] = s[self._k :]
        return q, v

    def _f(self, s: np.ndarray, p: np.ndarray) -> np.ndarray:
        """``ds/dt`` with the inputs ``p`` (pressures, or tensions with tendons) held."""
        q, v = self._full(s)
        if self._tendons:  # the chambers at zero pressure
            a = self.chain.forward_dynamics(q, v, tension=p, data=self._data, skip_checks=self._fast)
        else:
            a = self.chain.forward_dynamics(q, v, p, data=self._data, skip_checks=self._fast)
        return np.concatenate([s[self._k :], a[self.active]])

    def _f_derivatives(self, s: np.ndarray, p: np.ndarray):
        """``(f, df/ds (2k, 2k), df/du (2k, nu))`` with ``u = p / scale``. With tendons the
        tensions' force ``B_T(q) T`` enters as ``tau``: ``da/dT = M^-1 B_T`` and ``da/dq``
        gains ``M^-1 d(B_T T)/dq`` (the tendons' exact stiffness)."""
        q, v = self._full(s)
        k, a = self._k, self.active
        if self._tendons:
            Bt = self.chain.tendon_matrix(q)
            r = self.chain.forward_dynamics_derivatives(q, v, None, Bt @ p, data=self._data, skip_checks=self._fast)
            da_dq = r.da_dq + r.da_dtau @ self.chain.tendon_stiffness(q, p)
            da_du = r.da_dtau @ Bt
        else:
            r = self.chain.forward_dynamics_derivatives(q, v, p, data=self._data, skip_checks=self._fast)
            da_dq, da_du = r.da_dq, r.da_dp
        fs = self._fs0.copy()  # [[0, I], [da/dq, da/dv]]
        fs[k:, :k] = da_dq[self._ix]
        fs[k:, k:] = r.da_dv[self._ix]
        fu = np.zeros((self._nx, self._nu))
        fu[k:] = da_du[a] * self._scale
        return np.concatenate([s[k:], r.a[a]]), fs, fu

    def _step(self, s: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``F(s, u)``: ``steps`` RK4 steps over one interval, ``p = scale u`` held."""
        p = u * self._scale
        dt = self.h / self.steps
        for _ in range(self.steps):
            k1 = self._f(s, p)
            k2 = self._f(s + 0.5 * dt * k1, p)
            k3 = self._f(s + 0.5 * dt * k2, p)
            k4 = self._f(s + dt * k3, p)
            s = s + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return s

    def _step_derivatives(self, s: np.ndarray, u: np.ndarray):
        """``(F(s, u), dF/ds, dF/du)``: the RK4 steps and their exact Jacobians (chain rule
        through the stages, ``dy_i = I + c h dk_{i-1}`` for the stage states)."""
        p = u * self._scale
        dt = self.h / self.steps
        nx, nu = self._nx, self._nu
        eye = np.eye(nx)
        A, B = eye.copy(), np.zeros((nx, nu))  # d(s)/d(s_0), d(s)/d(u) so far
        for _ in range(self.steps):
            ks, dks, dku = [], [], []
            for c in (0.0, 0.5, 0.5, 1.0):
                if ks:
                    y = s + c * dt * ks[-1]
                    dys, dyu = eye + c * dt * dks[-1], c * dt * dku[-1]
                else:
                    y, dys, dyu = s, eye, np.zeros((nx, nu))
                f, fs, fu = self._f_derivatives(y, p)
                ks.append(f)
                dks.append(fs @ dys)
                dku.append(fs @ dyu + fu)
            w = (1.0, 2.0, 2.0, 1.0)
            s = s + dt / 6.0 * sum(wi * ki for wi, ki in zip(w, ks))
            Phi_s = eye + dt / 6.0 * sum(wi * d for wi, d in zip(w, dks))
            Phi_u = dt / 6.0 * sum(wi * d for wi, d in zip(w, dku))
            A, B = Phi_s @ A, Phi_s @ B + Phi_u
        return s, A, B

    # -- the compiled passes (qchain.sim.engine.horizon)
    def _pack_engine(self) -> dict | None:
        """The engine's packed model, workspace and scratch for the compiled passes, or None
        where compiled code cannot serve the chain (then the Python path runs)."""
        ch = self.chain
        m = packing.pack(ch, np.zeros(ch.nu), None, tension=np.zeros(ch.nt) if ch.nt else None)
        if m is None or m.base != system.FIXED:
            return None
        nx, nu, k = self._nx, self._nu, self._k
        return dict(m=m, wk=system.workspace(ch, m), fs=None, K=np.zeros((4, nx)), yt=np.zeros(nx),
                    y=np.zeros(nx), dK=np.zeros((4, nx, nx + nu)), D=np.zeros((nx, nx + nu)),
                    dY=np.zeros((nx, nx + nu)), Jq=np.zeros((k, k)), Jv=np.zeros((k, k)), kff=np.zeros((1, 1)),
                    Kfb=np.zeros((1, 1, 1)), Bt=np.zeros((ch.nv, nu)), da_du=np.zeros((ch.nv, nu)), g=np.zeros(3),
                    Hs=np.zeros((3, 3)), entries={})

    def _call(self, fn, *args) -> None:
        """``fn(fs, m, wk, h, steps, scale, *args)`` with the locked coordinates' values as the
        chart (the free ones zero: the engine's ``y`` is ``s``); raises on a failed status."""
        e = self._engine
        m, wk = e["m"], e["wk"]
        if e["fs"] is None:  # the engine's callbacks, loaded from numba's cache or compiled, once
            e["fs"] = (system.rhs(m).compile(m, wk, 0.0, e["y"], e["yt"]),
                       system.jacobian.compile(m, wk, 0.0, e["y"], e["Jq"], e["Jv"]))
        wk.q_chart[:] = self._q
        wk.q_chart[self.active] = 0.0
        args = (m, wk, self.h, self.steps, self._scale, *args)
        entry = e["entries"].get(fn)
        if entry is None:
            with first_class_functions():
                status = fn(e["fs"], *args)  # loaded from numba's cache or compiled, once
                sig = tuple(fn.typeof_pyval(a) for a in (e["fs"], *args))
            # later calls go to the compiled entry point with the callbacks as addresses:
            # the dispatcher would type the model, workspace and callbacks again at each call
            e["entries"][fn] = (fn.overloads[sig].entry_point, tuple(Address(cf.address) for cf in e["fs"]))
        else:
            status = entry[0](entry[1], *args)
        if status != system.OK:
            j = int(wk.info[3])
            if status == system.DOMAIN:
                raise DomainError(f"MPC: segment {int(wk.info[1])} left the model's domain (|kappa| r >= 1 or "
                                  f"l <= 0) in interval {j} of the planned motion")
            why = "an articulated inertia not positive definite" if status == system.SINGULAR else "non-finite values"
            raise NonFiniteError(f"MPC: the planned motion has {why} in interval {j}")

    def _engine_rollout(self, S, U, kff=None, Kfb=None, alpha=0.0, S_ref=None, U_ref=None) -> None:
        """``S[1:]`` from ``S[0]`` under ``U`` (scaled), in one compiled call; with ``kff``,
        ``Kfb`` the forward pass's ``U = clip(U_ref + alpha kff + Kfb (S - S_ref))`` is formed
        on the way."""
        e = self._engine
        feedback = kff is not None
        if not feedback:
            kff, Kfb, S_ref, U_ref = e["kff"], e["Kfb"], S, U
        self._call(compiled_horizon.rollout, self._tendons, float(self._lo), float(self._hi), S_ref, U_ref, kff, Kfb,
                   float(alpha), feedback, S, U, e["K"], e["yt"])

    def _dynamics_jacobians(self, S, U):
        """Every interval's ``A_k`` (H, 2k, 2k) and ``B_k`` (H, 2k, nu) (``u`` scaled) at the
        rollout's states ``S`` and inputs ``U``: one compiled call, or the Python chain rule."""
        if self._engine is None:
            return self._dynamics_jacobians_python(S, U)
        H, nx = U.shape[0], self._nx
        A = np.empty((H, nx, nx))
        B = np.empty((H, nx, self._nu))
        e = self._engine
        self._call(compiled_horizon.linearise, self._tendons, S, U, A, B, e["K"], e["dK"], e["y"], e["yt"], e["D"],
                   e["dY"], e["Jq"], e["Jv"], e["Bt"], e["da_du"], e["g"], e["Hs"])
        return A, B

    def _dynamics_jacobians_python(self, S, U):
        """:meth:`_dynamics_jacobians` by the Python path (per-stage calls, the chain rule in numpy)."""
        H, nx = U.shape[0], self._nx
        A = np.empty((H, nx, nx))
        B = np.empty((H, nx, self._nu))
        for j in range(H):
            _, A[j], B[j] = self._step_derivatives(S[j], U[j])
        return A, B

    # -- the cost
    def _tip_jacobian(self, s: np.ndarray) -> np.ndarray:
        return self.chain.tip_jacobian(self._full(s)[0], "local_world_aligned")[:3, self.active]

    def _weights(self) -> np.ndarray:
        w = np.full(self.horizon + 1, self.Q)
        w[0] = 0.0  # the measured state's tip: no control changes it
        w[-1] = self.Q_terminal
        return w

    def _targets(self, t: float) -> np.ndarray:
        return np.array([path_point(self.path, t + j * self.h) for j in range(self.horizon + 1)])

    def _rollout(self, s0, U, Xd):
        """States (H + 1, 2k) and cost of the plan ``U`` (H, nu) (scaled) from ``s0``."""
        S = np.empty((U.shape[0] + 1, self._nx))
        S[0] = s0
        if self._engine is not None:
            self._engine_rollout(S, U)
        else:
            for j in range(U.shape[0]):
                S[j + 1] = self._step(S[j], U[j])
        return (S, *self._cost(S, U, Xd))

    def _cost(self, S, U, Xd) -> tuple[float, np.ndarray]:
        """``(J, X)``: the cost and the tip positions ``X`` (H + 1, 3) m at the knots (``X[0]``
        not formed: NaN), which the linearisation reuses."""
        if not np.all(np.isfinite(S)):
            raise NonFiniteError(f"MPC: the planned motion has non-finite entries; the plan's {self.input}s "
                                 f"range {U.min() * self._scale:g} to {U.max() * self._scale:g} {self._unit}")
        w = self._weights()
        X = np.full((self.horizon + 1, 3), np.nan)
        Q = np.tile(self._q, (self.horizon, 1))
        Q[:, self.active] = S[1:, : self._k]
        # every knot's tip in one compiled (checked) call: equal to tip_placement's, bit for bit
        X[1:] = self.chain.frames_batch(Q, 2).translation[:, -1]
        track = sum(0.5 * w[j] * np.sum((X[j] - Xd[j]) ** 2) for j in range(1, self.horizon + 1))
        cost = track + 0.5 * self.R * self._scale**2 * float(np.sum(U * U))
        if not np.isfinite(cost) or not np.all(np.isfinite(S)):
            raise NonFiniteError(f"MPC: the planned motion has non-finite entries (cost {cost:g}); the plan's "
                                 f"{self.input}s range {U.min() * self._scale:g} to {U.max() * self._scale:g} "
                                 f"{self._unit}")
        return float(cost), X

    def _linearise(self, S, U, Xd, X):
        """Per stage ``A_k``, ``B_k`` and the tip cost's gradient and Gauss-Newton Hessian in
        ``s`` at the knots (``X`` (H + 1, 3) the knots' tip positions, from :meth:`_cost`)."""
        H, nx, k = self.horizon, self._nx, self._k
        lx = np.zeros((H + 1, nx))
        lxx = np.zeros((H + 1, nx, nx))
        A, B = self._dynamics_jacobians(S, U)
        w = self._weights()
        for j in range(1, H + 1):
            if w[j] == 0.0:
                continue
            J = self._tip_jacobian(S[j])
            lx[j, :k] = w[j] * J.T @ (X[j] - Xd[j])
            lxx[j, :k, :k] = w[j] * J.T @ J
        return A, B, lx, lxx

    # -- public derivatives of the horizon (tests, users' own optimisers)
    def _state(self, q, v) -> np.ndarray:
        q = as_vector("q", q, self.chain.nq)
        v = as_vector("v", v, self.chain.nv)
        self._q = q.copy()
        return np.concatenate([q[self.active], v[self.active]])

    def _sequence(self, P) -> np.ndarray:
        P = np.asarray(P, dtype=float)
        if P.shape != (self.horizon, self._nu):
            raise ValueError(f"P must have shape ({self.horizon}, {self._nu}) (horizon, "
                             f"{'nt' if self._tendons else '3 n'}), got {P.shape}")
        if not np.all(np.isfinite(P)):
            raise ValueError("P has non-finite entries")
        return P / self._scale

    def step(self, q, v, p, derivatives: bool = False):
        """The discrete dynamics over one control interval: ``(q', v')`` (nq,), (nv,) after
        ``1 / rate`` s from ``(q, v)`` with ``p`` (3 n,) Pa held (the tensions (nt,) N with
        tendons); with ``derivatives=True`` also ``A = ds'/ds`` (2k, 2k) and ``B = ds'/dp``
        (2k, 3 n) (1/Pa; (2k, nt), 1/N, with tendons), exact, on the free coordinates' state
        ``s = (q[active], v[active])``."""
        s = self._state(q, v)
        p = as_vector("p", p, self._nu)
        u = (p / self._scale)[None]
        if self._engine is None:
            if derivatives:
                s1, A, B = self._step_derivatives(s, u[0])
                return (*self._full(s1), A, B / self._scale)
            return self._full(self._step(s, u[0]))
        S = np.empty((2, self._nx))
        S[0] = s
        self._engine_rollout(S, u)
        if not np.all(np.isfinite(S[1])):
            raise NonFiniteError("MPC: the interval's end state has non-finite entries")
        if derivatives:
            A, B = self._dynamics_jacobians(S, u)
            return (*self._full(S[1]), A[0], B[0] / self._scale)
        return self._full(S[1])

    def horizon_cost(self, t: float, q, v, P) -> float:
        """``J(P)`` of the module docstring for the pressures ``P`` (H, 3 n) Pa (the tensions
        (H, nt) N with tendons) from ``(q, v)`` at ``t``: a rollout of the discrete dynamics."""
        s0 = self._state(q, v)
        return self._rollout(s0, self._sequence(P), self._targets(t))[1]

    def horizon_gradient(self, t: float, q, v, P) -> tuple[float, np.ndarray]:
        """``(J(P), dJ/dP (H, 3 n) 1/Pa (H, nt) 1/N with tendons)``: the gradient by the adjoint recursion on the
        linearisation, ``lam_H = l_s(H)``, ``dJ/dp_k = R p_k + B_k^T lam_{k+1}``,
        ``lam_k = l_s(k) + A_k^T lam_{k+1}`` (exact: the Gauss-Newton step enters only
        the Hessian)."""
        s0 = self._state(q, v)
        U = self._sequence(P)
        Xd = self._targets(t)
        S, cost, X = self._rollout(s0, U, Xd)
        A, B, lx, _ = self._linearise(S, U, Xd, X)
        G = np.empty_like(U)
        lam = lx[-1]
        for j in range(self.horizon - 1, -1, -1):
            G[j] = self.R * self._scale * U[j] + B[j].T @ lam / self._scale
            lam = lx[j] + A[j].T @ lam
        return cost, G

    # -- box-DDP
    def _box_qp(self, Quu, Qu, lo, hi):
        """``argmin 1/2 du^T Quu du + Qu^T du`` on ``lo <= du <= hi`` and the free mask."""
        L = cho_factor(Quu, lower=True, check_finite=False)
        free_step = -cho_solve(L, Qu, check_finite=False)
        if np.all(free_step >= lo) and np.all(free_step <= hi):
            return free_step, np.ones(Qu.size, dtype=bool)
        Lo = np.tril(L[0])
        # 1/2 |L^T du + L^-1 Qu|^2 = 1/2 du^T Quu du + Qu^T du + const
        r = lsq_linear(Lo.T, -solve_triangular(Lo, Qu, lower=True, check_finite=False), bounds=(lo, hi),
                       method="bvls")
        du = np.clip(r.x, lo, hi)
        return du, r.active_mask == 0

    def _backward(self, U, A, B, lx, lxx, mu):
        H, nu = self.horizon, self._nu
        r = self.R * self._scale**2
        kff = np.zeros((H, nu))
        Kfb = np.zeros((H, nu, self._nx))
        Vx, Vxx = lx[H].copy(), lxx[H].copy()
        d1 = d2 = 0.0
        for j in range(H - 1, -1, -1):
            Qx = lx[j] + A[j].T @ Vx
            Qu = r * U[j] + B[j].T @ Vx
            VB = Vxx @ B[j]
            Qxx = lxx[j] + A[j].T @ Vxx @ A[j]
            Qux = VB.T @ A[j]
            Quu = r * np.eye(nu) + B[j].T @ VB
            Quu = 0.5 * (Quu + Quu.T)
            kj, free = self._box_qp(Quu + mu * np.eye(nu), Qu, self._lo - U[j], self._hi - U[j])
            Kj = np.zeros((nu, self._nx))
            if free.any():
                f = np.ix_(free, free)
                Kj[free] = -np.linalg.solve(Quu[f] + mu * np.eye(int(free.sum())), Qux[free])
            kff[j], Kfb[j] = kj, Kj
            Vx = Qx + Kj.T @ Quu @ kj + Kj.T @ Qu + Qux.T @ kj
            Vxx = Qxx + Kj.T @ Quu @ Kj + Kj.T @ Qux + Qux.T @ Kj
            Vxx = 0.5 * (Vxx + Vxx.T)
            d1 += kj @ Qu
            d2 += 0.5 * kj @ Quu @ kj
        return kff, Kfb, d1, d2

    def _forward(self, s0, S, U, kff, Kfb, alpha, Xd):
        Sn = np.empty_like(S)
        Un = np.empty_like(U)
        Sn[0] = s0
        if self._engine is not None:
            self._engine_rollout(Sn, Un, kff, Kfb, alpha, S, U)
        else:
            for j in range(self.horizon):
                Un[j] = np.clip(U[j] + alpha * kff[j] + Kfb[j] @ (Sn[j] - S[j]), self._lo, self._hi)
                Sn[j + 1] = self._step(Sn[j], Un[j])
        return (Sn, Un, *self._cost(Sn, Un, Xd))

    def _solve(self, t: float, s0: np.ndarray, U: np.ndarray, max_iter: int):
        """Box-DDP from the plan ``U`` (scaled): ``(U, cost, iterations)``."""
        Xd = self._targets(t)
        S, cost, X = self._rollout(s0, U, Xd)
        mu, it = 0.0, 0
        while it < max_iter:
            it += 1
            A, B, lx, lxx = self._linearise(S, U, Xd, X)
            kff, Kfb, d1, d2 = self._backward(U, A, B, lx, lxx, mu)
            if -d1 <= self.tol * 1e-3 * cost:  # no descent left within the bounds: converged
                break
            for alpha in _ALPHAS:
                Sn, Un, cn, Xn = self._forward(s0, S, U, kff, Kfb, alpha, Xd)
                expected = -(alpha * d1 + alpha**2 * d2)
                if cn < cost and (cost - cn) >= 1e-4 * expected:
                    break
            else:
                mu = max(10.0 * mu, 1e-6 * self.R * self._scale**2)  # Levenberg-Marquardt: shorter steps
                if mu > 1e6 * self.R * self._scale**2:
                    break
                continue
            drop = cost - cn
            S, U, cost, X = Sn, Un, cn, Xn  # the accepted rollout's states and tips: not formed again
            mu = 0.0 if mu < 1e-5 * self.R * self._scale**2 else mu / 10.0
            if drop < self.tol * cost:
                break
        return U, cost, it

    def _warm_start(self, t: float) -> np.ndarray | None:
        if self.plan is None or self._t_plan is None:
            return None
        shift = int(round((t - self._t_plan) / self.h))
        if not 0 <= shift < self.horizon:
            return None
        U = self.plan / self._scale
        return np.concatenate([U[shift:], np.repeat(U[-1:], shift, axis=0)])

    def torque(self, t, q, v):
        """``(B(q) p_0 on the free coordinates, signals)``: the generalised force of the
        pressures (``B_T(q) T_0``: the tensions) the plan applies now (it solves the plan)."""
        c0, w0 = time.process_time(), time.perf_counter()
        s0 = self._state(q, v)
        U = self._warm_start(t)
        max_iter = self.max_iter
        if U is None:
            U = np.full((self.horizon, self._nu), np.clip(0.0, self._lo, self._hi))
            max_iter = _COLD_FACTOR * self.max_iter
        U, cost, it = self._solve(t, s0, U, max_iter)
        solve_s, solve_wall = time.process_time() - c0, time.perf_counter() - w0
        self.plan, self._t_plan = U * self._scale, t
        p = self.plan[0].copy()
        x = self.chain.tip_placement(q).translation
        x_d = path_point(self.path, t)
        tau = self._input_matrix(q) @ p
        return tau, {self._signal: p, "solve_s": solve_s, "solve_wall_s": solve_wall, "iterations": it, "cost": cost,
                     "x": x, "x_d": x_d, "error": x - x_d}

    def _command(self, t, q, v) -> dict:
        tau, own = self.torque(t, q, v)
        p = own[self._signal]
        lo, hi = self._bounds
        rec = {self._signal: p, "tau": tau, "tau_realised": tau, "residual": 0.0,
               "saturated": bool(np.any(p <= lo) or np.any(p >= hi)), "at_upper": int(np.sum(p >= hi))}
        rec.update(own)
        return rec

    def reset(self) -> None:
        """Forget the recorded signals and the plan (the next sample starts cold)."""
        super().reset()
        self.plan, self._t_plan = None, None

    @property
    def sustainable_rate(self) -> float:
        """The control rate (Hz) the recorded samples' median solve time (CPU) sustains in
        real time, ``1 / median(solve_s)``; NaN before any sample."""
        s = [r["solve_s"] for r in self._records]
        return 1.0 / float(np.median(s)) if s else float("nan")

    def __repr__(self) -> str:
        return (f"MPC(horizon={self.horizon}, rate={self.rate:g} Hz, Q={self.Q:g}, R={self.R:g}, "
                f"Q_terminal={self.Q_terminal:g}, {self._signal} in [{self._bounds[0]:g}, {self._bounds[1]:g}] "
                f"{self._unit})")
