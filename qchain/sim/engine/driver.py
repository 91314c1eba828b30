"""The one driver loop of the compiled engine: Python between stretches of compiled steps.

:func:`run` calls a stepper's ``advance`` (:mod:`qchain.sim.engine.steppers`) and between calls
does only what must be Python (docs/engine.md); a call otherwise runs a stretch sized to
take about :data:`STRETCH` s of wall time, so Ctrl-C is felt promptly. A stretch releases
Python's lock (:data:`qchain._jit.ejit`): runs in other threads go on meanwhile, and a run in
a thread stops between stretches when the event :func:`stop_on` set for that thread is set.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import signal
import sys
import threading
import time as _time

import numpy as np

from ..._jit import first_class_functions
from ...errors import QchainError
from ..trajectory import Trajectory
from . import steppers, system, warmup
from .steppers import AT_STOP, FAILED, STEPS

__all__ = ["run", "Interrupted", "STRETCH", "stop_on", "start_integrator"]

STRETCH = 0.05  #: s of wall time a compiled stretch aims at between looks from Python


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a run: carries the trajectory recorded so far (``.trajectory``)."""

    def __init__(self, trajectory: Trajectory):
        super().__init__("interrupted")
        self.trajectory = trajectory


_thread = threading.local()  # .stop: the event that interrupts this thread's runs (stop_on)


@contextlib.contextmanager
def stop_on(event: threading.Event):
    """A context in which this thread's runs stop at their next look from Python (within a
    stretch, about :data:`STRETCH` s) once ``event`` is set, as at Ctrl-C: :class:`Interrupted`
    with the trajectory so far. For runs on a thread of a pool, where Ctrl-C reaches only the
    main thread."""
    before = getattr(_thread, "stop", None)
    _thread.stop = event
    try:
        yield
    finally:
        _thread.stop = before


@contextlib.contextmanager
def sigint_between_calls():
    """A context in which Ctrl-C is taken between compiled calls, not inside one: yields an
    event set at SIGINT (``None`` off the main thread, or where SIGINT has no Python
    handler), for the caller to raise ``KeyboardInterrupt`` at its next look from Python.

    Python's SIGINT handler raises at the next bytecode, and numba runs Python while it
    unboxes a compiled call's arguments (a signature unpickled, a wrapper's address asked
    for): an interrupt there ends the call with an unrelated ``TypeError`` instead of
    ``KeyboardInterrupt``. Here the handler that was in place still runs (a command's
    count of Ctrl-C), its ``KeyboardInterrupt`` held back until the caller's look."""
    if threading.current_thread() is not threading.main_thread():
        yield None
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # SIG_IGN, SIG_DFL, or a handler not installed from Python
        yield None
        return
    event = threading.Event()

    def held(signum, frame):
        try:
            previous(signum, frame)
        except KeyboardInterrupt:
            event.set()

    signal.signal(signal.SIGINT, held)
    try:
        yield event
    finally:
        signal.signal(signal.SIGINT, previous)


class _Outputs:
    """Sample buffers the compiled steps write: ``t (K,)``, ``q (K, nq)``, ``v (K, nv)``, ``p (K, nu)``."""

    def __init__(self, chain, t_eval: np.ndarray | None, guess: int):
        self.every = t_eval is None
        K = guess if self.every else t_eval.size
        self.t = np.zeros(K) if self.every else np.array(t_eval, dtype=float)  # never the caller's t_eval
        self.q = np.zeros((K, chain.nq))
        self.v = np.zeros((K, chain.nv))
        self.p = np.zeros((K, chain.nu))

    @property
    def arrays(self):
        return (self.t, self.q, self.v, self.p)

    def grow(self):
        K = self.t.size
        for name in ("t", "q", "v", "p"):
            a = getattr(self, name)
            b = np.zeros((2 * K,) + a.shape[1:])
            b[:K] = a
            setattr(self, name, b)


class Batch:
    """What the runs of a batch share (:class:`qchain.sim.simulation.Runs`, on any number of
    threads): the engine :func:`warmup.prepare` made ready for one of them, reused by every
    later run whose inputs have the same types (the rest of a batch's arguments are made
    alike by the same code: the chain's packed model, the workspaces, the outputs on one
    grid), so the argument types are fingerprinted once a batch, not once a run; and the
    stretch size (steps a compiled call) the last run reached, where the next one starts
    instead of at one step. Neither changes a result: the stepper's state lives in its
    arrays, whatever the stretches."""

    def __init__(self):
        #: (the inputs' fingerprint, callbacks, compiled stepper), set as one tuple: threads read it
        self.ready: tuple | None = None
        self.stretch = 1


def _inputs_fingerprint(m) -> tuple:
    """The types of the packed model's input arrays, the fields
    :func:`qchain.sim.engine.packing.with_inputs` replaces run by run."""
    return tuple((a.dtype.num, a.ndim, a.flags.num) for a in (m.p_ints, m.p_params, m.tau_ints, m.tau_params))


def run(*args, **kw) -> Trajectory:
    """:func:`_run`, with numba's warning that first-class functions are experimental (which it
    gives at every call of the engine) silenced for the run: not the user's concern, and a
    ``warnings.simplefilter("error")`` would stop every run on it."""
    with first_class_functions():
        return _run(*args, **kw)


def _run(chain, m, method, q0, v0, t0, t1, *, dt, rtol, atol, t_eval, on_sample, pass_energies, events, bar,
         max_step, first_step, energies, deadline, controllers, controller_rate, inputs,
         max_total_steps: int | None = None, batch: Batch | None = None) -> Trajectory:
    """Integrate from ``(q0, v0)`` at ``t0`` to ``t1`` on the compiled engine (arguments as
    :func:`qchain.simulate`'s, validated there; ``m`` from :func:`qchain.sim.engine.packing.pack`;
    ``controllers``: ``[(callable (t, q, v) -> (size,), params array to hold it in)]``;
    ``inputs``: ``(t, q, v) -> (p, tau)`` in Python, for the samples Python writes (the first,
    one at a controller instant or a terminal event) and the stability limit);
    ``max_total_steps``: the budget's ``max_steps`` (docs/simulation.md); ``batch``: what the
    runs of a batch share (:class:`Batch`)."""
    idx = m.idx
    nA = idx.size
    c = steppers.constants(method)
    fixed = method in ("rk4", "midpoint")
    wk = system.workspace(chain, m)
    it = steppers.integrator(nA, chain.nq)
    y, tf, cnt = it.y, it.tf, it.cnt
    wk.q_chart[:] = q0
    y[nA:] = v0[idx]
    start_integrator(it, method, t0, t1, dt=dt, rtol=rtol, atol=atol, max_step=max_step, first_step=first_step)
    out = _Outputs(chain, t_eval, guess=int(min((t1 - t0) / dt + 2, 1 << 16)) if fixed and t_eval is None else 1024)
    if out.every:
        cnt[steppers.EVERY] = 1
    t_prep = _time.perf_counter()
    sample_energies = on_sample is not None and pass_energies
    ready = batch.ready if batch is not None and not sample_energies else None
    fp = None if batch is None else _inputs_fingerprint(m)
    if ready is not None and ready[0] == fp:
        fs, advance = ready[1:]
    else:
        fs, advance = warmup.prepare(method, m, wk, it, out.arrays, c, energies=sample_energies)
        if batch is not None:
            batch.ready = fp, fs, advance
    compile_s = _time.perf_counter() - t_prep
    hold_times = _hold_times(controllers, controller_rate, t0, t1)
    n_hold = 0

    def hold(t, q, v):
        for fn, params in controllers:
            params[:] = fn(t, q, v)

    # the samples at the start
    k = 0
    if controllers:
        hold(t0, q0, v0)
    p0 = inputs(t0, q0, v0)[0]
    while k < out.t.size and (out.every and k == 0 or not out.every and out.t[k] <= t0):
        if out.every:
            out.t[0] = t0
        out.q[k], out.v[k], out.p[k] = q0, v0, p0
        k += 1
    cnt[steppers.K_OUT] = k
    status, message = 0, "The end of the time span was reached."
    ev_log: list[tuple[str, float]] = []
    g_prev = [e(t0, q0, v0) for e in events]
    emitted = 0
    stop = getattr(_thread, "stop", None)
    # grows by 4x a stretch to STRETCH s: a costly step (a large implicit model) is felt at once
    max_steps = 1 if batch is None else batch.stretch
    t = t0
    if on_sample is not None and pass_energies:  # the samples' energies are needed as they come
        compile_s += warmup.prepare_energies(m, wk)
    elif getattr(on_sample, "record_batch", None) is not None:  # a batch taker records them
        pass_energies = True
        compile_s += warmup.prepare_energies(m, wk)
    try:
        with sigint_between_calls() as sigint:
            emitted = _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk)
            while True:
                t_stop = hold_times[n_hold] if n_hold < hold_times.size else t1
                max_out = _max_out(out, cnt, t, on_sample)
                steps = 1 if events else max_steps
                if max_total_steps is not None and not fixed:
                    taken = int(cnt[steppers.NSTEPS]) + int(cnt[steppers.NREJECT])
                    if taken >= max_total_steps:
                        status = -1
                        message = step_budget_message(max_total_steps, f"{taken} steps taken ({int(cnt[steppers.NSTEPS])} "
                                                      f"accepted, {int(cnt[steppers.NREJECT])} rejected)", t, t1, method)
                        break
                    steps = min(steps, max_total_steps - taken)
                w0 = _time.perf_counter()
                code = advance(fs, m, wk, it, out.arrays, c, t_stop, max_out, steps)
                wall = _time.perf_counter() - w0
                if code == STEPS and not events:  # size the next stretch to about STRETCH s
                    max_steps = int(min(max(max_steps * min(4.0, STRETCH / max(wall, 1e-6)), 1), 1 << 20))
                t = tf[steppers.T]
                if code == FAILED:
                    w0 = _time.perf_counter()  # (rk4's stability limit: the exact derivatives, compiled at their first use)
                    status, message = -1, _failure(chain, wk, it, method, q0, v0, t0, inputs)
                    compile_s += _time.perf_counter() - w0
                    emitted = _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk)
                    break
                if events and cnt[steppers.DENSE_OK]:
                    hit = _events(events, g_prev, ev_log, method, chain, m, wk, it, c)
                    if hit is not None:
                        _cut(out, cnt, hit, method, chain, m, wk, it, c, inputs)
                        emitted = _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk)
                        status, message = 1, f"A termination event occurred at t = {hit:.6g} s."
                        t = hit
                        break
                emitted = _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk)
                if out.every and cnt[steppers.K_OUT] == out.t.size:
                    out.grow()
                if bar is not None:
                    bar.update(t)
                if deadline is not None and _time.perf_counter() > deadline:
                    status, message = -1, f"wall-clock limit reached at t = {t:.6g} s"
                    break
                if stop is not None and stop.is_set() or sigint is not None and sigint.is_set():
                    raise KeyboardInterrupt
                if code == AT_STOP:
                    if t >= t1:
                        break
                    q, v = state(chain, m.idx, wk.q_chart, y)
                    hold(t, q, v)
                    n_hold += 1
                    for r in range(cnt[steppers.K_OUT] - 1, -1, -1):  # a sample at the instant shows the new hold
                        if abs(out.t[r] - t) > 1e-12 * max(1.0, abs(t)):
                            break
                        out.p[r] = inputs(t, q, v)[0]
                del code
            if sigint is not None and sigint.is_set():  # Ctrl-C in the last stretch
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        if getattr(on_sample, "record_batch", None) is not None:  # the samples it had not taken yet
            _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk)
        traj = _trajectory(chain, m, wk, out, cnt, -1, f"interrupted by the user at t = {t:.6g} s", energies, method,
                           ev_log)
        traj.meta["compile_s"] = compile_s
        raise Interrupted(traj) from None
    if batch is not None:
        batch.stretch = max_steps
    traj = _trajectory(chain, m, wk, out, cnt, status, message, energies, method, ev_log)
    traj.meta["compile_s"] = compile_s  # compiling or loading: a caller's wall time less this is the run's
    return traj


def start_integrator(it, method: str, t0: float, t1: float, *, dt, rtol: float, atol: float, max_step: float,
                     first_step: float | None) -> None:
    """Set the floats of a fresh integrator ``it`` (:func:`steppers.integrator`) for a run of
    ``method`` over ``(t0, t1)`` s with these settings (as :func:`qchain.simulate` checked
    them): the time, the fixed step, the tolerances, the first step and Newton's tolerance. The
    state ``it.y`` is the caller's (the start's velocities; ``delta = 0``)."""
    tf = it.tf
    tf[steppers.T] = tf[steppers.T0] = t0
    tf[steppers.DT] = dt if method in ("rk4", "midpoint") else 0.0
    tf[steppers.RTOL], tf[steppers.ATOL] = rtol, atol
    tf[steppers.MAX_STEP] = max_step
    h0 = first_step if first_step is not None else min(1e-4, (t1 - t0) / 10)
    # well above the steppers' floor, 10 float64 spacings of t (coarse at large t: 1.2e-4 s at
    # 1e12 s), where a first step's rejections would take it under the floor
    tf[steppers.H] = h0 if first_step is not None else \
        max(h0, min(1000.0 * float(np.spacing(max(abs(t0), abs(t1)))), (t1 - t0) / 4))
    tf[steppers.NEWTON_TOL] = max(10 * steppers.EPS / rtol, min(0.03, rtol**0.5))


def step_budget_message(max_steps: int, taken: str, t: float, t1: float, method: str) -> str:
    """A run stopped at ``budget.max_steps`` (``taken``: the steps, in words), and what to try
    by its method: an explicit one on a stiff model wants radau5; otherwise a larger budget,
    or longer intervals (``max_step``, ``controller_rate``) than those that cut its steps."""
    if method in EXPLICIT_STABILITY_EXTENT:
        hint = "the model is probably stiff: use method='radau5' (or raise budget.max_steps)"
    else:
        hint = "raise budget.max_steps (rejected steps count), or give max_step / controller_rate a longer interval"
    return (f"step budget exceeded: budget.max_steps = {max_steps}, {taken}, t reached = {t:.6g} s of {t1:.6g} s "
            f"with method {method!r}; {hint}")


def _hold_times(controllers, rate, t0, t1) -> np.ndarray:
    """The controller's sampling instants after ``t0`` and before ``t1`` (s)."""
    if not controllers:
        return np.zeros(0)
    n = int(np.floor((t1 - t0) * rate * (1 + 1e-12)))
    ts = t0 + np.arange(n + 1) / rate
    return ts[(ts > t0) & (ts < t1 - 1e-12 * max(1.0, abs(t1)))]


def _max_out(out, cnt, t, on_sample) -> int:
    """How many samples a compiled stretch may write before Python takes them: one for an
    ``on_sample`` called sample by sample; for one that takes batches (``record_batch``),
    the samples within its ``max_sim`` s of simulated time (what it may hold back at most,
    so a killed run loses no more); all that fit otherwise."""
    k = int(cnt[steppers.K_OUT])
    if on_sample is None:
        return out.t.size - k if out.every else 1 << 30
    if getattr(on_sample, "record_batch", None) is None or out.every:
        return 1
    max_sim = float(getattr(on_sample, "max_sim", 0.0))  # checked where on_sample enters (check_settings)
    # from the first sample not handed over yet: the last step may have passed samples before t
    t_first = out.t[k] if k < out.t.size else t
    return max(1, int(np.searchsorted(out.t, t_first + max_sim, side="left")) - k)


@functools.lru_cache(maxsize=32)
def _trusts_states(taker: type) -> bool:
    """Whether a batch taker's ``record_batch`` takes ``skip_checks`` (the engine's states
    were checked at every step: it need not check them again)."""
    try:
        return "skip_checks" in inspect.signature(taker.record_batch).parameters
    except (TypeError, ValueError, AttributeError):
        return False


def _hand_over(out, emitted, cnt, on_sample, pass_energies, m, wk) -> int:
    """Give the samples written since the last call to ``on_sample`` (in one
    ``on_sample.record_batch(t, q, v, p, kinetic, potential)`` call where it has one, with
    the energies of one compiled pass, prepared before the run); returns the new count."""
    k = int(cnt[steppers.K_OUT])
    batch = getattr(on_sample, "record_batch", None)
    if batch is not None and k > emitted:
        ke, pe = np.empty(k - emitted), np.empty(k - emitted)
        system.energies_batch(m, wk, out.t[emitted:k], out.q[emitted:k], out.v[emitted:k], ke, pe)
        # views of the run's own samples (no copy), read-only: a taker cannot change the results
        views = [_read_only(a[emitted:k]) for a in out.arrays] + [ke, pe]
        if _trusts_states(type(on_sample)):
            batch(*views, skip_checks=True)
        else:
            batch(*views)
    elif on_sample is not None:
        ke, pe = np.zeros(1), np.zeros(1)
        for r in range(emitted, k):
            if pass_energies:
                system.energies_batch(m, wk, out.t[r : r + 1], out.q[r : r + 1], out.v[r : r + 1], ke, pe)
                on_sample(out.t[r], out.q[r].copy(), out.v[r].copy(), out.p[r].copy(), energies=(ke[0], pe[0]))
            else:
                on_sample(out.t[r], out.q[r].copy(), out.v[r].copy(), out.p[r].copy())
    return k


def _read_only(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def state(chain, idx, q_chart, y):
    """``(q, v)`` of the state ``y = (delta, v)`` over the free coordinates ``idx`` in the
    chart at ``q_chart`` (Python's :func:`system.configuration`)."""
    nA = idx.size
    v = np.zeros(chain.nv)
    v[idx] = y[nA:]
    if chain.floating:
        delta = np.zeros(chain.nv)
        delta[idx] = y[:nA]
        return chain.integrate(q_chart, delta), v
    q = q_chart.copy()
    q[idx] += y[:nA]
    return q, v


def _state_at(method, chain, m, it, c, s):
    """``(q, v)`` at time ``s`` in the last step (its dense output)."""
    ys = it.tmp[steppers.Y_OUT]
    steppers.dense(steppers.CODES[method], it, c, s, ys)
    return state(chain, m.idx, it.qc, ys)


def crossings(events, g_prev, log, ta, tb, state_at):
    """Sign changes of the events over ``[ta, tb]`` (s), root-found on the state at a time,
    ``state_at(s) -> (q, v)``: ``g_prev`` (their values at ``ta``) updated to ``tb``, ``log``
    given ``(name, t s)`` of each crossing; returns the first terminal event's time or None."""
    from scipy.optimize import brentq

    hit = None
    for kk, e in enumerate(events):
        gb = e(tb, *state_at(tb))
        ga = g_prev[kk]
        g_prev[kk] = gb
        if (ga < 0 <= gb and e.direction >= 0) or (ga > 0 >= gb and e.direction <= 0):
            te = brentq(lambda s: e(s, *state_at(s)), ta, tb, xtol=1e-12 * max(1.0, abs(tb)))
            log.append((e.name, te))
            if e.terminal and (hit is None or te < hit):
                hit = te
    return hit


def _events(events, g_prev, ev_log, method, chain, m, wk, it, c):
    """:func:`crossings` over the last step, on its dense output."""
    return crossings(events, g_prev, ev_log, it.tf[steppers.T_OLD], it.tf[steppers.T],
                     lambda s: _state_at(method, chain, m, it, c, s))


def _cut(out, cnt, hit, method, chain, m, wk, it, c, inputs):
    """End the recording at a terminal event: drop samples after it; in every-step mode the
    last sample becomes the event's state."""
    k = int(cnt[steppers.K_OUT])
    while k > 0 and out.t[k - 1] > hit:
        k -= 1
    if out.every:
        q, v = _state_at(method, chain, m, it, c, hit)
        if k > 0 and abs(out.t[k - 1] - hit) <= 1e-12 * max(1.0, abs(hit)):
            k -= 1  # the event is at a step's end, already a sample: that sample, not a second one
        out.t[k], out.q[k], out.v[k], out.p[k] = hit, q, v, inputs(hit, q, v)[0]
        k += 1
    cnt[steppers.K_OUT] = k


def _failure(chain, wk, it, method, q0, v0, t0, inputs) -> str:
    """The message of a failed run: what failed, where and when; for a fixed step above the
    stability limit, that limit."""
    cnt, tf = it.cnt, it.tf
    code = int(cnt[steppers.STATUS])
    t = tf[steppers.T]
    # (T_FAIL is set where the right-hand side failed; a failure found in a step's stage
    # values leaves an earlier, rejected trial's there)
    t_fail = tf[steppers.T_FAIL] if tf[steppers.T_FAIL] >= t else t
    at = f"(at t = {t_fail:.6g} s, in the step from t = {t:.6g} s)"
    q_bad = wk.q.copy()
    if code == system.DOMAIN:
        msg = f"{_outside(chain, wk, q_bad)} {at}"
    elif code == system.SINGULAR:
        n = chain.n
        culprit = chain._overflowing_segment(wk.q[chain.nq - 3 * n :].reshape(n, 3),
                                             wk.v[chain.nv - 3 * n :].reshape(n, 3))
        msg = f"an articulated inertia is not positive definite{f' ({culprit})' if culprit else ''} {at}"
    elif code == system.NONFINITE:
        msg = f"{_nonfinite_what(chain, wk)} {at}"
    elif code == steppers.SAMPLE:
        msg = (f"{_outside(chain, wk, q_bad)} (at t = {tf[steppers.T_FAIL]:.6g} s, an output sample interpolated "
               f"inside the step from t = {tf[steppers.T_OLD]:.6g} s to {t:.6g} s, whose ends are inside the domain: a "
               "smaller rtol or dt keeps the samples inside)")
    elif code == steppers.NEWTON:
        msg = f"{method}: Newton did not converge in the step from t = {t:.6g} s (reduce dt)"
    else:
        floor = 10.0 * float(np.spacing(abs(t)))
        msg = (f"{method}: the step size fell below its floor, 10 float64 spacings of t ({floor:.3g} s), at t = "
               f"{t:.6g} s (the solution may be singular there"
               + ("; or t is so large that its spacing is coarse for this run: shift t_span toward 0)" if floor > 1e-9
                  else ")"))
    if method == "rk4":
        msg = unstable_message(msg, tf[steppers.DT], stability_limit(chain, q0, v0, *inputs(t0, q0, v0), t0))
    return msg


def _outside(chain, wk, q: np.ndarray) -> str:
    """What of the configuration ``q`` (nq,) is outside the model's domain: the chain's own
    error, naming the segment and the bound, or the non-finite entry."""
    if not np.all(np.isfinite(q)):
        return _nonfinite_what(chain, wk)
    try:
        chain._state(q)
    except QchainError as err:
        return str(err)
    return f"segment {int(wk.info[1])} left the model's domain"


def _nonfinite_what(chain, wk) -> str:
    """Which quantity of the last evaluation was not finite, and whose: the configuration
    ``wk.q``, the velocity ``wk.v`` or the acceleration ``wk.a`` (the first entry)."""
    for name, x, vel in (("configuration", wk.q, False), ("velocity", wk.v, True), ("acceleration", wk.a, True)):
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            i = int(bad[0])
            return f"non-finite {name} {'v' if vel else 'q'}[{i}] ({chain.coordinate_name(i, velocity=vel)})"
    return "non-finite state (the integrator's stage values)"


#: RK4 is stable for h |lambda| below about 2.78 on the negative real axis and 2.83 on the
#: imaginary axis; the smaller bound serves every eigenvalue direction of a damped arm.
RK4_STABILITY_RADIUS = 2.78


#: The largest ``|z|`` in each explicit adaptive method's stability region ``|R(z)| <= 1``
#: (its stability polynomial from the tableau, searched over the complex plane; the
#: region's lobes into the right half plane included): no step ``h`` with
#: ``h |lambda| > EXTENT`` is stable for an eigenvalue ``lambda``, so ``EXTENT / max |lambda|``
#: bounds every stable step from above (``tests/test_stability.py`` recomputes them).
EXPLICIT_STABILITY_EXTENT = {"dopri5": 3.99, "RK45": 3.99, "DOP853": 7.13}


#: the most free coordinates :func:`stability_limit` forms the Jacobian for: its eigenvalues
#: cost O((2 nv)^3), minutes for a thousand segments; where the limit is unknown the budget
#: check of an explicit method goes without it and the run stops at budget.max_steps
STABILITY_MAX_NV = 300


def stability_limit(chain, q, v, p, tau, t, radius: float = RK4_STABILITY_RADIUS) -> float | None:
    """``radius / max |lambda|`` over the eigenvalues of the exact Jacobian of the free
    coordinates at ``(t, q, v)`` with inputs ``p``, ``tau`` (s), or None where it cannot be
    formed or the chain has more than :data:`STABILITY_MAX_NV` free coordinates. For RK4 the
    limit at the start of a run is the one to quote: near the domain's boundary the model
    stiffens, and a state already blowing up has spurious fast modes."""
    idx = np.flatnonzero(chain.active)
    if idx.size > STABILITY_MAX_NV:
        return None
    key = tuple(np.asarray(x, dtype=float).tobytes() for x in (q, v, p, tau)) + (float(t),)
    last = _LAST_RADIUS[0]  # one read of one tuple: another thread may replace it meanwhile
    if last is not None and last[0] is chain and last[1] == key:  # (qchain run checks the budget, then simulate again)
        rho = last[2]
    else:
        rho = _spectral_radius(chain, idx, q, v, p, tau, t)
        _LAST_RADIUS[0] = (chain, key, rho)
    return radius / rho if rho is not None and rho > 0 else None


#: ``[(chain, state key, spectral radius)]`` of the last :func:`stability_limit` (the chain
#: kept, so that its identity is not another's), replaced whole
_LAST_RADIUS: list = [None]


def _spectral_radius(chain, idx, q, v, p, tau, t) -> float | None:
    """The largest ``|eigenvalue|`` of the exact Jacobian of the free coordinates ``idx``."""
    from ...algorithms.aba_derivatives import aba_derivatives

    if not len(aba_derivatives.overloads) and warmup.is_cached(aba_derivatives) is False:
        print("qchain: compiling the exact derivatives for this machine (the stability limit of an explicit "
              "method's step): about 20 s, once after install or an update (cached for later runs)",
              file=sys.stderr, flush=True)
    try:
        d = chain.forward_dynamics_derivatives(q, v, p, tau, t=t)
    except (QchainError, ValueError):
        return None
    ix = np.ix_(idx, idx)
    n = idx.size
    J = np.block([[np.zeros((n, n)), np.eye(n)], [d.da_dq[ix], d.da_dv[ix]]])
    return float(np.max(np.abs(np.linalg.eigvals(J))))


def unstable_message(message: str, h: float, limit: float | None) -> str:
    """A failed fixed-step RK4 run's message: the step's stability limit where ``h`` is above
    it (the cause, not the domain exit it ended in), else ``message`` as it is."""
    if limit is None or h <= limit:
        return message
    return (f"rk4 became unstable: the step dt = {h:g} s is above its stability limit, about {limit:.3g} s at the "
            f"start of the run (2.78 / the largest |eigenvalue| of the exact Jacobian); use a smaller dt or an "
            f"implicit method ('midpoint', 'radau5'). The run stopped at: {message}")


def _trajectory(chain, m, wk, out, cnt, status, message, energies, method, ev_log) -> Trajectory:
    K = int(cnt[steppers.K_OUT])
    t, q, v, p = out.t[:K].copy(), out.q[:K].copy(), out.v[:K].copy(), out.p[:K].copy()
    nan = np.full(K, np.nan)
    traj = Trajectory(t=t, q=q, v=v, p=p, kinetic_energy=nan, potential_energy=nan, success=status >= 0,
                      message=message, nfev=int(cnt[steppers.NFEV]), status=status)
    if energies:  # at their first use: a run whose energies nobody reads does not compile their pass
        def source():
            KE, PE = np.empty(K), np.empty(K)
            warmup.prepare_energies(m, wk)
            system.energies_batch(m, wk, t, q, v, KE, PE)
            return KE, PE

        traj.with_energies(source)
    traj.meta.update(method=method, engine="compiled", nsteps=int(cnt[steppers.NSTEPS]), njev=int(cnt[steppers.NJEV]),
                     nlu=int(cnt[steppers.NLU]), nreject=int(cnt[steppers.NREJECT]), events=ev_log)
    if m.env.kind.shape[0] or m.env.law[7]:  # an environment with obstacles or self-contact
        traj.meta["max_active_contacts"] = int(wk.info[2])
    return traj
