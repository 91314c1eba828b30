"""Work-precision charts: cost per simulated second against tip error, every method, two scenes.

Scenes (``examples/scenes``):

* ``wave_arm.toml``, the README's main job: three segments hanging under gravity, waved in
  a plane (the model is built planar: 6 free coordinates, the planar kernel), 4 s;
* ``spatial_arm.toml``: four segments driven in all chambers with pressures turning round
  each segment, so it swings in 3-D and no reduction applies (12 free coordinates), 2 s.

Reference: ``radau5`` at rtol = 1e-10 on the same model, checked against ``dopri5`` at
rtol = 1e-10 (their distance is printed). Error: the largest distance between the tip and
the reference tip over the scene's samples (50 Hz). Cost: wall seconds of ``simulate`` per
simulated second (energies off, the engine compiled and loaded before timing), median of
repeats, and the same cost in calls of ``pinocchio.aba`` on a rigid chain with the same nv
(RX, RY, PZ per segment), timed in the same run: "aba calls per simulated second".

Every method of ``qchain.sim.simulation.METHODS`` runs over a range of steps or tolerances:
the compiled ``radau5``, ``dopri5``, ``rk4``, ``midpoint`` and scipy's ``RK45``, ``DOP853``,
``Radau``, ``BDF`` (Python at every stage). A failed run (an explicit step above its
stability limit) is listed with its message and left out of the chart.

Headline: per scene, the cheapest setting within 1 mm and within 0.1 mm.

Run: ``python benchmarks/bench_precision.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study
from bench_chain import rigid_chain
from qchain.scene import load_scene
from qchain.sim.simulation import METHODS, simulate

SCENES = Path(__file__).resolve().parents[1] / "examples" / "scenes"
BOUNDS = (1e-3, 1e-4)  # m


def settings(method: str, quick: bool) -> list[dict]:
    """The steps or tolerances a method runs at."""
    if method == "rk4":
        return [dict(dt=dt) for dt in ([2e-4, 1e-4] if quick else [4e-4, 2e-4, 1e-4, 5e-5])]
    if method == "midpoint":
        return [dict(dt=dt) for dt in ([1e-2, 2e-3] if quick else [2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4])]
    if method in ("radau5", "dopri5"):
        rtols = [1e-1, 1e-2, 1e-4] if quick else [1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8]
    elif method in ("Radau", "BDF"):
        rtols = [1e-2] if quick else [3e-2, 1e-2, 1e-3, 1e-4, 1e-6]
    else:  # scipy's explicit pairs
        rtols = [1e-3] if quick else [1e-2, 1e-4, 1e-6, 1e-8]
    return [dict(rtol=r, atol=r * 1e-2) for r in rtols]


def label(kw: dict) -> str:
    return f"dt={kw['dt']:g}" if "dt" in kw else f"rtol={kw['rtol']:g}"


def aba_call_s(n: int, calls: int = 20000, repeats: int = 7) -> float:
    """Median seconds of one ``pinocchio.aba`` call on the equal-nv rigid chain."""
    model = rigid_chain(n)
    data = model.createData()
    rng = np.random.default_rng(0)
    q, v, tau = rng.normal(size=model.nq), rng.normal(size=model.nv), rng.normal(size=model.nv)
    pin.aba(model, data, q, v, tau)
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            pin.aba(model, data, q, v, tau)
        walls.append((time.perf_counter() - t0) / calls)
    return float(np.median(walls))


def run_scene(name: str, quick: bool) -> list[dict]:
    sc = load_scene(SCENES / f"{name}.toml")
    model = sc.build()
    ch = model.chain
    T = min(sc.duration, 1.0) if quick else sc.duration
    t_eval = sc.sample_times(T)

    def sim(method, **kw):
        return simulate(ch, model.q0, model.v0, (0.0, T), pressure=model.pressure, method=method, t_eval=t_eval,
                        energies=False, **kw)

    def tips(tr):
        return np.array([ch.tip_placement(q).translation for q in tr.q])

    ref = sim("radau5", rtol=1e-10, atol=1e-12)
    check = sim("dopri5", rtol=1e-10, atol=1e-12)
    x_ref = tips(ref)
    print(f"== {name}: {ch.n} segments, {ch.nv_active} free coordinates, {T:g} s; reference radau5 rtol 1e-10, "
          f"dopri5 rtol 1e-10 within {np.abs(tips(check) - x_ref).max():.1e} m of it", flush=True)
    aba = aba_call_s(ch.n)
    print(f"pinocchio.aba, rigid chain nv = {3 * ch.n}: {aba * 1e6:.2f} us a call")
    rows = []
    for method in METHODS:
        for kw in settings(method, quick):
            sim(method, **kw)  # compiles or loads the engine, warms the caches
            walls, tr = [], None
            while len(walls) < 7 and sum(walls) < (0.3 if quick else 1.0):
                t0 = time.perf_counter()
                tr = sim(method, **kw)
                walls.append(time.perf_counter() - t0)
            ok = tr.success and len(tr.t) == len(t_eval)
            err = float(np.max(np.linalg.norm(tips(tr) - x_ref, axis=1))) if ok else float("nan")
            cost = float(np.median(walls)) / T
            rows.append(dict(scene=name, method=method, setting=label(kw), engine=tr.meta.get("engine", ""),
                             tip_error_m=err, wall_per_sim_s=cost, aba_calls_per_sim_s=cost / aba,
                             realtime_factor=1.0 / cost, nfev=tr.nfev, nsteps=tr.meta.get("nsteps", 0),
                             njev=tr.meta.get("njev", 0), repeats=len(walls), success=ok,
                             message="" if ok else tr.message))
            print(f"{method:>9} {label(kw):>12}  err {err:9.2e} m  {cost * 1e3:9.3f} ms/s  "
                  f"{cost / aba:9.0f} aba/s  x{1 / cost:8.1f} real time  nfev {tr.nfev:6d}"
                  f"{'' if ok else '  FAILED: ' + tr.message[:70]}", flush=True)
    for bound in BOUNDS:
        best = cheapest_within(rows, bound)
        if best:
            print(f"{name}: cheapest within {bound * 1e3:g} mm: {best['method']} {best['setting']}: "
                  f"{best['wall_per_sim_s'] * 1e3:.3f} ms per simulated s (x{best['realtime_factor']:.0f} real time, "
                  f"{best['aba_calls_per_sim_s']:.0f} pinocchio.aba calls), error {best['tip_error_m']:.2e} m")
    return rows


def cheapest_within(rows, bound):
    ok = [r for r in rows if r["success"] and r["tip_error_m"] <= bound]
    return min(ok, key=lambda r: r["wall_per_sim_s"]) if ok else None


def run(quick: bool = False, out_dir: Path = Path("out/bench")) -> list[dict]:
    rows = run_scene("wave_arm", quick) + run_scene("spatial_arm", quick)
    _study.write_csv(rows, out_dir / "work_precision.csv")
    plot(rows, out_dir / "work_precision.png")
    return rows


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(7 * len(scenes), 5.5), squeeze=False)
    for ax, name in zip(axes[0], scenes):
        for k, method in enumerate(METHODS):
            pts = sorted((r["tip_error_m"], r["aba_calls_per_sim_s"]) for r in rows
                         if r["scene"] == name and r["method"] == method and r["success"])
            if pts:
                x, y = zip(*pts)
                ax.loglog(x, y, marker="o", label=method, ls="-" if k < 4 else "--")
        for b in BOUNDS:
            ax.axvline(b, color="gray", lw=0.8)
        ax.set_xlabel("largest tip error against the converged run (m)")
        ax.set_ylabel("cost per simulated second (pinocchio.aba calls, equal nv)")
        ax.set_title(f"{name}: compiled (solid) and scipy (dashed) methods")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    _study.save(fig, path)


def main(argv=None):
    return _study.main(__doc__, run, argv)


if __name__ == "__main__":
    main()
