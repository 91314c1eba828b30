"""Cost at equal accuracy: a soft cantilever released under gravity, qchain against MuJoCo 4.

Scene (SI units, the same numbers in both codes): a rod of length L = 0.2 m, radius
r = 0.02 m, density rho = 1000 kg/m^3, Young's modulus E = 5e5 Pa, clamped at the world
origin, straight along world +x and at rest at t = 0, then released under gravity
(g = 9.81 m/s^2 along -z), undamped, for T = 1 s (``--quick``: 0.5 s). Derived: A = pi r^2,
EI = E pi r^4 / 4 = 0.0628 N m^2, mass 0.251 kg, first bending frequency 3.1 Hz, static tip
deflection under the same load (linear theory) 39 mm; every cross-section is a uniform rigid
disk (rotary inertia rho I per length) in both codes.

Both codes discretise the same continuum: the shear-rigid, **inextensible** Kirchhoff rod
(planar Euler elastica dynamics with rotary inertia). Reference: qchain with n = 32 and
n = 64 inextensible segments (dopri5, rtol 1e-10, atol 1e-12), Richardson-extrapolated
(both codes converge at second order in the segment/link count: (4 x_64 - x_32) / 3 at
every sample); ``--quick``: qchain n = 32 alone. Independent check: the MuJoCo link chain
below with N = 80 and 160 links (``--quick``: 40 and 80) under RK4 at a small step, raw and
extrapolated the same way; the output gives the distances.

qchain: n equal segments (``Chain(..., planar=True)``, ``extensible=False``; ``True`` as a
variant, which converges to the extensible rod, EA = E A), damping 0, tiny unpressurised
chambers (bench_cosserat's ``CHAMBER``), every method of ``qchain.sim.simulation.METHODS`` (read at
run time): the fixed-step ones (``FIXED_STEP``) over steps dt = 5 ms / 2^j, the others over
rtol = 1e-2, 1e-3, ... (atol = rtol / 100).

MuJoCo: N rigid links of length h = L/N (each a cylinder of radius r: mass rho A h and the
rod's rotary inertia), hinges about world y at the link ends (the first at the clamp),
stiffness EI/h at the interior hinges and 2 EI/h at the clamp (its Voronoi length is h/2),
no damping, gravity, no contacts, built as MJCF text; tip = a site at the end of the last
link. Integrators Euler (semi-implicit without damping), implicitfast, RK4, and MuJoCo 4's
``discrete`` where present, over steps dt = 5 ms / 2^j (they divide the 10 ms sampling).

Error: distance between the tip and the reference tip over samples every 10 ms in [0, T];
RMS (the main figure) and max. "Converged in time": RMS distance to the same model and
method at half the step (fixed step) or at 10x tighter rtol (adaptive); a sweep goes from
coarse to fine and stops after a pair closer than 0.005 mm, or when a run takes longer than
the budget (the last run of a sweep has no such figure). Cost: wall seconds per simulated
second of the integration (model set-up excluded; qchain's kernels compiled by a warm-up
run of every method; ``energies=False`` and ``t_eval`` = the samples); median of 3 repeats
for runs under 2 s (quick: 0.3 s). Headline: each code's cheapest run within 1 mm RMS of
the reference and converged in time to 0.2 mm, and the ratio qchain / MuJoCo; the table's
ratio column divides every cost by that MuJoCo run's.

Run: ``python benchmarks/bench_release.py [--quick] [--out DIR] [--n 5 10 20] [--N 5 10 20 40 80]``
Writes ``release.csv`` and ``release.png`` into ``--out`` (default ``out/bench``).
Redraw the chart from a written CSV (no runs): ``python benchmarks/replot.py [DIR]``.
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np

import _study
import bench_cosserat as bc

SCENE = dict(L=0.2, r=0.02, rho=1000.0, E=5e5, g=9.81)  # m, m, kg/m^3, Pa, m/s^2
ACCURACY = 1e-3  # m RMS: the headline's accuracy level
CONVERGED = 2e-4  # m RMS: the headline's time-convergence level
STOP = 5e-6  # m RMS: a sweep stops after two neighbours this close
REF_TOL = dict(rtol=1e-10, atol=1e-12)  # qchain reference
REF_METHOD = "dopri5"  # compiled: the n = 64 reference in seconds, not minutes


def constants(scene=SCENE) -> dict:
    L, r, rho, E, g = (scene[k] for k in ("L", "r", "rho", "E", "g"))
    A = np.pi * r * r
    EI = E * np.pi * r**4 / 4
    return dict(A=A, EI=EI, mass=rho * A * L, q=rho * A * g,
                f1=1.875104**2 / (2 * np.pi * L * L) * np.sqrt(EI / (rho * A)),
                w_static=rho * A * g * L**4 / (8 * EI))


def describe(scene=SCENE, T: float = 1.0) -> str:
    c = constants(scene)
    return (f"L = {scene['L']:g} m, r = {scene['r']:g} m, rho = {scene['rho']:g} kg/m^3, E = {scene['E']:g} Pa, "
            f"g = {scene['g']:g} m/s^2 along -z, undamped, T = {T:g} s; EI = {c['EI']:.4g} N m^2, "
            f"mass {c['mass']:.4g} kg, first bending frequency {c['f1']:.3g} Hz, "
            f"linear static tip deflection {1e3 * c['w_static']:.3g} mm")


# ---------------------------------------------------------------------------------- error measures


def tip_rms(a: np.ndarray, b: np.ndarray) -> float:
    """RMS over the samples of the distance between two tip tracks (K, 3) (m); nan if either
    is incomplete."""
    d = np.linalg.norm(a - b, axis=1)
    return float(np.sqrt(np.mean(d * d))) if np.all(np.isfinite(d)) else float("nan")


def richardson(coarse: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Second-order extrapolation of two tracks at N and 2N: ``(4 fine - coarse) / 3``."""
    return (4.0 * fine - coarse) / 3.0


# ---------------------------------------------------------------------------------- MuJoCo


def mujoco_integrators() -> list[str]:
    import mujoco

    names = ["Euler", "implicitfast", "RK4"]
    if hasattr(mujoco.mjtIntegrator, "mjINT_DISCRETE"):
        names.append("discrete")  # MuJoCo 4: joint stiffness implicit (first order, dissipative)
    return names


def mujoco_xml(N: int, dt: float, integrator: str = "Euler", scene=SCENE, damping: float = 0.0) -> str:
    """MJCF of the rod as N hinged rigid links along +x from the world origin (see the module
    docstring). ``damping`` (N m s/rad) is ``damping * stiffness`` at every hinge (stiffness-
    proportional, for a test that steps to rest); 0 in the benchmark."""
    L, r, rho, g = scene["L"], scene["r"], scene["rho"], scene["g"]
    c = constants(scene)
    h = L / N
    m = rho * c["A"] * h
    Ixx, Iyy = m * r * r / 2.0, m * (3.0 * r * r + h * h) / 12.0  # a cylinder along its x axis
    body = f'<site name="tip" pos="{_num(h)} 0 0"/>'
    for i in reversed(range(N)):
        k = (2.0 if i == 0 else 1.0) * c["EI"] / h
        pos = "0 0 0" if i == 0 else f"{_num(h)} 0 0"
        body = (f'<body name="link{i}" pos="{pos}">'
                f'<joint name="hinge{i}" type="hinge" axis="0 1 0" pos="0 0 0" stiffness="{_num(k)}" '
                f'damping="{_num(damping * k)}" springref="0"/>'
                f'<inertial pos="{_num(h / 2)} 0 0" mass="{_num(m)}" '
                f'diaginertia="{_num(Ixx)} {_num(Iyy)} {_num(Iyy)}"/>'
                f"{body}</body>")
    return (f'<mujoco model="release{N}"><option timestep="{_num(dt)}" integrator="{integrator}" '
            f'gravity="0 0 {_num(-g)}"><flag contact="disable" autoreset="disable"/></option>'
            f"<worldbody>{body}</worldbody></mujoco>")


def _num(x) -> str:
    """A number for MJCF text, to full precision (a numpy scalar's repr would name its type)."""
    return repr(float(x))


def mujoco_model(N: int, dt: float, integrator: str = "Euler", scene=SCENE, damping: float = 0.0):
    """``(MjModel, MjData)`` of the rod at rest, straight."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(mujoco_xml(N, dt, integrator, scene, damping))
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    return model, data


def mujoco_run(N: int, integrator: str, dt: float, T: float, repeat_below: float = 0.0, scene=SCENE) -> dict:
    """Release the N-link rod; tips (K, 3) at ``bc.sample_times(T)``, cost (s/s) etc., as
    ``bc.qchain_run``. A run that goes non-finite or leaves 3 L stops as ``unstable``."""
    m = int(round(bc.SAMPLE / dt))
    if m < 1 or abs(m * dt - bc.SAMPLE) > 1e-9 * bc.SAMPLE:
        raise ValueError(f"dt = {dt:g} s must divide the sampling period {bc.SAMPLE:g} s")
    walls = []
    while True:
        tips, wall, status = _mujoco_once(N, integrator, dt, m, T, scene)
        walls.append(wall)
        if status != "ok" or len(walls) >= (3 if walls[0] < repeat_below else 1):
            break
    ok = status == "ok"
    return dict(tips=tips, cost=float(np.median(walls)) / T if ok else float("nan"), repeats=len(walls), ok=ok,
                status=status, work=int(round(T / dt)))


def _mujoco_once(N, integrator, dt, m, T, scene):
    import mujoco

    model, data = mujoco_model(N, dt, integrator, scene)
    site = model.site("tip").id
    K = int(round(T / bc.SAMPLE))
    tips = np.full((K + 1, 3), np.nan)
    tips[0] = data.site_xpos[site]
    far = 3.0 * scene["L"]
    bad = [int(getattr(mujoco.mjtWarning, w)) for w in ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")]
    status = "ok"
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: None)  # an unstable step is reported in the row, not on stderr
    try:
        t0 = time.perf_counter()
        for k in range(1, K + 1):
            mujoco.mj_step(model, data, nstep=m)
            mujoco.mj_kinematics(model, data)  # the site at the new time (mj_step leaves the old one)
            tip = data.site_xpos[site]
            if (any(data.warning[w].number for w in bad) or not np.all(np.isfinite(tip))
                    or np.linalg.norm(tip) >= far):
                status = f"unstable at t = {k * bc.SAMPLE:.2f} s"
                break
            tips[k] = tip
        wall = time.perf_counter() - t0
    finally:
        mujoco.set_mju_user_warning(previous)
    return tips, wall, status


# ---------------------------------------------------------------------------------- qchain


def qchain_methods() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(METHODS, FIXED_STEP)`` of qchain.sim.simulation as they are now."""
    import qchain.sim.simulation as qs

    return tuple(qs.METHODS), tuple(qs.FIXED_STEP)


def qchain_setting(method: str, value: float, fixed: tuple) -> dict:
    return dict(dt=value) if method in fixed else dict(rtol=value, atol=value / 100.0)


def qchain_warmup(configs) -> None:
    """A short run of every method on every ``(n, extensible)`` model: compiles what each compiles."""
    from qchain.sim.simulation import simulate

    methods, fixed = qchain_methods()
    for n, ext in configs:
        ch = bc.qchain_arm(n, SCENE, extensible=ext)
        for method in methods:
            kw = qchain_setting(method, 1e-3 if method in fixed else 1e-4, fixed)
            simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 0.004), method=method, energies=False, **kw)


# ---------------------------------------------------------------------------------- study


def settings(quick: bool) -> dict:
    steps = [5e-3 / 2**j for j in range(10)]  # 5 ms .. 9.8 us, all divide 10 ms
    if quick:
        return dict(T=0.5, ns=[10], ext_ns=[], Ns=[10, 20, 40], ref_ns=[32], check_Ns=(40, 80), check_dt=6.25e-5,
                    steps=steps[:8], rtols=[1e-1, 1e-2, 1e-3, 1e-4, 1e-5], repeat_below=0.3, budget=4.0)
    return dict(T=1.0, ns=[5, 10, 20], ext_ns=[10], Ns=[5, 10, 20, 40, 80], ref_ns=[32, 64], check_Ns=(80, 160),
                check_dt=2.5e-5, steps=steps, rtols=[10.0**-k for k in range(1, 10)], repeat_below=2.0, budget=60.0)


def _fmt_setting(kind: str, value: float) -> str:
    return f"dt={value * 1e3:g}ms" if kind == "dt" else f"rtol={value:g}"


def sweep(runner, values, kind: str, budget: float, T: float) -> list[dict]:
    """Run ``runner(value)`` from coarse to fine; each row gets ``value``, ``kind`` and, from
    the next finer run, ``time_conv_m`` (nan if either failed, or for the last). Stops after
    a pair within ``STOP``, or after a run slower than ``budget`` s of wall time."""
    rows = []
    for v in values:
        res = runner(v)
        res.update(value=v, kind=kind, setting=_fmt_setting(kind, v), time_conv_m=float("nan"))
        if rows and rows[-1]["ok"] and res["ok"]:
            rows[-1]["time_conv_m"] = tip_rms(rows[-1]["tips"], res["tips"])
        rows.append(res)
        print(f"    {res['setting']:<16} {res['cost']:9.4f} s/s  {res['status']}"
              + (f"  (previous vs this {1e3 * rows[-2]['time_conv_m']:.4f} mm)" if len(rows) > 1 and
                 np.isfinite(rows[-2]["time_conv_m"]) else ""), flush=True)
        if len(rows) > 1 and rows[-2]["time_conv_m"] < STOP:
            break
        if res["ok"] and res["cost"] * T * res["repeats"] > budget:
            break
    return rows


def run(quick: bool = False, out_dir: Path = Path("out/bench"), ns=None, Ns=None) -> list[dict]:
    """Run the study; write ``release.csv`` and ``release.png`` into ``out_dir``; return the rows."""
    cfg = settings(quick)
    if ns:
        cfg["ns"] = list(ns)
        cfg["ext_ns"] = [n for n in cfg["ext_ns"] if n in ns]
    if Ns:
        cfg["Ns"] = list(Ns)
    T, rb, budget = cfg["T"], cfg["repeat_below"], cfg["budget"]
    methods, fixed = qchain_methods()
    integrators = mujoco_integrators()
    import mujoco

    print(f"scene: {describe(SCENE, T)}", flush=True)
    print(f"qchain methods {methods} (fixed step: {fixed}); MuJoCo {mujoco.__version__}, integrators {integrators}",
          flush=True)
    t_start = time.perf_counter()
    rows: list[dict] = []

    def add(code, model, n, variant, method, role, res, value=float("nan"), kind=""):
        res.setdefault("value", value)
        res.setdefault("kind", kind)
        res.setdefault("setting", _fmt_setting(kind, value) if kind else "")
        res.setdefault("time_conv_m", float("nan"))
        rows.append(dict(code=code, model=model, n=n, variant=variant, method=method, role=role, T_s=T, **res))
        return rows[-1]

    # ---- reference: qchain, many segments
    qchain_warmup([(2, False)] + [(n, False) for n in cfg["ns"]] + [(n, True) for n in cfg["ext_ns"]])
    refs = {}
    for n in cfg["ref_ns"]:
        print(f"reference: qchain n = {n}, {REF_METHOD} rtol={REF_TOL['rtol']:g}", flush=True)
        res = bc.qchain_run(n, T, REF_METHOD, scene=SCENE, extensible=False, **REF_TOL)
        if not res["ok"]:
            raise RuntimeError(f"qchain reference run n = {n} failed: {res['status']}")
        refs[n] = add("qchain", f"n={n}", n, "inextensible", REF_METHOD, "reference", res, REF_TOL["rtol"], "rtol")
        print(f"    {res['cost']:.3f} s/s", flush=True)
    if len(refs) >= 2:
        n1, n2 = sorted(refs)[-2:]
        ref_tips = richardson(refs[n1]["tips"], refs[n2]["tips"])
        ref_note = f"qchain n = {n1} and {n2} inextensible, {REF_METHOD} rtol {REF_TOL['rtol']:g}, Richardson-extrapolated"
    else:
        n2 = max(refs)
        ref_tips = refs[n2]["tips"]
        ref_note = f"qchain n = {n2} inextensible, {REF_METHOD} rtol {REF_TOL['rtol']:g}"

    # ---- independent check: MuJoCo, many links, RK4 at a small step
    mj_ref = {}
    for N in cfg["check_Ns"]:
        print(f"check: MuJoCo N = {N}, RK4 dt = {cfg['check_dt'] * 1e3:g} ms", flush=True)
        res = mujoco_run(N, "RK4", cfg["check_dt"], T)
        if not res["ok"]:
            raise RuntimeError(f"MuJoCo check run N = {N} failed: {res['status']}")
        mj_ref[N] = add("mujoco", f"N={N}", N, "", "RK4", "check", res, cfg["check_dt"], "dt")
        print(f"    {res['cost']:.3f} s/s", flush=True)
    N1, N2 = cfg["check_Ns"]
    mj_extra = richardson(mj_ref[N1]["tips"], mj_ref[N2]["tips"])
    checks = dict(mj_fine=(tip_rms(mj_ref[N2]["tips"], ref_tips), bc.tip_error(mj_ref[N2]["tips"], ref_tips)),
                  mj_extra=(tip_rms(mj_extra, ref_tips), bc.tip_error(mj_extra, ref_tips)))
    if len(refs) >= 2:
        checks["q_fine"] = (tip_rms(refs[n2]["tips"], ref_tips), bc.tip_error(refs[n2]["tips"], ref_tips))
        checks["q_coarse"] = (tip_rms(refs[n1]["tips"], ref_tips), bc.tip_error(refs[n1]["tips"], ref_tips))

    # ---- qchain sweeps
    configs = [(n, False) for n in cfg["ns"]] + [(n, True) for n in cfg["ext_ns"]]
    for (n, ext), method in itertools.product(configs, methods):
        kind = "dt" if method in fixed else "rtol"
        values = cfg["steps"] if kind == "dt" else cfg["rtols"]
        variant = "extensible" if ext else "inextensible"
        print(f"qchain n = {n} {variant} {method}", flush=True)

        def runner(v, n=n, ext=ext, method=method):
            return bc.qchain_run(n, T, method, rb, scene=SCENE, extensible=ext, **qchain_setting(method, v, fixed))

        for res in sweep(runner, values, kind, budget, T):
            add("qchain", f"n={n}" + (" ext" if ext else ""), n, variant, method, "sweep", res)

    # ---- MuJoCo sweeps
    mujoco_run(4, "Euler", 1e-3, bc.SAMPLE)  # warm-up
    for N, integ in itertools.product(cfg["Ns"], integrators):
        print(f"MuJoCo N = {N} {integ}", flush=True)
        for res in sweep(lambda v, N=N, integ=integ: mujoco_run(N, integ, v, T, rb), cfg["steps"], "dt", budget, T):
            add("mujoco", f"N={N}", N, "", integ, "sweep", res)

    # ---- errors, headline
    for r in rows:
        tips = r.pop("tips")
        r["rms_error_m"] = tip_rms(tips, ref_tips) if r["ok"] else float("nan")
        r["max_error_m"] = bc.tip_error(tips, ref_tips) if r["ok"] else float("nan")
        r["wall_per_sim_s"] = r.pop("cost") if r["ok"] else float("nan")  # a failed run has no cost
        r.pop("max_kappa_r", None)
    best = {code: cheapest(rows, code) for code in ("qchain", "mujoco")}
    base = best["mujoco"]["wall_per_sim_s"] if best["mujoco"] else float("nan")
    for r in rows:
        r["cost_ratio"] = r["wall_per_sim_s"] / base if np.isfinite(base) else float("nan")
        r["reference"] = ref_note
    wall_total = time.perf_counter() - t_start

    print_table(rows)
    lines = [f"reference: {ref_note}"]
    if "q_fine" in checks:
        lines.append(f"  qchain n = {n2} alone: {1e3 * checks['q_fine'][0]:.4f} mm RMS "
                     f"({1e3 * checks['q_fine'][1]:.4f} max) from it, n = {n1}: "
                     f"{1e3 * checks['q_coarse'][0]:.4f} mm RMS "
                     f"({1e3 * checks['q_coarse'][1]:.4f} max)")
    lines.append(f"  independent check, MuJoCo N = {N2} links (RK4, dt = {cfg['check_dt'] * 1e3:g} ms): "
                 f"{1e3 * checks['mj_fine'][0]:.4f} mm RMS ({1e3 * checks['mj_fine'][1]:.4f} max); MuJoCo N = {N1} "
                 f"and {N2} Richardson-extrapolated: {1e3 * checks['mj_extra'][0]:.4f} mm RMS "
                 f"({1e3 * checks['mj_extra'][1]:.4f} max)")
    lines += headline(rows, best)
    for line in lines:
        print(line)
    out_dir = Path(out_dir)
    fields = ["code", "model", "n", "variant", "method", "role", "setting", "value", "kind", "T_s", "rms_error_m",
              "max_error_m", "time_conv_m", "wall_per_sim_s", "cost_ratio", "work", "repeats", "status", "reference"]
    _study.write_csv([{k: r.get(k, "") for k in fields} for r in rows], out_dir / "release.csv")
    plot(rows, out_dir / "release.png", T, ref_note, best)
    print(f"wrote {out_dir / 'release.csv'} and {out_dir / 'release.png'} ({wall_total:.1f} s of runs)")
    return rows


def eligible(r: dict, accuracy: float = ACCURACY) -> bool:
    """A sweep run within ``accuracy`` m RMS of the reference and converged in time to ``CONVERGED``."""
    return (r["role"] == "sweep" and r["ok"] and r["rms_error_m"] <= accuracy and np.isfinite(r["time_conv_m"])
            and r["time_conv_m"] <= CONVERGED)


def cheapest(rows: list[dict], code: str, keep=lambda r: True, accuracy: float = ACCURACY) -> dict | None:
    cand = [r for r in rows if r["code"] == code and eligible(r, accuracy) and keep(r)]
    return min(cand, key=lambda r: r["wall_per_sim_s"]) if cand else None


def _name(r: dict) -> str:
    return f"{r['code']} {r['model']} {r['method']} {r['setting']}"


def headline(rows: list[dict], best: dict) -> list[str]:
    q, m = best["qchain"], best["mujoco"]
    lines = [f"headline: the cheapest run within {ACCURACY * 1e3:g} mm RMS of the reference and converged in time to "
             f"{CONVERGED * 1e3:g} mm RMS"]
    for r, who in ((q, "qchain"), (m, "MuJoCo")):
        if r is None:
            lines.append(f"  {who}: no run qualifies")
        else:
            lines.append(f"  {who}: {_name(r)}: {r['wall_per_sim_s']:.4g} s per simulated second "
                         f"(error {1e3 * r['rms_error_m']:.3f} mm RMS, {1e3 * r['max_error_m']:.3f} max; "
                         f"time convergence {1e3 * r['time_conv_m']:.4f} mm)")
    if q and m:
        lines.append(f"  ratio qchain / MuJoCo: {q['wall_per_sim_s'] / m['wall_per_sim_s']:.3g}")
    lines.append("  at other accuracy levels (same rule):")
    for acc in (5e-4, 2e-4, 1e-4):
        qa, ma = cheapest(rows, "qchain", accuracy=acc), cheapest(rows, "mujoco", accuracy=acc)
        parts = [f"{who} " + (f"{r['wall_per_sim_s']:.4g} s/s [{r['model']} {r['method']} {r['setting']}]" if r else
                             "none") for r, who in ((qa, "qchain"), (ma, "MuJoCo"))]
        ratio = f", ratio {qa['wall_per_sim_s'] / ma['wall_per_sim_s']:.3g}" if qa and ma else ""
        lines.append(f"    {acc * 1e3:g} mm: " + "; ".join(parts) + ratio)
    lines.append("  per method (cheapest qualifying run):")
    for code in ("qchain", "mujoco"):
        for method in dict.fromkeys(r["method"] for r in rows if r["code"] == code and r["role"] == "sweep"):
            r = cheapest(rows, code, lambda r, method=method: r["method"] == method)
            lines.append(f"    {code} {method:<13} " + (f"{r['wall_per_sim_s']:.4g} s/s  [{r['model']} {r['setting']}, "
                                                        f"{1e3 * r['rms_error_m']:.3f} mm]" if r else "none"))
    return lines


# ---------------------------------------------------------------------------------- output


def _mm(x: float, fmt: str = ".3f") -> str:
    return format(1e3 * x, fmt) if np.isfinite(x) else "-"


def _short(status: str, width: int = 60) -> str:
    """A failed run's message cut for the table (the CSV has all of it)."""
    return status if len(status) <= width else status[: width - 3] + "..."


def print_table(rows: list[dict]) -> None:
    print(f"{'code':<7} {'model':<9} {'method':<13} {'step / tol':<16} {'RMS (mm)':>9} {'max (mm)':>9} "
          f"{'t-conv (mm)':>11} {'wall s/s':>9} {'x MuJoCo':>9} {'rep':>3}  status")
    for r in rows:
        ratio = f"{r['cost_ratio']:.3g}" if np.isfinite(r["cost_ratio"]) else "-"
        cost = f"{r['wall_per_sim_s']:.4f}" if np.isfinite(r["wall_per_sim_s"]) else "-"
        mark = " *" if eligible(r) else ""
        print(f"{r['code']:<7} {r['model']:<9} {r['method']:<13} {r['setting']:<16} {_mm(r['rms_error_m']):>9} "
              f"{_mm(r['max_error_m']):>9} {_mm(r['time_conv_m'], '.4f'):>11} {cost:>9} {ratio:>9} {r['repeats']:>3}  "
              f"{_short(r['status']) if r['role'] == 'sweep' else r['role']}{mark}")
    print(f"(errors: tip distance to the reference over samples every {bc.SAMPLE * 1e3:g} ms; t-conv: RMS distance to "
          f"the same run at half the step or 10x tighter rtol; x MuJoCo: cost over the MuJoCo headline run's; "
          f"*: within {ACCURACY * 1e3:g} mm RMS and converged in time to {CONVERGED * 1e3:g} mm)")


def frontier(runs: list[dict]) -> list[dict]:
    """The runs no other run beats in both RMS error and cost, in order of falling error.

    Parameters
    ----------
    runs : list of dict
        Rows with finite ``rms_error_m`` (m) and ``wall_per_sim_s`` (s/s).
    """
    front = []
    for r in sorted(runs, key=lambda r: (r["wall_per_sim_s"], r["rms_error_m"])):
        if not front or r["rms_error_m"] < front[-1]["rms_error_m"]:
            front.append(r)
    return front


def plot(rows: list[dict], path: Path, T: float, ref_note: str, best: dict) -> None:
    """Cost against accuracy, qchain left and MuJoCo right, one line a model size.

    Each line joins a model size's frontier: the runs (of any method and setting) that no other run
    of that size beats in both RMS error and cost; grey dots are the other runs. Filled: converged in
    time to ``CONVERGED``; hollow: not, or not measured. Circled: each code's headline run (``best``).
    ``T`` and ``ref_note`` describe the scene and reference (in the README's caption, not the chart).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweeps = [r for r in rows if r["role"] == "sweep" and r["ok"] and np.isfinite(r["rms_error_m"])
              and r["rms_error_m"] > 0 and np.isfinite(r["wall_per_sim_s"])]
    fig, axes = plt.subplots(1, 2, figsize=(12.5, 5.6), sharex=True, sharey=True)
    for ax, code, who in zip(axes, ("qchain", "mujoco"), ("qchain: n segments", "MuJoCo: N links")):
        mine = [r for r in sweeps if r["code"] == code]
        models = list(dict.fromkeys(r["model"] for r in mine))
        colors = plt.cm.viridis(np.linspace(0.0, 0.85, max(len(models), 1)))
        ax.plot([r["rms_error_m"] for r in mine], [r["wall_per_sim_s"] for r in mine], ".", color="0.75", ms=4,
                zorder=1, label="other runs")
        for model, color in zip(models, colors):
            front = frontier([r for r in mine if r["model"] == model])
            ax.plot([r["rms_error_m"] for r in front], [r["wall_per_sim_s"] for r in front], "-", color=color,
                    lw=1.5, zorder=2, label=model)
            for r in front:
                conv = np.isfinite(r["time_conv_m"]) and r["time_conv_m"] <= CONVERGED
                ax.plot(r["rms_error_m"], r["wall_per_sim_s"], "o", color=color, ms=5, mfc=color if conv else "white",
                        zorder=3)
        r = best.get(code)
        if r is not None:
            ax.plot(r["rms_error_m"], r["wall_per_sim_s"], "o", ms=15, mfc="none", mec="k", mew=1.5, zorder=4)
            ax.annotate(f"cheapest: {r['model']} {r['method']} {r['setting']}\n{r['wall_per_sim_s']:.3g} s/s",
                        (r["rms_error_m"], r["wall_per_sim_s"]), textcoords="offset points", xytext=(10, -22),
                        fontsize=8)
        _study.threshold(ax, ACCURACY, f"{ACCURACY * 1e3:g} mm RMS (headline bound)")
        ax.plot([], [], "o", color="k", mfc="white", ms=5, label=f"hollow: not converged to {CONVERGED * 1e3:g} mm")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{who}, best runs per size", fontsize=10)
        ax.set_xlabel("RMS tip error against the reference (m)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="lower left")
    axes[0].set_ylabel("wall time per simulated second (s)")
    _study.save(fig, path)


def replot(csv_path: Path, png_path: Path) -> None:
    """Redraw the chart from a written ``release.csv`` (no runs)."""
    import csv

    with open(csv_path) as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in ("n", "work", "repeats"):
            r[k] = int(float(r[k]))
        for k in ("value", "T_s", "rms_error_m", "max_error_m", "time_conv_m", "wall_per_sim_s", "cost_ratio"):
            r[k] = float(r[k]) if r[k] not in ("", "nan") else float("nan")
        r["ok"] = r["status"] == "ok"
    best = {code: cheapest(rows, code) for code in ("qchain", "mujoco")}
    plot(rows, png_path, rows[0]["T_s"], rows[0]["reference"], best)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="T = 0.5 s, n = 10 and fewer settings (under two minutes)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for release.csv and release.png")
    ap.add_argument("--n", type=int, nargs="+", help="qchain segment counts (default 5 10 20; quick: 10)")
    ap.add_argument("--N", type=int, nargs="+", dest="N_links",
                    help="MuJoCo link counts (default 5 10 20 40 80; quick: 10 20 40)")
    args = ap.parse_args(argv)
    return run(args.quick, args.out, ns=args.n, Ns=args.N_links)


if __name__ == "__main__":
    main()
