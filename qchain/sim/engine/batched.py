"""Many rollouts of one model in one compiled loop: no Python between them.

A batch whose rollouts differ only in their start and their compiled inputs (schedules,
constants) runs here (:class:`Rollouts`): each thread (or this one, serially) calls
:func:`run_rollouts`, which claims the next rollout not yet taken (an atomic counter the
threads share), resets its own workspace and integrator to what a fresh run starts from,
copies the rollout's packed inputs into its model, and steps it with the method's compiled
stepper (called through its address: the stepper is not compiled again into this loop),
writing the samples and their energies straight into the batch's arrays. It returns to
Python only after about :data:`qchain.sim.engine.driver.STRETCH` s of steps (a look at the
thread's stop event: Ctrl-C), when a rollout fails (its message is made in Python, from the
state it failed in, by :func:`qchain.sim.engine.driver._failure`), or when no rollout is left.

Each rollout is what :func:`qchain.sim.engine.driver.run` gives for it, bit for bit: the same
start (:func:`qchain.sim.engine.driver.start_integrator`), the same first sample (its input at
``t0`` evaluated in Python by the caller, as the driver does), the same stepper calls (where
a stretch ends changes no result), the same energies pass.
"""

from __future__ import annotations

import sys
import threading
import time

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.experimental.function_type import _get_wrapper_address
from numba.extending import intrinsic

try:
    from numpy.lib.array_utils import byte_bounds
except ImportError:  # numpy < 2
    byte_bounds = np.byte_bounds

from ..._jit import Address, cached_here, ejit, first_class_functions, inline
from . import driver, steppers, system, warmup
from .steppers import AT_STOP, FAILED, K_OUT, NFEV, NJEV, NLU, NREJECT, NSTEPS

__all__ = ["Rollouts", "run_rollouts", "DONE", "PAUSED", "FAILED_ONE"]

DONE, PAUSED, FAILED_ONE = 0, 1, 2  #: what :func:`run_rollouts` returns
#: CPU seconds a cold compile of :func:`run_rollouts` for one method takes (3.4 s measured on
#: the 2-core machine; loading it from the cache 0.1 s)
EXPECTED_COMPILE_S = 4
# stat's columns (B, 8) int64: the rollout's end, then its counters
S_END, S_K, S_NFEV, S_NSTEPS, S_NJEV, S_NLU, S_NREJECT, S_CONTACTS, S_WHO = range(9)
NOT_RUN, FINISHED, FAILED_RUN, OVER_BUDGET = 0, 1, 2, 3  #: stat[:, S_END]
F_T, F_CYCLES = 0, 1  # fl's columns (B, 2): the time reached (s), the time-stamp counter's ticks spent on it


@intrinsic
def _claim(typingctx, counter):
    """``counter[0]`` before adding 1 to it, atomically (the threads of a batch share it)."""
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        arr_t = signature.args[0]
        ary = context.make_array(arr_t)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, arr_t, ary, [context.get_constant(types.intp, 0)])
        return builder.atomic_rmw("add", ptr, context.get_constant(types.int64, 1), "seq_cst")

    return sig, codegen


@intrinsic
def _ticks(typingctx):
    """The processor's time-stamp counter (``llvm.readcyclecounter``): a rollout's share of a
    call's wall time, converted to seconds by the caller (ticks of the whole call against its
    wall time)."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(64), []),
                                            "llvm.readcyclecounter")
        return builder.call(fn, [])

    return sig, codegen


@inline
def _zero(a):
    b = a.reshape(a.size)
    for j in range(b.size):
        b[j] = 0


@inline
def _fresh(wk, it, tf0):
    """``wk`` and ``it`` as :func:`qchain.sim.engine.system.workspace` and
    :func:`qchain.sim.engine.steppers.integrator` make them, with the start's floats ``tf0``."""
    for a in (wk.q, wk.v, wk.q_chart, wk.p, wk.tau, wk.a, wk.A0, wk.scratch, wk.buf):
        _zero(a)
    for a in (wk.f, wk.qdd, wk.B, wk.R_WB, wk.Eenv, wk.prm_t, wk.vel, wk.roots):
        _zero(a)
    for a in (wk.W, wk.Jenv, wk.Denv, wk.nodes):
        _zero(a)
    _zero(wk.info)
    for a in (it.y, it.y_old, it.f, it.qc):
        _zero(a)
    for a in (it.K, it.tmp, it.Jq, it.Jv, it.LUr):
        _zero(a)
    _zero(it.cnt)
    _zero(it.piv_r)
    _zero(it.piv_c)
    _zero(it.LUc)
    _zero(it.ctmp)
    for j in range(tf0.shape[0]):
        it.tf[j] = tf0[j]


@ejit
def run_rollouts(adv, energies, fs, m, wk, it, c, tf0, t1, max_total, fixed, with_energies, steps, who, counter, own,
                 Q0, V0, P0, p_ints, p_params, tau_ints, tau_params, t_out, Q, V, P, KE, PE, stat, fl):
    """Run rollouts of the batch on this thread until none is left (:data:`DONE`), about
    ``steps`` stepper steps were taken (:data:`PAUSED`: ``own`` holds the rollout to go on
    with), or one failed (:data:`FAILED_ONE`: ``own[0]``; ``wk`` and ``it`` hold the state
    it failed in).

    Parameters
    ----------
    adv, energies : compiled functions
        The method's stepper (:data:`qchain.sim.engine.steppers.ADVANCE`) and
        :func:`qchain.sim.engine.system.energies_batch`, called through their addresses.
    fs, c : tuples
        The stepper's callbacks and coefficients.
    m, wk, it
        This thread's model (its own input arrays, at least as long as every rollout's
        packed inputs), workspace and integrator.
    tf0 : (16,) float
        The integrator's floats at a run's start (:func:`driver.start_integrator`).
    t1 : float
        The end of the span (s).
    max_total : int
        The budget's most steps of an adaptive method (-1: none).
    fixed, with_energies : int
        1 for a fixed-step method; 1 to compute each rollout's energies.
    steps : int
        Stepper steps this call may take (a stretch).
    who : int
        The calling thread's number, written beside each rollout it ran.
    counter : (1,) int64
        The next rollout to claim, shared by the threads.
    own : (2,) int64
        This thread's rollout and whether it has started.
    Q0 (B, nq), V0 (B, nv), P0 (B, nu)
        The starts and the inputs at ``t0`` (the first samples').
    p_ints, p_params, tau_ints, tau_params : (B, k) arrays
        Each rollout's packed inputs (:func:`qchain.sim.engine.schedules.pack_input`), padded.
    t_out : (N,) s
        The batch's grid.
    Q (B, N, nq), V (B, N, nv), P (B, N, nu), KE, PE (B, N)
        The batch's arrays, written here (a rollout's energies where it reached every sample).
    stat : (B, 9) int64, fl : (B, 2) float
        Each rollout's end, counters and thread; the time it reached (s) and its ticks.
    """
    B = Q0.shape[0]
    nA = m.idx.size
    left = steps
    mark = _ticks()
    while True:
        i = own[0]
        if own[1] == 0:  # a new rollout: the next not taken
            i = _claim(counter)
            if i >= B:
                own[0] = -1
                return DONE
            own[0] = i
            own[1] = 1
            mark = _ticks()
            _fresh(wk, it, tf0)
            for j in range(p_ints.shape[1]):
                m.p_ints[j] = p_ints[i, j]
            for j in range(p_params.shape[1]):
                m.p_params[j] = p_params[i, j]
            for j in range(tau_ints.shape[1]):
                m.tau_ints[j] = tau_ints[i, j]
            for j in range(tau_params.shape[1]):
                m.tau_params[j] = tau_params[i, j]
            for j in range(Q0.shape[1]):
                wk.q_chart[j] = Q0[i, j]
            for j in range(nA):
                it.y[nA + j] = V0[i, m.idx[j]]
            k = 0
            t0 = tf0[steppers.T0]
            while k < t_out.shape[0] and t_out[k] <= t0:
                for j in range(Q0.shape[1]):
                    Q[i, k, j] = Q0[i, j]
                for j in range(V0.shape[1]):
                    V[i, k, j] = V0[i, j]
                for j in range(P0.shape[1]):
                    P[i, k, j] = P0[i, j]
                k += 1
            it.cnt[K_OUT] = k
        cnt = it.cnt
        end = NOT_RUN
        while True:
            if left <= 0:
                fl[i, F_CYCLES] += _ticks() - mark
                return PAUSED
            n = left
            if max_total >= 0 and fixed == 0:
                taken = cnt[NSTEPS] + cnt[NREJECT]
                if taken >= max_total:
                    end = OVER_BUDGET
                    break
                n = min(n, max_total - taken)
            before = cnt[NSTEPS] + cnt[NREJECT]
            code = adv(fs, m, wk, it, (t_out, Q[i], V[i], P[i]), c, t1, 1 << 30, n)
            left -= max(1, cnt[NSTEPS] + cnt[NREJECT] - before)
            if code == FAILED:
                end = FAILED_RUN
                break
            if code == AT_STOP and it.tf[steppers.T] >= t1:
                end = FINISHED
                break
        K = cnt[K_OUT]
        if with_energies == 1 and K == t_out.shape[0]:  # (one that stopped early: in Python, on its samples)
            energies(m, wk, t_out, Q[i], V[i], KE[i], PE[i])
        stat[i, S_END] = end
        stat[i, S_K] = K
        stat[i, S_NFEV] = cnt[NFEV]
        stat[i, S_NSTEPS] = cnt[NSTEPS]
        stat[i, S_NJEV] = cnt[NJEV]
        stat[i, S_NLU] = cnt[NLU]
        stat[i, S_NREJECT] = cnt[NREJECT]
        stat[i, S_CONTACTS] = wk.info[2]
        stat[i, S_WHO] = who
        fl[i, F_T] = it.tf[steppers.T]
        now = _ticks()
        fl[i, F_CYCLES] += now - mark
        mark = now
        own[1] = 0
        if end == FAILED_RUN:
            return FAILED_ONE


class Rollouts:
    """B rollouts of one chain on the compiled engine, run by :meth:`work` on any number of
    threads at once (each claims rollouts until none is left), written into the batch's arrays.

    Parameters
    ----------
    chain : Chain
    base : EngineModel
        The chain's packed model (:func:`qchain.sim.engine.packing.pack`).
    method : str
        ``rk4``, ``midpoint`` or ``radau5`` (an explicit adaptive method checks its stability
        limit at each run's start, in Python: not here).
    t_span : (t0, t1) s
    settings : dict
        ``dt``, ``rtol``, ``atol``, ``max_step``, ``first_step`` as checked by
        :func:`qchain.sim.simulation.check_settings`; ``max_total_steps``: the budget's
        ``max_steps`` (None: none); ``energies``: compute each rollout's energies.
    Q0 : (B, nq), V0 : (B, nv)
        The checked starts.
    packed : (p_ints, p_params, tau_ints, tau_params), (B, k) arrays each
        Each rollout's compiled inputs, a row each (:func:`qchain.sim.engine.schedules.pack_inputs`).
    P0 : (B, nu) Pa
        Each rollout's pressure at ``t0`` as Python evaluates it (the first samples').
    inputs : callable
        ``inputs(i) -> ((t, q, v) -> (p, tau))`` for rollout ``i``, in Python (a failed
        run's message).
    t, q, v, p, ke, pe
        The batch's arrays: the grid (N,) s, writable, and (B, N, ...) each, C-ordered, NaN
        where nothing is written.
    """

    def __init__(self, chain, base, method: str, t_span: tuple[float, float], settings: dict, Q0: np.ndarray,
                 V0: np.ndarray, packed: tuple, P0: np.ndarray, inputs, t, q, v, p, ke, pe):
        self.chain, self.method, self.inputs = chain, method, inputs
        self.t0, self.t1 = t_span
        self.fixed = method in ("rk4", "midpoint")
        self.max_total = settings["max_total_steps"]
        self.energies = bool(settings["energies"])
        B = Q0.shape[0]
        self.Q0, self.V0, self.P0 = (np.ascontiguousarray(a, dtype=float) for a in (Q0, V0, P0))
        self.inputs_packed = tuple(np.ascontiguousarray(a, dtype=d) for a, d in zip(packed, (np.int64, float) * 2))
        self.m = _own_inputs(base, self.inputs_packed)
        self.out = (t, q, v, p, ke, pe)
        it = steppers.integrator(self.m.idx.size, chain.nq)
        driver.start_integrator(it, method, self.t0, self.t1, dt=settings["dt"], rtol=settings["rtol"],
                                atol=settings["atol"], max_step=settings["max_step"], first_step=settings["first_step"])
        self.tf0 = it.tf.copy()
        self.c = steppers.constants(method)
        wk = system.workspace(chain, self.m)
        self.fs = warmup.prepare(method, self.m, wk, it, (t, q[0], v[0], p[0]), self.c)[0]
        self.adv = steppers.ADVANCE[method]  # (the dispatcher: its compiled code's address is taken)
        if self.energies:
            warmup.prepare_energies(self.m, wk)
        self.stat = np.zeros((B, 9), dtype=np.int64)
        self.fl = np.zeros((B, 2))
        self.counter = np.zeros(1, dtype=np.int64)
        self.messages: list[str | None] = [None] * B
        self._entry, adv_at, en_at = _entry(method, self._arguments(self.m, wk, it, 1, 0, np.zeros(2, dtype=np.int64)))
        self._functions = (adv_at, en_at, tuple(Address(cf.address) for cf in self.fs))
        self._names: list[str] = []
        self._lock = threading.Lock()
        self._clock = [0.0, 0]  # wall seconds and ticks of every thread's work: a tick's length

    def _arguments(self, m, wk, it, steps: int, who: int, own: np.ndarray) -> tuple:
        """:func:`run_rollouts`' arguments after ``adv``, ``energies``, ``fs``."""
        return (m, wk, it, self.c, self.tf0, self.t1, -1 if self.max_total is None else int(self.max_total),
                int(self.fixed), int(self.energies), steps, who, self.counter, own, self.Q0, self.V0, self.P0,
                *self.inputs_packed, *self.out, self.stat, self.fl)

    def work(self, done=None) -> None:
        """Run rollouts on this thread until none is left; ``done(n)`` after each call, ``n``
        the rollouts the threads claimed meanwhile (a progress bar's count). A set stop event (:func:`qchain.sim.engine.driver.stop_on`)
        ends it between calls with ``KeyboardInterrupt``, as Ctrl-C does."""
        m = _own_inputs(self.m, self.inputs_packed)
        m, wk, it, own = _private((m, system.workspace(self.chain, m), steppers.integrator(m.idx.size, self.chain.nq),
                                   np.array([-1, 0], dtype=np.int64)))
        stop = getattr(driver._thread, "stop", None)
        with self._lock:
            who = len(self._names)
            self._names.append(threading.current_thread().name)
        steps = 16  # stepper steps a call, grown to about driver.STRETCH s a call
        B = self.Q0.shape[0]
        w_start, k_start = time.perf_counter(), _read_ticks()
        try:
            with first_class_functions(), driver.sigint_between_calls() as sigint:
                while True:
                    k0 = min(int(self.counter[0]), B)
                    w0 = time.perf_counter()
                    code = self._entry(*self._functions, *self._arguments(m, wk, it, steps, who, own))
                    w = time.perf_counter() - w0
                    if code == PAUSED:  # the next call about driver.STRETCH s
                        steps = int(min(max(steps * min(4.0, driver.STRETCH / max(w, 1e-6)), 1), 1 << 20))
                    elif code == FAILED_ONE:  # its message from the state it failed in
                        i = int(own[0])
                        self.messages[i] = driver._failure(self.chain, wk, it, self.method, self.Q0[i], self.V0[i],
                                                           self.t0, self.inputs(i))
                    if done is not None:
                        done(min(int(self.counter[0]), B) - k0)
                    if stop is not None and stop.is_set() or sigint is not None and sigint.is_set():
                        raise KeyboardInterrupt  # (also after the last call, as the driver's loop)
                    if code == DONE:
                        break
        finally:
            w, k = time.perf_counter() - w_start, _read_ticks() - k_start
            with self._lock:
                self._clock[0] += w
                self._clock[1] += k

    def finish(self) -> list[dict]:
        """After every :meth:`work`: each rollout's end, the energies of those that stopped
        early (from their samples, as a run's trajectory computes them), written into the
        batch's arrays; returns B dicts: ``status``, ``message``, ``nfev``, ``nsteps``,
        ``nsamples``, ``wall`` (s, the rollout's ticks at the threads' rate), ``thread`` (the
        name of the thread that ran it) and ``meta`` (as a run's ``Trajectory.meta``)."""
        t, q, v, p, ke, pe = self.out
        per_tick = self._clock[0] / self._clock[1] if self._clock[1] > 0 else 0.0
        env = bool(self.m.env.kind.shape[0] or self.m.env.law[7])
        out = []
        wk = None
        # the counters as Python numbers in one conversion (not one a field: B x 10 numpy scalars)
        for i, (s, f) in enumerate(zip(self.stat.tolist(), self.fl.tolist())):
            end, K = s[S_END], s[S_K]
            if end == FINISHED:
                status, message = 0, "The end of the time span was reached."
            elif end == FAILED_RUN:
                status, message = -1, self.messages[i]
            elif end == OVER_BUDGET:
                taken = s[S_NSTEPS] + s[S_NREJECT]
                status, message = -1, driver.step_budget_message(
                    self.max_total, f"{taken} steps taken ({s[S_NSTEPS]} accepted, {s[S_NREJECT]} rejected)",
                    f[F_T], self.t1, self.method)
            else:
                raise AssertionError(f"rollout {i} was not run")
            if self.energies and K < t.size:
                wk = wk or system.workspace(self.chain, self.m)
                KE, PE = np.empty(K), np.empty(K)
                system.energies_batch(self.m, wk, t[:K].copy(), q[i, :K].copy(), v[i, :K].copy(), KE, PE)
                ke[i, :K], pe[i, :K] = KE, PE
            meta = dict(method=self.method, engine="compiled", nsteps=s[S_NSTEPS], njev=s[S_NJEV], nlu=s[S_NLU],
                        nreject=s[S_NREJECT], events=[])
            if env:
                meta["max_active_contacts"] = s[S_CONTACTS]
            meta["compile_s"] = 0.0
            out.append(dict(status=status, message=message, nfev=s[S_NFEV], nsteps=s[S_NSTEPS], nsamples=K,
                            wall=f[F_CYCLES] * per_tick, thread=self._names[s[S_WHO]], meta=meta))
        return out


#: bytes between two arrays of :func:`_private` (a multiple of the cache line; the adjacent-line
#: prefetcher pulls lines in pairs)
_APART = 128


def _private(tree):
    """``tree`` (a tuple or namedtuple of arrays, nested) with every array copied into one
    fresh buffer of the calling thread, each on cache lines of its own.

    A thread's workspace and integrator are written at every step. Made one by one by each
    thread, small arrays of the two threads end up side by side (numpy and the allocator reuse
    what another thread freed): in a 2-thread batch of the four-segment arm, 1 to 4 cache lines
    a batch held arrays of both threads, among them one thread's Runge-Kutta stages ``it.K``
    or derivative ``it.f`` and the other's configuration ``wk.q``, lines the two cores then
    pass back and forth at every write, a cost that changes from batch to batch. One buffer a
    thread, large enough to be a mapping of its own, keeps each thread's arrays apart from the
    other's (no line shared), for about 0.1 ms of copying a batch.
    """
    every: dict = {}

    def collect(x):
        if isinstance(x, np.ndarray):
            every[id(x)] = x
        elif isinstance(x, tuple):
            for v in x:
                collect(v)

    collect(tree)
    spans = sorted(byte_bounds(a) for a in every.values() if a.size)
    if any(high > low for (_, high), (low, _) in zip(spans, spans[1:])):
        return tree  # arrays that overlap (views of one another) stay as they are, together
    # (an array that is read-only or not C-ordered stays where it is: its numba type says so)
    arrays = [a for a in every.values() if a.flags.writeable and a.flags.c_contiguous]
    placed = {}
    sizes = [-(-a.nbytes // _APART) * _APART + _APART for a in arrays]
    # at least 256 KiB: above the allocator's 128 KiB threshold, so a mapping of its own
    buf = np.empty(max(sum(sizes) + 4096, 1 << 18), dtype=np.uint8)
    at = [(-buf.ctypes.data) % 4096]  # from a page boundary
    for size in sizes[:-1]:
        at.append(at[-1] + size)
    for a, o in zip(arrays, at):
        v = buf[o:o + a.nbytes].view(a.dtype).reshape(a.shape)
        v[...] = a
        placed[id(a)] = v

    def rebuild(x):
        if isinstance(x, np.ndarray):
            return placed.get(id(x), x)
        if isinstance(x, tuple):
            parts = [rebuild(v) for v in x]
            return type(x)(*parts) if hasattr(x, "_fields") else tuple(parts)
        return x

    return rebuild(tree)


def _own_inputs(m, packed: tuple):
    """``m`` with input arrays of its own, as long as the batch's longest packed inputs."""
    return m._replace(p_ints=packed[0][0].copy(), p_params=packed[1][0].copy(), tau_ints=packed[2][0].copy(),
                      tau_params=packed[3][0].copy())


@ejit
def _read_ticks():
    """The time-stamp counter, from Python."""
    return _ticks()


_entries: dict = {}  # (method, the arguments' fingerprint) -> (entry point, the stepper's and energies' addresses)
_entries_lock = threading.Lock()


def _entry(method: str, args: tuple):
    """:func:`run_rollouts`' compiled entry point for the argument types of ``args``
    (:meth:`Rollouts._arguments`), with the stepper and the energies pass as function types
    (called through their addresses, not compiled again into it); returns it and those two
    functions' :class:`qchain._jit.Address`."""
    key = (method, warmup._fingerprint(args))
    known = _entries.get(key)
    if known is not None:
        return known
    m, wk, it, c = args[:4]
    t, q, v, p, ke, pe = args[20:26]
    with first_class_functions():
        adv_types = warmup._advance_types(method, m, wk, it, (t, q[0], v[0], p[0]), c)
        en_types = tuple(numba.typeof(a) for a in (m, wk, t, q[0], v[0], ke[0], pe[0]))
        adv_sig, en_sig = types.int64(*adv_types), types.none(*en_types)
        sig = (types.FunctionType(adv_sig), types.FunctionType(en_sig), adv_types[0]) + \
            tuple(numba.typeof(a) for a in args)
        with _entries_lock:
            if sig not in run_rollouts.overloads:
                if _cold(sig):
                    print(f"qchain: compiling the {method} batch loop for this machine: about {EXPECTED_COMPILE_S} s, "
                          "once after install or an update (cached for later runs)", file=sys.stderr, flush=True)
                run_rollouts.compile(sig)
            # the stepper and the energies pass as their addresses: unboxed at each call
            # without typing them again (a dispatcher looked up by its signature costs
            # milliseconds for the engine's), and looked up once a process
            _entries[key] = (run_rollouts.overloads[sig].entry_point,
                             Address(_get_wrapper_address(steppers.ADVANCE[method], adv_sig)),
                             Address(_get_wrapper_address(system.energies_batch, en_sig)))
    return _entries[key]


def _cold(sig: tuple) -> bool:
    """Whether numba's on-disk cache lacks :func:`run_rollouts` for ``sig`` (False where that
    cannot be told: nothing is said then)."""
    try:
        return not cached_here(run_rollouts, lambda key: key[0] == sig)
    except Exception:  # numba's cache layout is not public API: no answer, no notice
        return False
