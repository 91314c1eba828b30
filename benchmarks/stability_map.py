"""Stability map: integration methods (and coordinate choices) against stress scenes.

Each cell runs one scene with one method and records ``passed`` or ``failed`` with the
simulated time and the reason (the run's own message). A scene passes when the run ends
as the physics says it must (e.g. the boundary ramp must stop with a clear domain error,
never NaN) and its check holds (energy drift, momentum, quaternion norm). Output:
``stability_map.csv`` and a coloured grid ``stability_map.png``.

Run: ``python benchmarks/stability_map.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import _study
from qchain import Chain, Segment
from qchain.sim.inputs import Ramp, Sine
from qchain.sim.simulation import simulate

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)
FIXED_DT = 1e-3  # s, the step of the fixed-step methods in every scene
QUICK_ROWS = [  # --quick: fewer rows
    ("Radau", "Radau", "curvature"),
    ("RK45", "RK45", "curvature"),
    ("rk4 (dt=1ms)", "rk4", "curvature"),
    ("midpoint (dt=1ms)", "midpoint", "curvature"),
    ("RK45 / paper coords", "RK45", "paper"),
]
ROWS = [  # (label, method, coords)
    ("radau5", "radau5", "curvature"),
    ("dopri5", "dopri5", "curvature"),
    ("Radau", "Radau", "curvature"),
    ("BDF", "BDF", "curvature"),
    ("RK45", "RK45", "curvature"),
    ("DOP853", "DOP853", "curvature"),
    ("rk4 (dt=1ms)", "rk4", "curvature"),
    ("midpoint (dt=1ms)", "midpoint", "curvature"),
    ("Radau / paper coords", "Radau", "paper"),
    ("RK45 / paper coords", "RK45", "paper"),
]


@dataclass
class Cell:
    scene: str
    row: str
    passed: bool
    t_end: float
    wall: float
    reason: str


def _seg(coords, **kw):
    return Segment(**{**SEG, **kw}, coords=coords)


def _q_bent(ch, coords, ux, uy=0.0):
    q = ch.neutral()
    for j, s in enumerate(ch.segments):
        if coords == "paper":
            q[ch.q_slice(j)] = [s.length, np.arctan2(uy, ux), np.hypot(ux, uy)]
        else:
            q[ch.q_slice(j)] = [s.length, ux, uy]
    return q


def scenes(quick: bool):
    """Each scene: name -> function(method, coords, dt, wall_limit) -> (passed, t_end, reason)."""
    T_long = 2.0 if quick else 100.0
    f = 0.3 if quick else 1.0  # quick runs shorten every scene
    out = {}

    def run(ch, q0, v0, T, method, dt, wall, **kw):
        return simulate(ch, q0, v0, (0, T), method=method, dt=dt if method in ("rk4", "midpoint") else None,
                        wall_limit=wall, **kw)

    def straight(method, coords, dt, wall):
        ch = Chain([_seg(coords)], gravity=np.zeros(3))
        q0 = _q_bent(ch, coords, 6.0)
        tr = run(ch, q0, np.zeros(3), 0.1, method, dt, wall, energies=False)
        if not tr.success:
            return False, tr.t[-1], tr.message
        swung = np.min(tr.q[:, 1 if coords == "curvature" else 2]) < 0.0 if coords == "curvature" else True
        return bool(swung), tr.t[-1], "passed through the straight pose" if swung else "did not reach kappa = 0"

    out["through kappa = 0"] = straight

    for E in (1e4, 1e5, 1e6, 1e7, 1e8):
        def stiff(method, coords, dt, wall, E=E):
            ch = Chain([_seg(coords, youngs_modulus=E, damping=0.002) for _ in range(2)], gravity=(0, 0, 9.81))
            q0 = _q_bent(ch, coords, 4.0, 1.0)
            tr = run(ch, q0, np.zeros(ch.nv), 0.2 * f, method, dt, wall, energies=False)
            ok = tr.success and np.all(np.isfinite(tr.q))
            return ok, tr.t[-1], "ok" if ok else tr.message

        out[f"E = {E:.0e} Pa"] = stiff

    def drift(method, coords, dt, wall):
        ch = Chain([_seg(coords)], gravity=(0, 0, 9.81))
        q0 = _q_bent(ch, coords, 8.0, -3.0)
        v0 = np.array([0.0, 0.0, 3.0])
        tr = run(ch, q0, v0, T_long, method, dt, wall, t_eval=np.linspace(0, T_long, 101))
        if not tr.success:
            return False, tr.t[-1], tr.message
        E = tr.total_energy
        d = float(np.max(np.abs(E - E[0])) / abs(E[0]))
        return d < 1e-2, tr.t[-1], f"max energy error {d:.1e} (bound 1e-2)"

    out[f"{T_long:.0f} s undamped energy"] = drift

    def ramp(method, coords, dt, wall):
        ch = Chain([_seg(coords, damping=0.05)], gravity=np.zeros(3))
        q0 = _q_bent(ch, coords, 1.0)
        tr = run(ch, q0, np.zeros(3), f, method, dt, wall, pressure=Ramp(0.0, f, end=[3e6, 0, 0]), energies=False)
        clean = (not tr.success) and "segment 0" in tr.message and "|kappa| r_s" in tr.message and np.all(
            np.isfinite(tr.q))
        return clean, tr.t[-1], tr.message if not clean else "stopped with a domain error: " + tr.message[:60]

    out["ramp to |kappa| r_s = 1"] = ramp

    def tumble(method, coords, dt, wall):
        ch = Chain([_seg(coords) for _ in range(2)], base="floating", gravity=np.zeros(3))
        q0 = _q_bent(ch, coords, 5.0, -2.0)
        v0 = np.zeros(ch.nv)
        v0[:6] = [0.1, -0.2, 0.05, 8.0, -5.0, 6.0]
        P = Sine(np.full(6, 2e4), 2.0, np.tile([0.0, 2.1, 4.2], 2), np.full(6, 2e4))
        tr = run(ch, q0, v0, 0.5 * f, method, dt, wall, pressure=P, energies=False)
        if not tr.success:
            return False, tr.t[-1], tr.message
        h0 = ch.momentum(tr.q[0], tr.v[0])
        dh = np.linalg.norm(ch.momentum(tr.q[-1], tr.v[-1]) - h0) / np.linalg.norm(h0)
        qn = np.max(np.abs(np.linalg.norm(tr.q[:, 3:7], axis=1) - 1))
        ok = dh < 1e-3 and qn < 1e-12
        return ok, tr.t[-1], f"momentum error {dh:.1e}, |quat| - 1 <= {qn:.0e}"

    out["tumbling floating base"] = tumble

    def thirty(method, coords, dt, wall):
        ch = Chain([_seg(coords, length=0.03, mass=0.015, damping=0.01) for _ in range(30)], gravity=(0, 0, 9.81))
        q0 = _q_bent(ch, coords, 1.0, 0.5)
        P = Sine(np.full(90, 1e4), 1.0, np.tile([0.0, 2.1, 4.2], 30), np.full(90, 1e4))
        tr = run(ch, q0, np.zeros(ch.nv), 0.2 * f, method, dt, wall, pressure=P, energies=False)
        return tr.success, tr.t[-1], "ok" if tr.success else tr.message

    out["30 segments"] = thirty
    out.update(contact_scenes(run, f))
    return out


def _lying(coords, n=2, **kw):
    """A floating arm of ``n`` segments lying along the world x axis, its centre ``height`` (m)
    above the ground (the segments grow along the base's z axis: turned by -90 degrees about y)."""
    import pinocchio as pin

    height = kw.pop("height", 0.015)
    tilt = kw.pop("tilt", 0.0)
    ch = Chain([_seg(coords, damping=0.01) for _ in range(n)], base="floating", **kw)
    q0 = _q_bent(ch, coords, 0.5)  # nearly straight (the paper's coordinates are singular at straight)
    R = pin.rpy.rpyToMatrix(0.0, np.pi / 2 + tilt, 0.0)
    q0[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, np.array([-0.1, 0.0, height])))
    return ch, q0


def contact_scenes(run, f):
    """The contact columns: stiff ground, high friction on a slope, grazing contact, a fast
    impact; each checks what the physics says must happen, never only that the run ended."""
    from qchain.contact import ContactLaw, Environment, HalfSpace

    out = {}
    r_s = SEG["radius"]

    def deepest(ch, tr, env):
        return max((ch.contacts(q, v, env, t).penetration.max(initial=0.0) for t, q, v in zip(tr.t, tr.q, tr.v)),
                   default=0.0)

    def stiff_ground(method, coords, dt, wall):
        ch, q0 = _lying(coords, height=0.03)
        env = Environment([HalfSpace()], ContactLaw(stiffness=1e8, damping=5.0, mu_static=0.3, mu_dynamic=0.3))
        tr = run(ch, q0, np.zeros(ch.nv), 0.3 * f, method, dt, wall, env=env, energies=False,
                 t_eval=np.linspace(0, 0.3 * f, 61))
        if not tr.success:
            return False, tr.t[-1], tr.message
        d = deepest(ch, tr, env)
        return d < 0.1 * r_s, tr.t[-1], f"deepest penetration {d * 1e3:.3f} mm (bound {0.1 * r_s * 1e3:.1f} mm)"

    out["contact: stiff ground"] = stiff_ground

    def high_friction(method, coords, dt, wall):
        theta = np.pi / 4  # tan(theta) = 1 < mu = 2: the arm must stay
        import pinocchio as pin

        ch, q0 = _lying(coords, height=0.0149)
        g = 9.81 * np.array([np.sin(theta), 0.0, -np.cos(theta)])  # the slope as a tilted gravity
        ch = Chain(ch.segments, base="floating", gravity=g)
        env = Environment([HalfSpace()], ContactLaw(stiffness=1e5, damping=5.0, mu_static=2.0, mu_dynamic=2.0))
        T = 0.5 * f
        tr = run(ch, q0, np.zeros(ch.nv), T, method, dt, wall, env=env, energies=False, t_eval=[0.1 * T, T])
        if not tr.success:
            return False, tr.t[-1], tr.message
        slid = abs(tr.q[-1, 0] - tr.q[0, 0])
        return slid < 1e-3, tr.t[-1], f"slid {slid * 1e3:.3f} mm after settling (bound 1 mm: sticks)"

    out["contact: high friction"] = high_friction

    def grazing(method, coords, dt, wall):
        ch, q0 = _lying(coords, height=r_s + 2e-4, gravity=np.zeros(3))
        v0 = np.zeros(ch.nv)
        v0[:3] = [0.0, 0.0, 0.3]  # base frame: along the arm's axis, which lies along the ground
        v0[3:6] = [0.0, 0.5, 0.0]
        env = Environment([HalfSpace()], ContactLaw(stiffness=1e6, damping=1.0, mu_static=0.5, mu_dynamic=0.4))
        tr = run(ch, q0, v0, 0.3 * f, method, dt, wall, env=env, energies=False)
        ok = tr.success and np.all(np.isfinite(tr.q))
        return ok, tr.t[-1], "ok" if ok else tr.message

    out["contact: grazing"] = grazing

    def impact(method, coords, dt, wall):
        ch, q0 = _lying(coords, height=0.02, gravity=np.zeros(3))
        v0 = np.zeros(ch.nv)
        v0[0] = 5.0  # base-frame x is world -z once turned: 5 m/s down
        env = Environment([HalfSpace()], ContactLaw(stiffness=1e7, damping=0.05))
        tr = run(ch, q0, v0, 0.02, method, dt, wall, env=env, energies=False, t_eval=np.linspace(0, 0.02, 81))
        if not tr.success:
            return False, tr.t[-1], tr.message
        d = deepest(ch, tr, env)
        up = ch.centers_of_mass(tr.q[-1]).mean(axis=0)[2] > ch.centers_of_mass(tr.q[40]).mean(axis=0)[2]
        ok = d < r_s and up
        return ok, tr.t[-1], f"deepest {d * 1e3:.2f} mm (bound r_s), {'rebounds' if up else 'no rebound'}"

    out["contact: fast impact"] = impact
    return out


def run(quick: bool = False, out_dir: Path = Path("out/bench"), wall: float | None = None, rows=None) -> list[Cell]:
    wall = wall if wall is not None else (10.0 if quick else 120.0)
    cells = []
    for name, scene in scenes(quick).items():
        for label, method, coords in rows or (QUICK_ROWS if quick else ROWS):
            t0 = time.perf_counter()
            try:
                ok, t_end, reason = scene(method, coords, FIXED_DT, wall)
            except Exception as err:  # a crash is recorded as such: the map must show it
                ok, t_end, reason = False, float("nan"), f"CRASH {type(err).__name__}: {err}"
            cells.append(Cell(name, label, bool(ok), float(t_end), time.perf_counter() - t0, reason))
            print(f"{name:>26} | {label:>22} | {'passed' if ok else 'FAILED':>6} | t_end {t_end:8.4f} s | "
                  f"wall {cells[-1].wall:6.2f} s | {reason[:90]}", flush=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "stability_map.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["scene", "method", "passed", "t_end_s", "wall_s", "reason"])
        for c in cells:
            w.writerow([c.scene, c.row, c.passed, f"{c.t_end:.6g}", f"{c.wall:.3f}", c.reason])
    plot(cells, out_dir / "stability_map.png")
    return cells


def plot(cells: list[Cell], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes_ = list(dict.fromkeys(c.scene for c in cells))
    rows = list(dict.fromkeys(c.row for c in cells))
    grid = np.zeros((len(rows), len(scenes_)))
    fig, ax = plt.subplots(figsize=(1.15 * len(scenes_) + 2.5, 0.5 * len(rows) + 1.8))
    for c in cells:
        i, j = rows.index(c.row), scenes_.index(c.scene)
        grid[i, j] = 1.0 if c.passed else 0.0
        txt = f"{c.wall:.1f} s" if c.passed else f"fail\nt={c.t_end:.3g} s"
        ax.text(j, i, txt, ha="center", va="center", fontsize=8)
    ax.imshow(grid, cmap=matplotlib.colors.ListedColormap(["#e8847c", "#8cd08c"]), vmin=0, vmax=1, aspect="auto")
    ax.set_xticks(range(len(scenes_)), scenes_, rotation=35, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), rows, fontsize=8)
    ax.set_title("stability map: green passed (wall time), red failed (sim time reached)", fontsize=10)
    _study.save(fig, path)


def replot(csv_path: Path, png_path: Path) -> None:
    """Redraw ``stability_map.png`` from a written ``stability_map.csv`` (no runs)."""
    with open(csv_path, newline="") as fh:
        cells = [Cell(r["scene"], r["method"], r["passed"] == "True", float(r["t_end_s"]), float(r["wall_s"]),
                      r["reason"]) for r in csv.DictReader(fh)]
    plot(cells, png_path)


def main(argv=None):
    cells = _study.main(__doc__, run, argv)
    print(f"{sum(c.passed for c in cells)} of {len(cells)} cells passed")


if __name__ == "__main__":
    main()
