"""Step response of one segment: chamber 1 stepped to 40 kPa, tip position against time.

The scene (``scenes/step_response.toml``) holds one upright, damped segment under gravity.
The run starts from the straight pose; at ``t = 0.05 s`` chamber 1 jumps to 40 kPa and the
segment swings over to its new static shape, which :func:`qchain.equilibrium`
gives independently: the script prints the overshoot and the distance left to it at the
end, and plots the tip against time (``tip_response.png``).

Run: ``.venv/bin/python examples/step_response.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

import _common
from qchain import equilibrium


def main(argv=None) -> dict:
    args, sc, model, ch, traj, wall = _common.run(__doc__, "step_response", argv, quick=0.25)
    tip = _common.tips(ch, traj)

    p_after = sc.pressure_spec["after"]
    eq = equilibrium(ch, p_after, q0=model.q0)
    if not eq.success:
        raise RuntimeError(f"no static shape under p = {p_after}: {eq.message}")
    tip_eq = ch.tip_placement(eq.q).translation
    start = tip[0]
    travel = tip_eq - start
    progress = (tip - start) @ travel / (travel @ travel)  # 0 at the start, 1 at the static shape
    overshoot = 100.0 * (progress.max() - 1.0)
    left = float(np.linalg.norm(tip[-1] - tip_eq))
    print(f"static shape under {p_after / 1e3} kPa: tip ({', '.join(f'{x * 1e3:.2f}' for x in tip_eq)}) mm")
    print(f"simulated {traj.t[-1]:g} s in {wall:.3g} s wall; overshoot {overshoot:.1f} % of the {np.linalg.norm(travel) * 1e3:.2f} mm "
          f"travel; {left * 1e3:.3f} mm from the static shape at t = {traj.t[-1]:g} s")

    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for k, c in ((0, "x"), (2, "z")):
        axes[0].plot(traj.t, tip[:, k] * 1e3, label=f"tip {c}")
        axes[0].axhline(tip_eq[k] * 1e3, ls="--", color="0.5")
    axes[0].axvline(sc.pressure_spec["time"], color="r", lw=0.8, label="pressure step")
    axes[0].set_ylabel("tip position (mm)")
    axes[0].set_title("one segment, chamber 1 stepped to 40 kPa (dashed: static shape)")
    axes[0].legend()
    axes[1].plot(traj.t, progress)
    axes[1].axhline(1.0, ls="--", color="0.5")
    axes[1].set_ylabel("progress to the static shape")
    axes[1].set_xlabel("t (s)")
    for ax in axes:
        ax.grid(alpha=0.3)
    png = _common.save_figure(fig, args.out, "tip_response.png", dpi=110)
    return {"trajectory": traj, "png": png, "overshoot_percent": overshoot, "distance_to_static": left}


if __name__ == "__main__":
    main()
