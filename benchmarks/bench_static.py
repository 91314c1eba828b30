"""Static cantilever: model error against the Euler elastica vs cost, n = 1..32 segments.

Scene: a horizontal cantilever under its own weight, L = 0.3 m, r = 10 mm,
rho = 1100 kg/m^3, E = 5 MPa (a 27 % tip drop); qchain with n inextensible segments
(planar), solved by ``qchain.arm.statics.equilibrium``; reference: the Euler elastica (a
Cosserat rod without shear and extension) by ``scipy.integrate.solve_bvp``
(``qchain.reference``). Error: the tip distance (m); cost: wall time of the solve (median).

Run: ``python benchmarks/bench_static.py [--quick] [--out DIR]``
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import _study
from qchain import Chain, Segment
from qchain.reference import elastica_cantilever
from qchain.arm.statics import equilibrium

L, R, E, RHO = 0.3, 0.01, 5e6, 1100.0


def cantilever(n: int) -> Chain:
    A = np.pi * R * R
    segs = [Segment(length=L / n, radius=R, mass=RHO * A * L / n, chamber_area=1e-6, chamber_radius=0.005,
                    youngs_modulus=E, extensible=False) for _ in range(n)]
    return Chain(segs, base_placement=pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3)), planar=True)


def run(quick: bool = False, out_dir: Path = Path("out/bench")) -> list[dict]:
    ref = elastica_cantilever(L, E * np.pi * R**4 / 4, RHO * np.pi * R * R * 9.81)
    rows = []
    for n in ([1, 2, 4, 8, 16] if quick else [1, 2, 4, 8, 16, 32]):
        ch = cantilever(n)
        equilibrium(ch, tol=1e-12)  # warm up
        walls = []
        for _ in range(3 if quick else 7):
            t0 = time.perf_counter()
            res = equilibrium(ch, tol=1e-12)
            walls.append(time.perf_counter() - t0)
        tip = ch.tip_placement(res.q).translation
        err = float(np.hypot(tip[0] - ref.tip[0], tip[2] - ref.tip[1]))
        rows.append(dict(n=n, wall_s=float(np.median(walls)), tip_error_m=err, iterations=res.iterations,
                         success=res.success))
        print(f"static cantilever n={n:3d}: {rows[-1]['wall_s'] * 1e3:8.2f} ms  tip error {err:.2e} m  "
              f"({res.iterations} Newton iterations)", flush=True)
    errs = np.array([r["tip_error_m"] for r in rows])
    print("observed order: " + ", ".join(f"{x:.2f}" for x in np.log2(errs[:-1] / errs[1:])))
    _study.write_csv(rows, out_dir / "static_cantilever.csv")
    plot(rows, out_dir / "static_cantilever.png")
    return rows


def plot(rows, path: Path) -> None:
    """Tip error against solve time, one point a segment count (labelled with n).

    Parameters
    ----------
    rows : list of dict or path
        The study's rows (``n``, ``wall_s`` in s, ``tip_error_m`` in m), or the CSV they were written to.
    path : path
        The PNG to write.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not isinstance(rows, list):
        rows = _study.read_csv(Path(rows))
    fig, ax = plt.subplots(figsize=(6.5, 4.8))
    ax.loglog([r["wall_s"] for r in rows], [r["tip_error_m"] for r in rows], "o-",
              label="qchain equilibrium (labels: n segments)")
    for r in rows:
        ax.annotate(f"{r['n']:g}", (r["wall_s"], r["tip_error_m"]), textcoords="offset points", xytext=(4, 4))
    ax.set_xlabel("wall time of the static solve (s)")
    ax.set_ylabel("tip error against the Euler elastica (m)")
    ax.set_title("static cantilever: error ~ 1/n^2", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    _study.save(fig, path)


def main(argv=None):
    return _study.main(__doc__, run, argv)


if __name__ == "__main__":
    main()
