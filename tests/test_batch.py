"""Batched rollouts (qchain.simulate_batch) and the local worker pool (qchain.batch.workers):
bit-identical to simulate at any worker count, failures kept to their rollout, lost workers."""

import os
import signal
import threading
import time

import numpy as np
import pytest

import batch_probe
from qchain import Chain, Segment, simulate_batch
from qchain.batch.rollouts import RolloutError
from qchain.sim.inputs import Sine
from qchain.sim.simulation import simulate
from qchain.batch.workers import Lost, LocalPool, Payload, plan_chunks

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.02)
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


def test_a_rollout_that_raises_stops_the_batch_naming_it(arm, pool):
    q0, v0, _ = inputs(arm, 3)
    ctrl = [batch_probe.Hold(np.full(arm.nu, 1e4)), batch_probe.Broken(), batch_probe.Hold(np.full(arm.nu, 1e4))]
    for workers in (1, pool):
        with pytest.raises(RolloutError, match=r"rollout 1 raised ValueError: pressure\(t, q, v\) has non-finite"):
            simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=ctrl, controller_rate=100.0, method="rk4", dt=1e-3,
                           workers=workers)


def test_plan_chunks_cover_every_item_once_and_shrink():
    for n, w in ((1, 2), (7, 2), (256, 2), (1000, 16)):
        chunks = plan_chunks(n, w)
        assert [i for c in chunks for i in c] == list(range(n))
        sizes = [len(c) for c in chunks]
        assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 1 and max(sizes) <= 64


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
