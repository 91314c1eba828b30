"""What recording costs the simulating process, a sample.

    python benchmarks/bench_recording_cost.py [--rounds 30] [--duration 20] [--scene examples/scenes/wave_arm.toml]

The three-segment example as ``qchain run`` records it (:class:`qchain.recorder.ChainRecorder`
into a :class:`qchain.logging.RunLogger` writing an MCAP file through its journal and writer
process), against the same simulation with no ``on_sample`` and with an ``on_sample`` that
does nothing (but takes the samples' energies, as the recorder does). Measured: the
simulating process's CPU time (``time.process_time``: every thread of it; the writer is a
process of its own) from the start of ``simulate`` to the recorder's last batch in the
journal, divided by the samples. The three runs of a round go back to back in a rotating
order; each figure is the median over rounds with a bootstrap 95 % confidence interval of
the median (``scipy.stats.bootstrap``).

Printed per sample:

``recorder``   recording's own cost: record run - no-op run (copying the sample, the frames
               of a batch, packing rows, the journal write);
``hand-over``  the engine's cost of handing samples over at all: no-op run - bare run (it
               leaves compiled code at every sample and computes its energies);
``total``      record run - bare run;
``recorder, batch``  the recorder given the run's samples as arrays
               (:meth:`~qchain.recorder.ChainRecorder.record_batch`, as an engine that handed
               its samples over in batches would give them): its own CPU time / samples.

The logger's fixed costs (constructor, close: waiting for the writer to finish the file) are
printed apart: they do not grow with the run.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import bootstrap

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from qchain import cli  # noqa: E402
from qchain.logging import RunLogger, prepare_writer  # noqa: E402
from qchain.scene import load_scene  # noqa: E402


def _median_ci(x: np.ndarray) -> tuple[float, float, float]:
    x = np.asarray(x, dtype=float)
    res = bootstrap((x,), np.median, confidence_level=0.95, n_resamples=5000, method="percentile",
                    random_state=np.random.default_rng(0))
    return float(np.median(x)), float(res.confidence_interval.low), float(res.confidence_interval.high)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds a run")
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "scenes" / "wave_arm.toml")
    args = ap.parse_args(argv)
    scene = load_scene(args.scene)
    model = scene.build()
    qlog = cli._logging_module()
    folder = Path(tempfile.mkdtemp(prefix="qchain-bench-"))

    def noop(t, q, v, p, energies=None):
        pass

    # warm: compiled engine, energies, frames_batch, the writer's imports
    scene.simulate(model=model, duration=1.0, on_sample=noop)
    costs = {"off": [], "noop": [], "record": [], "batch": [], "open": [], "close": []}
    N = None
    for rnd in range(args.rounds + 1):
        order = ["off", "noop", "record", "batch"]
        order = order[rnd % 4:] + order[: rnd % 4]
        for kind in order:
            if kind == "off":
                c0 = time.process_time()
                traj = scene.simulate(model=model, duration=args.duration)
                cpu = time.process_time() - c0
            elif kind == "noop":
                c0 = time.process_time()
                traj = scene.simulate(model=model, duration=args.duration, on_sample=noop)
                cpu = time.process_time() - c0
            elif kind == "batch":
                traj = scene.simulate(model=model, duration=args.duration)
                T, Q, V, P, KE, PE = (np.ascontiguousarray(x) for x in (traj.t, traj.q, traj.v, traj.p,
                                                                          traj.kinetic_energy, traj.potential_energy))
                prepare_writer()
                time.sleep(0.5)
                ns = argparse.Namespace(no_record=False, mcap=folder / f"b{rnd}.mcap", serve=False, connect=None,
                                        rrd=None, bind="127.0.0.1", rerun_rate=None, realtime=False)
                logger, rec = cli._make_logger(qlog, ns, scene, model, duration=args.duration)
                with logger:
                    c0 = time.process_time()
                    rec.record_batch(T, Q, V, P, KE, PE)
                    cpu = time.process_time() - c0
            else:
                prepare_writer()  # as qchain run does, during the model build
                time.sleep(0.5)  # (the writer's start-up is not the simulating process's)
                ns = argparse.Namespace(no_record=False, mcap=folder / f"r{rnd}.mcap", serve=False, connect=None,
                                        rrd=None, bind="127.0.0.1", rerun_rate=None, realtime=False)
                c_open = time.process_time()
                logger, rec = cli._make_logger(qlog, ns, scene, model, duration=args.duration)
                c0 = time.process_time()
                with logger:
                    with rec:
                        traj = scene.simulate(model=model, duration=args.duration, on_sample=rec)
                    cpu = time.process_time() - c0
                    c_close = time.process_time()
                costs["open"].append(c0 - c_open)
                costs["close"].append(time.process_time() - c_close)
                assert isinstance(logger, RunLogger) and logger.close()["n_records"] == len(traj.t)
            N = len(traj.t)
            if rnd > 0:  # the first round warms up
                costs[kind].append(cpu)
    off, noop_, rec_, batch = (np.array(costs[k]) for k in ("off", "noop", "record", "batch"))
    rows = [("recorder", (rec_ - noop_) / N), ("hand-over", (noop_ - off) / N), ("total", (rec_ - off) / N),
            ("recorder, batch", batch / N), ("bare simulation", off / N)]
    print(f"{args.scene.name}: {args.duration:g} s simulated, {N} samples a run, {args.rounds} rounds "
          "(simulating process's CPU time a sample, us; median and bootstrap 95 % CI of the median)")
    print(f"{'':<18}{'median':>9}  {'95 % CI':>16}")
    for name, x in rows:
        m, lo, hi = _median_ci(x * 1e6)
        print(f"{name:<18}{m:>9.2f}  {lo:>7.2f} .. {hi:<7.2f}")
    for name in ("open", "close"):
        m, lo, hi = _median_ci(np.array(costs[name]) * 1e3)
        print(f"logger {name:<11}{m:>9.2f}  {lo:>7.2f} .. {hi:<7.2f} ms (once a run)")
    print("recorder: record - no-op on_sample; hand-over: no-op - no on_sample (the engine's part); "
          "target: recorder <= 10 us a sample")
    return 0


if __name__ == "__main__":
    sys.exit(main())
