"""What recording costs the simulating process, a sample.

    python benchmarks/bench_recording_cost.py [--rounds 30] [--duration 20] [--scene examples/scenes/wave_arm.toml]
    python benchmarks/bench_recording_cost.py --journal   # the journal's chunk: mcap Writer vs hand-built

The three-segment example as ``qchain run`` records it (:class:`qchain.recording.recorder.ChainRecorder`
into a :class:`qchain.logging.RunLogger` writing an MCAP file through its journal and writer
process), against the same simulation with no ``on_sample`` and with an ``on_sample`` that
takes the samples as the recorder does (in batches, within its ``max_sim`` of simulated
time, with their energies) and does nothing with them. Measured: the simulating process's
CPU time (``time.process_time``: every thread of it; the writer is a process of its own)
from the start of ``simulate`` to the recorder's last batch in the journal, divided by the
samples. The three runs of a round go back to back in a rotating order; each figure is the
median over rounds with a bootstrap 95 % confidence interval of the median
(``scipy.stats.bootstrap``).

Printed per sample:

``total``      what recording costs the simulating process: record run - bare run (the
               issue's target: <= 10 us);
``hand-over``  the engine's part: no-op run - bare run (shorter compiled stretches, the
               samples' energies);
``recorder``   the recorder's own part: record run - no-op run (the frames of a batch,
               packing rows, the journal write);
``contacts``   a scene with obstacles only (``--scene examples/scenes/arm_on_ground.toml``):
               what recording its contacts costs, record run - the same run recorded as a
               scene without obstacles is (a fourth run a round: no contact channel, no
               ``Chain.contacts`` a sample).

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

from qchain.cli import main as cli  # noqa: E402
from qchain.logging import RunLogger, prepare_writer  # noqa: E402
from qchain.scene import load_scene  # noqa: E402


def _median_ci(x: np.ndarray) -> tuple[float, float, float]:
    x = np.asarray(x, dtype=float)
    res = bootstrap((x,), np.median, confidence_level=0.95, n_resamples=5000, method="percentile",
                    random_state=np.random.default_rng(0))
    return float(np.median(x)), float(res.confidence_interval.low), float(res.confidence_interval.high)


def journal_paths(rounds: int, folder: Path, batch: int = 20, width: int = 168) -> None:
    """A journal batch (``batch`` rows of ``width`` float64, the wave arm's record) appended
    as a chunk of its own: through the mcap library's ``Writer`` (``add_message`` and
    ``flush``) against the record built by :func:`qchain.recording.journal.chunk_record`,
    the same bytes, each written and flushed to a file; us a batch."""
    from mcap.writer import CompressionType, IndexType, Writer

    from qchain.recording.journal import chunk_record

    rows = np.random.default_rng(0).normal(size=(batch, width))
    n = 2000
    costs = {"mcap Writer": [], "hand-built": []}
    for rnd in range(rounds + 1):
        with open(folder / "w.journal", "wb") as fh:
            w = Writer(fh, chunk_size=1 << 40, compression=CompressionType.NONE, index_types=IndexType.NONE,
                       use_statistics=False, use_summary_offsets=False)
            w.start(profile="", library="bench")
            ch = w.register_channel("/rows", "x", w.register_schema("s", "", b""), {})
            c0 = time.process_time()
            for k in range(n):
                w.add_message(ch, k, rows.tobytes(), k, k)
                w.flush()
            writer = time.process_time() - c0
        with open(folder / "h.journal", "wb") as fh:
            c0 = time.process_time()
            for k in range(n):
                fh.write(chunk_record(ch, k, k, k, rows))
                fh.flush()
            hand = time.process_time() - c0
        if rnd:
            costs["mcap Writer"].append(writer / n)
            costs["hand-built"].append(hand / n)
    print(f"journal chunk of {batch} rows x {width} float64, written and flushed; {rounds} rounds of {n}")
    print(f"{'':<14}{'median us':>10}  {'95 % CI':>16}")
    for name, x in costs.items():
        m, lo, hi = _median_ci(np.array(x) * 1e6)
        print(f"{name:<14}{m:>10.2f}  {lo:>7.2f} .. {hi:<7.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds a run")
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "scenes" / "wave_arm.toml")
    ap.add_argument("--journal", action="store_true", help="time the journal's chunk paths only")
    args = ap.parse_args(argv)
    if args.journal:
        journal_paths(args.rounds, Path(tempfile.mkdtemp(prefix="qchain-bench-")))
        return 0
    scene = load_scene(args.scene)
    model = scene.build()
    from qchain.cli import recording as qlog
    from qchain.recording.records import DEFAULT_FLUSH_INTERVAL
    folder = Path(tempfile.mkdtemp(prefix="qchain-bench-"))

    class NoOp:
        """Takes the samples as the recorder does (:meth:`record_batch`) and drops them."""

        max_sim = DEFAULT_FLUSH_INTERVAL

        def __call__(self, t, q, v, p, energies=None):
            pass

        def record_batch(self, t, q, v, p, kinetic, potential):
            pass

    noop = NoOp()
    # warm: compiled engine, energies, frames_batch, the writer's imports
    scene.simulate(model=model, duration=1.0, on_sample=noop)
    contact = scene.environment is not None and bool(scene.environment.obstacles)
    kinds = ["off", "noop", "record"] + (["record-nc"] if contact else [])
    costs = {"open": [], "close": [], **{k: [] for k in kinds}}
    N = None
    for rnd in range(args.rounds + 1):
        order = kinds[rnd % len(kinds):] + kinds[: rnd % len(kinds)]
        for kind in order:
            if kind == "off":
                c0 = time.process_time()
                traj = scene.simulate(model=model, duration=args.duration)
                cpu = time.process_time() - c0
            elif kind == "noop":
                c0 = time.process_time()
                traj = scene.simulate(model=model, duration=args.duration, on_sample=noop)
                cpu = time.process_time() - c0
            else:
                prepare_writer()  # as qchain run does, during the model build
                time.sleep(0.5)  # (the writer's start-up is not the simulating process's)
                ns = argparse.Namespace(no_record=False, mcap=folder / f"{kind}{rnd}.mcap", serve=False, connect=None,
                                        rrd=None, bind="127.0.0.1", rerun_rate=None, realtime=False)
                c_open = time.process_time()
                with_contacts = cli._contact_recording
                if kind == "record-nc":  # recorded as a scene without obstacles is
                    cli._contact_recording = lambda chain, env: ({}, None)
                try:
                    logger, rec = cli._make_logger(ns, scene, model, duration=args.duration)
                finally:
                    cli._contact_recording = with_contacts
                c0 = time.process_time()
                with logger:
                    with rec:
                        traj = scene.simulate(model=model, duration=args.duration, on_sample=rec)
                    cpu = time.process_time() - c0
                    c_close = time.process_time()
                if kind == "record":
                    costs["open"].append(c0 - c_open)
                    costs["close"].append(time.process_time() - c_close)
                assert isinstance(logger, RunLogger) and logger.close()["n_records"] == len(traj.t)
            N = len(traj.t)
            if rnd > 0:  # the first round warms up
                costs[kind].append(cpu)
    off, noop_, rec_ = (np.array(costs[k]) for k in ("off", "noop", "record"))
    rows = [("total", (rec_ - off) / N), ("hand-over", (noop_ - off) / N), ("recorder", (rec_ - noop_) / N),
            ("bare simulation", off / N)]
    if contact:
        rows.insert(3, ("contacts", (rec_ - np.array(costs["record-nc"])) / N))
    print(f"{args.scene.name}: {args.duration:g} s simulated, {N} samples a run, {args.rounds} rounds "
          "(simulating process's CPU time a sample, us; median and bootstrap 95 % CI of the median)")
    print(f"{'':<18}{'median':>9}  {'95 % CI':>16}")
    for name, x in rows:
        m, lo, hi = _median_ci(x * 1e6)
        print(f"{name:<18}{m:>9.2f}  {lo:>7.2f} .. {hi:<7.2f}")
    for name in ("open", "close"):
        m, lo, hi = _median_ci(np.array(costs[name]) * 1e3)
        print(f"logger {name:<11}{m:>9.2f}  {lo:>7.2f} .. {hi:<7.2f} ms (once a run)")
    print("total: record - bare (target <= 10 us a sample); hand-over: no-op - bare (the engine's part); "
          "recorder: record - no-op" + ("; contacts: record - record without contacts" if contact else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
