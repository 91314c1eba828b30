"""A free-floating arm in zero gravity: the chambers move it, its momentum stays put.

The scene (``scenes/floating_arm.toml``) launches a three-segment arm with a floating base
(drifting and spinning slowly) and drives its chambers in a rotating pattern. Pressure is
an internal force, so the world linear momentum and the angular momentum about the world
origin must stay exactly what they were at the start; what is left is the integrator's
error. Prints the drift of both, relative to their size, and writes ``momentum.png``
(drift against time) and ``floating_arm.png`` (the arm's path).

Run: ``.venv/bin/python examples/floating_arm.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

import _common


def main(argv=None) -> dict:
    args, sc, model, ch, traj, wall = _common.run(__doc__, "floating_arm", argv, quick=0.2)
    h = np.array([ch.momentum(q, v) for q, v in zip(traj.q, traj.v)])
    drift = h - h[0]
    lin = np.linalg.norm(drift[:, :3], axis=1)
    ang = np.linalg.norm(drift[:, 3:], axis=1)
    # scales: the momentum the arm's parts carry (sum of |M v| over its motion), not the net
    mass = sum(s.mass for s in ch.segments)
    speed = max(np.abs(np.linalg.norm(np.diff(_common.tips(ch, traj), axis=0), axis=1) / np.diff(traj.t)).max(), 1e-12)
    lin_scale = mass * speed
    ang_scale = lin_scale * sum(s.length for s in ch.segments)
    rel_lin, rel_ang = lin.max() / lin_scale, ang.max() / ang_scale
    print(f"simulated {traj.t[-1]:g} s in {wall:.3g} s wall")
    print(f"momentum at the start: linear {np.linalg.norm(h[0, :3]):.6g} kg m/s, angular {np.linalg.norm(h[0, 3:]):.6g} kg m^2/s")
    print(f"largest drift: linear {lin.max():.3g} kg m/s ({rel_lin:.2g} of m v_tip,max = {lin_scale:.3g}), "
          f"angular {ang.max():.3g} kg m^2/s ({rel_ang:.2g} of m v_tip,max L = {ang_scale:.3g})")

    args.out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.semilogy(traj.t[1:], np.maximum(lin[1:], 1e-20), label="|linear drift| (kg m/s)")
    ax.semilogy(traj.t[1:], np.maximum(ang[1:], 1e-20), label="|angular drift| (kg m^2/s)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|h(t) - h(0)|")
    ax.set_title(f"free-floating arm, zero gravity: momentum drift ({sc.method}, rtol {sc.rtol:g})")
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    png_m = args.out / "momentum.png"
    fig.savefig(png_m, dpi=110)
    plt.close(fig)

    tip = _common.tips(ch, traj)
    base = traj.q[:, :3]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    idx = _common.snapshot_indices(len(traj.t), 6)
    cmap = plt.get_cmap("viridis")
    for ax, axes_, name in ((axes[0], (0, 2), "x-z"), (axes[1], (0, 1), "x-y")):
        ax.plot(tip[:, axes_[0]] * 1e3, tip[:, axes_[1]] * 1e3, color="0.6", lw=1, label="tip path")
        ax.plot(base[:, axes_[0]] * 1e3, base[:, axes_[1]] * 1e3, "k--", lw=1, label="base path")
        for n, k in enumerate(idx):
            _common.draw_arm(ax, ch, traj.q[k], traj.t[k], axes=axes_, color=cmap(n / max(1, len(idx) - 1)),
                             label=f"t = {traj.t[k]:.2f} s")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"{name[0]} (mm)")
        ax.set_ylabel(f"{name[2]} (mm)")
        ax.set_title(f"{name} view")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    png_a = args.out / "floating_arm.png"
    fig.savefig(png_a, dpi=110)
    plt.close(fig)
    print(f"wrote {png_m}\nwrote {png_a}")
    return {"trajectory": traj, "momentum": h, "relative_drift": (rel_lin, rel_ang), "pngs": [png_m, png_a]}


if __name__ == "__main__":
    main()
