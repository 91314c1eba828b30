"""Step rate of the Gymnasium environment ``qchain/SoftArmReach-v0`` (docs/envs.md): one arm
(``gymnasium.make``) and N arms in one batch (``gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")``, :class:`qchain.envs.vector.SoftArmReachVec`), with
the engine alone beside them (one control period of :func:`qchain.simulate`, the call inside
a single ``env.step``) so that the environment's own overhead shows.

Workload: the built-in arm (three inextensible segments, rk4 at dt = 2 ms, a 20 ms control
period: 10 engine steps an ``env.step``). Each round starts every environment with
``reset(seed=round)`` (not timed) and then times ``steps`` steps of actions drawn once from a
fixed generator (the same actions for every round and every form); ``steps`` is below an
episode's 100 steps, so no episode is truncated inside a round. The first round is not timed
(compilation, thread pool start). Forms run side by side in each round, in a rotating order.

Figures: medians over rounds of CPU time (``time.process_time``: all threads of this process)
and wall time (``time.perf_counter``), as ``env.step`` calls a second, arm-steps a second
(N arms a call) and microseconds an arm-step. The machine's load average before and after is
printed beside them.

Run: ``python benchmarks/bench_envs.py [--quick] [--rounds R] [--steps S]``; on a shared machine
under ``flock /tmp/qchain-bench.flock``.
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium
import numpy as np

import qchain.envs  # noqa: F401  (registers qchain/SoftArmReach-v0)
from qchain import simulate
from qchain.envs import ENV_ID

SIZES = (1, 8, 32)
QUICK_SIZES = (1, 2)


def make_forms(sizes):
    """``{label: (N, env)}``: the single environment and one vectorised one a size."""
    forms = {"single": (1, gymnasium.make(ENV_ID))}
    for n in sizes:
        forms[f"vector N={n}"] = (n, gymnasium.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point"))
    return forms


def time_round(label, n, env, actions, seed):
    """CPU and wall seconds of ``len(actions)`` steps of ``env`` after an untimed reset."""
    env.reset(seed=seed)
    if label == "single":
        A = actions[:, 0]
    else:
        A = actions[:, :n]
    c0, w0 = time.process_time(), time.perf_counter()
    for a in A:
        env.step(a)
    return time.process_time() - c0, time.perf_counter() - w0


def time_engine(task, actions, seed):
    """CPU and wall seconds of the single environment's engine calls alone: one control period
    of :func:`qchain.simulate` an action, from the state the previous one reached."""
    q, v = task.q_rest.copy(), task.v_rest.copy()
    P = [task.pressures(a) for a in actions[:, 0]]
    c0, w0 = time.process_time(), time.perf_counter()
    for p in P:
        tr = simulate(task.chain, q, v, (0.0, task.dt_control), pressure=p, **task.run_settings)
        q, v = tr.q[-1], tr.v[-1]
    return time.process_time() - c0, time.perf_counter() - w0


def run(quick: bool = False, rounds: int | None = None, steps: int | None = None) -> list[dict]:
    sizes = QUICK_SIZES if quick else SIZES
    rounds = rounds or (2 if quick else 5)
    steps = steps or (3 if quick else 50)
    forms = make_forms(sizes)
    task = forms["single"][1].unwrapped.task
    if not steps < round(task.max_time / task.dt_control):
        raise SystemExit(f"--steps must be below an episode's {round(task.max_time / task.dt_control)} steps, got {steps}")
    nmax = max(sizes)
    actions = np.random.default_rng(12345).uniform(-1.0, 1.0, size=(steps, nmax, task.nu))
    labels = ["simulate (engine)"] + list(forms)
    cpu = {k: [] for k in labels}
    wall = {k: [] for k in labels}
    load0 = os.getloadavg()
    for r in range(rounds + 1):
        order = labels[r % len(labels):] + labels[:r % len(labels)]
        for k in order:
            if k == "simulate (engine)":
                c, w = time_engine(task, actions, seed=r)
            else:
                c, w = time_round(k, *forms[k], actions, seed=r)
            if r > 0:  # round 0: compilation, pool start
                cpu[k].append(c)
                wall[k].append(w)
    load1 = os.getloadavg()
    for _, env in forms.values():
        env.close()
    print(f"{ENV_ID}: {steps} steps a round, median of {rounds} rounds; dt_control = {task.dt_control * 1e3:g} ms, "
          f"method {task.method}; load average {load0[0]:.2f} -> {load1[0]:.2f}, {os.cpu_count()} CPUs")
    head = (f"{'form':>18} {'N':>3} | {'CPU steps/s':>11} {'arm-steps/s':>11} {'us/arm-step':>11} | "
            f"{'wall steps/s':>12} {'arm-steps/s':>11} {'us/arm-step':>11}")
    print(head)
    print("-" * len(head))
    rows = []
    for k in labels:
        n = 1 if k == "simulate (engine)" else forms[k][0]
        c, w = float(np.median(cpu[k])), float(np.median(wall[k]))
        row = dict(form=k, N=n, cpu_steps_per_s=steps / c, cpu_arm_steps_per_s=n * steps / c,
                   cpu_us_per_arm_step=c / (n * steps) * 1e6, wall_steps_per_s=steps / w,
                   wall_arm_steps_per_s=n * steps / w, wall_us_per_arm_step=w / (n * steps) * 1e6)
        rows.append(row)
        print(f"{k:>18} {n:3d} | {row['cpu_steps_per_s']:11.0f} {row['cpu_arm_steps_per_s']:11.0f} "
              f"{row['cpu_us_per_arm_step']:11.0f} | {row['wall_steps_per_s']:12.0f} "
              f"{row['wall_arm_steps_per_s']:11.0f} {row['wall_us_per_arm_step']:11.0f}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(prog="bench_envs.py", description=__doc__.strip().splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a tiny run (N = 1, 2; 2 rounds of 3 steps)")
    ap.add_argument("--rounds", type=int, default=None, help="timed rounds (default 5)")
    ap.add_argument("--steps", type=int, default=None, help="env.step calls a round (default 50)")
    args = ap.parse_args(argv)
    return run(args.quick, args.rounds, args.steps)


if __name__ == "__main__":
    main()
