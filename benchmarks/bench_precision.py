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
Redraw the chart from a written CSV (no runs): ``python benchmarks/replot.py [DIR]``.
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


def aba_call_s(n: int, calls: int = 20000, repeats: int = 7, clock=time.perf_counter) -> float:
    """Median seconds of one ``pinocchio.aba`` call on the equal-nv rigid chain (by ``clock``:
    wall time by default, ``time.process_time`` for CPU time)."""
    model = rigid_chain(n)
    data = model.createData()
    rng = np.random.default_rng(0)
    q, v, tau = rng.normal(size=model.nq), rng.normal(size=model.nv), rng.normal(size=model.nv)
    pin.aba(model, data, q, v, tau)
    walls = []
    for _ in range(repeats):
        t0 = clock()
        for _ in range(calls):
            pin.aba(model, data, q, v, tau)
        walls.append((clock() - t0) / calls)
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
    """Work-precision chart: one row of panels a scene, compiled methods left and scipy's right.

    Parameters
    ----------
    rows : list of dict or path
        The study's rows, or the ``work_precision.csv`` they were written to.
    path : path
        The PNG to write.

    Cost is wall milliseconds per simulated second (left axis); the right axis gives the same cost in
    ``pinocchio.aba`` calls on the equal-nv rigid chain, one scale a scene (the CSV's
    ``wall_per_sim_s / aba_calls_per_sim_s`` is the scene's seconds per aba call). Dotted lines: the
    headline's error bounds; circled: the cheapest run within each bound.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not isinstance(rows, list):
        rows = _study.read_csv(Path(rows))
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    groups = (("compiled", [m for m in METHODS if _engine(rows, m) == "compiled"]),
              ("scipy", [m for m in METHODS if _engine(rows, m) != "compiled"]))
    colors = dict(zip(METHODS, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(len(scenes), 2, figsize=(12, 4.6 * len(scenes)), squeeze=False, sharex=True,
                             sharey="row")
    for row_axes, name in zip(axes, scenes):
        here = [r for r in rows if r["scene"] == name and r["success"]]
        aba_s = float(np.median([r["wall_per_sim_s"] / r["aba_calls_per_sim_s"] for r in here]))
        best = {b: cheapest_within(here, b) for b in BOUNDS}
        for ax, (group, methods) in zip(row_axes, groups):
            for method in methods:
                pts = sorted((r["tip_error_m"], 1e3 * r["wall_per_sim_s"]) for r in here if r["method"] == method)
                if pts:
                    x, y = zip(*pts)
                    ax.loglog(x, y, marker="o", ms=4, color=colors[method], label=method)
            circled = [r for r in best.values() if r is not None and r["method"] in methods]
            for r in circled:
                ax.plot(r["tip_error_m"], 1e3 * r["wall_per_sim_s"], "o", ms=13, mfc="none", mec="k", mew=1.2)
            if circled:
                ax.plot([], [], "o", ms=9, mfc="none", mec="k", label="cheapest within a bound")
            for b in BOUNDS:
                _study.threshold(ax, b, f"{b * 1e3:g} mm bound")
            ax.set_title(f"{name}: {group} methods", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8, loc="lower left")
            if group == "scipy":  # the row shares its y axis: one aba scale on the right serves both panels
                sec = ax.secondary_yaxis("right", functions=(lambda ms, k=aba_s: ms * 1e-3 / k,
                                                             lambda calls, k=aba_s: calls * k * 1e3))
                sec.set_ylabel(f"pinocchio.aba calls per simulated s ({aba_s * 1e6:.2g} us a call)")
        row_axes[0].set_ylabel("wall time per simulated second (ms)")
    for ax in axes[-1]:
        ax.set_xlabel("largest tip error against the converged run (m)")
    _study.save(fig, path)


def _engine(rows, method):
    """The ``engine`` column of a method's rows (``compiled`` or ``python``)."""
    return next((r["engine"] for r in rows if r["method"] == method), "")


def replot(csv_path, png_path):
    """Redraw ``work_precision.png`` from a written ``work_precision.csv`` (no runs)."""
    plot(_study.read_csv(Path(csv_path)), png_path)


def main(argv=None):
    return _study.main(__doc__, run, argv)


if __name__ == "__main__":
    main()
