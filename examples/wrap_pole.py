"""A three-segment arm wraps a vertical pole and holds it.

The arm floats in water, neutrally buoyant (no net gravity), its base fixed with its axis
horizontal (world +x). A pole (a ``Cylinder``, radius 40 mm, axis along world z) stands beside
the arm's second segment. Chamber 1 of segments 1 and 2 is pressurised (a ramp from 0 to
140 kPa, then held): those two segments curl towards +y, round the pole, and squeeze it. The
contact law has friction (mu_static 0.5, mu_dynamic 0.4) and Hunt-Crossley damping.
(An arm lying on a table under gravity does not make a clean grasp: the table's friction
against the curling segments bends the free first segment the other way.)

Method: ``radau5``, the compiled implicit Runge-Kutta method with the exact Jacobian (the
contact's derivatives included). The contact is stiff: an explicit method must resolve the
contact points' vibration on the pole with its steps, an implicit one's steps follow the
arm's motion. Measured on this run (3 s): ``dopri5`` took 26 times the right-hand sides and
7 times the wall time of ``radau5``, for the same final shape (docs/contact_examples.md).

Writes ``wrap_pole.png``: top and side views of the arm at a few instants with the pole, the
contact points and the contact forces on the arm (arrows), and the contact forces against
time. Prints the largest contact force, the deepest penetration, the angle the arm wraps
round the pole and the wall-clock time per simulated second.

Run: ``.venv/bin/python examples/wrap_pole.py [--duration S] [--out DIR] [--quick]``
"""

from __future__ import annotations

import time

import _common
import matplotlib.pyplot as plt
import numpy as np
import pinocchio as pin

import qchain
from qchain import Chain, Ramp, Segment, equilibrium
from qchain.contact import ContactLaw, Cylinder, Environment, hunt_crossley_damping

#: one segment (SI units): tests/support.py's SEGMENT made softer (E = 50 kPa, so that 140 kPa
#: curls it to about 55 mm radius) and more damped (beta = 0.3 s: in water; with 0.01 s the floppy
#: arm swings round and its first segment bends the wrong way before the grasp closes)
SEGMENT = {"length": 0.1, "radius": 0.015, "mass": 0.05, "chamber_area": 4.5e-5,
           "chamber_radius": 0.0085, "youngs_modulus": 5e4, "damping": 0.3}
POLE_RADIUS = 0.04  # m
POLE_GAP = 0.002  # m between the straight arm's surface and the pole
PRESSURE = 1.4e5  # Pa in chamber 1 of segments 1 and 2
#: the base frame: the arm grows along world +x (local z), chamber 1 (local +x) faces world -y,
#: so chamber 1's pressure bends the arm towards world +y, in the horizontal plane
BASE_ROTATION = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def build(nodes: int = 16):
    """``(chain, env, pole)``: the weightless arm, the pole with the contact law."""
    r = SEGMENT["radius"]
    chain = Chain([Segment(**SEGMENT) for _ in range(3)], base_placement=pin.SE3(BASE_ROTATION, np.zeros(3)),
                  gravity=np.zeros(3))
    centre = np.array([SEGMENT["length"], r + POLE_GAP + POLE_RADIUS, 0.0])  # beside segment 1's start
    pole = Cylinder(centre - [0.0, 0.0, 0.075], centre + [0.0, 0.0, 0.075], POLE_RADIUS)
    law = ContactLaw(stiffness=1e6, exponent=1.5, damping=hunt_crossley_damping(0.5, 0.1), mu_static=0.5,
                     mu_dynamic=0.4, slip_velocity=1e-3, stribeck_velocity=1e-2)
    return chain, Environment([pole], law=law, nodes=nodes), pole


def wrap_angle(chain, q, pole) -> float:
    """The angle (deg) the backbone turns round the pole's axis from segment 1's start (where
    the grasp begins) to the tip, positive counter-clockwise seen from above."""
    pts = chain.backbone(q, 16)[1:].reshape(-1, 3)  # segments 1 and 2
    ang = np.unwrap(np.arctan2(pts[:, 1] - pole.a[1], pts[:, 0] - pole.a[0]))
    return float(np.degrees(ang[-1] - ang[0]))


def contact_span(c, pole) -> float:
    """The arc of the pole's circumference (deg) between its outermost contacts (in order along
    the arm)."""
    if len(c.segment) < 2:
        return 0.0
    ang = np.unwrap(np.arctan2(c.point[:, 1] - pole.a[1], c.point[:, 0] - pole.a[0]))
    return float(np.degrees(np.ptp(ang)))


def main(argv=None) -> dict:
    ap = _common.parser(__doc__, "wrap_pole", scene_flag=False)
    ap._option_string_actions["--duration"].help = "simulated time (s); default 3 s, 1.2 s with --quick"  # no scene here
    args = ap.parse_args(argv)
    T = args.duration if args.duration is not None else (1.2 if args.quick else 3.0)
    if not T > 0:
        raise SystemExit(f"--duration must be > 0 s, got {T}")
    ramp = min(1.0, 0.5 * T)
    chain, env, pole = build()
    p = np.zeros(chain.nu)
    p[[3, 6]] = PRESSURE
    print(f"arm: 3 segments of {SEGMENT['length'] * 1e3:g} mm, radius {SEGMENT['radius'] * 1e3:g} mm; "
          f"pole radius {POLE_RADIUS * 1e3:g} mm; chamber 1 of segments 1, 2 ramped to {PRESSURE / 1e3:g} kPa "
          f"over {ramp:g} s; contact time scale {env.time_scale(chain) * 1e3:.2f} ms")
    t_eval = np.linspace(0.0, T, round(T * 200) + 1)
    t0 = time.perf_counter()
    traj = qchain.simulate(chain, chain.neutral(), np.zeros(chain.nv), (0.0, T), pressure=Ramp(0.0, ramp, p),
                           method="radau5", env=env, t_eval=t_eval)
    wall = time.perf_counter() - t0 - traj.meta.get("compile_s", 0.0)
    _common.report(traj)

    cs = [chain.contacts(q, v, env) for q, v in zip(traj.q, traj.v)]
    n_pole = np.array([len(c.segment) for c in cs])
    f_net = np.array([np.linalg.norm(c.force.sum(axis=0)) for c in cs])  # the resultant on the arm
    f_sum = np.array([np.linalg.norm(c.force, axis=1).sum() for c in cs])  # the grip: sum of magnitudes
    f_fric = np.array([np.linalg.norm(c.force - np.sum(c.force * c.normal, axis=1)[:, None] * c.normal,
                                      axis=1).sum() for c in cs])
    f_max = max(float(np.linalg.norm(c.force, axis=1).max()) if len(c.force) else 0.0 for c in cs)
    depth = max(float(c.penetration.max()) if len(c.penetration) else 0.0 for c in cs)
    wrap = wrap_angle(chain, traj.q[-1], pole)
    span = contact_span(cs[-1], pole)
    # once settled, the arm's own forces (pressure, elastic, damping) are balanced by the
    # contact forces alone: what is left is the inertia M a + C v, ~0 at rest
    q, v = traj.q[-1], traj.v[-1]
    own = chain.internal_forces(q, v, p) - chain.generalized_gravity(q)
    tau_env = chain.environment_force(q, v, env)
    balance = float(np.linalg.norm(own + tau_env) / np.linalg.norm(tau_env))
    # the frictionless static shape near the final one: friction holds the arm a little away from it
    eq = equilibrium(chain, p, q0=q, env=env)
    to_static = float(np.linalg.norm(chain.tip_placement(q).translation - chain.tip_placement(eq.q).translation))
    print(f"simulated {T:g} s in {wall:.3g} s wall (not counting {traj.meta.get('compile_s', 0.0):.2g} s compiling or "
          f"loading the engine): {wall / T:.3g} s wall per simulated second (radau5, {traj.nfev} right-hand sides)")
    print(f"largest contact force at one point {f_max * 1e3:.1f} mN; deepest penetration {depth * 1e3:.3f} mm "
          f"({depth / SEGMENT['radius'] * 100:.1f}% of the arm's radius)")
    print(f"at t = {T:g} s: {n_pole[-1]} contact points on the pole, pressing {f_sum[-1]:.3f} N in all "
          f"(resultant {f_net[-1]:.3f} N, friction {f_fric[-1]:.3f} N); the arm wraps {wrap:.0f} deg round the pole, "
          f"its contacts span {span:.0f} deg of it")
    print(f"balance at the end: |B p - D v - dU/dq - g + tau_env| / |tau_env| = {balance:.2e}; the tip is "
          f"{to_static * 1e3:.2f} mm from the frictionless static shape (qchain.equilibrium, "
          f"{'converged' if eq.success else 'NOT converged'})")

    fig, axs = plt.subplots(1, 3, figsize=(15, 5), gridspec_kw={"width_ratios": [1.1, 1.1, 1.2]})
    ax, sx, fx = axs
    idx = _common.snapshot_indices(len(traj.t), 4)
    cmap = plt.get_cmap("viridis")
    _common.draw_obstacle(ax, pole, axes=(0, 1))
    _common.draw_obstacle(sx, pole, axes=(0, 2))
    for n, k in enumerate(idx):
        col = cmap(0.85 * n / max(1, len(idx) - 1))
        last = k == idx[-1]
        for a, axes in ((ax, (0, 1)), (sx, (0, 2))):
            _common.draw_arm(a, chain, traj.q[k], traj.t[k], axes=axes, color=col, lw=3 if last else 1.5,
                             label=f"t = {traj.t[k]:.2f} s" if a is ax else None)
    _common.draw_contacts(ax, cs[-1], axes=(0, 1), mm_per_newton=100.0)
    _common.draw_contacts(sx, cs[-1], axes=(0, 2), mm_per_newton=100.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title=f"top view (contact forces on the arm at {T:g} s: 1 N = 100 mm)")
    ax.legend(fontsize=7, loc="lower right")
    sx.set_aspect("equal", adjustable="datalim")
    sx.set(xlabel="x (mm)", ylabel="z (mm)", title="side view")
    fx.plot(traj.t, f_sum, label="sum of the contact forces' magnitudes")
    fx.plot(traj.t, f_net, label="their resultant")
    fx.plot(traj.t, f_fric, label="sum of the friction forces' magnitudes")
    fx.plot(traj.t, 1e-5 * traj.p[:, 3], "k--", lw=1, label="pressure (100 kPa)")
    fx.set(xlabel="t (s)", ylabel="force (N)", title="contact forces against time")
    fx.legend(fontsize=7)
    for a in axs:
        a.grid(alpha=0.3)
    fig.suptitle(f"wrapping a pole: radau5, friction mu_s = {env.law.mu_static:g}, mu_d = {env.law.mu_dynamic:g}")
    png = _common.save_figure(fig, args.out, "wrap_pole.png", dpi=80)
    return {"trajectory": traj, "png": png, "chain": chain, "env": env, "pole": pole, "wrap_deg": wrap,
            "span_deg": span, "contacts_on_pole": n_pole, "grip": f_sum, "resultant": f_net, "friction": f_fric,
            "balance": balance, "to_static": to_static, "static": eq, "max_force": f_max, "max_penetration": depth,
            "wall_per_second": wall / T, "ramp_end": ramp}


if __name__ == "__main__":
    main()
