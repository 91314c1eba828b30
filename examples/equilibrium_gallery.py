"""A gallery of static shapes: the arm of ``scenes/equilibrium_gallery.toml`` under each
pressure set of its table, solved with :func:`qchain.equilibrium`.

For every row of the scene's pressure table the script finds the shape where elastic,
gravity and pressure forces balance, prints its bends, lengths and tip position, and draws
all shapes (``gallery.png``: 3-D view and top view). Then it checks one shape against the
dynamics: starting from rest under a gallery pressure set held constant, the damped arm
must come to rest on that static shape; the distance left after ``--duration`` seconds
(default 3 s) is printed.

Run: ``.venv/bin/python examples/equilibrium_gallery.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
"""

from __future__ import annotations

import time

import matplotlib.pyplot as plt
import numpy as np

import _common
from qchain import Constant, equilibrium

CHECK_ROW = 2  # the S-shape: segment 0 bent one way, segment 1 the other


def main(argv=None) -> dict:
    args = _common.parser(__doc__, "equilibrium_gallery").parse_args(argv)
    sc = _common.scene("equilibrium_gallery", args)
    model = sc.build()
    ch = model.chain
    rows = sc.pressure_spec["values"]
    print("\n".join(sc.describe(model)))
    print(f"{'pressures (kPa), segment by segment':>44}  {'bends (deg)':>14}  {'lengths (mm)':>14}  tip (mm)  [iterations]")
    shapes = []
    for p in rows:
        eq = equilibrium(ch, p)
        if not eq.success:
            raise RuntimeError(f"no static shape under p = {p}: {eq.message}")
        q = eq.q
        bends = [np.degrees(np.hypot(*q[ch.q_slice(j)][1:]) * q[ch.q_slice(j)][0]) for j in range(ch.n)]
        lengths = [q[ch.q_slice(j)][0] * 1e3 for j in range(ch.n)]
        tip = ch.tip_placement(q).translation * 1e3
        label = " | ".join(",".join(f"{x / 1e3:g}" for x in p[3 * j : 3 * j + 3]) for j in range(ch.n))
        print(f"{label:>44}  {', '.join(f'{b:6.1f}' for b in bends):>14}  {', '.join(f'{x:6.2f}' for x in lengths):>14}"
              f"  ({tip[0]:6.1f}, {tip[1]:6.1f}, {tip[2]:6.1f})  [{eq.iterations}]")
        shapes.append((label, q, tip))

    fig = plt.figure(figsize=(12, 5.5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    for label, q, tip in shapes:
        pts = ch.backbone(q, 24).reshape(-1, 3) * 1e3
        (line,) = ax3.plot(pts[:, 0], pts[:, 1], pts[:, 2], lw=3, label=f"kPa {label}")
        ax2.plot(pts[:, 0], pts[:, 1], lw=3, color=line.get_color())
        ax2.plot(tip[0], tip[1], "o", color=line.get_color())
    ax3.set_box_aspect(np.ptp(np.array([ax3.get_xlim3d(), ax3.get_ylim3d(), ax3.get_zlim3d()]), axis=1))
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    ax3.set_title("static shapes under gravity")
    ax3.legend(fontsize=6, loc="upper left")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x (mm)")
    ax2.set_ylabel("y (mm)")
    ax2.set_title("top view (chambers 1, 2, 3 at 0, 120, -120 deg)")
    ax2.grid(alpha=0.3)
    png = _common.save_figure(fig, args.out, "gallery.png", dpi=110)

    T = _common.duration(args, sc, quick=0.3) if (args.duration is not None or args.quick) else 3.0
    label, q_eq, tip_eq = shapes[CHECK_ROW]
    t0 = time.perf_counter()
    traj = sc.simulate(model=model, duration=T, pressure=Constant(rows[CHECK_ROW]))
    wall = time.perf_counter() - t0
    _common.report(traj)
    tip_dyn = ch.tip_placement(traj.q[-1]).translation * 1e3
    start = ch.tip_placement(traj.q[0]).translation * 1e3
    left = float(np.linalg.norm(tip_dyn - tip_eq))
    print(f"dynamics from rest under {label} kPa for {T:g} s ({wall:.2f} s wall): tip {left:.4f} mm from the static "
          f"shape (it started {np.linalg.norm(start - tip_eq):.1f} mm away)")
    return {"shapes": shapes, "png": png, "trajectory": traj, "distance_to_static_mm": left}


if __name__ == "__main__":
    main()
