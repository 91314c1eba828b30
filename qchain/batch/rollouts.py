"""Many rollouts of one chain at once: ``simulate_batch(chain, q0, v0, t_span, ...) -> BatchTrajectory``,
each rollout bit for bit what :func:`qchain.simulate` gives with the same arguments, on
threads of this process (:mod:`qchain.batch.threads`) or the engines of
:mod:`qchain.batch.workers`. Behaviour, failures, guarantees and which engine is the default:
``docs/sweeps.md`` ("Batched rollouts", "Engines")."""

from __future__ import annotations

import dataclasses
import functools
import os
import pickle
import socket
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..arm.chain import Chain
from ..checks import bounds as _bounds
from ..checks.convert import as_bool, as_real_array
from ..errors import QchainError, RolloutError
from ..sim.inputs import BUILT_IN, Schedule, as_input, schedules_inside
from ..sim.budget import Budget, as_budget
from ..sim.simulation import (
    COMPILED, DEFAULT_METHOD, FIXED_STEP, Event, Runs, _check_start, check_run, check_settings, run_cost_of, simulate)
from ..sim.trajectory import Trajectory
from .workers import DEFAULT_RETRIES, DaskEngine, LocalPool, Lost, Payload, check_engine, dumps, engine_for

__all__ = ["simulate_batch", "BatchTrajectory", "RolloutError"]


@dataclass
class BatchTrajectory:
    """B rollouts on one time grid, rollout-major.

    Attributes
    ----------
    t : (N,) s
        Sample times shared by every rollout.
    q : (B, N, nq), v : (B, N, nv), p : (B, N, 3 n) Pa
        States and chamber pressures; after a rollout stopped early its entries are NaN
        (``nsamples`` says how many it has).
    tension : (B, N, nt) N or None
        The tendons' tensions at the samples (a chain with tendons, docs/tendons.md), NaN
        likewise; None for a chain without tendons.
    kinetic_energy, potential_energy : (B, N) J
    success : (B,) bool
    status : (B,) int
        0 finished, 1 stopped by a terminal event, -1 failed.
    message : (B,) str
        Why each rollout ended.
    nfev, nsteps, nsamples : (B,) int
        Dynamics evaluations, steps, samples recorded.
    wall : (B,) s
        Wall time of each rollout's ``simulate`` call in its worker (``meta["rollouts"][i]
        ["compile_s"]`` of it went to compiling or loading the engine); in a compiled loop
        (``meta["loop"]``), the time-stamp counter's ticks between its start and end, at
        the rate the loops' calls measured.
    meta : dict
        ``method``, ``engine`` ("serial", "threads", "local" or "dask"), ``workers``,
        ``wall_s`` (the whole call), ``compile_s`` (this process's compile or load of the engine
        before fanning out, with the compiled loops' preparation where they run), ``t_span``,
        ``loop`` ("compiled": every rollout in compiled loops, :mod:`qchain.sim.engine.batched`;
        "python": a Python loop, each rollout a run of the driver), ``rollouts`` (each rollout's
        ``Trajectory.meta``, with ``worker``: the ``host:pid`` that ran it, and ``thread``: the
        name of its thread).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    kinetic_energy: np.ndarray
    potential_energy: np.ndarray
    success: np.ndarray
    status: np.ndarray
    message: np.ndarray
    nfev: np.ndarray
    nsteps: np.ndarray
    nsamples: np.ndarray
    wall: np.ndarray
    meta: dict = field(default_factory=dict)
    tension: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def __getitem__(self, i: int) -> Trajectory:
        """Rollout ``i`` as the :class:`~qchain.sim.trajectory.Trajectory` ``simulate`` returns."""
        B = len(self)
        if not isinstance(i, (int, np.integer)) or isinstance(i, (bool, np.bool_)) or not -B <= i < B:
            raise IndexError(f"rollout index must be an int in [-{B}, {B}), got {i!r}")
        i = int(i) % B
        K = int(self.nsamples[i])
        tr = Trajectory(t=self.t[:K].copy(), q=self.q[i, :K].copy(), v=self.v[i, :K].copy(), p=self.p[i, :K].copy(),
                        kinetic_energy=self.kinetic_energy[i, :K].copy(),
                        potential_energy=self.potential_energy[i, :K].copy(), success=bool(self.success[i]),
                        message=str(self.message[i]), nfev=int(self.nfev[i]), status=int(self.status[i]),
                        tension=None if self.tension is None else self.tension[i, :K].copy())
        tr.meta.update(self.meta["rollouts"][i])
        return tr

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    @property
    def total_energy(self) -> np.ndarray:
        """``kinetic_energy + potential_energy`` (B, N) J."""
        return self.kinetic_energy + self.potential_energy

    @property
    def valid(self) -> np.ndarray:
        """(B, N) bool: which samples each rollout reached."""
        return np.arange(self.t.size)[None, :] < self.nsamples[:, None]

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.success))


# ------------------------------------------------------------------------------ inputs


def _batched_input(name: str, u, size: int) -> tuple[object, list | None]:
    """``(shared, per_rollout)``: one input for every rollout, or a list of B of them."""
    if u is None or isinstance(u, Schedule) or callable(u):
        as_input(name, u, size)
        return u, None
    if isinstance(u, np.ndarray) or (isinstance(u, (list, tuple)) and not any(
            x is None or isinstance(x, Schedule) or callable(x) for x in u)):
        try:  # real numbers only: booleans, strings and complex numbers are refused by name
            arr = as_real_array(name, u)
        except ValueError:  # ragged: a sequence of B inputs of their own
            arr = None
        if arr is not None and arr.ndim == 1:
            as_input(name, arr, size)  # its bounds too (a pressure within qchain.checks.bounds.PRESSURE)
            return arr, None
        if arr is not None and arr.ndim == 2:
            if arr.shape[1] != size:
                raise ValueError(f"{name} as an array of constants must have shape (B, {size}), got {arr.shape}")
            for i in range(arr.shape[0]):
                as_input(f"{name}[{i}]", arr[i], size)
            return None, [arr[i] for i in range(arr.shape[0])]
        if arr is not None:
            raise ValueError(f"{name} must be one input, an array (B, {size}) of constants or a sequence of B inputs; "
                             f"got an array of shape {arr.shape}")
    if isinstance(u, (list, tuple)):
        if not schedules_inside(name, u, size):  # (the common batch, checked at once)
            for i, x in enumerate(u):
                as_input(f"{name}[{i}]", x, size)
        return None, list(u)
    raise TypeError(f"{name} must be None, a constant (3 n,), a schedule, a controller, an array (B, {size}) or a "
                    f"sequence of B inputs; got {type(u).__name__}")


def _states(name: str, x, size: int) -> np.ndarray:
    arr = as_real_array(name, x)  # booleans, strings and complex numbers refused by name, never cast
    if arr.ndim != 1 and (arr.ndim != 2 or arr.shape[1] != size):
        raise ValueError(f"{name} must have shape (B, {size}) (or ({size},), the same for every rollout), "
                         f"got shape {arr.shape}")
    return arr


def _batch_size(sizes: dict[str, int]) -> int:
    if not sizes:
        raise ValueError("simulate_batch needs a batch: q0 of shape (B, nq), v0 of shape (B, nv), or pressure or "
                         "tau given per rollout (an array (B, size) or a sequence of B inputs)")
    values = set(sizes.values())
    if len(values) > 1:
        desc = ", ".join(f"{k} has {b}" for k, b in sizes.items())
        raise ValueError(f"the batched arguments disagree on the batch size B: {desc} rollouts")
    B = values.pop()
    if B < 1:
        raise ValueError(f"the batch is empty: {', '.join(sizes)} give B = 0 rollouts")
    return B


def _as_item(u, what: str):
    """A rollout's input as it travels: None, an array, one of qchain's schedules (immutable:
    shared, not copied), an empty list of events, or pickled (any other schedule or a
    controller: each rollout unpickles its own copy, so none sees another's state)."""
    if u is None or isinstance(u, np.ndarray) or type(u) in BUILT_IN or (type(u) is list and not u):
        return u
    return dumps(u, what)


def _from_item(x):
    return pickle.loads(x) if isinstance(x, bytes) else x


# ------------------------------------------------------------------------------ the rollouts


@dataclass
class _Shared:
    chain: Chain
    t_span: tuple[float, float]
    kw: dict  # simulate's keyword arguments shared by every rollout (inputs and events pickled)
    each: dict  # "pressure", "tau", "tension": whether the items carry their own
    #: (B,) bool: the starts whose energies are finite (one compiled pass), or None (each checked by its rollout)
    starts_finite: np.ndarray | None = None
    #: the runs' shared part, made once (:func:`_runs_of`); never pickled: a worker process makes its own
    runs: Runs | None = None

    def __getstate__(self):
        return {**self.__dict__, "runs": None}


_SETTINGS = ("pressure", "tau", "tension", "events", "method", "budget")  # kw's entries that are not check_settings'


def _runs_of(shared: _Shared) -> Runs:
    """The :class:`qchain.sim.simulation.Runs` of the batch (made here once)."""
    if shared.runs is None:
        kw = shared.kw
        shared.runs = Runs(shared.chain, shared.t_span, method=kw["method"], budget=kw["budget"],
                           **{k: x for k, x in kw.items() if k not in _SETTINGS})
    return shared.runs


def _inputs(shared: _Shared, item) -> dict:
    """simulate's keyword arguments for one rollout, with fresh copies of its inputs."""
    _, _, _, p, tau, tension = item
    kw = dict(shared.kw)
    kw["pressure"] = _from_item(p if shared.each["pressure"] else kw["pressure"])
    kw["tau"] = _from_item(tau if shared.each["tau"] else kw["tau"])
    kw["tension"] = _from_item(tension if shared.each["tension"] else kw["tension"])
    kw["events"] = _from_item(kw["events"])
    return kw


def _rollouts(shared: _Shared, items: list) -> list:
    """In a worker (or this process): run each ``(index, q0, v0, pressure, tau, tension)``; returns
    ``(Trajectory, wall seconds)`` each."""
    runs = _runs_of(shared)  # simulate's checks of the shared settings were made by simulate_batch, once
    out = []
    for item in items:
        i, q0, v0 = item[:3]
        kw = _inputs(shared, item)
        w0 = time.perf_counter()
        try:
            tr = runs.run(q0, v0, pressure=kw["pressure"], tau=kw["tau"], tension=kw["tension"], events=kw["events"],
                          start_finite=shared.starts_finite is not None and bool(shared.starts_finite[i]),
                          inputs_checked=True)  # by simulate_batch (_batched_input), every rollout's
        except Exception as err:
            raise RolloutError(i, f"{type(err).__name__}: {err}") from err
        wall = time.perf_counter() - w0
        tr.meta["worker"] = f"{socket.gethostname()}:{os.getpid()}"
        tr.meta["thread"] = threading.current_thread().name
        out.append((tr, wall))
    return out


def _rollouts_into(sink: _Sink, shared: _Shared, items: list) -> list:
    """:func:`_rollouts`, each result written into ``sink`` by the thread that ran it
    (this process's engines: serial, threads); returns None an item."""
    for item, (tr, wall) in zip(items, _rollouts(shared, items)):
        sink.put(item[0], tr, wall)
    return [None] * len(items)


def _warm(shared_and_item: tuple) -> tuple[float, str]:
    """A one-step run of ``(shared, item)`` (compiles or loads the engine); returns its wall
    time and the engine it ran on (``"compiled"`` or ``"python"``). Here and in a worker
    (:meth:`qchain.batch.workers.DaskEngine.warm`)."""
    shared, item = shared_and_item
    t0 = shared.t_span[0]
    kw = _inputs(shared, item)
    kw["t_eval"] = None
    kw["wall_limit"] = None
    span = kw["dt"] if kw["method"] in FIXED_STEP else 1e-6
    w0 = time.perf_counter()
    try:
        tr = simulate(shared.chain, item[1], item[2], (t0, t0 + span), **kw)
        if kw["energies"]:  # their pass compiled or loaded here too, not by every thread or worker at once
            tr.kinetic_energy
    except Exception as err:  # what rollout item[0] would raise at its first step
        raise RolloutError(item[0], f"{type(err).__name__}: {err}") from err
    return time.perf_counter() - w0, tr.meta.get("engine")


def simulate_batch(
    chain: Chain,
    q0,
    v0,
    t_span: Sequence[float],
    *,
    pressure=None,
    tau=None,
    tension=None,
    method: str = DEFAULT_METHOD,
    dt: float | None = None,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    t_eval=None,
    events: Sequence[Event] | None = None,
    max_step: float = np.inf,
    first_step: float | None = None,
    energies: bool = True,
    wall_limit: float | None = None,
    controller_rate: float | None = None,
    budget: Budget | None = None,
    workers=None,
    client=None,
    retries: int = DEFAULT_RETRIES,
    progress: bool = False,
) -> BatchTrajectory:
    """Run B rollouts of ``chain`` at once; each equals ``simulate`` with the same arguments.

    Parameters
    ----------
    chain : Chain
    q0 : (B, nq) or (nq,), v0 : (B, nv) or (nv,)
        Initial states, one a rollout (or one for all).
    t_span : (t0, t1) s
    pressure : input or per-rollout inputs
        One input for every rollout (None, a constant (3 n,) Pa, a schedule of
        :mod:`qchain.sim.inputs`, a controller ``(t, q, v) -> (3 n,)``), an array (B, 3 n) of
        constants, or a sequence of B inputs.
    tau : input or per-rollout inputs
        External generalised forces, in the same forms with size nv.
    tension : input or per-rollout inputs
        The tendons' tensions (N, each >= 0: docs/tendons.md), in the same forms with size
        nt, for a chain with tendons (a batch with tensions runs each rollout as a run of
        the compiled driver, on threads: :func:`qchain.simulate` with ``tension=``).
    method, dt, rtol, atol, events, max_step, first_step, energies, wall_limit, controller_rate, budget
        As :func:`qchain.simulate`, shared (a rollout's cost is checked here, before any runs).
    t_eval : (N,) s
        The batch's one time grid: required for the adaptive methods; for ``rk4`` and
        ``midpoint`` without events the default is every step.
    workers : int, None, ThreadPool or LocalPool
        None or -1 every core (default), 1 this process, up to 1024 (:data:`qchain.checks.bounds.WORKERS`):
        threads of this process where every rollout runs in compiled code (a compiled
        ``method``, no ``events``, schedules or constants as inputs or a controller held at
        ``controller_rate``), worker processes otherwise (``docs/sweeps.md``, "Engines"). A
        :class:`qchain.batch.threads.ThreadPool` or :class:`qchain.batch.workers.LocalPool`
        chooses the engine.
    client : dask.distributed.Client, str or DaskEngine, optional
        A Dask cluster instead (a client or a scheduler address ``tcp://HOST:PORT``).
    retries : int
        Runs of a rollout again after its worker process died, 0 to 100.
    progress : bool
        A progress bar (tqdm) on stderr.

    Returns
    -------
    BatchTrajectory
        ``batch[i]`` is rollout ``i`` as a :class:`~qchain.sim.trajectory.Trajectory`. Bad
        arguments raise ``ValueError``/``TypeError`` naming the argument (and the rollout)
        before anything runs; an exception inside a rollout, :class:`RolloutError`."""
    t0, t1, retries, progress, cfg = _check_shared_settings(
        chain, t_span, method=method, workers=workers, client=client, retries=retries, progress=progress, dt=dt,
        rtol=rtol, atol=atol, max_step=max_step, first_step=first_step, wall_limit=wall_limit, t_eval=t_eval,
        energies=energies, events=events, controller_rate=controller_rate)
    Q0 = _states("q0", q0, chain.nq)
    V0 = _states("v0", v0, chain.nv)
    p_in = _batched_input("pressure", pressure, chain.nu)  # (shared, per_rollout)
    tau_in = _batched_input("tau", tau, chain.nv)
    if tension is not None and not chain.nt:
        raise ValueError("tension is given but the chain has no tendons (Chain(..., tendons=[...]))")
    tn_in = _batched_input("tension", tension, chain.nt)
    budget, B = _check_budget(chain, t0, t1, method, cfg, budget, Q0, V0, p_in, tau_in, tn_in)
    Q0, V0 = _check_starts(chain, Q0, V0, B, t0)
    shared, items = _share(chain, (t0, t1), method, cfg, budget, Q0, V0, p_in, tau_in, tn_in, B)
    shared.starts_finite = _runs_of(shared).starts_finite(Q0, V0)
    w_start = time.perf_counter()
    sink = _Sink(chain, B, cfg["t_eval"], (t0, t1), cfg["dt"])
    name, n_workers, compile_s, loop = _run_all(shared, items, sink, workers=workers, client=client, retries=retries,
                                          progress=progress, python_inputs=_calls_python(cfg, p_in, tau_in, tn_in))
    wall_s = time.perf_counter() - w_start
    return sink.result(dict(method=method, engine=name, workers=n_workers, wall_s=wall_s, compile_s=compile_s,
                            t_span=(t0, t1), loop=loop))


def _check_shared_settings(chain: Chain, t_span, *, method: str, workers, client, retries, progress, rtol, atol,
                           **settings) -> tuple[float, float, int, bool, dict]:
    """Step 1 of :func:`simulate_batch`: :func:`qchain.simulate`'s checks of the shared settings
    and the engine's, where they enter; returns ``(t0, t1, retries, progress, cfg)``
    (``cfg["t_eval"]`` the batch's own copy). An adaptive method (or events) needs ``t_eval``:
    the batch shares one time grid."""
    t0, t1 = check_run(chain, method, t_span)  # the checks of simulate, here where the arguments enter
    retries = check_engine(workers, client, retries)
    for name, val, rng in (("rtol", rtol, _bounds.RTOL), ("atol", atol, _bounds.ATOL)):
        if isinstance(val, (int, float, np.integer, np.floating)) and not isinstance(val, (bool, np.bool_)) and val <= 0:
            raise ValueError(f"{name} must be > 0, got {val!r} (it must be {rng.what()})")
    progress = as_bool("progress", progress)
    cfg = check_settings(chain, t0, t1, method=method, rtol=rtol, atol=atol, progress=False, on_sample=None,
                         **settings)
    if cfg["t_eval"] is None and (method not in FIXED_STEP or cfg["events"]):
        raise ValueError(f"t_eval is required for method {method!r}{' with events' if cfg['events'] else ''}: each "
                         "rollout takes its own steps, and a batch shares one time grid; give the output times (N,) s")
    if cfg["t_eval"] is not None:
        cfg["t_eval"] = np.array(cfg["t_eval"])  # the batch's own copy (BatchTrajectory.t is made from it)
    return t0, t1, retries, progress, cfg


def _row(X: np.ndarray, i: int) -> np.ndarray:
    """Rollout ``i``'s row of a batched state ``(B, size)``, or the state ``(size,)`` all share."""
    return X[i] if X.ndim == 2 else X


def _check_budget(chain: Chain, t0: float, t1: float, method: str, cfg: dict, budget, Q0: np.ndarray,
                  V0: np.ndarray, p: tuple, tau: tuple, tension: tuple) -> tuple[Budget, int]:
    """Step 2 of :func:`simulate_batch`: a rollout's cost and the B rollouts' samples, held
    together, against the budget, and the batch size B the batched arguments agree on; returns
    ``(budget, B)``."""
    budget = as_budget(budget)
    (p_shared, p_each), (tau_shared, tau_each), (tn_shared, tn_each) = p, tau, tension
    cost = run_cost_of(chain, t0, t1, method=method, dt=cfg["dt"], max_step=cfg["max_step"], t_eval=cfg["t_eval"],
                       inputs=(p_shared, tau_shared, tn_shared, *(p_each or ()), *(tau_each or ()), *(tn_each or ())),
                       controller_rate=cfg["controller_rate"])
    budget.check(cost)
    sizes = {name: len(x) for name, x in (("q0", Q0 if Q0.ndim == 2 else None), ("v0", V0 if V0.ndim == 2 else None),
                                          ("pressure", p_each), ("tau", tau_each), ("tension", tn_each))
             if x is not None}
    B = _batch_size(sizes)
    # the batch's results are held together: B rollouts' samples against the memory budget
    held = B * (cost.memory - cost.matrix_memory) + cost.matrix_memory
    if held > budget.max_memory:
        budget.check(dataclasses.replace(cost, memory=held, memory_why=f"{B} rollouts x ({cost.memory_why})"),
                     how="pass budget=qchain.sim.budget.Budget(...) to allow more, or run fewer rollouts a call")
    return budget, B


def _check_starts(chain: Chain, Q0: np.ndarray, V0: np.ndarray, B: int, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Every rollout's start ``(q0[i], v0[i])`` inside the model at ``t0`` (s), its locks
    held, checked here where it enters (``ValueError`` naming the rollout); returns the
    checked starts ``(B, nq)``, ``(B, nv)`` (their energies are checked by the rollouts:
    :meth:`qchain.sim.simulation.Runs.starts_finite`)."""
    Q, V = np.empty((B, chain.nq)), np.empty((B, chain.nv))
    if Q0.ndim == 1 and V0.ndim == 1:  # one start for all: checked once
        try:
            Q[:], V[:] = _check_start(chain, Q0, V0, t0, ("q0", "v0"), energies=False)
        except (QchainError, ValueError) as err:
            raise ValueError(f"every rollout: q0, v0: {err}") from err
        return Q, V
    for i in range(B):
        try:
            Q[i], V[i] = _check_start(chain, _row(Q0, i), _row(V0, i), t0, (f"q0[{i}]", f"v0[{i}]"), energies=False)
        except (QchainError, ValueError) as err:
            raise ValueError(f"rollout {i}: q0[{i}], v0[{i}]: {err}") from err
    return Q, V


def _share(chain: Chain, t_span: tuple[float, float], method: str, cfg: dict, budget: Budget, Q0: np.ndarray,
           V0: np.ndarray, p: tuple, tau: tuple, tension: tuple, B: int) -> tuple[_Shared, list]:
    """Step 3 of :func:`simulate_batch`: what every rollout shares (the chain, the span,
    simulate's keyword arguments, the shared inputs and the events pickled) and the B items
    ``(index, q0 (nq,), v0 (nv,), pressure, tau, tension)``, a rollout's own inputs pickled in it."""
    (p_shared, p_each), (tau_shared, tau_each), (tn_shared, tn_each) = p, tau, tension
    kw = {k: x for k, x in cfg.items() if k not in ("progress", "events")}  # (a rollout shows no progress)
    kw.update(method=method, budget=budget, pressure=_as_item(p_shared, "pressure"), tau=_as_item(tau_shared, "tau"),
              tension=_as_item(tn_shared, "tension"), events=_as_item(cfg["events"], "events"))
    items = [(i, _row(Q0, i), _row(V0, i),
              None if p_each is None else _as_item(p_each[i], f"pressure[{i}]"),
              None if tau_each is None else _as_item(tau_each[i], f"tau[{i}]"),
              None if tn_each is None else _as_item(tn_each[i], f"tension[{i}]")) for i in range(B)]
    shared = _Shared(chain=chain, t_span=t_span, kw=kw, each={"pressure": p_each is not None, "tau": tau_each is not None,
                                                             "tension": tn_each is not None})
    return shared, items


def _calls_python(cfg: dict, p: tuple, tau: tuple, tension: tuple) -> bool:
    """Whether a rollout calls Python at every step: events, or a controller not held at a
    ``controller_rate`` (which runs on the Python steppers)."""
    if cfg["events"]:
        return True
    inputs = [x for shared, each in (p, tau, tension) for x in (shared, *(each or ()))]
    return cfg["controller_rate"] is None and any(callable(x) and not isinstance(x, Schedule) for x in inputs)


def _run_all(shared: _Shared, items: list, sink: _Sink, *, workers, client, retries: int, progress: bool,
             python_inputs: bool):
    """Step 4 of :func:`simulate_batch`: run the rollouts here one after the other or on the
    engine :func:`qchain.batch.workers.engine_for` picks (threads where every rollout runs in
    compiled code: a compiled method on the compiled engine, ``python_inputs`` False), the
    method's engine compiled or loaded here first; each result written into ``sink``. Every
    rollout in compiled loops where none needs Python (:func:`_together`), on this thread or
    the threads. Returns ``(engine name, workers, compile_s, loop)``, ``loop`` "compiled" or
    "python" (a Python loop over the rollouts, each a :class:`qchain.sim.simulation.Runs` run)."""
    chain, method = shared.chain, shared.kw["method"]
    B = len(items)
    compile_s, runs_on = 0.0, "python"
    together = None
    if client is None and not isinstance(workers, (LocalPool, DaskEngine)):
        # every rollout in compiled loops, here or on threads of this process: their preparation
        # compiles or loads the engine, once, so no one-step run comes first
        w0 = time.perf_counter()
        together = _together(shared, items, sink)
        compile_s = time.perf_counter() - w0 if together is not None else 0.0
    if together is None and method in COMPILED and (workers != 1 or client is not None):
        # compile or load the engine here once: threads share it, worker processes load it from the cache
        compile_s, runs_on = _warm((shared, items[0]))
    engine = engine_for(workers, client, tasks=B,
                        threads=together is not None or runs_on == "compiled" and not python_inputs)
    from tqdm import tqdm

    bar = tqdm(total=B, unit="rollout", file=sys.stderr, smoothing=0.1, disable=not progress)
    try:
        if together is not None:  # every rollout in compiled loops, none in Python
            name, n_workers = ("serial", 1) if engine is None else (engine.kind, min(engine.workers, B))
            for _ in (engine.map(lambda _, __: [together.work(bar.update)], None, range(n_workers))
                      if engine is not None else [together.work(bar.update)]):
                pass
            sink.put_all(together.finish())
        elif engine is None:
            name, n_workers = "serial", 1
            for item in items:
                _rollouts_into(sink, shared, [item])
                bar.update(1)
        elif engine.kind == "threads":
            name, n_workers = engine.kind, min(engine.workers, B)
            for _ in engine.map(functools.partial(_rollouts_into, sink), shared, items):
                bar.update(1)
        else:
            name, n_workers = engine.kind, engine.workers
            payload = Payload.of(shared, "the chain and the shared inputs")
            if method in COMPILED:
                engine.warm(_warm, Payload.of((shared, items[0])), key=("rollout", method, bool(chain.planar)))
            for i, res in engine.map(_rollouts, payload, items, retries=retries):
                if isinstance(res, Lost):
                    sink.lost(i, res)
                else:
                    sink.put(i, *res)
                bar.update(1)
    finally:
        bar.close()
        if engine is not None and isinstance(client, str):  # a client this call connected
            engine.close()
    return name, n_workers, compile_s, "compiled" if together is not None else "python"


def _together(shared: _Shared, items: list, sink: _Sink):
    """The batch as :class:`qchain.sim.engine.batched.Rollouts` (every rollout in compiled
    loops, writing into ``sink``'s arrays), or None where a rollout needs Python between its
    steps or at its start: events, a controller, tensions (each rollout then a run of the driver), a wall-clock limit, a method that checks its
    stability limit at each start (``dopri5``), an every-step grid (no ``t_eval``), a chain the
    compiled engine does not serve, a start whose energies must be checked in Python, or an
    input that is not a constant or a schedule of :data:`qchain.sim.inputs.BUILT_IN`."""
    from ..sim.engine.batched import Rollouts
    from ..sim.engine.schedules import pack_inputs, values_at
    from ..sim.simulation import _input_function

    kw, chain = shared.kw, shared.chain
    runs = _runs_of(shared)
    if (kw["method"] not in ("rk4", "midpoint", "radau5") or runs.base is None or kw["events"]
            or kw["tension"] is not None or shared.each["tension"]
            or kw["controller_rate"] is not None or kw["wall_limit"] is not None or kw["t_eval"] is None
            or shared.starts_finite is None or not shared.starts_finite.all()):
        return None
    t0 = shared.t_span[0]
    B = len(items)
    Q0, V0 = np.array([it[1] for it in items]), np.array([it[2] for it in items])
    given, packed = {}, []
    for k, (name, size) in enumerate((("pressure", chain.nu), ("tau", chain.nv))):
        # the rollouts' own inputs, or the one they share (packed once, a row each)
        us = [it[3 + k] for it in items] if shared.each[name] else [kw[name]]
        if not all(u is None or isinstance(u, np.ndarray) or type(u) in BUILT_IN for u in us):
            return None  # (pickled: a schedule of the user's or a controller)
        ints, params = pack_inputs(us, size, name)
        packed += [ints, params] if len(us) == B else [np.repeat(ints, B, axis=0), np.repeat(params, B, axis=0)]
        given[name] = us
    P0 = values_at(given["pressure"], t0, chain.nu)
    if P0.shape[0] != B:
        P0 = np.repeat(P0, B, axis=0)

    def inputs(i):  # a rollout's inputs, for the message of one that failed
        p_of, tau_of = (_input_function(name, us[i if len(us) == B else 0], size, True)
                        for name, size, us in (("pressure", chain.nu, given["pressure"]), ("tau", chain.nv, given["tau"])))
        return lambda t, q, v: (p_of(t, q, v), tau_of(t, q, v))

    settings = dict(dt=kw["dt"], rtol=kw["rtol"], atol=kw["atol"], max_step=kw["max_step"],
                    first_step=kw["first_step"], max_total_steps=kw["budget"].max_steps, energies=kw["energies"])
    return Rollouts(chain, runs.base, kw["method"], shared.t_span, settings, Q0, V0, tuple(packed), P0, inputs, sink.t,
                    sink.q, sink.v, sink.p, sink.ke, sink.pe)


class _Sink:
    """The batch's arrays, made before any rollout runs (NaN until written); each rollout's
    results are written into its rows as it ends, by the thread that ran it where it ran in
    this process. ``t_eval`` (N,) s the batch's grid, or None for a fixed step ``dt`` s over
    ``t_span``: every rollout's own steps, the same grid up to where each stopped."""

    def __init__(self, chain: Chain, B: int, t_eval, t_span: tuple[float, float], dt: float | None):
        self.method_grid = t_eval is None
        if self.method_grid:  # at most a sample at t0, one a grid step inside the span and one at t1
            t0, t1 = t_span
            N = int(np.floor((t1 - t0) / dt)) + 3
            self.t = np.full(N, np.nan)
        else:
            self.t = t_eval.copy()
            N = self.t.size
        self.n_t = 0  # samples of the longest rollout so far (the grid known up to there)
        self.q, self.v, self.p = (np.full((B, N, size), np.nan) for size in (chain.nq, chain.nv, chain.nu))
        self.tension = np.full((B, N, chain.nt), np.nan) if chain.nt else None
        self.ke, self.pe, self.wall = np.full((B, N), np.nan), np.full((B, N), np.nan), np.full(B, np.nan)
        self.success, self.status, self.message = np.zeros(B, bool), np.full(B, -1, int), np.empty(B, object)
        self.nfev, self.nsteps, self.nsamples = np.zeros(B, int), np.zeros(B, int), np.zeros(B, int)
        self.rollouts: list = [None] * B
        self._lock = threading.Lock()

    def put(self, i: int, tr: Trajectory, wall: float) -> None:
        """Rollout ``i``'s trajectory into its rows (its energies computed here if they were not)."""
        K = len(tr.t)
        with self._lock:  # the grid: every rollout's samples are at the batch's one grid's times
            known = min(K, self.n_t) if self.method_grid else K
            if K > self.t.size or not np.array_equal(tr.t[:known], self.t[:known]):
                raise AssertionError(f"rollout {i} was sampled at other times than the batch's grid")
            if K > self.n_t:
                if self.method_grid:
                    self.t[self.n_t : K] = tr.t[self.n_t :]
                self.n_t = K
        self.q[i, :K], self.v[i, :K], self.p[i, :K] = tr.q, tr.v, tr.p
        if self.tension is not None:
            self.tension[i, :K] = tr.tension
        self.ke[i, :K], self.pe[i, :K] = tr.kinetic_energy, tr.potential_energy
        self.success[i], self.status[i], self.message[i] = tr.success, tr.status, tr.message
        self.nfev[i], self.nsteps[i], self.nsamples[i], self.wall[i] = tr.nfev, tr.meta.get("nsteps", 0), K, wall
        self.rollouts[i] = dict(tr.meta)

    def put_all(self, ends: list[dict]) -> None:
        """Every rollout's end (:meth:`qchain.sim.engine.batched.Rollouts.finish`), its samples
        and energies already written into the arrays."""
        worker = f"{socket.gethostname()}:{os.getpid()}"
        for i, e in enumerate(ends):
            self.success[i], self.status[i], self.message[i] = e["status"] >= 0, e["status"], e["message"]
            self.nfev[i], self.nsteps[i], self.nsamples[i], self.wall[i] = e["nfev"], e["nsteps"], e["nsamples"], e["wall"]
            self.rollouts[i] = dict(e["meta"], worker=worker, thread=e["thread"])
            if self.tension is not None:  # (compiled loops run no tensions: a chain's tendons slack, as simulate's)
                self.tension[i, : e["nsamples"]] = 0.0

    def lost(self, i: int, r: Lost) -> None:
        """Rollout ``i`` not run: its workers died (``r``)."""
        self.message[i] = f"not run: {r.message}"
        self.rollouts[i] = {"lost": r.message, "attempts": r.attempts}

    def result(self, meta: dict) -> BatchTrajectory:
        """The batch, with ``meta`` (and each rollout's in ``meta["rollouts"]``)."""
        N = self.n_t if self.method_grid else self.t.size
        cut = (lambda a: a[:, :N]) if N < self.t.size else (lambda a: a)  # (the grid's rows beyond its last sample)
        meta["rollouts"] = [r if r is None or "lost" not in r else {"method": meta["method"], **r} for r in self.rollouts]
        return BatchTrajectory(t=self.t[:N].copy(), q=cut(self.q), v=cut(self.v), p=cut(self.p),
                               kinetic_energy=cut(self.ke), potential_energy=cut(self.pe), success=self.success,
                               status=self.status, message=self.message, nfev=self.nfev, nsteps=self.nsteps,
                               nsamples=self.nsamples, wall=self.wall, meta=meta,
                               tension=None if self.tension is None else cut(self.tension))
