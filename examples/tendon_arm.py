"""A three-segment arm hanging from its base, driven by two tendons: a straight one ending
mid-arm and a helical one running to the tip.

The arm (built here in Python; `examples/scenes/hanging_tendons.toml` is the same arm as a scene,
``qchain run examples/scenes/hanging_tendons.toml``): three 0.2 m segments of
radius 20 mm, E = 0.2 MPa, damped, hanging along world -z from a base 0.5 m up. Tendon 0 runs
straight at 15 mm from the backbone on the base's +x side and ends at the tip of segment 1
(mid-arm); tendon 1 winds round the arm at 12 mm, from
the base's +y side to the tip, half a turn in the arm's 0.6 m (one turn in 1.2 m of rest
length). Their tensions ramp to 5 N and 4 N over 0.5 s and are held;
the chambers stay at 0 Pa. Tendon 0 curls the upper two segments towards +x and leaves the
third straight; tendon 1, which changes side as it winds, twists the arm's bend out of the
x-z plane.

Checked at the end, against statics: the settled state beside ``qchain.equilibrium`` at the
final tensions.

Writes ``tendon_arm.png``: side (x-z), front (y-z) and top (x-y) views of the arm at a few
instants with both tendons' paths drawn, and the tip's position and the tensions against
time. Prints the tip's travel, the distance to the static shape and the wall-clock time.

Run: ``.venv/bin/python examples/tendon_arm.py [--duration S] [--out DIR] [--quick]``
(``--quick``: 1 s)
"""

from __future__ import annotations

import time

import _common
import matplotlib.pyplot as plt
import numpy as np
import pinocchio as pin

from qchain import Chain, Segment, Tendon, equilibrium, simulate
from qchain.sim.inputs import Ramp

#: the tensions held after the ramp (N)
TENSIONS = np.array([5.0, 4.0])
RAMP = 0.5  # s


def tendon_arm() -> Chain:
    seg = Segment(length=0.2, radius=0.02, mass=0.08, chamber_area=1e-4, chamber_radius=0.01, youngs_modulus=2e5,
                  damping=0.15)
    down = pin.SE3(pin.rpy.rpyToMatrix(np.pi, 0.0, 0.0), np.array([0.0, 0.0, 0.5]))  # hanging along -z
    tendons = [Tendon(radius=0.015, angle=0.0, end=1),  # straight, ends mid-arm
               Tendon(radius=0.012, angle=np.pi / 2, pitch=1.2)]  # a helix to the tip, half a turn
    return Chain([seg, seg, seg], base_placement=down, tendons=tendons)


def main(argv=None) -> dict:
    args = _common.parser(__doc__, "tendon_arm", scene_flag=False).parse_args(argv)
    T_end = args.duration if args.duration is not None else (1.0 if args.quick else 4.0)
    ch = tendon_arm()
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    tension = Ramp(0.0, RAMP, TENSIONS, np.zeros(2))
    t0 = time.perf_counter()
    traj = simulate(ch, q0, v0, (0.0, T_end), tension=tension, method="radau5", rtol=1e-7, atol=1e-9,
                    t_eval=np.linspace(0.0, T_end, int(100 * T_end) + 1))
    wall = time.perf_counter() - t0 - traj.meta.get("compile_s", 0.0)
    _common.report(traj)
    tips = _common.tips(ch, traj)
    eq = equilibrium(ch, tension=TENSIONS, q0=traj.q[-1])
    to_static = float(np.linalg.norm(ch.tip_placement(eq.q).translation - tips[-1]))
    travel = float(np.linalg.norm(tips[-1] - tips[0]))
    print(f"tendons: 0 straight to the tip of segment 1 ({TENSIONS[0]:g} N), 1 helical to the tip "
          f"({TENSIONS[1]:g} N), both ramped over {RAMP:g} s")
    print(f"tip: from {np.round(tips[0] * 1e3, 1)} mm to {np.round(tips[-1] * 1e3, 1)} mm, {travel * 1e3:.1f} mm "
          f"of travel; {to_static * 1e3:.3g} mm from the static shape (qchain.equilibrium, "
          f"{'converged' if eq.success else 'NOT converged'})")
    print(f"wall: {wall:.2f} s for {T_end:g} s simulated ({traj.meta.get('engine')} engine)")

    fig = plt.figure(figsize=(13, 8))
    grid = fig.add_gridspec(2, 6)
    views = [((0, 2), "side (x-z)"), ((1, 2), "front (y-z)"), ((0, 1), "top (x-y)")]
    picks = _common.snapshot_indices(len(traj.t), 5)
    for c, (axes, title) in enumerate(views):
        ax = fig.add_subplot(grid[0, 2 * c : 2 * c + 2])
        for i, k in enumerate(picks):
            shade = 0.25 + 0.75 * i / max(1, len(picks) - 1)
            _common.draw_arm(ax, ch, traj.q[k], traj.t[k], axes=axes, color=plt.cm.Blues(shade), lw=3,
                             label=f"t = {traj.t[k]:.2f} s")
            for m, path in enumerate(ch.tendon_paths(traj.q[k], 24)):
                ax.plot(path[:, axes[0]] * 1e3, path[:, axes[1]] * 1e3, color=("C3", "C2")[m], lw=0.9,
                        alpha=shade, label=(None if i < len(picks) - 1 else f"tendon {m}"))
        ax.set_title(title)
        ax.set_xlabel("xyz"[axes[0]] + " (mm)")
        ax.set_ylabel("xyz"[axes[1]] + " (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        if c == 0:
            ax.legend(fontsize=7, loc="lower left")
    ax = fig.add_subplot(grid[1, :3])
    for d in range(3):
        ax.plot(traj.t, tips[:, d] * 1e3, label="xyz"[d])
    ax.set_xlabel("t (s)")
    ax.set_ylabel("tip (mm)")
    ax.legend()
    ax.grid(alpha=0.3)
    ax = fig.add_subplot(grid[1, 3:])
    for m in range(ch.nt):
        ax.plot(traj.t, traj.tension[:, m], color=("C3", "C2")[m],
                label=f"tendon {m} ({'helical' if ch.tendons[m].helical else 'straight'})")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("tension (N)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.suptitle("A hanging arm driven by a mid-arm tendon and a helical one")
    png = _common.save_figure(fig, args.out, "tendon_arm.png")
    return dict(trajectory=traj, chain=ch, tips=tips, static=eq, to_static=to_static, png=png)


if __name__ == "__main__":
    main()
