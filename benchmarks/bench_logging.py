"""Cost of logging a run, as a ratio to the same run without logging.

    python benchmarks/bench_logging.py [--steps 20000] [--block 500] [--pad-us 0]
    python benchmarks/bench_logging.py --example [--duration 20] [--repeats 10]
        [--only command|process|steady|corun] [--configs mcap,rrd,both] [--save PREFIX]
    python benchmarks/bench_logging.py --example --only steady [--rounds 40] [--block-s 20]
    python benchmarks/bench_logging.py --pool PREFIX-kind.json ...

``--example`` measures the three-segment example (``examples/scenes/wave_arm.toml``): first
the whole ``qchain run`` command as a user runs it (fresh interpreter, model build,
simulation, files finished), with the time of each of its phases, then the simulation phase
in one process (logger created to files finished, the writer started ahead as ``qchain
run`` does), each logged run against the mean of the unlogged runs either side of it; the
simulation's steady state, what a long run pays per simulated second (blocks of the
configurations interleaved, each logger open throughout: :func:`example_steady`); what a busy
process on the other core costs the simulation on this machine (no logging); and the
writer's start-up time. ``--save`` keeps every run, ``--pool`` summarises several saved sets
of one kind as one. The rest of this docstring is about the default mode.

Drives a simulation step function with logging off, MCAP on, Rerun (.rrd) on and both on.
One logger a configuration stays open for the whole measurement; the steps go in blocks,
the configurations interleaved block by block (the order rotates every round), and after
each block the logger is flushed (``RunLogger.flush``: everything logged is in the files) so
that no writer still works while another configuration is timed. Printed: median steps/s;
the overhead = median over rounds of (block time with logging / block time without, same
round) - 1 (target <= 5 %); the CPU time of the simulating process a step (its ``log()``
calls included) and of the writer process (on the other core); the time a flush waited for
the writer after a block; MCAP bytes a simulated second.

The paired, block-interleaved design is there because a small virtual machine's speed
drifts by up to 2x within seconds; comparing whole runs measured minutes apart would
measure the drift, not the logging.

The default mode's workload is the analytically bending three-segment arm of
``tests/logging_fixtures.py`` (closed-form constant-curvature arcs, 12 backbone points a
segment, ~150-250 us a step in numpy), optionally padded with 27 x 27 solves (``--pad-us``)
to a chosen cost: a record every step, the worst case for the logger.
:func:`measure_overhead` takes any step function returning a
:class:`qchain.logging.StepRecord`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from logging_fixtures import arm_info, arm_record  # noqa: E402

from qchain.logging import RunInfo, RunLogger  # noqa: E402

CONFIGS = ("off", "mcap", "rrd", "both")


def synthetic_step(dt: float = 1e-3, pad_us: float = 0.0, seed: int = 0):
    """A step function of the synthetic arm: each call advances ``dt`` and returns its record.

    Parameters
    ----------
    dt : float, s
        Time step.
    pad_us : float, us
        Extra numpy work a step (27 x 27 solves, the size of a three-segment mass matrix
        with a floating base), on top of the arm's own ~150-250 us.
    """
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((27, 27))
    M = A @ A.T + 27 * np.eye(27)
    b = rng.standard_normal(27)
    t0 = time.perf_counter()
    for _ in range(200):
        np.linalg.solve(M, b)
    solve_us = (time.perf_counter() - t0) / 200 * 1e6
    n_pad = int(round(pad_us / max(solve_us, 1e-3)))
    state = {"k": 0}

    def step():
        k = state["k"]
        state["k"] = k + 1
        x = b
        for _ in range(n_pad):
            x = np.linalg.solve(M, x)
        return arm_record(k * dt, k)

    return step


def _cpu_seconds(pid: int | None) -> float:
    """User + system CPU time of a process (from /proc; 0 where unavailable)."""
    if pid is None:
        return 0.0
    try:
        fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def measure_overhead(step_fn, n_steps: int, sinks=CONFIGS, block: int = 500, info: RunInfo | None = None,
                     workdir: str | os.PathLike | None = None) -> dict:
    """Cost of logging with each sink set, in interleaved blocks of steps.

    Parameters
    ----------
    step_fn : callable () -> StepRecord
        Advances the simulation one step and returns its record.
    n_steps : int
        Steps a configuration in all (``n_steps // block`` rounds).
    sinks : sequence of {"off", "mcap", "rrd", "both"}
        Configurations; "off" (no logging) is the reference and always measured.
    block : int
        Steps a block.
    info : RunInfo or None
        Run information (default: the synthetic arm's).
    workdir : path or None
        Where the files go (default: a temporary folder, removed after).

    Returns
    -------
    dict
        config -> {"steps_per_s", "overhead", "overhead_q1", "overhead_q3",
        "cpu_us_per_step", "writer_cpu_us_per_step", "flush_wait_ms",
        "mcap_bytes_per_sim_s"}, and "_meta".
    """
    info = info or arm_info()
    configs = ["off"] + [c for c in sinks if c != "off"]
    rounds = max(3, n_steps // block)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        loggers = {}
        for c in configs[1:]:
            mcap = tmp / f"{c}.mcap" if c in ("mcap", "both") else None
            rrd = tmp / f"{c}.rrd" if c in ("rrd", "both") else None
            loggers[c] = RunLogger(info, mcap, rrd=rrd, worker="process", quiet=True)
        res = {c: {"loop": [], "cpu": [], "writer": [], "flush": [], "sim": 0.0, "log_cpu": []} for c in configs}
        try:
            for c in configs:  # warm-up block, not counted
                log = loggers.get(c)
                for _ in range(min(block, 200)):
                    rec = step_fn()
                    if log is not None:
                        log.log(rec)
                if log is not None:
                    log.flush()
            # the cost of log() itself, on records made beforehand: CPU time of this thread a call
            records = [step_fn() for _ in range(block)]
            for c in configs[1:]:
                for _ in range(3):
                    put = loggers[c].log
                    c0 = time.thread_time()
                    for rec in records:
                        put(rec)
                    res[c]["log_cpu"].append((time.thread_time() - c0) / block)
                    res[c]["sim"] += (records[-1].t - records[0].t) * block / max(block - 1, 1)
                    loggers[c].flush()
            for r in range(rounds):
                order = configs[r % len(configs):] + configs[: r % len(configs)]
                for c in order:
                    log = loggers.get(c)
                    wpid = None if log is None else log.worker_pid
                    w0 = _cpu_seconds(wpid)
                    c0 = time.process_time()
                    t0 = time.perf_counter()
                    if log is None:
                        for _ in range(block):
                            rec = step_fn()
                    else:
                        put = log.log
                        first = None
                        for _ in range(block):
                            rec = step_fn()
                            put(rec)
                            if first is None:
                                first = rec.t
                    t1 = time.perf_counter()
                    c1 = time.process_time()
                    if log is not None:
                        log.flush()
                        res[c]["sim"] += (rec.t - first) * block / max(block - 1, 1)
                    t2 = time.perf_counter()
                    res[c]["loop"].append(t1 - t0)
                    res[c]["cpu"].append(c1 - c0)
                    res[c]["flush"].append(t2 - t1)
                    res[c]["writer"].append(_cpu_seconds(wpid) - w0)
        finally:
            for log in loggers.values():
                log.close()
        sizes = {c: (tmp / f"{c}.mcap").stat().st_size for c in configs if (tmp / f"{c}.mcap").exists()}
    table = {}
    off = res["off"]["loop"]
    for c in configs:
        x = res[c]
        ratios = sorted(a / b - 1.0 for a, b in zip(x["loop"], off))
        q = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else [ratios[0]] * 3
        table[c] = {
            "steps_per_s": block / statistics.median(x["loop"]),
            "overhead": statistics.median(ratios),
            "overhead_q1": q[0],
            "overhead_q3": q[2],
            "cpu_us_per_step": statistics.median(x["cpu"]) / block * 1e6,
            "writer_cpu_us_per_step": sum(x["writer"]) / (block * rounds) * 1e6,
            "flush_wait_ms": statistics.median(x["flush"]) * 1e3,
            "log_cpu_us": statistics.median(x["log_cpu"]) * 1e6 if x["log_cpu"] else 0.0,
            "mcap_bytes_per_sim_s": sizes[c] / x["sim"] if c in sizes and x["sim"] > 0 else None,
        }
    table["_meta"] = {"block": block, "rounds": rounds, "us_per_step_off": statistics.median(off) / block * 1e6,
                      "load": os.getloadavg()[0]}
    return table


def print_table(table: dict) -> None:
    meta = table["_meta"]
    print(f"{meta['rounds']} rounds of {meta['block']} steps a configuration, interleaved; a step without "
          f"logging: {meta['us_per_step_off']:.0f} us (median); load average {meta['load']:.2f}")
    print(f"{'logging':<8} {'steps/s':>8} {'overhead':>9} {'(quartiles)':>15} {'sim CPU/step':>13} "
          f"{'log() CPU':>10} {'writer CPU/step':>16} {'flush wait':>11} {'MCAP/sim s':>11}")
    cpu_off = table["off"]["cpu_us_per_step"]
    for c, row in table.items():
        if c.startswith("_"):
            continue
        mb = row["mcap_bytes_per_sim_s"]
        quart = f"{100 * row['overhead_q1']:+.1f}..{100 * row['overhead_q3']:+.1f}%"
        extra = row["cpu_us_per_step"] - cpu_off
        cpu = f"{row['cpu_us_per_step']:.0f} us" + ("" if c == "off" else f" ({extra:+.1f})")
        print(f"{c:<8} {row['steps_per_s']:>8.0f} {100 * row['overhead']:>8.1f}% {quart:>15} {cpu:>13} "
              f"{row['log_cpu_us']:>7.1f} us {row['writer_cpu_us_per_step']:>13.0f} us {row['flush_wait_ms']:>8.1f} ms "
              f"{'' if mb is None else f'{mb / 1e6:.2f} MB':>11}")
    print("overhead: median over rounds of block time with logging / without - 1 (target <= 5 %). sim CPU: "
          "CPU time of the simulating process a step, log() included. log() CPU: a call's own CPU time, on "
          "records made beforehand. writer CPU: the writer process's a record, on the other core. flush "
          "wait: how long the writer still needed after a block. With the second core busy elsewhere "
          "(load average > 1), the writer takes time from the simulation and the overhead rises.")


EXAMPLE_SCENE = HERE.parent / "examples" / "scenes" / "wave_arm.toml"


def _example_model():
    """The three-segment example's scene and model, the simulation compiled (warmed up)."""
    from qchain import load_scene

    scene = load_scene(EXAMPLE_SCENE)
    model = scene.build()
    scene.simulate(model=model, duration=0.2)
    return scene, model


EXAMPLE_CONFIGS = {"mcap": ["--mcap", "{d}/run.mcap"], "rrd": ["--rrd", "{d}/run.rrd", "--no-record"],
                   "both": ["--mcap", "{d}/run.mcap", "--rrd", "{d}/run.rrd"]}


def _flanked(run, configs, repeats: int) -> dict:
    """Run ``off, c1, off, c2, off, c3, off, c1, ...`` (``repeats`` runs a config); each
    logging run is compared with the mean of the two "off" runs either side of it, so that
    the machine's drift over seconds cancels. ``run(config, index)`` returns a dict with
    "wall" (s) and anything else to report. Returns config -> list of those dicts, each with
    "ratio" (wall / flanking off walls) added, "cpu_ratio" the same of "cpu" and
    "phase_extra" (phase -> s more than the flanking off runs' mean) of "phases" if the runs
    report them; "off" -> the off runs."""
    seq = ["off"]
    for r in range(repeats):
        for c in configs:
            seq += [c, "off"]
    res = [run(c, i) for i, c in enumerate(seq)]
    out = {"off": [x for c, x in zip(seq, res) if c == "off"]}
    for i, c in enumerate(seq):
        if c != "off":
            for key, name in (("wall", "ratio"), ("cpu", "cpu_ratio")):
                if key in res[i]:
                    res[i][name] = res[i][key] / (0.5 * (res[i - 1][key] + res[i + 1][key]))
            if "phases" in res[i]:
                res[i]["phase_extra"] = {k: v - 0.5 * (res[i - 1]["phases"][k] + res[i + 1]["phases"][k])
                                         for k, v in res[i]["phases"].items()}
            out.setdefault(c, []).append(res[i])
    return out


def median_ci(values, level: float = 0.95, resamples: int = 4000, seed: int = 0) -> tuple[float, float]:
    """Percentile-bootstrap confidence interval of the median of ``values``."""
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return (float(x[0]), float(x[0])) if x.size else (0.0, 0.0)
    rng = np.random.default_rng(seed)
    med = np.median(x[rng.integers(0, x.size, (resamples, x.size))], axis=1)
    a = (1.0 - level) / 2
    return float(np.quantile(med, a)), float(np.quantile(med, 1.0 - a))


def _steal_s() -> float:
    """CPU time the hypervisor has taken from this virtual machine so far, all CPUs (the
    "steal" column of /proc/stat), s; 0 where there is none."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def _overheads(ratios: list[float], cpu: list[float]) -> dict:
    """The overheads of a configuration's runs or blocks (time / unlogged time - 1): median,
    quartiles and bootstrap 95 % CI of the median ("overhead", "overhead_q1", "overhead_q3",
    "overhead_ci"), and the median and CI of the same ratios of CPU time ("cpu_overhead",
    "cpu_ci"; None without them)."""
    q = statistics.quantiles(ratios, n=4) if len(ratios) > 1 else [ratios[0]] * 3 if ratios else [0.0] * 3
    return {"overhead": statistics.median(ratios) if ratios else 0.0, "overhead_q1": q[0], "overhead_q3": q[2],
            "overhead_ci": median_ci(ratios) if ratios else (0.0, 0.0),
            "cpu_overhead": statistics.median(cpu) if cpu else None, "cpu_ci": median_ci(cpu) if cpu else None}


def _summary(rows: list[dict], duration: float) -> dict:
    """Medians (and bootstrap CIs) of a configuration's runs of ``duration`` s simulated;
    "runs" and "duration" keep what they came from (for ``--save`` and ``--pool``)."""
    ratios = [x["ratio"] - 1.0 for x in rows if "ratio" in x]
    out = {"wall_s": statistics.median(x["wall"] for x in rows), "n": len(ratios), "runs": rows, "duration": duration,
           **_overheads(ratios, [x["cpu_ratio"] - 1.0 for x in rows if "cpu_ratio" in x])}
    out["steal_ms"] = statistics.median(x["steal"] for x in rows) * 1e3
    sizes = [x["mcap_bytes"] for x in rows if x.get("mcap_bytes")]
    out["mcap_bytes_per_sim_s"] = statistics.median(sizes) / duration if sizes else None
    for key in ("sample_us", "start_s", "close_s", "samples", "direct"):
        vals = [x[key] for x in rows if key in x]
        out[key] = statistics.median(vals) if vals else None
    if rows and "phases" in rows[0]:
        key = "phase_extra" if "phase_extra" in rows[0] else "phases"
        out[key] = {k: statistics.median(x[key][k] for x in rows) for k in rows[0][key]}
    return out


# phases of the whole command, from the marks of benchmarks/_timed_command.py
COMMAND_PHASES = {"start-up": ("launch", "start"), "imports, scene": ("start", "build0"), "model build": ("build0", "build1"),
                  "logger start": ("build1", "sim0"), "simulation": ("sim0", "sim1"), "files, summary": ("sim1", "main"),
                  "exit": ("main", "done")}


def example_command_overhead(duration: float | None = None, repeats: int = 10, workdir=None,
                             configs=tuple(EXAMPLE_CONFIGS)) -> dict:
    """The three-segment example as a user runs it: the whole ``qchain run
    examples/scenes/wave_arm.toml --no-plots`` command in a fresh interpreter (start-up,
    model build, simulation, files finished), with ``--no-record`` (off) and with MCAP,
    ``.rrd`` or both, run through ``benchmarks/_timed_command.py`` for the times of its
    phases (:data:`COMMAND_PHASES`). Returns config -> summary (see :func:`_summary`), with
    "phases" (off: median s a phase) or "phase_extra" (a logged config: median s more than
    the flanking off runs)."""
    import subprocess

    scene = EXAMPLE_SCENE
    extra = [] if duration is None else ["--duration", str(duration)]
    env = dict(os.environ, PYTHONPATH=str(HERE.parent) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        def run(c, i):
            d = Path(tmp) / f"{c}-{i}"
            d.mkdir()
            flags = ["--no-record"] if c == "off" else [a.format(d=d) for a in EXAMPLE_CONFIGS[c]]
            marks = d / "marks.json"
            cmd = [sys.executable, str(HERE / "_timed_command.py"), str(marks), "run", str(scene), "--no-plots",
                   "--no-progress", *extra, *flags]
            s0 = _steal_s()
            launch = time.monotonic()
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env, cwd=tmp)
            wall = time.perf_counter() - t0
            mk = dict(json.loads(marks.read_text()), launch=launch, done=time.monotonic())
            m = d / "run.mcap"
            return {"wall": wall, "mcap_bytes": m.stat().st_size if m.exists() else None, "steal": _steal_s() - s0,
                    "phases": {k: mk[b] - mk[a] for k, (a, b) in COMMAND_PHASES.items()}}

        run("off", -1)  # warm the file cache
        res = _flanked(run, list(configs), repeats)
    from qchain import load_scene

    T = load_scene(scene).duration if duration is None else duration
    return {c: _summary(rows, T) for c, rows in res.items()}


def example_overhead(duration: float = 20.0, repeats: int = 10, workdir=None, worker: str = "auto",
                     head_start: float = 1.5, configs=tuple(EXAMPLE_CONFIGS)) -> dict:
    """The simulation phase of ``qchain run``'s run of the three-segment example, in this
    process with its model built once: from creating the logger to its files finished
    (``with logger, recorder: scene.simulate(...)``) against the simulation unlogged. The
    writer is started ``head_start`` seconds ahead, untimed (``qchain run`` starts it before
    building the model, which takes ~1.1 s in a fresh process); every run, logged or not,
    waits that long first. Returns config -> summary with also the mean cost of a sample in
    the simulating process ("sample_us"), the wait in the logger's constructor ("start_s")
    and the wait for the files at the end ("close_s")."""
    from qchain.cli import main as cli

    from qchain.cli import recording as qlog
    scene, model = _example_model()
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        def run(c, i):
            if c != "off":
                qlog.prepare_writer(rerun=c != "mcap")
            time.sleep(head_start)
            if c == "off":
                s0, c0 = _steal_s(), time.process_time()
                t0 = time.perf_counter()
                scene.simulate(model=model, duration=duration)
                return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "steal": _steal_s() - s0}
            d = Path(tmp) / f"{c}-{i}"
            d.mkdir()
            argv = ["run", str(scene.path), *[a.format(d=d) for a in EXAMPLE_CONFIGS[c]], "--no-progress"]
            args = cli._parser().parse_args(argv)
            spent = [0.0, 0]
            s0, c0 = _steal_s(), time.process_time()
            t0 = time.perf_counter()
            logger, recorder = cli._make_logger(args, scene, model, worker=worker)

            def on_sample(t, q, v, p, energies=None):
                s = time.perf_counter()
                recorder(t, q, v, p, energies=energies)
                spent[0] += time.perf_counter() - s
                spent[1] += 1

            with logger, recorder:
                t1 = time.perf_counter()
                scene.simulate(model=model, duration=duration, on_sample=on_sample)
                t2 = time.perf_counter()
            t3 = time.perf_counter()
            m = d / "run.mcap"
            return {"wall": t3 - t0, "cpu": time.process_time() - c0, "steal": _steal_s() - s0,
                    "sample_us": spent[0] / max(spent[1], 1) * 1e6, "samples": spent[1],
                    "start_s": t1 - t0, "close_s": t3 - t2, "mcap_bytes": m.stat().st_size if m.exists() else None,
                    "direct": (spent[0] + (t1 - t0) + (t3 - t2)) / (t3 - t0)}

        res = _flanked(run, list(configs), repeats)
    return {c: _summary(rows, duration) for c, rows in res.items()}


def example_steady(block: float = 20.0, rounds: int = 40, workdir=None, configs=tuple(EXAMPLE_CONFIGS)) -> dict:
    """The example's simulation as in a long run, the configurations interleaved block by
    block: what logging costs per simulated second once its fixed costs have faded.

    One logger a configuration, created as ``qchain run`` creates it (its writer process,
    ``ChainRecorder``), stays open the whole time. A block is ``scene.simulate`` of
    ``block`` s from the scene's initial state (the same work in every block), unlogged or
    logged to one configuration (the times shifted block after block, so each logger sees
    one growing run). A round runs one block of each configuration, back to back, in an
    order that rotates round by round; a logged block is timed up to its records in the
    files (``RunLogger.flush``: the writer's last work, done while the simulation waits,
    is counted in full, so the figure errs high). The ratio of a block to the unlogged
    block of the same round (seconds apart) cancels the machine's drift. Round 0 warms up
    and is not counted. Returns config -> {"wall_s", "overhead", "overhead_ci", "overhead_q1",
    "overhead_q3", "cpu_overhead", "cpu_ci", "sample_us", "direct", "flush_ms",
    "writer_cpu", "steal_ms", "ratios", "cpu_ratios"} ("off": "wall_s", "steal_ms")."""
    from qchain.cli import main as cli

    from qchain.cli import recording as qlog
    scene, model = _example_model()
    configs = ["off", *configs]
    res = {c: {"wall": [], "cpu": [], "spent": [], "samples": [], "flush": [], "writer": [], "steal": []}
           for c in configs}
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        loggers, recorders = {}, {}
        try:
            for c in configs[1:]:
                d = Path(tmp) / c
                d.mkdir()
                args = cli._parser().parse_args(["run", str(scene.path), *[a.format(d=d) for a in EXAMPLE_CONFIGS[c]],
                                                     "--no-progress"])
                loggers[c], recorders[c] = cli._make_logger(args, scene, model)
            for log in loggers.values():
                log.flush()  # the writers are up (Rerun imported and started)
            offset = {c: 0.0 for c in configs}
            for r in range(rounds + 1):
                order = configs[r % len(configs):] + configs[: r % len(configs)]
                for c in order:
                    rec, log = recorders.get(c), loggers.get(c)
                    spent = [0.0, 0]
                    if rec is not None:
                        off = offset[c]

                        def on_sample(t, q, v, p, energies=None, rec=rec, off=off):
                            s0 = time.perf_counter()
                            rec(t + off, q, v, p, energies=energies)
                            spent[0] += time.perf_counter() - s0
                            spent[1] += 1
                    else:
                        on_sample = None
                    w0 = _cpu_seconds(None if log is None else log.worker_pid)
                    s0, c0 = _steal_s(), time.process_time()
                    t0 = time.perf_counter()
                    scene.simulate(model=model, duration=block, on_sample=on_sample)
                    t1 = time.perf_counter()
                    if rec is not None:
                        f0 = time.perf_counter()
                        rec.flush()
                        spent[0] += time.perf_counter() - f0
                        log.flush()
                        offset[c] += block + 1.0
                    t2 = time.perf_counter()
                    if r == 0:
                        continue
                    x = res[c]
                    x["wall"].append(t2 - t0)
                    x["cpu"].append(time.process_time() - c0)
                    x["steal"].append(_steal_s() - s0)
                    x["spent"].append(spent[0])
                    x["samples"].append(spent[1])
                    x["flush"].append(t2 - t1)
                    x["writer"].append(_cpu_seconds(None if log is None else log.worker_pid) - w0)
        finally:
            for log in loggers.values():
                log.close()
    out = {}
    off = res["off"]
    for c in configs:
        x = res[c]
        row = {"wall_s": statistics.median(x["wall"]), "steal_ms": statistics.median(x["steal"]) * 1e3,
               "rounds": rounds, "block": block}
        if c != "off":
            ratios = [a / b - 1.0 for a, b in zip(x["wall"], off["wall"])]
            cpu = [a / b - 1.0 for a, b in zip(x["cpu"], off["cpu"])]
            row.update(_overheads(ratios, cpu),
                       sample_us=sum(x["spent"]) / max(sum(x["samples"]), 1) * 1e6,
                       direct=statistics.median((s + f) / w for s, f, w in zip(x["spent"], x["flush"], x["wall"])),
                       flush_ms=statistics.median(x["flush"]) * 1e3,
                       writer_cpu=statistics.median(w / (a - f) for w, a, f in zip(x["writer"], x["wall"], x["flush"])),
                       ratios=ratios, cpu_ratios=cpu)
        out[c] = row
    return out


def _pool_steady(results: list[dict]) -> dict:
    """Several saved results of :func:`example_steady` as one: the rounds' ratios pooled;
    the other figures are medians over the sets."""
    out = {}
    for c in results[0]:
        rows = [r[c] for r in results if c in r]
        row = {k: statistics.median(x[k] for x in rows) for k in ("wall_s", "steal_ms")}
        row.update(rounds=sum(x["rounds"] for x in rows), block=rows[0]["block"])
        if c != "off":
            ratios = [v for x in rows for v in x["ratios"]]
            cpu = [v for x in rows for v in x["cpu_ratios"]]
            row.update(_overheads(ratios, cpu), ratios=ratios, cpu_ratios=cpu,
                       **{k: statistics.median(x[k] for x in rows)
                          for k in ("sample_us", "direct", "flush_ms", "writer_cpu")})
        out[c] = row
    return out


def print_steady(res: dict, sets: str = "") -> None:
    off = res["off"]
    print(f"steady state, the example's simulation: {off['rounds']} rounds of one {off['block']:g} s block a "
          f"configuration, interleaved (order rotating), each against the unlogged block of its round; "
          + (sets or f"load average {os.getloadavg()[0]:.2f}"))
    print(f"{'logging':<8} {'block':>8} {'overhead':>9} {'(95 % CI)':>16} {'(quartiles)':>16} {'a sample':>9} "
          f"{'flush':>8} {'direct':>7} {'sim CPU':>8} {'(95 % CI)':>16} {'writer':>7} {'steal':>8}")
    for c, row in res.items():
        if c == "off":
            print(f"{c:<8} {row['wall_s']:>7.3f}s {'':>9} {'':>16} {'':>16} {'':>9} {'':>8} {'':>7} {'':>8} {'':>16} "
                  f"{'':>7} {row['steal_ms']:>5.1f} ms")
            continue
        ci = "{:+.1f}..{:+.1f}%".format(*(100 * x for x in row["overhead_ci"]))
        quart = f"{100 * row['overhead_q1']:+.1f}..{100 * row['overhead_q3']:+.1f}%"
        cci = "{:+.1f}..{:+.1f}%".format(*(100 * x for x in row["cpu_ci"]))
        print(f"{c:<8} {row['wall_s']:>7.3f}s {100 * row['overhead']:>+8.1f}% {ci:>16} {quart:>16} "
              f"{row['sample_us']:>6.0f} us {row['flush_ms']:>5.1f} ms {100 * row['direct']:>6.1f}% "
              f"{100 * row['cpu_overhead']:>+7.1f}% {cci:>16} {100 * row['writer_cpu']:>6.1f}% {row['steal_ms']:>5.1f} ms")
    print("block: median wall time of a block (a logged one up to its records in the files). overhead: median over "
          "rounds of block / unlogged block of the same round - 1, with a bootstrap 95 % CI of that median. a "
          "sample: the recorder's cost in the simulating process. flush: the wait at a block's end for the writer "
          "(counted in the block). direct: (the recorder's time + flush) / block, within one block. sim CPU: the "
          "same ratio of the simulating process's CPU time. writer: the writer's CPU time / the block's simulation "
          "time, its load on the other core.")


_BUSY_LOOP = "x = 0\nwhile True:\n    x = (x * 1103515245 + 12345) & 0xffffffff\n"
# what a writer's start-up does: fresh interpreters importing rerun-sdk, one after another
_IMPORT_LOOP = ("import subprocess, sys\nwhile True:\n"
                "    subprocess.run([sys.executable, '-c', 'import rerun, rerun.blueprint'])\n")


def co_running(duration: float = 4.0, repeats: int = 20) -> dict:
    """What a busy process on the other core costs the simulation, with no logging at all:
    the example's simulation phase (``duration`` s simulated) timed with the other core idle
    and with a Python busy loop there, at normal priority and at the writer's idle priority
    (``SCHED_IDLE``), and with a loop of fresh interpreters importing rerun-sdk (a writer's
    start-up, memory-heavy) at idle priority, interleaved. On a machine with cores of their
    own this is ~0; where the virtual CPUs share a physical core, caches or a power budget,
    it is what the writer's work on the other core costs the simulation beyond the
    simulating process's own logging. Returns "off" (other core idle), "normal", "idle" and
    "import" -> summary (see :func:`_summary`)."""
    import subprocess

    scene, model = _example_model()
    here = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    if here is None or len(here) < 2:
        return {}
    sim_cpu, other = sorted(here)[:2]
    os.sched_setaffinity(0, {sim_cpu})
    try:
        def run(c, i):
            proc = None
            if c != "off":
                code = f"import os\nos.sched_setaffinity(0, {{{other}}})\n" + (
                    _IMPORT_LOOP if c == "import" else _BUSY_LOOP)
                proc = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
                if c != "normal":  # inherited by the importing interpreters
                    os.sched_setscheduler(proc.pid, os.SCHED_IDLE, os.sched_param(0))
                time.sleep(0.2)  # the loop is running
            s0 = _steal_s()
            t0 = time.perf_counter()
            scene.simulate(model=model, duration=duration)
            wall = time.perf_counter() - t0
            steal = _steal_s() - s0
            if proc is not None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            return {"wall": wall, "steal": steal}

        res = _flanked(run, ["normal", "idle", "import"], repeats)
    finally:
        os.sched_setaffinity(0, here)
    return {c: _summary(rows, duration) for c, rows in res.items()}


def writer_startup(repeats: int = 5) -> dict:
    """Wall time from launching a writer to its first answer (the logger's constructor and a
    first ``flush()``), for an MCAP and for MCAP + .rrd (median of ``repeats``): what
    :func:`qchain.logging.prepare_writer` hides."""
    from qchain.logging import RunLogger

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, kw in (("mcap", {}), ("mcap + rrd", {"rrd": Path(tmp) / "a.rrd"})):
            walls = []
            for i in range(repeats):
                t0 = time.perf_counter()
                log = RunLogger(arm_info(), Path(tmp) / f"{i}.mcap", quiet=True, **kw)
                log.flush()
                walls.append(time.perf_counter() - t0)
                log.close()
            out[name] = statistics.median(walls)
    return out


def print_phases(res: dict) -> None:
    """Where the whole command's extra time goes: a phase's median in the unlogged runs and
    what a logged run spends more in it (median over runs, against the unlogged runs either
    side)."""
    names = list(COMMAND_PHASES)
    print(f"{'phase (ms)':<16}" + "".join(f"{c:>10}" for c in res))
    for k in names:
        cells = []
        for c, row in res.items():
            cells.append(f"{row['phases'][k] * 1e3:>10.1f}" if c == "off" else f"{row['phase_extra'][k] * 1e3:>+10.1f}")
        print(f"{k:<16}" + "".join(cells))
    print("off: median ms of a phase without logging; the others: median ms more than the unlogged runs "
          "either side. start-up: launch to the first line of Python; logger start: from the model built to "
          "the simulation's start (the logger is created there); files, summary: from the simulation's end "
          "to the command's return (the logger finishes its files there); exit: exit handlers and teardown.")


def print_example(title: str, res: dict) -> None:
    print(title)
    print(f"{'logging':<8} {'wall':>8} {'overhead':>9} {'(95 % CI)':>16} {'(quartiles)':>16} {'a sample':>9} "
          f"{'start':>8} {'close':>8} {'direct':>7} {'sim CPU':>10} {'(95 % CI)':>16} {'steal':>8} {'MCAP/sim s':>11}")
    for c, row in res.items():
        quart = "" if c == "off" else f"{100 * row['overhead_q1']:+.1f}..{100 * row['overhead_q3']:+.1f}%"
        ci = "" if c == "off" else f"{100 * row['overhead_ci'][0]:+.1f}..{100 * row['overhead_ci'][1]:+.1f}%"
        over = "" if c == "off" else f"{100 * row['overhead']:+.1f}%"
        us = "" if row["sample_us"] is None else f"{row['sample_us']:.0f} us"
        st = "" if row["start_s"] is None else f"{row['start_s'] * 1e3:.1f} ms"
        cl = "" if row["close_s"] is None else f"{row['close_s'] * 1e3:.1f} ms"
        di = "" if row["direct"] is None else f"{100 * row['direct']:.1f}%"
        mb = row["mcap_bytes_per_sim_s"]
        co = "" if row["cpu_overhead"] is None else f"{100 * row['cpu_overhead']:+.1f}%"
        cci = "" if row["cpu_ci"] is None else f"{100 * row['cpu_ci'][0]:+.1f}..{100 * row['cpu_ci'][1]:+.1f}%"
        print(f"{c:<8} {row['wall_s']:>7.3f}s {over:>9} {ci:>16} {quart:>16} {us:>9} {st:>8} {cl:>8} {di:>7} "
              f"{co:>10} {cci:>16} {row['steal_ms']:>5.1f} ms {'' if mb is None else f'{mb / 1e3:.1f} kB':>11}")


def _save(prefix: str | None, kind: str, res: dict) -> None:
    """Write the runs of one measurement (``kind``: "command" or "process") to
    ``PREFIX-kind.json``, for :func:`print_pooled`."""
    if not prefix:
        return
    data = {"kind": kind, "duration": next(iter(res.values()))["duration"], "date": time.strftime("%Y-%m-%d %H:%M"),
            "load": os.getloadavg()[0], "runs": {c: row["runs"] for c, row in res.items()}}
    Path(f"{prefix}-{kind}.json").write_text(json.dumps(data))


def print_pooled(files: list[str]) -> int:
    """The tables of ``--example`` over the runs of several saved sets of one kind: each
    logged run keeps its ratio to its own flanking unlogged runs, and the ratios of all sets
    are pooled."""
    sets = [json.loads(Path(f).read_text()) for f in files]
    kinds = {d["kind"] for d in sets}
    if len(kinds) != 1:
        raise SystemExit(f"--pool: the files mix kinds {sorted(kinds)}; pool one kind at a time")
    if kinds == {"steady"}:
        print_steady(_pool_steady([d["result"] for d in sets]),
                     f"{len(sets)} sets pooled ({', '.join(d['date'] for d in sets)})")
        return 0
    runs: dict[str, list] = {}
    for d in sets:
        for c, rows in d["runs"].items():
            runs.setdefault(c, []).extend(rows)
    res = {c: _summary(rows, sets[0]["duration"]) for c, rows in runs.items()}
    print_example(f"{kinds.pop()}: {len(sets)} sets pooled ({', '.join(d['date'] for d in sets)}), "
                  + ", ".join(f"{c} {row['n']} runs" for c, row in res.items() if c != "off"), res)
    if "phases" in res.get("off", {}):
        print_phases(res)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=20000, help="steps a configuration in all")
    ap.add_argument("--block", type=int, default=500, help="steps a block")
    ap.add_argument("--pad-us", type=float, default=0.0,
                    help="extra numpy work a step on top of the synthetic arm's own")
    ap.add_argument("--dt", type=float, default=1e-3, help="time step of the synthetic arm, s")
    ap.add_argument("--example", action="store_true",
                    help="measure the three-segment example (qchain run of wave_arm.toml) instead")
    ap.add_argument("--duration", type=float, default=20.0,
                    help="--example: simulated time of the in-process measurement, s")
    ap.add_argument("--repeats", type=int, default=10, help="--example: runs a config")
    ap.add_argument("--worker", choices=["auto", "process", "thread"], default="auto",
                    help="--example: where the logger writes (RunLogger's worker)")
    ap.add_argument("--only", choices=["command", "process", "steady", "corun"], default=None,
                    help="--example: only the whole command, only the simulation phase in one process, only "
                         "the simulation's steady state (blocks interleaved), or only the cost of a busy other "
                         "core")
    ap.add_argument("--rounds", type=int, default=40, help="--example --only steady: rounds of blocks")
    ap.add_argument("--block-s", type=float, default=20.0, help="--example --only steady: simulated s a block")
    ap.add_argument("--configs", default="mcap,rrd,both",
                    help="--example: logging configurations, comma-separated from mcap, rrd, both")
    ap.add_argument("--save", metavar="PREFIX",
                    help="--example: also write every run to PREFIX-command.json / PREFIX-process.json")
    ap.add_argument("--pool", nargs="+", metavar="FILE",
                    help="summarise runs saved with --save (several sets of one kind pooled) and exit")
    args = ap.parse_args(argv)
    if args.pool:
        return print_pooled(args.pool)
    if args.example:
        n = args.repeats
        configs = args.configs.split(",")
        if not set(configs) <= set(EXAMPLE_CONFIGS):
            ap.error(f"--configs: choose from {', '.join(EXAMPLE_CONFIGS)}, got {args.configs!r}")
        if args.only in (None, "command"):
            res = example_command_overhead(None, n, configs=configs)
            _save(args.save, "command", res)
            print_example(f"the three-segment example as a user runs it: `qchain run wave_arm.toml --no-plots` "
                          f"(4 s simulated, 201 samples), whole command; {n} runs a config, each against the "
                          f"unlogged runs either side of it; load average {os.getloadavg()[0]:.2f}", res)
            print_phases(res)
            print()
        if args.only in (None, "process"):
            res = example_overhead(args.duration, n, worker=args.worker, configs=configs)
            _save(args.save, "process", res)
            print_example(f"simulation phase, in one process: {args.duration:g} s simulated "
                          f"({res[configs[0]]['samples']:.0f} samples), logger created to files finished, the "
                          f"writer started 1.5 s ahead as qchain run does; {args.worker} writer; {n} runs a "
                          f"config; load average {os.getloadavg()[0]:.2f}", res)
            print()
        if args.only in (None, "steady"):
            res = example_steady(args.block_s, args.rounds, configs=configs)
            if args.save:
                Path(f"{args.save}-steady.json").write_text(json.dumps(
                    {"kind": "steady", "date": time.strftime("%Y-%m-%d %H:%M"), "load": os.getloadavg()[0],
                     "result": res}))
            print_steady(res)
            print()
        co = co_running() if args.only in (None, "corun") else {}
        if co:
            print(f"work on the other core, no logging ({co['off']['wall_s']:.3f} s a 4 s simulation with "
                  f"the other core idle, steal {co['off']['steal_ms']:.0f} ms; 20 runs each): "
                  + ", ".join(f"{label} {100 * co[c]['overhead']:+.1f}% ({100 * co[c]['overhead_ci'][0]:+.1f}.."
                              f"{100 * co[c]['overhead_ci'][1]:+.1f}%), steal {co[c]['steal_ms']:.0f} ms"
                              for c, label in (("normal", "normal priority"), ("idle", "idle priority"),
                                               ("import", "rerun-sdk imports at idle priority")))
                  + ": what any work of the writer's on the other core costs the simulation on this machine")
        if args.only not in ("corun", "steady"):
            st = writer_startup()
            print("writer start-up without prepare_writer (launch to its first answer, median of 5): "
                  + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in st.items())
                  + " (with the .rrd: Rerun imported and started, which otherwise happens in the background)")
        print("overhead: median over runs of wall / mean of the unlogged runs either side - 1 (target <= 5 %), "
              "with a bootstrap 95 % confidence interval of that median. a sample: the recorder's cost in the "
              "simulating process (frames of a batch of samples in one compiled call, one write to the "
              "writer). start: creating the logger; close: waiting for the files at the end. direct: "
              "(samples + start + close) / wall of the same run, the share of the run the simulating "
              "process spent logging (a ratio within one run: the machine's drift cancels). "
              "sim CPU: the simulating process's CPU time (it leaves out time the hypervisor took: steal). "
              "steal: CPU time the hypervisor took from this virtual machine during a run, median.")
        return 0
    step = synthetic_step(args.dt, args.pad_us)
    print_table(measure_overhead(step, args.steps, block=args.block))
    return 0


if __name__ == "__main__":
    sys.exit(main())
