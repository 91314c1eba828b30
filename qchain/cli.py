"""The ``qchain`` command: run a scene file, describe the model it builds, replay a recording.

::

    qchain run SCENE.toml [--duration S] [--out DIR] [--full] [--no-plots] [--no-record]
                          [--progress | --no-progress] [--mcap OUT] [--serve | --connect URL] [--rrd OUT]
    qchain info SCENE.toml [--full]
    qchain replay LOG.mcap [--serve | --connect URL | --rrd OUT]
    qchain sweep SWEEP.toml [--workers N | --dask ADDRESS] [--out DIR] [--restart] [--dry-run] (qchain.sweeps)
    qchain recover LOG.mcap
    qchain layout LOG.mcap [-o layout.json]

``run`` builds the scene's model (:meth:`qchain.scene.Scene.build`), integrates it,
writes the plots and ``trajectory.npz`` the scene's ``[output]`` asks for, and prints a
summary: the final tip pose (position in mm, orientation as roll-pitch-yaw in degrees and
as a quaternion), the energies, the wall time, the real-time factor (simulated seconds per
wall-clock second), the number of dynamics evaluations and how the run ended. A progress
bar goes to stderr for runs longer than a second of wall time when stderr is a terminal
(``--progress`` forces it). Every output sample is recorded to an MCAP file (``--no-record``
turns that off) and can be streamed to Rerun; the output paths are checked before the model
is built, and a recording that cannot be written stops the run with an error (never a run
without its recording). ``recover`` makes the recording of a killed run whole from its
journal; ``layout`` writes a recording's Foxglove layout.

Exit codes: 0 success, 1 the run failed (domain exit, solver failure, interruption, a
recording that could not be written), 2 a bad scene file or bad usage (an output path that
cannot be used included).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from .errors import QchainError
from .scene import Scene, SceneError, SceneModel, load_scene

__all__ = ["main", "write_outputs", "tip_positions", "summary_lines"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def _logging_module():
    """:mod:`qchain.logging`, or None where it (or what it needs) is not installed."""
    try:
        from . import logging as qlog
    except ImportError:
        return None
    return qlog


# --------------------------------------------------------------------------------------
# outputs


def tip_positions(model: SceneModel, traj) -> np.ndarray:
    """World tip positions (N, 3) m of a trajectory."""
    ch = model.chain
    return np.array([ch.tip_placement(q, t=t).translation for t, q in zip(traj.t, traj.q)])


def write_outputs(scene: Scene, model: SceneModel, traj, folder: Path, plots=None, save: bool | None = None) -> list[Path]:
    """Write the plots (PNG) and ``trajectory.npz`` of a run into ``folder``; return the paths.

    Parameters
    ----------
    plots : sequence of str, optional
        Names from :data:`qchain.scene.PLOTS`; default the scene's ``output.plots``.
    save : bool, optional
        Write ``trajectory.npz`` (``t, q, v, p, kinetic_energy, potential_energy, tip``
        and ``success``, ``message``); default the scene's ``output.save``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots = scene.plots if plots is None else tuple(plots)
    save = scene.save if save is None else save
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    t = traj.t
    tip = tip_positions(model, traj) if len(t) else np.zeros((0, 3))
    title = scene.name or (scene.path.stem if scene.path else "scene")

    def finish(fig, name):
        path = folder / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    if "tip" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        for k, c in enumerate("xyz"):
            ax.plot(t, tip[:, k] * 1e3, label=c)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("tip position, world (mm)")
        ax.set_title(f"{title}: tip position")
        ax.legend()
        ax.grid(alpha=0.3)
        finish(fig, "tip.png")
    if "arm" in plots:
        fig = plot_arm(model, traj, tip, title)
        finish(fig, "arm.png")
    if "energy" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        ax.plot(t, traj.kinetic_energy, label="kinetic")
        ax.plot(t, traj.potential_energy, label="potential (gravity + elastic)")
        ax.plot(t, traj.total_energy, "k", label="total")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("energy (J)")
        ax.set_title(f"{title}: energies")
        ax.legend()
        ax.grid(alpha=0.3)
        finish(fig, "energy.png")
    if "pressure" in plots:
        fig, ax = plt.subplots(figsize=(8, 4))
        for k in range(traj.p.shape[1]):
            ax.plot(t, traj.p[:, k] / 1e3, label=f"segment {k // 3}, chamber {k % 3 + 1}")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("pressure (kPa)")
        ax.set_title(f"{title}: chamber pressures")
        ax.legend(fontsize=7, ncol=3)
        ax.grid(alpha=0.3)
        finish(fig, "pressure.png")
    if "momentum" in plots and model.chain.floating and len(t):
        h = momenta(model, traj)
        fig, ax = plt.subplots(figsize=(8, 4))
        for k, name in enumerate(["px", "py", "pz", "Lx", "Ly", "Lz"]):
            ax.plot(t, h[:, k] - h[0, k], label=name)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("momentum drift h(t) - h(0) (kg m/s, kg m^2/s)")
        ax.set_title(f"{title}: world momentum drift (max {np.abs(h - h[0]).max():.2e})")
        ax.legend(ncol=2)
        ax.grid(alpha=0.3)
        finish(fig, "momentum.png")
    if save:
        path = folder / "trajectory.npz"
        np.savez_compressed(path, t=t, q=traj.q, v=traj.v, p=traj.p, kinetic_energy=traj.kinetic_energy,
                            potential_energy=traj.potential_energy, tip=tip, success=traj.success,
                            message=traj.message)
        written.append(path)
    return written


def momenta(model: SceneModel, traj) -> np.ndarray:
    """World momentum (N, 6) of a trajectory: linear (kg m/s), angular about the origin (kg m^2/s)."""
    ch = model.chain
    return np.array([ch.momentum(q, v, t=t) for t, q, v in zip(traj.t, traj.q, traj.v)])


def plot_arm(model: SceneModel, traj, tip: np.ndarray, title: str, snapshots: int = 8):
    """Side (x-z) and top (x-y) views of the arm at ``snapshots`` times, with the tip path."""
    import matplotlib.pyplot as plt

    ch = model.chain
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    N = len(traj.t)
    idx = np.unique(np.linspace(0, N - 1, min(snapshots, N)).round().astype(int)) if N else []
    cmap = plt.get_cmap("viridis")
    for (a, b), ax, view in (((0, 2), axes[0], "side view (x-z)"), ((0, 1), axes[1], "top view (x-y)")):
        ax.plot(tip[:, a] * 1e3, tip[:, b] * 1e3, color="0.6", lw=1, label="tip path")
        for n_, k in enumerate(idx):
            pts = ch.backbone(traj.q[k], 16, t=traj.t[k]).reshape(-1, 3) * 1e3
            c = cmap(n_ / max(1, len(idx) - 1))
            ax.plot(pts[:, a], pts[:, b], color=c, lw=3, label=f"t = {traj.t[k]:.2f} s")
            ax.plot(pts[0, a], pts[0, b], "ks", ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"{'xyz'[a]} (mm)")
        ax.set_ylabel(f"{'xyz'[b]} (mm)")
        ax.set_title(view)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{title}: arm snapshots")
    return fig


# --------------------------------------------------------------------------------------
# summary


def summary_lines(scene: Scene, model: SceneModel, traj, wall: float) -> list[str]:
    """The run summary ``qchain run`` prints."""
    lines = [f"run: {'success' if traj.success else 'FAILED'}: {traj.message}"]
    if len(traj.t) == 0:
        return lines + ["no samples were recorded"]
    t_end = float(traj.t[-1])
    rtf = t_end / wall if wall > 0 else math.inf
    lines.append(f"simulated {t_end:.6g} s in {wall:.3g} s wall time: {rtf:.3g} x real time; nfev = {traj.nfev}, "
                 f"{len(traj.t)} samples, method {scene.method} ({traj.meta.get('engine', 'python')} engine)")
    if traj.meta.get("compile_s", 0.0) > 0.05:
        lines.append(f"  compiled or loaded the engine first in {traj.meta['compile_s']:.3g} s (not in the wall time)")
    X = model.chain.tip_placement(traj.q[-1], t=t_end)
    p = X.translation * 1e3
    rpy = np.degrees(pin.rpy.matrixToRpy(X.rotation))
    quat = pin.Quaternion(X.rotation).coeffs()  # x, y, z, w
    lines.append(f"final tip (t = {t_end:.6g} s, world): position ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) mm")
    lines.append(f"  orientation rpy ({rpy[0]:.3f}, {rpy[1]:.3f}, {rpy[2]:.3f}) deg, quaternion xyzw "
                 f"({quat[0]:.6f}, {quat[1]:.6f}, {quat[2]:.6f}, {quat[3]:.6f})")
    reached = scene.bends(model.chain, traj)
    line = f"largest bends reached (rad): {', '.join(f'{x:.3g}' for x in reached)}"
    if model.max_bend is not None:
        line += f"; nodes sized for {', '.join(sorted({f'{x:.3g}' for x in model.max_bend}))}"
        over = np.flatnonzero(reached > model.max_bend)
        if over.size:
            j = int(over[0])
            line += (f"\nwarning: segment {j} bent {reached[j]:.3g} rad, more than the {model.max_bend[j]:.3g} rad its "
                     f"{model.nodes[j]} nodes were sized for: set model.max_bend in the scene")
    lines.append(line)
    ke, pe = traj.kinetic_energy, traj.potential_energy
    lines.append(f"energies (J): kinetic {ke[-1]:.6g}, potential {pe[-1]:.6g} (gravity + elastic), total "
                 f"{ke[-1] + pe[-1]:.6g}; at the start total {ke[0] + pe[0]:.6g}")
    return lines


# --------------------------------------------------------------------------------------
# commands


def _run(args, parser) -> int:
    scene = load_scene(args.scene)
    duration = scene.duration if args.duration is None else args.duration
    if not (math.isfinite(duration) and duration > 0):
        parser.error(f"--duration must be > 0 s, got {args.duration}")
    if scene.method in ("rk4", "midpoint") and scene.dt > duration:
        parser.error(f"--duration {duration:g} s is shorter than the scene's step dt = {scene.dt:g} s")
    qlog = _logging_module()
    record = qlog is not None and not (args.no_record and not (args.serve or args.connect or args.rrd))
    if record:
        if args.mcap is None and not args.no_record:
            args.mcap = qlog.default_mcap_path(scene.path)
        try:  # before anything is built: a bad path is said at once
            notices = qlog.check_outputs(None if args.no_record and not args.mcap else args.mcap, args.rrd,
                                         scene.path)
        except qlog.LoggingError as err:
            print(f"qchain run: error: {err}", file=sys.stderr)
            return EXIT_USAGE
        for notice in notices:
            print(f"qchain run: {notice}", file=sys.stderr)
        qlog.prepare_writer()  # the log writer starts up on the other core while the model is built
    model = scene.build(reduce=False if args.full else None)
    for line in scene.describe(model):
        print(line)
    sys.stdout.flush()
    progress = sys.stderr.isatty() if args.progress is None else args.progress

    if qlog is None and (args.mcap or args.serve or args.connect or args.rrd):
        print("qchain run: error: recording needs qchain.logging, which is not available", file=sys.stderr)
        return EXIT_USAGE
    logger = None
    on_sample = None
    if record:
        try:
            with warnings.catch_warnings():  # the notices were printed above
                warnings.simplefilter("ignore", qlog.LoggingWarning)
                logger, on_sample = _make_logger(qlog, args, scene, model, duration=duration)
        except (QchainError, OSError, ValueError) as err:
            print(f"qchain run: error: the recording could not start: {err}", file=sys.stderr)
            return EXIT_FAILED
    t0 = time.perf_counter()
    traj = None
    interrupted = False
    try:
        if logger is not None:
            with logger, on_sample:  # the recorder logs its last samples before the logger finishes
                try:
                    traj = scene.simulate(model=model, duration=duration, on_sample=on_sample, progress=progress)
                except KeyboardInterrupt as err:
                    traj = getattr(err, "trajectory", None)
                    interrupted = True
                if traj is not None:  # samples computed but not handed over (an interrupt between the two)
                    for k in range(on_sample.taken, len(traj.t)):
                        on_sample(traj.t[k], traj.q[k], traj.v[k], traj.p[k],
                                  energies=(traj.kinetic_energy[k], traj.potential_energy[k]))
                    logger.set_outcome(traj.success and not interrupted, traj.message, traj.status, traj.nfev)
                else:
                    logger.set_outcome(False, "interrupted by the user")
            done = logger.close()
            if logger.mcap_path is not None:
                reached = "no sample" if done.get("last_t") is None else f"t = {done['last_t']:.6g} s"
                print(f"recorded {logger.mcap_path} ({done.get('n_records', 0)} samples, up to {reached})")
            if done.get("error"):
                print(f"qchain run: error: the recording failed: {done['error']}", file=sys.stderr)
                return EXIT_FAILED
        else:
            try:
                traj = scene.simulate(model=model, duration=duration, progress=progress)
            except KeyboardInterrupt as err:
                traj = getattr(err, "trajectory", None)
                interrupted = True
    except (ValueError, QchainError) as err:  # the start state or an input outside the model, a full disk
        print(f"qchain run: error: {err}", file=sys.stderr)
        if logger is not None and logger.mcap_path is not None:
            done = logger.close()
            reached = "no sample" if done.get("last_t") is None else f"t = {done['last_t']:.6g} s"
            print(f"recorded {logger.mcap_path} ({done.get('n_records', 0)} samples, up to {reached})",
                  file=sys.stderr)
        return EXIT_FAILED
    wall = time.perf_counter() - t0 - (traj.meta.get("compile_s", 0.0) if traj is not None else 0.0)
    if traj is None:
        print("run: interrupted before the first sample", file=sys.stderr)
        return EXIT_FAILED
    if interrupted and len(traj.t):
        print(f"run: interrupted at t = {traj.t[-1]:.6g} s", file=sys.stderr)
    for line in summary_lines(scene, model, traj, wall):
        print(line)
    if not args.no_plots and len(traj.t):
        folder = Path(args.out) if args.out is not None else scene.output_folder
        for path in write_outputs(scene, model, traj, folder):
            print(f"wrote {path}")
    return EXIT_OK if traj.success and not interrupted else EXIT_FAILED


def _make_logger(qlog, args, scene: Scene, model: SceneModel, duration: float | None = None, **logger_kwargs):
    """The run logger and the ``on_sample`` callback that feeds it one record a sample, a
    :class:`qchain.recorder.ChainRecorder` (``logger_kwargs`` go to
    :class:`qchain.logging.RunLogger`). Enter both: ``with logger, recorder: ...``."""
    from .recorder import ChainRecorder, series_names

    ch = model.chain
    q_names, v_names = series_names(ch)
    info = qlog.RunInfo(
        n_segments=ch.n,
        radii=[s.radius for s in ch.segments],
        chamber_radii=[s.chamber_radius for s in ch.segments],
        scene=scene.text,
        scene_path=str(scene.path) if scene.path else None,
        params={
            "base": ch.base,
            "gravity": ch.gravity,
            "nodes": model.nodes,
            "planar": ch.planar,
            "extensible": [s.extensible for s in ch.segments],
            "reductions": model.reductions,
            "method": scene.method,
            "segments": [{k: getattr(s, k) for k in ("length", "radius", "mass", "chamber_area", "chamber_radius",
                                                       "youngs_modulus", "damping", "coords", "actuation")}
                         for s in ch.segments],
        },
        name=scene.name or (scene.path.stem if scene.path else "qchain run"),
        q_names=q_names,
        v_names=v_names,
        duration=duration if duration is not None else scene.duration,
    )
    if args.no_record and not args.mcap:
        logger = qlog.RunLogger(info, None, serve=args.serve, connect=args.connect, rrd=args.rrd,
                                bind=args.bind, linger=args.serve, **logger_kwargs)
    else:
        logger = qlog.logger_from_args(args, info, **logger_kwargs)
    return logger, ChainRecorder(logger, ch, realtime=bool(getattr(args, "realtime", False)))


def _info(args) -> int:
    scene = load_scene(args.scene)
    model = scene.build(reduce=False if args.full else None)
    for line in scene.describe(model):
        print(line)
    return EXIT_OK


def _parser(qlog) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="qchain", description="Simulate soft continuum arms described in TOML "
                                     "scene files (format: the docstring of qchain.scene).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run = sub.add_parser("run", help="run a scene and write its outputs", description="Run a scene file: build the "
                         "smallest model that represents it, integrate, print a summary, write plots.")
    run.add_argument("scene", type=Path, help="the scene file (.toml)")
    run.add_argument("--duration", type=float, default=None, metavar="S", help="simulated time (s), instead of the scene's")
    run.add_argument("--out", type=Path, default=None, metavar="DIR", help="output folder, instead of the scene's")
    run.add_argument("--full", action="store_true", help="no automatic reductions (as model.reduce = false)")
    run.add_argument("--no-plots", action="store_true", help="write no plots and no trajectory.npz")
    bar = run.add_mutually_exclusive_group()
    bar.add_argument("--progress", dest="progress", action="store_true", default=None,
                     help="progress bar on stderr (default: when stderr is a terminal)")
    bar.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    if qlog is not None:
        run.add_argument("--no-record", action="store_true", help="write no MCAP recording (unless --mcap is given)")
        qlog.add_logging_arguments(run)
    else:  # the same flags, refused with a clear message at run time
        run.set_defaults(no_record=True, mcap=None, serve=False, connect=None, rrd=None, bind="127.0.0.1",
                         realtime=False)
    info = sub.add_parser("info", help="describe the model a scene builds", description="Describe the model a scene "
                          "file builds: sizes, reductions and why, nodes, method.")
    info.add_argument("scene", type=Path, help="the scene file (.toml)")
    info.add_argument("--full", action="store_true", help="the model without automatic reductions")
    if qlog is not None:
        sub.add_parser("replay", help="replay an MCAP recording in Rerun (qchain replay --help)", add_help=False)
        sub.add_parser("recover", help="make a killed run's recording whole (qchain recover --help)",
                       add_help=False)
        sub.add_parser("layout", help="write a recording's Foxglove layout (qchain layout --help)", add_help=False)
    sub.add_parser("bench", help="speed against accuracy: every benchmark chart (qchain bench --help)",
                   add_help=False)
    sub.add_parser("sweep", help="run a scene over axes of its values, on every core or a Dask cluster "
                   "(qchain sweep --help)", add_help=False)
    return parser


def _bench(argv) -> int:
    """``qchain bench``: the scripts of the source tree's ``benchmarks/`` folder (not in a wheel)."""
    folder = Path(__file__).resolve().parents[1] / "benchmarks"
    if not (folder / "run_all.py").is_file():
        print(f"qchain bench: error: the benchmarks folder is not here ({folder}); run it from a source checkout "
              "(pip install -e .)", file=sys.stderr)
        return EXIT_USAGE
    sys.path.insert(0, str(folder))
    import run_all

    return int(run_all.main(argv) or 0)


def _sweep(argv) -> int:
    """``qchain sweep SWEEP.toml``: :func:`qchain.sweeps.main`."""
    from .sweeps import main as sweep_main

    return sweep_main(argv)


def main(argv=None) -> int:
    """Entry point of the ``qchain`` command; returns the exit code (0 ok, 1 run failed,
    2 bad scene or usage)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    qlog = _logging_module()
    handed = {"replay": "replay_main", "recover": "recover_main", "layout": "layout_main"}
    if argv and argv[0] in handed and qlog is not None:
        try:
            return int(getattr(qlog, handed[argv[0]])(argv[1:]) or 0)
        except SystemExit as exc:
            return _exit_code(exc)
    if argv and argv[0] == "bench":
        try:
            return _bench(argv[1:])
        except SystemExit as exc:
            return _exit_code(exc)
    if argv and argv[0] == "sweep":
        return _sweep(argv[1:])
    parser = _parser(qlog)
    try:
        args = parser.parse_args(argv)
        if args.command == "run":
            return _run(args, parser)
        return _info(args)
    except SystemExit as exc:  # argparse: --help (0) and usage errors (2)
        return _exit_code(exc)
    except SceneError as err:
        print(f"qchain {argv[0] if argv else ''}: error: {err}", file=sys.stderr)
        return EXIT_USAGE


def _exit_code(exc: SystemExit) -> int:
    if exc.code is None:
        return 0
    return exc.code if isinstance(exc.code, int) else EXIT_USAGE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
