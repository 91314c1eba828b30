"""Calibration on synthetic bags: do two standard errors cover the truth, and what a fit costs.

Each of ``--bags`` (default 20) lab-style ROS 2 bags is ``examples/calibrate.py``'s: the
hidden arm run from rest under the swept pressures for ``--duration`` s (default 1), its tip
seen at 100 Hz with 0.5 mm of noise, the pressures read at 100 Hz with ``--pressure-noise``
Pa of noise (default the example's 300), a different noise seed each. Each bag is read back
(``qchain.fit.read_bag``) and fitted from the datasheet's values (the four keys of the
example). Printed: per bag the fitted values in standard errors from the truth; per
parameter how many bags put the truth within two standard errors; the median fit cost
(wall, CPU, rollouts with sensitivities, Jacobians).

The fit's standard errors (``--covariance``, default ``inputs``) count the pressure sensor's
noise, an error in the fit's inputs: its level estimated from each bag's pressures, its effect
sampled by runs of the model under fresh noise (docs/fit.md, "Noisy pressures"); ``iid``
takes the pressures as exact, ``hac`` is Newey-West. ``--pressure-filter HZ`` low-passes the
pressures first. ``--pressure-noise 0`` measures the coverage with mocap noise alone.

Run: ``python benchmarks/bench_fit.py [--bags 20] [--duration 1] [--pressure-noise 300] [--covariance inputs]
[--pressure-filter HZ] [--out DIR]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))

import calibrate  # noqa: E402  (the example's bag and keys)


def main(argv=None) -> dict:
    from qchain.fit import FitWarning, fit, read_bag
    from qchain.fit.measurements import MeasurementWarning

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bags", type=int, default=20)
    p.add_argument("--duration", type=float, default=1.0)
    p.add_argument("--pressure-noise", type=float, default=calibrate.PRESSURE_NOISE)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--covariance", default="inputs", choices=["inputs", "iid", "hac"])
    p.add_argument("--pressure-filter", type=float, default=None, help="low-pass cutoff (Hz) of the pressures")
    args = p.parse_args(argv)
    calibrate.PRESSURE_NOISE = args.pressure_noise
    scene = calibrate._common.SCENES / "calibrate.toml"
    truth = np.array([calibrate.HIDDEN[k] for k in calibrate.KEYS])
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_fit-"))
    out.mkdir(parents=True, exist_ok=True)
    z, costs = [], []
    print(f"{args.bags} bags, {args.duration:g} s each, mocap noise {calibrate.MOCAP_NOISE * 1e3:g} mm, pressure noise "
          f"{args.pressure_noise:g} Pa; covariance {args.covariance!r}, pressure filter "
          f"{args.pressure_filter or 'none'} Hz; (fitted - truth) / standard error:")
    print(f"{'bag':>4} " + " ".join(f"{k:>28}" for k in calibrate.KEYS) + f" {'wall s':>7} {'CPU s':>6} {'nfev':>5} {'njev':>5}")
    for b in range(args.bags):
        bag = out / f"bag{b}.mcap"
        calibrate.record_lab_bag(scene, args.duration, bag, seed=100 + b)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", (FitWarning, MeasurementWarning))
            meas = read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
            t0, c0 = time.perf_counter(), time.process_time()
            res = fit(scene, [meas], calibrate.KEYS, f_scale=calibrate.MOCAP_NOISE, covariance=args.covariance,
                      pressure_filter=args.pressure_filter).result
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        z.append((res.x - truth) / res.stderr)
        costs.append((wall, cpu, res.nfev, res.njev))
        print(f"{b:4d} " + " ".join(f"{v:28.2f}" for v in z[-1]) + f" {wall:7.1f} {cpu:6.1f} {res.nfev:5d} {res.njev:5d}")
    z = np.array(z)
    within = (np.abs(z) <= 2).sum(axis=0)
    print("within 2 standard errors: " + ", ".join(f"{k} {w}/{args.bags}" for k, w in zip(calibrate.KEYS, within)))
    print(f"z RMS: {np.array2string(np.sqrt((z ** 2).mean(axis=0)), precision=2)}")
    c = np.median(np.array(costs), axis=0)
    print(f"median fit: {c[0]:.1f} s wall, {c[1]:.1f} s CPU, {c[2]:.0f} rollouts with sensitivities, {c[3]:.0f} Jacobians")
    return {"z": z, "within": within, "costs": costs}


if __name__ == "__main__":
    main()
