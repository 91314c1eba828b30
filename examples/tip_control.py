"""Model-based tip control: PD on the tip position plus gravity and elastic compensation,
with the chamber pressures as the control input.

The arm of ``scenes/tip_control.toml`` (three inextensible segments hanging from a fixed
mount) is driven by the controller

    tau = g(q) + dU_el/dq(q) + J(q)^T (Kp (x_d - x) - Kd xdot) - c v

on its free coordinates: gravity and elasticity are cancelled, the tip is pulled to the
target ``x_d`` by a spring ``Kp`` with a damper ``Kd``, and ``c v`` damps the motions the
tip does not see. With the skew-symmetry of ``dM/dt - 2C`` the energy
``V = 1/2 v^T M v + 1/2 e^T Kp e`` has ``dV/dt = -xdot^T Kd xdot - c v^T v - v^T D v <= 0``
(``D`` the material damping), so the arm comes to rest with ``J^T Kp e = 0``: on the
target. It is :class:`qchain.control.TipPD` (docs/control.md), running at CONTROL_RATE
(500 Hz), its pressures held between samples (``controller_rate``: the arm is integrated in
compiled code between them). The pressures that realise ``tau`` solve ``B(q) p = tau`` in
the least-squares sense with ``0 <= p <= p_max`` (:func:`qchain.control.allocate`: bounded
least squares with a small penalty on ``p``: equal pressure in a segment's three chambers
does not bend it, so the least pressure is taken).

The default target is the tip of the static shape under a pressure set (so it is
reachable with admissible pressures); ``--target X Y Z`` (mm, world) picks another.
Writes ``tip_control.png``: the tip error (log scale), the tip against the target, the
pressures.

Run: ``.venv/bin/python examples/tip_control.py [--duration S] [--out DIR] [--quick] [--scene FILE] [--target X Y Z]``
"""

from __future__ import annotations

import time

import matplotlib.pyplot as plt
import numpy as np

import _common
from qchain import equilibrium
from qchain.control import TipPD

KP = 20.0  # N/m, tip spring
KD = 2.0  # N s/m, tip damper
C_NULL = 2e-5  # N m^2 s, damping of the coordinates (ux, uy rates, 1/(m s))
CONTROL_RATE = 500.0  # Hz: sampled and held between samples, as a real controller runs
P_MAX = 1.0e5  # Pa, largest chamber pressure
TARGET_PRESSURES = [0.0, 6e4, 0.0] * 3  # Pa: chamber 2 of every segment: the default target's shape


def main(argv=None) -> dict:
    par = _common.parser(__doc__, "tip_control")
    par.add_argument("--target", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                     help="tip target, world, mm (default: the tip of a static shape)")
    args = par.parse_args(argv)
    sc = _common.scene("tip_control", args)
    model = sc.build(controlled=True)
    ch = model.chain
    print("\n".join(sc.describe(model)))
    if args.target is None:
        eq = equilibrium(ch, TARGET_PRESSURES)
        if not eq.success:
            raise RuntimeError(f"no static shape for the default target: {eq.message}")
        target = ch.tip_placement(eq.q).translation
    else:
        target = np.array(args.target) * 1e-3
    x0 = ch.tip_placement(model.q0).translation
    print(f"target ({', '.join(f'{x * 1e3:.1f}' for x in target)}) mm, tip starts "
          f"{np.linalg.norm(target - x0) * 1e3:.1f} mm away")
    T = _common.duration(args, sc, quick=0.3)
    ctl = TipPD(ch, target, Kp=KP, Kd=KD, c=C_NULL, rate=CONTROL_RATE, p_max=P_MAX)
    t0 = time.perf_counter()
    traj = sc.simulate(model=model, duration=T, pressure=ctl, controller_rate=CONTROL_RATE)
    wall = time.perf_counter() - t0
    _common.report(traj)
    tip = _common.tips(ch, traj)
    err = np.linalg.norm(tip - target, axis=1)
    within = np.flatnonzero(err > 1e-3)
    settle = traj.t[within[-1] + 1] if within.size and within[-1] + 1 < len(traj.t) else (0.0 if not within.size else None)
    print(f"simulated {traj.t[-1]:g} s in {wall:.3g} s wall; tip error {err[0] * 1e3:.1f} mm -> {err[-1] * 1e3:.4f} mm; "
          + (f"within 1 mm from t = {settle:.3g} s" if settle is not None else "not yet within 1 mm"))
    print(f"largest pressure {traj.p.max() / 1e3:.1f} kPa (limit {P_MAX / 1e3:g}); largest |B p - tau| "
          f"{ctl.signals()['residual'].max():.2g} N m^2 (nonzero where the pressure limits bind)")

    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    axes[0].semilogy(traj.t, np.maximum(err * 1e3, 1e-6))
    axes[0].axhline(1.0, color="0.5", ls="--", lw=0.8)
    axes[0].set_ylabel("|tip - target| (mm)")
    axes[0].set_title(f"PD + gravity + elastic compensation, Kp = {KP:g} N/m, Kd = {KD:g} N s/m")
    for k, c in enumerate("xyz"):
        (line,) = axes[1].plot(traj.t, tip[:, k] * 1e3, label=f"tip {c}")
        axes[1].axhline(target[k] * 1e3, color=line.get_color(), ls="--", lw=0.8)
    axes[1].set_ylabel("tip (mm); dashed: target")
    axes[1].legend(fontsize=8)
    for k in range(traj.p.shape[1]):
        axes[2].plot(traj.t, traj.p[:, k] / 1e3, label=f"s{k // 3} c{k % 3 + 1}")
    axes[2].set_ylabel("pressure (kPa)")
    axes[2].set_xlabel("t (s)")
    axes[2].legend(fontsize=7, ncol=3)
    for ax in axes:
        ax.grid(alpha=0.3)
    png = _common.save_figure(fig, args.out, "tip_control.png", dpi=110)
    return {"trajectory": traj, "png": png, "error": err, "target": target}


if __name__ == "__main__":
    main()
