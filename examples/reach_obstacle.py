"""Reaching a point behind an obstacle, with contact: tip PD straight at the target against
tip PD on via points beside the obstacle.

The arm is the one of ``scenes/tip_control.toml`` (three inextensible segments of 0.1 m
hanging from a fixed mount 0.5 m up), starting at rest hanging straight. The target is the
tip of the static shape under 60 kPa in chambers 2 and 3 of every segment (63 mm to the
side, so reachable with admissible pressures). A ball of 12 mm radius (``qchain.contact.Sphere``)
sits at the midpoint of the straight line from the hanging tip to the target: the straight
approach runs the tip into it. The obstacle is in the plant only (``run(..., env=...)``, the
contact law's defaults); the controller, :class:`qchain.control.TipPD` with
``examples/tip_control.py``'s gains, does not know it is there.

- ``straight``: the target from the start;
- ``via points``: two via points 45 mm to the side of the straight line (horizontally,
  across it), beside the start and beside the target, so the tip's path goes sideways, along
  the line 45 mm from the ball's centre (the arm's 15 mm radius and the ball's 12 mm leave
  18 mm of clearance), and back: the first until ``SWITCHES[0]`` = 0.8 s, the second until
  ``SWITCHES[1]`` = 1.6 s, then the target. (One via point 45 mm beside the ball's centre would
  not do: the lines from the start to it and from it to the target pass 26 mm from the ball's
  centre, less than the 27 mm of the two radii, and the arm brushed the ball, 0.13 N.)

Prints, for each, the final tip error (the tip by forward kinematics of the last state) and
the contact force on the arm (the sum of the contact points' forces, ``chain.contacts``): its
largest value over the run and its final value. Writes ``reach_obstacle.png``: the arm's
final shapes and the tip paths from above and from the side with the ball, the tip error
and the contact force against time.

Run: ``.venv/bin/python examples/reach_obstacle.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
(default 3 s; ``--quick``: 0.5 s)
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle

import _common
from qchain import equilibrium
from qchain.contact import Environment, Sphere
from qchain.control import TipPD

KP, KD, C_NULL = 20.0, 2.0, 2e-5  # examples/tip_control.py's gains (N/m, N s/m, N m^2 s)
RATE = 500.0  # Hz
P_MAX = 1.0e5  # Pa
TARGET_PRESSURES = [0.0, 6e4, 6e4]  # Pa, each segment's chambers: the target's static shape
BALL_RADIUS = 0.012  # m
VIA_OFFSET = 0.045  # m, the via points' distance from the straight line
SWITCHES = (0.8, 1.6)  # s: the via-point controller turns to the second via point, then to the target
DURATION = 3.0  # s
OUTPUT_RATE = 100.0  # Hz


def contact_force(chain, traj, env) -> np.ndarray:
    """(K,) N: the magnitude of the summed contact force on the arm at each sample."""
    return np.array([np.linalg.norm(chain.contacts(q, v, env).force.sum(axis=0)) for q, v in zip(traj.q, traj.v)])


def main(argv=None) -> dict:
    args = _common.parser(__doc__, "reach_obstacle", scene="tip_control").parse_args(argv)
    sc = _common.scene("tip_control", args)
    model = sc.build(controlled=True)
    ch = model.chain
    print("\n".join(sc.describe(model)))
    T = args.duration if args.duration is not None else (0.5 if args.quick else DURATION)
    if not T > 0:
        raise SystemExit(f"--duration must be > 0 s, got {T}")

    eq = equilibrium(ch, TARGET_PRESSURES * ch.n)
    if not eq.success:
        raise RuntimeError(f"no static shape for the target: {eq.message}")
    target = ch.tip_placement(eq.q).translation
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    start = ch.tip_placement(q0).translation
    centre = 0.5 * (start + target)
    env = Environment([Sphere(centre, BALL_RADIUS)])
    line = (target - start) / np.linalg.norm(target - start)
    side = np.cross(line, ch.gravity / np.linalg.norm(ch.gravity))  # horizontal, across the line
    off = VIA_OFFSET * side / np.linalg.norm(side)
    vias = np.array([start + off, target + off])
    print(f"target ({', '.join(f'{x * 1e3:.1f}' for x in target)}) mm, {np.linalg.norm(target - start) * 1e3:.1f} mm "
          f"from the hanging tip; ball of {BALL_RADIUS * 1e3:g} mm radius at ({', '.join(f'{x * 1e3:.1f}' for x in centre)}) mm; "
          f"via points " + ", ".join(f"({', '.join(f'{x * 1e3:.1f}' for x in v)}) mm until t = {s:g} s" for v, s in zip(vias, SWITCHES)))

    zero = np.zeros(3)
    approaches = {"straight": lambda t: (target, zero),
                  "via points": lambda t: (vias[0] if t < SWITCHES[0] else vias[1] if t < SWITCHES[1] else target, zero)}
    t_eval = np.linspace(0.0, T, int(round(T * OUTPUT_RATE)) + 1)
    results = {}
    for name, x_d in approaches.items():
        ctl = TipPD(ch, x_d, Kp=KP, Kd=KD, c=C_NULL, rate=RATE, p_max=P_MAX)
        traj = ctl.run(q0, v0, T, method="dopri5", env=env, t_eval=t_eval)
        if not traj.success:
            raise RuntimeError(f"{name}: the run failed: {traj.message}")
        tip = _common.tips(ch, traj)
        F = contact_force(ch, traj, env)
        err = np.linalg.norm(tip - target, axis=1)
        results[name] = {"trajectory": traj, "tip": tip, "error": err, "force": F}
        print(f"{name:>9}: final tip error {err[-1] * 1e3:.2f} mm; contact force largest {F.max():.3f} N "
              f"(t = {traj.t[np.argmax(F)]:.2f} s), final {F[-1]:.3f} N; largest pressure {traj.p.max() / 1e3:.1f} kPa")

    fig, axes = plt.subplots(2, 2, figsize=(10, 8))
    for k, (ax, (i, j), title) in enumerate(zip(axes[0], [(0, 1), (0, 2)], ["from above", "from the side"])):
        ax.add_patch(Circle(centre[[i, j]] * 1e3, BALL_RADIUS * 1e3, color="0.6", alpha=0.6))
        ax.plot(*(target[[i, j]] * 1e3), "k*", ms=10, label="target")
        ax.plot(vias[:, i] * 1e3, vias[:, j] * 1e3, "kx", ms=7, label="via points")
        for c, (name, r) in enumerate(results.items()):
            ax.plot(r["tip"][:, i] * 1e3, r["tip"][:, j] * 1e3, color=f"C{c}", lw=1.2, label=f"tip, {name}")
            traj = r["trajectory"]
            if k == 1:
                _common.draw_arm(ax, ch, traj.q[-1], traj.t[-1], axes=(i, j), color=f"C{c}", lw=2.0)
        ax.set_xlabel(f"{'xyz'[i]} (mm)")
        ax.set_ylabel(f"{'xyz'[j]} (mm)")
        ax.set_title(title, fontsize=10)
        ax.set_aspect("equal", adjustable="datalim")
    axes[0, 0].legend(fontsize=7)
    for c, (name, r) in enumerate(results.items()):
        t = r["trajectory"].t
        axes[1, 0].semilogy(t, np.maximum(r["error"] * 1e3, 1e-3), color=f"C{c}", label=name)
        axes[1, 1].plot(t, r["force"], color=f"C{c}", label=name)
    axes[1, 0].set_ylabel("|tip - target| (mm)")
    axes[1, 1].set_ylabel("contact force on the arm (N)")
    for ax in axes[1]:
        for s in SWITCHES:
            ax.axvline(s, color="0.5", ls="--", lw=0.8)
        ax.set_xlabel("t (s)")
        ax.legend(fontsize=8)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    fig.suptitle("Tip PD to a target behind a ball: straight, and by via points (contact in the plant)")
    png = _common.save_figure(fig, args.out, "reach_obstacle.png", dpi=90)
    return {"results": results, "png": png, "target": target, "vias": vias, "env": env, "chain": ch}


if __name__ == "__main__":
    main()
