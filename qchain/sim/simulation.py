"""Time integration of a chain: ``simulate(chain, q0, v0, t_span, ...) -> Trajectory``.

The methods (:data:`METHODS`), which backend serves a run (the compiled engine or
:mod:`qchain.sim.python_backend`, ``Trajectory.meta["engine"]``), the checks and the failures
are described in docs/simulation.md and docs/engine.md.
"""

from __future__ import annotations

import dataclasses
import difflib
import sys
import time as _time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..checks import bounds as B
from .budget import Budget, as_budget, input_frequency, run_cost
from ..arm.chain import Chain
from . import python_backend
from .engine import driver, packing, system
from ..checks.convert import as_bool, as_real, as_real_array, as_vector, check_callable, describe_value
from .inputs import BUILT_IN, Schedule, _copy, as_input
from .trajectory import Trajectory
from ..errors import PythonBackendWarning

__all__ = ["simulate", "Runs", "METHODS", "FIXED_STEP", "COMPILED", "DEFAULT_METHOD", "Event"]

FIXED_STEP = ("rk4", "midpoint")
#: the methods that form the exact Jacobian (a dense, O(nv^3) computation) and factor it
JACOBIAN_METHODS = ("radau5", "midpoint", "Radau", "BDF")
COMPILED = ("radau5", "dopri5", "rk4", "midpoint")
#: the method names, matched exactly (:func:`check_method`); scipy's run on
#: :mod:`qchain.sim.python_backend`
METHODS = COMPILED + ("RK45", "DOP853", "Radau", "BDF")
DEFAULT_METHOD = "radau5"


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


class _Progress:
    """The progress of a run on stderr, as :func:`simulate`'s ``progress`` says (``"lines"``:
    after :data:`LINES_AFTER` s of wall time, then every :data:`LINES_EVERY` s)."""

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


#: The shortest span a run may have, relative to ``max(1 s, |t0|, |t1|)``: below it the
#: times of the steps are not distinct in double precision.
SPAN_RESOLUTION = 64 * np.finfo(float).eps


def check_run(chain, method, t_span) -> tuple[float, float]:
    """The checks :func:`simulate` and :func:`qchain.batch.simulate_batch` begin with, in this
    order: ``chain`` a :class:`Chain`, ``method`` one of :data:`METHODS`, ``t_span``; returns
    ``(t0, t1)`` (s)."""
    if not isinstance(chain, Chain):
        raise TypeError(f"chain must be a qchain.Chain, got {type(chain).__name__}")
    check_method(method)
    return _check_span(t_span)


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
    """The stability limit (s) of an explicit adaptive method's step at ``(t0, q0, v0)``:
    :func:`qchain.sim.engine.driver.stability_limit` at the method's stability extent. Inputs
    are taken at ``t0``; a controller's as zero (it is not called before the run: it may keep
    state)."""
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
    env=None,
    tension=None,
) -> Trajectory:
    """Integrate ``M a + C v + g + D v + dU/dq = B p + B_T T + tau`` from ``(q0, v0)`` over ``t_span``.

    Parameters
    ----------
    chain : Chain
    q0 : (nq,), v0 : (nv,)
        Initial state (locked coordinates at their locked values, zero velocity).
    t_span : (t0, t1) s
    pressure : None, (3 n,) Pa, a :class:`qchain.sim.inputs.Schedule`, or a controller ``(t, q, v) -> (3 n,)``.
    tau : None, (nv,), a schedule or a controller: external generalised forces.
    method : one of ``METHODS`` (docs/engine.md, "Methods").
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
        Sample a controller ``pressure`` (or ``tau``, or ``tension``) at this rate and hold its output
        between samples (zero-order hold), as a real controller runs: the run leaves
        compiled code only at those instants. Without it a controller is called at every
        stage of every step (the Python steppers).
    budget : Budget, optional
        What the run may cost (:mod:`qchain.sim.budget`; default :data:`qchain.sim.budget.DEFAULT`):
        a run whose steps (``duration / dt``, ``duration / max_step``, 2 a period of the
        fastest sine input or base motion), samples or memory would exceed it is refused
        before it starts (:class:`qchain.sim.budget.BudgetError`).
    env : qchain.contact.Environment, optional
        Obstacles, the contact law and point loads (docs/contact.md): their generalised
        force joins ``tau`` (with its exact derivatives in the implicit methods' Jacobian).
    tension : None, (nt,) N, a schedule or a controller ``(t, q, v) -> (nt,)``
        The tensions of the chain's tendons (docs/tendons.md), each within
        :data:`qchain.checks.bounds.TENSION`: a tendon pulls and cannot push, so a negative
        tension (a schedule's at any time, a controller's at any call) raises ``ValueError``
        naming the tendon and the value. Schedules and constants run on the compiled engine
        (with the tendons' exact stiffness in the implicit methods' Jacobian); a controller
        runs on the Python steppers. The samples' tensions are ``Trajectory.tension``.

    Every argument is checked where it enters, each error naming it, the value and the bound
    (docs/simulation.md); callbacks get their own copies of the state.

    Returns
    -------
    Trajectory
        ``t (N,)``, ``q (N, nq)``, ``v (N, nv)``, ``p (N, 3 n)``, energies, ``success``,
        ``message``, ``nfev``, ``status`` (0 finished, 1 terminal event, -1 failed) and
        ``meta`` (``method``, ``nsteps``, ``njev``, ``events``: list of (name, t)).
    """
    run = _check_arguments(chain, q0, v0, t_span, pressure=pressure, tau=tau, method=method, budget=budget,
                           on_sample=on_sample, env=env, dt=dt, rtol=rtol, atol=atol, max_step=max_step, first_step=first_step,
                           wall_limit=wall_limit, t_eval=t_eval, energies=energies, progress=progress, events=events,
                           controller_rate=controller_rate, tension=tension)
    return _execute(run)


def _execute(run: _Run, base=None) -> Trajectory:
    """Steps 2 and 3 of :func:`simulate`: the checked run ``run`` on the compiled engine or
    :mod:`qchain.sim.python_backend`; ``base``: the chain's packed model without its inputs
    where the caller packed it once (:class:`Runs`)."""
    deadline = None if run.wall_limit is None else _time.perf_counter() + float(run.wall_limit)
    bar = _Progress(run.t0, run.t1, run.progress)
    _announce_dense_jacobians(run)
    m = _choose_backend(run, base)
    traj = _run_compiled(run, m, bar, deadline) if m is not None else python_backend.run(run, bar, deadline)
    _note_contact_steps(run, traj)
    if run.chain.nt:  # the samples' tensions: a schedule's or a controller's at the sample
        traj.tension = np.array([run.Tn_in(t, q, v) for t, q, v in zip(traj.t, traj.q, traj.v)]
                                ).reshape(len(traj.t), run.chain.nt)
    return traj


class Runs:
    """Runs of ``chain`` over ``t_span`` that share every setting but the start and the inputs
    (:func:`qchain.batch.simulate_batch`'s rollouts): :func:`simulate`'s checks of the shared
    settings and the packing of the model done once, by the caller, and each :meth:`run` bit
    for bit what :func:`simulate` gives with the same arguments.

    Parameters
    ----------
    chain : Chain
    t_span : (t0, t1) s, checked (:func:`check_run`)
    method : str
        One of :data:`METHODS`.
    budget : Budget
        Already checked against the cost of every run the caller will make (their inputs'
        fastest sine included); an explicit method's stability limit is checked at each run's
        start, as :func:`simulate` does.
    **settings
        :func:`check_settings`' output without ``progress`` and ``events`` (``dt``, ``rtol``,
        ``atol``, ``max_step``, ``first_step``, ``wall_limit``, ``t_eval``, ``energies``,
        ``controller_rate``). Safe to share between threads (nothing here is written by a run).
    """

    def __init__(self, chain: Chain, t_span: tuple[float, float], *, method: str, budget: Budget, **settings):
        t0, t1 = t_span
        self.template = _Run(chain=chain, q0=None, v0=None, t0=t0, t1=t1, method=method, pressure=None, tau=None,
                             on_sample=None, budget=budget, progress=False, events=[], batch=driver.Batch(),
                             **settings)
        # the inputs are packed at each run, into this model of the chain (None: the Python backend serves it)
        self.base = packing.pack(chain, None, None) if method in COMPILED else None

    def starts_finite(self, Q: np.ndarray, V: np.ndarray) -> np.ndarray | None:
        """``(B,) bool``: whether each start ``(Q[i] (nq,), V[i] (nv,))``, checked without its
        energies (:func:`_check_start`), has finite energies at ``t0``, in one compiled pass;
        None without the compiled engine (or its energies' pass, where the runs compute no energies). A start
        whose energies are not finite is checked again in Python by
        its :meth:`run`, which raises :func:`simulate`'s error for it."""
        if self.base is None or not (self.template.energies or len(system.energies_batch.overloads)):
            return None  # (runs without energies do not load or compile their pass for this)
        from .engine import warmup

        wk = system.workspace(self.template.chain, self.base)
        warmup.prepare_energies(self.base, wk)
        B = Q.shape[0]
        ke, pe = np.empty(B), np.empty(B)
        system.energies_batch(self.base, wk, np.full(B, self.template.t0), np.ascontiguousarray(Q, dtype=float),
                              np.ascontiguousarray(V, dtype=float), ke, pe)
        return np.isfinite(ke) & np.isfinite(pe)

    def run(self, q0: np.ndarray, v0: np.ndarray, *, pressure=None, tau=None, tension=None, events=(),
            start_finite: bool = False, inputs_checked: bool = False) -> Trajectory:
        """:func:`simulate` from ``(q0 (nq,), v0 (nv,))``, a start checked without its energies
        (:func:`_check_start` with ``energies=False``: float arrays), with these inputs and
        ``events`` (fresh: a run's inputs and events are its own). ``start_finite``: its
        energies are known finite (:meth:`starts_finite`); otherwise they are checked here,
        in Python, as :func:`simulate` does. ``inputs_checked``: the caller checked the
        inputs (:func:`qchain.sim.inputs.as_input`), so schedules of
        :data:`qchain.sim.inputs.BUILT_IN` are not checked again."""
        tpl = self.template
        if not start_finite:
            _check_start(tpl.chain, q0, v0, tpl.t0)
        run = dataclasses.replace(tpl, q0=q0, v0=v0, pressure=pressure, tau=tau, tension=tension, events=list(events),
                                  held=[])
        return _execute(_with_inputs(run, inputs_checked), self.base)


def _logged_tension(controllers: list, slot: np.ndarray) -> tuple[list, Callable]:
    """``controllers`` with the tension controller's holds logged, and ``(t, q, v) -> (nt,)``
    the tension held at ``t`` (the last hold at or before ``t``, a sample at a hold's
    instant showing the new one, as the driver's pressures do): the tensions of the run's
    samples, which the compiled steppers do not record."""
    times: list[float] = []
    values: list[np.ndarray] = []

    def logged(fn):
        def hold(t, q, v):
            out = fn(t, q, v)
            times.append(t)
            values.append(np.array(out, dtype=float))
            return out
        return hold

    def held_at(t, q, v):
        k = int(np.searchsorted(times, t + 1e-12 * max(1.0, abs(t)), side="right")) - 1
        return values[max(k, 0)].copy()

    return [(logged(fn), s) if s is slot else (fn, s) for fn, s in controllers], held_at


def _note_contact_steps(run: _Run, traj: Trajectory) -> None:
    """Say in ``traj.meta`` whether the contact's time scale limited the steps:
    ``contact_time_scale`` (s, :meth:`qchain.contact.Environment.time_scale`) and
    ``step_limited_by_contact``: an explicit method's run in which the arm touched an obstacle
    (at any evaluation on the compiled engine, ``meta["max_active_contacts"] > 0``; at one of
    up to 200 samples on the Python backend) and the mean step was below a quarter of that time scale
    (explicit steps are bounded by it for stability; an implicit method's steps follow the
    tolerance, and its flag is False)."""
    if run.env is None or not run.env.obstacles:
        return
    T = run.env.time_scale(run.chain)
    traj.meta["contact_time_scale"] = T
    steps = traj.meta.get("nsteps") or 0
    span = (traj.t[-1] - run.t0) if len(traj.t) else 0.0
    if "max_active_contacts" in traj.meta:  # the compiled engine counted them at every evaluation
        touched = traj.meta["max_active_contacts"] > 0
    else:
        picks = np.unique(np.linspace(0, len(traj.t) - 1, min(len(traj.t), 200)).astype(int)) if len(traj.t) else []
        touched = any(len(run.chain.contacts(traj.q[k], traj.v[k], run.env, traj.t[k]).segment) for k in picks)
    explicit = run.method not in JACOBIAN_METHODS
    traj.meta["step_limited_by_contact"] = bool(explicit and touched and steps and span / steps < 0.25 * T)


def check_method(method) -> str:
    """``method`` if it is one of :data:`METHODS`, matched exactly (case included: ``"radau"``
    is neither ``"radau5"`` nor ``"Radau"``, methods an order of magnitude apart in speed).

    Raises
    ------
    ValueError
        Naming the argument and the value, and the close names among :data:`METHODS`
        (:func:`difflib.get_close_matches`, case ignored), the compiled ones first, each
        said to be compiled or scipy's: ``method must be one of (...), got 'radau': did you
        mean 'radau5' (compiled) or 'Radau' (scipy's)?``
    """
    if isinstance(method, str) and method in METHODS:
        return method
    hint = ""
    if isinstance(method, str) and len(method) < 100:
        by_lower = {m.lower(): m for m in METHODS}
        close = [by_lower[c] for c in difflib.get_close_matches(method.lower(), list(by_lower), n=3)]
        close.sort(key=lambda m: m not in COMPILED)  # stable: by closeness within each kind
        kind = {m: "compiled" if m in COMPILED else "scipy's" for m in close}
        names = [f"{m!r} ({kind[m]})" for m in close]
        if names:
            hint = ": did you mean " + (names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]) + "?"
    raise ValueError(f"method must be one of {METHODS}, got {method!r}{hint}")


@dataclass
class _Run:
    """A run's arguments as :func:`simulate` checked them (floats, ``t_eval (K,)`` s a float
    array, ``events`` a list, ``budget`` a :class:`Budget`), and what they make: the inputs as
    functions ``P_in(t, q, v) -> (3 n,) Pa``, ``T_in(t, q, v) -> (nv,)``, and ``held``, the
    controllers sampled at ``controller_rate``: ``(name, input, size)`` each."""

    chain: Chain
    q0: np.ndarray
    v0: np.ndarray
    t0: float
    t1: float
    method: str
    pressure: object
    tau: object
    on_sample: Callable | None
    budget: Budget
    dt: float | None
    rtol: float
    atol: float
    max_step: float
    first_step: float | None
    wall_limit: float | None
    t_eval: np.ndarray | None
    energies: bool
    progress: bool | str
    events: list
    controller_rate: float | None
    env: object = None
    tension: object = None
    P_in: Callable | None = None
    T_in: Callable | None = None
    Tn_in: Callable | None = None
    held: list = field(default_factory=list)
    #: what the runs of a batch share on the compiled engine (:class:`Runs`), or None
    batch: driver.Batch | None = None

    def cost(self, stable_step: float | None = None):
        """The run's :class:`qchain.sim.budget.Cost` (:func:`run_cost_of`), with an explicit
        method's stability limit ``stable_step`` (s) if given."""
        return run_cost_of(self.chain, self.t0, self.t1, method=self.method, dt=self.dt, max_step=self.max_step,
                           t_eval=self.t_eval, inputs=(self.pressure, self.tau), controller_rate=self.controller_rate,
                           stable_step=stable_step)


def _check_arguments(chain, q0, v0, t_span, *, pressure, tau, method, budget, on_sample, env=None, tension=None,
                     **settings) -> _Run:
    """Step 1 of :func:`simulate`: check its arguments (as :func:`simulate`'s; ``**settings``
    by :func:`check_settings`) where they enter, in a fixed order (the first bad one is the one
    said), and the run's cost against the budget before it starts."""
    t0, t1 = check_run(chain, method, t_span)
    q0, v0 = _check_start(chain, q0, v0, t0)
    cfg = check_settings(chain, t0, t1, method=method, on_sample=on_sample, **settings)
    run = _Run(chain=chain, q0=q0, v0=v0, t0=t0, t1=t1, method=method, pressure=pressure, tau=tau,
               on_sample=on_sample, budget=as_budget(budget), env=_check_env(chain, env), tension=tension, **cfg)
    run.budget.check(run.cost())
    return _with_inputs(run)


def _with_inputs(run: _Run, checked: bool = False) -> _Run:
    """``run`` with its inputs as functions (``P_in``, ``T_in``, ``held``), checked (but
    :data:`qchain.sim.inputs.BUILT_IN` schedules where the caller ``checked`` them), and an
    explicit method's stability limit at its start against its budget (the rest of its cost
    checked)."""
    chain, method, pressure, tau, q0, v0, t0 = run.chain, run.method, run.pressure, run.tau, run.q0, run.v0, run.t0
    run.P_in, run.T_in = (_input_function(name, u, size, checked) for name, u, size in  # checked here
                          (("pressure", pressure, chain.nu), ("tau", tau, chain.nv)))
    if run.tension is not None and not chain.nt:
        raise ValueError("tension is given but the chain has no tendons (Chain(..., tendons=[...]))")
    run.Tn_in = _input_function("tension", run.tension, chain.nt, False)  # checked: >= 0 (TENSION)
    if method in driver.EXPLICIT_STABILITY_EXTENT:  # a stiff model: refused before hours of tiny steps
        run.budget.check(run.cost(explicit_stability_limit(chain, method, q0, v0, t0, pressure, tau)))
    if run.controller_rate is not None:
        for name, u, size in (("pressure", pressure, chain.nu), ("tau", tau, chain.nv), ("tension", run.tension, chain.nt)):
            if callable(u) and not isinstance(u, Schedule):
                run.held.append((name, run.Tn_in if name == "tension" else as_input(name, u, size), size))
        if not run.held:
            raise ValueError("controller_rate is given but none of pressure, tau and tension is a controller "
                             "(t, q, v) -> array")
    return run


def _input_function(name: str, u, size: int, checked: bool) -> Callable:
    """:func:`as_input`, or, for a built-in schedule the caller ``checked`` (its size and its
    extent within bounds), the same function without checking it again."""
    if checked and type(u) in BUILT_IN:
        return lambda t, q, v: u(t)
    return as_input(name, u, size)


def _check_start(chain: Chain, q0, v0, t0: float, names=("q0", "v0"), energies: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The initial state ``q0 (nq,)``, ``v0 (nv,)`` as float arrays (called ``names`` in
    errors), checked inside the model at ``t0`` (s): its locks held, and with ``energies`` its
    energies finite and a paper-coordinate start not singular; each error names the segment
    and the coordinate."""
    q0 = chain._q(q0, names[0])
    v0 = as_vector(names[1], v0, chain.nv)
    st = chain._state(q0, v0, t=t0)  # raises at the input if the start is outside the model
    if chain._any_locked:
        chain._check_locks(st.q_e, st.v_e)
    if not energies:
        return q0, v0
    if not _energies_bounded(chain, q0, v0):
        chain.kinetic_energy(q0, v0, t=t0)  # NonFiniteError naming the segment if the start overflows
        chain.potential_energy(q0, t=t0)
    if any(s.coords == "paper" for s in chain.segments):  # a singular start (kappa = 0) is said here, by name
        chain.forward_dynamics(q0, v0, np.zeros(chain.nu), t=t0)
    return q0, v0


#: |q| and |v| entries (SI units) within which a start's energies are finite for every chain
#: whose parameters are within their bounds (:mod:`qchain.checks.bounds`; a segment's
#: ``stiffness_matrix``, which has none, excepted) and every configuration in the model's domain:
#: at the box's corners, with every parameter at its bound, they stay below 1e72 J
#: (``tests/test_simulate.py``). :func:`_check_start` computes them, to name the segment whose
#: energy overflows, only for a start outside it (a tenth of a short run's cost).
ENERGY_BOX = 1e15


def _energies_bounded(chain: Chain, q0: np.ndarray, v0: np.ndarray) -> bool:
    """Whether the start ``(q0 (nq,), v0 (nv,))``, inside the model's domain, lies within
    :data:`ENERGY_BOX` on a chain whose energies it bounds."""
    return (max(float(np.max(np.abs(q0), initial=0.0)), float(np.max(np.abs(v0), initial=0.0))) <= ENERGY_BOX
            and all(s.stiffness_matrix is None for s in chain.segments))


def _announce_dense_jacobians(run: _Run) -> None:
    """With a progress display, say on stderr that a method forming the exact Jacobian on
    more than :data:`qchain.sim.engine.driver.STABILITY_MAX_NV` free coordinates is slow
    (each Jacobian dense ``nv x nv`` work, O(nv^3)) before the first step is taken."""
    n_free = int(np.count_nonzero(run.chain.active))
    if run.progress and run.method in JACOBIAN_METHODS and n_free > driver.STABILITY_MAX_NV:
        sys.stderr.write(f"qchain: {run.method} on {n_free} free coordinates: each exact Jacobian is dense "
                         f"{run.chain.nv} x {run.chain.nv} work, O(nv^3) (seconds to minutes each for nv in the "
                         "thousands, docs/engine.md); progress is shown after each step\n")
        sys.stderr.flush()


def _check_env(chain: Chain, env):
    """``env``: None or a :class:`qchain.contact.Environment` that fits ``chain``."""
    if env is None:
        return None
    from ..contact.environment import Environment

    if not isinstance(env, Environment):
        raise TypeError(f"env must be a qchain.contact.Environment, got {type(env).__name__}")
    env.check_segments(chain.n)
    return env


def _choose_backend(run: _Run, base=None):
    """Step 2 of :func:`simulate`: the compiled engine's packed model
    (:func:`qchain.sim.engine.packing.pack`, or ``base``, the chain's packed once, with the
    run's inputs: :func:`qchain.sim.engine.packing.with_inputs`) where it serves the run, else
    None for :mod:`qchain.sim.python_backend` (``ValueError`` then if ``controller_rate`` is
    given). A held controller is packed as zeros (its output is written into the packed model
    at its instants)."""
    if run.method not in COMPILED:
        if run.controller_rate is not None:
            raise ValueError(f"controller_rate needs the compiled engine; method {run.method!r} is scipy's, on the "
                             f"Python backend (use one of {COMPILED})")
        return None
    zeros = {name: np.zeros(size) for name, _, size in run.held}
    p, tau, tn = zeros.get("pressure", run.pressure), zeros.get("tau", run.tau), zeros.get("tension", run.tension)
    m = (packing.pack(run.chain, p, tau, run.env, tn) if base is None else
         packing.with_inputs(base, run.chain, p, tau, tn))
    if m is not None:
        return m
    reason = packing.python_reason(run.chain, p, tau, tn)
    if run.controller_rate is not None:
        raise ValueError(f"controller_rate needs the compiled engine, which cannot serve this run: {reason}")
    # never silently: the Python steppers are one to two orders of magnitude slower
    warnings.warn(PythonBackendWarning(f"simulate: method {run.method!r} runs on the Python backend, not the "
                                       f"compiled engine: {reason}"), stacklevel=4)
    return None


def _run_compiled(run: _Run, m, bar: _Progress, deadline: float | None) -> Trajectory:
    """Step 3 of :func:`simulate` on the compiled engine (:func:`qchain.sim.engine.driver.run`,
    which builds the :class:`Trajectory`): the packed model ``m`` (:func:`_choose_backend`), the
    held controllers written into its input slots at their instants, samples' inputs read from
    those slots; ``deadline``: ``time.perf_counter()`` (s) at which the run stops."""
    p_of, tau_of = run.P_in, run.T_in
    controllers = []
    if run.controller_rate is not None:
        slots = {"pressure": m.p_params, "tau": m.tau_params, "tension": m.tn_params}
        controllers = [(fn, slots[name]) for name, fn, _ in run.held]
        if any(name == "tension" for name, _, _ in run.held):  # the samples' tensions: the hold at their time
            controllers, run.Tn_in = _logged_tension(controllers, slots["tension"])
        # a sample's input is the held output, not another call of the controller
        held = {name: (lambda t, q, v, slot=slots[name]: slot.copy()) for name, _, _ in run.held}
        p_of, tau_of = held.get("pressure", p_of), held.get("tau", tau_of)
    try:
        traj = driver.run(run.chain, m, run.method, run.q0, run.v0, run.t0, run.t1, dt=run.dt, rtol=run.rtol,
                          atol=run.atol, t_eval=run.t_eval, on_sample=run.on_sample,
                          pass_energies=python_backend.takes_energies(run.on_sample, run.energies),
                          events=run.events, bar=bar if run.progress else None, max_step=run.max_step,
                          first_step=run.first_step, energies=run.energies, deadline=deadline,
                          controllers=controllers, controller_rate=run.controller_rate,
                          inputs=lambda t, q, v: (p_of(t, q, v), tau_of(t, q, v)),
                          max_total_steps=run.budget.max_steps, batch=run.batch)
    except driver.Interrupted as err:
        bar.close(err.trajectory.t[-1] if len(err.trajectory.t) else run.t0)
        raise
    bar.close(traj.t[-1] if len(traj.t) else run.t0)
    return traj
