"""Model-predictive control (qchain.control.MPC): solve time per control step against the
horizon, the control rate it sustains in real time, and the accuracy of its discrete dynamics.

The arm of ``examples/tip_control.py`` (three inextensible segments of 0.1 m hanging from a
mount 0.5 m up) tracks a horizontal circle of 5 cm radius at 0.5 Hz, centred under the
mount 0.206 m above the ground (where a constant-curvature arc of 0.3 m reaches 5 cm
sideways), starting at rest hanging straight (5 cm from the circle's first point). For each
horizon ``H`` the closed loop runs for one period (2 s) at ``--rate`` (50 Hz), pressures in
[0, 100] kPa, the plant integrated by ``rk4`` at 2 ms. Printed per horizon: the CPU time of
a control step's optimisation (median, 10th and 90th percentile over the steps after the
first, which starts cold), the median iterations, the rate it sustains in real time
(``1 / median``), whether that is the rate asked for, and the tip's RMS error over the
second half of the period. Each horizon runs twice, interleaved in this one process: the
compiled horizon passes (``compiled=True``, the default: one compiled call a rollout and one a
linearisation, :mod:`qchain.sim.engine.horizon`) and the Python path (``compiled=False``:
per-stage calls of the model, the chain rule in numpy); ``speed-up`` is the ratio of their
median solve times. The machine's load average is printed first (other processes share
the cores: CPU time, not wall time, is what is measured).

The second table: the discrete dynamics' accuracy. From states of the first run, one control
interval of the MPC's map (``steps`` RK4 steps) against ``dopri5`` at ``rtol = 1e-11``:
the largest error of the state after the interval, relative to the state's change over it,
and the CPU time of one interval with its derivatives (``MPC.step(..., derivatives=True)``)
on either path.

Run: ``python benchmarks/bench_mpc.py [--horizons 5 10 20 40] [--rate 50] [--duration 2] [--max-iter 5] [--max-step 0.01]``
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import pinocchio as pin

from qchain import Chain, Segment, simulate
from qchain.control import MPC

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.02, extensible=False)
RADIUS, FREQ, Z_C = 0.05, 0.5, 0.206  # m, Hz, m


def arm() -> Chain:
    X = pin.SE3(pin.rpy.rpyToMatrix(np.pi, 0.0, 0.0), np.array([0.0, 0.0, 0.5]))
    return Chain([Segment(**SEG) for _ in range(3)], gravity=(0.0, 0.0, -9.81), base_placement=X)


def circle(t: float) -> np.ndarray:
    w = 2.0 * np.pi * FREQ
    return np.array([RADIUS * np.cos(w * t), RADIUS * np.sin(w * t), Z_C])


def main(argv=None) -> None:
    par = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    par.add_argument("--horizons", type=int, nargs="+", default=[5, 10, 20, 40])
    par.add_argument("--rate", type=float, default=50.0)
    par.add_argument("--duration", type=float, default=1.0 / FREQ)
    par.add_argument("--max-step", type=float, default=0.01, help="largest RK4 step of the MPC's dynamics (s)")
    par.add_argument("--max-iter", type=int, default=5, help="box-DDP iterations a control step (1: real-time iteration)")
    args = par.parse_args(argv)
    ch = arm()
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    print(f"3-segment hanging arm, 5 cm circle at {FREQ:g} Hz, control rate {args.rate:g} Hz, "
          f"{args.duration:g} s closed loop a horizon, at most {args.max_iter} iterations a step, "
          f"RK4 steps of <= {args.max_step * 1e3:g} ms")
    print("load average (1, 5, 15 min) at the start: " + ", ".join(f"{x:.1f}" for x in os.getloadavg()))
    print(f"{'H':>4} {'path':>8} {'plan s':>7} {'median ms':>10} {'p10 ms':>8} {'p90 ms':>8} {'iters':>6} "
          f"{'sustained Hz':>13} {'real time':>10} {'tip RMS mm':>11} {'p max kPa':>10} {'speed-up':>9}")
    states = None
    for H in args.horizons:
        medians = {}
        for compiled in (False, True):
            path = "compiled" if compiled else "python"
            ctl = MPC(ch, circle, horizon=H, rate=args.rate, p_max=1e5, max_iter=args.max_iter,
                      max_step=args.max_step, compiled=compiled)
            tr = ctl.run(q0, v0, args.duration, method="rk4", dt=2e-3)
            s = ctl.signals()
            solve = s["solve_s"][1:]  # the first step starts cold
            second = s["t"] >= 0.5 * args.duration
            rms = np.sqrt(np.mean(np.sum(s["error"][second] ** 2, axis=1)))
            med = medians[path] = float(np.median(solve))
            ratio = f"{medians['python'] / med:>9.1f}" if compiled else f"{'':>9}"
            print(f"{H:>4} {path:>8} {H / args.rate:>7.2f} {med * 1e3:>10.1f} {np.percentile(solve, 10) * 1e3:>8.1f} "
                  f"{np.percentile(solve, 90) * 1e3:>8.1f} {np.median(s['iterations'][1:]):>6.0f} {1.0 / med:>13.1f} "
                  f"{'yes' if 1.0 / med >= args.rate else 'no':>10} {rms * 1e3:>11.3f} {s['p'].max() / 1e3:>10.1f}"
                  f"{ratio}", flush=True)
        if states is None:
            states = [(tr.q[i], tr.v[i], s["p"][min(int(round(tr.t[i] * args.rate)), len(s["p"]) - 1)])
                      for i in np.linspace(0, len(tr.t) - 1, 8).astype(int)]

    print(f"\ndiscrete dynamics: one interval of 1/{args.rate:g} s against dopri5 (rtol 1e-11), 8 states of the run")
    print(f"{'max_step ms':>12} {'RK4 steps':>10} {'rel. error':>11} {'python ms':>10} {'compiled ms':>12}")
    a = ch.active
    for max_step in (0.02, 0.01, 0.005):
        ctl = MPC(ch, circle, horizon=1, rate=args.rate, p_max=1e5, max_step=max_step)
        slow = MPC(ch, circle, horizon=1, rate=args.rate, p_max=1e5, max_step=max_step, compiled=False)
        worst, cpu, cpu_py = 0.0, [], []
        ctl.step(*states[0], derivatives=True)  # (the compiled passes loaded)
        for q, v, p in states:
            for c, times in ((slow, cpu_py), (ctl, cpu)):
                c0 = time.process_time()
                c.step(q, v, p, derivatives=True)
                times.append(time.process_time() - c0)
            q1, v1 = ctl.step(q, v, p)
            ref = simulate(ch, q, v, (0.0, 1.0 / args.rate), pressure=p, method="dopri5", rtol=1e-11, atol=1e-13)
            x1 = np.concatenate([q1[a], v1[a]])
            xr = np.concatenate([ref.q[-1][a], ref.v[-1][a]])
            change = np.abs(xr - np.concatenate([q[a], v[a]])).max()
            worst = max(worst, np.abs(x1 - xr).max() / change)
        print(f"{max_step * 1e3:>12g} {ctl.steps:>10} {worst:>11.2e} {np.median(cpu_py) * 1e3:>10.2f} "
              f"{np.median(cpu) * 1e3:>12.2f}")


if __name__ == "__main__":
    main()
