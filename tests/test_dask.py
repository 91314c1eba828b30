"""Batches and sweeps on a real dask.distributed cluster on 127.0.0.1 (a LocalCluster of 2
worker processes; separate scheduler and worker processes where a test kills them): the same
results as in this process; a worker killed mid-sweep costs only its unfinished runs, which run
again; a cluster left without workers or without its scheduler ends the sweep with a clear error
within a bound, not a hang. Every test has a deadline: a hang fails it with every thread's stack."""

import contextlib
import gc
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import dask
import numpy as np
import psutil
import pyarrow.parquet as pq
import pytest

import distributed  # the test extra installs dask[distributed]

import batch_probe
import dask_probe
from dask_probe import read_log
from helpers import deadline
from qchain import simulate_batch, sweep
from qchain.batch.rollouts import RolloutError
from qchain.scene import parse_scene
from qchain.sim.simulation import simulate
from qchain.batch.sweeps import load_sweep, run_sweep
from qchain.cli.sweep import main
from qchain.batch.workers import _DASK_FACTOR, ClusterLost, DaskEngine, Payload, plan_chunks
from test_batch import T, T_EVAL, inputs, same, two_segment_arm
from test_sweep import BASE, deterministic

pytestmark = pytest.mark.slow  # see tests/README.md

TESTS = Path(__file__).parent
DEADLINE = 120  # s, for any one test of this file


@pytest.fixture(autouse=True)
def no_hang(request):
    with deadline(DEADLINE, request.node.name):
        yield


@pytest.fixture(scope="module")
def arm():
    return two_segment_arm()


def live_pids(client, n: int = 2, timeout: float = 60) -> list[int]:
    """The pids of the cluster's ``n`` live workers, once it has them (a killed worker's nanny
    starts another)."""
    end = time.monotonic() + timeout
    while True:
        pids = [p for p in client.run(os.getpid, on_error="return").values() if isinstance(p, int)]
        if len(pids) == n:
            return sorted(pids)
        assert time.monotonic() < end, f"the cluster has {len(pids)} live workers after {timeout} s, not {n}"
        time.sleep(0.1)


@pytest.fixture(scope="module")
def cluster():
    """2 worker processes of 1 thread, everything on 127.0.0.1. Tests kill its workers (their
    nannies start others). A LocalCluster closes a worker for good when its name is missing
    from the scheduler 15 s after one of its deaths (``distributed.deploy.lost-worker-timeout``):
    a worker killed twice about 15 s apart is missing then, while its nanny starts it again,
    and the cluster would go on with one worker. That timeout is out of reach here."""
    with dask.config.set({"distributed.deploy.lost-worker-timeout": "1h"}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                      dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR) as c:
            with distributed.Client(c) as client:
                live_pids(client)
                yield c, client


def test_a_batch_on_dask_equals_simulate(arm, cluster):
    _, client = cluster
    live_pids(client)
    B = 6
    q0, v0, P = inputs(arm, B, seed=5)
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    b = simulate_batch(arm, q0, v0, T, pressure=P, client=client, **kw)
    assert b.meta["engine"] == "dask" and b.meta["workers"] == 2 and b.success.all()
    for i in range(B):
        assert same(b[i], simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw)), i
    assert len({m["worker"] for m in b.meta["rollouts"]}) == 2  # both workers took rollouts


def test_qchain_sweep_dask_gives_the_same_table(cluster, tmp_path):
    c, client = cluster
    live_pids(client)
    (tmp_path / "base.toml").write_text(BASE)
    f = tmp_path / "s.toml"
    f.write_text(f'scene = "base.toml"\nfolder = "{tmp_path / "dask"}"\n[sampling]\nkind = "lhs"\nn = 6\nseed = 2\n'
                 '[[axes]]\nkey = "segments[*].youngs_modulus"\nrange = [8e4, 1.5e5]\n'
                 '[[axes]]\nkey = "pressure.frequency"\nrange = [1.0, 3.0]\n')
    assert main([str(f), "--dask", c.scheduler_address, "--no-progress"]) == 0
    on_dask = pq.read_table(tmp_path / "dask" / "summary.parquet")
    assert main([str(f), "--workers", "1", "--out", str(tmp_path / "serial"), "--no-progress"]) == 0
    serial = pq.read_table(tmp_path / "serial" / "summary.parquet")
    assert on_dask.num_rows == 6 and all(on_dask.column("success").to_pylist())
    assert deterministic(on_dask).equals(deterministic(serial))
    assert len(set(on_dask.column("worker").to_pylist()) - set(serial.column("worker").to_pylist())) == 2


def test_a_scheduler_address_is_enough(arm, cluster):
    c, _ = cluster
    q0, v0, P = inputs(arm, 2, seed=7)
    b = simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=P, client=c.scheduler_address, method="rk4", dt=1e-3)
    for i in range(2):
        assert same(b[i], simulate(arm, q0[i], v0[i], (0.0, 0.05), pressure=P[i], method="rk4", dt=1e-3))
    with pytest.raises(ValueError, match="give workers or client, not both"):
        simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=P, client=c.scheduler_address, workers=2, method="rk4",
                       dt=1e-3)


def test_a_rollout_that_raises_on_dask_stops_the_batch_naming_it(arm, cluster):
    """The exception a task raised is raised here, as on the local engine."""
    _, client = cluster
    q0, v0, _ = inputs(arm, 3)
    ctrl = [batch_probe.Hold(np.full(arm.nu, 1e4)), batch_probe.Broken(), batch_probe.Hold(np.full(arm.nu, 1e4))]
    with pytest.raises(RolloutError, match=r"rollout 1 raised ValueError: pressure\(t, q, v\) has non-finite"):
        simulate_batch(arm, q0, v0, (0.0, 0.05), pressure=ctrl, controller_rate=100.0, method="rk4", dt=1e-3,
                       client=client)


# ------------------------------------------------------------------------------ lost workers

DAMPINGS = [round(0.011 + 0.001 * k, 3) for k in range(12)]  # run i has segment 0's damping DAMPINGS[i]
PAUSE = 0.4  # s a run takes (dask_probe.logged waits that long between its start and end lines)


def journal_rows(journal: Path) -> list[dict]:
    """The sweep journal's rows written so far (a line being written is left for later)."""
    try:
        text = journal.read_text()
    except FileNotFoundError:
        return []
    return [json.loads(x) for x in text[:text.rfind("\n") + 1].splitlines()]


@pytest.fixture(scope="module")
def local_result(tmp_path_factory):
    """The sweep on the local engine (2 worker processes): every run's row and trajectory."""
    tmp = tmp_path_factory.mktemp("local")
    scene = parse_scene(BASE, path=tmp / "base.toml")
    res = sweep(scene, {"segments[0].damping": DAMPINGS}, set={"description": f"probe {tmp / 'ran.log'} 0"},
                workers=2, trajectories=True, progress=False, metrics="dask_probe:logged")
    assert res.complete and res.engine == "local" and res.n_failed == 0
    return res


@pytest.mark.parametrize("moment", ["first start", "mid-run"])
def test_a_dask_worker_killed_mid_sweep_costs_only_its_unfinished_runs(cluster, local_result, tmp_path, moment):
    """A worker killed as the sweep's first run starts (before any result came back), or in
    the middle of a run after some of its runs came back: the sweep completes with every
    run's row and trajectory equal to the local engine's; the runs received before the kill
    ran once; the runs run twice are exactly the killed worker's unfinished ones."""
    _, client = cluster
    victim = live_pids(client)[0]
    log = tmp_path / "ran.log"
    journal = tmp_path / "out" / "runs.jsonl"
    chunk_of = {DAMPINGS[i]: k for k, c in enumerate(plan_chunks(len(DAMPINGS), 2, factor=_DASK_FACTOR)) for i in c}

    def received() -> set:
        return {row["segments[0].damping"] for row in journal_rows(journal)}

    def ready():
        """The damping of the run to kill the victim in, once the moment has come."""
        lines = read_log(log)
        if moment == "first start":
            return lines[0][1] if lines else None
        started = {d for kind, d, pid in lines if kind == "start" and pid == victim}
        ended = {d for kind, d, pid in lines if kind == "end" and pid == victim}
        running = started - ended
        got = received()
        if len(running) != 1 or len(got) < 3:
            return None
        (r,) = running
        # its runs of earlier tasks all came back: no finished result of the victim is in flight
        return r if all(d in got for d in ended if chunk_of[d] != chunk_of[r]) else None

    seen: dict = {}

    def kill():
        end = time.monotonic() + 90
        while time.monotonic() < end:
            r = ready()
            if r is not None and moment == "mid-run":
                time.sleep(0.1)  # the release of the tasks it handed back reaches the scheduler
                if ready() != r:
                    continue
            if r is not None:
                seen["received"] = received()
                os.kill(victim, signal.SIGKILL)
                seen["run"] = r
                return
            time.sleep(0.01)

    th = threading.Thread(target=kill, daemon=True)
    th.start()
    scene = parse_scene(BASE, path=tmp_path / "base.toml")
    res = sweep(scene, {"segments[0].damping": DAMPINGS}, set={"description": f"probe {log} {PAUSE}"}, client=client,
                folder=tmp_path / "out", trajectories=True, progress=False, metrics="dask_probe:logged")
    th.join(10)
    assert "run" in seen, "the moment to kill never came"
    assert victim not in live_pids(client)  # it died, and its nanny started another worker

    # the sweep completed, with the local engine's results
    assert res.complete and res.table.num_rows == len(DAMPINGS) and res.n_failed == 0
    assert sorted(json.loads(x)["run"] for x in journal.read_text().splitlines()) == list(range(len(DAMPINGS)))
    assert deterministic(res.table).equals(deterministic(local_result.table))
    for i in range(len(DAMPINGS)):
        a, b = res.trajectory(i), local_result.trajectory(i)
        assert all(np.array_equal(getattr(a, k), getattr(b, k))
                   for k in ("t", "q", "v", "p", "kinetic_energy", "potential_energy")), i
        assert np.array_equal(res.tip_path(i), local_result.tip_path(i)), i

    # which runs ran where, and how often
    lines = read_log(log)
    starts = {d: [pid for kind, dd, pid in lines if kind == "start" and dd == d] for d in DAMPINGS}
    assert all(starts[d] for d in DAMPINGS)
    before = seen["received"]
    if moment == "first start":
        assert before == set()
    else:
        assert len(before) >= 3 and seen["run"] not in before
    assert all(len(starts[d]) == 1 for d in before)  # finished runs are not computed again
    again = {d for d in DAMPINGS if len(starts[d]) > 1}
    unfinished = {d for d in DAMPINGS if victim in starts[d]} - before  # the victim's runs it did not hand back
    assert again == unfinished  # only those, and all of them, ran again
    assert all(len(starts[d]) == 2 and starts[d][0] == victim and starts[d][1] != victim for d in again)
    if moment == "mid-run":
        assert seen["run"] in again


def test_a_task_dask_gives_up_on_is_sent_again_as_single_items(cluster, tmp_path):
    """Dask gives a task up (KilledWorker) once its workers died more than the scheduler's
    allowed-failures times (0 here): the engine sends its items again one by one, and every
    item gets its result."""
    _, client = cluster
    live_pids(client)

    def allowed_failures(n, dask_scheduler=None):
        old = dask_scheduler.allowed_failures
        dask_scheduler.allowed_failures = n
        return old

    old = client.run_on_scheduler(allowed_failures, 0)
    try:
        got = dict(DaskEngine(client).map(dask_probe.die_once, Payload.of(str(tmp_path / "died")), list(range(8))))
    finally:
        client.run_on_scheduler(allowed_failures, old)
    assert (tmp_path / "died").exists()  # item 3 did kill its worker once
    assert got == {i: -i for i in range(8)}


# ------------------------------------------------------------------------------ lost cluster

LOST_TIMEOUT = 3  # s, qchain.lost-timeout for the sweeps below
LOST_PAUSE = 0.1  # s a run takes in them: runs are still to come when the first ones are back
ENV = dict(os.environ, DASK_QCHAIN__LOST_TIMEOUT=str(LOST_TIMEOUT),
           PYTHONPATH=os.pathsep.join([str(TESTS)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))


def _dask(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", *args], env=ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


@pytest.fixture
def own_cluster(tmp_path):
    """A scheduler and two worker processes without nannies (a killed worker stays dead), on
    127.0.0.1; all of them stopped afterwards."""
    info = tmp_path / "scheduler.json"
    procs = [_dask("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                   "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(info))]
    try:
        end = time.monotonic() + 60
        address = None
        while address is None:
            assert time.monotonic() < end and procs[0].poll() is None, "the scheduler did not start"
            with contextlib.suppress(FileNotFoundError, ValueError, KeyError):  # not there, or half written
                address = json.loads(info.read_text())["address"]
            time.sleep(0.05)
        procs += [_dask("distributed.cli.dask_worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                        "--dashboard-address", "127.0.0.1:0", "--host", "127.0.0.1", "--death-timeout", "10")
                  for _ in range(2)]
        with distributed.Client(address, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=60)
        yield address, procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(timeout=30)


def sweep_file(tmp_path) -> Path:
    """The sweep of the tests above as a sweep file (runs of LOST_PAUSE s), its results in
    tmp_path/out."""
    (tmp_path / "base.toml").write_text(BASE)
    f = tmp_path / "s.toml"
    f.write_text(f'scene = "base.toml"\nfolder = "{tmp_path / "out"}"\nmetrics = "dask_probe:logged"\n'
                 f'[set]\ndescription = "probe {tmp_path / "ran.log"} {LOST_PAUSE}"\n'
                 f'[[axes]]\nkey = "segments[0].damping"\nvalues = {json.dumps(DAMPINGS)}\n')
    return f


def first_runs_back(journal: Path, still_running) -> None:
    """Wait until the sweep journaled its first run (``still_running()`` stays true meanwhile)."""
    while not (journal.is_file() and journal.read_text().count("\n") >= 1):
        assert still_running(), "the sweep ended before its first run came back"
        time.sleep(0.02)


def kept_runs(tmp_path) -> list[int]:
    """The runs the stopped sweep kept: each once in its journal, all in its summary."""
    rows = [json.loads(x)["run"] for x in (tmp_path / "out" / "runs.jsonl").read_text().splitlines()]
    assert 1 <= len(rows) < len(DAMPINGS) and len(set(rows)) == len(rows)
    assert sorted(pq.read_table(tmp_path / "out" / "summary.parquet").column("run").to_pylist()) == sorted(rows)
    return rows


def test_every_worker_lost_mid_sweep_ends_qchain_sweep_with_a_clear_error(own_cluster, tmp_path):
    """Both workers killed after the first runs came back: `qchain sweep --dask` (the only
    Dask client of its process) stops LOST_TIMEOUT s later with an error saying so, keeps
    the runs it finished, and leaves no process behind."""
    address, procs = own_cluster
    f = sweep_file(tmp_path)
    cli = subprocess.Popen([sys.executable, "-c", "import sys; from qchain.cli.sweep import main; sys.exit(main(sys.argv[1:]))",
                            str(f), "--dask", address, "--no-progress"], env=ENV, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    family: set = set()  # the sweep's own child processes, seen while it ran

    def running() -> bool:
        with contextlib.suppress(psutil.NoSuchProcess):
            family.update(psutil.Process(cli.pid).children(recursive=True))
        return cli.poll() is None

    try:
        first_runs_back(tmp_path / "out" / "runs.jsonl", running)
        for p in procs[1:]:
            p.kill()
        killed = time.monotonic()
        out, err = cli.communicate(timeout=60)
        took = time.monotonic() - killed
    finally:
        if cli.poll() is None:
            cli.kill()
            cli.communicate()
    assert cli.returncode == 1, err
    assert f"the Dask cluster at {address}: no worker for" in err, err
    assert f"lost_timeout = {LOST_TIMEOUT} s" in err and "(run the sweep again to compute the rest)" in err, err
    assert LOST_TIMEOUT < took < LOST_TIMEOUT + 25, took  # it waited LOST_TIMEOUT after the loss, within a bound
    rows = kept_runs(tmp_path)
    assert f"the {len(rows)} of {len(DAMPINGS)} runs finished are in" in err, err
    assert not [p for p in family if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


def open_clients() -> set:
    return {id(o) for o in gc.get_objects() if isinstance(o, distributed.Client) and o.status != "closed"}


def test_a_scheduler_lost_mid_sweep_ends_it_with_a_clear_error(own_cluster, tmp_path):
    """The scheduler killed after the first runs came back: the sweep (given the scheduler's
    address) raises ClusterLost LOST_TIMEOUT s later, keeps the runs it finished, closes the
    client it opened and starts no process."""
    address, procs = own_cluster
    spec = load_sweep(sweep_file(tmp_path))
    me = psutil.Process()
    before = set(me.children(recursive=True))
    clients = open_clients()
    seen: dict = {}

    def kill():
        first_runs_back(tmp_path / "out" / "runs.jsonl", lambda: "error" not in seen)
        procs[0].kill()
        seen["killed"] = time.monotonic()

    th = threading.Thread(target=kill, daemon=True)
    th.start()
    with dask.config.set({"qchain.lost-timeout": LOST_TIMEOUT}):
        with pytest.raises(ClusterLost) as err:
            try:
                run_sweep(spec, client=address, progress=False)
            finally:
                seen["error"] = time.monotonic()
    th.join(10)
    took = seen["error"] - seen["killed"]
    assert f"the Dask cluster at {address}: the scheduler does not answer for" in str(err.value)
    assert f"lost_timeout = {LOST_TIMEOUT} s" in str(err.value) and "run the sweep again" in str(err.value)
    assert LOST_TIMEOUT < took < LOST_TIMEOUT + 25, took
    kept_runs(tmp_path)
    assert open_clients() <= clients  # the client it opened is closed
    assert set(me.children(recursive=True)) - before - {psutil.Process(p.pid) for p in procs if p.poll() is None} \
        == set()  # it started no process


def test_a_scheduler_that_cannot_be_reached_is_a_clear_error(tmp_path):
    """A scheduler address where nothing listens: an error naming it within the connect
    timeout, not a wait; nothing runs."""
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    scene = parse_scene(BASE, path=tmp_path / "base.toml")
    t0 = time.monotonic()
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        with pytest.raises(ClusterLost, match=f"cannot reach the Dask scheduler at {address}"):
            sweep(scene, {"segments[0].damping": [0.01, 0.02]}, client=address, folder=tmp_path / "out", progress=False)
    assert time.monotonic() - t0 < 20
    assert (tmp_path / "out" / "runs.jsonl").read_text() == ""  # nothing ran
