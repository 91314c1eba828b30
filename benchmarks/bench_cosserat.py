"""Model error against cost: a soft cantilever released under gravity, qchain against PyElastica.

Scene (the same numbers in both codes, SI units): a rod of free length L = 0.3 m, radius
r = 0.01 m, density rho = 1100 kg/m^3, Young's modulus E = 5 MPa, Poisson ratio nu = 0.5,
so shear modulus G = E / (2 (1 + nu)) = E / 3 (PyElastica only: qchain has no shear),
gravity g = 9.81 m/s^2 along world -z, no damping in either code. Clamped at the world
origin, straight along world +x and at rest at t = 0, then released: it falls to about
half its length below the clamp and swings back, about two swings (first bending
frequency 2.1 Hz) in T = 1 s (``--quick``: T = 0.3 s). Derived: A = pi r^2, EI = E pi r^4 / 4
= 0.0393 N m^2, EA = E pi r^2 = 1571 N, mass 0.104 kg; every cross-section carries the
rotary inertia of a uniform disk in both codes.

qchain: n = 1, 2, 4, 8, 16, 32 equal segments (length L/n, mass rho A L/n, modulus E, damping
0, default 6 nodes), fixed base rotated so the backbone runs along world +x, ``planar=True``
(the motion stays in the x-z plane), ``extensible=True`` (EA = E pi r^2 as in the rod; an
unshearable rod, so qchain converges to the Kirchhoff rod, not to the shearable Cosserat rod).
The chambers (1 mm^2 at 5 mm) are unpressurised and play no part. Main series: DOP853 at
rtol = 1e-8, atol = 1e-10 (integration error, measured against rtol = 1e-10: 2e-12 m at n = 16);
looser runs: RK45 at rtol = 1e-3 and 1e-5, and the implicit midpoint rule at dt = 1 ms.

PyElastica: ``CosseratRod.straight_rod`` with N elements, ``shear_modulus = G`` (PyElastica's
shear stiffness is 27/28 G A), ``OneEndFixedBC`` on node 0 and element 0, ``GravityForces``,
``PositionVerlet`` at a fixed step dt, no damper. Clamp placement: ``OneEndFixedBC`` fixes the
first element's frame and bending lives on the Voronoi regions of the interior nodes, so a rod
that starts at the wall is clamped half an element too far out and converges at first order
only (measured: with N = 200 it is still 5e-3 m off). The rod therefore starts half an element
inside the wall: N elements of dl = L / (N - 1/2) from x = -dl/2, so the first free node's
Voronoi region starts at x = 0, the moving mass covers [0, L] and the tip (the last node) sits
at x = L; the error then falls about 3x per doubling of N (2.2e-5 m at N = 200).

Reference: PyElastica with N = 400 elements, dt = 6.25 us (``--quick``: N = 100, dt = 25 us),
checked by halving the elements and halving the step; without PyElastica (an optional
``bench`` extra), the finest qchain run (n = 32; ``--quick``: 16), and the output says so.
Error: the largest distance between the two tips over samples every 10 ms in [0, T] (m).
A second column measures every run against the finest qchain run instead: qchain's own
discretisation error, and for PyElastica rows its distance from the unshearable limit.
Cost: wall seconds of the integration loop per simulated second (model set-up excluded; a
warm-up run compiles the numba kernels first); median of 3 repeats for runs under 5 s
(quick: 0.5 s), one run above.

Headline: each code's cheapest cost (lower envelope of its points, log-log interpolated) at
error levels both reach, and their ratio.

Run: ``python benchmarks/bench_cosserat.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import argparse
import itertools
import csv
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study

from qchain import Chain, Segment
from qchain.sim.simulation import simulate

SCENE = dict(L=0.3, r=0.01, rho=1100.0, E=5e6, nu=0.5, g=9.81)  # m, m, kg/m^3, Pa, -, m/s^2
SAMPLE = 0.01  # s, tip sampling period
CHAMBER = dict(chamber_area=1e-6, chamber_radius=0.005)  # m^2, m: unpressurised
TIGHT = ("DOP853", dict(rtol=1e-8, atol=1e-10))


def shear_modulus(scene=SCENE) -> float:
    return scene["E"] / (2.0 * (1.0 + scene["nu"]))


def describe(scene=SCENE, T: float = 1.0) -> str:
    L, r, rho, E, g = (scene[k] for k in ("L", "r", "rho", "E", "g"))
    A = np.pi * r * r
    EI = E * np.pi * r**4 / 4
    f1 = 1.875104**2 / (2 * np.pi * L * L) * np.sqrt(EI / (rho * A))
    return (f"L = {L:g} m, r = {r:g} m, rho = {rho:g} kg/m^3, E = {E:g} Pa, nu = {scene['nu']:g} "
            f"(G = {shear_modulus(scene):.4g} Pa, PyElastica only), g = {g:g} m/s^2 along -z, no damping, "
            f"T = {T:g} s; EI = {EI:.4g} N m^2, EA = {E * A:.4g} N, mass = {rho * A * L:.4g} kg, "
            f"first bending frequency {f1:.3g} Hz")


# ---------------------------------------------------------------------------------- qchain


def qchain_arm(n: int, scene=SCENE, extensible: bool = True, planar: bool = True,
               node_tolerance: float | None = None, max_bend: float | None = None) -> Chain:
    """The cantilever as n equal segments, backbone along world +x, undamped; ``planar=False``
    is the full spatial model (3 coordinates a segment). ``node_tolerance``: each segment's
    Gauss nodes sized for this relative ``M_xi`` accuracy at the bend ``max_bend`` (rad, a
    segment's ``l |u|``; None: the largest the model allows, ``l0 / r_s``), as a scene sizes them
    (:func:`qchain.model.segment.nodes_for_tolerance`, ``model.max_bend``); None: the segment's
    default (:data:`qchain.model.segment.DEFAULT_NODES`)."""
    from qchain.model.segment import nodes_for_tolerance

    L, r, rho, E = scene["L"], scene["r"], scene["rho"], scene["E"]
    seg = dict(length=L / n, radius=r, mass=rho * np.pi * r * r * L / n, youngs_modulus=E, damping=0.0,
               extensible=extensible, **CHAMBER)
    if node_tolerance is not None:
        seg["nodes"] = nodes_for_tolerance(Segment(**seg), (L / n) / r if max_bend is None else max_bend,
                                           node_tolerance)
    X = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3))
    return Chain([Segment(**seg) for _ in range(n)], base_placement=X, gravity=(0.0, 0.0, -scene["g"]),
                 planar=planar)


def sample_times(T: float) -> np.ndarray:
    return np.linspace(0.0, T, int(round(T / SAMPLE)) + 1)


def qchain_run(n: int, T: float, method: str = "DOP853", repeat_below: float = 0.0, scene=SCENE,
               extensible: bool = True, planar: bool = True, clock=time.perf_counter,
               node_tolerance: float | None = None, max_bend: float | None = None, **kw) -> dict:
    """Release the n-segment arm; returns tips (K, 3) at ``sample_times(T)``, cost (s/s), etc.

    The run is repeated 3 times (cost: the median) if the first takes under ``repeat_below`` s
    (as measured by ``clock``: wall time by default, ``time.process_time`` for CPU time).
    ``extensible=False`` is the reduced model without the axial mode (the rod's stretch under
    its own weight is W / EA ~ 7e-4 here), so explicit steps are no longer bounded by it.
    ``planar=False`` is the full spatial model; ``node_tolerance`` and ``max_bend`` as
    :func:`qchain_arm`'s. The result's ``max_bend`` is the largest bend of a segment over the run
    (rad, ``l |u|``) and ``nodes`` the segments' node count.
    """
    ch = qchain_arm(n, scene, extensible=extensible, planar=planar, node_tolerance=node_tolerance,
                    max_bend=max_bend)
    t_eval = sample_times(T)
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    walls = []
    while True:
        t0 = clock()
        tr = simulate(ch, q0, v0, (0.0, T), method=method, t_eval=t_eval, energies=False, **kw)
        walls.append(clock() - t0)
        if len(walls) >= (3 if walls[0] < repeat_below else 1):
            break
    ok = bool(tr.success) and len(tr.t) == len(t_eval)
    tips = np.full((len(t_eval), 3), np.nan)
    for k, q in enumerate(tr.q):
        tips[k] = ch.tip_placement(q).translation
    kappa = np.hypot(tr.q[:, 1::3], tr.q[:, 2::3]) if len(tr.q) else np.zeros((1, 1))
    bend = tr.q[:, 0::3] * kappa if len(tr.q) else np.zeros((1, 1))
    return dict(tips=tips, cost=float(np.median(walls)) / T, repeats=len(walls), ok=ok,
                status="ok" if ok else f"failed: {tr.message}", work=int(tr.nfev),
                max_kappa_r=float(kappa.max() * scene["r"]), max_bend=float(bend.max()),
                nodes=int(ch.segments[0].node_count))


def qchain_warmup() -> None:
    """Compile the numba kernels and load scipy's integrators before anything is timed."""
    ch = qchain_arm(2)
    for method, kw in (TIGHT, ("RK45", dict(rtol=1e-3)), ("midpoint", dict(dt=1e-3))):
        simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 0.005), method=method, energies=False, **kw)


# ---------------------------------------------------------------------------------- PyElastica


def have_elastica() -> bool:
    try:
        import elastica  # noqa: F401
    except ImportError:
        return False
    return True


def elastica_run(N: int, dt: float, T: float, repeat_below: float = 0.0, scene=SCENE,
                 shear_factor: float = 1.0, filter_order: int | None = None) -> dict:
    """The same release in PyElastica: N elements, PositionVerlet at step dt (s); tips (K, 3).

    The rod starts half an element inside the wall (see the module docstring).
    Repeats as :func:`qchain_run`. ``shear_factor`` scales the shear modulus (a diagnostic;
    1 is the scene's material).
    A run whose tip leaves the finite world (beyond 3 L) stops early as ``unstable``.
    """
    m = int(round(SAMPLE / dt))
    if abs(m * dt - SAMPLE) > 1e-9 * SAMPLE:
        raise ValueError(f"dt = {dt:g} s must divide the sampling period {SAMPLE:g} s")
    walls = []
    while True:
        tips, wall, status = _elastica_once(N, dt, m, T, scene, shear_factor, filter_order)
        walls.append(wall)
        if status != "ok" or len(walls) >= (3 if walls[0] < repeat_below else 1):
            break
    cost = float(np.median(walls)) / T if status == "ok" else float("nan")  # a cut-short run has no cost
    return dict(tips=tips, cost=cost, repeats=len(walls), ok=status == "ok", status=status,
                work=int(round(T / dt)), max_kappa_r=float("nan"))


def _elastica_once(N, dt, m, T, scene, shear_factor, filter_order=None):
    import elastica as ea

    class Release(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping):
        pass

    L, r, rho, E, g = (scene[k] for k in ("L", "r", "rho", "E", "g"))
    dl = L / (N - 0.5)
    sim = Release()
    rod = ea.CosseratRod.straight_rod(N, np.array([-0.5 * dl, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]),
                                      np.array([0.0, 0.0, 1.0]), N * dl, r, rho, youngs_modulus=E,
                                      shear_modulus=shear_factor * shear_modulus(scene))
    sim.append(rod)
    sim.constrain(rod).using(ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,))
    sim.add_forcing_to(rod).using(ea.GravityForces, acc_gravity=np.array([0.0, 0.0, -g]))
    if filter_order is not None:
        sim.dampen(rod).using(ea.LaplaceDissipationFilter, filter_order=filter_order)
    sim.finalize()
    stepper = ea.PositionVerlet()
    K = int(round(T / SAMPLE))
    tips = np.full((K + 1, 3), np.nan)
    tips[0] = rod.position_collection[:, -1]
    status = "ok"
    t = 0.0
    t0 = time.perf_counter()
    for k in range(1, K + 1):
        for _ in range(m):
            t = stepper.step(sim, t, dt)
        tip = rod.position_collection[:, -1]
        if not (np.all(np.isfinite(tip)) and np.linalg.norm(tip) < 3.0 * L):
            status = f"unstable at t = {k * SAMPLE:.2f} s"
            break
        tips[k] = tip
    return tips, time.perf_counter() - t0, status


def elastica_warmup() -> None:
    m = int(round(SAMPLE / 1e-4))
    _elastica_once(6, 1e-4, m, SAMPLE, SCENE, 1.0)


# ---------------------------------------------------------------------------------- study


def tip_error(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance between two tip tracks (K, 3) sampled at the same times (m); nan if
    either is incomplete."""
    d = np.linalg.norm(a - b, axis=1)
    return float(d.max()) if np.all(np.isfinite(d)) else float("nan")


def settings(quick: bool) -> dict:
    if quick:
        return dict(
            T=0.3,
            ns=[1, 2, 4, 8],
            loose=[("RK45", dict(rtol=1e-3, atol=1e-5), [4, 8]), ("midpoint", dict(dt=1e-3), [2, 4, 8, 16])],
            inext=[("RK45", dict(rtol=1e-5, atol=1e-7), [2, 4])],
            pe={2e-4: [3, 6, 12], 1e-4: [6, 12, 25], 5e-5: [25, 50]},
            pe_ref=(100, 2.5e-5),
            repeat_below=0.5,
            shear_check=None,
        )
    return dict(
        T=1.0,
        ns=[1, 2, 4, 8, 16, 32],
        loose=[("RK45", dict(rtol=1e-3, atol=1e-5), [2, 4, 8, 16]), ("RK45", dict(rtol=1e-5, atol=1e-7), [2, 4, 8, 16]),
               ("midpoint", dict(dt=1e-3), [1, 2, 4, 8, 16, 32])],
        inext=[("RK45", dict(rtol=1e-5, atol=1e-7), [2, 4, 8, 16, 32]), ("midpoint", dict(dt=2e-3), [2, 4, 8, 16, 32])],
        pe={2e-4: [3, 6, 12, 25], 1e-4: [6, 12, 25, 50], 5e-5: [12, 25, 50, 100], 2.5e-5: [25, 50, 100, 200],
            1.25e-5: [100, 200]},
        pe_ref=(400, 6.25e-6),
        repeat_below=5.0,
        shear_check=(100, 6.25e-6, 16.0),  # N, dt, shear modulus factor
    )


def _label(method: str, kw: dict) -> str:
    return f"dt={kw['dt']:g}" if "dt" in kw else f"rtol={kw['rtol']:g}"


def run(quick: bool = False, out_dir: Path = Path("out/bench"), use_elastica: bool | None = None) -> list[dict]:
    """Run the study; write ``cosserat_release.csv`` and ``cosserat_release.png`` into ``out_dir``.

    ``use_elastica``: None runs the PyElastica side when it is installed, False skips it.
    """
    cfg = settings(quick)
    T = cfg["T"]
    rb = cfg["repeat_below"]
    pe = have_elastica() if use_elastica is None else bool(use_elastica)
    print(f"scene: {describe(SCENE, T)}", flush=True)
    if not pe:
        print("PyElastica is not installed (optional `bench` extra: pip install pyelastica): qchain side only, "
              "against its finest run", flush=True)
    t_start = time.perf_counter()
    results: list[dict] = []

    def add(code, series, role, n, method, setting, res):
        results.append(dict(code=code, series=series, role=role, n=n, method=method, setting=setting, T_s=T, **res))
        print(f"  {series:<36} n={n:<4} {res['cost']:10.4f} s/s  {res['status']}", flush=True)

    # ---- qchain
    qchain_warmup()
    tight_label = f"qchain {TIGHT[0]} {_label(*TIGHT)}"
    for n in cfg["ns"]:
        add("qchain", tight_label, "series", n, TIGHT[0], _label(*TIGHT), qchain_run(n, T, TIGHT[0], rb, **TIGHT[1]))
    for method, kw, ns in cfg["loose"]:
        for n in ns:
            add("qchain", f"qchain {method} {_label(method, kw)}", "series", n, method, _label(method, kw),
                qchain_run(n, T, method, rb, **kw))
    for method, kw, ns in cfg["inext"]:
        for n in ns:
            add("qchain", f"qchain inextensible {method} {_label(method, kw)}", "series", n, method,
                _label(method, kw), qchain_run(n, T, method, rb, extensible=False, **kw))
    finest_q = max((r for r in results if r["series"] == tight_label), key=lambda r: r["n"])
    if not pe:
        finest_q["role"] = "reference"

    # ---- PyElastica
    ref_note = f"qchain n = {finest_q['n']} ({TIGHT[0]} {_label(*TIGHT)}): PyElastica not run"
    ref_tips = finest_q["tips"]
    checks = {}
    if pe:
        elastica_warmup()
        Nr, dtr = cfg["pe_ref"]
        ref = elastica_run(Nr, dtr, T)
        add("pyelastica", "PyElastica reference", "reference", Nr, "PositionVerlet", f"dt={dtr:g}", ref)
        if not ref["ok"]:
            raise RuntimeError(f"PyElastica reference run failed: {ref['status']}")
        ref_tips = ref["tips"]
        for what, (N, dt) in (("half the elements", (Nr // 2, dtr)), ("half the step", (Nr, dtr / 2))):
            res = elastica_run(N, dt, T)
            add("pyelastica", f"PyElastica check: {what}", "reference-check", N, "PositionVerlet", f"dt={dt:g}", res)
            checks[what] = tip_error(res["tips"], ref_tips)
        ref_note = (f"PyElastica N = {Nr}, dt = {dtr:g} s; differences from it: half the elements "
                    f"{checks['half the elements']:.2g} m, half the step {checks['half the step']:.2g} m")
        for dt, Ns in cfg["pe"].items():
            for N in Ns:
                add("pyelastica", f"PyElastica dt={dt:g}", "series", N, "PositionVerlet", f"dt={dt:g}",
                    elastica_run(N, dt, T, rb))
        if cfg["shear_check"]:
            N, dt, f = cfg["shear_check"]
            add("pyelastica", f"PyElastica G x{f:g} (diagnostic)", "diagnostic", N, "PositionVerlet", f"dt={dt:g}",
                elastica_run(N, dt, T, shear_factor=f))

    # ---- errors
    rows = []
    qref_tips = finest_q["tips"]
    for r in results:
        tips = r.pop("tips")
        r["tip_error_m"] = tip_error(tips, ref_tips) if r["ok"] else float("nan")
        r["tip_error_vs_qchain_m"] = tip_error(tips, qref_tips) if r["ok"] else float("nan")
        r["reference"] = ref_note
        rows.append(r)
    wall_total = time.perf_counter() - t_start

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fields = ["code", "series", "role", "n", "method", "setting", "T_s", "wall_per_sim_s", "tip_error_m",
              "tip_error_vs_qchain_m", "max_kappa_r", "max_bend", "nodes", "work", "repeats", "status", "reference"]
    for r in rows:
        r["wall_per_sim_s"] = r.pop("cost")
        r.pop("ok")
    with open(out_dir / "cosserat_release.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    print_table(rows)
    print(f"reference: {ref_note}")
    kr = max(r["max_kappa_r"] for r in rows if r["code"] == "qchain" and np.isfinite(r["max_kappa_r"]))
    print(f"model domain: largest |kappa| r over all qchain runs {kr:.3f} (must stay < 1)")
    floor = next(r for r in rows if r["series"] == tight_label and r["n"] == finest_q["n"])
    if pe:
        print(f"model floor: qchain n = {floor['n']} vs the Cosserat reference {floor['tip_error_m']:.2e} m "
              "(qchain has no shear)")
        for r in rows:
            if r["role"] == "diagnostic":
                print(f"  {r['series']}, N = {r['n']}: {r['tip_error_m']:.2e} m from the reference, "
                      f"{r['tip_error_vs_qchain_m']:.2e} m from qchain n = {floor['n']} (stiffer shear moves the "
                      "rod towards qchain's unshearable limit)")
        for line in headline(rows):
            print(line)
    plot(rows, out_dir / "cosserat_release.png", T, ref_note, floor if pe else None)
    print(f"wrote {out_dir / 'cosserat_release.csv'} and {out_dir / 'cosserat_release.png'} "
          f"({wall_total:.1f} s of runs)")
    return rows


# ---------------------------------------------------------------------------------- output


def print_table(rows: list[dict]) -> None:
    print(f"{'series':<36} {'role':<15} {'n/N':>4} {'setting':>12} {'wall s/sim s':>13} {'tip err (m)':>12} "
          f"{'vs qchain (m)':>13} {'|k| r':>6} {'work':>8} {'rep':>3}  status")
    for r in rows:
        kr = f"{r['max_kappa_r']:.3f}" if np.isfinite(r["max_kappa_r"]) else "-"
        print(f"{r['series']:<36} {r['role']:<15} {r['n']:>4} {r['setting']:>12} {r['wall_per_sim_s']:>13.4f} "
              f"{r['tip_error_m']:>12.2e} {r['tip_error_vs_qchain_m']:>13.2e} {kr:>6} {r['work']:>8} "
              f"{r['repeats']:>3}  {r['status']}")
    print("(work: right-hand-side evaluations for qchain, time steps for PyElastica; tip err: max over samples "
          "every 10 ms against the reference)")


def frontier(points) -> list[tuple]:
    """Lower envelope of ``(cost, error, ...)`` points (extra items ride along): cost increasing,
    error strictly decreasing; non-finite and zero errors dropped."""
    out = []
    best = np.inf
    for p in sorted((p for p in points if np.isfinite(p[0]) and np.isfinite(p[1]) and p[1] > 0),
                    key=lambda p: (p[0], p[1])):
        if p[1] < best:
            out.append(tuple(p))
            best = p[1]
    return out


def cost_at(front, err: float) -> float:
    """Cost to reach ``err`` on a frontier, log-log interpolated; nan outside its error range."""
    if not front or err > front[0][1] or err < front[-1][1]:
        return float("nan")
    for p0, p1 in zip(front, front[1:]):
        (c0, e0), (c1, e1) = p0[:2], p1[:2]
        if e1 <= err <= e0:
            w = np.log(e0 / err) / np.log(e0 / e1)
            return float(np.exp(np.log(c0) + w * np.log(c1 / c0)))
    return float(front[0][0])  # a single-point frontier at exactly err


def headline(rows: list[dict]) -> list[str]:
    """Cost of each code at equal tip error: all qchain runs, then its tight DOP853 series alone."""
    tight = f"qchain {TIGHT[0]} {_label(*TIGHT)}"

    def front(keep):
        return frontier([(r["wall_per_sim_s"], r["tip_error_m"], f"{r['series']} n={r['n']}") for r in rows
                         if r["role"] == "series" and keep(r)])

    fp = front(lambda r: r["code"] == "pyelastica")
    lines = ["headline: qchain vs PyElastica cost at equal tip error (each code's cheapest runs, log-log "
             "interpolated; ratio = qchain / PyElastica wall time; in brackets the cheapest run of each that "
             "reaches the level)"]
    for which, keep in (("all qchain runs", lambda r: r["code"] == "qchain"),
                        (f"{tight} only", lambda r: r["series"] == tight)):
        lines.append(f" {which}:")
        lines += _compare(front(keep), fp)
    return lines


def _compare(fq, fp) -> list[str]:
    if not fq or not fp:
        return ["  no points to compare"]
    hi, lo = min(fq[0][1], fp[0][1]), max(fq[-1][1], fp[-1][1])
    if hi < lo:
        return [f"  the codes share no error level (qchain {fq[-1][1]:.2g}..{fq[0][1]:.2g} m, "
                f"PyElastica {fp[-1][1]:.2g}..{fp[0][1]:.2g} m)"]
    levels = [e for e in (1e-1, 5e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4) if lo <= e <= hi]
    if not levels:
        levels = [float(np.sqrt(hi * lo))]

    def who(front, e):  # the cheapest run on the frontier at or below error e
        return next(p[2] for p in front if p[1] <= e) if len(front[0]) > 2 else "?"

    lines = []
    for e in levels:
        cq, cp = cost_at(fq, e), cost_at(fp, e)
        lines.append(f"  tip error {e:.0e} m: qchain {cq:.3g} s/s, PyElastica {cp:.3g} s/s, ratio {cq / cp:.3g}"
                     f"   [{who(fq, e)}; {who(fp, e)}]")
    lines.append(f"  (shared error range {lo:.2g}..{hi:.2g} m; qchain reaches no lower than {fq[-1][1]:.2g} m "
                 f"against the shearable rod, PyElastica reaches {fp[-1][1]:.2g} m)")
    return lines


def plot(rows: list[dict], path: Path, T: float, ref_note: str, floor: dict | None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = list(dict.fromkeys(r["series"] for r in rows if r["role"] == "series"))
    codes = list(dict.fromkeys(r["code"] for r in rows if r["role"] == "series"))
    fig, axes = plt.subplots(1, len(codes), figsize=(6.2 * len(codes), 5.4), sharex=True, sharey=True, squeeze=False)
    axes = dict(zip(codes, axes[0]))
    qmarks, pmarks = itertools.cycle("os^D*p"), itertools.cycle("vP<>Xh")
    qcolors = itertools.cycle(["tab:blue", "tab:cyan", "tab:purple", "tab:green", "tab:olive", "tab:gray"])
    pcolors = itertools.cycle(plt.cm.autumn(np.linspace(0.0, 0.8, 6)))
    for s in series:
        pts = sorted((r["n"], r["wall_per_sim_s"], r["tip_error_m"], r["code"]) for r in rows if r["series"] == s
                     and r["role"] == "series" and np.isfinite(r["tip_error_m"]) and r["tip_error_m"] > 0)
        if not pts:
            continue
        q = s.startswith("qchain")
        n, x, y, code = zip(*pts)
        ax = axes[code[0]]
        ax.loglog(x, y, marker=next(qmarks) if q else next(pmarks), color=next(qcolors) if q else next(pcolors),
                  ls="-" if q else "--", label=s.split(" ", 1)[1])
        for nk, xk, yk, _ in pts:
            ax.annotate(f"{nk:g}", (xk, yk), textcoords="offset points", xytext=(4, 4), fontsize=7)
    for code, ax in axes.items():
        if floor is not None and np.isfinite(floor["tip_error_m"]):
            q = code == "qchain"  # qchain's own points crowd the right end of the line: write under its left end
            _study.threshold(ax, floor["tip_error_m"], f"no-shear floor (qchain n = {floor['n']:g})", axis="y",
                             at=0.01 if q else 0.99, below=q)
        ax.set_xlabel("wall time per simulated second (s)")
        q = code == "qchain"
        ax.set_title(f"{'qchain' if q else 'PyElastica'} (point labels: {'n segments' if q else 'N elements'})",
                     fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="lower left" if q else "upper right")
    next(iter(axes.values())).set_ylabel("max tip position error over [0, T] (m)")
    _study.save(fig, path)


def replot(csv_path: Path, png_path: Path) -> None:
    """Redraw the chart from a written ``cosserat_release.csv`` (no runs)."""
    import csv as _csv

    with open(csv_path) as fh:
        rows = list(_csv.DictReader(fh))
    for r in rows:
        for k in ("n", "work", "repeats"):
            r[k] = int(float(r[k]))
        for k in ("T_s", "wall_per_sim_s", "tip_error_m", "tip_error_vs_qchain_m"):
            r[k] = float(r[k]) if r[k] not in ("", "nan") else float("nan")
    tight = f"qchain {TIGHT[0]} {_label(*TIGHT)}"
    floor = max((r for r in rows if r["series"] == tight), key=lambda r: r["n"])
    pe = any(r["code"] == "pyelastica" for r in rows)
    plot(rows, png_path, rows[0]["T_s"], rows[0].get("reference", ""), floor if pe else None)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="T = 0.3 s and fewer points (under a minute)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV and PNG")
    ap.add_argument("--no-elastica", action="store_true", help="qchain side only, even if PyElastica is installed")
    args = ap.parse_args(argv)
    return run(args.quick, args.out, use_elastica=False if args.no_elastica else None)


if __name__ == "__main__":
    main()
