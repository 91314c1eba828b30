"""Cost of the chain's dynamics against Pinocchio's ``aba`` on a rigid chain of equal nv.

For n segments (fixed base, curvature coordinates, default nodes) this prints the median
microseconds per call (CPU time of the process: the machine is shared) of ``mass_matrix``,
``nonlinear_effects`` and ``forward_dynamics`` (checked), ``forward_dynamics`` on the unchecked
path of integrators (``data=``, ``skip_checks=True``), the same accelerations solved by ``crba``
+ Cholesky (``M a = B p - D v - dU/dq - nle``), the median of ``pinocchio.aba`` on a rigid
chain with the same nv (RX, RY, PZ joints per segment carrying cylinder bodies of the same
mass, radius and length), measured interleaved in one run, the ratios of the two forward
dynamics to ``pinocchio.aba`` (ratio of the medians, with the quartiles of the per-set ratios),
and the accuracy bought: the relative difference of ``forward_dynamics`` at the default node
count from a 24-node reference.

Run: ``python benchmarks/bench_chain.py [--n 1 3 8 10 30] [--nodes 4 5 6] [--repeats 15] [--csv out.csv]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.linalg import cho_factor, cho_solve

import _study
from qchain import Chain, Segment

SEGMENT = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
               youngs_modulus=1e5, damping=0.01)


def soft_chain(n: int, nodes=None) -> Chain:
    return Chain([Segment(**SEGMENT, nodes=nodes) for _ in range(n)])


def rigid_chain(n: int) -> pin.Model:
    """RX, RY, PZ per segment; a cylinder body per segment on the PZ joint."""
    m = pin.Model()
    parent = 0
    for j in range(n):
        for k, joint in enumerate((pin.JointModelRX(), pin.JointModelRY(), pin.JointModelPZ())):
            offset = pin.SE3(np.eye(3), np.array([0.0, 0.0, SEGMENT["length"] if (k == 0 and j > 0) else 0.0]))
            parent = m.addJoint(parent, joint, offset, f"s{j}_{k}")
        body = pin.Inertia.FromCylinder(SEGMENT["mass"], SEGMENT["radius"], SEGMENT["length"])
        body = pin.SE3(np.eye(3), np.array([0.0, 0.0, SEGMENT["length"] / 2])).act(body)
        m.appendBodyToJoint(parent, body, pin.SE3.Identity())
    return m


def state(ch: Chain, rng):
    q = ch.neutral()
    for j in range(ch.n):
        q[ch.q_slice(j)] = [SEGMENT["length"] * 1.02, *rng.uniform(-8, 8, 2)]
    v = rng.normal(size=ch.nv)
    p = rng.uniform(0, 5e4, ch.nu)
    return q, v, p


def per_call_us(f, calls: int) -> float:
    """CPU microseconds per call of ``f`` over ``calls`` calls (process time: another job on the
    shared cores does not count)."""
    t0 = time.process_time()
    for _ in range(calls):
        f()
    return (time.process_time() - t0) / calls * 1e6


def run(ns, repeats: int, calls: int, nodes=(None,)):
    rows = []
    for n, nk in [(n, nk) for n in ns for nk in nodes]:
        rng = np.random.default_rng(n)  # one state per n, whatever the node count
        ch = soft_chain(n, nodes=nk)
        ref = soft_chain(n, nodes=24)
        q, v, p = state(ch, rng)
        cdata = ch.create_data()
        model = rigid_chain(n)
        data = model.createData()
        qr = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        vr = rng.normal(size=model.nv)
        tr = rng.normal(size=model.nv)
        fns = {
            "mass_matrix": lambda: ch.mass_matrix(q),
            "nonlinear_effects": lambda: ch.nonlinear_effects(q, v),
            "forward_dynamics": lambda: ch.forward_dynamics(q, v, p),
            "fwd_unchecked": lambda: ch.forward_dynamics(q, v, p, data=cdata, skip_checks=True),
            "crba+cholesky": lambda: cho_solve(
                cho_factor(ch.mass_matrix(q)), ch.internal_forces(q, v, p) - ch.nonlinear_effects(q, v)
            ),
            "pin.aba": lambda: pin.aba(model, data, qr, vr, tr),
        }
        for f in fns.values():  # warm up (and compile)
            f()
        times = {k: [] for k in fns}
        for _ in range(repeats):  # interleaved
            for k, f in fns.items():
                times[k].append(per_call_us(f, calls))
        med = {k: float(np.median(t)) for k, t in times.items()}
        a = ch.forward_dynamics(q, v, p)
        a_ref = ref.forward_dynamics(q, v, p)
        err = float(np.linalg.norm(a - a_ref) / np.linalg.norm(a_ref))
        aba = np.array(times["pin.aba"])
        spread = {}
        for k in ("forward_dynamics", "fwd_unchecked"):
            r = np.array(times[k]) / aba
            spread[k] = (float(np.percentile(r, 25)), float(np.percentile(r, 75)))
        rows.append(dict(n=n, nv=ch.nv, nodes=ch.segments[0].node_count, **{k + "_us": med[k] for k in fns},
                         ratio_fd_aba=med["forward_dynamics"] / med["pin.aba"],
                         ratio_fd_aba_q1=spread["forward_dynamics"][0], ratio_fd_aba_q3=spread["forward_dynamics"][1],
                         ratio_fu_aba=med["fwd_unchecked"] / med["pin.aba"],
                         ratio_fu_aba_q1=spread["fwd_unchecked"][0], ratio_fu_aba_q3=spread["fwd_unchecked"][1],
                         fd_rel_err=err))
    return rows


def plot(rows, path):
    """Cost scaling chart: us per forward-dynamics call vs n, qchain vs pinocchio.aba."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n"] for r in rows]
    fig, ax = plt.subplots(figsize=(7, 5))
    ax.loglog(n, [r["forward_dynamics_us"] for r in rows], "o-", label="qchain forward_dynamics (aba, 6 nodes)")
    ax.loglog(n, [r["crba+cholesky_us"] for r in rows], "s--", label="qchain crba + Cholesky")
    ax.loglog(n, [r["pin.aba_us"] for r in rows], "^-", label="pinocchio.aba, rigid chain, same nv")
    for r in rows:
        ax.annotate(f"x{r['ratio_fd_aba']:.1f}", (r["n"], r["forward_dynamics_us"]), textcoords="offset points",
                    xytext=(4, 6), fontsize=8)
    ax.margins(x=0.08)  # room for the last ratio label
    ax.set_xlabel("segments n (nv = 3 n)")
    ax.set_ylabel("median time per call (us)")
    ax.set_title("forward dynamics cost (labels: qchain / pinocchio.aba)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _study.save(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 3, 8, 10, 30])
    ap.add_argument("--nodes", type=int, nargs="+", default=[None],
                    help="Gauss nodes a segment (default: the Segment default), one table row each")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--calls", type=int, default=200)
    ap.add_argument("--csv", default=None, help="also write the table as CSV")
    ap.add_argument("--png", default=None, help="also draw the cost scaling chart")
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats, args.calls, args.nodes)
    print(f"{'n':>3} {'nv':>4} {'nod':>3} {'mass_matrix':>12} {'nle':>9} {'fwd_dyn':>9} {'fwd_unchk':>9} {'crba+chol':>10}"
          f" {'pin.aba':>9} {'fwd/aba':>8} {'(q1-q3)':>11} {'unchk/aba':>9} {'(q1-q3)':>11} {'fwd err':>9}")
    for r in rows:
        print(f"{r['n']:>3} {r['nv']:>4} {r['nodes']:>3} {r['mass_matrix_us']:>12.1f} {r['nonlinear_effects_us']:>9.1f}"
              f" {r['forward_dynamics_us']:>9.1f} {r['fwd_unchecked_us']:>9.1f} {r['crba+cholesky_us']:>10.1f}"
              f" {r['pin.aba_us']:>9.2f} {r['ratio_fd_aba']:>8.2f} {r['ratio_fd_aba_q1']:>5.2f}-{r['ratio_fd_aba_q3']:<5.2f}"
              f" {r['ratio_fu_aba']:>9.2f} {r['ratio_fu_aba_q1']:>5.2f}-{r['ratio_fu_aba_q3']:<5.2f}"
              f" {r['fd_rel_err']:>9.1e}")
    print("(median CPU us per call, interleaved; ratios of medians, quartiles of the per-set ratios; "
          "err: relative to 24 nodes)")
    by_n = {r["n"]: r for r in rows}
    if 10 in by_n and 30 in by_n:
        g = by_n[30]["forward_dynamics_us"] / by_n[10]["forward_dynamics_us"]
        print(f"forward_dynamics cost growth n=10 -> 30: x{g:.2f} (linear would be x3.00)")
    if args.png:
        plot(rows, args.png)
    if args.csv:
        _study.write_csv(rows, Path(args.csv))
    return rows


if __name__ == "__main__":
    main()
