"""Cost of a rollout with forward sensitivities (qchain.sim.sensitivity) against a plain rollout.

For a 3- and a 10-segment spatial arm driven by a sine in every chamber this prints the median
CPU time of a plain ``simulate`` run and of ``sensitivities`` with 1, 5 and 20 columns (model
parameters: each kind on each segment in turn, then gravity, then initial-state columns), with the same
method and steps, measured interleaved in one run: ``rk4`` at a fixed ``dt`` and ``dopri5``
(the sensitivity pass on the steps of the plain run, frozen; "total" adds that plain run, which
chooses them). The last columns: the ratio to the plain rollout, and what central differences
of whole runs would cost for the same columns (2 ncol rollouts).

Run: ``python benchmarks/bench_sensitivity.py [--n 3 10] [--repeats 7] [--span 0.2]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from qchain import Chain, Segment, simulate
from qchain.sim.inputs import Sine
from qchain.sim.sensitivity import sensitivities

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.02)
COLUMNS = (1, 5, 20)


def arm(n: int) -> Chain:
    return Chain([Segment(**SEG) for _ in range(n)], gravity=(0, 0, -9.81))


def cpu(fn) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def columns(chain: Chain, ncol: int):
    """``ncol`` columns: the model's parameters (every kind on each segment in turn, then
    gravity's axes), then initial-state columns if the parameters run out."""
    kinds = ("youngs_modulus", "damping", "mass", "length", "chamber_area")
    every = [(k, j) for j in range(chain.n) for k in kinds] + [("gravity", a) for a in range(3)]
    params = every[:ncol]
    free = np.flatnonzero(chain.active)
    names = [f"q0[{i}]" for i in free] + [f"v0[{i}]" for i in free]
    return params, names[: ncol - len(params)]


def run(ns, repeats: int, span: float):
    rows = []
    for n in ns:
        chain = arm(n)
        q0, v0 = chain.neutral(), np.zeros(chain.nv)
        P = Sine(amplitude=[2e4, 1e4, 0] * n, frequency=2.0, phase=[0, 2.09, 4.19] * n, offset=[2e4, 1e4, 0] * n)
        t_eval = np.linspace(0, span, 51)
        for method, kw in (("rk4", dict(dt=1e-4)), ("dopri5", dict(rtol=1e-6, atol=1e-8))):
            common = dict(pressure=P, t_eval=t_eval, method=method)
            plain = lambda: simulate(chain, q0, v0, (0, span), energies=False, **common, **kw)
            tr = simulate(chain, q0, v0, (0, span), energies=False, pressure=P, method=method, **kw)
            steps = np.array(tr.t)  # every step's end: the steps the plain run takes
            fns = {"plain": plain}
            for ncol in COLUMNS:
                params, initial = columns(chain, ncol)
                fns[ncol] = (lambda params=params, initial=initial:
                             sensitivities(chain, q0, v0, (0, span), params=params, initial=initial, steps=steps,
                                           **common))
            for f in fns.values():  # warm up (and compile)
                f()
            samples = {k: [] for k in fns}
            for _ in range(repeats):  # interleaved
                for k, f in fns.items():
                    samples[k].append(cpu(f))
            med = {k: float(np.median(s)) for k, s in samples.items()}
            r = fns[1]()
            for ncol in COLUMNS:
                total = med[ncol] + (med["plain"] if method == "dopri5" else 0.0)
                rows.append(dict(n=n, nv=chain.nv, method=method, nsteps=r.nsteps, ncol=ncol,
                                 plain_ms=1e3 * med["plain"], sens_ms=1e3 * med[ncol], total_ms=1e3 * total,
                                 ratio=total / med["plain"], fd_ratio=2.0 * ncol))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[3, 10])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--span", type=float, default=0.2)
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats, args.span)
    print(f"{'n':>3} {'nv':>3} {'method':>7} {'steps':>6} {'cols':>5} {'plain ms':>9} {'sens ms':>9} {'total ms':>9}"
          f" {'x plain':>8} {'x plain (FD)':>13}")
    for r in rows:
        print(f"{r['n']:>3} {r['nv']:>3} {r['method']:>7} {r['nsteps']:>6} {r['ncol']:>5} {r['plain_ms']:>9.2f}"
              f" {r['sens_ms']:>9.2f} {r['total_ms']:>9.2f} {r['ratio']:>8.1f} {r['fd_ratio']:>13.0f}")
    print(f"(median CPU time of {args.repeats} interleaved rounds, {args.span} s simulated; dopri5's total includes "
          "the plain run that chooses the steps; FD: central differences of whole runs, 2 per column)")


if __name__ == "__main__":
    main()
