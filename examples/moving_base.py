"""An arm hanging from a shaking mount: a prescribed sinusoidal translation of the base.

The scene (``scenes/moving_base.toml``) hangs two idle segments from a mount that moves
20 mm to and fro along x at 1.5 Hz (``[base.motion]``, exact base velocity and
acceleration). The arm is driven only through its base. Prints the tip's sway against the
mount's and writes ``moving_base.png``: mount and tip against time, and snapshots.

Run: ``.venv/bin/python examples/moving_base.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

import _common


def main(argv=None) -> dict:
    args, sc, model, ch, traj, wall = _common.run(__doc__, "moving_base", argv, quick=0.3)
    tip = _common.tips(ch, traj)
    mount = np.array([ch.base_state(t)[0].translation for t in traj.t])
    rel = tip - mount
    print(f"simulated {traj.t[-1]:g} s in {wall:.3g} s wall")
    print(f"mount sway {np.ptp(mount[:, 0]) * 1e3:.1f} mm peak to peak; tip sway {np.ptp(tip[:, 0]) * 1e3:.1f} mm; "
          f"tip relative to the mount {np.ptp(rel[:, 0]) * 1e3:.1f} mm")

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [1.4, 1]})
    ax.plot(traj.t, mount[:, 0] * 1e3, "k--", label="mount x")
    ax.plot(traj.t, tip[:, 0] * 1e3, label="tip x")
    ax.plot(traj.t, rel[:, 0] * 1e3, label="tip x - mount x")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("mm")
    ax.set_title(f"mount shaken at {sc.base.motion.frequency:g} Hz, {sc.base.motion.amplitude * 1e3:g} mm")
    ax.legend()
    ax.grid(alpha=0.3)
    idx = _common.snapshot_indices(len(traj.t), 6)
    cmap = plt.get_cmap("viridis")
    bx.plot(tip[:, 0] * 1e3, tip[:, 2] * 1e3, color="0.6", lw=1, label="tip path")
    for n, k in enumerate(idx):
        _common.draw_arm(bx, ch, traj.q[k], traj.t[k], color=cmap(n / max(1, len(idx) - 1)), label=f"t = {traj.t[k]:.2f} s")
    bx.set_aspect("equal", adjustable="datalim")
    bx.set_xlabel("x (mm)")
    bx.set_ylabel("z (mm)")
    bx.set_title("side view")
    bx.legend(fontsize=7)
    bx.grid(alpha=0.3)
    png = _common.save_figure(fig, args.out, "moving_base.png", dpi=110)
    return {"trajectory": traj, "png": png, "tip": tip, "mount": mount}


if __name__ == "__main__":
    main()
