"""Tip tracking of a circle: configuration-space PD with compensation and passivity-based
(Slotine-Li) tracking side by side, on the model and on a mismatched arm.

The arm is the one of ``scenes/tip_control.toml`` (three inextensible segments of 0.1 m
hanging from a fixed mount 0.5 m up). Its tip is to follow a horizontal circle 50 mm across
(radius ``RADIUS`` = 25 mm) at 0.5 Hz, centred under the mount in the horizontal plane a
uniformly bent arm's tip reaches 25 mm from the mount's axis (1.4 mm above the hanging tip).
It starts at rest at the inverse-kinematics configuration of the circle's first point
(``qchain.control.tip_inverse_kinematics``, from the static shape under 20 kPa in chambers 2
and 3 of every segment, which leans the tip that way).

The controllers (``CONTROLLERS``: a list of ``(name, factory)``, ``factory(chain, path,
duration, q_home) -> Controller``, so another controller is one more line):

- ``PD + compensation``: :class:`qchain.control.PDCompensation` on the configuration
  reference of the circle by inverse kinematics (:class:`qchain.control.TipPathReference`);
- ``Slotine-Li``: :class:`qchain.control.TipTracking` (the same reference, followed by
  :class:`qchain.control.SlotineLi`, with the reference's accelerations fed forward);
- ``tip PD``: :class:`qchain.control.TipPD` on the moving tip target (no feed-forward), with
  ``examples/tip_control.py``'s gains;
- ``MPC``: :class:`qchain.control.MPC`, box-constrained iLQR on the model's exact derivatives
  over ``MPC_HORIZON`` (10) intervals of 20 ms (0.2 s ahead), one warm-started iteration a
  sample at ``MPC_RATE`` (50 Hz), pressure weight ``MPC_R`` (1e-10 1/Pa^2), the circle itself
  as its target path.

The configuration controllers get the same bandwidth ``BANDWIDTH`` (5 Hz, ten times the
circle's) on every free coordinate ``i``: ``Kp_i = m_i w^2``, ``Kd_i = 2 m_i w`` (PD) and
``Lambda = w``, ``K_i = m_i w`` (Slotine-Li: ``s`` and ``e`` both decaying at ``w``), with
``w = 2 pi BANDWIDTH`` and ``m_i = 1 / (M^-1)_ii`` the inertia coordinate ``i`` shows when
the others move freely (the model's mass matrix at the start). ``M_ii`` in its place would
overstate the distal coordinates' inertia (the segments are strongly coupled: near the start
``M``'s eigenvalues span 3.9e-8 to 3.1e-5 against diagonal entries of 2.6e-7 to 2.6e-5), and
``M^-1 Kd`` would reach 2400 1/s, beyond the 2 / (2 ms) = 1000 1/s up to which a damper
sampled and held at 500 Hz stays stable (the pressures chattered between the bounds in 99 %
of the calls); with ``m_i`` the closed loop's rates span 5-50 rad/s. All but MPC run at 500 Hz with the pressures held
between samples, within ``0 <= p <= 100 kPa``.

Each runs on the controller's own model ("matched") and on a mismatched arm: every segment's
Young's modulus ``E_REL_STDERR`` (0.75 %) higher than the model's -- the larger relative
standard error of the moduli the fit of ``examples/calibrate.py`` reports on its full 3 s run
(634 Pa on 84.3 kPa; docs/fit.md) -- and an unmodelled 20 g ball (10 mm radius) at the tip, centred
10 mm beyond it.

Prints a table: RMS tip error over the run (mm, the plant's tip by forward kinematics against
the circle at the output samples), RMS pressure (kPa, over the samples and the 9 chambers)
and the median CPU time of one control step (us: the controller's call, allocation included).
Writes ``track_circle.png`` (tip paths seen from above against the circle, tip error against
time, the pressures) and, for each run, ``<key>.npz`` (``t``, ``q``, ``v``, ``p``, ``x_d``,
``tip`` of the output samples) with the controller's signals in ``<key>-signals.npz``.

Run: ``.venv/bin/python examples/track_circle.py [--duration S] [--out DIR] [--quick] [--scene FILE]``
(default 4 s: two turns; ``--quick``: 0.4 s)
"""

from __future__ import annotations

import dataclasses
import re

import matplotlib.pyplot as plt
import numpy as np
import pinocchio as pin
from scipy.optimize import brentq

import _common
from qchain import Chain, equilibrium
from qchain.control import MPC, PDCompensation, TipPD, TipPathReference, TipTracking, tip_inverse_kinematics

RADIUS = 0.025  # m: a circle 50 mm across
FREQUENCY = 0.5  # Hz, once round in 2 s
DURATION = 4.0  # s: two turns
RATE = 500.0  # Hz, every controller but MPC
MPC_RATE = 50.0  # Hz: a plan every 20 ms (docs/control.md: the solve times against the horizon)
MPC_HORIZON = 10  # control intervals: 0.2 s ahead
#: 1/Pa^2, MPC's pressure weight: MPC's default (1e-12) lets the one-iteration plans jump between
#: 0 and p_max from one sample to the next on this circle (1.70 mm RMS); 1e-11 still chatters
#: (0.71 mm), 1e-10 plans smooth pressures (docs/control.md)
MPC_R = 1e-10
P_MAX = 1.0e5  # Pa
BANDWIDTH = 5.0  # Hz, the configuration controllers' (ten times the circle's frequency)
OUTPUT_RATE = 200.0  # Hz, the samples the tip error is measured at
#: relative standard error of a Young's modulus fitted by examples/calibrate.py (its full 3 s run:
#: 84302 +- 634 Pa for segments 2-3, 125623 +- 621 Pa for segment 1; the larger ratio; docs/fit.md):
#: the mismatched arm's moduli are this much higher
E_REL_STDERR = 634.0 / 84302.0
PAYLOAD_MASS = 0.02  # kg, the mismatched arm's unmodelled tip payload
PAYLOAD_RADIUS = 0.01  # m, a ball, centred its radius beyond the tip


def _bandwidth_gains(chain, q_home):
    """``(m, w)``: ``m_i = 1 / (M^-1)_ii`` (k,) on the free coordinates, the model's mass matrix
    ``M`` at ``q_home``, and ``w = 2 pi BANDWIDTH`` rad/s (the module docstring)."""
    a = np.flatnonzero(chain.active)
    M = chain.mass_matrix(q_home)[np.ix_(a, a)]
    return 1.0 / np.diag(np.linalg.inv(M)), 2.0 * np.pi * BANDWIDTH


def pd_compensation(chain, path, duration, q_home):
    M, w = _bandwidth_gains(chain, q_home)
    return PDCompensation(chain, TipPathReference(chain, path, duration, q_home), Kp=M * w ** 2, Kd=2.0 * M * w,
                          rate=RATE, p_max=P_MAX)


def slotine_li(chain, path, duration, q_home):
    M, w = _bandwidth_gains(chain, q_home)
    return TipTracking(chain, path, duration, q_home, K=M * w, Lambda=w, rate=RATE, p_max=P_MAX)


def tip_pd(chain, path, duration, q_home):
    return TipPD(chain, path, Kp=20.0, Kd=2.0, c=2e-5, rate=RATE, p_max=P_MAX)  # examples/tip_control.py's gains


def mpc(chain, path, duration, q_home):
    # one iteration a sample, warm-started: the real-time setting of docs/control.md's table
    return MPC(chain, path, horizon=MPC_HORIZON, max_iter=1, R=MPC_R, rate=MPC_RATE, p_max=P_MAX)


#: ``(name, factory)``; ``factory(chain, path, duration, q_home) -> qchain.control.Controller``,
#: ``path(t) -> (x_d (3,) m, xd_dot (3,) m/s)`` (world), ``q_home`` the start (nq,)
CONTROLLERS = [
    ("PD + compensation", pd_compensation),
    ("Slotine-Li", slotine_li),
    ("tip PD", tip_pd),
    ("MPC", mpc),
]


class Circle:
    """``t -> (x_d, xd_dot)``: the horizontal circle of ``radius`` m about ``centre`` (3,) m at
    ``frequency`` Hz, starting on +x and turning counter-clockwise seen from above."""

    def __init__(self, centre, radius: float, frequency: float):
        self.centre, self.radius, self.w = np.asarray(centre, dtype=float), radius, 2.0 * np.pi * frequency

    def point(self, t):
        """(3,) or (K, 3) m for a number or (K,) times."""
        t = np.asarray(t, dtype=float)
        ph = self.w * t
        return self.centre + self.radius * np.stack([np.cos(ph), np.sin(ph), np.zeros_like(ph)], axis=-1)

    def __call__(self, t):
        ph = self.w * t
        return self.point(t), self.radius * self.w * np.array([-np.sin(ph), np.cos(ph), 0.0])


def mismatched(chain: Chain) -> Chain:
    """The arm the mismatched runs drive: every modulus ``1 + E_REL_STDERR`` times the model's
    and a 20 g ball of 10 mm radius centred 10 mm beyond the tip (tip frame +z)."""
    segs = [dataclasses.replace(s, youngs_modulus=s.youngs_modulus * (1.0 + E_REL_STDERR)) for s in chain.segments]
    ball = pin.Inertia(PAYLOAD_MASS, np.array([0.0, 0.0, PAYLOAD_RADIUS]),
                       0.4 * PAYLOAD_MASS * PAYLOAD_RADIUS ** 2 * np.eye(3))
    plant = Chain(segs, gravity=chain.gravity, base_placement=chain.base_placement, payload=ball)
    if not np.array_equal(plant.active, chain.active):  # the locks follow the segments' own flags
        raise RuntimeError("the mismatched arm does not have the model's free coordinates")
    return plant


def key(name: str, case: str) -> str:
    """A file name for a run: ``pd-compensation-matched``."""
    return re.sub(r"[^a-z0-9]+", "-", f"{name} {case}".lower()).strip("-")


def rms_tip_error(chain, traj, circle) -> tuple[float, np.ndarray, np.ndarray]:
    """``(rms, tip, x_d)``: the RMS over the samples of ``|tip - x_d|`` (m), the tip (K, 3) by
    forward kinematics of ``chain`` and the circle's point (K, 3) at the samples' times."""
    tip = _common.tips(chain, traj)
    x_d = circle.point(traj.t)
    return float(np.sqrt(np.mean(np.sum((tip - x_d) ** 2, axis=1)))), tip, x_d


def main(argv=None) -> dict:
    args = _common.parser(__doc__, "track_circle", scene="tip_control").parse_args(argv)
    sc = _common.scene("tip_control", args)
    model = sc.build(controlled=True)
    ch = model.chain
    print("\n".join(sc.describe(model)))
    T = args.duration if args.duration is not None else (0.4 if args.quick else DURATION)
    if not T > 0:
        raise SystemExit(f"--duration must be > 0 s, got {T}")

    base = ch.base_placement.translation
    reach = sum(s.length for s in ch.segments)
    down = ch.gravity / np.linalg.norm(ch.gravity)
    # a uniform arc of length L bent by theta puts its tip L (1 - cos theta) / theta off its axis
    # and L sin(theta) / theta along it
    theta = brentq(lambda th: reach * (1 - np.cos(th)) / th - RADIUS, 1e-6, np.pi)
    centre = base + reach * np.sin(theta) / theta * down
    circle = Circle(centre, RADIUS, FREQUENCY)
    lean = equilibrium(ch, [0.0, 2e4, 2e4] * ch.n)  # chambers 2 and 3: the tip leans to +x
    if not lean.success:
        raise RuntimeError(f"no static shape to start the inverse kinematics from: {lean.message}")
    q_home = tip_inverse_kinematics(ch, circle.point(0.0), lean.q)
    plants = {"matched": ch, "mismatched": mismatched(ch)}
    print(f"circle: radius {RADIUS * 1e3:g} mm at {FREQUENCY:g} Hz about ({', '.join(f'{c * 1e3:.1f}' for c in centre)}) mm; "
          f"{T:g} s; mismatched arm: E x {1 + E_REL_STDERR:.4f}, {PAYLOAD_MASS * 1e3:g} g at the tip")

    t_eval = np.linspace(0.0, T, int(round(T * OUTPUT_RATE)) + 1)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for name, factory in CONTROLLERS:
        ctl = factory(ch, circle, T, q_home)
        for case, plant in plants.items():
            traj = ctl.run(q_home, np.zeros(ch.nv), T, plant=plant, method=sc.method, dt=sc.dt, t_eval=t_eval)
            if not traj.success:
                raise RuntimeError(f"{name}, {case}: the run failed: {traj.message}")
            rms, tip, x_d = rms_tip_error(ch, traj, circle)
            sig = ctl.signals()
            k = key(name, case)
            np.savez(out / f"{k}.npz", t=traj.t, q=traj.q, v=traj.v, p=traj.p, x_d=x_d, tip=tip)
            ctl.save(out / f"{k}-signals.npz")
            results.append({"name": name, "case": case, "key": k, "rms_mm": rms * 1e3,
                            "p_rms_kpa": float(np.sqrt(np.mean(traj.p ** 2))) / 1e3,
                            "p_max_kpa": float(traj.p.max()) / 1e3, "p_min_kpa": float(traj.p.min()) / 1e3,
                            "compute_us": float(np.median(sig["compute_s"])) * 1e6, "rate": ctl.rate,
                            "saturated": float(np.mean(sig["saturated"])), "t": traj.t, "tip": tip, "x_d": x_d,
                            "p": traj.p})

    head = f"{'controller':<20} {'plant':<11} {'RMS tip error (mm)':>18} {'RMS pressure (kPa)':>19} " \
           f"{'compute/step (us)':>18} {'saturated':>10}"
    print(head)
    print("-" * len(head))
    for r in results:
        print(f"{r['name']:<20} {r['case']:<11} {r['rms_mm']:>18.3f} {r['p_rms_kpa']:>19.2f} {r['compute_us']:>18.0f} "
              f"{r['saturated'] * 100:>9.1f}%")
    print("(RMS over the output samples at 200 Hz; compute: median CPU time of one controller call; saturated: the "
          "share of calls where the pressure bounds bind)")

    fig = plt.figure(figsize=(11, 9))
    gs = fig.add_gridspec(3, len(CONTROLLERS))
    styles = {"matched": "-", "mismatched": "--"}
    ring = circle.point(np.linspace(0.0, 1.0 / FREQUENCY, 200))
    for i, (name, _) in enumerate(CONTROLLERS):
        ax = fig.add_subplot(gs[0, i])
        ax.plot(ring[:, 0] * 1e3, ring[:, 1] * 1e3, color="0.6", lw=3, label="circle")
        for r in results:
            if r["name"] == name:
                ax.plot(r["tip"][:, 0] * 1e3, r["tip"][:, 1] * 1e3, styles[r["case"]], lw=1, label=r["case"])
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=7)
    ax = fig.add_subplot(gs[1, :])
    for i, r in enumerate(results):
        err = np.linalg.norm(r["tip"] - r["x_d"], axis=1) * 1e3
        ax.plot(r["t"], err, styles[r["case"]], color=f"C{i // 2}", lw=1,
                label=f"{r['name']}, {r['case']} (RMS {r['rms_mm']:.2f} mm)")
    ax.set_yscale("log")
    ax.set_ylim(bottom=1e-2)  # the runs start on the circle: 1e-14 mm at t = 0 would squash the rest
    ax.set_ylabel("|tip - circle| (mm)")
    ax.legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(gs[2, :])
    for i, r in enumerate(results):
        if r["case"] == "mismatched":
            ax.plot(r["t"], r["p"] / 1e3, color=f"C{i // 2}", lw=0.6)
            ax.plot([], [], color=f"C{i // 2}", label=f"{r['name']}, mismatched (9 chambers)")
    ax.set_ylabel("pressure (kPa)")
    ax.set_xlabel("t (s)")
    ax.legend(fontsize=7)
    for a in fig.axes:
        a.grid(alpha=0.3)
    fig.suptitle(f"Tip on a {2 * RADIUS * 1e3:g} mm circle at {FREQUENCY:g} Hz: model (solid) and mismatched arm (dashed)")
    png = _common.save_figure(fig, out, "track_circle.png", dpi=90)
    return {"results": results, "png": png, "circle": circle, "chain": ch, "q_home": q_home}


if __name__ == "__main__":
    main()
