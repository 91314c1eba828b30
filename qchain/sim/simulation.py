"""Time integration of a chain: ``simulate(chain, q0, v0, t_span, ...) -> Trajectory``.

Methods, chosen by name (``METHODS``); the first four run on the compiled engine
(:mod:`qchain.sim.engine`): whole stretches of steps in compiled code, Python entered only
for output samples, controller instants, events and progress.

=============  =========================================================================
``"radau5"``   (default) Radau IIA of order 5, adaptive, L-stable (Hairer and Wanner's
               RADAU5): Newton with the exact Jacobian (``forward_dynamics_derivatives``),
               factorisations reused over steps; for stiff, damped arms.
``"dopri5"``   Dormand-Prince 5(4), adaptive explicit, error-controlled by ``rtol``/``atol``.
``"rk4"``      classical Runge-Kutta, fixed step ``dt``, 4th order (Munthe-Kaas form on
               the base's Lie group: a chart re-centred every step, ``dexp^-1`` applied).
``"midpoint"`` implicit midpoint rule, fixed step ``dt``: symmetric (time-reversible) and
               A-stable; on undamped, unforced runs its energy error stays bounded instead
               of drifting. Newton with ``I - dt/2 Jv - dt^2/4 Jq`` of the exact Jacobian.
``"RK45"``     scipy's solvers, Python at every stage (kept for comparison and for what
``"DOP853"``   the compiled engine does not serve): RK45 and DOP853 explicit, Radau and
``"Radau"``    BDF implicit with the model's exact elastic stiffness and damping as the
``"BDF"``      Newton matrix.
=============  =========================================================================

The compiled engine serves chains in curvature coordinates with the material law, inputs
that are constants or schedules (:mod:`qchain.sim.inputs`), a fixed or floating base or a
prescribed :class:`qchain.sim.inputs.SineMotion`, and Python controllers sampled at
``controller_rate`` (zero-order hold). Anything else (paper coordinates, the linear law, a
controller called at every stage, a Python ``base_motion``) runs the same method names on
the Python steppers (``dopri5`` as scipy's RK45, ``radau5`` as scipy's Radau);
``Trajectory.meta["engine"]`` says which ran.

A floating base is always advanced on the Lie group: the state is ``(delta, v)`` with
``q = chain.integrate(q_chart, delta)`` in a chart re-centred as the base turns, never by
adding to a quaternion. Locked coordinates (``Chain.active``) are not integrated.

Leaving the model's domain (``|kappa| r_s -> 1``, ``l -> 0``), a singular paper-coordinate
configuration or a non-finite state stops the run with ``success = False`` and a message
naming the segment, the coordinate and the time; the trajectory up to that point is kept.
"""

from __future__ import annotations

import inspect
import sys
import time as _time
from collections.abc import Callable, Sequence

import numpy as np
import pinocchio as pin

from ..checks import bounds as B
from .budget import Budget, as_budget, input_frequency, run_cost
from ..arm.chain import Chain
from .engine import driver, system
from ..errors import QchainError, as_bool, as_real, as_real_array, as_vector, check_callable, describe_value
from .inputs import Schedule, _copy, as_input
from .trajectory import Trajectory

__all__ = ["simulate", "METHODS", "FIXED_STEP", "COMPILED", "DEFAULT_METHOD", "Event"]

FIXED_STEP = ("rk4", "midpoint")
#: the methods that form the exact Jacobian (a dense, O(nv^3) computation) and factor it
JACOBIAN_METHODS = ("radau5", "midpoint", "Radau", "BDF")
COMPILED = ("radau5", "dopri5", "rk4", "midpoint")
# scipy's solver classes by name (imported where a Python-path run needs them: scipy's import
# is a third of qchain's); dopri5 and radau5 stand in for the compiled two on that path
ADAPTIVE = {"RK45": "RK45", "DOP853": "DOP853", "Radau": "Radau", "BDF": "BDF", "dopri5": "RK45", "radau5": "Radau"}
METHODS = COMPILED + ("RK45", "DOP853", "Radau", "BDF")
DEFAULT_METHOD = "radau5"
_RECENTER = 0.5  # rad/m of base chart coordinates before the chart is moved


class Event:
    """A scalar function ``g(t, q, v)`` whose sign change the run reports (and stops at if
    ``terminal``); ``direction`` > 0 only rising, < 0 only falling, 0 both."""

    def __init__(self, fun: Callable, terminal: bool = False, direction: float = 0.0, name: str | None = None):
        if not callable(fun):
            raise TypeError(f"Event fun must be callable (t, q, v) -> float, got {describe_value(fun)}")
        if name is not None and not isinstance(name, str):
            raise TypeError(f"Event name must be None or a str, got {describe_value(name)}")
        self.fun = fun
        self.terminal = as_bool("Event terminal", terminal)
        self.direction = as_real("Event direction", direction)
        self.name = name or getattr(fun, "__name__", "event")

    def __call__(self, t, q, v) -> float:
        """``fun(t, q, v)`` as a finite float (``TypeError``/``ValueError`` naming the event and
        the time otherwise); ``fun`` gets copies of the state, so its writes stay its own."""
        g = self.fun(t, _copy(q), _copy(v))
        if not (type(g) is float and g - g == 0.0):
            g = as_real(f"event {self.name!r}: fun(t, q, v) at t = {float(t):.6g} s", g)
        return g


class _DomainExit(Exception):
    pass


class _WallLimit(Exception):
    pass


class _Stop(Exception):
    """Ends a Python-path run with ``success = False`` and this message, the samples kept."""


class _Progress:
    """The progress of a run on stderr: a bar redrawn in place (``True``, for a terminal), or
    for a log or a pipe (``"lines"``) a plain line once the run has taken
    :data:`LINES_AFTER` s of wall time and then every :data:`LINES_EVERY` s, with the time
    still to go (a long run is seen going on, not mistaken for a hang)."""

    def __init__(self, t0, t1, enabled):
        self.t0, self.t1, self.enabled = t0, t1, enabled
        self.lines = enabled == "lines"
        self.start = _time.perf_counter()
        self.last = self.start
        self.shown = False

    def update(self, t, force=False):
        if not self.enabled:
            return
        now = _time.perf_counter()
        wall = now - self.start
        frac = min(max((t - self.t0) / (self.t1 - self.t0), 0.0), 1.0)
        if self.lines:
            if force or wall < LINES_AFTER or (self.shown and now - self.last < LINES_EVERY):
                return
            self.last, self.shown = now, True
            left = f", about {wall * (1 - frac) / frac:.3g} s to go" if frac > 0 else ""
            sys.stderr.write(f"qchain: t = {t:.6g} s of {self.t1:.6g} s ({100 * frac:.1f} %) after {wall:.3g} s "
                             f"wall time{left}\n")
            sys.stderr.flush()
            return
        if not force and (now - self.last < 0.25 or wall < 1.0):
            return
        self.last = now
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        rtf = (t - self.t0) / wall if wall > 0 else 0.0
        sys.stderr.write(f"\r[{bar}] {100 * frac:5.1f}%  t = {t:.3f} s  wall {wall:.1f} s  x{rtf:.3g} real time")
        sys.stderr.flush()
        self.shown = True

    def close(self, t):
        if self.shown and not self.lines:
            self.update(t, force=True)
            sys.stderr.write("\n")


#: s of wall time before a run's first progress line (``progress="lines"``), and between lines
LINES_AFTER, LINES_EVERY = 10.0, 30.0


class _System:
    """The first-order system in a chart: ``y = (delta_A, v_A)`` over the active coordinates."""

    def __init__(self, chain: Chain, P, Tq):
        self.ch = chain
        self.P, self.Tq = P, Tq
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

    def q_of(self, yd: np.ndarray) -> np.ndarray:
        ch = self.ch
        if ch.floating:
            return ch.integrate(self.q_chart, self.full(yd))
        q = self.q_chart.copy()  # additive for a fixed or prescribed base (no quaternion)
        q[self.idx] += yd
        return q

    def delta_dot(self, yd: np.ndarray, v: np.ndarray) -> np.ndarray:
        dd = v.copy()
        if self.ch.floating:
            d = self.full(yd)[:6]
            if np.any(d):
                dd[:6] = np.linalg.solve(pin.Jexp6(pin.Motion(d)), v[:6])
        return dd[self.idx]

    deadline = None

    def accel(self, t, q, v) -> np.ndarray:
        if self.deadline is not None and _time.perf_counter() > self.deadline:
            raise _WallLimit(f"wall-clock limit reached at t = {t:.6g} s")
        p = self.P(t, q, v)
        tau = self.Tq(t, q, v)
        self.nfev += 1
        return self.ch.forward_dynamics(q, v, p, tau, t=t, data=self.data)

    def rhs(self, t, y):
        yd, yv = y[: self.nA], y[self.nA :]
        if not np.all(np.isfinite(y)):
            return np.full_like(y, np.nan)
        try:
            q = self.q_of(yd)
            v = self.full(yv)
            a = self.accel(t, q, v)
        except QchainError as err:  # domain exit or singular coordinates at a trial point
            self.error = f"{err} (at t = {t:.6g} s)"
            return np.full_like(y, np.nan)
        return np.concatenate([self.delta_dot(yd, v), a[self.idx]])

    def stiffness_jacobian(self, t, y):
        """``[[0, I], [-M^-1 K, -M^-1 D]]`` on the active coordinates (elastic + damping): the
        stiff part of the Jacobian: scipy's Radau and BDF's Newton matrix on the Python path
        (the compiled ``radau5`` and ``midpoint`` use the exact one)."""
        self.njev += 1
        yd, yv = y[: self.nA], y[self.nA :]
        n = self.nA
        J = np.zeros((2 * n, 2 * n))
        J[:n, n:] = np.eye(n)
        try:
            q = self.q_of(yd)
            v = self.full(yv)
            M, K, D = self.mkd(q, v)
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


#: The shortest span a run may have, relative to ``max(1 s, |t0|, |t1|)``: below it the
#: times of the steps are not distinct in double precision.
SPAN_RESOLUTION = 64 * np.finfo(float).eps


def _check_span(t_span):
    ts = as_real_array("t_span", t_span)
    if ts.shape != (2,) or not np.all(np.isfinite(ts)) or not ts[1] > ts[0]:
        raise ValueError(f"t_span must be (t0, t1) with finite t1 > t0, got {describe_value(t_span)}")
    B.TIME.check("t_span[0]", ts[0])
    B.TIME.check("t_span[1]", ts[1])
    B.DURATION.check("t_span[1] - t_span[0]", ts[1] - ts[0])
    floor = SPAN_RESOLUTION * max(1.0, abs(float(ts[0])), abs(float(ts[1])))
    if not ts[1] - ts[0] >= floor:
        raise ValueError(f"t_span must last at least {floor:.3g} s (64 float64 epsilons of max(1 s, |t0|, |t1|), "
                         f"where the times of steps are still distinct), got t_span[1] - t_span[0] = "
                         f"{float(ts[1] - ts[0]):.3g} s")
    return float(ts[0]), float(ts[1])


def check_settings(chain: Chain, t0: float, t1: float, *, method, dt, rtol, atol, max_step, first_step, wall_limit,
                   t_eval, energies, progress, on_sample, events, controller_rate) -> dict:
    """The run settings shared by :func:`simulate` and :func:`qchain.batch.simulate_batch`,
    checked where they enter (each error names the argument, the value and the bound) and
    normalised: floats, ``t_eval`` a float array, ``events`` a list of :class:`Event`."""
    if method in FIXED_STEP:
        if dt is None:
            raise ValueError(f"method {method!r} needs a step dt > 0 s, got None")
        try:
            dt = B.STEP.check("dt", dt)
        except ValueError as err:
            raise ValueError(f"method {method!r} needs a step dt > 0 s: {err}") from None
    elif dt is not None:  # ignored by the adaptive methods, but a bad one is still refused
        dt = B.STEP.check("dt", dt)
    rtol = B.RTOL.check("rtol", rtol)
    atol = B.ATOL.check("atol", atol)
    if not (isinstance(max_step, (float, np.floating)) and max_step == np.inf):
        max_step = B.STEP.check("max_step", max_step)
    if first_step is not None:
        first_step = B.STEP.check("first_step", first_step)
        least = 20.0 * float(np.spacing(max(1.0, abs(t0), abs(t1))))  # twice the steppers' floor
        if first_step < least:
            raise ValueError(f"first_step must be >= {least:.3g} s (20 float64 spacings of max(1 s, |t0|, |t1|)), "
                             f"got {first_step:.17g} s")
    if wall_limit is not None:
        wall_limit = B.WALL_LIMIT.check("wall_limit", wall_limit)
    if t_eval is not None:
        t_eval = _check_t_eval(t_eval, t0, t1)
    if controller_rate is not None:
        controller_rate = B.SAMPLE_RATE.check("controller_rate", controller_rate)
    energies = as_bool("energies", energies)
    if not (isinstance(progress, str) and progress == "lines"):
        try:
            progress = as_bool("progress", progress)
        except TypeError:
            raise TypeError(f"progress must be True, False or 'lines', got {describe_value(progress)}") from None
    check_callable("on_sample", on_sample)
    if on_sample is not None and getattr(on_sample, "record_batch", None) is not None:
        max_sim = as_real("on_sample.max_sim", getattr(on_sample, "max_sim", 0.0))
        if not max_sim >= 0.0:
            raise ValueError(f"on_sample.max_sim must be a number of seconds >= 0, got {max_sim!r}")
    if events is None:
        events = []
    elif isinstance(events, Event) or not isinstance(events, (list, tuple)):
        raise TypeError(f"events must be None or a list of qchain.sim.simulation.Event, got {describe_value(events)}")
    events = list(events)
    for k, e in enumerate(events):
        if not isinstance(e, Event):
            raise TypeError(f"events[{k}] must be a qchain.sim.simulation.Event, got {describe_value(e)}")
    return dict(dt=dt, rtol=rtol, atol=atol, max_step=max_step, first_step=first_step, wall_limit=wall_limit,
                t_eval=t_eval, energies=energies, progress=progress, events=events, controller_rate=controller_rate)


def _check_t_eval(t_eval, t0: float, t1: float) -> np.ndarray:
    t = as_real_array("t_eval", t_eval)
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"t_eval must be a non-empty 1-D array of times (s), got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"t_eval[{int(bad[0])}] must be finite, got {t[bad[0]]}")
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise ValueError(f"t_eval must be strictly increasing: t_eval[{k + 1}] = {t[k + 1]:g} s <= t_eval[{k}] = "
                         f"{t[k]:g} s")
    if t[0] < t0 or t[-1] > t1:
        raise ValueError(f"t_eval must be inside t_span = ({t0:g}, {t1:g}) s, got {t[0]:g} s to {t[-1]:g} s")
    return t


def _state_entry(chain: Chain, q, v) -> str:
    """The first non-finite entry of a state, in words (``"v[4] (segment 1, ux)"``)."""
    for name, x, vel in (("q", q, False), ("v", v, True)):
        bad = np.flatnonzero(~np.isfinite(np.asarray(x, dtype=float)))
        if bad.size:
            return f"{name}[{int(bad[0])}] ({chain.coordinate_name(int(bad[0]), velocity=vel)})"
    return "the state"


def run_cost_of(chain: Chain, t0: float, t1: float, *, method: str, dt, max_step, t_eval, inputs=(),
                controller_rate=None, stable_step=None):
    """The :class:`qchain.sim.budget.Cost` of a run of ``chain`` over ``(t0, t1)`` with checked
    settings (:func:`check_settings`); ``inputs``: the pressure and torque inputs (their
    fastest sine counts)."""
    return run_cost(duration=t1 - t0, method=method, fixed_step=method in FIXED_STEP, dt=dt, max_step=max_step,
                    frequency=input_frequency(*inputs, chain.base_motion), samples=float(
                        t_eval.size) if t_eval is not None else (np.nan if method in FIXED_STEP else 1.0),
                    samples_why="len(t_eval)" if t_eval is not None else "", nq=chain.nq, nv=chain.nv,
                    nu=chain.nu, stable_step=stable_step, controller_rate=controller_rate)


def explicit_stability_limit(chain: Chain, method: str, q0, v0, t0: float, pressure=None, tau=None) -> float | None:
    """The stability limit of an explicit adaptive method's step at the start (s): the
    largest ``|z|`` of its stability region (:data:`qchain.sim.engine.driver.EXPLICIT_STABILITY_EXTENT`)
    over the largest ``|eigenvalue|`` of the exact Jacobian at ``(t0, q0, v0)``; no stable
    step is longer. Inputs are taken at ``t0``; a controller's as zero (it is not called
    before the run: it may keep state). None where the Jacobian cannot be formed or has more
    than :data:`qchain.sim.engine.driver.STABILITY_MAX_NV` free coordinates."""
    def at_start(u, size):
        if u is None or (callable(u) and not isinstance(u, Schedule)):
            return np.zeros(size)
        return as_input("input", u, size)(t0, q0, v0)

    return driver.stability_limit(chain, q0, v0, at_start(pressure, chain.nu), at_start(tau, chain.nv), t0,
                                  radius=driver.EXPLICIT_STABILITY_EXTENT[method])


def simulate(
    chain: Chain,
    q0,
    v0,
    t_span: Sequence[float],
    *,
    pressure=None,
    tau=None,
    method: str = DEFAULT_METHOD,
    dt: float | None = None,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    t_eval=None,
    events: Sequence[Event] | None = None,
    progress: bool = False,
    on_sample: Callable | None = None,
    max_step: float = np.inf,
    first_step: float | None = None,
    energies: bool = True,
    wall_limit: float | None = None,
    controller_rate: float | None = None,
    budget: Budget | None = None,
) -> Trajectory:
    """Integrate ``M a + C v + g + D v + dU/dq = B p + tau`` from ``(q0, v0)`` over ``t_span``.

    Parameters
    ----------
    chain : Chain
    q0 : (nq,), v0 : (nv,)
        Initial state (locked coordinates at their locked values, zero velocity).
    t_span : (t0, t1) s
    pressure : None, (3 n,) Pa, a :class:`qchain.sim.inputs.Schedule`, or a controller ``(t, q, v) -> (3 n,)``.
    tau : None, (nv,), a schedule or a controller: external generalised forces.
    method : one of ``METHODS`` (see the module docstring).
    dt : float, s
        Step of the fixed-step methods (required for them; ignored by the others).
    rtol, atol : float
        Tolerances of the adaptive methods (on ``(delta, v)``).
    t_eval : (K,) s, optional
        Output times (interpolated by the solver's dense output); default every step.
    events : sequence of :class:`Event`, optional
    progress : bool or "lines"
        Show a progress bar on stderr for runs longer than a second of wall time; ``"lines"``
        (for a log or a pipe): a plain line after 10 s of wall time and every 30 s after, with
        the time still to go.
    on_sample : callable ``(t, q, v, p)``, optional
        Called at every output sample as it is produced (e.g. to log it). If it takes a
        keyword ``energies``, it also gets ``(kinetic, potential)`` (J) of the sample.
        An object with a method ``record_batch(t, q, v, p, kinetic, potential)`` and an
        attribute ``max_sim`` (s) takes the compiled engine's samples in batches instead:
        arrays ``(K,)``, ``(K, nq)``, ``(K, nv)``, ``(K, 3 n)``, ``(K,)``, ``(K,)`` (the
        first four read-only views of the run's samples: no copy, and the results cannot
        be changed through them), each batch within ``max_sim`` of simulated time (a
        number of seconds >= 0: what it may hold back at most), the
        samples' energies included; a ``skip_checks`` keyword, if it takes one, is True
        (the states were checked at every step). :class:`qchain.recording.recorder.ChainRecorder` is
        one.
    max_step, first_step : float, s
        Passed to the adaptive solvers (``first_step`` defaults to ``min(1e-4 s, span / 10)``).
    energies : bool
        Compute kinetic and potential energy at every sample.
    wall_limit : float, s, optional
        Stop (``success = False``) when the run has taken this much wall-clock time.
    controller_rate : float, Hz, optional
        Sample a controller ``pressure`` (or ``tau``) at this rate and hold its output
        between samples (zero-order hold), as a real controller runs: the run leaves
        compiled code only at those instants. Without it a controller is called at every
        stage of every step (the Python steppers).
    budget : Budget, optional
        What the run may cost (:mod:`qchain.sim.budget`; default :data:`qchain.sim.budget.DEFAULT`):
        a run whose steps (``duration / dt``, ``duration / max_step``, 2 a period of the
        fastest sine input or base motion), samples or memory would exceed it is refused
        before it starts (:class:`qchain.sim.budget.BudgetError`).

    Every number is a real (``bool``, strings and complex numbers raise ``TypeError``)
    inside its range (:mod:`qchain.checks.bounds`; else ``ValueError`` naming the argument, the
    value and the bound): ``t_span`` within +-1e12 s, ``dt``, ``max_step`` and
    ``first_step`` > 0 s, ``1e-15 <= rtol <= 1``, ``1e-20 <= atol <= 1e3``, ``t_eval``
    finite, strictly increasing and inside ``t_span``, ``wall_limit`` > 0 s,
    ``0 < controller_rate <= 1e9`` Hz; ``t_span`` lasts at least :data:`SPAN_RESOLUTION`
    times ``max(1 s, |t0|, |t1|)`` (shorter spans have no distinct step times); ``energies``
    and ``progress`` are booleans, ``on_sample`` a callable, ``events`` a list of
    :class:`Event`, a controller takes ``(t, q, v)`` or ``(t)``. A controller, an event
    function and ``on_sample`` get their own copies of the state: what they do with them
    changes neither the run nor its samples. An exception they raise propagates unchanged.

    Returns
    -------
    Trajectory
        ``t (N,)``, ``q (N, nq)``, ``v (N, nv)``, ``p (N, 3 n)``, energies, ``success``,
        ``message``, ``nfev``, ``status`` (0 finished, 1 terminal event, -1 failed) and
        ``meta`` (``method``, ``nsteps``, ``njev``, ``events``: list of (name, t)).
    """
    if not isinstance(chain, Chain):
        raise TypeError(f"chain must be a qchain.Chain, got {type(chain).__name__}")
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    t0, t1 = _check_span(t_span)
    q0 = chain._q(q0, "q0")
    v0 = as_vector("v0", v0, chain.nv)
    st = chain._state(q0, v0, t=t0)  # raises at the input if the start is outside the model
    if chain._any_locked:
        chain._check_locks(st.q_e, st.v_e)
    chain.kinetic_energy(q0, v0, t=t0)  # NonFiniteError naming the segment if the start overflows
    chain.potential_energy(q0, t=t0)
    if any(s.coords == "paper" for s in chain.segments):  # a singular start (kappa = 0) is said here, by name
        chain.forward_dynamics(q0, v0, np.zeros(chain.nu), t=t0)
    cfg = check_settings(chain, t0, t1, method=method, dt=dt, rtol=rtol, atol=atol, max_step=max_step,
                         first_step=first_step, wall_limit=wall_limit, t_eval=t_eval, energies=energies,
                         progress=progress, on_sample=on_sample, events=events, controller_rate=controller_rate)
    dt, rtol, atol, max_step, first_step = cfg["dt"], cfg["rtol"], cfg["atol"], cfg["max_step"], cfg["first_step"]
    wall_limit, t_eval, energies, progress, events = (cfg["wall_limit"], cfg["t_eval"], cfg["energies"],
                                                      cfg["progress"], cfg["events"])
    controller_rate = cfg["controller_rate"]
    budget = as_budget(budget)
    def cost(stable_step=None):
        return run_cost_of(chain, t0, t1, method=method, dt=dt, max_step=max_step, t_eval=t_eval,
                           inputs=(pressure, tau), controller_rate=controller_rate, stable_step=stable_step)

    budget.check(cost())
    P_in, T_in = as_input("pressure", pressure, chain.nu), as_input("tau", tau, chain.nv)  # checked where they enter
    if method in driver.EXPLICIT_STABILITY_EXTENT:  # a stiff model: refused before hours of tiny steps
        budget.check(cost(explicit_stability_limit(chain, method, q0, v0, t0, pressure, tau)))
    controllers = []
    if controller_rate is not None:
        held = []
        for name, u, size in (("pressure", pressure, chain.nu), ("tau", tau, chain.nv)):
            if callable(u) and not isinstance(u, Schedule):
                held.append((name, as_input(name, u, size), size))
        if not held:
            raise ValueError("controller_rate is given but neither pressure nor tau is a controller (t, q, v) -> array")
    deadline = None if wall_limit is None else _time.perf_counter() + float(wall_limit)
    bar = _Progress(t0, t1, progress)
    n_free = int(np.count_nonzero(chain.active))
    if progress and method in JACOBIAN_METHODS and n_free > driver.STABILITY_MAX_NV:
        sys.stderr.write(f"qchain: {method} on {n_free} free coordinates: each exact Jacobian is dense "
                         f"{chain.nv} x {chain.nv} work, O(nv^3) (seconds to minutes each for nv in the thousands, "
                         "docs/engine.md); progress is shown after each step\n")
        sys.stderr.flush()
    if method in COMPILED:
        pk, tk = pressure, tau
        if controller_rate is not None:
            for name, _, size in held:
                if name == "pressure":
                    pk = np.zeros(size)
                else:
                    tk = np.zeros(size)
        m = system.pack(chain, pk, tk)
        if m is not None:
            p_of, tau_of = P_in, T_in
            if controller_rate is not None:
                slots = {"pressure": m[21], "tau": m[23]}
                controllers = [(fn, slots[name]) for name, fn, _ in held]
                names = {name for name, _, _ in held}
                if "pressure" in names:  # the held output, not another call of the controller
                    p_of = lambda t, q, v: m[21].copy()  # noqa: E731
                if "tau" in names:
                    tau_of = lambda t, q, v: m[23].copy()  # noqa: E731
            pass_energies = False
            if on_sample is not None and energies:
                try:
                    pass_energies = "energies" in inspect.signature(on_sample).parameters
                except (TypeError, ValueError):
                    pass
            try:
                traj = driver.run(chain, m, method, q0, v0, t0, t1, dt=dt, rtol=rtol, atol=atol, t_eval=t_eval,
                                  on_sample=on_sample, pass_energies=pass_energies, events=events,
                                  bar=bar if progress else None, max_step=max_step, first_step=first_step,
                                  energies=energies, deadline=deadline, controllers=controllers,
                                  controller_rate=controller_rate,
                                  inputs=lambda t, q, v: (p_of(t, q, v), tau_of(t, q, v)),
                                  max_total_steps=budget.max_steps)
            except driver.Interrupted as err:
                bar.close(err.trajectory.t[-1] if len(err.trajectory.t) else t0)
                raise
            bar.close(traj.t[-1] if len(traj.t) else t0)
            return traj
    if controller_rate is not None:
        raise ValueError("controller_rate needs the compiled engine: a chain in curvature coordinates with the "
                         "material law, schedules or constants for the other input, no Python base_motion")
    sysm = _System(chain, P_in, T_in)
    sysm.deadline = deadline
    rec = _Recorder(chain, sysm, t_eval, on_sample, energies)
    status, message = 0, "The end of the time span was reached."
    ev_log: list[tuple[str, float]] = []
    nsteps = 0
    q, v, t = q0.copy(), v0.copy(), t0
    try:
        rec.start(t, q, v)
    except _Stop as err:  # the first sample's energies overflow: a run of no steps, its message says why
        traj = rec.trajectory(-1, str(err), sysm.nfev)
        traj.meta.update(method=method, engine="python", nsteps=0, njev=0, events=[])
        return traj
    g_prev = [e(t, q, v) for e in events]

    def check_events(t_a, t_b, interp):
        """Root-find sign changes of the events over [t_a, t_b]; return the first terminal time."""
        nonlocal g_prev
        g_now = []
        hit = None
        for k, e in enumerate(events):
            qb, vb = interp(t_b)
            gb = e(t_b, qb, vb)
            g_now.append(gb)
            ga = g_prev[k]
            rising, falling = ga < 0 <= gb, ga > 0 >= gb
            if (rising and e.direction >= 0) or (falling and e.direction <= 0):
                from scipy.optimize import brentq

                te = brentq(lambda s: e(s, *interp(s)), t_a, t_b, xtol=1e-12 * max(1.0, abs(t_b)))
                ev_log.append((e.name, te))
                if e.terminal and (hit is None or te < hit):
                    hit = te
        g_prev = g_now
        return hit

    try:
        if method in FIXED_STEP:
            step = _rk4_step if method == "rk4" else _midpoint_step
            nsteps_total = int(np.ceil((t1 - t0) / dt - 1e-9))
            h_stable = (driver.stability_limit(chain, q0, v0, sysm.P(t0, q0, v0), sysm.Tq(t0, q0, v0), t0)
                        if method == "rk4" else None)
            for k in range(nsteps_total):
                h = min(dt, t1 - t)
                sysm.q_chart = q
                try:
                    q1, v1 = step(sysm, t, q, v, h)
                except _DomainExit as err:
                    status, message = -1, driver.unstable_message(str(err), h, h_stable)
                    break
                if not (np.all(np.isfinite(q1)) and np.all(np.isfinite(v1))):
                    status, message = -1, driver.unstable_message(
                        f"non-finite state {_state_entry(chain, q1, v1)} at t = {t + h:.6g} s", h, h_stable)
                    break
                try:
                    chain._state(q1, v1, t=t + h)
                except QchainError as err:
                    status, message = -1, driver.unstable_message(f"{err} (at t = {t + h:.6g} s)", h, h_stable)
                    break
                t_new = t0 + (k + 1) * dt if k + 1 < nsteps_total else t1
                interp = _linear_interp(chain, t, q, v, t_new, q1, v1)
                hit = check_events(t, t_new, interp) if events else None
                if hit is not None:
                    rec.advance(t, t_new, interp, t_stop=hit)
                    t, (q, v) = hit, interp(hit)
                    status, message = 1, f"A termination event occurred at t = {hit:.6g} s."
                    break
                rec.advance(t, t_new, interp)
                t, q, v = t_new, q1, v1
                nsteps += 1
                bar.update(t)
        else:
            with np.errstate(under="ignore"):  # (scipy's first step takes nextafter(0, inf), an underflow)
                t, q, v, status, message, nsteps = _run_adaptive(
                    ADAPTIVE[method], sysm, rec, bar, check_events, t0, t1, q, v, rtol, atol, max_step, first_step,
                    method, max_total_steps=budget.max_steps)
    except (_WallLimit, _Stop) as err:
        status, message = -1, str(err)
    except KeyboardInterrupt:
        # an adaptive run is interrupted inside _run_adaptive: its samples say how far it got
        t = max(t, rec.T[-1]) if rec.T else t
        status, message = -1, f"interrupted by the user at t = {t:.6g} s"
        bar.close(t)
        traj = rec.trajectory(status, message, sysm.nfev)
        traj.meta.update(method=method, engine="python", nsteps=nsteps, njev=sysm.njev, events=ev_log)
        raise driver.Interrupted(traj) from None
    bar.close(t)
    traj = rec.trajectory(status, message, sysm.nfev)
    traj.meta.update(method=method, engine="python", nsteps=nsteps, njev=sysm.njev, events=ev_log)
    return traj


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
        bad = int(np.flatnonzero(~np.isfinite(y1))[0])
        which = sysm.ch.coordinate_name(int(sysm.idx[bad % nA]))
        raise _DomainExit(f"non-finite state ({'velocity' if bad >= nA else 'position'} of {which}) at "
                          f"t = {t + h:.6g} s")
    return sysm.q_of(y1[:nA]), sysm.full(y1[nA:])


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
    B = getattr(sysm, "_mp_B", None)
    if B is not None and B[1] != h:
        B = None
    B = None if B is None else B[0]
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


#: An adaptive run on the Python steppers stops as stalled after STALL_STEPS accepted steps in
#: a row each shorter than STALL_STEP x max(1 s, |t|): no smooth model of an arm needs them
#: (an explicit method's stability limit below it is refused before the run by the budget),
#: a noisy controller drives the step to them and would take hours to reach the step budget
STALL_STEP, STALL_STEPS = 1e-9, 1000


def _run_adaptive(name, sysm, rec, bar, check_events, t0, t1, q, v, rtol, atol, max_step, first_step, method,
                  max_total_steps=None):
    import scipy.integrate as si

    cls = getattr(si, name)
    nA = sysm.nA
    implicit = name in ("Radau", "BDF")
    nsteps = 0
    t = t0
    status, message = 0, "The end of the time span was reached."

    def new_solver(t_start, q_start, v_start, h0):
        sysm.q_chart = q_start
        y0 = np.concatenate([np.zeros(nA), v_start[sysm.idx]])
        kw = dict(rtol=rtol, atol=atol, max_step=max_step)
        if h0 is not None:
            kw["first_step"] = min(h0, t1 - t_start)
        if implicit:
            kw["jac"] = sysm.stiffness_jacobian
        return cls(sysm.rhs, t_start, y0, t1, **kw)

    # scipy's own first-step guess probes y0 + h f(y0), which can leave the model's domain
    # (or the paper coordinates' regular set) and return NaN; start small instead: the
    # controllers grow the step by up to 10x per step.
    solver = new_solver(t, q, v, first_step if first_step is not None else min(1e-4, (t1 - t0) / 10))
    tiny = 0  # accepted steps in a row below STALL_STEP
    while True:
        if max_total_steps is not None and nsteps >= max_total_steps:
            status = -1
            message = driver.step_budget_message(max_total_steps, f"{nsteps} steps taken", t, t1, method)
            break
        if tiny >= STALL_STEPS:
            status = -1
            message = (f"{method} stalled: {STALL_STEPS} steps in a row shorter than {STALL_STEP:g} x max(1 s, |t|), "
                       f"t reached = {t:.6g} s of {t1:.6g} s; the right-hand side is not smooth in time (a controller "
                       "whose output is noisy or keeps state between calls, a discontinuous input): give "
                       "controller_rate to hold the controller between its instants, or use a fixed-step method")
            break
        msg = solver.step()
        if solver.status == "failed":
            status = -1
            message = sysm.error or f"{method} failed at t = {solver.t:.6g} s: {msg}"
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
            bad = int(np.flatnonzero(~np.isfinite(y))[0])
            which = sysm.ch.coordinate_name(int(sysm.idx[bad % nA]))
            status, message = -1, (f"non-finite state ({'velocity' if bad >= nA else 'position'} of {which}) at "
                                   f"t = {t_new:.6g} s")
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
        self._pass_energies = False  # on_sample(..., energies=(kinetic, potential)) if it takes them
        if on_sample is not None and energies:
            try:
                self._pass_energies = "energies" in inspect.signature(on_sample).parameters
            except (TypeError, ValueError):
                pass
        self.T, self.Q, self.V, self.Pp, self.KE, self.PE = [], [], [], [], [], []

    def _add(self, t, q, v):
        p = self.sysm.P(t, q, v)
        if self.energies:
            try:
                ke, pe = self.ch.kinetic_energy(q, v, t=t), self.ch.potential_energy(q, t=t)
            except QchainError as err:  # a state whose energies overflow ends the run, the samples before it kept
                raise _Stop(f"{err} (a sample's energies)") from None
        self.T.append(t)
        self.Q.append(q)
        self.V.append(v)
        self.Pp.append(np.array(p, dtype=float))
        if self.energies:
            self.KE.append(ke)
            self.PE.append(pe)
        if self.on_sample is not None:
            # its own copies: what it does with them cannot change the recorded samples or the run
            if self._pass_energies:
                self.on_sample(t, q.copy(), v.copy(), self.Pp[-1].copy(), energies=(self.KE[-1], self.PE[-1]))
            else:
                self.on_sample(t, q.copy(), v.copy(), self.Pp[-1].copy())

    def start(self, t, q, v):
        if self.t_eval is None:
            self._add(t, q, v)
        else:
            while self.k < self.t_eval.size and self.t_eval[self.k] <= t:
                self._add(self.t_eval[self.k], q, v)
                self.k += 1

    def advance(self, ta, tb, interp, t_stop=None):
        end = tb if t_stop is None else t_stop
        if self.t_eval is None:
            self._add(end, *interp(end))
            return
        while self.k < self.t_eval.size and self.t_eval[self.k] <= end:
            s = self.t_eval[self.k]
            self._add(s, *interp(s))
            self.k += 1

    def trajectory(self, status, message, nfev) -> Trajectory:
        ch = self.ch
        N = len(self.T)
        return Trajectory(
            t=np.array(self.T),
            q=np.array(self.Q).reshape(N, ch.nq),
            v=np.array(self.V).reshape(N, ch.nv),
            p=np.array(self.Pp).reshape(N, ch.nu),
            kinetic_energy=np.array(self.KE) if self.energies else np.full(N, np.nan),
            potential_energy=np.array(self.PE) if self.energies else np.full(N, np.nan),
            success=status >= 0,
            message=message,
            nfev=nfev,
            status=status,
        )
