"""Cost of the exact dynamics derivatives against one forward-dynamics call and against
``pinocchio.computeABADerivatives`` on the rigid chain of equal nv (``bench_chain.rigid_chain``).

For n segments (fixed base, curvature coordinates, default nodes) this prints the median
CPU microseconds per call of ``forward_dynamics``, ``forward_dynamics_derivatives``,
``inverse_dynamics_derivatives`` and Pinocchio's ``aba``, ``computeABADerivatives`` and
``computeRNEADerivatives``, measured interleaved in one run (each set of ``--calls`` calls
is one sample), with the ratios of the derivative calls to one ``forward_dynamics`` call and
the spread (quartiles) of the ratio over the samples; the same ratio on the unchecked path of
integrators (both calls with ``data=`` and ``skip_checks=True``); Pinocchio's own ratio
``computeABADerivatives / aba`` on the rigid chain; the unchecked derivatives of the same chain
with one node a segment (``fwdD_u 1 node``: the part of their cost that does not grow with the
nodes, over the default-node forward call); and the accuracy: the relative difference of
``da_dq`` from central differences of ``forward_dynamics``.

Run: ``python benchmarks/bench_derivatives.py [--n 1 3 8 10 30] [--repeats 15] [--csv out.csv]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study
from bench_chain import per_call_us, rigid_chain, soft_chain, state


def fd_error(ch, q, v, p, da_dq) -> float:
    """Relative (Frobenius) difference of ``da_dq`` from central differences along integrate."""
    h = 1e-6
    cols = [(ch.forward_dynamics(ch.integrate(q, e), v, p) - ch.forward_dynamics(ch.integrate(q, -e), v, p)) / (2 * h)
            for e in h * np.eye(ch.nv)]
    ref = np.stack(cols, axis=1)
    return float(np.linalg.norm(da_dq - ref) / np.linalg.norm(ref))


def run(ns, repeats: int, calls: int):
    rng = np.random.default_rng(0)
    rows = []
    for n in ns:
        ch = soft_chain(n)
        q, v, p = state(ch, rng)
        ch1 = soft_chain(n, nodes=1)
        cdata1 = ch1.create_data()
        a = rng.normal(size=ch.nv)
        cdata = ch.create_data()
        model = rigid_chain(n)
        data = model.createData()
        qr = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        vr = rng.normal(size=model.nv)
        tr = rng.normal(size=model.nv)
        fns = {
            "forward_dynamics": lambda: ch.forward_dynamics(q, v, p),
            "fd_derivatives": lambda: ch.forward_dynamics_derivatives(q, v, p),
            "id_derivatives": lambda: ch.inverse_dynamics_derivatives(q, v, a),
            "fwd_unchecked": lambda: ch.forward_dynamics(q, v, p, data=cdata, skip_checks=True),
            "fwdD_unchecked": lambda: ch.forward_dynamics_derivatives(q, v, p, data=cdata, skip_checks=True),
            "fwdD_unchecked_1node": lambda: ch1.forward_dynamics_derivatives(q, v, p, data=cdata1, skip_checks=True),
            "pin.aba": lambda: pin.aba(model, data, qr, vr, tr),
            "pin.aba_derivs": lambda: pin.computeABADerivatives(model, data, qr, vr, tr),
            "pin.rnea_derivs": lambda: pin.computeRNEADerivatives(model, data, qr, vr, tr),
        }
        for f in fns.values():  # warm up (and compile)
            f()
        samples = {k: [] for k in fns}
        for _ in range(repeats):  # interleaved
            for k, f in fns.items():
                samples[k].append(per_call_us(f, calls))
        med = {k: float(np.median(s)) for k, s in samples.items()}
        ratio = np.array(samples["fd_derivatives"]) / np.array(samples["forward_dynamics"])
        ratio_u = np.array(samples["fwdD_unchecked"]) / np.array(samples["fwd_unchecked"])
        ratio_pin = np.array(samples["pin.aba_derivs"]) / np.array(samples["pin.aba"])
        err = fd_error(ch, q, v, p, ch.forward_dynamics_derivatives(q, v, p).da_dq)
        rows.append(dict(
            n=n, nv=ch.nv, **{k.replace(".", "_") + "_us": med[k] for k in fns},
            fdd_over_fd=med["fd_derivatives"] / med["forward_dynamics"],
            fdd_over_fd_q1=float(np.percentile(ratio, 25)), fdd_over_fd_q3=float(np.percentile(ratio, 75)),
            idd_over_fd=med["id_derivatives"] / med["forward_dynamics"],
            fddu_over_fdu=med["fwdD_unchecked"] / med["fwd_unchecked"],
            fddu_over_fdu_q1=float(np.percentile(ratio_u, 25)), fddu_over_fdu_q3=float(np.percentile(ratio_u, 75)),
            fdd_over_pin=med["fd_derivatives"] / med["pin.aba_derivs"],
            pin_d_over_pin=med["pin.aba_derivs"] / med["pin.aba"],
            pin_d_over_pin_q1=float(np.percentile(ratio_pin, 25)), pin_d_over_pin_q3=float(np.percentile(ratio_pin, 75)),
            fddu_1node_over_fdu=med["fwdD_unchecked_1node"] / med["fwd_unchecked"],
            da_dq_rel_err=err,
        ))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 3, 8, 10, 30])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--csv", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats, args.calls)
    print(f"{'n':>3} {'nv':>4} {'fwd_dyn':>8} {'fwd_derivs':>11} {'inv_derivs':>11} {'pin.aba_d':>10}"
          f" {'pin.rnea_d':>10} {'fwdD/fwd':>9} {'(q1-q3)':>12} {'invD/fwd':>9} {'fwdD/pin':>9}"
          f" {'fwd_u':>7} {'fwdD_u':>7} {'fwdD_u/fwd_u':>12} {'(q1-q3)':>12} {'1 node/fwd_u':>12}"
          f" {'pin.aba':>8} {'pin_d/pin':>9} {'(q1-q3)':>12} {'da_dq err':>10}")
    for r in rows:
        print(f"{r['n']:>3} {r['nv']:>4} {r['forward_dynamics_us']:>8.1f} {r['fd_derivatives_us']:>11.1f}"
              f" {r['id_derivatives_us']:>11.1f} {r['pin_aba_derivs_us']:>10.2f} {r['pin_rnea_derivs_us']:>10.2f}"
              f" {r['fdd_over_fd']:>9.2f} {r['fdd_over_fd_q1']:>5.2f}-{r['fdd_over_fd_q3']:<5.2f}"
              f" {r['idd_over_fd']:>9.2f} {r['fdd_over_pin']:>9.1f} {r['fwd_unchecked_us']:>7.1f}"
              f" {r['fwdD_unchecked_us']:>7.1f} {r['fddu_over_fdu']:>12.2f}"
              f" {r['fddu_over_fdu_q1']:>5.2f}-{r['fddu_over_fdu_q3']:<5.2f} {r['fddu_1node_over_fdu']:>12.2f}"
              f" {r['pin_aba_us']:>8.2f} {r['pin_d_over_pin']:>9.2f}"
              f" {r['pin_d_over_pin_q1']:>5.2f}-{r['pin_d_over_pin_q3']:<5.2f} {r['da_dq_rel_err']:>10.1e}")
    print("(median CPU us per call, interleaved; ratios of medians, quartiles of the per-set ratios; _u: data= and "
          "skip_checks=True; 1 node/fwd_u: the unchecked derivatives of the chain with one node a segment over "
          "fwd_u; pin_d/pin: computeABADerivatives over aba on the rigid chain; da_dq err: relative to central "
          "differences)")
    if args.csv:
        _study.write_csv(rows, Path(args.csv))
    return rows


if __name__ == "__main__":
    main()
