"""Full against reduced models: what locking coordinates saves, per call and per rollout.

Scene: the cantilever of ``bench_release.py`` (L = 0.2 m, r = 0.02 m, rho = 1000 kg/m^3,
E = 0.5 MPa, no damping), clamped along world +x, released straight under gravity, as
n = 10 segments, in three models of the same motion:

* ``full``: every coordinate free (3 n = 30), the 3-D kernel;
* ``planar``: ``uy`` locked (``Chain(planar=True)``, 20 free), the planar kernel
  (:mod:`qchain.algorithms.planar`);
* ``planar, inextensible``: ``l`` locked too (10 free), the planar kernel.

Per call: ``forward_dynamics(q, v, p, data=d, skip_checks=True)`` from Python (median of
interleaved timed sets), beside ``pinocchio.aba`` on a rigid planar chain of revolute joints
with as many coordinates as the model has free ones ("a chain of its free coordinates").
Per rollout: 1 s of the release with ``radau5`` (rtol 1e-4) and ``rk4`` (dt 0.1 ms, under
the full model's stability limit), wall per simulated second, and the largest tip distance
between the models (what the reduction changes: nothing for ``planar``, the axial stretch
for ``inextensible``).

Work-precision (``reduced_precision.csv``, ``reduced_precision.png``): each model with
``radau5`` over a ladder of tolerances, CPU time per simulated second (median of interleaved
repeats) against the largest tip error over the second, all against one reference, the full
extensible model at rtol 1e-10 (one line a model). The planar model is exact here (the
scene is symmetric), so it meets the full model's errors; the inextensible one levels off at
what locking ``l`` changes. A scene file of this rod (``benchmarks/bench_reduced.py``'s
``SCENE``) says which model a plain run builds, and why, at the default
``model.length_tolerance`` and at 2 mm.

Run: ``python benchmarks/bench_reduced.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study
from qchain import Chain, Segment
from qchain.sim.simulation import simulate

ROD = dict(L=0.2, r=0.02, rho=1000.0, E=5e5, g=9.81)
N = 10
MODELS = {"full": (False, True), "planar": (True, True), "planar, inextensible": (True, False)}
RTOLS = (1e-1, 3e-2, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
#: the rod as a scene file (the model a plain ``qchain run`` of it builds)
SCENE = f"""
name = "cantilever release"
[[segments]]
count = {N}
length = {ROD["L"] / N!r}
radius = {ROD["r"]!r}
mass = {ROD["rho"] * np.pi * ROD["r"] ** 2 * ROD["L"] / N!r}
chamber_area = 1e-6
chamber_radius = 0.005
youngs_modulus = {ROD["E"]!r}
[base]
rpy = [0, 1.5707963267948966, 0]
[simulation]
duration = 1.0
[output]
save = false
"""


def rod(planar: bool, extensible: bool, n: int = N) -> Chain:
    L, r, rho, E = ROD["L"], ROD["r"], ROD["rho"], ROD["E"]
    seg = dict(length=L / n, radius=r, mass=rho * np.pi * r * r * L / n, youngs_modulus=E, damping=0.0,
               extensible=extensible, chamber_area=1e-6, chamber_radius=0.005)
    X = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3))
    return Chain([Segment(**seg) for _ in range(n)], base_placement=X, gravity=(0.0, 0.0, -ROD["g"]), planar=planar)


def rigid_planar(nv: int) -> pin.Model:
    """``nv`` revolute joints about y, links of the rod's pieces."""
    m = pin.Model()
    h = ROD["L"] / nv
    mass = ROD["rho"] * np.pi * ROD["r"] ** 2 * h
    parent = 0
    for k in range(nv):
        parent = m.addJoint(parent, pin.JointModelRY(), pin.SE3(np.eye(3), np.array([0.0, 0.0, h if k else 0.0])),
                            f"j{k}")
        body = pin.SE3(np.eye(3), np.array([0.0, 0.0, h / 2])).act(pin.Inertia.FromCylinder(mass, ROD["r"], h))
        m.appendBodyToJoint(parent, body, pin.SE3.Identity())
    return m


def per_call_us(fns: dict, calls: int, sets: int) -> dict:
    """Median microseconds a call of each function, sets interleaved."""
    times = {k: [] for k in fns}
    for _ in range(sets):
        for k, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(calls):
                f()
            times[k].append((time.perf_counter() - t0) / calls * 1e6)
    return {k: float(np.median(v)) for k, v in times.items()}


def run(quick: bool = False, out_dir: Path = Path("out/bench")) -> list[dict]:
    models = {"full": rod(False, True), "planar": rod(True, True), "planar, inextensible": rod(True, False)}
    rng = np.random.default_rng(1)
    fns = {}
    for name, ch in models.items():
        q = ch.neutral()
        q[1::3] = rng.uniform(-3, 3, ch.n)
        v = np.zeros(ch.nv)
        v[ch.active] = rng.normal(size=ch.nv_active)
        v[2::3] = 0.0
        d = ch.create_data()
        p = np.zeros(ch.nu)
        ch.forward_dynamics(q, v, p, data=d, skip_checks=True)
        fns[name] = (lambda ch=ch, q=q, v=v, p=p, d=d: ch.forward_dynamics(q, v, p, data=d, skip_checks=True))
        model = rigid_planar(ch.nv_active)
        data = model.createData()
        qp, vp, tp = rng.normal(size=model.nq), rng.normal(size=model.nv), rng.normal(size=model.nv)
        fns[f"pin.aba nv={ch.nv_active}"] = (lambda model=model, data=data, qp=qp, vp=vp, tp=tp:
                                            pin.aba(model, data, qp, vp, tp))
    us = per_call_us(fns, 200 if quick else 1000, 7 if quick else 21)
    T = 0.3 if quick else 1.0
    t_eval = np.linspace(0.0, T, int(round(T / 0.01)) + 1)
    rows = []
    tips = {}
    print(f"{'model':>22} {'free':>5} {'fd us':>8} {'pin.aba us':>11} {'ratio':>6} {'method':>8} {'ms/sim s':>9} "
          f"{'tip vs full (m)':>15}")
    for method, kw in (("radau5", dict(rtol=1e-4, atol=1e-6)), ("rk4", dict(dt=1e-4))):
        for name, ch in models.items():
            sim = lambda: simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, T), method=method, t_eval=t_eval,  # noqa: E731
                                   energies=False, **kw)
            sim()
            walls = []
            for _ in range(1 if quick else 3):
                t0 = time.perf_counter()
                tr = sim()
                walls.append(time.perf_counter() - t0)
            tip = np.array([ch.tip_placement(q).translation for q in tr.q])
            tips[name] = tip
            dist = float(np.abs(tip - tips["full"]).max()) if tr.success and len(tip) == len(tips["full"]) else np.nan
            pin_us = us[f"pin.aba nv={ch.nv_active}"]
            row = dict(model=name, free=ch.nv_active, fd_us=us[name], pin_aba_us=pin_us, fd_over_aba=us[name] / pin_us,
                       method=method, setting=kw, wall_per_sim_s=float(np.median(walls)) / T, nfev=tr.nfev,
                       tip_vs_full_m=dist, success=tr.success)
            rows.append(row)
            print(f"{name:>22} {ch.nv_active:5d} {us[name]:8.2f} {pin_us:11.2f} {us[name] / pin_us:6.2f} {method:>8} "
                  f"{row['wall_per_sim_s'] * 1e3:9.2f} {dist:15.2e}", flush=True)
    _study.write_csv(rows, out_dir / "reduced.csv")
    return rows + work_precision(quick, out_dir)


def scene_models() -> list[str]:
    """What the rod's scene builds at the default ``model.length_tolerance`` and at 2 mm."""
    from dataclasses import replace

    from qchain.scene import parse_scene

    sc = parse_scene(SCENE)
    out = []
    for tol in (sc.length_tolerance, 2e-3):
        m = replace(sc, length_tolerance=tol).build()
        out += [f"length_tolerance {tol * 1e3:g} mm: {m.chain.nv_active} free; {r}" for r in m.reductions + m.kept
                if r.startswith(("planar", "inextensible"))]
    return out


def work_precision(quick: bool = False, out_dir: Path = Path("out/bench")) -> list[dict]:
    """CPU time per simulated second against the largest tip error over the run, each model
    with radau5 over :data:`RTOLS`, against the full model at rtol 1e-10."""
    T = 0.3 if quick else 1.0
    reps = 1 if quick else 3
    rtols = RTOLS[:4] if quick else RTOLS
    t_eval = np.linspace(0.0, T, int(round(T / 0.002)) + 1)
    models = {name: rod(*flags) for name, flags in MODELS.items()}

    def sim(ch, rtol):
        return simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, T), method="radau5", rtol=rtol, atol=rtol * 1e-2,
                        t_eval=t_eval, energies=False)

    def tips(ch, tr):
        return ch.frames_batch(tr.q, 2, t=tr.t).translation[:, -1]

    ref_ch = models["full"]
    ref = tips(ref_ch, sim(ref_ch, 1e-10))
    cpu = {(name, r): [] for name in models for r in rtols}
    err = {}
    for name, ch in models.items():  # compiled or loaded, once
        sim(ch, rtols[0])
    for _ in range(reps):
        for name, ch in models.items():
            for r in rtols:
                t0 = time.process_time()
                tr = sim(ch, r)
                cpu[name, r].append(time.process_time() - t0)
                err[name, r] = float(np.max(np.linalg.norm(tips(ch, tr) - ref, axis=1))) if tr.success else np.nan
    rows = []
    print(f"\nwork-precision: radau5, {T:g} s, tip error against the full model at rtol 1e-10; CPU medians of {reps}")
    print(f"{'model':>22} {'free':>5} {'rtol':>7} {'ms/sim s':>9} {'tip err mm':>11}")
    for name, ch in models.items():
        for r in rtols:
            c = float(np.median(cpu[name, r])) / T
            rows.append(dict(model=name, free=ch.nv_active, rtol=r, cpu_per_sim_s=c, tip_error_m=err[name, r]))
            print(f"{name:>22} {ch.nv_active:5d} {r:7.0e} {c * 1e3:9.2f} {err[name, r] * 1e3:11.4f}")
    for line in scene_models():
        print("scene: " + line)
    _study.write_csv(rows, out_dir / "reduced_precision.csv")
    plot(rows, out_dir / "reduced_precision.png")
    return rows


def plot(rows: list[dict], path: Path) -> None:
    """Cost per simulated second against tip error, one line a model (rtol labelled)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 4.6))
    for name, marker in zip(MODELS, "osD"):
        rs = [r for r in rows if r["model"] == name and np.isfinite(r["tip_error_m"])]
        x = [r["tip_error_m"] * 1e3 for r in rs]
        y = [r["cpu_per_sim_s"] * 1e3 for r in rs]
        ax.plot(x, y, marker=marker, label=f"{name} ({int(rs[0]['free'])} free)")
        for r, xi, yi in zip(rs, x, y):
            ax.annotate(f"{r['rtol']:.0e}", (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("largest tip error over the run (mm), against the full model at rtol 1e-10")
    ax.set_ylabel("CPU ms per simulated second")
    ax.set_title("Cantilever release, n = 10, radau5: full and reduced models")
    _study.threshold(ax, 1.0, "1 mm")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    _study.save(fig, path)


def replot(csv_path: Path, png_path: Path) -> None:
    plot(_study.read_csv(csv_path), png_path)


def main(argv=None):
    return _study.main(__doc__, run, argv)


if __name__ == "__main__":
    main()
