"""Batch throughput: 256 one-second rollouts of the four-segment spatial arm on 1 and 2 cores,
on threads, on the local worker pool and on a Dask LocalCluster.

The workload (``examples/scenes/spatial_arm.toml``'s model, 12 free coordinates): each
rollout is the scene's rotating sine pressure with its own amplitude (x 0.5..1), frequency
(0.5..1.5 Hz) and phase, 1 s, ``radau5`` at rtol = 3e-2, atol = 3e-4, sampled at the
scene's 50 Hz; the tip error of every rollout against a converged reference (the same
batch at rtol = 1e-10) is printed, so "within 1 mm" is measured here, not assumed.

Engines, timed side by side in rounds (each round runs every engine once, in a rotating
order; the first round is not timed: pools started, engines loaded):

* ``serial``   ``simulate_batch(workers=1)``: one core, in this process;
* ``threads-2`` ``simulate_batch(workers=2)``: 2 threads of this process (the default engine
  of these rollouts, :class:`qchain.batch.threads.ThreadPool`);
* ``pool-1``   a :class:`qchain.batch.workers.LocalPool` of 1 worker process;
* ``pool-2``   a :class:`qchain.batch.workers.LocalPool` of 2 worker processes;
* ``dask-2``   a ``dask.distributed.LocalCluster`` on 127.0.0.1, 2 worker processes of 1 thread.

Figures: wall time of the whole ``simulate_batch`` call (median and min-max over rounds),
the batch's simulated seconds per wall second (1 s of the batch / wall: every rollout
advanced together) and the rollouts' seconds per wall second (256 times that), parallel
efficiency ``rate(pool-2) / (2 rate(serial))`` and ``rate(pool-2) / (2 rate(pool-1))`` (per round,
then the median), the speed-ups ``wall(serial) / wall(threads-2)`` and ``wall(serial) /
wall(pool-2)`` (per round, then the median), and the Dask overhead ``wall(dask-2) / wall(pool-2)
- 1`` (per round). Then serial and threads rounds from a script without
``if __name__ == "__main__":``, run as a command of its own (threads need no guard): the
batch above, and a quarter of it at rtol = 1e-6 (``HEAVY``, longer rollouts), each round
followed by the same arithmetic (:func:`spin`, no memory, no Python) on one thread and halved
on two: its speed-up is what the machine gives two busy threads in those minutes. The
machine's load average and CPU steal time are printed beside them. Start-up costs (pool and
cluster start, first batch with the engine loaded in the workers) are measured once.

Last, the compiled loop (:mod:`qchain.sim.engine.batched`, the rollouts' default) against
the Python loop (each rollout a run of the driver), side by side: a serial batch's CPU time
a rollout and each loop's 2-thread speed-up (``--loops``: only these).

Run: ``python benchmarks/bench_batch.py [--quick] [--rounds N] [--out DIR] [--loops]``; on a shared
machine under ``flock /tmp/qchain-bench.flock``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

import _study
from qchain import simulate_batch
from qchain.sim.inputs import Sine
from qchain.scene import load_scene
from qchain.batch.threads import ThreadPool
from qchain.batch.workers import LocalPool

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "spatial_arm.toml"
SETTING = dict(method="radau5", rtol=3e-2, atol=3e-4)
REFERENCE = dict(method="radau5", rtol=1e-10, atol=1e-12)
#: longer rollouts (about 7 times the steps): the part of a rollout in Python, which threads run one
#: at a time, is then a smaller share
HEAVY = dict(method="radau5", rtol=1e-6, atol=1e-8)


def workload(B: int, seed: int = 0):
    sc = load_scene(SCENE)
    model = sc.build()
    spec = sc.pressure_spec
    rng = np.random.default_rng(seed)
    P = [Sine(amplitude=spec["amplitude"] * rng.uniform(0.5, 1.0), frequency=spec["frequency"] * rng.uniform(0.5, 1.5),
              phase=spec["phase"] + rng.uniform(0, 2 * np.pi), offset=spec["offset"]) for _ in range(B)]
    return sc, model, P, sc.sample_times(1.0)


def cpu_steal() -> float:
    """Seconds of CPU time the hypervisor took from this machine so far (``/proc/stat`` steal)."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def tip_errors(model, batch, ref) -> np.ndarray:
    """Largest tip distance (m) of each rollout from its reference over the samples."""
    ch = model.chain
    out = np.empty(len(batch))
    for i in range(len(batch)):
        a = ch.frames_batch(batch.q[i], 2, t=batch.t).translation[:, -1]
        b = ch.frames_batch(ref.q[i], 2, t=ref.t).translation[:, -1]
        out[i] = np.max(np.linalg.norm(a - b, axis=1))
    return out


def result_encoding(sc, model, P, t_eval, n: int = 64, reps: int = 20) -> tuple[float, float]:
    """Milliseconds (median of ``reps``) a Dask worker spends encoding one chunk of ``n``
    rollouts' results: with Dask's own protocol (out-of-band, a frame per array) and as one
    in-band pickle (what :class:`qchain.batch.workers.DaskEngine` hands Dask instead)."""
    import pickle

    from distributed.protocol import dumps, to_serialize

    from qchain.sim.simulation import simulate

    # what a worker returns for a chunk: (Trajectory, wall seconds) a rollout
    res = [(simulate(model.chain, model.q0, model.v0, (0.0, 1.0), pressure=p, t_eval=t_eval, **SETTING), 0.0)
           for p in P[:n]]

    def ms(f) -> float:
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            f()
            ts.append(time.perf_counter() - t0)
        return float(np.median(ts) * 1e3)

    return (ms(lambda: dumps({"op": "get_data-response", "data": {"k": to_serialize(res)}})),
            ms(lambda: dumps({"op": "get_data-response", "data": {"k": to_serialize(
                pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))}})))


#: the serial and threads rounds as a script without a main guard (run by :func:`unguarded`)
UNGUARDED = """
import json, sys, threading, time
sys.path.insert(0, {here!r})
from bench_batch import spin, workload
from qchain import simulate_batch
sc, model, P, t_eval = workload({B})
args = (model.chain, model.q0, model.v0, (0.0, 1.0))
kw = dict(pressure=P, t_eval=t_eval, **{setting!r})
simulate_batch(*args, **{{**kw, "pressure": P[:2]}}, workers=2)
walls = {{"serial": [], "threads-2": [], "spin-1": [], "spin-2": []}}
spin(10)
t0 = time.perf_counter()
spin(10 ** 7)
n = int(10 ** 7 * 0.1 / (time.perf_counter() - t0))  # about 0.1 s of arithmetic on one thread
for r in range({rounds} + 1):
    for name, w in (("serial", 1), ("threads-2", 2))[:: 1 if r % 2 else -1]:
        t0 = time.perf_counter()
        b = simulate_batch(*args, **kw, workers=w)
        if r > 0:
            walls[name].append(time.perf_counter() - t0)
        assert b.meta["engine"] == ("threads" if w == 2 else "serial")
    for name, w in (("spin-1", 1), ("spin-2", 2)):  # the same work, on one thread or halved on two
        ts = [threading.Thread(target=spin, args=(n // w,)) for _ in range(w)]
        t0 = time.perf_counter()
        for t in ts:
            t.start()
        for t in ts:
            t.join()
        if r > 0:
            walls[name].append(time.perf_counter() - t0)
print(json.dumps(walls))
"""


@numba.njit(nogil=True, cache=False)
def spin(n: int) -> float:
    """``n`` rounds of four independent multiply-adds, without Python's lock and without memory
    traffic: two threads of it show what the machine gives two busy threads at that minute
    (the ceiling of a 2-thread batch's speed-up)."""
    x, y, z, w = 1.0, 0.5, 0.25, 0.125
    for _ in range(n):
        x = x * 0.9999999 + 1e-9
        y = y * 1.0000001 - 1e-9
        z = z * 0.9999998 + 2e-9
        w = w * 1.0000002 - 2e-9
    return x + y + z + w


def unguarded(B: int, rounds: int, setting: dict) -> dict[str, list[float]]:
    """Wall times (s) of ``rounds`` serial and threads rounds of ``B`` rollouts at ``setting``
    in a script without a main guard."""
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "unguarded_batch.py"
        script.write_text(UNGUARDED.format(here=str(Path(__file__).resolve().parent), B=B, rounds=rounds, setting=setting))
        r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def loops(B: int, rounds: int) -> dict:
    """The compiled loop against the Python loop, side by side in rounds: a serial batch's CPU
    time a rollout (``time.process_time``; the compiled work is the same, so the difference
    is Python saved) and the 2-thread speed-up of each. The Python loop is forced by a
    ``wall_limit`` no rollout reaches (it needs the clock between stretches)."""
    sc, model, P, t_eval = workload(B)
    args = (model.chain, model.q0, model.v0, (0.0, 1.0))
    kws = {"compiled": dict(pressure=P, t_eval=t_eval, **SETTING),
           "python": dict(pressure=P, t_eval=t_eval, wall_limit=1e6, **SETTING)}
    for kw in kws.values():
        simulate_batch(*args, **{**kw, "pressure": P[:2]}, workers=2)
    cpu = {k: [] for k in kws}
    wall = {(k, w): [] for k in kws for w in (1, 2)}
    load0 = os.getloadavg()[0]
    for r in range(rounds + 1):
        for k in (list(kws) if r % 2 else list(kws)[::-1]):
            for w in (1, 2):
                c0, w0 = time.process_time(), time.perf_counter()
                b = simulate_batch(*args, **kws[k], workers=w)
                c1, w1 = time.process_time(), time.perf_counter()
                assert b.meta["loop"] == k
                if r > 0:
                    wall[k, w].append(w1 - w0)
                    if w == 1:
                        cpu[k].append((c1 - c0) / B)
    out = {"load_before": load0, "load_after": os.getloadavg()[0]}
    print(f"\ncompiled loop against Python loop, {B} rollouts, {rounds} rounds (load average {load0:.2f} -> "
          f"{out['load_after']:.2f}):")
    print(f"{'loop':>9} {'serial CPU ms a rollout':>24} {'serial wall s':>14} {'threads-2 wall s':>17} {'speed-up':>16}")
    for k in kws:
        up = np.array(wall[k, 1]) / np.array(wall[k, 2])
        out[k] = dict(cpu_ms=float(np.median(cpu[k]) * 1e3), speedup=float(np.median(up)))
        print(f"{k:>9} {np.median(cpu[k]) * 1e3:24.3f} {np.median(wall[k, 1]):14.3f} {np.median(wall[k, 2]):17.3f} "
              f"{np.median(up):7.2f}x ({up.min():.2f}-{up.max():.2f})")
    print(f"Python saved a rollout: {out['python']['cpu_ms'] - out['compiled']['cpu_ms']:.3f} ms CPU")
    return out


def run(quick: bool = False, out_dir: Path = Path("out/bench"), rounds: int | None = None) -> list[dict]:
    import distributed

    B = 64 if quick else 256
    rounds = rounds or (3 if quick else 7)
    sc, model, P, t_eval = workload(B)
    ch = model.chain
    args = (ch, model.q0, model.v0, (0.0, 1.0))
    kw = dict(pressure=P, t_eval=t_eval, **SETTING)
    load0, steal0 = os.getloadavg(), cpu_steal()
    print(f"machine: {os.cpu_count()} cores; load average before: {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}")
    print(f"workload: {B} rollouts of 1 s, {ch.n} segments, {ch.nv_active} free coordinates, "
          f"{SETTING['method']} rtol {SETTING['rtol']:g}, {t_eval.size} samples each")

    # start-up, once
    t0 = time.perf_counter()
    loop = simulate_batch(*args, **{**kw, "pressure": P[:2]}, workers=1).meta["loop"]  # engine compiled or loaded
    warm_s = time.perf_counter() - t0
    print(f"rollouts run in {loop} loops (meta['loop'])")
    pools = {}
    startup = {}
    for n in (1, 2):
        t0 = time.perf_counter()
        pools[n] = LocalPool(n).start()
        simulate_batch(*args, **{**kw, "pressure": P[: 2 * n]}, workers=pools[n])
        startup[f"pool-{n}"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address=None, silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    client.wait_for_workers(2)
    simulate_batch(*args, **{**kw, "pressure": P[:4]}, client=client)
    startup["dask-2"] = time.perf_counter() - t0
    print(f"start-up: this process's engine {warm_s:.2f} s; " +
          ", ".join(f"{k} started and its engines loaded {v:.2f} s" for k, v in startup.items()))

    engines = {"serial": dict(workers=1), "threads-2": dict(workers=ThreadPool(2)), "pool-1": dict(workers=pools[1]),
               "pool-2": dict(workers=pools[2]), "dask-2": dict(client=client)}
    walls: dict[str, list[float]] = {k: [] for k in engines}
    batches = {}
    try:
        for r in range(rounds + 1):
            names = list(engines)
            names = names[r % len(names):] + names[: r % len(names)]
            for name in names:
                t0 = time.perf_counter()
                b = simulate_batch(*args, **kw, **engines[name])
                w = time.perf_counter() - t0
                if r > 0:
                    walls[name].append(w)
                batches[name] = b
            if r > 0:
                print(f"round {r}: " + ", ".join(f"{k} {walls[k][-1]:.3f} s" for k in engines), flush=True)
    finally:
        client.close()
        cluster.close()
        for p in pools.values():
            p.close()
    load1, steal1 = os.getloadavg(), cpu_steal()
    enc_dask, enc_pickle = result_encoding(sc, model, P, t_eval)

    ref = simulate_batch(*args, pressure=P, t_eval=t_eval, **REFERENCE, workers=2)
    err = tip_errors(model, batches["serial"], ref)
    same = all(np.array_equal(batches[k].q, batches["serial"].q) and np.array_equal(batches[k].v, batches["serial"].v)
               for k in engines)
    print(f"tip error against the reference (rtol 1e-10), over all {B} rollouts: median {np.median(err) * 1e3:.3f} mm, "
          f"largest {err.max() * 1e3:.3f} mm; all rollouts succeeded: {bool(batches['serial'].success.all())}; "
          f"every engine's batch bit-identical to the serial one: {same}")

    W = {k: np.array(v) for k, v in walls.items()}
    rows = []
    print(f"\n{'engine':>8} {'cores':>5} {'wall s (median, min-max)':>26} {'batch s/s':>10} {'rollout s/s':>12}")
    for k, w in W.items():
        cores = 1 if k in ("serial", "pool-1") else 2
        med = float(np.median(w))
        rows.append(dict(engine=k, cores=cores, rollouts=B, rounds=len(w), wall_median_s=med, wall_min_s=float(w.min()),
                         wall_max_s=float(w.max()), batch_sim_s_per_wall_s=1.0 / med, rollout_sim_s_per_wall_s=B / med))
        print(f"{k:>8} {cores:>5} {med:10.3f} ({w.min():.3f}-{w.max():.3f}) {1 / med:10.2f} {B / med:12.0f}")
    eff_serial = W["serial"] / (2 * W["pool-2"])
    eff_pool = W["pool-1"] / (2 * W["pool-2"])
    over = W["dask-2"] / W["pool-2"] - 1
    up_threads, up_pool = W["serial"] / W["threads-2"], W["serial"] / W["pool-2"]
    scripts = {}
    for label, b, setting in (("rtol 3e-2", B, SETTING), ("rtol 1e-6", B // 4, HEAVY)):
        w = {k: np.array(v) for k, v in unguarded(b, rounds, setting).items()}
        scripts[label] = (b, w, w["serial"] / w["threads-2"], w["spin-1"] / w["spin-2"])
    print(f"\nparallel efficiency 1 -> 2 cores (per round): against serial {np.median(eff_serial) * 100:.1f} % "
          f"({eff_serial.min() * 100:.1f}-{eff_serial.max() * 100:.1f}), against pool-1 {np.median(eff_pool) * 100:.1f} % "
          f"({eff_pool.min() * 100:.1f}-{eff_pool.max() * 100:.1f})")
    print(f"speed-up on 2 cores against serial (per round): threads-2 {np.median(up_threads):.2f}x "
          f"({up_threads.min():.2f}-{up_threads.max():.2f}), pool-2 {np.median(up_pool):.2f}x "
          f"({up_pool.min():.2f}-{up_pool.max():.2f})")
    for label, (b, w, up, ceiling) in scripts.items():
        print(f"from a script without a main guard, {b} rollouts at {label} ({len(up)} rounds): serial "
              f"{np.median(w['serial']):.3f} s ({np.median(w['serial']) / b * 1e3:.1f} ms a rollout), threads-2 "
              f"{np.median(w['threads-2']):.3f} s, speed-up {np.median(up):.2f}x ({up.min():.2f}-{up.max():.2f}); "
              f"pure arithmetic on 2 threads in the same rounds {np.median(ceiling):.2f}x "
              f"({ceiling.min():.2f}-{ceiling.max():.2f})")
    print(f"Dask LocalCluster overhead against pool-2 (per round): {np.median(over) * 100:+.1f} % "
          f"({over.min() * 100:+.1f}..{over.max() * 100:+.1f})")
    print(f"a Dask worker encoding one chunk of 64 rollouts' results: {enc_dask:.2f} ms with Dask's protocol, "
          f"{enc_pickle:.2f} ms as one pickle (what qchain sends)")
    print(f"machine load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}; CPU steal during the run: "
          f"{steal1 - steal0:.2f} s")
    summary = dict(engine="summary", cores=2, rollouts=B, rounds=rounds,
                   efficiency_vs_serial=float(np.median(eff_serial)), efficiency_vs_pool1=float(np.median(eff_pool)),
                   speedup_threads2=float(np.median(up_threads)), speedup_pool2=float(np.median(up_pool)),
                   speedup_threads2_unguarded=float(np.median(scripts["rtol 3e-2"][2])),
                   speedup_threads2_unguarded_heavy=float(np.median(scripts["rtol 1e-6"][2])),
                   speedup_spin2_unguarded=float(np.median(scripts["rtol 3e-2"][3])),
                   dask_overhead=float(np.median(over)), tip_error_max_m=float(err.max()),
                   tip_error_median_m=float(np.median(err)), load_before=load0[0], load_after=load1[0],
                   steal_s=steal1 - steal0, bit_identical=same, loop=loop, encode_dask_ms=enc_dask, encode_pickle_ms=enc_pickle)
    lp = loops(B, rounds)
    summary.update(cpu_ms_compiled_loop=lp["compiled"]["cpu_ms"], cpu_ms_python_loop=lp["python"]["cpu_ms"],
                   speedup_threads2_compiled_loop=lp["compiled"]["speedup"],
                   speedup_threads2_python_loop=lp["python"]["speedup"])
    _study.write_csv(rows, out_dir / "batch.csv")
    _study.write_csv([summary], out_dir / "batch_summary.csv")
    return rows + [summary]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="64 rollouts, 3 rounds")
    ap.add_argument("--rounds", type=int, default=None, help="timed rounds (default 7, 3 with --quick)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV files")
    ap.add_argument("--loops", action="store_true", help="only the compiled loop against the Python loop")
    args = ap.parse_args(argv)
    if args.loops:
        return loops(64 if args.quick else 256, args.rounds or (3 if args.quick else 7))
    return run(args.quick, args.out, args.rounds)


if __name__ == "__main__":
    main()
