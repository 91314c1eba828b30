"""A design study: the reachable tip workspace against chamber radius and segment count.

Runs the sweep ``sweeps/design_study.toml`` (the four-segment spatial arm's family: chamber
radius 5-11 mm x 2-4 segments x three pressure levels, 36 runs of 4 s, on every core; or
on a Dask cluster with ``--dask ADDRESS``) and plots what each design reaches: in every
run the pressures turn once round the chambers, so after the start's swing the tip traces
the rim of the region that pressure level reaches. Adds two metrics to the sweep's table
(a function of the trajectory, run in the workers), over the last three quarters of each
run: ``reach_lateral`` (m, the tip's largest distance from the hanging axis) and
``rim_area`` (m^2, the area the tip's path encloses seen from above).
Writes ``design_study.png``: the lateral reach against chamber radius for each segment
count and pressure level, and the tip's paths seen from above for the largest chambers;
the sweep's folder (``summary.parquet``, the trajectories) is ``<out>/sweep``; running the
example again resumes it (nothing is computed twice).

Run: ``.venv/bin/python examples/design_study.py [--quick] [--duration S] [--out DIR] [--sweep FILE]
[--workers N | --dask ADDRESS]``
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import _common
from qchain import run_sweep
from qchain.batch.sweep_spec import load_sweep

SWEEP = _common.SCENES.parent / "sweeps" / "design_study.toml"


def workspace_metrics(scene, model, traj) -> dict:
    """``reach_lateral`` (m): the tip's largest distance from the hanging axis, and
    ``rim_area`` (m^2): the area its path encloses seen from above, both over the last three
    quarters of the run (after the start's swing)."""
    tip = model.chain.frames_batch(traj.q, 2, t=traj.t).translation[:, -1]
    axis = model.chain.base_placement.translation  # the arm hangs along the world z axis through the base
    late = traj.t >= traj.t[-1] / 4
    x, y = tip[late, 0] - axis[0], tip[late, 1] - axis[1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return {"reach_lateral": float(np.max(np.hypot(x, y))), "rim_area": float(area)}


def main(argv=None) -> dict:
    p = _common.parser(__doc__, "design_study", scene_flag=False)
    p.add_argument("--sweep", type=Path, default=SWEEP, metavar="FILE",
                   help="sweep file (default: examples/sweeps/design_study.toml)")
    engine = p.add_mutually_exclusive_group()
    engine.add_argument("--workers", type=int, default=None, metavar="N", help="local worker processes (default: all)")
    engine.add_argument("--dask", default=None, metavar="ADDRESS", help="a Dask scheduler, e.g. tcp://127.0.0.1:8786")
    args = p.parse_args(argv)
    spec = load_sweep(args.sweep)
    if args.quick:  # two chamber radii, two counts, one level, a short turn
        spec.axes = [a if a.keys[0] != "segments[0].chamber_radius" else type(a)(a.key, values=(0.005, 0.011))
                     for a in spec.axes]
        spec.axes = [a if a.keys[0] != "segments[0].count" else type(a)(a.key, values=(2, 3)) for a in spec.axes]
        spec.axes = [a if len(a.keys) == 1 else type(a)(a.key, values=a.values[-1:]) for a in spec.axes]
    T = args.duration if args.duration is not None else (1.0 if args.quick else None)
    if T is not None:
        if not T > 0:
            raise SystemExit(f"--duration must be > 0 s, got {T}")
        spec.set["simulation.duration"] = T
    spec.folder = args.out / "sweep"
    spec.metrics = workspace_metrics
    for line in spec.describe():
        print(line)
    res = run_sweep(spec, workers=args.workers, client=args.dask, progress=None)
    rows = res.rows()
    sim_s = sum(r["t_end"] for r in rows if r["t_end"] == r["t_end"])
    print(f"{len(rows)} runs ({res.resumed} from an earlier run, {res.computed} computed on the {res.engine} engine, "
          f"{res.n_failed} failed) in {res.wall_s:.3g} s wall; {sim_s:.3g} s simulated")

    radii = sorted({r["segments[0].chamber_radius"] for r in rows})
    counts = sorted({r["segments[0].count"] for r in rows})
    levels = sorted({r["pressure.offset"]["each_segment"][0] for r in rows})
    reach = {}
    for r in rows:
        key = (r["segments[0].count"], r["pressure.offset"]["each_segment"][0], r["segments[0].chamber_radius"])
        reach[key] = r["reach_lateral"] if r["success"] else np.nan
    for n in counts:
        print(f"{n} segments: lateral reach (mm) at the top level {2 * levels[-1] / 1e3:.0f} kPa peak, chamber radius "
              + ", ".join(f"{rc * 1e3:g} mm: {reach[(n, levels[-1], rc)] * 1e3:.1f}" for rc in radii))

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.5))
    cmap = plt.get_cmap("viridis")
    for j, n in enumerate(counts):
        for k, lev in enumerate(levels):
            ax.plot(np.array(radii) * 1e3, [reach[(n, lev, rc)] * 1e3 for rc in radii], "o-",
                    color=cmap(j / max(1, len(counts) - 1)), alpha=0.35 + 0.65 * (k + 1) / len(levels),
                    label=f"{n} segments, peak {2 * lev / 1e3:.0f} kPa")
    ax.set_xlabel("chamber radius (mm)")
    ax.set_ylabel("lateral reach of the tip (mm)")
    ax.set_title("reach against chamber radius")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    rc = radii[-1]
    for r in rows:
        if r["segments[0].chamber_radius"] != rc or not r["success"]:
            continue
        traj = res.trajectory(r["run"])
        tip = res.tip_path(r["run"])[traj.t >= traj.t[-1] / 4]
        j = counts.index(r["segments[0].count"])
        k = levels.index(r["pressure.offset"]["each_segment"][0])
        bx.plot(tip[:, 0] * 1e3, tip[:, 1] * 1e3, color=cmap(j / max(1, len(counts) - 1)),
                alpha=0.35 + 0.65 * (k + 1) / len(levels), label=f"{r['segments[0].count']} segments" if
                k == len(levels) - 1 else None)
    bx.set_aspect("equal", adjustable="datalim")
    bx.set_xlabel("x (mm)")
    bx.set_ylabel("y (mm)")
    bx.set_title(f"tip paths from above, last 3/4 of each run (the arm swings as the pressures turn), "
                 f"chamber radius {rc * 1e3:g} mm", fontsize=9)
    bx.legend(fontsize=7)
    bx.grid(alpha=0.3)
    fig.suptitle(f"design study: {len(rows)} runs, {res.engine} engine, {res.wall_s:.3g} s wall")
    png = _common.save_figure(fig, args.out, "design_study.png", dpi=110)
    return {"result": res, "png": png, "reach": reach, "radii": radii, "counts": counts, "levels": levels}


if __name__ == "__main__":
    main()
