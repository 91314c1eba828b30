"""A three-segment arm hanging under gravity, waving: the tip's path and snapshots of the arm.

The scene (``scenes/wave_arm.toml``) drives chamber 1 of every segment against chambers 2
and 3 with sinusoidal pressures, 60 degrees later in each segment towards the tip, so a
bending wave runs down the arm. Chambers 2 and 3 get the same pressure, so the scene is
symmetric about the base's x-z plane and the model is built planar (reported below).
Writes ``wave_arm.png``: the arm at a few instants with the tip's path (side view), and
the tip against time.

Run: ``.venv/bin/python examples/wave_arm.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

import _common


def main(argv=None) -> dict:
    args, sc, model, ch, traj, wall = _common.run(__doc__, "wave_arm", argv, quick=0.3)
    tip = _common.tips(ch, traj)
    print(f"simulated {traj.t[-1]:g} s in {wall:.3g} s wall ({traj.t[-1] / wall:.0f} x real time)")
    print(f"tip sweep: x {np.ptp(tip[:, 0]) * 1e3:.1f} mm, z {np.ptp(tip[:, 2]) * 1e3:.1f} mm; "
          f"largest out-of-plane offset {np.abs(tip[:, 1]).max() * 1e3:.2g} mm")

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5.5), gridspec_kw={"width_ratios": [1, 1.3]})
    ax.plot(tip[:, 0] * 1e3, tip[:, 2] * 1e3, color="0.55", lw=1, label="tip path")
    idx = _common.snapshot_indices(len(traj.t), 7)
    cmap = plt.get_cmap("plasma")
    for n, k in enumerate(idx):
        _common.draw_arm(ax, ch, traj.q[k], traj.t[k], color=cmap(0.85 * n / max(1, len(idx) - 1)),
                         label=f"t = {traj.t[k]:.2f} s")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_title("side view: snapshots and tip path")
    ax.legend(fontsize=7, loc="lower left")
    ax.grid(alpha=0.3)
    for k, c in ((0, "x"), (2, "z")):
        bx.plot(traj.t, tip[:, k] * 1e3, label=f"tip {c}")
    bx.set_xlabel("t (s)")
    bx.set_ylabel("tip position (mm)")
    bx.set_title("tip against time")
    bx.legend()
    bx.grid(alpha=0.3)
    fig.suptitle(f"{sc.name}: {sc.n} segments, sinusoidal pressures, {model.chain.nv_active} free coordinates")
    png = _common.save_figure(fig, args.out, "wave_arm.png", dpi=110)
    return {"trajectory": traj, "png": png, "tip": tip}


if __name__ == "__main__":
    main()
