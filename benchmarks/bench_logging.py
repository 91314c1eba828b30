"""Cost of logging a run, as a ratio to the same run without logging.

    python benchmarks/bench_logging.py [--steps 5000] [--repeats 5] [--workload-us 200]

Drives a simulation step function with logging off, MCAP on, Rerun (.rrd) on and both on,
interleaved (the order rotates every repeat), and prints the median steps/s of each, the
overhead ratios (time with logging / time without - 1; target <= 5 %), the time the writer
needed after the last step to drain and finish the files, and the MCAP bytes per simulated
second.

To measure a real simulation, give :func:`measure_overhead` a function that advances it one
step and returns a :class:`qchain.logging.StepRecord`, e.g.::

    from bench_logging import measure_overhead, print_table
    sim = make_three_segment_example()          # yours
    def step():
        sim.advance()                           # one integrator step
        return sim.step_record()                # a StepRecord of the new state
    print_table(measure_overhead(step, 5000, info=sim.run_info()))

Until then the synthetic workload stands in: the analytically bending three-segment arm of
``tests/logging_fixtures.py`` (closed-form constant-curvature arcs, ~200-250 us a step in
numpy), optionally padded with small dense solves to a chosen cost.
"""

from __future__ import annotations

import argparse
import os
import resource
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
        Extra numpy work a step (27 x 27 solves, like a three-segment mass matrix), to make
        a step cost about ``arm_record``'s cost + ``pad_us``.
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


def _run(step_fn, n_steps: int, config: str, info: RunInfo, workdir: Path, tag: str) -> dict:
    mcap = workdir / f"{tag}.mcap" if config in ("mcap", "both") else None
    rrd = workdir / f"{tag}.rrd" if config in ("rrd", "both") else None
    logger = None
    if config != "off":
        logger = RunLogger(info, mcap, rrd=rrd, worker="process", quiet=True)
    t_first = t_last = None
    children0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    c0 = time.process_time()
    t0 = time.perf_counter()
    if logger is None:
        for _ in range(n_steps):
            rec = step_fn()
        t_first = t_last = rec.t
    else:
        log = logger.log
        for i in range(n_steps):
            rec = step_fn()
            log(rec)
            if i == 0:
                t_first = rec.t
        t_last = rec.t
    t1 = time.perf_counter()
    c1 = time.process_time()
    if logger is not None:
        logger.close()
    t2 = time.perf_counter()
    children1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    writer_cpu = (children1.ru_utime + children1.ru_stime) - (children0.ru_utime + children0.ru_stime)
    out = {"loop": t1 - t0, "drain": t2 - t1, "cpu": c1 - c0, "writer_cpu": writer_cpu, "sim_span": None,
           "mcap_bytes": None}
    if mcap is not None:
        out["mcap_bytes"] = mcap.stat().st_size
        out["sim_span"] = (t_last - t_first) * n_steps / max(n_steps - 1, 1)
    for f in (mcap, rrd):
        if f is not None and f.exists():
            f.unlink()
    return out


def measure_overhead(step_fn, n_steps: int, sinks=CONFIGS, repeats: int = 5, info: RunInfo | None = None,
                     workdir: str | os.PathLike | None = None, warmup: bool = True) -> dict:
    """Median cost of logging with each sink set, interleaved.

    Parameters
    ----------
    step_fn : callable () -> StepRecord
        Advances the simulation one step and returns its record.
    n_steps : int
        Steps a run.
    sinks : sequence of {"off", "mcap", "rrd", "both"}
        Configurations; "off" (no logger) is the reference and is always measured.
    repeats : int
        Runs a configuration; the median is reported.
    info : RunInfo or None
        Run information (default: the synthetic arm's).
    workdir : path or None
        Where the files go (default: a temporary folder, removed after).

    Returns
    -------
    dict
        config -> {"steps_per_s", "loop_s", "drain_s", "overhead", "mcap_bytes_per_sim_s",
        "loops" (all repeats)}.
    """
    info = info or arm_info()
    configs = ["off"] + [c for c in sinks if c != "off"]
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        tmp = Path(tmp)
        fixed = {c: 0.0 for c in configs}  # writer CPU of a run without steps: start and finish
        if warmup:
            for c in configs:
                _run(step_fn, min(n_steps, 300), c, info, tmp, f"warm-{c}")
                if c != "off":
                    fixed[c] = statistics.median(_run(step_fn, 1, c, info, tmp, f"fixed-{c}")["writer_cpu"]
                                                 for _ in range(3))
        results = {c: [] for c in configs}
        for r in range(repeats):
            order = configs[r % len(configs):] + configs[: r % len(configs)]
            for c in order:
                results[c].append(_run(step_fn, n_steps, c, info, tmp, f"{c}-{r}"))
    ref = statistics.median(x["loop"] for x in results["off"])
    table = {}
    for c, runs in results.items():
        loop = statistics.median(x["loop"] for x in runs)
        row = {
            "steps_per_s": n_steps / loop,
            "loop_s": loop,
            "drain_s": statistics.median(x["drain"] for x in runs),
            "overhead": loop / ref - 1.0,
            "loops": [x["loop"] for x in runs],
            "cpu_us_per_step": statistics.median(x["cpu"] for x in runs) / n_steps * 1e6,
            "writer_cpu_us_per_step": (statistics.median(x["writer_cpu"] for x in runs) - fixed[c]) / n_steps * 1e6,
            "writer_fixed_cpu_s": fixed[c],
            "mcap_bytes_per_sim_s": None,
        }
        if runs[0]["mcap_bytes"] is not None:
            row["mcap_bytes_per_sim_s"] = statistics.median(x["mcap_bytes"] / x["sim_span"] for x in runs)
        table[c] = row
    table["_meta"] = {"n_steps": n_steps, "repeats": repeats, "us_per_step_off": ref / n_steps * 1e6}
    return table


def print_table(table: dict) -> None:
    meta = table["_meta"]
    print(f"{meta['n_steps']} steps a run, median of {meta['repeats']} interleaved runs; "
          f"a step without logging: {meta['us_per_step_off']:.0f} us wall; load average {os.getloadavg()[0]:.2f}")
    cpu_off = table["off"]["cpu_us_per_step"]
    print(f"{'logging':<8} {'steps/s':>8} {'overhead':>9} {'sim CPU/step':>13} {'writer CPU/step':>16} "
          f"{'drain':>7} {'MCAP/sim s':>11}")
    for c, row in table.items():
        if c.startswith("_"):
            continue
        mb = row["mcap_bytes_per_sim_s"]
        extra = row["cpu_us_per_step"] - cpu_off
        print(f"{c:<8} {row['steps_per_s']:>8.0f} {100 * row['overhead']:>8.1f}% "
              f"{row['cpu_us_per_step']:>7.0f} us{'' if c == 'off' else f' (+{extra:.1f})':>4} "
              f"{row['writer_cpu_us_per_step']:>13.0f} us {row['drain_s']:>6.2f}s "
              f"{'' if mb is None else f'{mb / 1e6:.2f} MB':>11}")
    print("overhead = median wall time of the run with logging / without - 1 (target <= 5 %); sim CPU = CPU "
          "time of the simulating process (its log() calls included); writer CPU = the writer process's "
          "(on the other core); drain = wait at close for the writer to finish the files.")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--pad-us", type=float, default=0.0,
                    help="extra numpy work a step on top of the synthetic arm's own (~200-250 us)")
    ap.add_argument("--dt", type=float, default=1e-3)
    args = ap.parse_args(argv)
    step = synthetic_step(args.dt, args.pad_us)
    print_table(measure_overhead(step, args.steps, repeats=args.repeats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
