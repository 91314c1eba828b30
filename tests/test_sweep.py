"""Sweeps (qchain.sweep, qchain sweep): axes and sampling, the sweep file, per-run metrics,
results identical whatever the engine, and a killed sweep resumed without recomputing; sweep
files, grids and results folders refused before any run where they cannot work."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from helpers import SEGMENTS_TOML, deadline
from qchain import sweep
from qchain.batch.sweep_spec import (
    DEFAULT_MAX_RUNS,
    Axis,
    SweepError,
    SweepSpec,
    address_problem,
    apply_values,
    check_results_folder,
    load_sweep,
    parse_key,
    runs_problem,
    validate_runs,
)
from qchain.batch.sweeps import METRICS, TIMING_COLUMNS, summary_metrics
from qchain.cli.sweep import main
from qchain.scene import parse_scene
from support import AXIS, FAST, ONE_SEGMENT_SCENE, SCENE, SWEEP_HEAD, error_line, run, sweep_file
from test_batch import _alive

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


@pytest.mark.slow
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


@pytest.mark.slow
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


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_a_set_table_is_merged_into_the_scenes_table():
    """``set={'simulation': {'duration': ...}}`` changes the duration and keeps method and dt
    (it replaced the whole [simulation] table: the runs used the default method)."""
    from qchain.batch.sweep_spec import apply_values

    raw = {"simulation": {"duration": 0.2, "method": "rk4", "dt": 1e-3}, "segments": [{"damping": 0.1}]}
    out = apply_values(raw, {"simulation": {"duration": 0.03}})
    assert out["simulation"] == {"duration": 0.03, "method": "rk4", "dt": 1e-3}
    assert raw["simulation"]["duration"] == 0.2
    out = apply_values(raw, {"simulation": {"duration": 0.03, "output": {"x": 1}}, "segments[0]": {"mass": 2.0}})
    assert out["simulation"]["method"] == "rk4" and out["segments"][0] == {"damping": 0.1, "mass": 2.0}


def test_sweep_keys_take_ascii_digits_only():
    from qchain.batch.sweep_spec import parse_key

    assert parse_key("segments[0].damping") == ["segments", 0, "damping"]
    for key in ("segments[\u0660].damping", "segments[\uff11].damping"):
        with pytest.raises(ValueError, match="segments"):
            parse_key(key)


def bad_metric(scene, model, traj):
    return {"x": object(), "ok": 1.0}


def test_an_unserialisable_metric_fails_its_run_not_the_sweep(tmp_path):
    from helpers import SEGMENTS_TOML
    from qchain import sweep
    from qchain.batch.sweeps import _check_metric

    base = tmp_path / "base.toml"
    base.write_text('name = "m"\n' + SEGMENTS_TOML + '[simulation]\nduration = 0.002\nmethod = "rk4"\ndt = 1e-3\n')
    res = sweep(base, {"segments[0].damping": [0.01, 0.02]}, workers=1, folder=tmp_path / "f", progress=False,
                metrics=bad_metric)
    rows = res.rows()
    assert len(rows) == 2 and all(not r["success"] for r in rows)
    assert all("'x'" in r["message"] and "object" in r["message"] for r in rows), rows[0]["message"]
    assert (tmp_path / "f" / "summary.parquet").exists()
    for ok in (None, True, 1, 2.5, "s", [1.0, 2], [[1.0], [2.0]]):
        _check_metric("k", ok)
    for bad in (object(), {"a": 1}, [1.0, math.nan], [1.0, "a"], b"x"):
        with pytest.raises(TypeError, match="'k'"):
            _check_metric("k", bad)


ROOT = Path(__file__).parents[1]


def test_a_sweep_seed_and_an_integer_axis_are_checked():
    from qchain.batch.sweep_spec import Axis

    with pytest.raises(ValueError, match=r"axis segments\[0\].count: an integer range needs a whole number in it, "
                                         r"got \[1.2, 1.8\]"):
        Axis("segments[0].count", range=(1.2, 1.8), num=3, integer=True)
    ax = Axis("segments[0].count", range=(1.2, 3.8), num=4, integer=True)
    assert ax.grid() == [2, 3] and all(1.2 <= x <= 3.8 for x in ax.grid())
    from qchain.batch.sweeps import sweep

    with pytest.raises(ValueError, match=r"seed must be an int >= 0 and < 2\*\*128"):
        sweep(ROOT / "examples" / "scenes" / "step_response.toml", [Axis("segments[0].count", values=(1, 2))],
              sampling="random", n=2, seed=-1)


def test_two_sweeps_on_one_folder_and_a_restart_that_keeps_what_is_not_its_own(tmp_path):
    """Two sweeps on one folder both computed every run; --restart removed a qchain run's
    runs/run-<time>.mcap from a sweep folder '.'."""
    from qchain.batch.sweep_spec import SweepError
    from qchain.batch.sweeps import _Folder

    a = _Folder(tmp_path)
    a.lock()
    with pytest.raises(SweepError, match=rf"another sweep \(pid {os.getpid()}\) is writing it"):
        _Folder(tmp_path).lock()
    a.close()
    b = _Folder(tmp_path)
    b.lock()  # free again
    runs = tmp_path / "runs"
    runs.mkdir()
    for name in ("run-00003.npz", ".run-00003.npz.tmp", "run-20261202-134758.mcap", "notes.txt"):
        (runs / name).write_text("x")
    b.clear()
    b.close()
    assert sorted(p.name for p in runs.iterdir()) == ["notes.txt", "run-20261202-134758.mcap"]


def test_sweep_keys_metrics_and_huge_grids(tmp_path):
    from qchain.batch.sweep_spec import Axis, SweepSpec, runs_problem
    from qchain.scene import parse_scene

    sc = parse_scene(ONE_SEGMENT_SCENE.replace("NAME", "sw"))
    with pytest.raises(ValueError, match=r"address the same value, on two axes"):
        SweepSpec(scene=sc, axes=[Axis("segments[0].youngs_modulus", values=(1e5,)),
                                  Axis("segments[*].youngs_modulus", values=(1e9,))])
    axes = [Axis(f"segments[{i}].damping", range=(0.0, 0.1), num=10**8) for i in range(40)]
    key, expected, found = runs_problem("grid", None, axes, 1000)
    assert key == "axes" and "more than 1e300" in found
    from qchain.batch.sweeps import run_sweep

    spec = SweepSpec(scene=sc, axes=[Axis("segments[0].damping", values=(0.01, 0.02))],
                     metrics=lambda scene, model, traj: {"segments[0].damping": -1.0}, folder=tmp_path / "m")
    res = run_sweep(spec, workers=1)
    table = res.table.to_pydict()
    assert table["segments[0].damping"] == [0.01, 0.02] and not any(table["success"])
    assert all("are the sweep's axis keys" in m for m in table["message"])


def test_the_sweep_api_checks_that_axis_values_are_a_list():
    from qchain.batch.sweeps import sweep

    scene = ROOT / "examples" / "scenes" / "step_response.toml"
    for bad in (0.1, None, "xy"):
        with pytest.raises(TypeError, match=r"axes\['segments\[0\].length'\] must be a list of values"):
            sweep(scene, {"segments[0].length": bad}, workers=1)


@pytest.mark.parametrize("text, key, found", [
    (SWEEP_HEAD + '[[axes]]\nkey = "segments[0].damping"\nrange = [0.0, 1.0]\nnum = 1000000000\n', "axes",
     "a grid of 1e+09 runs: 1000000000 (segments[0].damping) values"),
    (SWEEP_HEAD + "".join(f'[[axes]]\nkey = "{k}"\nvalues = {[0.01 * j for j in range(1, 11)]}\n' for k in (
        "gravity[0]", "gravity[1]", "gravity[2]", "segments[0].damping", "segments[1].damping", "segments[0].mass")),
     "axes", "a grid of 1e+06 runs: 10 (gravity[0]) x 10 (gravity[1])"),
    (SWEEP_HEAD + '[sampling]\nkind = "random"\nn = 1000000000\n' + AXIS, "sampling.n", "n = 1000000000"),
    (SWEEP_HEAD + '[sampling]\nkind = "lhs"\nn = 9223372036854775807\n' + AXIS, "sampling.n", "n = 9223372036854775807"),
])
def test_a_sweep_of_too_many_runs_is_refused_before_any_is_made(text, key, found, tmp_path):
    """A grid of 1e9 runs, or n = 1e9, was made run by run (minutes, gigabytes) or ended in
    numpy's 'array is too big'."""
    p = sweep_file(tmp_path, text)
    with deadline(10, "a huge sweep"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    (prob,) = exc.value.problems
    assert prob.key == key and prob.expected == f"at most [sampling] max_runs = {DEFAULT_MAX_RUNS} runs (raise it " \
                                                "to allow more)", prob
    assert prob.found.startswith(found), prob.found


def test_raising_max_runs_lets_a_larger_sweep_through_and_the_api_checks_it_too(tmp_path):
    text = SWEEP_HEAD + '[sampling]\nkind = "random"\nn = 200000\nmax_runs = 300000\n' + AXIS
    spec = load_sweep(sweep_file(tmp_path, text))
    assert spec.n == 200000 and spec.max_runs == 300000
    with pytest.raises(ValueError, match=r"sampling.n: expected at most \[sampling\] max_runs = 100000 runs"):
        SweepSpec(scene=spec.scene, axes=spec.axes, sampling="random", n=200000)
    with deadline(5, "a grid counted"):
        with pytest.raises(ValueError, match=r"axes: expected at most .* a grid of 1e\+12 runs"):
            SweepSpec(scene=spec.scene, axes=[Axis("segments[0].damping", range=(0, 1), num=10**6),
                                              Axis("segments[1].damping", range=(0, 1), num=10**6)])


@given(sizes=st.lists(st.integers(1, 10**4), min_size=0, max_size=5), limit=st.integers(1, 10**8))
@FAST
def test_runs_problem_counts_the_grid_without_making_it(sizes, limit):
    axes = [Axis(f"segments[0].{k}", range=(0.0, 1.0), num=n) for k, n in zip(
        ["damping", "mass", "radius", "length", "youngs_modulus"], sizes)]
    got = runs_problem("grid", None, axes, limit)
    assert (got is None) == (math.prod(sizes) <= limit)


@pytest.mark.parametrize("make, found", [
    (lambda p: os.mkfifo(p), "expected a regular sweep file, found a FIFO"),  # hung
    (lambda p: os.symlink("/dev/zero", p), "expected a regular sweep file, found a device"),  # hung
    (lambda p: p.write_text("x = " + "[" * 600 + "]" * 600 + "\n"), "nested at most 32 deep"),  # RecursionError
    (lambda p: p.write_bytes(b'scene = "sc\xe9ne.toml"\n'), "expected a readable UTF-8 text file"),
    (lambda p: p.write_bytes(b"#" * (9 * 2**20)), "expected a sweep file of at most 8388608 bytes"),
])
def test_a_sweep_file_that_is_not_a_text_file_is_refused_at_once(make, found, tmp_path):
    p = tmp_path / "study.toml"
    make(p)
    with deadline(10, "reading a sweep file"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    assert str(exc.value).startswith(f"{p}: (file): ") and found in str(exc.value), str(exc.value)


@pytest.mark.parametrize("top, table, key, words", [
    ('folder = ""', "", "folder", "a folder path"),  # wrote the results into the working folder
    ('name = "../../x"', "", "name", "no NUL, / or \\"),
    ('metrics = "no_such_module_here:f"', "", "metrics", "module 'no_such_module_here' cannot be imported"),  # rows failed
    ("", "[engine]\nworkers = 100000", "engine.workers", "an integer >= 1 and <= 1024"),  # one process a worker
    ("", '[engine]\ndask = "not an address"', "engine.dask", "a Dask scheduler's address"),  # waited 30 s or more
    ("", '[engine]\ndask = "tcp://127.0.0.1:70000"', "engine.dask", "a bad port (Port out of range"),
])
def test_sweep_file_values_are_checked_where_they_enter(top, table, key, words, tmp_path):
    p = sweep_file(tmp_path, f'scene = "scene.toml"\n{top}\n{AXIS}{table}\n')
    with deadline(20, "a sweep file"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    hits = [pr for pr in exc.value.problems if pr.key == key]
    assert hits and words in f"{hits[0].expected} {hits[0].found}", str(exc.value)


def test_dask_addresses():
    for good in ("tcp://127.0.0.1:8786", "127.0.0.1:8786", "tls://scheduler.example.org:8786", "inproc://x"):
        assert address_problem(good) is None, good
    for bad in ("", "tcp://:8786", "udp://1.2.3.4:1", "tcp://127.0.0.1:0", "tcp://h:abc"):
        assert address_problem(bad), bad


@pytest.mark.parametrize("files, name, words", [
    ({"sweep.json": b"\x00garbage{"}, "sweep.json", "not JSON"),
    ({"sweep.json": "[1, 2, 3]"}, "sweep.json", "a JSON object with the sweep's fingerprint"),
    ({"sweep.json": None}, "sweep.json", "a regular file, found a folder"),
    ({"runs.jsonl": '{"x": 1}\n'}, "runs.jsonl, line 1", "a JSON object with 'run', a whole run number below 2"),
    ({"runs.jsonl": '{"run": 0}\n{"run": 99}\n'}, "runs.jsonl, line 2", "below 2, found {run = 99}"),
    ({"runs.jsonl": b"\xff\xfe\n"}, "runs.jsonl, line 1", "one JSON object a finished run"),
    ({"summary.parquet": None}, "summary.parquet", "a regular file, found a folder"),
    ({"runs": b"a file"}, "runs", "a folder, found a file"),
])
def test_check_results_folder_names_the_file_a_sweep_cannot_resume_from(files, name, words, tmp_path):
    res = tmp_path / "res"
    res.mkdir()
    for f, data in files.items():
        if data is None:
            (res / f).mkdir()
        elif isinstance(data, bytes):
            (res / f).write_bytes(data)
        else:
            (res / f).write_text(data)
    with pytest.raises(SweepError) as exc:
        check_results_folder(res, n_runs=2)
    (p,) = exc.value.problems
    assert p.key == str(res / name) and words in f"{p.expected}, found {p.found}", p
    check_results_folder(tmp_path / "missing")  # a new sweep: nothing to check


@pytest.mark.parametrize("flags, words", [
    (["--workers", "100000"], "--workers must be an integer >= 1 and <= 1024, got 100000"),  # hung starting processes
    (["--workers", "0"], "--workers must be an integer >= 1 and <= 1024, got 0"),
    (["--retries", "101"], "--retries must be an integer >= 0 and <= 100, got 101"),
    (["--dask", "not an address"], "--dask 'not an address': not an address"),  # waited 45 s for a scheduler
    (["--dask", "tcp://127.0.0.1:70000"], "--dask 'tcp://127.0.0.1:70000': a bad port"),  # exit 1 after 30 s
    (["--out", ""], "argument --out: expected a path, found an empty string"),  # wrote into the working folder
])
def test_sweep_command_flags_are_refused_before_anything_runs(flags, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    code, out, err = run(["sweep", p, *flags], capsys, seconds=20)
    assert code == 2 and words in error_line(err), err
    assert not (tmp_path / "res").exists() and "runs;" not in out  # nothing was made or run


def test_a_results_folder_a_sweep_cannot_resume_from_is_refused_before_any_run(tmp_path, capsys, monkeypatch):
    """A damaged ``runs.jsonl`` ended in a JSONDecodeError, KeyError or TypeError; a run
    number out of range was taken as a finished run."""
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "runs.jsonl").write_text('{"run": 0}\n{"run": 7}\n')
    code, _, err = run(["sweep", p, "--workers", "1", "--no-progress"], capsys)
    line = error_line(err)
    assert code == 2 and "runs.jsonl, line 2" in line and "found {run = 7}" in line, err
    assert sorted(x.name for x in (tmp_path / "res").iterdir()) == ["runs.jsonl"]  # nothing written, nothing lost


def test_the_python_sweep_refuses_engine_arguments_where_they_enter(tmp_path):
    from qchain import sweep
    from qchain.batch.workers import LocalPool, resolve_workers

    (tmp_path / "scene.toml").write_text(SCENE)
    axes = {"segments[0].damping": [0.01, 0.02]}
    for kw, words in (({"workers": 10**9}, "workers must be None or -1 (every core), an int >= 1 and <= 1024"),
                      ({"workers": True}, "workers must be None or -1"),
                      ({"retries": -1}, "retries must be an int >= 0 and <= 100, got an int -1"),
                      ({"client": 3.5}, "client must be None, a scheduler address")):
        with deadline(10, f"sweep({kw})"), pytest.raises((TypeError, ValueError)) as exc:
            sweep(tmp_path / "scene.toml", axes, folder=tmp_path / "res", **kw)
        assert words in str(exc.value), (kw, str(exc.value))
    from qchain.batch.threads import ThreadPool

    with pytest.raises(ValueError, match="a sweep's run builds its scene, computes its metrics and writes its files"):
        sweep(tmp_path / "scene.toml", axes, folder=tmp_path / "res", workers=ThreadPool(2))
    assert not (tmp_path / "res").exists()
    with pytest.raises(ValueError, match="<= 1024, a qchain.batch.threads.ThreadPool or a qchain.batch.workers.LocalPool, "
                                         "got an int 1000000000"):
        LocalPool(10**9)
    assert resolve_workers(2) == 2 and resolve_workers(-1) >= 1


@pytest.mark.slow
def test_a_closed_stdout_does_not_stop_a_sweep(tmp_path):
    import subprocess
    import sys

    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    proc = subprocess.run([sys.executable, "-m", "qchain", "sweep", str(p), "--dry-run"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True, timeout=120, cwd=tmp_path,
                          preexec_fn=lambda: os.close(1))
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr


def test_control_characters_of_a_sweep_are_escaped_in_its_description(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, 'name = "s\\u001b[31m"\n' + SWEEP_HEAD + AXIS)
    code, out, err = run(["sweep", p, "--dry-run"], capsys)
    assert code == 0, err
    assert "\x1b" not in out, out
