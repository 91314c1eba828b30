"""Batches and sweeps on a real dask.distributed LocalCluster (127.0.0.1, 2 worker processes):
the same results as in this process."""

import logging

import pyarrow.parquet as pq
import pytest

import distributed  # the test extra installs dask[distributed]

from qchain import simulate_batch
from qchain.simulate import simulate
from qchain.sweeps import main
from test_batch import T, T_EVAL, inputs, same, two_segment_arm
from test_sweep import BASE, deterministic


@pytest.fixture(scope="module")
def arm():
    return two_segment_arm()


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, silence_logs=logging.ERROR) as c:
        with distributed.Client(c) as client:
            client.wait_for_workers(2, timeout=120)
            yield c, client


def test_a_batch_on_dask_equals_simulate(arm, cluster):
    _, client = cluster
    B = 6
    q0, v0, P = inputs(arm, B, seed=5)
    kw = dict(method="radau5", rtol=1e-4, atol=1e-6, t_eval=T_EVAL)
    b = simulate_batch(arm, q0, v0, T, pressure=P, client=client, **kw)
    assert b.meta["engine"] == "dask" and b.meta["workers"] == 2 and b.success.all()
    for i in range(B):
        assert same(b[i], simulate(arm, q0[i], v0[i], T, pressure=P[i], **kw)), i
    assert len({m["worker"] for m in b.meta["rollouts"]}) == 2  # both workers took rollouts


def test_qchain_sweep_dask_gives_the_same_table(cluster, tmp_path):
    c, _ = cluster
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
