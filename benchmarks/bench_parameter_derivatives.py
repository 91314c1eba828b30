"""Cost of the exact parameter derivatives against one forward-dynamics call.

For n segments (fixed base, curvature coordinates, default nodes) this prints the median
microseconds per call, measured interleaved in one run (each set of ``--calls`` calls is one
sample; the thread's CPU time, so waiting for a core on a loaded machine does not count), of

* ``fwd``: ``forward_dynamics`` on its fast path (``skip_checks=True``, a ``data``);
* ``aba``: the compiled articulated-body pass alone (:func:`qchain.algorithms.recursive.aba`),
  the forward dynamics without Python around it;

(``aba`` and the compiled passes below are timed as ``--calls`` calls from a compiled loop: a
call from Python would time numba's typing of the structures' dozens of arrays)
* ``state_d``: the compiled state derivatives (:func:`qchain.algorithms.aba_derivatives.aba_derivatives`:
  ``a``, ``da/dq``, ``da/dv``, ``da/dp``, ``M^-1``);
* ``theta_k``: the compiled entry the trajectory sensitivities call
  (:func:`qchain.algorithms.parameter_derivatives.first_order_parameter_derivatives`: the state
  derivatives and ``d(v, a)/dtheta`` in one call) for ``k`` parameters: 1 (segment 0's E),
  ``n`` (every segment's mass: the O(n^2) inertia columns), ``5n + 3`` (every per-segment kind
  and gravity);
* ``checked``: the checked API ``Chain.forward_dynamics_parameter_derivatives`` for ``5n + 3``;

and the ratios to ``aba``: what the parameter columns add to
a call that computes the state derivatives anyway (a forward sensitivity's stage), in units of
one forward-dynamics pass, is timed on its own as ``at_k``
(:func:`qchain.algorithms.parameter_derivatives.parameter_derivatives_at`, reading the state
derivatives' workspaces).

Run: ``python benchmarks/bench_parameter_derivatives.py [--n 3 10] [--repeats 15] [--csv out.csv]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numba
import numpy as np

import _study
from bench_chain import soft_chain, state
from qchain._jit import OPTIONS
from qchain.algorithms import aba_derivatives, parameter_derivatives as pd, recursive
from qchain.arm.parameter_derivatives import PARAMETER_KINDS

PER_SEGMENT = [k for k, (_, _, seg) in PARAMETER_KINDS.items() if seg]


def per_call_us(f, calls: int) -> float:
    """Microseconds of this thread's CPU time per call (``time.thread_time``): on a shared,
    loaded machine the time the thread waits for a core does not count."""
    t0 = time.thread_time()
    for _ in range(calls):
        f()
    return (time.thread_time() - t0) / calls * 1e6


# Compiled loops: a call from Python types every array of the structures it is passed (dozens),
# which at n = 3 costs more than the pass itself; timed K calls inside compiled code, the figures
# are the passes' own. Compiled as the engine's code is (qchain._jit.OPTIONS: no reference
# counting, which the callees inherit), so the passes run as they do in a simulation.
@numba.njit(**OPTIONS)
def _loop_aba(K, arr, q, qd, f, z6, A0, qdd, A0o, ws, sc):
    ok = True
    for _ in range(K):
        ok &= recursive.aba(arr, q, qd, f, z6, A0, False, z6, qdd, A0o, ws, sc)
    return ok


@numba.njit(**OPTIONS)
def _loop_state(K, arr, q, qd, p, tau, z6, g_B, ws, wd, wa, sc):
    s = 0
    for _ in range(K):
        s += aba_derivatives.aba_derivatives(arr, False, q, qd, p, tau, z6, z6, g_B, ws, wd, wa, sc)
    return s


@numba.njit(**OPTIONS)
def _loop_theta(K, arr, q, qd, p, tau, z6, g_B, R, E, kinds, index, ws, wd, wa, wq, sc, dID, dx):
    s = 0
    for _ in range(K):
        s += pd.first_order_parameter_derivatives(arr, False, q, qd, p, tau, z6, z6, g_B, R, E, kinds, index, ws, wd,
                                                  wa, wq, sc, dID, dx)
    return s


@numba.njit(**OPTIONS)
def _loop_at(K, arr, q, qd, p, qdd, A0, z6, g_B, R, E, kinds, index, ws, wd, wa, wq, sc, da, dID):
    s = 0
    for _ in range(K):
        s += pd.parameter_derivatives_at(arr, False, q, qd, p, qdd, A0, z6, g_B, R, E, kinds, index, ws, wd, wa, wq,
                                         sc, da, dID)
    return s


def run(ns, repeats: int, calls: int):
    rng = np.random.default_rng(0)
    rows = []
    for n in ns:
        ch = soft_chain(n)
        q, v, p = state(ch, rng)
        nv = ch.nv
        data = ch.create_data()
        q3, v3, p3 = q.reshape(n, 3), v.reshape(n, 3), p.reshape(n, 3)
        z6, tau = np.zeros(6), np.zeros(nv)
        A0 = np.zeros(6)
        A0[:3] = -ch._g_B
        f = ch.internal_forces(q, v, p).reshape(n, 3).copy()
        qdd, A0o = np.empty((n, 3)), np.empty(6)
        ws, wd, wa = (tuple(data.aba_workspace()), tuple(data.rnea_workspace()),
                      tuple(data.aba_derivatives_workspace()))
        R = np.ascontiguousarray(ch.base_placement.rotation)
        E = np.array([s.youngs_modulus for s in ch.segments])
        sets = {"1": [("youngs_modulus", 0)], "n": [("mass", j) for j in range(n)],
                "5n3": [(k, j) for j in range(n) for k in PER_SEGMENT] + [("gravity", None)]}
        entry, at = {}, {}
        wat = data.aba_derivatives_workspace()
        for key, params in sets.items():
            P = ch.parameters(params)
            wq = tuple(pd.parameter_workspace(n, nv, len(P)))
            dx, dID = np.empty((2 * nv, len(P))), np.empty((nv, len(P)))
            entry[key] = (lambda P=P, wq=wq, dx=dx, dID=dID: _loop_theta(
                calls, ch._arrays, q3, v3, p3, tau, z6, ch._g_B, R, E, P.kinds, P.index, ws, wd, wa, wq,
                data.scratch, dID, dx))
            at[key] = (lambda P=P, wq=wq, dx=dx, dID=dID: _loop_at(
                calls, ch._arrays, q3, v3, p3, wat.a_c, wat.A0, z6, ch._g_B, R, E, P.kinds, P.index, ws, wd, wa, wq,
                data.scratch, dx[nv:], dID))
        Pall = ch.parameters(sets["5n3"])
        fns = {
            "fwd": lambda: ch.forward_dynamics(q, v, p, data=data, skip_checks=True),
            "aba": lambda: _loop_aba(calls, ch._arrays, q3, v3, f, z6, A0, qdd, A0o, ws, data.scratch),
            "state_d": lambda: _loop_state(calls, ch._arrays, q3, v3, p3, tau, z6, ch._g_B, ws, wd, wa, data.scratch),
            **{f"theta_{k}": fn for k, fn in entry.items()},
            **{f"at_{k}": fn for k, fn in at.items()},
            "checked": lambda: ch.forward_dynamics_parameter_derivatives(q, v, p, Pall, data=data),
        }
        fns["state_d"]()  # the workspaces the at_k calls read
        for fn in fns.values():  # warm up (and compile)
            fn()
        looped = {k for k in fns if k not in ("fwd", "checked")}  # K calls in compiled code a sample
        samples = {k: [] for k in fns}
        for _ in range(repeats):  # interleaved
            for k, fn in fns.items():
                samples[k].append(per_call_us(fn, 1) / calls if k in looped else per_call_us(fn, calls))
        med = {k: float(np.median(s)) for k, s in samples.items()}
        row = dict(n=n, nv=nv, **{k + "_us": med[k] for k in fns})
        for k in entry:
            row[f"extra_{k}_over_aba"] = med[f"at_{k}"] / med["aba"]
            row[f"total_{k}_over_aba"] = med[f"theta_{k}"] / med["aba"]
        row["state_d_over_aba"] = med["state_d"] / med["aba"]
        rows.append(row)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[3, 10])
    ap.add_argument("--repeats", type=int, default=31)
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--csv", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats, args.calls)
    print(f"{'n':>3} {'nv':>4} {'fwd':>7} {'aba':>7} {'state_d':>8} {'th_1':>7} {'th_n':>7} {'th_5n+3':>8}"
          f" {'at_1':>6} {'at_n':>6} {'at_5n+3':>8} {'checked':>8} | {'sd/aba':>7} {'at_1/aba':>9}"
          f" {'at_n/aba':>9} {'at_5n+3/aba':>12} {'th_5n+3/aba':>12}")
    for r in rows:
        print(f"{r['n']:>3} {r['nv']:>4} {r['fwd_us']:>7.1f} {r['aba_us']:>7.1f} {r['state_d_us']:>8.1f}"
              f" {r['theta_1_us']:>7.1f} {r['theta_n_us']:>7.1f} {r['theta_5n3_us']:>8.1f} {r['at_1_us']:>6.1f}"
              f" {r['at_n_us']:>6.1f} {r['at_5n3_us']:>8.1f} {r['checked_us']:>8.1f} | {r['state_d_over_aba']:>7.2f}"
              f" {r['extra_1_over_aba']:>9.2f} {r['extra_n_over_aba']:>9.2f} {r['extra_5n3_over_aba']:>12.2f}"
              f" {r['total_5n3_over_aba']:>12.2f}")
    print("(median us of CPU time per call, interleaved; th_k: state and parameter derivatives in one compiled "
          "call; at_k: the parameter columns alone after the state derivatives; ratios of medians to one aba pass)")
    if args.csv:
        _study.write_csv(rows, Path(args.csv))
    return rows


if __name__ == "__main__":
    main()
