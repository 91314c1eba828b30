"""The cost of contact: qchain with and without an environment, and a contact scene against MuJoCo.

Scene (SI units): bench_release's soft rod, L = 0.2 m, r = 0.02 m, rho = 1000 kg/m^3,
E = 5e5 Pa, g = 9.81 m/s^2 along -z, clamped at ``(0, 0, z0)`` and straight along world +x at
rest at t = 0, then released under gravity; the ground is the plane z = 0. Both codes damp the
rod in proportion to its stiffness, ``D = beta K`` with beta = 0.5 ms (qchain's
``Segment(damping=beta)``, MuJoCo's hinge damping ``beta k``): 0.5 % of critical in the first
bending mode (3.1 Hz), but enough to still the links' chatter on the ground: undamped, MuJoCo's
40-link runs do not converge in time over 1 s (RK4: 0.5 to 2 mm RMS between a step and its
half, at every step down to 10 us; Euler likewise). qchain
models it as n equal inextensible segments (bench_cosserat's tiny unpressurised chambers), the
contact law ``ContactLaw(stiffness=1e6, exponent=1.5, damping=c)`` with ``c`` Hunt and
Crossley's for restitution 0.5 at 0.5 m/s, frictionless, 16 contact points a segment in part (a)
and the references of part (b), ``contact_nodes``' count (what a scene takes) in part (b)'s sweeps.

(a) **Overhead** (the same arm, n = 10, planar and spatial, dopri5 at rtol 1e-6,
atol 1e-8): the arm clamped at z0 = r (its underside at the ground) run T = 1 s
(``--quick``: 0.1 s)

* ``none``: no environment (the cantilever swings through where the ground would be);
* ``far``: ``Environment([HalfSpace([0, 0, -3]), Sphere([5, 5, 5], 0.5)])``, never touched
  (targets: at most 5 % dearer than ``none``);
* ``contact``: the ground, so the arm lies on it along its whole length (target: at most 2x);
  ``contact/8``, ``contact/4``: the same with 8 and 4 contact points a segment instead of 16;
  ``rule (K)``: with ``K = contact_nodes(...)``, the count a scene of this arm takes (5).

Cost: wall seconds per simulated second, median over ``repeats`` runs taken in turn (none,
far, contact, none, ...; spread: min and max); the runs' right-hand-side evaluations (nfev)
and the cost per evaluation (us). Then the forward-dynamics call from Python in a loop
(``data=ch.create_data()``), microseconds per call (median over repeats of ``calls`` calls,
min-max): ``chain.forward_dynamics(q, v, p, data=data)`` at the state where the contact run
ended (the arm lying on the ground), then with ``env=far`` and ``env=ground``, each checked and
with ``skip_checks=True``.

(b) **Against MuJoCo**: the rod clamped at z0 = 0.04 m (its underside 20 mm above the ground;
its linear static deflection is 39 mm) falls, its free end strikes the ground, bounces and
comes to rest propped on it, over T = 1 s (``--quick``: 0.3 s); tip sampled every 10 ms.
qchain: n = 5, 10, 20 segments, planar, inextensible, dopri5 over rtol 1e-2 .. 1e-8
(atol = rtol / 100) and rk4 over dt = 5 ms / 2^j. Reference: n = 32, dopri5 rtol 1e-10
(``--quick``: n = 16, rtol 1e-9).
MuJoCo: bench_release's N-link rod (hinges of stiffness EI/h, 2 EI/h at the clamp, the
rod's mass and rotary inertia per link) with a capsule geom of radius r on every link
(fromto its ends; links collide with the plane only: contype 1 / conaffinity 0 on links,
0 / 1 on the plane), a plane at z = 0, frictionless contacts (condim 1), and MuJoCo's default
soft contact (solref = 0.02 s, damping ratio 1; solimp = 0.9, 0.95, 0.001 m, width;
no margin; the Newton solver, 100 iterations, tolerance 1e-8); N = 5 .. 40 links, Euler, implicitfast, RK4 (and MuJoCo 4's discrete) over
dt = 5 ms / 2^j. Reference: N = 80, RK4 at dt = 10 us (``--quick``: N = 40, 25 us).
Accuracy: each code against **its own** converged run (RMS tip distance over the samples);
the headline is each code's cheapest run within 1 mm RMS of its reference and converged in
time to 0.2 mm (bench_release's rule and ``cheapest``). The two references differ by their
physics (soft Hunt-Crossley per length of tube against MuJoCo's per-capsule soft
constraint; constant-curvature segments against rigid links; no end cap beyond the last
contact point's ball against a capsule's round end), and the output gives that distance.

Run: ``python benchmarks/bench_contact.py [--quick] [--out DIR] [--part a|b|ab]``; writes
``contact_overhead.csv`` (a), ``contact_mujoco.csv`` and ``contact_mujoco.png`` (b) into ``--out``
(default ``out/bench``); ``--replot`` redraws the chart from the CSV in ``--out`` (no runs).
"""

from __future__ import annotations

import argparse
import itertools
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study
import bench_cosserat as bc
import bench_release as br
from qchain import Chain, Segment
from qchain.contact import ContactLaw, Environment, HalfSpace, Sphere, contact_nodes, hunt_crossley_damping
from qchain.sim.simulation import simulate

SCENE = br.SCENE
TOL = dict(rtol=1e-6, atol=1e-8)  # part (a): the same tolerances with and without contact
BETA = 5e-4  # s, stiffness-proportional damping D = beta K in both codes (mode 1: 0.5 %; links' chatter: ~50 %)
DROP_Z0 = 0.04  # m, part (b): the clamp's height (the rod's underside 20 mm above the ground)
RESTITUTION, IMPACT = 0.5, 0.5  # qchain's Hunt-Crossley damping: restitution at impact speed (m/s)
FEWER_NODES = (8, 4)  # part (a): contact runs with these contact points a segment besides the default 16
REF_NODES = 16  # part (b): the references' contact points a segment (the sweeps take contact_nodes' count)
TARGET_FAR, TARGET_CONTACT = 1.05, 2.0  # part (a)'s targets (cost over the no-environment run's)


# ---------------------------------------------------------------------------------- models


def law() -> ContactLaw:
    """The contact law of both parts: frictionless, Hertz exponent, damped."""
    return ContactLaw(stiffness=1e6, exponent=1.5, damping=hunt_crossley_damping(RESTITUTION, IMPACT))


def environments() -> dict:
    """``{"none": None, "far": ..., "contact": the ground}``."""
    return {"none": None,
            "far": Environment([HalfSpace([0.0, 0.0, -3.0]), Sphere([5.0, 5.0, 5.0], 0.5)], law()),
            "contact": Environment([HalfSpace()], law())}


def rod(n: int, z0: float, planar: bool = True, beta: float = BETA) -> Chain:
    """The rod as n inextensible segments from ``(0, 0, z0)`` along world +x (bench_cosserat's
    ``qchain_arm`` with the clamp raised)."""
    L, r, rho, E = SCENE["L"], SCENE["r"], SCENE["rho"], SCENE["E"]
    seg = dict(length=L / n, radius=r, mass=rho * np.pi * r * r * L / n, youngs_modulus=E, damping=beta,
               extensible=False, **bc.CHAMBER)
    X = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.array([0.0, 0.0, z0]))
    return Chain([Segment(**seg) for _ in range(n)], base_placement=X, gravity=(0.0, 0.0, -SCENE["g"]),
                 planar=planar)


def mujoco_contact_xml(N: int, dt: float, integrator: str, z0: float = DROP_Z0, beta: float = BETA) -> str:
    """bench_release's N-link rod (``mujoco_xml``) with contacts on, the clamp at height ``z0``,
    a capsule of the rod's radius on every link and the ground plane (module docstring)."""
    root = ET.fromstring(br.mujoco_xml(N, dt, integrator, SCENE, damping=beta))
    root.find("option/flag").set("contact", "enable")
    ET.SubElement(root, "compiler", inertiafromgeom="false")  # the links keep bench_release's inertia
    world = root.find("worldbody")
    ET.SubElement(world, "geom", name="ground", type="plane", size="1 1 0.01", contype="0", conaffinity="1",
                  condim="1")
    h = SCENE["L"] / N
    for body in world.iter("body"):
        ET.SubElement(body, "geom", type="capsule", fromto=f"0 0 0 {br._num(h)} 0 0", size=br._num(SCENE["r"]),
                      contype="1", conaffinity="0", condim="1")
    world.find("body").set("pos", f"0 0 {br._num(z0)}")
    return ET.tostring(root, encoding="unicode")


# ---------------------------------------------------------------------------------- part (a)


def _spread(x) -> tuple[float, float, float]:
    return float(np.median(x)), float(np.min(x)), float(np.max(x))


def overhead_runs(ch: Chain, T: float, repeats: int) -> tuple[list[dict], np.ndarray, np.ndarray]:
    """Part (a)'s runs on ``ch`` (clamped at z0 = r), in turn; rows and the contact run's end state."""
    envs = environments()
    for k in FEWER_NODES:  # the same ground with fewer contact points a segment (16 by default)
        envs[f"contact/{k}"] = Environment([HalfSpace()], law(), nodes=k)
    rule = contact_nodes(ch.segments, law(), ch.gravity)  # what a scene of this arm takes
    envs[f"rule ({rule})"] = Environment([HalfSpace()], law(), nodes=rule)
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    walls = {k: [] for k in envs}
    cpus = {k: [] for k in envs}  # CPU time: less disturbed than wall time by other jobs on the machine
    last = {}
    for k, env in envs.items():  # warm-up: compiles what each needs
        simulate(ch, q0, v0, (0.0, 0.01), method="dopri5", env=env, energies=False, **TOL)
    for _ in range(repeats):
        for k, env in envs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            tr = simulate(ch, q0, v0, (0.0, T), method="dopri5", env=env, energies=False, **TOL)
            walls[k].append(time.perf_counter() - t0)
            cpus[k].append(time.process_time() - c0)
            if not tr.success:
                raise RuntimeError(f"part (a) {k} run failed: {tr.message}")
            last[k] = tr
    # a never-touched environment must change nothing: the same steps to the same state
    if last["far"].nfev != last["none"].nfev or not np.array_equal(last["far"].q, last["none"].q):
        raise RuntimeError("part (a): the far environment changed the run (it must exert no force)")
    rows = []
    base, cpu_base = np.median(walls["none"]), np.median(cpus["none"])
    for k in envs:
        med, lo, hi = _spread(np.array(walls[k]) / T)
        tr = last[k]
        rows.append(dict(part="a", item="simulate", case=k, wall_per_sim_s=med, lo=lo, hi=hi,
                         nfev=int(tr.nfev), us_per_rhs=1e6 * med * T / tr.nfev, ratio=np.median(walls[k]) / base,
                         cpu_per_sim_s=np.median(cpus[k]) / T, cpu_ratio=np.median(cpus[k]) / cpu_base,
                         repeats=repeats))
    return rows, last["contact"].q[-1].copy(), last["contact"].v[-1].copy()


def call_costs(ch: Chain, q: np.ndarray, v: np.ndarray, calls: int, repeats: int) -> list[dict]:
    """Forward dynamics from Python (us per call) at ``(q, v)`` with each environment, checked
    and ``skip_checks``, timed in turn."""
    envs = environments()
    p = np.zeros(3 * ch.n)
    data = ch.create_data()
    cases = {}
    for k, env in envs.items():
        for skip in (False, True):
            cases[(k, skip)] = (lambda env=env, skip=skip:
                                ch.forward_dynamics(q, v, p, data=data, env=env, skip_checks=skip))
    for f in cases.values():
        f()  # compile / warm
    times = {key: [] for key in cases}
    for _ in range(repeats):
        for key, f in cases.items():
            times[key].append(bc_per_call_us(f, calls))
    rows = []
    for (k, skip), t in times.items():
        med, lo, hi = _spread(t)
        base = np.median(times[("none", skip)])  # the same call without an environment
        rows.append(dict(part="a", item="forward_dynamics" + (" skip_checks" if skip else ""), case=k,
                         us_per_call=med, lo=lo, hi=hi, ratio=med / base, repeats=repeats, calls=calls))
    base = np.median(times[("none", False)])
    # the contact pass alone, from Python
    far, ground = envs["far"], envs["contact"]
    for k, env in (("far", far), ("contact", ground)):
        f = lambda env=env: ch.environment_force(q, v, env)
        f()
        t = [bc_per_call_us(f, calls) for _ in range(repeats)]
        med, lo, hi = _spread(t)
        rows.append(dict(part="a", item="environment_force", case=k, us_per_call=med, lo=lo, hi=hi,
                         ratio=med / base, repeats=repeats, calls=calls))
    return rows


def bc_per_call_us(f, calls: int) -> float:
    """Microseconds per call of ``f()`` over ``calls`` calls (bench_chain's loop)."""
    t0 = time.perf_counter()
    for _ in range(calls):
        f()
    return (time.perf_counter() - t0) / calls * 1e6


def part_a(quick: bool) -> list[dict]:
    T, repeats = (0.1, 3) if quick else (1.0, 7)
    calls, call_repeats = (300, 3) if quick else (2000, 7)
    rows = []
    for planar in (True, False):
        ch = rod(10, SCENE["r"], planar=planar)
        arm = f"n=10 {'planar' if planar else 'spatial'}"
        print(f"(a) {arm}: dopri5 rtol {TOL['rtol']:g}, T = {T:g} s, {repeats} repeats", flush=True)
        runs, q, v = overhead_runs(ch, T, repeats)
        touching = len(ch.contacts(q, v, environments()["contact"]).segment)
        calls_rows = call_costs(ch, q, v, calls, call_repeats)
        for r in runs + calls_rows:
            r["arm"] = arm
            r["contacts"] = touching
        rows += runs + calls_rows
    return rows


def print_a(rows: list[dict]) -> None:
    print(f"\n(a) cost of an environment on the same arm (dopri5, rtol {TOL['rtol']:g}, atol {TOL['atol']:g})")
    print(f"{'arm':<15} {'case':<10} {'wall ms/s':>10} {'min-max':>15} {'x none':>7} {'cpu ms/s':>9} {'x none':>7} "
          f"{'nfev':>7} {'us/rhs':>7}")
    for r in rows:
        if r["item"] == "simulate":
            print(f"{r['arm']:<15} {r['case']:<10} {1e3 * r['wall_per_sim_s']:>10.2f} "
                  f"{1e3 * r['lo']:>7.2f}-{1e3 * r['hi']:<7.2f} {r['ratio']:>7.3f} {1e3 * r['cpu_per_sim_s']:>9.2f} "
                  f"{r['cpu_ratio']:>7.3f} {r['nfev']:>7d} "
                  f"{r['us_per_rhs']:>7.2f}")
    print(f"(targets: far <= {TARGET_FAR:g}x, contact <= {TARGET_CONTACT:g}x the no-environment run; cpu: process "
          f"time, medians; us/rhs: median wall time over nfev)")
    print(f"\n{'arm':<15} {'call (from Python)':<30} {'case':<8} {'us/call':>8} {'min-max':>15} {'x none':>7}")
    for r in rows:
        if r["item"] != "simulate":
            print(f"{r['arm']:<15} {r['item']:<30} {r['case']:<8} {r['us_per_call']:>8.2f} "
                  f"{r['lo']:>7.2f}-{r['hi']:<7.2f} {r['ratio']:>7.3f}")
    for arm in dict.fromkeys(r["arm"] for r in rows):
        c = next(r["contacts"] for r in rows if r["arm"] == arm)
        print(f"({arm}: the contact state has {c} active contact points)")
    print("(x none: over the same call without env; environment_force: over the checked call without env)")


# ---------------------------------------------------------------------------------- part (b)


def qchain_drop(n: int, T: float, method: str, repeat_below: float = 0.0, nodes: int | None = None, **kw) -> dict:
    """The falling rod in qchain; bench_cosserat's ``qchain_run`` with the ground (same fields);
    ``nodes`` contact points a segment (None: :func:`qchain.contact.contact_nodes`' count)."""
    ch = rod(n, DROP_Z0)
    env = Environment([HalfSpace()], law(), nodes=nodes or contact_nodes(ch.segments, law(), ch.gravity))
    t_eval = bc.sample_times(T)
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    walls = []
    tr = None
    while True:
        t0 = time.perf_counter()
        try:
            tr = simulate(ch, q0, v0, (0.0, T), method=method, t_eval=t_eval, energies=False, env=env, **kw)
        except (ValueError, RuntimeError) as err:  # a step the engine refuses up front
            return dict(tips=np.full((len(t_eval), 3), np.nan), cost=float("nan"), repeats=1, ok=False,
                        status=f"refused: {err}".splitlines()[0], work=0)
        walls.append(time.perf_counter() - t0)
        if not tr.success or len(walls) >= (3 if walls[0] < repeat_below else 1):
            break
    ok = bool(tr.success) and len(tr.t) == len(t_eval)
    tips = np.full((len(t_eval), 3), np.nan)
    for k, q in enumerate(tr.q):
        tips[k] = ch.tip_placement(q).translation
    return dict(tips=tips, cost=float(np.median(walls)) / T if ok else float("nan"), repeats=len(walls), ok=ok,
                status="ok" if ok else f"failed: {tr.message}", work=int(tr.nfev))


def mujoco_drop(N: int, integrator: str, dt: float, T: float, repeat_below: float = 0.0) -> dict:
    """The falling rod in MuJoCo; bench_release's ``mujoco_run`` on :func:`mujoco_contact_xml`."""
    import mujoco

    m = int(round(bc.SAMPLE / dt))
    if m < 1 or abs(m * dt - bc.SAMPLE) > 1e-9 * bc.SAMPLE:
        raise ValueError(f"dt = {dt:g} s must divide the sampling period {bc.SAMPLE:g} s")
    K = int(round(T / bc.SAMPLE))
    bad = [int(getattr(mujoco.mjtWarning, w)) for w in ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")]
    walls = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: None)  # an unstable run is reported in its row
    try:
        while True:
            model = mujoco.MjModel.from_xml_string(mujoco_contact_xml(N, dt, integrator))
            data = mujoco.MjData(model)
            mujoco.mj_kinematics(model, data)
            site = model.site("tip").id
            tips = np.full((K + 1, 3), np.nan)
            tips[0] = data.site_xpos[site]
            status = "ok"
            t0 = time.perf_counter()
            for k in range(1, K + 1):
                mujoco.mj_step(model, data, nstep=m)
                mujoco.mj_kinematics(model, data)  # the site at the new time
                tip = data.site_xpos[site]
                if any(data.warning[w].number for w in bad) or not np.all(np.isfinite(tip)) \
                        or np.linalg.norm(tip) >= 3.0 * SCENE["L"]:
                    status = f"unstable at t = {k * bc.SAMPLE:.2f} s"
                    break
                tips[k] = tip
            walls.append(time.perf_counter() - t0)
            if status != "ok" or len(walls) >= (3 if walls[0] < repeat_below else 1):
                break
    finally:
        mujoco.set_mju_user_warning(previous)
    ok = status == "ok"
    return dict(tips=tips, cost=float(np.median(walls)) / T if ok else float("nan"), repeats=len(walls), ok=ok,
                status=status, work=K * m)


def settings_b(quick: bool) -> dict:
    steps = [5e-3 / 2**j for j in range(10)]
    if quick:
        return dict(T=0.3, ns=[5, 10], ref_n=16, check_n=8, ref_tol=dict(rtol=1e-9, atol=1e-11),
                    rtols=[1e-2, 1e-3, 1e-4, 1e-5], methods=["dopri5"], Ns=[10, 20], ref_N=40, check_N=20,
                    ref_dt=2.5e-5, integrators=["Euler", "implicitfast"], steps=steps[:7], repeat_below=0.2, budget=3.0)
    return dict(T=1.0, ns=[5, 10, 20], ref_n=32, check_n=16, ref_tol=dict(rtol=1e-10, atol=1e-12),
                rtols=[10.0**-k for k in range(2, 9)], methods=["dopri5", "rk4"], Ns=[5, 10, 20, 40], ref_N=80,
                check_N=40, ref_dt=1e-5, integrators=br.mujoco_integrators(), steps=steps, repeat_below=2.0,
                budget=30.0)


def part_b(quick: bool) -> tuple[list[dict], list[str]]:
    cfg = settings_b(quick)
    T, rb, budget = cfg["T"], cfg["repeat_below"], cfg["budget"]
    rows: list[dict] = []

    def add(code, model, method, role, res, ref=None, value=float("nan"), kind=""):
        res.update(value=value, kind=kind, setting=br._fmt_setting(kind, value) if kind else "")
        res.setdefault("time_conv_m", float("nan"))
        rows.append(dict(part="b", code=code, model=model, method=method, role=role, T_s=T, **res))
        return rows[-1]

    print(f"(b) the rod dropped from z0 = {DROP_Z0 * 1e3:g} mm onto the ground, T = {T:g} s", flush=True)
    qchain_drop(2, 0.01, "dopri5", rtol=1e-3, atol=1e-5)  # compile
    qchain_drop(2, 0.01, "rk4", dt=1e-4)
    refs = {}
    for n in (cfg["check_n"], cfg["ref_n"]):
        print(f"  qchain reference n = {n}, dopri5 rtol {cfg['ref_tol']['rtol']:g}", flush=True)
        refs[n] = add("qchain", f"n={n}", "dopri5", "reference",
                      qchain_drop(n, T, "dopri5", nodes=REF_NODES, **cfg["ref_tol"]), value=cfg["ref_tol"]["rtol"],
                      kind="rtol")
    for N in (cfg["check_N"], cfg["ref_N"]):
        print(f"  MuJoCo reference N = {N}, RK4 dt {cfg['ref_dt'] * 1e3:g} ms", flush=True)
        refs[N, "mj"] = add("mujoco", f"N={N}", "RK4", "reference", mujoco_drop(N, "RK4", cfg["ref_dt"], T),
                            value=cfg["ref_dt"], kind="dt")
    for r in refs.values():
        if not r["ok"]:
            raise RuntimeError(f"reference {r['code']} {r['model']} failed: {r['status']}")
    q_ref, m_ref = refs[cfg["ref_n"]]["tips"], refs[cfg["ref_N"], "mj"]["tips"]

    for n, method in itertools.product(cfg["ns"], cfg["methods"]):
        kind = "dt" if method == "rk4" else "rtol"
        print(f"  qchain n = {n} {method}, {contact_nodes(rod(n, DROP_Z0).segments, law(), (0, 0, -SCENE['g']))} "
              "contact points a segment (contact_nodes)", flush=True)

        def runner(v, n=n, method=method):
            kw = dict(dt=v) if method == "rk4" else dict(rtol=v, atol=v / 100.0)
            return qchain_drop(n, T, method, rb, **kw)

        for res in br.sweep(runner, cfg["steps"] if kind == "dt" else cfg["rtols"], kind, budget, T):
            add("qchain", f"n={n}", method, "sweep", res, value=res["value"], kind=kind)
    mujoco_drop(4, "Euler", 1e-3, bc.SAMPLE)  # warm-up
    for N, integ in itertools.product(cfg["Ns"], cfg["integrators"]):
        print(f"  MuJoCo N = {N} {integ}", flush=True)
        for res in br.sweep(lambda v, N=N, integ=integ: mujoco_drop(N, integ, v, T, rb), cfg["steps"], "dt",
                            budget, T):
            add("mujoco", f"N={N}", integ, "sweep", res, value=res["value"], kind="dt")

    lines = [(f"references: qchain n = {cfg['check_n']} is {1e3 * br.tip_rms(refs[cfg['check_n']]['tips'], q_ref):.3f} "
             f"mm RMS from n = {cfg['ref_n']}; MuJoCo N = {cfg['check_N']} is "
             f"{1e3 * br.tip_rms(refs[cfg['check_N'], 'mj']['tips'], m_ref):.3f} mm RMS from N = {cfg['ref_N']}; "
             f"the two codes' references differ by {1e3 * br.tip_rms(q_ref, m_ref):.3f} mm RMS "
             f"({1e3 * bc.tip_error(q_ref, m_ref):.3f} max); lowest tip z: qchain {1e3 * np.nanmin(q_ref[:, 2]):.2f} "
             f"mm, MuJoCo {1e3 * np.nanmin(m_ref[:, 2]):.2f} mm")]
    for r in rows:
        tips = r.pop("tips")
        own = q_ref if r["code"] == "qchain" else m_ref
        r["rms_error_m"] = br.tip_rms(tips, own) if r["ok"] else float("nan")
        r["max_error_m"] = bc.tip_error(tips, own) if r["ok"] else float("nan")
        r["wall_per_sim_s"] = r.pop("cost") if r["ok"] else float("nan")
    best = {code: br.cheapest(rows, code) for code in ("qchain", "mujoco")}
    base = best["mujoco"]["wall_per_sim_s"] if best["mujoco"] else float("nan")
    for r in rows:
        r["cost_ratio"] = r["wall_per_sim_s"] / base
    lines += br.headline(rows, best)
    return rows, lines


def print_b(rows: list[dict], lines: list[str]) -> None:
    print("\n(b) the rod falling onto the ground: each code against its own reference")
    print(f"{'code':<7} {'model':<7} {'method':<13} {'step / tol':<16} {'RMS (mm)':>9} {'max (mm)':>9} "
          f"{'t-conv (mm)':>11} {'wall ms/s':>10} {'x MuJoCo':>9} {'work':>8}  status")
    for r in rows:
        cost = f"{1e3 * r['wall_per_sim_s']:.3f}" if np.isfinite(r["wall_per_sim_s"]) else "-"
        ratio = f"{r['cost_ratio']:.3g}" if np.isfinite(r["cost_ratio"]) else "-"
        mark = " *" if br.eligible(r) else ""
        print(f"{r['code']:<7} {r['model']:<7} {r['method']:<13} {r['setting']:<16} {br._mm(r['rms_error_m']):>9} "
              f"{br._mm(r['max_error_m']):>9} {br._mm(r['time_conv_m'], '.4f'):>11} {cost:>10} {ratio:>9} "
              f"{r['work']:>8}  {br._short(r['status']) if r['role'] == 'sweep' else r['role']}{mark}")
    print(f"(*: within {br.ACCURACY * 1e3:g} mm RMS of its own code's reference and converged in time to "
          f"{br.CONVERGED * 1e3:g} mm; work: right-hand sides (qchain) or steps (MuJoCo))")
    for line in lines:
        print(line)


def plot_b(rows: list[dict], path: Path) -> None:
    """Part (b)'s cost against accuracy, qchain left and MuJoCo right (bench_release's chart: each
    size's frontier, filled where converged in time, each code's headline run circled); the
    errors are against each code's own reference."""
    best = {code: br.cheapest(rows, code) for code in ("qchain", "mujoco")}
    br.plot(rows, path, rows[0]["T_s"], "", best)


def replot(out_dir: Path) -> None:
    """Redraw ``contact_mujoco.png`` from a written ``contact_mujoco.csv`` (no runs)."""
    rows = _study.read_csv(Path(out_dir) / "contact_mujoco.csv")
    for r in rows:
        r["ok"] = r["status"] == "ok"
    plot_b(rows, Path(out_dir) / "contact_mujoco.png")


# ---------------------------------------------------------------------------------- run


def run(quick: bool = False, out_dir: Path = Path("out/bench"), parts: str = "ab") -> list[dict]:
    """The parts named in ``parts`` ("a", "b" or "ab"); print their tables; write
    ``contact_overhead.csv`` (a) and ``contact_mujoco.csv`` (b) into ``out_dir``; return the rows."""
    mujoco = None
    if "b" in parts:
        try:
            import mujoco
        except ImportError as err:  # part (a) needs no MuJoCo
            print(f"skipping part (b), the MuJoCo comparison (the `bench` extra: pip install mujoco): {err}")
    t0 = time.perf_counter()
    print(f"scene: {br.describe(SCENE, 1.0)}, damping beta = {BETA * 1e3:g} ms"
          + (f"; MuJoCo {mujoco.__version__}" if mujoco else ""), flush=True)
    rows_a = part_a(quick) if "a" in parts else []
    rows_b, lines = part_b(quick) if mujoco else ([], [])
    for rows, name in ((rows_a, "contact_overhead.csv"), (rows_b, "contact_mujoco.csv")):
        if rows:
            fields = list(dict.fromkeys(k for r in rows for k in r))
            _study.write_csv([{k: r.get(k, "") for k in fields} for r in rows], Path(out_dir) / name)
    if rows_a:
        print_a(rows_a)
    if rows_b:
        print_b(rows_b, lines)
        plot_b(rows_b, Path(out_dir) / "contact_mujoco.png")
    print(f"wrote into {out_dir} ({time.perf_counter() - t0:.1f} s)")
    return rows_a + rows_b


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs (under a minute)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV files")
    ap.add_argument("--part", choices=["a", "b", "ab"], default="ab", help="(a) overhead, (b) against MuJoCo")
    ap.add_argument("--replot", action="store_true", help="only redraw contact_mujoco.png from its CSV in --out")
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.out)
    return run(args.quick, args.out, args.part)


if __name__ == "__main__":
    main()
