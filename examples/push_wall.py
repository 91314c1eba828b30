"""A two-segment arm hanging from its base pushes a wall with its tip, harder as the pressure rises;
the same arm lying on the floor is pulled along it by a tip load.

The arm hangs under gravity (its base frame turned upside down), a wall (a ``HalfSpace``,
normal +x) 50 mm to its -x side. Chamber 1 of both segments is raised in steps (a ramp of
0.2 s, then a hold of 0.5 s at each of 30, 60, 90, 120, 150 kPa): the arm bends towards
-x, its tip reaches the wall and pushes it. The wall is frictionless, so that the settled
force can be compared with statics: :func:`qchain.equilibrium` with ``env=`` solves the
static balance with the contact (at rest the regularised friction would be zero there, so a
rubbing wall's stiction could not be compared). Three figures of the wall's normal force:

* the dynamic run (``qchain.simulate``, method ``radau5``), against the pressure of each instant;
* the static force at many pressures (``equilibrium(chain, p, env=env)``);
* the pressure at which the free arm (no wall; ``equilibrium(chain, p)``) first reaches the
  wall: no force below it.

Method: ``radau5``, the compiled implicit Runge-Kutta method with the exact Jacobian (the
contact's derivatives included): the contact is stiff, which limits an explicit method's
steps for as long as the tip touches the wall; an implicit one's steps follow the arm's
motion. Measured on this run (3.5 s): ``dopri5`` took 5 times the right-hand sides and 3.7
times the wall time of ``radau5``, for the same final shape (docs/contact_examples.md).

Then a second experiment: the same arm, free (a floating base), lying on the floor and
pulled along its axis at the tip by a constant ``PointLoad`` of half and of 1.5 times the
static friction limit (friction mu_static 0.5, mu_dynamic 0.4), checked against Coulomb's
law: the first holds, the second slides with its momentum growing at ``F - mu_dynamic W``.

Writes ``push_wall.png``: the arm's shape at each pressure with the contact forces (arrows),
and the wall's normal force against pressure; ``push_floor.png``: the sliding arm with its
contact forces, and both runs' momentum against Coulomb's law. Prints the largest contact
force, the deepest penetration, the settled force at each pressure beside the static one,
the momentum rates beside Coulomb's, and the wall-clock time per simulated second.

Run: ``.venv/bin/python examples/push_wall.py [--duration S] [--out DIR] [--quick]``
"""

from __future__ import annotations

import time

import _common
import matplotlib.pyplot as plt
import numpy as np
import pinocchio as pin

import qchain
from qchain import Chain, Segment, Table, equilibrium
from qchain.contact import (
    ContactLaw,
    Environment,
    HalfSpace,
    PointLoad,
    hunt_crossley_damping,
)

#: one segment (SI units): tests/support.py's SEGMENT, more damped (beta = 0.05 s) so that
#: each pressure step settles within its hold
SEGMENT = {"length": 0.1, "radius": 0.015, "mass": 0.05, "chamber_area": 4.5e-5,
           "chamber_radius": 0.0085, "youngs_modulus": 1e5, "damping": 0.05}
WALL_X = -0.05  # m: the wall's plane x = WALL_X, the solid on its -x side
LEVELS = (3e4, 6e4, 9e4, 1.2e5, 1.5e5)  # Pa in chamber 1 of both segments
RISE, HOLD = 0.2, 0.5  # s: each step's ramp and hold


def build(nodes: int = 16):
    """``(chain, env)``: the hanging arm (base frame turned half a turn about x: the arm grows
    along world -z, chamber 1 faces world +x) and the frictionless wall."""
    chain = Chain([Segment(**SEGMENT) for _ in range(2)], base_placement=pin.SE3(pin.utils.rotate("x", np.pi),
                                                                                   np.zeros(3)))
    law = ContactLaw(stiffness=1e6, exponent=1.5, damping=hunt_crossley_damping(0.5, 0.1))
    return chain, Environment([HalfSpace([WALL_X, 0.0, -0.1], [1.0, 0.0, 0.0])], law=law, nodes=nodes)


def pressures(P: float) -> np.ndarray:
    """The chain's pressures (3 n,) Pa: ``P`` in chamber 1 of both segments."""
    return np.array([P, 0.0, 0.0, P, 0.0, 0.0])


def staircase(levels) -> tuple[Table, np.ndarray]:
    """The pressure schedule (a ``Table``) and the end of each hold (s)."""
    times, values, ends = [0.0], [pressures(0.0)], []
    for P in levels:
        t = times[-1]
        times += [t + RISE, t + RISE + HOLD]
        values += [pressures(P)] * 2
        ends.append(t + RISE + HOLD)
    return Table(np.array(times), np.array(values)), np.array(ends)


def wall_force(chain, q, v, env) -> float:
    """The wall's normal force on the arm (N, along the wall's normal)."""
    return float((chain.contacts(q, v, env).force @ env.obstacles[0].normal).sum())


def onset_pressure(chain, hi: float = 1.5e5) -> float:
    """The pressure (Pa) at which the free arm's surface first reaches the wall (statics without
    the wall, bisection to 10 Pa)."""
    r = SEGMENT["radius"]

    def reach(P):
        q = equilibrium(chain, pressures(P)).q
        return chain.backbone(q, 64).reshape(-1, 3)[:, 0].min() - r - WALL_X  # > 0: clear of the wall

    lo = 0.0
    while hi - lo > 10.0:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if reach(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


def floor_arm():
    """``(chain, q0, law)``: a free (floating-base) two-segment arm lying straight along world +x
    on the floor ``z <= 0``, sunk by the depth at which the floor carries its weight, and the
    contact law with friction (mu_static 0.5, mu_dynamic 0.4)."""
    chain = Chain([Segment(**SEGMENT) for _ in range(2)], base="floating")
    law = ContactLaw(stiffness=1e6, exponent=1.5, damping=hunt_crossley_damping(0.5, 0.1), mu_static=0.5,
                     mu_dynamic=0.4, slip_velocity=1e-3, stribeck_velocity=1e-2)
    g = float(np.linalg.norm(chain.gravity))
    # l k d^e = m g per contact point of rest length l and mass m, i.e. per metre: k d^e = (mass/length) g
    sink = (SEGMENT["mass"] / SEGMENT["length"] * g / law.stiffness) ** (1.0 / law.exponent)
    q0 = chain.neutral()
    q0[:3] = [0.0, 0.0, SEGMENT["radius"] - sink]
    q0[3:7] = pin.Quaternion(pin.utils.rotate("y", np.pi / 2)).coeffs()  # the arm's axis (base z) along world x
    return chain, q0, law


def drag(args) -> dict:
    """The arm lying on the floor, pulled along its axis at the tip by a constant ``PointLoad``
    of half and of 1.5 times the static friction limit ``mu_static W`` (``W`` its weight), for
    0.5 s (0.3 s with ``--quick``). Coulomb's law, independent of the model: below the limit
    the arm stays put (friction cancels the load); above it the arm slides and its momentum
    grows at ``F - mu_dynamic W`` (once the sliding speed is far above the Stribeck velocity).
    Writes ``push_floor.png``."""
    chain, q0, law = floor_arm()
    mass = sum(s.mass for s in chain.segments)
    W = mass * float(np.linalg.norm(chain.gravity))
    T = 0.3 if args.quick else 0.5
    t_ref = 0.1  # s: the sliding arm is far above the Stribeck velocity from here on
    runs = {}
    for ratio in (0.5, 1.5):
        load = ratio * law.mu_static * W
        env = Environment([HalfSpace()], law=law, loads=[PointLoad(1, 1.0, [load, 0.0, 0.0])], nodes=16)
        t0 = time.perf_counter()
        traj = qchain.simulate(chain, q0, np.zeros(chain.nv), (0.0, T), method="radau5", env=env,
                               t_eval=np.linspace(0.0, T, round(T * 200) + 1))
        wall = time.perf_counter() - t0 - traj.meta.get("compile_s", 0.0)
        _common.report(traj)
        momentum = np.array([chain.momentum(q, v)[0] for q, v in zip(traj.q, traj.v)])  # kg m/s along x
        c = chain.contacts(traj.q[-1], traj.v[-1], env)
        k = int(np.argmin(np.abs(traj.t - t_ref)))
        rate = (momentum[-1] - momentum[k]) / (traj.t[-1] - traj.t[k])  # N
        runs[ratio] = {"trajectory": traj, "load": load, "momentum": momentum, "contacts": c, "rate": rate,
                       "friction": float(c.force[:, 0].sum()), "normal": float(c.force[:, 2].sum()),
                       "wall_per_second": wall / T}
        expect = load - law.mu_dynamic * W if ratio > 1 else 0.0
        print(f"dragged at {load:.4f} N ({ratio:g} x mu_s W): momentum rate {rate:.5f} N after {t_ref:g} s "
              f"(Coulomb: {expect:.5f} N); at {T:g} s friction {runs[ratio]['friction']:+.5f} N, floor's normal "
              f"force {runs[ratio]['normal']:.5f} N (weight {W:.5f} N), fastest slip {c.slip.max():.3g} m/s; "
              f"{wall / T:.3g} s wall per simulated second")

    fig, (ax, mx) = plt.subplots(1, 2, figsize=(12, 4.5))
    slide = runs[1.5]
    tr = slide["trajectory"]
    tip = chain.tip_placement(tr.q[-1]).translation * 1e3
    _common.draw_obstacle(ax, HalfSpace([tip[0] * 1e-3, 0.0, 0.0]), axes=(0, 2), height=0.4)
    _common.draw_arm(ax, chain, tr.q[-1], tr.t[-1])
    _common.draw_contacts(ax, slide["contacts"], axes=(0, 2), mm_per_newton=500.0)
    ax.annotate("", xy=(tip[0] + slide["load"] * 100.0, tip[2]), xytext=(tip[0], tip[2]),
                arrowprops={"arrowstyle": "->", "color": "k"})
    ax.set_xlim(tip[0] - 230.0, tip[0] + 100.0)
    ax.set_ylim(-40.0, 60.0)
    ax.set_aspect("equal")
    slid = (tr.q[-1][0] - tr.q[0][0]) * 1e3
    ax.set(xlabel="x (mm)", ylabel="z (mm)",
           title=f"{1.5:g} x mu_s W at {tr.t[-1]:.2f} s, {slid:.0f} mm along: contact forces on the\n"
                 f"arm (red, 1 N = 500 mm), the tip load (black, 1 N = 100 mm)")
    for ratio, r in runs.items():
        tr = r["trajectory"]
        mx.plot(tr.t, r["momentum"], label=f"load {ratio:g} x mu_s W: simulated")
        k = int(np.argmin(np.abs(tr.t - t_ref)))
        expect = r["load"] - law.mu_dynamic * W if ratio > 1 else 0.0
        mx.plot(tr.t[k:], r["momentum"][k] + expect * (tr.t[k:] - tr.t[k]), "--", color="k", lw=1,
                label="Coulomb: rate F - mu_d W" if ratio > 1 else "Coulomb: at rest")
    mx.set(xlabel="t (s)", ylabel="linear momentum along x (kg m/s)", title="the arm's momentum against Coulomb's law")
    mx.legend(fontsize=7)
    for a in (ax, mx):
        a.grid(alpha=0.3)
    fig.suptitle(f"an arm on the floor pulled at its tip: mu_s = {law.mu_static:g}, mu_d = {law.mu_dynamic:g}")
    png = _common.save_figure(fig, args.out, "push_floor.png", dpi=80)
    return {"runs": runs, "weight": W, "mass": mass, "law": law, "png": png}


def main(argv=None) -> dict:
    ap = _common.parser(__doc__, "push_wall", scene_flag=False)
    # no scene here: say the example's own default
    ap._option_string_actions["--duration"].help = "simulated time (s); default the steps' 3.5 s, 2.1 s with --quick"
    args = ap.parse_args(argv)
    levels = LEVELS[::2] if args.quick else LEVELS
    schedule, ends = staircase(levels)
    T = args.duration if args.duration is not None else float(ends[-1])
    if not T > 0:
        raise SystemExit(f"--duration must be > 0 s, got {T}")
    chain, env = build()
    rest = equilibrium(chain)  # hanging straight under gravity: no pressure, clear of the wall
    print(f"arm: 2 segments of {SEGMENT['length'] * 1e3:g} mm hanging; wall at x = {WALL_X * 1e3:g} mm; "
          f"chamber 1 stepped to {', '.join(f'{P / 1e3:g}' for P in levels)} kPa; contact time scale "
          f"{env.time_scale(chain) * 1e3:.2f} ms")
    t_eval = np.linspace(0.0, T, round(T * 200) + 1)
    t0 = time.perf_counter()
    traj = qchain.simulate(chain, rest.q, np.zeros(chain.nv), (0.0, T), pressure=schedule, method="radau5", env=env,
                           t_eval=t_eval)
    wall = time.perf_counter() - t0 - traj.meta.get("compile_s", 0.0)
    _common.report(traj)
    cs = [chain.contacts(q, v, env) for q, v in zip(traj.q, traj.v)]
    normal = env.obstacles[0].normal
    F = np.array([float((c.force @ normal).sum()) for c in cs])
    f_max = max(float(np.linalg.norm(c.force, axis=1).max()) if len(c.force) else 0.0 for c in cs)
    depth = max(float(c.penetration.max()) if len(c.penetration) else 0.0 for c in cs)
    P_t = traj.p[:, 0]

    # statics: the settled force at each level, and the curve through many pressures
    p_on = onset_pressure(chain)
    settled, static, shapes = [], [], []
    q = rest.q
    for P, te in zip(levels, ends):
        k = int(np.argmin(np.abs(traj.t - te)))
        eq = equilibrium(chain, pressures(P), q0=q, env=env)
        if not eq.success:
            raise RuntimeError(f"no static shape at {P / 1e3:g} kPa: {eq.message}")
        q = eq.q
        settled.append(F[k] if traj.t[k] > te - 1e-9 else np.nan)  # nan: the run stopped before this hold's end
        static.append(wall_force(chain, eq.q, np.zeros(chain.nv), env))
        shapes.append((P, k, eq.q))
    settled, static = np.array(settled), np.array(static)
    curve_P = np.linspace(0.0, max(levels), 31)
    curve, q = [], rest.q
    for P in curve_P:
        q = equilibrium(chain, pressures(P), q0=q, env=env).q
        curve.append(wall_force(chain, q, np.zeros(chain.nv), env))

    print(f"simulated {T:g} s in {wall:.3g} s wall (not counting {traj.meta.get('compile_s', 0.0):.2g} s compiling or "
          f"loading the engine): {wall / T:.3g} s wall per simulated second (radau5, {traj.nfev} right-hand sides)")
    print(f"largest contact force at one point {f_max * 1e3:.1f} mN; deepest penetration {depth * 1e3:.3f} mm")
    print(f"the free arm reaches the wall at {p_on / 1e3:.2f} kPa (statics without the wall)")
    print(f"{'pressure (kPa)':>15} {'settled (mN)':>13} {'static (mN)':>12} {'relative difference':>20}")
    for P, fs, fe in zip(levels, settled, static):
        rel = f"{(fs - fe) / fe:+.1e}" if fe > 0 else f"{(fs - fe) * 1e3:+.3f} mN"
        rel = "(run ended before)" if np.isnan(fs) else rel
        print(f"{P / 1e3:15g} {fs * 1e3:13.3f} {fe * 1e3:12.3f} {rel:>20}")

    fig, (ax, fx) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [1, 1.3]})
    _common.draw_obstacle(ax, env.obstacles[0], axes=(0, 2), height=0.13)
    cmap = plt.get_cmap("viridis")
    _common.draw_arm(ax, chain, traj.q[0], 0.0, color="0.6", lw=1.5, label="0 kPa")
    for n, (P, k, _) in enumerate(shapes):
        _common.draw_arm(ax, chain, traj.q[k], traj.t[k], color=cmap(0.85 * n / max(1, len(shapes) - 1)),
                         label=f"{P / 1e3:g} kPa, t = {traj.t[k]:.2f} s")
        _common.draw_contacts(ax, cs[k], axes=(0, 2), mm_per_newton=100.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x (mm)", ylabel="z (mm)", title="settled shapes; contact forces on the arm (1 N = 100 mm)")
    ax.legend(fontsize=7, loc="lower right")
    fx.plot(P_t / 1e3, F, color="C0", lw=1, label="dynamics (radau5), every sample")
    fx.plot(curve_P / 1e3, curve, "k--", lw=1, label="statics: qchain.equilibrium(env=)")
    fx.plot(np.array(levels) / 1e3, settled, "o", color="C3", label="dynamics, end of each hold")
    fx.axvline(p_on / 1e3, color="0.5", ls=":", label="free arm reaches the wall (statics, no wall)")
    fx.set(xlabel="pressure in chamber 1 (kPa)", ylabel="wall's normal force (N)",
           title="the wall's normal force against pressure")
    fx.legend(fontsize=7)
    for a in (ax, fx):
        a.grid(alpha=0.3)
    fig.suptitle("pushing a frictionless wall: radau5 against statics")
    png = _common.save_figure(fig, args.out, "push_wall.png", dpi=80)
    dragged = drag(args)
    return {"trajectory": traj, "png": png, "chain": chain, "env": env, "levels": np.array(levels), "drag": dragged,
            "settled": settled, "static": static, "onset": p_on, "force": F, "max_force": f_max,
            "max_penetration": depth, "wall_per_second": wall / T}


if __name__ == "__main__":
    main()
