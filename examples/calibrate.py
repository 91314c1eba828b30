"""Calibrate an arm's model from a ROS 2 bag of its motion: moduli, damping and chamber area.

The "real" arm is the datasheet model of ``scenes/calibrate.toml`` with other values (the
hidden parameters: first segment's modulus 1.25e5 Pa, the others' 0.85e5 Pa, damping 0.035 s,
chamber area 5.0e-5 m^2). It starts at rest and is driven for 3 s by pressures that sweep
each chamber in turn; a motion-capture system sees its tip at 100 Hz with 0.5 mm of noise
and a pressure sensor reads the chambers at 100 Hz with 300 Pa of noise, both stamped on the
lab's clock. The recording is a ROS 2 bag (``geometry_msgs/PoseStamped`` on ``/mocap/tip``,
``sensor_msgs/JointState`` on ``/pressures``), written with qchain's ``BagWriter``.

The fit reads the bag (``qchain.fit.read_bag``), starts from the datasheet's values and fits
four scene keys with the exact trajectory sensitivities (``qchain.fit.fit``); it prints the
fitted values with their standard errors against the hidden ones (the fit's default
standard errors count the pressure sensor's noise, its level estimated from the bag's
pressures and its effect sampled by runs of the fitted model: docs/fit.md, "Noisy
pressures"), writes the fitted scene
and draws the tip measured, as the datasheet model moves and as the fitted model moves,
with the residuals (``out/calibrate/calibrate.png``).

The same fit as a fit file for the command line: ``qchain fit examples/fit/calibrate-fit.toml``
(after this example, from the repository's root: it reads ``out/calibrate/lab_run.mcap``).
"""

from __future__ import annotations

import sys
import time
import tomllib
from pathlib import Path

import _common
import numpy as np

KEYS = ["segments[0].youngs_modulus", "segments[1].youngs_modulus", "segments[*].damping",
        "segments[*].chamber_area"]
HIDDEN = {"segments[0].youngs_modulus": 1.25e5, "segments[1].youngs_modulus": 0.85e5, "segments[*].damping": 0.035,
          "segments[*].chamber_area": 5.0e-5}
MOCAP_NOISE = 5e-4  # m, each axis
PRESSURE_NOISE = 300.0  # Pa
RATE = 100.0  # Hz, both streams
EPOCH = 1_764_900_000.0  # s: the lab's clock at the start


def pressures(t: np.ndarray) -> np.ndarray:
    """(K, 9) Pa: each segment's three chambers swept in turn (0.8 Hz, phases 120 deg apart,
    the segments' sweeps 45 deg apart), over a common 10 kPa."""
    p = np.empty((t.size, 9))
    for j in range(3):
        for c in range(3):
            p[:, 3 * j + c] = 1e4 + 2e4 * np.sin(2 * np.pi * 0.8 * t - 2 * np.pi * c / 3 - np.pi / 4 * j) ** 2
    return p


def model_of(path: Path, values: dict | None = None):
    """The chain of the scene file ``path`` with ``values`` ({scene key: value}) put in."""
    import tomli_w

    from qchain.batch.sweep_spec import apply_values
    from qchain.scene.reading import parse_scene

    raw = tomllib.loads(path.read_text())
    return parse_scene(tomli_w.dumps(apply_values(raw, values or {})), path).build(reduce=False).chain


def run_from_rest(chain, table, t_eval):
    """The arm at rest under the first pressures, then driven by ``table``: tip (K, 3) m."""
    from qchain import equilibrium, simulate

    q0 = equilibrium(chain, table(0.0)).q
    traj = simulate(chain, q0, np.zeros(chain.nv), (0.0, float(t_eval[-1])), pressure=table, method="dopri5",
                    rtol=1e-9, atol=1e-11, t_eval=t_eval)
    return np.array([chain.points(q, [(-1, 1.0)])[0] for q in traj.q])


def record_lab_bag(scene: Path, duration: float, path: Path, seed: int = 7) -> None:
    """The "real" arm's run, as the lab's recorder would write it."""
    from qchain.recording.ros2 import BagWriter, stamp
    from qchain.sim.inputs import Table

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration + 1e-9, 1.0 / RATE)
    p_true = pressures(t)
    tip = run_from_rest(model_of(scene, HIDDEN), Table(t, p_true), t + 0.004)  # mocap frames 4 ms after
    tip += MOCAP_NOISE * rng.normal(size=tip.shape)
    p_read = p_true + PRESSURE_NOISE * rng.normal(size=p_true.shape)
    names = [f"segment{j + 1}/chamber{c + 1}" for j in range(3) for c in range(3)]
    with open(path, "wb") as fh:
        w = BagWriter(fh)
        for k, tk in enumerate(t):
            w.write("/pressures", "sensor_msgs/msg/JointState", EPOCH + tk,
                    {"header": {"stamp": stamp(EPOCH + tk)}, "name": names, "effort": p_read[k].tolist()})
            w.write("/mocap/tip", "geometry_msgs/msg/PoseStamped", EPOCH + tk + 0.004,
                    {"header": {"stamp": stamp(EPOCH + tk + 0.004), "frame_id": "world"},
                     "pose": {"position": dict(zip("xyz", tip[k].tolist())), "orientation": {"w": 1.0}}})
        w.finish()


def main(argv=None) -> dict:
    import matplotlib.pyplot as plt

    from qchain.fit import fit, read_bag

    args = _common.parser(__doc__, "calibrate").parse_args(argv)
    duration = args.duration or (1.0 if args.quick else 3.0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "lab_run.mcap"
    record_lab_bag(args.scene, duration, bag)
    meas = read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
    print(f"read {bag}: {meas.n_samples} tip samples, pressures {meas.pressures.values.shape} over "
          f"{meas.duration:.2f} s")

    t0, c0 = time.perf_counter(), time.process_time()
    rep = fit(args.scene, [meas], KEYS, f_scale=MOCAP_NOISE)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    res = rep.result
    print("\n".join(res.table()))
    print(f"hidden: {', '.join(f'{k} = {v:g}' for k, v in HIDDEN.items())}")
    z = (res.x - np.array([HIDDEN[k] for k in KEYS])) / res.stderr
    print(f"fitted - hidden, in standard errors: {np.array2string(z, precision=2)}; residual RMS "
          f"{np.sqrt(np.mean(res.residuals ** 2)) * 1e3:.3f} mm (mocap noise {MOCAP_NOISE * 1e3:g} mm)")
    print(f"fit: {res.nfev} rollouts with sensitivities ({res.njev} Jacobians), {wall:.1f} s wall, {cpu:.1f} s CPU")
    fitted = rep.write_scene(out / "calibrate-fitted.toml")
    print(f"wrote {fitted}")

    # cost of one gradient against one plain rollout of the fitted model (the gradient's dopri5
    # run chooses its steps with a plain run first, counted in)
    from qchain import equilibrium, simulate
    from qchain.sim.sensitivity import sensitivities

    chain = model_of(fitted)
    q0 = equilibrium(chain, meas.pressures(0.0)).q
    v0 = np.zeros(chain.nv)
    span = (0.0, meas.duration)
    sens_params = [("youngs_modulus", 0), ("youngs_modulus", 1), ("youngs_modulus", 2)] + \
        [(k, j) for k in ("damping", "chamber_area") for j in range(3)]
    timings = {}
    for name, call in (("rollout", lambda: simulate(chain, q0, v0, span, pressure=meas.pressures, method="dopri5",
                                                    rtol=1e-7, atol=1e-9)),
                       ("gradient", lambda: sensitivities(chain, q0, v0, span, params=sens_params,
                                                          pressure=meas.pressures, rtol=1e-7, atol=1e-9))):
        call()
        ts = []
        for _ in range(3):
            c = time.process_time()
            call()
            ts.append(time.process_time() - c)
        timings[name] = float(np.median(ts))
    print(f"one rollout {timings['rollout'] * 1e3:.1f} ms CPU, with the sensitivities of {len(sens_params)} parameters "
          f"and the initial state {timings['gradient'] * 1e3:.1f} ms ({timings['gradient'] / timings['rollout']:.1f}x)")

    # before and after: the datasheet model and the fitted one, driven by the measured pressures
    t = meas.t
    before = run_from_rest(model_of(args.scene), meas.pressures, t)
    after = run_from_rest(chain, meas.pressures, t)
    measured = meas.points[:, 0]
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    for i, ax in enumerate(axes[:3]):
        ax.plot(t, measured[:, i] * 1e3, ".", ms=2, color="0.4", label="measured (mocap)")
        ax.plot(t, before[:, i] * 1e3, color="C3", lw=1.2, label="datasheet model")
        ax.plot(t, after[:, i] * 1e3, color="C0", lw=1.2, label="fitted model")
        ax.set_ylabel(f"tip {'xyz'[i]} (mm)")
    axes[0].legend(loc="upper right", fontsize=8)
    err_b = np.linalg.norm(before - measured, axis=1) * 1e3
    err_a = np.linalg.norm(after - measured, axis=1) * 1e3
    axes[3].plot(t, err_b, color="C3", lw=1, label=f"datasheet (RMS {np.sqrt(np.mean(err_b ** 2)):.2f} mm)")
    axes[3].plot(t, err_a, color="C0", lw=1, label=f"fitted (RMS {np.sqrt(np.mean(err_a ** 2)):.2f} mm)")
    axes[3].set_ylabel("tip error (mm)")
    axes[3].set_xlabel("t (s)")
    axes[3].legend(loc="upper right", fontsize=8)
    fig.suptitle("Calibration from a ROS 2 bag: tip measured, before and after the fit")
    png = _common.save_figure(fig, out, "calibrate.png", dpi=80)
    print(f"tip error RMS: datasheet {np.sqrt(np.mean(err_b ** 2)):.2f} mm, fitted {np.sqrt(np.mean(err_a ** 2)):.2f} mm")
    return {"report": rep, "z": z, "png": png, "rms_before": float(np.sqrt(np.mean(err_b ** 2))),
            "rms_after": float(np.sqrt(np.mean(err_a ** 2))), "timings": timings, "fitted": fitted, "bag": bag,
            "wall": wall}


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
