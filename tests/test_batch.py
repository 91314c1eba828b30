"""Batched rollouts (qchain.simulate_batch) and the local worker pool (qchain.batch.workers):
bit-identical to simulate at any worker count, failures kept to their rollout, lost workers;
batch arrays, run settings and worker counts checked before anything runs."""

import io
import os
import signal
import subprocess
import sys
import threading
import time
from decimal import Decimal
from pathlib import Path

import numba
import numpy as np
import pytest

import batch_probe
from helpers import deadline
from logging_fixtures import arm_info
from qchain import Chain, Segment, simulate_batch
from qchain.batch.rollouts import RolloutError
from qchain.batch.workers import LocalPool, Lost, Payload, plan_chunks
from qchain.logging import RunLogger
from qchain.sim.budget import BudgetError
from qchain.sim.inputs import Sine
from qchain.sim.simulation import simulate
from support import CH1, SEGMENT, pressure_arm, refused, soft_arm

SEG = dict(SEGMENT, damping=0.02)
T = (0.0, 0.3)
T_EVAL = np.linspace(0.0, 0.3, 16)


def two_segment_arm():
    return Chain([Segment(**SEG) for _ in range(2)], gravity=(0, 0, -9.81))


@pytest.fixture(scope="module")
def arm():
    return two_segment_arm()


@pytest.fixture(scope="module")
def pool():
    with LocalPool(2) as p:
        yield p.start()


def inputs(ch, B, seed=0):
    """B initial states (bent in different directions) and B pressure schedules."""
    rng = np.random.default_rng(seed)
    q0 = np.tile(ch.neutral(), (B, 1))
    for i in range(B):
        q0[i, 1::3] = rng.uniform(-3, 3, ch.n)  # ux, 1/m
        q0[i, 2::3] = rng.uniform(-3, 3, ch.n)  # uy
    v0 = rng.normal(0, 0.1, (B, ch.nv))
    P = [Sine(amplitude=rng.uniform(1e4, 3e4, ch.nu), frequency=rng.uniform(1, 3), phase=rng.uniform(0, 6, ch.nu),
              offset=np.full(ch.nu, 2e4)) for _ in range(B)]
    return q0, v0, P


def same(tr, ref):
    return (np.array_equal(tr.t, ref.t) and np.array_equal(tr.q, ref.q) and np.array_equal(tr.v, ref.v)
            and np.array_equal(tr.p, ref.p) and np.array_equal(tr.kinetic_energy, ref.kinetic_energy)
            and np.array_equal(tr.potential_energy, ref.potential_energy) and tr.success == ref.success
            and tr.status == ref.status and tr.message == ref.message and tr.nfev == ref.nfev)


@pytest.mark.slow
def test_rollouts_are_bit_identical_to_simulate_at_any_worker_count(arm, pool):
    B = 7
    q0, v0, P = inputs(arm, B)
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    refs = [simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw) for i in range(B)]
    serial = simulate_batch(arm, q0, v0, T, pressure=P, workers=1, **kw)
    pooled = simulate_batch(arm, q0, v0, T, pressure=P, workers=pool, **kw)
    assert serial.meta["engine"] == "serial" and pooled.meta["engine"] == "local" and pooled.meta["workers"] == 2
    for b in (serial, pooled):
        assert len(b) == B and b.q.shape == (B, T_EVAL.size, arm.nq) and np.array_equal(b.t, T_EVAL)
        assert b.success.all() and np.all(b.nsamples == T_EVAL.size)
        for i in range(B):
            assert same(b[i], refs[i]), i
    assert np.array_equal(serial.q, pooled.q) and np.array_equal(serial.nfev, pooled.nfev)
    assert len({refs[i].nfev for i in range(B)}) > 1  # the rollouts differ: not one rollout copied B times
    assert {m["worker"] for m in pooled.meta["rollouts"]} == {f"{os.uname().nodename}:{pid}" for pid in pool.pids()}


def test_shared_and_per_rollout_inputs_and_a_fixed_step_grid(arm, pool):
    B = 4
    q0, v0, _ = inputs(arm, B, seed=1)
    Pc = np.linspace(1e4, 4e4, B)[:, None] * np.tile([1.0, 0.0, 0.5], arm.n)  # (B, 3n) constants
    kw = dict(method="rk4", dt=1e-3)
    b = simulate_batch(arm, q0, v0[0], (0.0, 0.05), pressure=Pc, workers=pool, **kw)  # one v0 for all
    assert b.t.size == 51 and b.t[-1] == 0.05
    for i in range(B):
        assert same(b[i], simulate(arm, q0[i], v0[0], (0.0, 0.05), pressure=Pc[i], **kw)), i
    shared = Sine(amplitude=np.full(arm.nu, 2e4), frequency=2.0, phase=np.zeros(arm.nu))
    b = simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=shared, workers=pool, **kw)
    for i in range(B):
        assert same(b[i], simulate(arm, q0[i], v0[i], (0.0, 0.05), pressure=shared, **kw)), i


def test_a_failing_rollout_does_not_stop_the_others(arm, pool):
    B = 4
    q0, v0, _ = inputs(arm, B, seed=2)
    Pc = np.full((B, arm.nu), 1e4)
    Pc[2] = np.tile([4e6, 0.0, 0.0], arm.n)  # bends segment 0 past |kappa| r_s = 1: leaves the model
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    b = simulate_batch(arm, q0, v0, T, pressure=Pc, workers=pool, **kw)
    assert list(b.success) == [True, True, False, True] and b.n_failed == 1
    ref = simulate(arm, q0[2], v0[2], T, pressure=Pc[2], **kw)
    assert not ref.success and "segment" in ref.message and same(b[2], ref)
    K = b.nsamples[2]
    assert 0 < K < T_EVAL.size and np.isnan(b.q[2, K:]).all() and np.isfinite(b.q[2, :K]).all()
    assert not b.valid[2, K] and b.valid[2, K - 1] and b.valid[[0, 1, 3]].all()
    for i in (0, 1, 3):
        assert same(b[i], simulate(arm, q0[i], v0[i], T, pressure=Pc[i], **kw))


def test_bad_arguments_are_named_where_they_enter(arm):
    q0, v0, P = inputs(arm, 3)
    kw = dict(t_eval=T_EVAL, workers=1)
    with pytest.raises(ValueError, match=r"q0 must have shape \(B, 6\)"):
        simulate_batch(arm, q0[:, :4], v0, T, **kw)
    with pytest.raises(ValueError, match="q0 has 3, v0 has 3, pressure has 2 rollouts"):
        simulate_batch(arm, q0, v0, T, pressure=P[:2], **kw)
    bad = q0.copy()
    bad[1, 1] = 1.0 / 0.015  # |kappa| r_s = 1
    with pytest.raises(ValueError, match=r"rollout 1: q0\[1\], v0\[1\]:.*segment 0"):
        simulate_batch(arm, bad, v0, T, **kw)
    with pytest.raises(ValueError, match=r"every rollout: q0, v0:.*segment 0"):  # one start for all, checked once
        simulate_batch(arm, bad[1], v0[0], T, pressure=P, **kw)
    with pytest.raises(ValueError, match=r"pressure\[1\] schedule gives 3 values, the model needs 6"):
        simulate_batch(arm, q0, v0, T, pressure=[P[0], Sine(np.ones(3), 1.0), P[2]], **kw)
    with pytest.raises(ValueError, match=r"pressure as an array of constants must have shape \(B, 6\)"):
        simulate_batch(arm, q0, v0, T, pressure=np.zeros((3, 5)), **kw)
    with pytest.raises(ValueError, match="t_eval is required for method 'radau5'"):
        simulate_batch(arm, q0, v0, T, workers=1)
    with pytest.raises(ValueError, match="needs a batch"):
        simulate_batch(arm, q0[0], v0[0], T, **kw)
    with pytest.raises(ValueError, match="workers must be None or -1"):
        simulate_batch(arm, q0, v0, T, t_eval=T_EVAL, workers=0)
    with pytest.raises(ValueError, match="retries must be an int >= 0"):
        simulate_batch(arm, q0, v0, T, retries=-1, **kw)
    with pytest.raises(ValueError, match="method 'rk4' needs a step dt > 0 s, got None"):
        simulate_batch(arm, q0, v0, T, method="rk4", **kw)
    with pytest.raises(ValueError, match="rtol must be > 0, got -1"):
        simulate_batch(arm, q0, v0, T, rtol=-1, **kw)
    with pytest.raises(ValueError, match=r"t_span must be \(t0, t1\)"):
        simulate_batch(arm, q0, v0, (0.0, np.nan), **kw)
    with pytest.raises(ValueError, match=r"got 'radau': did you mean 'radau5' \(compiled\) or 'Radau' \(scipy's\)\?"):
        simulate_batch(arm, q0, v0, T, method="radau", **kw)


def test_a_rollout_that_raises_stops_the_batch_naming_it(arm, pool):
    q0, v0, _ = inputs(arm, 3)
    ctrl = [batch_probe.Hold(np.full(arm.nu, 1e4)), batch_probe.Broken(), batch_probe.Hold(np.full(arm.nu, 1e4))]
    for workers in (1, pool, 2):  # (2: threads, the controller held at its rate)
        with pytest.raises(RolloutError, match=r"rollout 1 raised ValueError: pressure\(t, q, v\) has non-finite"):
            simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=ctrl, controller_rate=100.0, method="rk4", dt=1e-3,
                           workers=workers)


def test_plan_chunks_cover_every_item_once_and_shrink():
    for n, w in ((1, 2), (7, 2), (256, 2), (1000, 16)):
        chunks = plan_chunks(n, w)
        assert [i for c in chunks for i in c] == list(range(n))
        sizes = [len(c) for c in chunks]
        assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 1 and max(sizes) <= 64


@pytest.mark.slow
def test_a_killed_worker_costs_only_its_unfinished_items(tmp_path, pool):
    log = tmp_path / "ran.log"
    items = list(range(24))
    payload = Payload.of((str(log), 0.15))
    first = pool.pids()
    received = []
    killed = {}

    def kill_soon():
        while len(received) < 4:
            time.sleep(0.01)
        killed["before"] = set(received)
        os.kill(first[0], signal.SIGKILL)

    th = threading.Thread(target=kill_soon, daemon=True)
    th.start()
    for i, res in pool.map(batch_probe.square_logged, payload, items):
        received.append(i)
        assert res == i * i, (i, res)
    th.join(5)
    assert sorted(received) == items and pool.replaced >= 1
    assert first[0] not in pool.pids() and first[1] in pool.pids()
    ran = [int(x) for x in log.read_text().split()]
    assert sorted(set(ran)) == items
    again = {i for i in ran if ran.count(i) > 1}
    assert not again & killed["before"]  # nothing received before the kill ran again
    assert len(again) <= 2 * max(len(c) for c in plan_chunks(len(items), 2))  # at most what the dead worker held


def test_an_item_that_kills_every_worker_it_meets_is_given_up(pool):
    results = dict(pool.map(batch_probe.die_on_three, Payload.of(None), list(range(8)), retries=1))
    assert sorted(results) == list(range(8))
    assert isinstance(results[3], Lost) and results[3].attempts == 2 and "died 2 times" in results[3].message
    assert all(results[i] == -i for i in range(8) if i != 3)


@pytest.mark.slow
def test_a_worker_that_died_between_batches_is_replaced(pool):
    pid = pool.pids()[1]
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and _alive(pid):
        time.sleep(0.05)
    time.sleep(0.5)  # the pool's executor notices the death on its own thread
    replaced = pool.replaced
    results = dict(pool.map(batch_probe.square_logged, Payload.of((os.devnull, 0.0)), list(range(10))))
    assert results == {i: i * i for i in range(10)}
    assert pool.replaced == replaced + 1 and pid not in pool.pids()


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        return False


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_run_settings_are_checked_alike_in_simulate_and_simulate_batch():
    q0 = np.tile(CH1.neutral(), (2, 1))
    z = np.zeros(3)
    te = [0.0, 0.01]
    cases = [(dict(t_span="0 1"), "t_span"), (dict(t_span=(False, True)), "t_span"),
             (dict(t_span=(Decimal(0), Decimal("0.01"))), "t_span"), (dict(t_span=(0.0, 1e-300)), "t_span"),
             (dict(t_eval=[0.0, 0.005 + 0j]), "t_eval"), (dict(rtol="1e-6"), "rtol"), (dict(rtol=np.ones(2)), "rtol"),
             (dict(atol="x"), "atol"), (dict(method="rk4", dt="1e-3"), "dt"), (dict(method="rk4", dt=1 + 0j), "dt"),
             (dict(energies="no"), "energies"), (dict(events=3), "events"), (dict(events=[lambda t, q, v: 1]), "events")]
    for kw, name in cases:
        span = kw.pop("t_span", (0.0, 0.01))
        refused(lambda: simulate(CH1, CH1.neutral(), z, span, **kw), name)
        refused(lambda: simulate_batch(CH1, q0, z, span, **{"t_eval": te, "workers": 1, **kw}), name)
    refused(lambda: simulate(CH1, CH1.neutral(), z, (0, 0.01), progress="yes"), "progress")
    refused(lambda: simulate(CH1, CH1.neutral(), z, (0, 0.01), on_sample=3), "on_sample")
    refused(lambda: simulate_batch(CH1, q0, z, (0, 0.01), t_eval=te, workers=1, progress="yes"), "progress")


@pytest.mark.parametrize("workers", [10**9, 10**30, 0, -2, True, 2.0, "2"])
def test_absurd_worker_counts_are_refused_at_once(workers):
    """``workers=10**9`` made a pool of a billion slots (a hang, then the process killed)."""
    q0 = np.tile(CH1.neutral(), (2, 1))
    t0 = time.perf_counter()
    with deadline(20):
        refused(lambda: simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), t_eval=[0, 0.01], workers=workers), "workers")
    assert time.perf_counter() - t0 < 5.0
    refused(lambda: simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), t_eval=[0, 0.01], workers=1, retries=10**30),
            "retries")


@pytest.mark.parametrize("name, value", [("q0", np.ones((2, 3), bool)), ("q0", np.tile([0.1, 0, 0], (2, 1)) + 1e-3j),
                                         ("q0", "abc"), ("pressure", np.zeros((2, 3), bool)),
                                         ("pressure", np.zeros(3) + 1j), ("tau", np.zeros((2, 3), bool))])
def test_batch_arrays_are_never_cast_from_booleans_strings_or_complex_numbers(name, value):
    kw = dict(q0=np.tile(CH1.neutral(), (2, 1)), v0=np.zeros(3), t_span=(0, 0.01), t_eval=[0, 0.01], workers=1)
    kw[name] = value
    refused(lambda: simulate_batch(CH1, kw.pop("q0"), kw.pop("v0"), kw.pop("t_span"), **kw), name)


def test_valid_batch_layouts_give_the_plain_result():
    q0 = np.tile(CH1.neutral(), (2, 1))
    ref = simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), pressure=np.full((2, 3), 1e4), t_eval=[0, 0.01], workers=1)
    ro = np.full((2, 3), 1e4)
    ro.flags.writeable = False
    for Q, P in ((np.asfortranarray(q0), np.full((2, 3), 1e4)), (q0.astype(">f8"), ro), (q0, [[10000] * 3] * 2)):
        b = simulate_batch(CH1, Q, np.zeros(3), (0, 0.01), pressure=P, t_eval=[0, 0.01], workers=1)
        assert np.array_equal(b.q, ref.q)


def test_a_batch_checks_each_rollouts_cost_and_inputs_before_anything_runs():
    ch = soft_arm()
    q, v = ch.neutral(), np.zeros(ch.nv)
    with pytest.raises(BudgetError, match=r"duration 1 s / dt 1e-300 s"):
        simulate_batch(ch, q, v, (0, 1), method="rk4", dt=1e-300, workers=1)
    with pytest.raises(ValueError, match=r"pressure\[1\]\[0\] must be >= -101325 and <= 1e\+09 Pa, got 2e\+09 Pa"):
        simulate_batch(ch, q, v, (0, 0.1), pressure=np.array([np.zeros(9), np.full(9, 2e9)]), t_eval=[0.1],
                       workers=1)
    with pytest.raises(ValueError, match=r"client must be a scheduler address 'tcp://HOST:PORT', got 'not a url'"):
        simulate_batch(ch, q, v, (0, 0.1), t_eval=[0.1], client="not a url")


def test_a_batch_taker_gets_read_only_views_and_t_eval_stays_the_callers():
    class Taker:
        max_sim = 0.05

        def __call__(self, t, q, v, p):
            pass

        def record_batch(self, t, q, v, p, ke, pe):
            for a in (t, q, v, p):
                with pytest.raises(ValueError, match="read-only"):
                    a[...] = -1.0
            self.n = getattr(self, "n", 0) + len(t)

    ch = soft_arm()
    te = np.linspace(0, 0.2, 11)
    keep = te.copy()
    taker = Taker()
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), t_eval=te, on_sample=taker)
    np.testing.assert_array_equal(te, keep)
    np.testing.assert_array_equal(tr.t, keep)
    assert taker.n == 11 and tr.t.base is not te
    taker.max_sim = "soon"
    with pytest.raises(TypeError, match=r"on_sample.max_sim must be a real number"):
        simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), t_eval=te, on_sample=taker)


def test_no_more_workers_start_than_there_are_tasks():
    from qchain.batch.workers import engine_for

    assert engine_for(1024, tasks=1) is None  # one run: in this process
    pool = engine_for(1024, tasks=2)
    try:
        assert pool.workers == 2
    finally:
        pool.close()


def test_a_batch_index_is_no_boolean_and_a_logger_stream_must_seek():
    ch = soft_arm(1)
    b = simulate_batch(ch, ch.neutral(), np.zeros(3), (0, 0.01), t_eval=[0.01], workers=1,
                       pressure=np.zeros((2, 3)))
    with pytest.raises(IndexError, match="rollout index must be an int"):
        b[True]

    class NoSeek(io.RawIOBase):
        def writable(self):
            return True

        def write(self, data):
            return len(data)

    with pytest.raises(ValueError, match="a binary stream that can seek"):
        RunLogger(arm_info(), NoSeek(), quiet=True)


def test_a_batch_is_checked_as_a_whole_against_the_memory_budget():
    ch = soft_arm(2)
    with pytest.raises(BudgetError, match=r"budget.max_memory: .* \(1000000 rollouts x"):
        simulate_batch(ch, np.broadcast_to(ch.neutral(), (10**6, ch.nq)), np.zeros(ch.nv), (0, 1),
                       t_eval=np.linspace(0, 1, 1001), workers=1)


def test_a_batch_names_the_rollout_whose_pressure_is_out_of_range():
    from qchain import simulate_batch

    ch = pressure_arm()
    P = [np.full(6, 1e4), np.full(6, 1e4), Sine(np.full(6, 3e5), 1.0)]
    with deadline(60):
        with pytest.raises(ValueError, match=r"pressure\[2\]\[0\] must stay >= -101325"):
            simulate_batch(ch, np.tile(ch.neutral(), (3, 1)), np.zeros((3, 6)), (0.0, 0.1), pressure=P, workers=1,
                           t_eval=np.linspace(0.0, 0.1, 11))


# --------------------------------------------------------------------------------------
# Threads (issue 29): the compiled engine releases Python's lock, so a batch's rollouts run on
# threads of this process by default; processes where a rollout calls Python at every step.

def runs_beside(work) -> bool:
    """Whether this thread runs while another thread is inside ``work()``.

    With the switch interval at 100 s no thread takes Python's lock from another: the
    other thread keeps it from starting until it ends ``work()``, unless ``work()`` releases
    it. Nothing in the other thread releases the lock before ``work()`` (``Event.set`` does
    not)."""
    inside, done = threading.Event(), threading.Event()

    def target():
        inside.set()
        work()
        done.set()

    old = sys.getswitchinterval()
    sys.setswitchinterval(100.0)
    try:
        th = threading.Thread(target=target)
        th.start()
        inside.wait()
        beside = not done.is_set()
        th.join()
    finally:
        sys.setswitchinterval(old)
    return beside


def rk4_stretch(steps: int):
    """The rk4 stepper's compiled entry point and its arguments for ``steps`` steps of a
    one-segment arm (no samples written), as the driver calls it."""
    from qchain.sim.engine import steppers, warmup

    m, wk, it, _, c = warmup.standin("rk4", False)
    out = (np.array([1e9]), np.zeros((1, wk.q.size)), np.zeros((1, wk.v.size)), np.zeros((1, m.p_params.size)))
    fs, entry = warmup.prepare("rk4", m, wk, it, out, c)
    wk.q_chart[:] = warmup._standin_chain(False).neutral()
    it.tf[steppers.T] = it.tf[steppers.T0] = 0.0
    it.tf[steppers.DT] = it.tf[steppers.H] = 1e-5
    it.tf[steppers.MAX_STEP] = np.inf
    return lambda: entry(fs, m, wk, it, out, c, np.inf, 1 << 30, steps)


@numba.njit
def holds(n):
    """Compiled without ``nogil``: :func:`runs_beside` must see it hold the lock. (At module
    level: numba leaves a dead weak proxy behind a dispatcher made in a function, which
    ``isinstance`` over ``gc.get_objects()`` in tests/test_dask.py then trips on.)"""
    s = 0.0
    for i in range(n):
        s += np.sin(i * 1e-9)
    return s


def test_the_compiled_engine_releases_pythons_lock_while_it_steps():
    from qchain.sim.engine import steppers, system

    holds(10)
    assert not runs_beside(lambda: holds(30_000_000))  # (the probe can fail)
    rk4_stretch(10)()  # (loaded, and called once, before the probe)
    assert runs_beside(rk4_stretch(50_000))
    for fn in (*steppers.ADVANCE.values(), system.energies_batch):  # every entry point of a rollout
        assert fn.targetoptions.get("nogil") is True, fn


def test_rollouts_on_threads_are_bit_identical_to_simulate(arm):
    from qchain.batch.threads import ThreadPool

    B = 4
    q0, v0, P = inputs(arm, B, seed=3)
    P[2] = np.tile([4e6, 0.0, 0.0], arm.n)  # leaves the model: fails, the others go on
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    refs = [simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw) for i in range(B)]
    for workers in (2, None, ThreadPool(2)):
        b = simulate_batch(arm, q0, v0, T, pressure=P, workers=workers, **kw)
        assert b.meta["engine"] == "threads" and b.meta["workers"] == 2, workers
        assert list(b.success) == [True, True, False, True]
        for i in range(B):
            assert same(b[i], refs[i]), (workers, i)
        assert {r["worker"] for r in b.meta["rollouts"]} == {f"{os.uname().nodename}:{os.getpid()}"}
        assert all(r["thread"].startswith("qchain-rollout") for r in b.meta["rollouts"])
    fixed = dict(method="rk4", dt=1e-3)  # no t_eval: every step, the grid of the longest rollout
    b = simulate_batch(arm, q0, v0[0], (0.0, 0.05), pressure=P, workers=2, **fixed)
    assert b.meta["engine"] == "threads" and b.t.size == max(b.nsamples) == 51
    for i in range(B):
        assert same(b[i], simulate(arm, q0[i], v0[0], (0.0, 0.05), pressure=P[i], **fixed)), i


@pytest.mark.slow
def test_rollouts_that_call_python_at_every_step_run_on_processes_by_default(arm):
    from qchain.batch.threads import ThreadPool
    from qchain.sim.simulation import Event

    q0, v0, _ = inputs(arm, 2, seed=4)
    hold = batch_probe.Hold(np.full(arm.nu, 1e4))
    kw = dict(method="rk4", dt=1e-3, t_eval=np.linspace(0, 0.02, 5))
    refs = [simulate(arm, q0[i], v0[i], (0.0, 0.02), pressure=hold, **kw) for i in range(2)]
    b = simulate_batch(arm, q0, v0, (0.0, 0.02), pressure=hold, workers=2, **kw)  # a controller at every stage
    assert b.meta["engine"] == "local" and all(same(b[i], refs[i]) for i in range(2))
    b = simulate_batch(arm, q0, v0, (0.0, 0.02), pressure=hold, workers=ThreadPool(2), **kw)  # chosen: threads
    assert b.meta["engine"] == "threads" and all(same(b[i], refs[i]) for i in range(2))
    held = simulate_batch(arm, q0, v0, (0.0, 0.02), pressure=hold, controller_rate=500.0, workers=2, **kw)
    assert held.meta["engine"] == "threads"  # held: Python only at the controller's instants
    ev = [Event(batch_probe.Never(), name="never")]
    b = simulate_batch(arm, q0, v0, (0.0, 0.02), events=ev, workers=2, **kw)
    assert b.meta["engine"] == "local" and b.success.all()


@pytest.mark.slow
def test_a_script_without_a_main_guard_runs_a_batch_on_threads(tmp_path):
    script = tmp_path / "batch_script.py"
    script.write_text(
        "import numpy as np\n"
        "from qchain import Chain, Segment, simulate, simulate_batch\n"
        "from qchain.sim.inputs import Sine\n"
        f"arm = Chain([Segment(**{SEG!r}) for _ in range(2)], gravity=(0, 0, -9.81))\n"
        "P = [Sine(amplitude=np.full(6, 2e4), frequency=f, offset=np.full(6, 2e4)) for f in (1.0, 2.0, 3.0, 4.0)]\n"
        "te = np.linspace(0, 0.1, 6)\n"
        "b = simulate_batch(arm, np.tile(arm.neutral(), (4, 1)), np.zeros(arm.nv), (0, 0.1), pressure=P, t_eval=te,\n"
        "                   rtol=1e-4, atol=1e-6, workers=2)\n"
        "same = all(np.array_equal(b.q[i], simulate(arm, arm.neutral(), np.zeros(arm.nv), (0, 0.1), pressure=P[i],\n"
        "                                           t_eval=te, rtol=1e-4, atol=1e-6).q) for i in range(4))\n"
        "print(b.meta['engine'], b.meta['workers'], bool(b.success.all()), same)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                                       os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, env=env,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["threads", "2", "True", "True"], (r.stdout, r.stderr)


@pytest.mark.slow
def test_an_error_or_ctrl_c_on_threads_stops_the_rollouts_still_running(arm):
    q0, v0, _ = inputs(arm, 4, seed=5)
    long = dict(method="rk4", dt=1e-5, t_eval=np.linspace(0, 50.0, 11))  # minutes a rollout
    def rollout_threads():
        return [t for t in threading.enumerate() if t.name.startswith("qchain-rollout")]


    def interrupt():
        time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGINT)  # as Ctrl-C: to the process, whichever thread takes it

    threading.Thread(target=interrupt, daemon=True).start()
    with deadline(120, "a batch on threads after Ctrl-C"), pytest.raises(KeyboardInterrupt):
        simulate_batch(arm, q0, v0, (0.0, 50.0), pressure=np.full((4, arm.nu), 1e4), workers=2, **long)
    assert not rollout_threads()  # every rollout's thread ended
    ctrl = [batch_probe.Hold(np.full(arm.nu, 1e4)) for _ in range(4)]
    ctrl[1] = batch_probe.Broken()  # raises at once, on the second thread, while the first runs rollout 0
    with deadline(120, "a batch on threads after an error"), \
            pytest.raises(RolloutError, match=r"rollout 1 raised ValueError: pressure\(t, q, v\) has non-finite"):
        simulate_batch(arm, q0, v0, (0.0, 50.0), pressure=ctrl, controller_rate=100.0, workers=2, **long)
    assert not rollout_threads()


def test_a_start_whose_energies_overflow_fails_its_rollout_with_simulates_error(arm):
    """The starts' energies are checked in one compiled pass a batch; a start whose energies
    are not finite is checked again in Python by its rollout, which raises what simulate
    raises for it (and a batch of finite starts runs as simulate does)."""
    from qchain.errors import NonFiniteError

    q0, v0, P = inputs(arm, 3, seed=7)
    v0[1] = 1e200  # its kinetic energy overflows: inside the model, refused by simulate
    with pytest.raises(NonFiniteError, match=r"kinetic energy inf J") as ref:
        simulate(arm, q0[1], v0[1], T, pressure=P[1], t_eval=T_EVAL)
    from qchain.sim.budget import as_budget
    from qchain.sim.simulation import Runs

    runs = Runs(arm, T, method="radau5", budget=as_budget(None), dt=None, rtol=1e-6, atol=1e-8, max_step=np.inf,
                first_step=None, wall_limit=None, t_eval=T_EVAL, energies=True, controller_rate=None)
    assert list(runs.starts_finite(q0, v0)) == [True, False, True]
    for workers in (1, 2):
        with pytest.raises(RolloutError, match=r"rollout 1 raised NonFiniteError") as err:
            simulate_batch(arm, q0, v0, T, pressure=P, t_eval=T_EVAL, workers=workers)
        assert str(ref.value) in str(err.value), workers


def test_a_batch_of_schedules_runs_in_one_compiled_loop_bit_identical_to_simulate(arm):
    """Rollouts whose inputs are constants or qchain's schedules run in compiled loops
    (qchain.sim.engine.batched), serially and on threads: each what simulate gives, bit for
    bit, whatever the mix of input kinds (packed into rows of different lengths)."""
    from qchain.sim.inputs import Step, Table

    B = 5
    q0, v0, _ = inputs(arm, B, seed=11)
    nu = arm.nu
    P = [Sine(amplitude=np.full(nu, 2e4), frequency=3.0, phase=np.linspace(0, 1, nu), offset=np.full(nu, 2e4)),
         np.full(nu, 3e4),
         Step(time=0.1, after=np.full(nu, 4e4), before=np.zeros(nu)),
         Table(times=np.array([0.0, 0.1, 0.2]), values=np.array([np.zeros(nu), np.full(nu, 3e4), np.full(nu, 1e4)])),
         None]
    for kw in (dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL), dict(method="rk4", dt=1e-3, t_eval=T_EVAL),
               dict(method="midpoint", dt=5e-3, t_eval=T_EVAL)):
        refs = [simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw) for i in range(B)]
        for workers in (1, 2):
            b = simulate_batch(arm, q0, v0, T, pressure=P, workers=workers, **kw)
            assert b.meta["loop"] == "compiled", (kw["method"], workers)
            assert b.meta["engine"] == ("serial" if workers == 1 else "threads")
            for i in range(B):
                assert same(b[i], refs[i]), (kw["method"], workers, i)
                assert b.nsteps[i] == refs[i].meta["nsteps"] and b.meta["rollouts"][i]["njev"] == refs[i].meta["njev"]
            assert b.success.all() and np.all(b.wall > 0) and np.all(b.wall < b.meta["wall_s"] + 1e-3)
            assert 0.0 < b.meta["compile_s"] < b.meta["wall_s"]  # the loops' preparation, before they run
            names = {r["thread"] for r in b.meta["rollouts"]}
            assert names == {"MainThread"} if workers == 1 else all(n.startswith("qchain-rollout") for n in names)
    # a batch of one kind of input (packed and valued at t0 at once: qchain.sim.engine.schedules.pack_inputs)
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    sines = [Sine(amplitude=np.full(nu, 1e4 * (1 + i)), frequency=2.0 + i, phase=np.linspace(0, i, nu),
                  offset=np.full(nu, 2e4)) for i in range(B)]
    held = np.linspace(1e4, 4e4, B)[:, None] * np.ones(nu)
    for P, each in ((sines, sines), (held, list(held)), (sines[1], [sines[1]] * B)):
        refs = [simulate(arm, q0[i], v0[i], T, pressure=each[i], **kw) for i in range(B)]
        for workers in (1, 2):
            b = simulate_batch(arm, q0, v0, T, pressure=P, workers=workers, **kw)
            assert b.meta["loop"] == "compiled"
            assert all(same(b[i], refs[i]) for i in range(B)), (type(P).__name__, workers)


def test_each_threads_arrays_are_copied_onto_cache_lines_of_their_own():
    """A compiled loop's thread places its model, workspace and integrator in one buffer of its
    own (qchain.sim.engine.batched._private): every writable C-ordered array copied, on lines no
    other array touches; read-only or strided ones, and any tree whose arrays overlap, left as
    they are (their numba types and their aliasing unchanged)."""
    from collections import namedtuple

    from qchain.sim.engine.batched import _APART, _private

    Pair = namedtuple("Pair", "a b")
    frozen = np.arange(4.0)
    frozen.flags.writeable = False
    strided = np.zeros((3, 4)).T
    tree = (Pair(np.arange(3.0), np.ones((2, 5), dtype=np.int64)), np.zeros(1, dtype=np.complex128), frozen, strided,
            np.zeros(0), Pair(np.array([-1, 0]), np.full(7, 2.0)))
    out = _private(tree)
    assert type(out[0]) is Pair and type(out[5]) is Pair
    pairs = [(tree[0].a, out[0].a), (tree[0].b, out[0].b), (tree[1], out[1]), (tree[4], out[4]), (tree[5].a, out[5].a),
             (tree[5].b, out[5].b)]
    spans = []
    for old, new in pairs:
        assert new is not old and not np.shares_memory(new, old) and np.array_equal(new, old)
        assert new.dtype == old.dtype and new.shape == old.shape and new.flags.c_contiguous and new.flags.writeable
        if new.size:
            assert new.ctypes.data % _APART == 0
            spans.append((new.ctypes.data, new.ctypes.data + new.nbytes))
    spans.sort()
    assert all(b0 - e >= _APART for (_, e), (b0, _) in zip(spans, spans[1:]))  # a line apart, at least
    assert out[2] is frozen and out[3] is strided
    again = _private(tree)
    assert not np.shares_memory(again[0].a, out[0].a)  # a buffer a call
    base = np.zeros(8)
    overlapping = (base, base[2:5])
    assert _private(overlapping) is overlapping


def test_a_compiled_loop_stops_a_rollout_at_the_step_budget_as_simulate_does(arm):
    """Where a run stops on ``budget.max_steps`` depends on its stretches (a stepper call
    counts accepted steps; the rejected ones of its last call go beyond the budget), in
    simulate as in a batch: the same message, the samples both have alike, and the energies
    of a rollout that stopped early computed on its own samples."""
    from qchain.sim.budget import Budget

    q0, v0, P = inputs(arm, 3, seed=12)
    kw = dict(method="radau5", rtol=1e-8, atol=1e-10, t_eval=T_EVAL, budget=Budget(max_steps=60))
    refs = [simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw) for i in range(3)]
    assert not any(r.success for r in refs)  # (the budget bites)
    for workers in (1, 2):
        b = simulate_batch(arm, q0, v0, T, pressure=P, workers=workers, **kw)
        assert b.meta["loop"] == "compiled"
        for i in range(3):
            tr, ref = b[i], refs[i]
            assert tr.status == ref.status == -1 and tr.message.startswith(
                "step budget exceeded: budget.max_steps = 60, ") and "rejected), t reached = " in tr.message
            meta = b.meta["rollouts"][i]
            assert 60 <= meta["nsteps"] + meta["nreject"] <= 60 + meta["nreject"]
            K = min(len(tr.t), len(ref.t))
            assert K >= 1 and np.array_equal(tr.q[:K], ref.q[:K]) and np.array_equal(tr.p[:K], ref.p[:K])
            assert np.array_equal(tr.kinetic_energy[:K], ref.kinetic_energy[:K])
            assert b.nsamples[i] < T_EVAL.size and np.isnan(b.kinetic_energy[i, b.nsamples[i]:]).all()


def test_a_batch_that_needs_python_between_steps_runs_in_the_python_loop(arm):
    from qchain.batch.threads import ThreadPool

    q0, v0, _ = inputs(arm, 2, seed=13)
    hold = batch_probe.Hold(np.full(arm.nu, 1e4))
    kw = dict(method="rk4", dt=1e-3, t_eval=np.linspace(0, 0.02, 5))
    b = simulate_batch(arm, q0, v0, (0.0, 0.02), pressure=hold, controller_rate=500.0, workers=ThreadPool(2), **kw)
    assert b.meta["loop"] == "python" and b.success.all()
    b = simulate_batch(arm, q0, v0, (0.0, 0.02), pressure=np.full(arm.nu, 1e4), wall_limit=60.0, workers=1, **kw)
    assert b.meta["loop"] == "python" and b.success.all()


def test_a_batch_of_tendon_tensions_equals_simulate_and_records_them():
    """simulate_batch(tension=): each rollout's tensions (a constant, a sine, a table, or one
    input for all) give what simulate gives bit for bit, serial and on threads, with the
    samples' tensions in ``batch.tension``; a negative tension or a chain without tendons is
    refused where it enters, naming the rollout."""
    from qchain import Tendon
    from qchain.sim.inputs import Table

    ch = Chain([Segment(**SEG) for _ in range(2)], gravity=(0, 0, -9.81),
               tendons=[Tendon(radius=0.012, angle=0.0, end=0), Tendon(radius=0.012, angle=2.0, pitch=0.5)])
    B = 3
    q0, v0, P = inputs(ch, B)
    Tn = [np.array([2.0, 0.5]), Sine(amplitude=[1.0, 0.5], frequency=2.0, offset=[1.5, 1.0]),
          Table([0.0, 0.1, 0.3], [[0.0, 0.0], [3.0, 1.0], [1.0, 2.0]])]
    kw = dict(method="radau5", rtol=1e-5, atol=1e-7, t_eval=T_EVAL)
    refs = [simulate(ch, q0[i], v0[i], T, pressure=P[i], tension=Tn[i], **kw) for i in range(B)]
    for workers in (1, 2):
        b = simulate_batch(ch, q0, v0, T, pressure=P, tension=Tn, workers=workers, **kw)
        assert b.tension.shape == (B, T_EVAL.size, 2)
        for i in range(B):
            assert same(b[i], refs[i]) and np.array_equal(b[i].tension, refs[i].tension)
            assert np.array_equal(b.tension[i], refs[i].tension)
    assert np.allclose(b.tension[2, 2], [0.0 + 3.0 * T_EVAL[2] / 0.1, T_EVAL[2] / 0.1])  # the table at t = 0.04 s
    shared = simulate_batch(ch, q0, v0, T, pressure=P, tension=Tn[1], workers=1, **kw)
    assert same(shared[0], simulate(ch, q0[0], v0[0], T, pressure=P[0], tension=Tn[1], **kw))
    slack = simulate_batch(ch, q0, v0, T, pressure=P, workers=1, **kw)  # no tension: compiled loops, tendons slack
    assert slack.meta["loop"] == "compiled" and np.array_equal(slack.tension, np.zeros((B, T_EVAL.size, 2)))
    with pytest.raises(ValueError, match=r"tension\[1\]\[0\] must be >= 0 and <= 1e\+09 N, got -0.5 N"):
        simulate_batch(ch, q0, v0, T, pressure=P, tension=[Tn[0], np.array([-0.5, 1.0]), Tn[2]], workers=1, **kw)
    with pytest.raises(ValueError, match="q0 has 3, v0 has 3, tension has 2 rollouts"):
        simulate_batch(ch, q0, v0, T, tension=Tn[:2], workers=1, **kw)
    with pytest.raises(ValueError, match="tension is given but the chain has no tendons"):
        simulate_batch(two_segment_arm(), q0, v0, T, tension=Tn, workers=1, **kw)
