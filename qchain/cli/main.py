"""The ``qchain`` command: ``run`` and ``info`` here, the dispatch of ``replay``, ``recover``,
``layout``, ``sweep`` and ``fit``. Commands, flags, what is checked before a run, errors and exit
codes (0 success, 1 the run failed or stopped, 2 bad input): ``docs/cli.md``."""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from .checks import (
    CONNECT_TIMEOUT, file_argument, path_argument, _recording_stem, check_bind_address, check_flag_values,
    check_output_folder, check_output_path, check_viewer_url, viewer_silence)
from .errors import (
    EXIT_FAILED, EXIT_OK, EXIT_USAGE, BadInput, _one_line, _Session, guarded, report_error, take_debug)
from .command import command
from .outputs import OutputError, planned_outputs, summary_lines, tip_positions, write_outputs
from ..checks.text import printable, show_path

if TYPE_CHECKING:  # the model's libraries load when a command needs them: Ctrl-C and --version answer at once
    from ..scene.scene import Scene, SceneModel

__all__ = ["main", "command", "write_outputs", "tip_positions", "summary_lines", "version", "report_error", "guarded",
           "take_debug", "check_output_path", "check_output_folder", "viewer_silence", "BadInput", "EXIT_OK",
           "EXIT_FAILED", "EXIT_USAGE", "CONNECT_TIMEOUT"]

#: The commands; the first word of the command line names one.
COMMANDS = ("run", "info", "replay", "recover", "layout", "sweep", "fit")


def version() -> str:
    """The installed qchain's version (``X.Y.Z``)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("qchain")
    except PackageNotFoundError:  # a source tree on sys.path, not installed
        from .. import __version__

        return __version__


# --------------------------------------------------------------------------------------
# commands


def _run(args, parser, session: _Session) -> int:
    """``qchain run``: check the scene and every output, reach the viewer, build the model,
    start the recording, integrate, then print the summary and write the plots. Returns
    :data:`EXIT_OK` or :data:`EXIT_FAILED`; raises :class:`BadInput` for input refused before
    the model is built, ``KeyboardInterrupt`` for Ctrl-C during start-up."""
    from . import recording as qlog

    scene, duration = _load_run_scene(args, parser)
    record, notices = _check_run_outputs(args, scene, duration)
    if args.connect:  # a viewer that never answers would hold the run without end
        record = _reach_viewer(args, record)
    for notice in notices:
        print(f"qchain run: {notice}", file=sys.stderr)
    if record:
        qlog.prepare_writer()  # the log writer starts up on the other core while the model is built
    model = _build_run_model(args, scene, duration, session)
    progress = (True if sys.stderr.isatty() else "lines") if args.progress is None else args.progress
    logger = on_sample = None
    if record:
        started = _start_recording(args, scene, model, duration, notices)
        if started is None:
            return EXIT_FAILED
        logger, on_sample = started
    ran = _simulate(scene, model, duration, progress, logger, on_sample, session)
    if ran is None:
        return EXIT_FAILED
    traj, interrupted, wall = ran
    code = _report_run(args, scene, model, traj, interrupted, wall, session)
    if args.ros2 is not None and logger is not None and traj is not None:
        code = max(code, _export_ros2(logger.mcap_path, args.ros2))
    return code


def _export_ros2(mcap, out) -> int:
    """``--ros2 OUT``: the finished recording written as a ROS 2 bag
    (:func:`qchain.recording.ros2.export_ros2`); an export that fails is said, and the
    recording stays as it is."""
    from ..recording.ros2 import export_ros2

    try:
        count = export_ros2(mcap, out)
    except Exception as err:  # the recording is whole: say why the bag is not, exit 1
        print(f"qchain run: error: the ROS 2 bag {printable(show_path(out))} could not be written: {_one_line(err)}; "
              f"`qchain export {printable(show_path(mcap))} -o OUT.mcap` retries it", file=sys.stderr)
        return EXIT_FAILED
    print(f"wrote {printable(show_path(out))} (ROS 2 bag, {count} messages)")
    return EXIT_OK


def _load_run_scene(args, parser) -> tuple[Scene, float]:
    """The run's scene and its duration (s), checked against the scene's step and budget;
    a ``--duration`` beyond the budget is :class:`BadInput`."""
    from ..scene.reading import load_scene
    from ..sim.budget import BudgetError

    scene = load_scene(args.scene)
    duration = scene.duration if args.duration is None else args.duration
    if scene.method in ("rk4", "midpoint") and scene.dt > duration:
        parser.commands["run"].error(f"argument --duration: expected a duration >= the scene's step dt = {scene.dt:g} s, found "
                     f"{duration:g} s")
    try:  # a --duration beyond the budget is refused before anything is built
        scene.check_budget(duration)
    except BudgetError as err:
        if args.duration is None:
            raise
        raise BadInput(f"--duration {duration:g} s: {err}") from None
    return scene, duration


def _check_run_outputs(args, scene: Scene, duration: float) -> tuple[bool, list[str]]:
    """Check every output of the run before the model is built (the recording, the plots'
    folder, the plots and ``trajectory.npz``); sets ``args.mcap`` to the default recording.
    Returns whether the run records and the notices :func:`qchain.cli.recording.check_outputs`
    has to say of the paths (printed by the caller, not repeated as warnings)."""
    from ..scene.scene import SceneError
    from . import recording as qlog

    record = not (args.no_record and not (args.mcap or args.serve or args.connect or args.rrd))
    notices: list[str] = []
    if not args.no_plots:  # a recording where the plots' folder is, or above it: refused before either is made
        folder = os.path.abspath(args.out if args.out is not None else scene.output_folder)
        for flag, p in (("--mcap", args.mcap), ("--rrd", args.rrd)):
            if p is not None and (folder == os.path.abspath(p) or folder.startswith(os.path.abspath(p) + os.sep)):
                raise BadInput(f"{flag} {printable(show_path(p))} is the plots' folder {printable(show_path(folder))} or a "
                               "folder above it: give the recording a file path of its own")
    if record or args.rrd:  # a recording's times end at 2**32 s: said before the model is built
        from ..recording.records import T_MAX, T_MAX_WHY

        if duration > T_MAX:
            src = "--duration" if args.duration is not None else f"{printable(show_path(args.scene))}: simulation.duration"
            raise BadInput(f"{src} {duration:g} s: a recorded run lasts at most {T_MAX:.10g} s ({T_MAX_WHY}); run "
                           "it with --no-record (and no --rrd, --serve or --connect)")
    if args.ros2 is not None:
        if not record:
            raise BadInput("--ros2 is written from the run's recording: drop --no-record (or give --mcap)")
        if Path(args.ros2).suffix != ".mcap":
            raise BadInput(f"--ros2 {printable(show_path(args.ros2))}: a ROS 2 bag is an .mcap file; name it *.mcap")
        check_output_path("--ros2", args.ros2)
    mcap = None
    if record:
        if args.mcap is None and not args.no_record:
            args.mcap = qlog.default_mcap_path(f"{_recording_stem(scene.path)}.toml")
        mcap = None if args.no_record and not args.mcap else args.mcap
        check_output_path("--mcap", mcap, extra=".journal")
        check_output_path("--rrd", args.rrd)
        try:  # before anything is built: a bad path is said at once
            notices = qlog.check_outputs(mcap, args.rrd, scene.path)
        except qlog.LoggingError as err:
            raise BadInput(str(err)) from None
    if not args.no_plots:  # the plots' and trajectory.npz's folder: made, writable, with room
        try:
            scene.check_output(args.out)
        except SceneError as err:
            if args.out is None or not err.problems:
                raise
            p = err.problems[0]
            raise BadInput(f"--out {show_path(args.out)}: expected {p.expected}, found {p.found}") from None
    _check_planned_outputs(args, scene, mcap)
    return record, notices


def _reach_viewer(args, record: bool) -> bool:
    """Whether the run still records once the viewer of ``--connect`` is tried: one that does
    not answer within ``--viewer-timeout`` s is given up with a warning (``args.connect = None``)."""
    why = viewer_silence(args.connect, timeout=_viewer_timeout(args))
    if why is not None:
        print(f"qchain run: warning: no Rerun viewer answers at {args.connect} ({why}); the run goes on without "
              "it", file=sys.stderr)
        args.connect = None
        record = not (args.no_record and not (args.mcap or args.serve or args.rrd))
    return record


def _build_run_model(args, scene: Scene, duration: float, session: _Session) -> SceneModel:
    """Build the scene's model (``--full``: no reductions), check it against the budget
    (:class:`BadInput`) and print its description."""
    from ..sim.budget import BudgetError

    session.check_interrupt()
    model = scene.build(reduce=False if args.full else None)
    session.check_interrupt()
    try:  # an explicit method on a stiff model: refused before anything is recorded
        scene.check_budget(duration, model)
    except BudgetError as err:
        raise BadInput(f"{printable(show_path(args.scene))}: {err}") from None
    _print_lines(scene.describe(model, duration=duration, folder=args.out, plots=not args.no_plots))
    sys.stdout.flush()
    return model


def _start_recording(args, scene: Scene, model: SceneModel, duration: float, notices: list[str]):
    """The run's logger and recorder (:func:`_make_logger`), or None when the recording could
    not start (said: the run never runs without its recording); ``notices`` are not repeated."""
    from ..errors import QchainError

    with warnings.catch_warnings():  # the notices were printed already; other warnings are lines
        for notice in notices:
            warnings.filterwarnings("ignore", message=re.escape(f"qchain.logging: {notice}"))
        try:
            return _make_logger(args, scene, model, duration=duration, viewer_timeout=_viewer_timeout(args))
        except (QchainError, OSError, ValueError) as err:
            print(f"qchain run: error: the recording could not start: {_one_line(err)}", file=sys.stderr)
            return None


def _simulate(scene: Scene, model: SceneModel, duration: float, progress, logger, on_sample, session: _Session):
    """Integrate the model, recorded when ``logger`` is given; Ctrl-C ends the run with the
    samples it has. Returns ``(trajectory or None, interrupted, wall s)``, the wall time without
    compiling; None when the run failed and said so."""
    from ..errors import QchainError

    t0 = time.perf_counter()
    try:
        session.check_interrupt()
    except KeyboardInterrupt:
        if logger is not None:
            with logger, on_sample:
                logger.set_outcome(False, "interrupted by the user (Ctrl-C) before the first sample")
        raise
    session.phase = "run"
    try:  # t1: when the simulation ended; the wall time excludes finishing the recording (a slow viewer)
        if logger is not None:
            ran = _simulate_recorded(scene, model, duration, progress, logger, on_sample, session)
            if ran is None:
                return None
            traj, interrupted, t1 = ran
        else:
            traj, interrupted, t1 = _integrate(scene, model, duration, progress)
    except (ValueError, QchainError) as err:  # the start state or an input outside the model, a full disk
        print(f"qchain run: error: {_one_line(err)}", file=sys.stderr)
        if logger is not None and logger.mcap_path is not None:
            _say_recording(logger, logger.close(), sys.stderr)
        return None
    session.phase = "end"
    wall = t1 - t0 - (traj.meta.get("compile_s", 0.0) if traj is not None else 0.0)
    return traj, interrupted, wall


def _integrate(scene: Scene, model: SceneModel, duration: float, progress, on_sample=None):
    """Integrate; returns the trajectory (None: interrupted before the first sample), whether
    Ctrl-C ended it, and when it ended (:func:`time.perf_counter`, s)."""
    try:
        traj = scene.simulate(model=model, duration=duration, on_sample=on_sample, progress=progress)
        interrupted = False
    except KeyboardInterrupt as err:
        traj, interrupted = getattr(err, "trajectory", None), True
    return traj, interrupted, time.perf_counter()


def _simulate_recorded(scene: Scene, model: SceneModel, duration: float, progress, logger, on_sample,
                       session: _Session):
    """:func:`_integrate` with every sample recorded (samples computed but not handed over are
    handed over before the outcome is set), then finish the recording and say what became of it;
    None when the recording failed."""
    with logger, on_sample:  # the recorder logs its last samples before the logger finishes
        traj, interrupted, t1 = _integrate(scene, model, duration, progress, on_sample)
        if traj is not None:  # samples computed but not handed over (an interrupt between the two)
            session.reached = float(traj.t[-1]) if len(traj.t) else None
            for k in range(on_sample.taken, len(traj.t)):
                on_sample(traj.t[k], traj.q[k], traj.v[k], traj.p[k],
                          energies=(traj.kinetic_energy[k], traj.potential_energy[k]))
            message = _interrupt_message(traj) if interrupted else traj.message
            logger.set_outcome(traj.success and not interrupted, message, traj.status, traj.nfev)
        else:
            logger.set_outcome(False, "interrupted by the user (Ctrl-C) before the first sample")
    done = logger.close()
    if done.get("error"):
        print(f"qchain run: error: the recording failed: {_one_line(done['error'])}", file=sys.stderr)
    _say_recording(logger, done, sys.stdout)
    return None if done.get("error") else (traj, interrupted, t1)


def _report_run(args, scene: Scene, model: SceneModel, traj, interrupted: bool, wall: float,
                session: _Session) -> int:
    """Print how the run ended and its summary, write its plots and ``trajectory.npz`` (unless
    ``--no-plots``); returns the exit code."""
    if traj is None:
        print("run: interrupted before the first sample", file=sys.stderr)
        return EXIT_FAILED
    session.reached = float(traj.t[-1]) if len(traj.t) else None
    if interrupted and len(traj.t):
        print(f"run: interrupted at t = {traj.t[-1]:.6g} s", file=sys.stderr)
    _print_lines(summary_lines(scene, model, traj, wall, message=_interrupt_message(traj) if interrupted else None))
    if not args.no_plots and len(traj.t):
        folder = Path(args.out) if args.out is not None else scene.output_folder
        try:
            written = write_outputs(scene, model, traj, folder)
        except OutputError as err:
            for path in err.written:
                print(f"wrote {printable(show_path(path))}")
            print(f"qchain run: error: {_one_line(err)}", file=sys.stderr)
            return EXIT_FAILED
        for path in written:
            print(f"wrote {printable(show_path(path))}")
    return EXIT_OK if traj.success and not interrupted else EXIT_FAILED


def _say_recording(logger, done: dict, stream) -> None:
    """What became of the run's recording: ``recorded PATH (N samples, up to t = T s)`` on
    ``stream``, or for one that could not be finished where its records are (its journal,
    if it stayed: ``qchain replay`` reads it, ``qchain recover`` makes the file whole)."""
    if logger.mcap_path is None:
        return
    mcap = printable(show_path(logger.mcap_path))
    if done.get("error"):
        jp = getattr(logger, "journal_path", None)
        if jp is not None and os.path.exists(jp):
            print(f"qchain run: the recording {mcap} is not finished; its records are in {printable(show_path(jp))} "
                  f"(`qchain replay {mcap}` reads them, `qchain recover {mcap}` makes the file whole)", file=sys.stderr)
        return
    reached = "no sample" if done.get("last_t") is None else f"t = {done['last_t']:.6g} s"
    print(f"recorded {mcap} ({done.get('n_records', 0)} samples, up to {reached})", file=stream)


def _check_planned_outputs(args, scene, mcap) -> None:
    """Refuse a plot or ``trajectory.npz`` path that is not a regular file, and two outputs of
    the run that are the same file (:class:`BadInput` naming the flags and the path)."""
    outputs: list[tuple[str, object]] = []
    if mcap is not None:
        outputs += [("--mcap", mcap), ("--mcap (its journal)", os.fspath(mcap) + ".journal")]
    if args.rrd is not None:
        outputs.append(("--rrd", args.rrd))
    if args.ros2 is not None:
        outputs.append(("--ros2", args.ros2))
    if not args.no_plots:
        flag = "--out" if args.out is not None else "output.folder"
        for path in planned_outputs(scene, args.out):
            check_output_path(f"{flag} {show_path(path.parent)}: output", path)
            outputs.append((f"{flag} {show_path(path.parent)} (its {path.name})", path))
    seen: dict[str, str] = {}
    for what, path in outputs:
        try:
            key = os.path.realpath(os.fspath(path))
        except (OSError, ValueError):
            continue
        if key in seen:
            raise BadInput(f"{what} path {show_path(path)} is the same file as {seen[key]}: the run would write both "
                           "there; choose another path")
        seen[key] = what


def _print_lines(lines) -> None:
    """Print lines holding text from outside one printed line each (control characters escaped)."""
    for line in lines:
        print(printable(line))


def _viewer_timeout(args) -> float:
    """s a Rerun viewer has to answer (``--viewer-timeout``, default :data:`CONNECT_TIMEOUT`)."""
    t = getattr(args, "viewer_timeout", None)
    return CONNECT_TIMEOUT if t is None else float(t)


def _check_run_flags(args) -> None:
    """The flags of ``qchain run`` argparse cannot check alone: the viewer's URL, the address to
    serve on, flags that exclude each other (:class:`BadInput`)."""
    if getattr(args, "serve", False) and getattr(args, "connect", None) is not None:
        raise BadInput("argument --connect: not allowed with --serve (they exclude each other: serve a viewer here, "
                       "or stream to a running one)")
    check_viewer_url("argument --connect", getattr(args, "connect", None))
    if getattr(args, "serve", False):
        check_bind_address("argument --bind", getattr(args, "bind", None))


def _interrupt_message(traj) -> str:
    """How an interrupted run ended, with the time its samples reach."""
    if len(traj.t):
        return f"interrupted by the user (Ctrl-C) at t = {traj.t[-1]:.6g} s"
    return "interrupted by the user (Ctrl-C) before the first sample"


def _make_logger(args, scene: Scene, model: SceneModel, duration: float | None = None, **logger_kwargs):
    """The run logger (``logger_kwargs`` go to :class:`qchain.logging.RunLogger`) and the
    ``on_sample`` recorder that feeds it; enter both: ``with logger, recorder: ...``."""
    from ..recording.recorder import ChainRecorder, series_names
    from . import recording as qlog

    ch = model.chain
    q_names, v_names = series_names(ch)
    stem = _recording_stem(scene.path) if scene.path else None
    contact, contacts = _contact_recording(ch, scene.environment)
    info = qlog.RunInfo(
        n_segments=ch.n,
        radii=[s.radius for s in ch.segments],
        chamber_radii=[s.chamber_radius for s in ch.segments],
        scene=scene.text,
        scene_path=show_path(scene.path) if scene.path else None,  # stored as UTF-8 text
        params={
            "base": ch.base,
            "gravity": ch.gravity,
            "nodes": model.nodes,
            "planar": ch.planar,
            "extensible": [s.extensible for s in ch.segments],
            "reductions": model.reductions,
            "method": scene.method,
            "segments": [{k: getattr(s, k) for k in ("length", "radius", "mass", "chamber_area", "chamber_radius",
                                                       "youngs_modulus", "damping", "damping_matrix", "drag_linear",
                                                       "drag_quadratic", "coords", "actuation")}
                         for s in ch.segments],
            **({"tendons": [{"radius": td.radius, "angle": td.angle, "pitch": td.pitch, "end": td.end}
                            for td in ch.tendons]} if ch.nt else {}),
        },
        name=scene.name or stem or "qchain run",
        q_names=q_names,
        v_names=v_names,
        duration=duration if duration is not None else scene.duration,
        **contact,
    )
    if args.no_record and not args.mcap:  # a viewer or .rrd only: the same rate as with a recording
        logger = qlog.RunLogger(info, None, serve=args.serve, connect=args.connect, rrd=args.rrd, bind=args.bind,
                                linger=args.serve, **{"rerun_rate": args.rerun_rate, **logger_kwargs})
    else:
        logger = qlog.logger_from_args(args, info, **logger_kwargs)
    import numpy as np

    tension = None
    if ch.nt:  # the scene's tension schedule (0 N without [tension]): what simulate applies at each sample
        zeros = np.zeros(ch.nt)
        tension = (lambda t, q, v: zeros) if scene.tension is None else (lambda t, q, v: scene.tension(t))
    return logger, ChainRecorder(logger, ch, realtime=bool(getattr(args, "realtime", False)), contacts=contacts,
                                 tension=tension)


#: Contacts a sample of ``qchain run`` records at most (``RunInfo.max_contacts``): 11 numbers
#: each travel in every row of the journal, NaN-padded; past it a sample keeps its largest forces.
MAX_RUN_CONTACTS = 1024


def _contact_recording(chain, env) -> tuple[dict, object]:
    """What a run with obstacles records of them: the :class:`~qchain.logging.RunInfo` fields
    (``obstacles`` = ``env.describe()``; ``max_contacts`` = segments x contact points x the
    obstacles counted up to two (a point seldom touches more at once than the ground and a
    wall), bounded by :data:`MAX_RUN_CONTACTS`; ``force_ref`` (N) = the weight a contact point carries when the
    arm lies flat, ``m g / (n nodes)`` with the arm's and payload's mass ``m`` and standard
    gravity for a weightless run, so a resting arm's forces are drawn a quarter reach long)
    and the recorder's ``contacts(t, q, v)`` (:meth:`qchain.Chain.contacts`). ``({}, None)``
    without obstacles (``env`` None, or loads only): no contact channel, no contact call."""
    if env is None or not env.obstacles:
        return {}, None
    import numpy as np
    from scipy.constants import g as standard_gravity

    n_points = chain.n * env.nodes
    mass = sum(s.mass for s in chain.segments) + (chain.payload.mass if chain.payload is not None else 0.0)
    g = float(np.linalg.norm(chain.gravity)) or standard_gravity
    info = {"obstacles": env.describe(), "max_contacts": min(n_points * min(len(env.obstacles), 2), MAX_RUN_CONTACTS),
            "force_ref": mass * g / n_points}
    return info, lambda t, q, v: chain.contacts(q, v, env, t)


def _info(args) -> int:
    from ..scene.reading import load_scene

    scene = load_scene(args.scene)
    model = scene.build(reduce=False if args.full else None)
    _print_lines(scene.describe(model))
    return EXIT_OK


def _parser() -> argparse.ArgumentParser:
    """The parser of ``qchain``: ``run`` and ``info``; ``replay``, ``recover``, ``layout`` and
    ``sweep`` are listed only, and parse their own arguments."""
    from . import recording as qlog

    parser = argparse.ArgumentParser(prog="qchain", description="Simulate soft continuum arms described in TOML "
                                     "scene files (format: docs/scene-format.md). Exit codes: 0 success, 1 the run "
                                     "failed or was interrupted, 2 bad input or usage.")
    parser.add_argument("--version", action="version", version=f"qchain {version()}")
    parser.add_argument("--debug", action="store_true", help="print the traceback of an error too (anywhere on the "
                        "command line)")
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
                     help="progress bar on stderr (default: when stderr is a terminal; else a line every 30 s "
                          "once a run has taken 10 s)")
    bar.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    run.add_argument("--no-record", action="store_true", help="write no MCAP recording (unless --mcap is given)")
    run.add_argument("--ros2", type=Path, default=None, metavar="OUT",
                     help="also write the recording as a ROS 2 bag (an .mcap file: /tf, /joint_states, "
                          "/qchain/pressures, /qchain/markers) once the run ends")
    g = qlog.add_logging_arguments(run)
    g.add_argument("--viewer-timeout", type=float, default=None, metavar="S",
                   help=f"seconds a Rerun viewer (--connect, --serve) has to answer before it is given up, with a "
                        f"warning (default {CONNECT_TIMEOUT:g})")
    info = sub.add_parser("info", help="describe the model a scene builds", description="Describe the model a scene "
                          "file builds: sizes, reductions and why, nodes, method.")
    info.add_argument("scene", type=Path, help="the scene file (.toml)")
    info.add_argument("--full", action="store_true", help="the model without automatic reductions")
    sub.add_parser("replay", help="replay an MCAP recording in Rerun (qchain replay --help)", add_help=False)
    sub.add_parser("recover", help="make a killed run's recording whole (qchain recover --help)", add_help=False)
    sub.add_parser("layout", help="write a recording's Foxglove layout (qchain layout --help)", add_help=False)
    sub.add_parser("export", help="write a recording as a ROS 2 bag (qchain export --help)", add_help=False)
    sub.add_parser("sweep", help="run a scene over axes of its values, on every core or a Dask cluster "
                   "(qchain sweep --help)", add_help=False)
    sub.add_parser("fit", help="fit a scene's parameters to measured motion as a fit file says (qchain fit --help)",
                   add_help=False)
    parser.commands = {"run": run, "info": info}  # (their usage errors: _dispatch)
    for p in (run, info):  # every path argument: not empty (Path("") is the working folder), no NUL
        for action in p._actions:
            if action.type is Path:
                action.type = file_argument if action.dest in ("mcap", "rrd", "ros2") else path_argument
    return parser


def _dispatch(argv: list[str], session: _Session, debug: bool) -> int:
    if argv[:1] in (["--version"], ["-V"]) and len(argv) == 1:  # at once, before the libraries load
        print(f"qchain {version()}")
        return EXIT_OK
    try:
        os.getcwd()
    except OSError as exc:  # relative paths (the scene, runs/, out/) would fail later, naming nothing
        raise BadInput(f"the working folder cannot be used ({exc.strerror or exc}: deleted?): change to an existing "
                       "folder") from None
    if argv and argv[0] in ("run", "info", "sweep", "fit") and \
            os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0"):
        raise BadInput(f"NUMBA_DISABLE_JIT={os.environ['NUMBA_DISABLE_JIT'][:20]} is set: qchain's engine is "
                       "numba-compiled (and would take hours as Python); unset it")
    if argv and argv[0] == "sweep":
        from .sweep import main as sweep_main

        return sweep_main(argv[1:], debug=debug, session=session)
    if argv and argv[0] == "fit":
        from .fit import main as fit_main

        return fit_main(argv[1:], debug=debug, session=session)

    # imported here, not with the module: `qchain --version` answers without the recording's libraries
    from . import recording as qlog

    handed = {"replay": "replay_main", "recover": "recover_main", "layout": "layout_main", "export": "export_main"}
    if argv and argv[0] in handed:
        session.phase = "run"  # qchain.logging says its errors and their exit codes itself
        return int(getattr(qlog, handed[argv[0]])(argv[1:]) or 0)
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        check_flag_values(args)
    except BadInput as err:  # as argparse says a bad value: the command's usage, then the line
        parser.commands[args.command].error(str(err))
    _check_run_flags(args)
    if args.command == "run":
        return _run(args, parser, session)
    return _info(args)


def _result_on_stdout(argv: list[str]) -> bool:
    """Whether standard output is the command's result (``info``; ``layout`` without ``-o``):
    an output that cannot be written then fails it."""
    if not argv:
        return False
    if argv[0] == "info":
        return True
    return argv[0] == "layout" and not any(a in ("-o", "--out") or a.startswith("--out=") or
                                           (a.startswith("-o") and len(a) > 2) for a in argv[1:])


def main(argv=None) -> int:
    """Entry point of ``qchain`` and ``python -m qchain``: ``argv`` (default ``sys.argv[1:]``;
    ``--debug`` anywhere before a ``--``) -> the exit code."""
    argv, debug = take_debug([os.fspath(a) for a in (sys.argv[1:] if argv is None else argv)])
    name = argv[0] if argv and argv[0] in COMMANDS else ""
    return command(name, lambda session: _dispatch(argv, session, debug), debug,
                   result_on_stdout=_result_on_stdout(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
