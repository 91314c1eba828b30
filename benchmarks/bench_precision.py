"""Work-precision chart: wall time per simulated second against tip error, per method and fidelity.

Scene: the three-segment arm hanging under gravity and waving with phase-shifted
sinusoidal chamber pressures (segments: l0 = 0.1 m, r = 15 mm, m = 50 g, E = 100 kPa,
beta = 0.01 s; chambers A = 45 mm^2 at 8.5 mm; p_i = 20 kPa (1 + sin(2 pi t + phase))).
Reference: DOP853 at rtol = 1e-12 with 12 nodes per segment. Error: the largest distance
between the tip and the reference tip over samples every 10 ms. Cost: wall seconds per
simulated second, median of repeats (the inverse is the real-time factor).

Curves: each integration method over its step sizes or tolerances (6 nodes, the default);
model fidelity (nodes per segment, at a tight tolerance); the reduced model without the
axial mode (``extensible = false``), whose error includes the modelling difference.

Run: ``python benchmarks/bench_precision.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import _study
from qchain import Chain, Segment
from qchain.inputs import Sine
from qchain.simulate import simulate

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.01)
GRAVITY = (0.0, 0.0, 9.81)  # the arm hangs along +z of its base


def arm(nodes=None, extensible=True) -> Chain:
    return Chain([Segment(**SEG, nodes=nodes, extensible=extensible) for _ in range(3)], gravity=GRAVITY)


def pressure(ch: Chain) -> Sine:
    return Sine(amplitude=np.full(ch.nu, 2e4), frequency=1.0, phase=np.tile([0.0, 2.09, 4.19], ch.n) +
                np.repeat([0.0, 0.5, 1.0], 3), offset=np.full(ch.nu, 2e4))


def tips(ch: Chain, q: np.ndarray) -> np.ndarray:
    return np.array([ch.tip_placement(qk).translation for qk in q])


def measure(ch, T, t_eval, method, repeats, **kw):
    walls = []
    tr = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, T), pressure=pressure(ch), method=method,
                      t_eval=t_eval, energies=False, **kw)
        walls.append(time.perf_counter() - t0)
    return tr, float(np.median(walls)) / T


def series(quick: bool):
    s = {
        "rk4": [("rk4", dict(dt=dt)) for dt in ([2e-3, 1e-3, 5e-4] if quick else [4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4])],
        "midpoint": [("midpoint", dict(dt=dt)) for dt in ([8e-3, 4e-3, 1e-3] if quick else
                                                           [1.6e-2, 8e-3, 4e-3, 2e-3, 1e-3, 5e-4])],
        "RK45": [("RK45", dict(rtol=r, atol=r * 1e-2)) for r in ([1e-2, 1e-4, 1e-7] if quick else
                                                                 [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9])],
        "DOP853": [("DOP853", dict(rtol=r, atol=r * 1e-2)) for r in ([1e-4, 1e-7, 1e-10] if quick else
                                                                     [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10])],
        "Radau": [("Radau", dict(rtol=r, atol=r * 1e-2)) for r in ([1e-2, 1e-4] if quick else
                                                                   [3e-2, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7])],
        "BDF": [("BDF", dict(rtol=r, atol=r * 1e-2)) for r in ([1e-2, 1e-4] if quick else
                                                               [3e-2, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7])],
    }
    return s


def run(quick: bool = False, out_dir: Path = Path("out/bench")) -> list[dict]:
    T = 0.5 if quick else 2.0
    repeats = 1 if quick else 3
    t_eval = np.arange(0.0, T + 1e-9, 0.01)
    ref_ch = arm(nodes=12)
    ref, _ = measure(ref_ch, T, t_eval, "DOP853", 1, rtol=1e-12, atol=1e-14)
    if not ref.success:
        raise RuntimeError(f"reference run failed: {ref.message}")
    x_ref = tips(ref_ch, ref.q)
    rows = []

    def add(curve, label, ch, method, kw):
        tr, cost = measure(ch, T, t_eval, method, repeats, **kw)
        ok = tr.success and len(tr.t) == len(t_eval)
        err = float(np.max(np.linalg.norm(tips(ch, tr.q) - x_ref, axis=1))) if ok else float("nan")
        rows.append(dict(curve=curve, setting=label, method=method, wall_per_sim_s=cost,
                         realtime_factor=1.0 / cost, tip_error_m=err, nfev=tr.nfev, success=ok,
                         message="" if ok else tr.message))
        print(f"{curve:>18} {label:>14}  {cost:9.4f} s/s  x{1 / cost:7.2f} real time  err {err:9.2e} m"
              f"  nfev {tr.nfev:7d}{'' if ok else '  FAILED: ' + tr.message[:60]}", flush=True)

    ch6 = arm()
    for curve, runs in series(quick).items():
        for method, kw in runs:
            label = f"dt={kw['dt']:g}" if "dt" in kw else f"rtol={kw['rtol']:g}"
            add(curve, label, ch6, method, kw)
    for n in ([2, 4] if quick else [2, 3, 4, 6, 8]):
        add("nodes (DOP853)", f"nodes={n}", arm(nodes=n), "DOP853", dict(rtol=1e-10, atol=1e-12))
    red = arm(extensible=False)
    for r in ([1e-4] if quick else [1e-3, 1e-4, 1e-5, 1e-6, 1e-8]):
        add("inextensible", f"rtol={r:g}", red, "RK45", dict(rtol=r, atol=r * 1e-2))
    _study.write_csv(rows, out_dir / "work_precision.csv")
    plot(rows, out_dir / "work_precision.png", T)
    for bound in (1e-3, 1e-4):
        best = fastest_within(rows, bound)
        if best:
            print(f"fastest within {bound * 1e3:g} mm: {best['curve']} {best['setting']}: "
                  f"{best['wall_per_sim_s']:.4f} s per simulated s (x{best['realtime_factor']:.2f} real time), "
                  f"error {best['tip_error_m']:.2e} m")
    return rows


def fastest_within(rows, bound):
    ok = [r for r in rows if r["success"] and r["tip_error_m"] <= bound and r["curve"] != "nodes (DOP853)"]
    return min(ok, key=lambda r: r["wall_per_sim_s"]) if ok else None


def plot(rows, path, T):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6))
    for curve in dict.fromkeys(r["curve"] for r in rows):
        pts = [(r["wall_per_sim_s"], r["tip_error_m"]) for r in rows if r["curve"] == curve and r["success"]]
        if pts:
            x, y = zip(*pts)
            ax.loglog(x, y, marker="o", label=curve, ls="--" if curve in ("nodes (DOP853)", "inextensible") else "-")
    for b, c in ((1e-3, "gray"), (1e-4, "lightgray")):
        ax.axhline(b, color=c, lw=0.8)
    ax.set_xlabel("wall time per simulated second (s/s)")
    ax.set_ylabel("max tip error vs converged reference (m)")
    ax.set_title(f"work-precision: 3-segment arm waving under gravity, {T:g} s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _study.save(fig, path)


def main(argv=None):
    return _study.main(__doc__, run, argv)


if __name__ == "__main__":
    main()
