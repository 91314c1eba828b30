"""Sweeps (qchain.sweep, qchain sweep): axes and sampling, the sweep file, per-run metrics,
results identical whatever the engine, and a killed sweep resumed without recomputing."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from qchain import sweep
from qchain.scene import parse_scene
from qchain.batch.sweep_spec import Axis, SweepError, SweepSpec, apply_values, load_sweep, parse_key, validate_runs
from qchain.batch.sweeps import METRICS, TIMING_COLUMNS, summary_metrics
from qchain.cli.sweep import main
from test_batch import _alive
from helpers import SEGMENTS_TOML

TESTS = Path(__file__).parent

BASE = """
name = "sweep base"
gravity = [0.0, 0.0, -9.81]
""" + SEGMENTS_TOML + """[pressure]
type = "sine"
offset = [2e4, 2e4, 2e4, 2e4, 2e4, 2e4]
amplitude = [2e4, 2e4, 2e4, 2e4, 2e4, 2e4]
phase = [0.0, 2.0943951023931953, 4.1887902047863905, 0.0, 2.0943951023931953, 4.1887902047863905]
frequency = 2.0
[simulation]
duration = 0.2
method = "radau5"
rtol = 1e-3
atol = 1e-5
[output]
sample_rate = 50.0
"""


@pytest.fixture
def base(tmp_path):
    p = tmp_path / "base.toml"
    p.write_text(BASE)
    return p


def deterministic(table):
    return table.drop_columns([c for c in TIMING_COLUMNS if c in table.column_names])


# ------------------------------------------------------------------------------ what runs


def test_keys_values_and_each_segment():
    assert parse_key("segments[0].chamber_radius") == ["segments", 0, "chamber_radius"]
    assert parse_key("segments[*].radius") == ["segments", "*", "radius"]
    with pytest.raises(ValueError, match="does not start with a scene key"):
        parse_key("segmnts[0].radius")
    with pytest.raises(ValueError, match="has 'radius!'"):
        parse_key("segments[0].radius!")
    raw = {"segments": [{"count": 2, "radius": 0.01}, {"radius": 0.02}], "pressure": {"type": "constant"}}
    out = apply_values(raw, {"segments[*].radius": 0.03, "segments[0].count": 3,
                             "pressure.value": {"each_segment": [1.0, 2.0, 3.0]}})
    assert [s["radius"] for s in out["segments"]] == [0.03, 0.03] and raw["segments"][0]["radius"] == 0.01
    assert out["pressure"]["value"] == [1.0, 2.0, 3.0] * 4  # 3 + 1 segments
    with pytest.raises(ValueError, match="index 5 is past the end of an array of 2"):
        apply_values(raw, {"segments[5].radius": 0.1})


def test_grid_random_and_latin_hypercube_sampling(base):
    sc = parse_scene(BASE, path=base)
    grid = SweepSpec(scene=sc, axes=[Axis("segments[0].damping", values=(0.01, 0.02)),
                                     Axis("simulation.rtol", range=(1e-4, 1e-2), num=3, log=True)])
    pts = grid.points()
    assert len(pts) == 6 and pts[0] == {"segments[0].damping": 0.01, "simulation.rtol": pytest.approx(1e-4)}
    assert [p["simulation.rtol"] for p in pts[:3]] == pytest.approx([1e-4, 1e-3, 1e-2])  # first axis outermost
    axes = [Axis("segments[0].youngs_modulus", range=(5e4, 2e5)), Axis("segments[0].count", range=(1, 4),
                                                                        integer=True)]
    lhs = SweepSpec(scene=sc, axes=axes, sampling="lhs", n=20, seed=3).points()
    again = SweepSpec(scene=sc, axes=axes, sampling="lhs", n=20, seed=3).points()
    other = SweepSpec(scene=sc, axes=axes, sampling="lhs", n=20, seed=4).points()
    assert lhs == again and lhs != other
    E = np.array([p["segments[0].youngs_modulus"] for p in lhs])
    assert np.all((E >= 5e4) & (E <= 2e5))
    # Latin hypercube: each of the 20 equal strata of the range holds exactly one sample
    assert sorted(np.floor((E - 5e4) / (1.5e5 / 20)).astype(int).tolist()) == list(range(20))
    counts = [p["segments[0].count"] for p in lhs]
    assert set(counts) == {1, 2, 3, 4} and all(isinstance(c, int) for c in counts)
    rnd = SweepSpec(scene=sc, axes=axes, sampling="random", n=50, seed=0).points()
    assert len(rnd) == 50 and {p["segments[0].count"] for p in rnd} == {1, 2, 3, 4}
    with pytest.raises(ValueError, match="lhs sampling needs n"):
        SweepSpec(scene=sc, axes=axes, sampling="lhs")
    with pytest.raises(ValueError, match="a range on a grid needs num"):
        SweepSpec(scene=sc, axes=axes)
    with pytest.raises(ValueError, match="is on two axes"):
        SweepSpec(scene=sc, axes=[Axis("simulation.rtol", values=(1e-3,)), Axis("simulation.rtol", values=(1e-4,))])


def test_sweep_file_problems_are_listed(tmp_path, base):
    p = tmp_path / "bad.toml"
    p.write_text(f'scene = "{base.name}"\nsamplng = 1\n[sampling]\nkind = "lhs"\n'
                 '[[axes]]\nkey = "segments[0].radius"\n[[axes]]\nkeys = ["segments[0].count", "simulation.rtol"]\nvalues = [1]\n')
    with pytest.raises(SweepError) as err:
        load_sweep(p)
    msg = str(err.value)
    assert "samplng: expected one of the keys" in msg and "(did you mean 'sampling'?)" in msg
    assert "sampling.n: expected the number of runs" in msg
    assert "axes[0]: expected a valid axis, found axis segments[0].radius: give values or range, not neither" in msg
    assert "axes[1]: expected a valid axis" in msg and "each value must list 2 entries, one a key; got 1" in msg
    # every run's scene is checked before anything runs, naming the run and its values
    p.write_text(f'scene = "{base.name}"\n[[axes]]\nkey = "segments[0].chamber_radius"\nvalues = [0.008, 0.02]\n')
    spec = load_sweep(p)
    with pytest.raises(SweepError, match=r"run 1 \(segments\[0\]\.chamber_radius = 0\.02\).*segments\[0\]\."
                                         r"chamber_radius: expected chambers inside the segment"):
        validate_runs(spec, spec.run_texts())
    assert main([str(p), "--dry-run"]) == 2


# ------------------------------------------------------------------------------ running


def test_results_are_the_same_in_this_process_and_on_worker_processes(base, tmp_path):
    axes = {"segments[0].damping": [0.01, 0.03], "pressure.frequency": [1.0, 3.0]}
    serial = sweep(base, axes, workers=1, folder=tmp_path / "serial", trajectories=True, progress=False)
    pooled = sweep(base, axes, workers=2, folder=tmp_path / "pooled", trajectories=True, progress=False)
    assert serial.engine == "serial" and pooled.engine == "local" and serial.complete and pooled.complete
    assert serial.table.num_rows == 4 and serial.n_failed == 0
    assert deterministic(serial.table).equals(deterministic(pooled.table))
    assert {r["worker"] for r in pooled.rows()} != {r["worker"] for r in serial.rows()}
    rows = serial.rows()
    assert [(r["segments[0].damping"], r["pressure.frequency"]) for r in rows] == [(0.01, 1.0), (0.01, 3.0),
                                                                                  (0.03, 1.0), (0.03, 3.0)]
    # a row is what a plain run of its scene gives
    sc = parse_scene(BASE.replace("damping = 0.02", "damping = 0.03").replace("frequency = 2.0", "frequency = 3.0"))
    model = sc.build()
    traj = sc.simulate(model=model)
    want = summary_metrics(sc, model, traj)
    for k, v in want.items():
        assert rows[3][k] == v, k
    tip = model.chain.tip_placement(traj.q[-1]).translation
    assert rows[3]["tip_final_z"] == pytest.approx(tip[2], abs=1e-12)
    saved = pooled.trajectory(3)
    assert np.array_equal(saved.q, traj.q) and np.array_equal(saved.t, traj.t)
    z = np.load(tmp_path / "pooled" / "runs" / "run-00003.npz")
    assert z["tip"].shape == (len(traj.t), 3)
    assert deterministic(pq.read_table(tmp_path / "pooled" / "summary.parquet")).equals(deterministic(pooled.table))
    assert set(METRICS) <= set(serial.table.column_names)


def test_failed_runs_are_rows_and_mcap_recordings(base, tmp_path):
    res = sweep(base, {"pressure.offset": [[2e4] * 6, [1e6, 0, 0, 1e6, 0, 0]]}, workers=1, mcap=True,
                folder=tmp_path / "f", progress=False, metrics="batch_probe:damping_logged")
    ok, bad = res.rows()
    assert ok["success"] and not bad["success"] and bad["status"] == -1 and "segment 1" in bad["message"]
    assert 0 < bad["t_end"] < 0.2 and ok["tip_path_points"] == 11
    from qchain.logging import read_mcap

    rec = read_mcap(tmp_path / "f" / "runs" / "run-00000.mcap")
    assert rec.t.size == 11 and np.isfinite(rec.q).all()


def test_a_killed_sweep_resumes_without_recomputing_finished_runs(base, tmp_path):
    sweep_file = tmp_path / "s.toml"
    dampings = [0.011, 0.012, 0.013, 0.014, 0.015, 0.016, 0.017, 0.018]
    log = tmp_path / "ran.log"
    sweep_file.write_text(f'scene = "{base.name}"\nfolder = "{tmp_path / "out"}"\nmetrics = '
                          f'"batch_probe:damping_logged"\n[set]\ndescription = "probe {log} 0.3"\n'
                          f'[[axes]]\nkey = "segments[0].damping"\nvalues = {dampings}\n')
    env = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    cmd = [sys.executable, "-m", "qchain", "sweep", str(sweep_file), "--no-progress"]
    journal = tmp_path / "out" / "runs.jsonl"
    proc = subprocess.Popen(cmd + ["--workers", "2"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if journal.is_file() and journal.read_text().count("\n") >= 2:
                break
            time.sleep(0.02)
        assert proc.poll() is None, proc.stdout.read().decode()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    before = [json.loads(line) for line in journal.read_text().splitlines()]
    assert 2 <= len(before) < len(dampings)
    # the killed sweep's worker processes do not outlive it
    pids = {int(r["worker"].rsplit(":", 1)[1]) for r in before}
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids)
    r = subprocess.run(cmd + ["--workers", "2"], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"({len(before)} finished before, {len(dampings) - len(before)} computed now" in r.stdout
    ran = [float(x) for x in log.read_text().split()]
    assert sorted(set(ran)) == dampings
    done_before = {r["segments[0].damping"] for r in before}
    assert all(ran.count(d) == 1 for d in done_before)  # a finished run is never computed again
    # again at most what the workers held when it was killed: 2 workers x 2 chunks of 1 run
    assert len(ran) - len(dampings) <= 4
    resumed = pq.read_table(tmp_path / "out" / "summary.parquet")
    assert resumed.num_rows == len(dampings) and all(resumed.column("success").to_pylist())
    fresh = sweep(parse_scene(BASE, path=base), {"segments[0].damping": dampings}, workers=1, progress=False,
                  metrics="batch_probe:damping_logged", set={"description": f"probe {tmp_path / 'x.log'} 0"})
    assert deterministic(resumed).equals(deterministic(fresh.table))
    # a sweep file that now describes other runs does not mix with these results
    sweep_file.write_text(sweep_file.read_text().replace("0.018]", "0.019]"))
    r = subprocess.run(cmd + ["--workers", "1"], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "the results of another sweep" in r.stderr and "--restart" in r.stderr


def test_the_design_study_example(tmp_path):
    sys.path.insert(0, str(TESTS.parent / "examples"))  # the example's metric function is imported by the workers
    try:
        import design_study

        out = design_study.main(["--quick", "--out", str(tmp_path), "--workers", "2"])
        res = out["result"]
        assert res.table.num_rows == 4 and res.n_failed == 0 and res.computed == 4
        assert out["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out["png"].stat().st_size > 10_000
        lev = out["levels"][-1]
        for n in out["counts"]:  # a longer lever arm bends the arm further
            assert out["reach"][(n, lev, 0.011)] > 1.5 * out["reach"][(n, lev, 0.005)] > 0.005
        again = design_study.main(["--quick", "--out", str(tmp_path), "--workers", "2"])["result"]
        assert again.computed == 0 and again.resumed == 4
        assert deterministic(again.table).equals(deterministic(res.table))
    finally:
        sys.path.remove(str(TESTS.parent / "examples"))
