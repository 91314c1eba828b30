"""The Python backend of :func:`qchain.sim.simulation.simulate`: what the compiled engine
(:mod:`qchain.sim.engine`) does not run, with Python at every stage (docs/simulation.md says
which runs come here); ``Trajectory.meta["engine"]`` is ``"python"``.
"""

from __future__ import annotations

import inspect
import time as _time
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from ..arm.chain import Chain
from ..errors import QchainError
from .engine import driver
from .trajectory import Trajectory

# scipy's solver classes by name (imported where a Python-path run needs them: scipy's import
# is a third of qchain's); dopri5 and radau5 stand in for the compiled two on this path
ADAPTIVE = {"RK45": "RK45", "DOP853": "DOP853", "Radau": "Radau", "BDF": "BDF", "dopri5": "RK45", "radau5": "Radau"}
_RECENTER = 0.5  # rad/m of base chart coordinates before the chart is moved


class _DomainExit(Exception):
    pass


class _WallLimit(Exception):
    pass


class _Stop(Exception):
    """Ends a Python-path run with ``success = False`` and this message, the samples kept."""


class _System:
    """The first-order system in a chart: ``y = (delta_A, v_A)`` over the active coordinates."""

    def __init__(self, chain: Chain, P, Tq, deadline: float | None = None):
        self.ch = chain
        self.P, self.Tq, self.deadline = P, Tq, deadline  # deadline: time.perf_counter() s, or None
        self.idx = np.flatnonzero(chain.active)
        self.nA = self.idx.size
        self.nfev = 0
        self.njev = 0
        self.error: str | None = None
        self.q_chart = None
        self.data = chain.create_data()  # the passes' workspace, made once for the run

    def full(self, xA: np.ndarray) -> np.ndarray:
        x = np.zeros(self.ch.nv)
        x[self.idx] = xA
        return x

    def delta_dot(self, yd: np.ndarray, v: np.ndarray) -> np.ndarray:
        dd = v.copy()
        if self.ch.floating:
            d = self.full(yd)[:6]
            if np.any(d):
                dd[:6] = np.linalg.solve(pin.Jexp6(pin.Motion(d)), v[:6])
        return dd[self.idx]

    def accel(self, t, q, v) -> np.ndarray:
        if self.deadline is not None and _time.perf_counter() > self.deadline:
            raise _WallLimit(f"wall-clock limit reached at t = {t:.6g} s")
        p = self.P(t, q, v)
        tau = self.Tq(t, q, v)
        self.nfev += 1
        return self.ch.forward_dynamics(q, v, p, tau, t=t, data=self.data)

    def rhs(self, t, y):
        yd = y[: self.nA]
        if not np.all(np.isfinite(y)):
            return np.full_like(y, np.nan)
        try:
            q, v = driver.state(self.ch, self.idx, self.q_chart, y)
            a = self.accel(t, q, v)
        except QchainError as err:  # domain exit or singular coordinates at a trial point
            self.error = f"{err} (at t = {t:.6g} s)"
            return np.full_like(y, np.nan)
        return np.concatenate([self.delta_dot(yd, v), a[self.idx]])

    def nonfinite(self, y: np.ndarray, t: float) -> str:
        """The message of a state ``y`` with a non-finite entry at ``t`` (s), naming its first."""
        bad = int(np.flatnonzero(~np.isfinite(y))[0])
        which = self.ch.coordinate_name(int(self.idx[bad % self.nA]))
        return f"non-finite state ({'velocity' if bad >= self.nA else 'position'} of {which}) at t = {t:.6g} s"

    def stiffness_jacobian(self, t, y):
        """``[[0, I], [-M^-1 K, -M^-1 D]]`` on the active coordinates (elastic + damping): the
        stiff part of the Jacobian: scipy's Radau and BDF's Newton matrix on the Python path
        (the compiled ``radau5`` and ``midpoint`` use the exact one)."""
        self.njev += 1
        n = self.nA
        J = np.zeros((2 * n, 2 * n))
        J[:n, n:] = np.eye(n)
        try:
            M, K, D = self.mkd(*driver.state(self.ch, self.idx, self.q_chart, y))
        except QchainError:
            return J
        from scipy.linalg import cho_factor, cho_solve

        c = cho_factor(M)
        J[n:, :n] = -cho_solve(c, K)
        J[n:, n:] = -cho_solve(c, D)
        return J

    def mkd(self, q, v):
        """Mass, elastic stiffness and damping matrices on the active coordinates."""
        ch = self.ch
        ix = np.ix_(self.idx, self.idx)
        return ch.mass_matrix(q)[ix], ch.elastic_stiffness(q)[ix], ch.dissipation_matrix(q)[ix]


def takes_energies(on_sample: Callable | None, energies: bool) -> bool:
    """Whether ``on_sample`` is to get the samples' energies, ``on_sample(..., energies=(kinetic,
    potential))``: when the run computes them and it takes a keyword ``energies``."""
    if on_sample is None or not energies:
        return False
    try:
        return "energies" in inspect.signature(on_sample).parameters
    except (TypeError, ValueError):
        return False


def _state_entry(chain: Chain, q, v) -> str:
    """The first non-finite entry of a state, in words (``"v[4] (segment 1, ux)"``)."""
    for name, x, vel in (("q", q, False), ("v", v, True)):
        bad = np.flatnonzero(~np.isfinite(np.asarray(x, dtype=float)))
        if bad.size:
            return f"{name}[{int(bad[0])}] ({chain.coordinate_name(int(bad[0]), velocity=vel)})"
    return "the state"


def run(r, bar, deadline: float | None) -> Trajectory:
    """Run ``r.chain`` from ``(r.q0, r.v0)`` over ``(r.t0, r.t1)`` on the Python steppers and
    build its :class:`Trajectory` (``meta["engine"] = "python"``).

    Parameters
    ----------
    r : qchain.sim.simulation._Run
        The run's arguments as :func:`qchain.sim.simulation.simulate` checked them.
    bar : qchain.sim.simulation._Progress
    deadline : float or None, s
        ``time.perf_counter()`` at which the run stops (``wall_limit``).

    Returns
    -------
    Trajectory
        ``status`` 0 at ``t1``, 1 at a terminal event, -1 failed (the samples up to there).

    Raises
    ------
    qchain.sim.engine.driver.Interrupted
        On Ctrl-C, carrying the trajectory up to there.
    """
    method = r.method
    T_in = r.T_in
    if r.chain.nt:  # the tendons' generalised force B_T(q) T joins tau
        T_in = lambda t, q, v, _T=T_in: _T(t, q, v) + r.chain.tendon_force(q, r.Tn_in(t, q, v))  # noqa: E731
    if r.env is not None:  # the environment's forces join the external ones
        T_in = lambda t, q, v, _T=T_in: _T(t, q, v) + r.chain.environment_force(q, v, r.env, t)  # noqa: E731
    sysm = _System(r.chain, r.P_in, T_in, deadline)
    rec = _Recorder(r.chain, sysm, r.t_eval, r.on_sample, r.energies)
    # how far the run has got: time t (s), state q (nq,), v (nv,) and accepted steps, kept where an
    # exception that ends the run (a wall-clock limit, Ctrl-C) finds them
    at = SimpleNamespace(t=r.t0, q=r.q0.copy(), v=r.v0.copy(), nsteps=0)
    try:
        rec.start(at.t, at.q, at.v)
    except _Stop as err:  # the first sample's energies overflow: a run of no steps, its message says why
        return rec.trajectory(-1, str(err), method, 0, [])
    watch = _Events(r.events, at.t, at.q, at.v)
    try:
        if method in _STEPPERS:
            status, message = _run_fixed(sysm, rec, bar, watch, at, r)
        else:
            with np.errstate(under="ignore"):  # (scipy's first step takes nextafter(0, inf), an underflow)
                at.t, at.q, at.v, status, message, at.nsteps = _run_adaptive(sysm, rec, bar, watch, r, at.q, at.v)
    except (_WallLimit, _Stop) as err:
        status, message = -1, str(err)
    except KeyboardInterrupt:
        # an adaptive run is interrupted inside _run_adaptive: its samples say how far it got
        t = max(at.t, rec.T[-1]) if rec.T else at.t
        status, message = -1, f"interrupted by the user at t = {t:.6g} s"
        bar.close(t)
        raise driver.Interrupted(rec.trajectory(status, message, method, at.nsteps, watch.log)) from None
    bar.close(at.t)
    return rec.trajectory(status, message, method, at.nsteps, watch.log)


class _Events:
    """The events of a run, watched step by step: their values at the end of the last step
    and the log of their zero crossings, ``log``: a list of ``(name, t s)``."""

    def __init__(self, events: list, t: float, q: np.ndarray, v: np.ndarray):
        self.events = events
        self.log: list[tuple[str, float]] = []
        self.g_prev = [e(t, q, v) for e in events]

    def __call__(self, t_a: float, t_b: float, interp: Callable) -> float | None:
        """:func:`qchain.sim.engine.driver.crossings` over [t_a, t_b] (s), the state at a time
        given by ``interp(s) -> (q, v)``."""
        return driver.crossings(self.events, self.g_prev, self.log, t_a, t_b, interp)


def _run_fixed(sysm: _System, rec: _Recorder, bar, watch: _Events, at: SimpleNamespace, r) -> tuple[int, str]:
    """Fixed steps of ``dt = r.dt`` (s) with the stepper of ``r.method`` (:func:`_rk4_step`,
    :func:`_midpoint_step`) from ``at`` to ``t1 = r.t1`` (s), ``at`` advanced step by step; step
    ``k`` ends at ``t0 + (k + 1) dt`` exactly (no drift of summed steps), the last at ``t1``.

    Returns
    -------
    (status, message)
        0 at ``t1``, 1 at a terminal event, -1 where the state left the model's domain or
        stopped being finite (the message names the rk4 stability limit at ``(t0, q0, v0)``).
    """
    chain, step, (t0, t1, dt, q0, v0) = sysm.ch, _STEPPERS[r.method], (r.t0, r.t1, r.dt, r.q0, r.v0)
    nsteps_total = int(np.ceil((t1 - t0) / dt - 1e-9))
    h_stable = (driver.stability_limit(chain, q0, v0, sysm.P(t0, q0, v0), sysm.Tq(t0, q0, v0), t0)
                if r.method == "rk4" else None)
    t, q, v = at.t, at.q, at.v
    for k in range(nsteps_total):
        h = min(dt, t1 - t)
        sysm.q_chart = q
        try:
            q1, v1 = step(sysm, t, q, v, h)
        except _DomainExit as err:
            return -1, driver.unstable_message(str(err), h, h_stable)
        if not (np.all(np.isfinite(q1)) and np.all(np.isfinite(v1))):
            return -1, driver.unstable_message(
                f"non-finite state {_state_entry(chain, q1, v1)} at t = {t + h:.6g} s", h, h_stable)
        try:
            chain._state(q1, v1, t=t + h)
        except QchainError as err:
            return -1, driver.unstable_message(f"{err} (at t = {t + h:.6g} s)", h, h_stable)
        t_new = t0 + (k + 1) * dt if k + 1 < nsteps_total else t1
        interp = _linear_interp(chain, t, q, v, t_new, q1, v1)
        hit = watch(t, t_new, interp) if watch.events else None
        if hit is not None:
            rec.advance(t, t_new, interp, t_stop=hit)
            at.t, (at.q, at.v) = hit, interp(hit)
            return 1, f"A termination event occurred at t = {hit:.6g} s."
        rec.advance(t, t_new, interp)
        t, q, v = t_new, q1, v1
        at.t, at.q, at.v = t, q, v
        at.nsteps += 1
        bar.update(t)
    return 0, "The end of the time span was reached."


def _linear_interp(chain, ta, qa, va, tb, qb, vb):
    """Interpolation on a fixed step: Hermite-free linear in the Lie algebra (exact at the ends)."""
    dq = chain.difference(qa, qb)

    def interp(s):
        w = (s - ta) / (tb - ta) if tb > ta else 1.0
        return chain.integrate(qa, w * dq), (1 - w) * va + w * vb

    return interp


def _rk4_step(sysm: _System, t, q, v, h):
    nA = sysm.nA
    y = np.concatenate([np.zeros(nA), v[sysm.idx]])
    k1 = sysm.rhs(t, y)
    k2 = sysm.rhs(t + h / 2, y + h / 2 * k1)
    k3 = sysm.rhs(t + h / 2, y + h / 2 * k2)
    k4 = sysm.rhs(t + h, y + h * k3)
    y1 = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    if not np.all(np.isfinite(y1)):
        if sysm.error:
            raise _DomainExit(f"{sysm.error}, in a stage of the step from t = {t:.6g} s (dt = {h:g} s)")
        raise _DomainExit(sysm.nonfinite(y1, t + h))
    return driver.state(sysm.ch, sysm.idx, sysm.q_chart, y1)


def _midpoint_step(sysm: _System, t, q, v, h, tol=1e-10, max_iter=50):
    """Implicit midpoint: ``v_m = v + h/2 a(q (+) h/2 v_m, v_m)``, ``q1 = q (+) h v_m``, ``v1 = 2 v_m - v``.

    The residual ``R(v_m)`` is solved by quasi-Newton iterations: the matrix starts from
    the model's ``M^-1 (M + h/2 D + h^2/4 K)`` (exact elastic stiffness and damping) and is
    corrected by Broyden updates, kept from step to step and rebuilt when the iteration
    slows down; the first guess is ``v + h/2 a_prev``.
    """
    ch = sysm.ch
    idx = sysm.idx
    vA = v[idx]
    a_prev = getattr(sysm, "_mp_a", None)
    vm = vA + 0.5 * h * a_prev if a_prev is not None else vA.copy()
    B = getattr(sysm, "_mp_B", None)  # (matrix, step) kept from the last step: its matrix if the step is the same
    B = B[0] if B is not None and B[1] == h else None
    R_old = dx = None
    for it in range(max_iter):
        vmf = sysm.full(vm)
        qm = ch.integrate(q, 0.5 * h * vmf)
        try:
            a = sysm.accel(t + h / 2, qm, vmf)
        except QchainError as err:
            raise _DomainExit(f"{err} (at t = {t + h / 2:.6g} s)") from None
        R = vm - vA - 0.5 * h * a[idx]
        if not np.all(np.isfinite(R)):
            bad = int(np.flatnonzero(~np.isfinite(R))[0])
            raise _DomainExit(f"non-finite midpoint velocity of {ch.coordinate_name(int(idx[bad]))} at "
                              f"t = {t + h / 2:.6g} s")
        if np.max(np.abs(R)) <= tol * (1.0 + np.max(np.abs(vm))):
            break
        if R_old is not None:
            dR = R - R_old
            B = B + np.outer(dR - B @ dx, dx) / (dx @ dx)  # Broyden: learns what M, D, K leave out
        if B is None or it == 8:
            try:
                M, K, D = sysm.mkd(qm, vmf)
            except QchainError as err:
                raise _DomainExit(f"{err} (at t = {t + h / 2:.6g} s)") from None
            B = np.linalg.solve(M, M + 0.5 * h * D + 0.25 * h * h * K)
        dx = -np.linalg.solve(B, R)
        vm = vm + dx
        R_old = R
    else:
        raise _DomainExit(f"implicit midpoint: Newton did not converge in {max_iter} iterations at t = {t:.6g} s "
                          "(reduce dt)")
    sysm._mp_a = a[idx]
    sysm._mp_B = (B, h) if B is not None else getattr(sysm, "_mp_B", None)
    vmf = sysm.full(vm)
    return ch.integrate(q, h * vmf), sysm.full(2 * vm - vA)


#: the fixed-step methods' steppers by name (the others run on scipy's solvers, :data:`ADAPTIVE`)
_STEPPERS = {"rk4": _rk4_step, "midpoint": _midpoint_step}


#: an adaptive run stops as stalled after STALL_STEPS accepted steps in a row each shorter
#: than STALL_STEP x max(1 s, |t|) (docs/simulation.md)
STALL_STEP, STALL_STEPS = 1e-9, 1000


def _run_adaptive(sysm, rec, bar, check_events, r, q, v):
    """``r.method`` on scipy's solver (:data:`ADAPTIVE`) from ``(q, v)`` at ``r.t0`` to ``r.t1``
    (s): ``(t, q, v, status, message, nsteps)`` where it ended."""
    import scipy.integrate as si

    t0, t1, method, max_total_steps = r.t0, r.t1, r.method, r.budget.max_steps
    name = ADAPTIVE[method]
    cls = getattr(si, name)
    nA = sysm.nA
    implicit = name in ("Radau", "BDF")
    nsteps = 0
    t = t0
    status, message = 0, "The end of the time span was reached."

    def new_solver(t_start, q_start, v_start, h0):
        sysm.q_chart = q_start
        y0 = np.concatenate([np.zeros(nA), v_start[sysm.idx]])
        kw = dict(rtol=r.rtol, atol=r.atol, max_step=r.max_step)
        if h0 is not None:
            kw["first_step"] = min(h0, t1 - t_start)
        if implicit:
            kw["jac"] = sysm.stiffness_jacobian
        return cls(sysm.rhs, t_start, y0, t1, **kw)

    # scipy's own first-step guess probes y0 + h f(y0), which can leave the model's domain
    # (or the paper coordinates' regular set) and return NaN; start small instead: the
    # controllers grow the step by up to 10x per step.
    solver = new_solver(t, q, v, r.first_step if r.first_step is not None else min(1e-4, (t1 - t0) / 10))
    tiny = 0  # accepted steps in a row below STALL_STEP
    while True:
        if max_total_steps is not None and nsteps >= max_total_steps:
            status, message = -1, driver.step_budget_message(max_total_steps, f"{nsteps} steps taken", t, t1, method)
            break
        if tiny >= STALL_STEPS:
            status, message = -1, (
                f"{method} stalled: {STALL_STEPS} steps in a row shorter than {STALL_STEP:g} x max(1 s, |t|), "
                f"t reached = {t:.6g} s of {t1:.6g} s; the right-hand side is not smooth in time (a controller "
                "whose output is noisy or keeps state between calls, a discontinuous input): give "
                "controller_rate to hold the controller between its instants, or use a fixed-step method")
            break
        msg = solver.step()
        if solver.status == "failed":
            status, message = -1, sysm.error or f"{method} failed at t = {solver.t:.6g} s: {msg}"
            break
        sysm.error = None
        dense = solver.dense_output()
        chart = sysm.q_chart
        t_prev, t_new = solver.t_old, solver.t
        y = solver.y

        def interp(s, dense=dense, chart=chart):
            ys = dense(s)
            return sysm.ch.integrate(chart, sysm.full(ys[:nA])), sysm.full(ys[nA:])

        if not np.all(np.isfinite(y)):
            status, message = -1, sysm.nonfinite(y, t_new)
            break
        hit = check_events(t_prev, t_new, interp)
        if hit is not None:
            rec.advance(t_prev, t_new, interp, t_stop=hit)
            t = hit
            q, v = interp(hit)
            status, message = 1, f"A termination event occurred at t = {hit:.6g} s."
            break
        rec.advance(t_prev, t_new, interp)
        nsteps += 1
        tiny = tiny + 1 if t_new - t_prev < STALL_STEP * max(1.0, abs(t_new)) else 0
        t = t_new
        q, v = interp(t_new)
        bar.update(t)
        if solver.status == "finished":
            break
        if sysm.ch.floating and np.max(np.abs(y[:6])) > _RECENTER:
            solver = new_solver(t, q, v, solver.step_size)
    return t, q, v, status, message, nsteps


class _Recorder:
    """Collects output samples (every step, or at ``t_eval``) and hands them to ``on_sample``."""

    def __init__(self, chain, sysm, t_eval, on_sample, energies):
        self.ch, self.sysm = chain, sysm
        self.t_eval = t_eval
        self.k = 0  # next t_eval index
        self.on_sample = on_sample
        self.energies = energies
        self._pass_energies = takes_energies(on_sample, energies)
        self.T, self.Q, self.V, self.Pp, self.KE, self.PE = [], [], [], [], [], []

    def _add(self, t, q, v):
        try:  # an interpolant can leave the domain the step's ends are in: the run ends before that sample
            self.ch._state(q, v, t=t)
        except QchainError as err:
            raise _Stop(f"{err} (at t = {t:.6g} s, an output sample interpolated inside a step whose ends are inside "
                        "the domain: a smaller rtol or dt keeps the samples inside)") from None
        p = self.sysm.P(t, q, v)
        if self.energies:
            try:
                ke, pe = self.ch.kinetic_energy(q, v, t=t), self.ch.potential_energy(q, t=t)
            except QchainError as err:  # a state whose energies overflow ends the run, the samples before it kept
                raise _Stop(f"{err} (a sample's energies)") from None
        p = np.array(p, dtype=float)
        for column, x in zip((self.T, self.Q, self.V, self.Pp), (t, q, v, p)):
            column.append(x)
        if self.energies:
            self.KE.append(ke)
            self.PE.append(pe)
        if self.on_sample is not None:
            # its own copies: what it does with them cannot change the recorded samples or the run
            self.on_sample(t, q.copy(), v.copy(), p.copy(), **({"energies": (ke, pe)} if self._pass_energies else {}))

    def start(self, t, q, v):
        self.advance(t, t, lambda s: (q, v))  # the samples at or before the start: the start state

    def advance(self, ta, tb, interp, t_stop=None):
        end = tb if t_stop is None else t_stop
        if self.t_eval is None:
            self._add(end, *interp(end))
            return
        while self.k < self.t_eval.size and self.t_eval[self.k] <= end:
            s = self.t_eval[self.k]
            self._add(s, *interp(s))
            self.k += 1

    def trajectory(self, status: int, message: str, method: str, nsteps: int, events: list) -> Trajectory:
        """The run's :class:`Trajectory` from its samples, with ``meta``: ``method``, ``engine``
        (``"python"``), ``nsteps``, ``njev`` and ``events`` (a list of ``(name, t s)``)."""
        ch = self.ch
        N = len(self.T)
        traj = Trajectory(
            t=np.array(self.T),
            q=np.array(self.Q).reshape(N, ch.nq),
            v=np.array(self.V).reshape(N, ch.nv),
            p=np.array(self.Pp).reshape(N, ch.nu),
            kinetic_energy=np.array(self.KE) if self.energies else np.full(N, np.nan),
            potential_energy=np.array(self.PE) if self.energies else np.full(N, np.nan),
            success=status >= 0,
            message=message,
            nfev=self.sysm.nfev,
            status=status,
        )
        traj.meta.update(method=method, engine="python", nsteps=nsteps, njev=self.sysm.njev, events=events)
        return traj
