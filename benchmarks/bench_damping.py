"""Cost of each damping law per simulated second on the compiled engine.

The same arm (2 and 4 segments, fixed base, curvature coordinates, the chambers waving at
2 Hz from rest, gravity), 1 s, radau5 at rtol 1e-3 (the default method and a typical
tolerance), with each law in turn:

* ``none``: no damping;
* ``stiffness``: stiffness-proportional, ``damping = beta`` (``D = beta K(q0)``), the reference;
* ``matrix=beta K``: the same ``D`` given as a ``damping_matrix`` (the law's own cost: the
  same dynamics, so the same steps);
* ``matrix rate law``: a per-coordinate ``damping_matrix`` with its own axial and bending
  coefficients (a strain-rate law ``diag(beta_a EA / l0, beta_b EI l0, beta_b EI l0)``,
  ``beta_a = beta / 2``, ``beta_b = 2 beta``: other dynamics);
* ``drag linear``, ``drag quadratic``: the drag of a still medium on the backbone
  (``drag_linear = c_1``, ``drag_quadratic = c_2``, docs/model.md section 9) alone, and
  ``+stiffness`` beside the stiffness-proportional damping (the material's damping and the
  medium's: the internal modes damped as in the reference).

Each run's CPU time (``time.process_time``: the machine is shared), the laws interleaved in
each repeat, after a warm-up run of each (compiling or loading the engine); printed: the
median ms of CPU per simulated second, the quartiles, the ratio of the medians to the
stiffness-proportional law's, the CPU per right-hand side (the run's CPU over its ``nfev``,
Jacobians and factorisations included) and its ratio, the engine (``meta["engine"]``),
right-hand sides, Jacobians and steps. A law that leaves the arm's fast internal modes
undamped (``none``, drag alone) costs more per simulated second by its steps, not by its
evaluations.

Run: ``python benchmarks/bench_damping.py [--quick] [--repeats 9] [--out out/bench]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import _study
from qchain import Chain, Segment, simulate
from qchain.sim.inputs import Sine

SEGMENT = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)
BETA = 0.01  # s
_EA = SEGMENT["youngs_modulus"] * np.pi * SEGMENT["radius"] ** 2
_EI = SEGMENT["youngs_modulus"] * np.pi * SEGMENT["radius"] ** 4 / 4
L0 = SEGMENT["length"]

#: the laws, as Segment keywords
LAWS = {
    "none": {},
    "stiffness": dict(damping=BETA),
    "matrix=beta K": dict(damping_matrix=BETA * np.diag([_EA / L0, _EI * L0, _EI * L0])),
    "matrix rate law": dict(damping_matrix=np.diag([0.5 * BETA * _EA / L0, 2 * BETA * _EI * L0, 2 * BETA * _EI * L0])),
    "drag linear": dict(drag_linear=2.0),  # N s/m^2
    "drag quadratic": dict(drag_quadratic=24.0),  # kg/m^2: water on a 3 cm arm, C_d = 1.6
    "drag linear+stiffness": dict(drag_linear=2.0, damping=BETA),
    "drag quadratic+stiffness": dict(drag_quadratic=24.0, damping=BETA),
}


def arm(n: int, law: str) -> Chain:
    return Chain([Segment(**SEGMENT, **LAWS[law]) for _ in range(n)])


def pressure(ch: Chain) -> Sine:
    return Sine(amplitude=np.full(ch.nu, 2e4), frequency=2.0, phase=np.tile([0.0, 2.1, 4.2], ch.n),
                offset=np.full(ch.nu, 2e4))


def one_run(ch: Chain, duration: float):
    t0 = time.process_time()
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, duration), pressure=pressure(ch), method="radau5",
                  rtol=1e-3, atol=1e-6, t_eval=np.linspace(0.0, duration, 11), energies=False)
    cpu = time.process_time() - t0
    assert tr.success, tr.message
    return cpu, tr


def run(quick: bool, out: Path, repeats: int = 9, sizes=(2, 4)) -> list[dict]:
    duration = 0.25 if quick else 1.0
    repeats = 3 if quick else repeats
    rows = []
    for n in sizes:
        chains = {law: arm(n, law) for law in LAWS}
        runs = {law: one_run(ch, duration)[1] for law, ch in chains.items()}  # warm-up: compile or load
        cpu = {law: [] for law in LAWS}
        for _ in range(repeats):
            for law, ch in chains.items():  # interleaved: the machine's load falls on every law alike
                cpu[law].append(one_run(ch, duration)[0] / duration)
        ref = float(np.median(cpu["stiffness"]))
        ref_eval = ref / runs["stiffness"].nfev
        for law in LAWS:
            c = np.array(cpu[law]) * 1e3
            tr = runs[law]
            per_eval = float(np.median(cpu[law])) * duration / tr.nfev  # s per right-hand side
            rows.append(dict(n=n, law=law, ms_per_sim_s=float(np.median(c)), q1=float(np.percentile(c, 25)),
                             q3=float(np.percentile(c, 75)), ratio=float(np.median(cpu[law])) / ref,
                             us_per_eval=per_eval * 1e6, eval_ratio=per_eval / (ref_eval * duration),
                             engine=tr.meta["engine"], nfev=tr.nfev, njev=tr.meta["njev"], nsteps=tr.meta["nsteps"]))
    print(f"radau5 rtol 1e-3, {duration:g} s simulated, CPU time, median of {repeats} (interleaved)")
    print(f"{'n':>2} {'law':<25} {'ms/sim s':>9} {'quartiles':>15} {'ratio':>6} {'us/eval':>8} {'ratio':>6} "
          f"{'engine':>9} {'nfev':>6} {'njev':>5} {'steps':>6}")
    for r in rows:
        print(f"{r['n']:>2} {r['law']:<25} {r['ms_per_sim_s']:>9.2f} {r['q1']:>7.2f}-{r['q3']:<7.2f} "
              f"{r['ratio']:>6.2f} {r['us_per_eval']:>8.2f} {r['eval_ratio']:>6.2f} {r['engine']:>9} {r['nfev']:>6} "
              f"{r['njev']:>5} {r['nsteps']:>6}")
    _study.write_csv(rows, out / "damping.csv")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="0.25 s runs, 3 repeats")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV file")
    args = ap.parse_args()
    run(args.quick, args.out, args.repeats)
