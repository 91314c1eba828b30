"""Cost per step against the number of segments, for every compiled method, with
``pinocchio.aba`` on equal-nv rigid chains for reference; the exponent fitted.

The arm: n = 1 .. 100 of bench_chain's segments (0.1 m, 15 mm, 50 g, E = 0.1 MPa, damped) on a
fixed base, hanging under gravity from a bent start (bench_chain's ``state``), no pressure;
curvature coordinates, the default slice nodes, the full spatial model (no planar or
inextensible reduction, so nv = 3 n). Each method runs a fixed number of steps on the compiled
engine (rk4, midpoint: ``dt`` = 10 us; dopri5, radau5: ``first_step`` = ``max_step`` = 10 us at
rtol 1e-3, so every run takes the same steps whatever n); cost per step = the marginal cost,
(time of a 550-step run - that of a 50-step run) / 500 (medians of ``repeats``, engine
compiled), which leaves out a run's fixed cost (checks, packing: about a millisecond). Times are
CPU (process) time, which other jobs on a shared machine disturb less than wall time.
Reference: ``pinocchio.aba`` on bench_chain's rigid chain (RX, RY, PZ a segment) with the same
nv, median CPU time a call, and a step's cost in ``aba`` calls.

The exponent ``b`` of ``cost = a n^b`` is fitted by least squares on log-log over n >= 5 (below, a
step's work that does not grow with n dominates), with its standard error (``scipy.stats.linregress``).

Run: ``python benchmarks/bench_step_scaling.py [--n 1 2 5 10 20 50 100] [--repeats 5] [--out DIR]``;
writes ``step_scaling.csv`` and ``step_scaling.png`` into ``--out`` (default ``out/bench``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.stats import linregress

import _study
from bench_chain import rigid_chain, soft_chain, state
from qchain.sim.simulation import COMPILED, FIXED_STEP, simulate

DT = 1e-5  # s, every method's step
STEPS = (50, 550)  # the two runs whose difference is the marginal cost of 500 steps
FIT_FROM = 5  # segments: the fit's smallest n


def run_cost(ch, q, v, method: str, repeats: int) -> tuple[float, int]:
    """Marginal CPU seconds per step of ``method`` on ``ch`` from ``(q, v)``, and the steps of
    the longer run."""
    kw = dict(dt=DT) if method in FIXED_STEP else dict(first_step=DT, max_step=DT, rtol=1e-3, atol=1e-6)
    simulate(ch, q, v, (0.0, 2 * DT), method=method, energies=False, **kw)  # compile or load
    cpu = {k: [] for k in STEPS}
    steps = {}
    for _ in range(repeats):
        for k in STEPS:
            T = k * DT
            t0 = time.process_time()
            tr = simulate(ch, q, v, (0.0, T), method=method, energies=False, t_eval=np.array([T]), **kw)
            cpu[k].append(time.process_time() - t0)
            if not tr.success:
                raise RuntimeError(f"{method} at n = {ch.n} failed: {tr.message}")
            steps[k] = int(tr.meta.get("nsteps") or k)
    a, b = STEPS
    return (float(np.median(cpu[b])) - float(np.median(cpu[a]))) / (steps[b] - steps[a]), steps[b]


def cpu_per_call_us(f, calls: int) -> float:
    """CPU microseconds per call of ``f()`` over ``calls`` calls."""
    t0 = time.process_time()
    for _ in range(calls):
        f()
    return (time.process_time() - t0) / calls * 1e6


def run(ns, repeats: int) -> list[dict]:
    rng = np.random.default_rng(0)
    rows = []
    for n in ns:
        ch = soft_chain(n)
        q, v, _ = state(ch, rng)
        model = rigid_chain(n)
        data = model.createData()
        qr = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        vr, tr = rng.normal(size=model.nv), rng.normal(size=model.nv)
        aba = float(np.median([cpu_per_call_us(lambda: pin.aba(model, data, qr, vr, tr), 2000)
                               for _ in range(repeats)]))
        row = dict(n=n, nv=ch.nv, aba_us=aba)
        for method in COMPILED:
            cost, steps = run_cost(ch, q, v, method, repeats)
            row[f"{method}_us_per_step"] = 1e6 * cost
            row[f"{method}_steps"] = steps
            row[f"{method}_aba_calls"] = 1e6 * cost / aba
        rows.append(row)
        print(f"n = {n:3d}: " + ", ".join(f"{m} {row[m + '_us_per_step']:.1f} us" for m in COMPILED)
              + f"; pin.aba {aba:.2f} us", flush=True)
    return rows


def fits(rows) -> dict:
    """``{name: (exponent, its standard error)}`` of cost ~ n^b over n >= FIT_FROM."""
    use = [r for r in rows if r["n"] >= FIT_FROM]
    out = {}
    if len(use) < 2:
        return out
    x = np.log([r["n"] for r in use])
    for name in [f"{m}_us_per_step" for m in COMPILED] + ["aba_us"]:
        f = linregress(x, np.log([r[name] for r in use]))
        out[name] = (float(f.slope), float(f.stderr))
    return out


def plot(rows, fitted, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n"] for r in rows]
    fig, ax = plt.subplots(figsize=(7, 5))
    for m, mark in zip(COMPILED, "osD^"):
        b, se = fitted.get(f"{m}_us_per_step", (np.nan, np.nan))
        ax.loglog(n, [r[f"{m}_us_per_step"] for r in rows], mark + "-", label=f"qchain {m} (n^{b:.2f} +- {se:.2f})")
    b, se = fitted.get("aba_us", (np.nan, np.nan))
    ax.loglog(n, [r["aba_us"] for r in rows], "k--", label=f"pinocchio.aba, rigid, same nv (n^{b:.2f} +- {se:.2f})")
    ax.set_xlabel("segments n (nv = 3 n)")
    ax.set_ylabel("median time per step or call (us)")
    ax.set_title(f"cost per step against n (exponents fitted over n >= {FIT_FROM})", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _study.save(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2, 5, 10, 20, 50, 100])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats)
    fitted = fits(rows)
    print(f"\n{'n':>4} {'nv':>4} " + " ".join(f"{m + ' us/step':>16} {'x aba':>7}" for m in COMPILED) + f" {'aba us':>8}")
    for r in rows:
        print(f"{r['n']:>4} {r['nv']:>4} " + " ".join(
            f"{r[m + '_us_per_step']:>16.2f} {r[m + '_aba_calls']:>7.1f}" for m in COMPILED) + f" {r['aba_us']:>8.2f}")
    print(f"\nexponent b of cost ~ n^b (least squares on log-log over n >= {FIT_FROM}, +- standard error):")
    for name, (b, se) in fitted.items():
        print(f"  {name.replace('_us_per_step', '').replace('_us', ''):<8} {b:.2f} +- {se:.2f}")
    _study.write_csv(rows, args.out / "step_scaling.csv")
    plot(rows, fitted, args.out / "step_scaling.png")
    print(f"wrote step_scaling.csv and step_scaling.png into {args.out}")


if __name__ == "__main__":
    main()
