"""Cost of ``planar_aba`` against ``recursive.aba`` on ``planar=True`` chains, and ``pinocchio.aba``.

For n segments (fixed base, curvature coordinates) at the default node count and at 3 nodes,
extensible and not, this prints the median microseconds per call of the compiled kernels
``qchain.algorithms.recursive.aba`` and ``qchain.algorithms.planar.planar_aba`` called directly from Python with
the same arguments (their ratio), of ``pinocchio.aba`` on a rigid planar chain with the same
number of free coordinates (an RY joint per segment, and a PZ joint if extensible, carrying a
cylinder of the segment's mass, radius and length), and the same two kernels called in a
compiled loop (``loop`` columns: what a compiled simulation engine pays, without Python's
per-call dispatch of about a microsecond). The timed sets are interleaved: every repeat times
each function once in turn, a set being as many calls as last about ``--set-ms``. The last
column is ``planar_aba``'s relative difference from ``aba``.

Run: ``python benchmarks/bench_planar.py [--n 1 3 10 30] [--repeats 41] [--set-ms 1] [--csv out.csv]``
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # no spinning BLAS threads
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

import _study  # noqa: E402
from qchain import Chain, Segment
from qchain.algorithms import recursive  # noqa: E402
from qchain.algorithms.planar import planar_aba, planar_workspace  # noqa: E402

SEGMENT = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
               youngs_modulus=1e5, damping=0.01)


def planar_chain(n: int, nodes, extensible: bool) -> Chain:
    return Chain([Segment(**SEGMENT, nodes=nodes, extensible=extensible) for _ in range(n)], planar=True)


def rigid_planar_chain(n: int, extensible: bool) -> pin.Model:
    """RY (and PZ if ``extensible``) per segment; a cylinder body per segment on its last joint."""
    m = pin.Model()
    parent = 0
    L = SEGMENT["length"]
    for j in range(n):
        joints = (pin.JointModelRY(), pin.JointModelPZ()) if extensible else (pin.JointModelRY(),)
        for k, joint in enumerate(joints):
            offset = pin.SE3(np.eye(3), np.array([0.0, 0.0, L if (k == 0 and j > 0) else 0.0]))
            parent = m.addJoint(parent, joint, offset, f"s{j}_{k}")
        body = pin.Inertia.FromCylinder(SEGMENT["mass"], SEGMENT["radius"], L)
        m.appendBodyToJoint(parent, pin.SE3(np.eye(3), np.array([0.0, 0.0, L / 2])).act(body), pin.SE3.Identity())
    return m


def planar_state(ch: Chain, rng):
    q = ch.neutral()
    v = np.zeros(ch.nv)
    for j, s in enumerate(ch.segments):
        q[ch.q_slice(j)] = [s.length * (1.02 if s.extensible else 1.0), rng.uniform(-8, 8), 0.0]
        v[ch.v_slice(j)] = [0.05 * rng.normal() if s.extensible else 0.0, rng.normal(), 0.0]
    p = rng.uniform(0, 5e4, ch.nu)
    return q, v, p


@numba.njit
def _aba_loop(K, arr, q, qd, tau, V0, A0, F0, qdd, A0_out, ws, sc):
    ok = True
    for _ in range(K):
        ok &= recursive.aba(arr, q, qd, tau, V0, A0, False, F0, qdd, A0_out, ws, sc)
    return ok


@numba.njit
def _planar_loop(K, arr, q, qd, tau, A0, qdd, ws, sc):
    ok = True
    for _ in range(K):
        ok &= planar_aba(arr, q, qd, tau, A0, qdd, ws, sc)
    return ok


def per_call_us(f, calls: int) -> float:
    t0 = time.perf_counter()
    for _ in range(calls):
        f()
    return (time.perf_counter() - t0) / calls * 1e6


def run(ns, repeats: int, set_ms: float):
    rng = np.random.default_rng(0)
    rows = []
    for extensible in (True, False):
        for n in ns:
            for nodes in (None, 3):
                ch = planar_chain(n, nodes, extensible)
                q, v, p = planar_state(ch, rng)
                q_c = np.ascontiguousarray(q.reshape(n, 3))
                v_c = np.ascontiguousarray(v.reshape(n, 3))
                f = ch.internal_forces(q, v, p).reshape(n, 3).copy()
                A0 = np.zeros(6)
                A0[:3] = -ch._g_B
                V0 = np.zeros(6)
                F0 = np.zeros(6)
                A0_out = np.zeros(6)
                ws = recursive.aba_workspace(n, 3 * n)
                pw = planar_workspace(n)
                qdd_a = np.zeros((n, 3))
                qdd_p = np.zeros((n, 3))
                common = (ch.kernel_arrays(), q_c, v_c, f)
                a_args = (*common, V0, A0, False, F0, qdd_a, A0_out, ws, ws[8])
                p_args = (*common, A0, qdd_p, pw, pw[-1])
                la_args = (*common, V0, A0, F0, qdd_a, A0_out, ws, ws[8])
                model = rigid_planar_chain(n, extensible)
                data = model.createData()
                qr = rng.uniform(-1, 1, model.nq)
                vr = rng.normal(size=model.nv)
                tr = rng.normal(size=model.nv)
                loops = {"aba_loop": lambda K: _aba_loop(K, *la_args),
                         "planar_loop": lambda K: _planar_loop(K, *p_args)}
                fns = {
                    "aba": lambda: recursive.aba(*a_args),
                    "planar_aba": lambda: planar_aba(*p_args),
                    "pin.aba": lambda: pin.aba(model, data, qr, vr, tr),
                }
                for fn in fns.values():  # warm up (and compile)
                    fn()
                for lp in loops.values():
                    lp(1)
                assert recursive.aba(*a_args) and planar_aba(*p_args)
                err = float(np.linalg.norm(qdd_p - qdd_a) / np.linalg.norm(qdd_a))
                # every timed set lasts about `set_ms`, well inside a scheduler slice, so a set that
                # another process interrupts is an outlier the median ignores
                calls = {}
                for k, fn in fns.items():
                    calls[k] = max(3, int(set_ms * 1e3 / min(per_call_us(fn, 5) for _ in range(3))))
                for k, lp in loops.items():
                    calls[k] = max(3, int(set_ms * 1e3 / min(per_call_us(lambda: lp(10), 1) / 10 for _ in range(3))))
                times = {k: [] for k in (*fns, *loops)}
                for _ in range(repeats):  # interleaved
                    for k, fn in fns.items():
                        times[k].append(per_call_us(fn, calls[k]))
                    for k, lp in loops.items():
                        K = calls[k]
                        times[k].append(per_call_us(lambda: lp(K), 1) / K)
                med = {k: float(np.median(t)) for k, t in times.items()}
                rows.append(dict(extensible=extensible, n=n, nodes=ch.segments[0].node_count,
                                 free_dofs=ch.nv_active, aba_us=med["aba"], planar_aba_us=med["planar_aba"],
                                 ratio=med["aba"] / med["planar_aba"], pin_aba_us=med["pin.aba"],
                                 aba_loop_us=med["aba_loop"], planar_loop_us=med["planar_loop"],
                                 ratio_loop=med["aba_loop"] / med["planar_loop"], rel_err=err))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 3, 10, 30])
    ap.add_argument("--repeats", type=int, default=41)
    ap.add_argument("--set-ms", type=float, default=1.0, help="duration of one timed set (ms)")
    ap.add_argument("--csv", default=None, help="also write the table as CSV")
    args = ap.parse_args(argv)
    rows = run(args.n, args.repeats, args.set_ms)
    print(f"{'ext':>5} {'n':>3} {'nodes':>5} {'dofs':>4} {'aba us':>8} {'planar us':>9} {'ratio':>6} {'pin.aba us':>10}"
          f" {'aba loop':>9} {'planar loop':>11} {'ratio':>6} {'rel err':>8}   (median us per call)")
    for r in rows:
        print(f"{str(r['extensible']):>5} {r['n']:>3} {r['nodes']:>5} {r['free_dofs']:>4} {r['aba_us']:>8.2f}"
              f" {r['planar_aba_us']:>9.2f} {r['ratio']:>6.2f} {r['pin_aba_us']:>10.2f} {r['aba_loop_us']:>9.2f}"
              f" {r['planar_loop_us']:>11.2f} {r['ratio_loop']:>6.2f} {r['rel_err']:>8.1e}")
    if args.csv:
        _study.write_csv(rows, Path(args.csv))
    return rows


if __name__ == "__main__":
    main()
