"""The recording commands and flags: ``qchain replay``, ``qchain recover``, ``qchain layout``,
and the flags with which ``qchain run`` and ``qchain sweep`` ask for a recording or a viewer
(:func:`add_logging_arguments`, :func:`logger_from_args`). The work itself is
:mod:`qchain.recording`'s; this module parses, checks flags, prints and sets exit codes."""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from ..checks.paths import written_whole
from ..checks.text import printable
from ..recording.bounded import DEFAULT_LIMITS, ReadLimits
from ..recording.foxglove_layout import layout_json
from ..recording.logger import RunLogger
from ..recording.reader import Recording, read_recording
from ..recording.records import LoggingError, LoggingWarning, RunInfo
from ..recording.writer import prepare_writer
from ..recording.options import check_outputs, default_mcap_path, refuse_recording
from ..recording.replay import _IncompleteWarning, recover, replay
from ..recording.rerun_sink import CONNECT_TIMEOUT, DEFAULT_BIND
from ..sim.budget import RANGES
from .checks import check_bind_address, check_output_path, check_viewer_url, file_argument
from .errors import BadInput

_default_mcap_path = default_mcap_path  # reachable where a parameter has the same name

__all__ = ["replay_main", "recover_main", "layout_main", "export_main", "add_logging_arguments", "logger_from_args",
           # what qchain run needs of the recording service, in one place
           "RunInfo", "RunLogger", "LoggingError", "check_outputs", "default_mcap_path", "prepare_writer"]


def _summary(rec: Recording) -> list[str]:
    lines = []
    if len(rec):
        lines.append(f"{len(rec)} steps of {rec.path}, t = {rec.t[0]:.6g} .. {rec.t[-1]:.6g} s")
    else:
        lines.append(f"{rec.path} holds no complete step")
    if rec.truncated:
        where = f"t = {rec.t[-1]:.6g} s" if len(rec) else "its start"
        lines.append(f"the recording is truncated: it stops at {where} ({rec.stop_reason})")
    elif rec.outcome is not None:
        lines.append(f"the run ended: {rec.outcome.get('message', '')}")
    for g in rec.gaps:
        lines.append(f"damaged: {g.describe()}")
    shown = {g.reason for g in rec.gaps}
    for d in rec.damage:
        if d not in shown and "(no chunk there, per the summary: no record lost)" not in d:
            lines.append(f"damaged: {d}")
    for d in rec.nonfinite:
        lines.append(f"non-finite values (null in the file, read as NaN): {d}")
    if rec.disorder:
        lines.append(rec.disorder)
    return lines


#: What the commands report as an error (exit code 2) rather than a traceback.
_ERRORS = (LoggingError, OSError, ValueError, TypeError)


def _error(prog: str, exc: BaseException) -> int:
    print(f"qchain {prog}: error: {printable(exc)}", file=sys.stderr)
    return 2


def _parse(prog: str, description: str, argv, add=None) -> tuple[argparse.Namespace, ReadLimits]:
    """The command line of a command on a recording: the recording, the flags ``add(parser)``
    adds, ``--max-segments``; returns the arguments and the reading limits they ask for."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("log", type=Path, help="the .mcap recording")
    if add is not None:
        add(parser)
    parser.add_argument("--max-segments", type=int, default=DEFAULT_LIMITS.max_segments, metavar="N",
                        help=f"segments a recording may declare (default {DEFAULT_LIMITS.max_segments}; a run whose "
                             "budget allowed more needs it raised)")
    args = parser.parse_args(argv)
    top = int(RANGES["max_segments"].high)
    if not 1 <= args.max_segments <= top:
        parser.error(f"argument --max-segments: expected an integer >= 1 and <= {top}, found {args.max_segments}")
    return args, replace(DEFAULT_LIMITS, max_segments=args.max_segments)


def replay_main(argv: Sequence[str] | None = None) -> int:
    """``qchain replay LOG.mcap [--serve | --connect URL | --rrd OUT]``; returns the exit code.

    Without a target the replay is served on 127.0.0.1 (``--serve``) until Ctrl-C.
    Exit codes: 0 done, 1 a target not reached (a viewer that cannot be reached or does
    not answer in time, said on standard error), 2 not a (readable) qchain recording, an
    output that cannot be written, or bad arguments.
    """
    def add(parser):
        target = parser.add_mutually_exclusive_group()
        target.add_argument("--serve", action="store_true", help="serve a web viewer on 127.0.0.1 (the default)")
        target.add_argument("--connect", metavar="URL",
                            help="send to a running Rerun viewer (rerun+http://HOST:PORT/proxy)")
        target.add_argument("--rrd", metavar="OUT", type=file_argument, help="write a Rerun .rrd file")
        parser.add_argument("--bind", default=DEFAULT_BIND,
                            help="address to serve on (default 127.0.0.1: this machine only)")
        parser.add_argument("--timeout", type=float, default=CONNECT_TIMEOUT, metavar="S",
                            help=f"seconds a viewer at --connect has to answer and take the recording (default "
                                 f"{CONNECT_TIMEOUT:g})")

    args, limits = _parse("qchain replay", "Re-log a qchain MCAP recording into Rerun with its original simulation "
                          "times.", argv, add)
    serve = args.serve or not (args.connect or args.rrd)

    try:  # the same checks as qchain run's, before the file is read
        if not 0.0 < args.timeout <= 3600.0:
            raise BadInput(f"argument --timeout: expected a number > 0 and <= 3600 (s), found {args.timeout!r}")
        check_viewer_url("argument --connect", args.connect)
        if serve:
            check_bind_address("argument --bind", args.bind)
    except BadInput as exc:
        return _error("replay", exc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LoggingWarning)
        try:
            session = replay(args.log, serve=serve, connect=args.connect, rrd=args.rrd, bind=args.bind, quiet=True,
                             timeout=args.timeout, limits=limits)
        except _ERRORS as exc:
            return _error("replay", exc)
    for w in caught:
        if issubclass(w.category, LoggingWarning) and not issubclass(w.category, _IncompleteWarning):
            print(f"qchain replay: warning: {printable(str(w.message).removeprefix('qchain.logging: '))}",
                  file=sys.stderr)
    rec = session.recording
    lines = _summary(rec)
    sent = session.sent is not False
    if len(rec):
        lines[0] = ("replayed " if sent else "read ") + lines[0]
    print("\n".join(map(printable, lines)))
    if args.rrd:
        print(f"wrote {printable(args.rrd)}")
    if args.connect:
        print(printable(f"sent to {args.connect}" if sent else f"not sent to {args.connect}: see the warning above"))
    if serve:
        if session.viewer_url:
            print(f"open {session.viewer_url}  - Ctrl-C to stop", flush=True)
        elif session.grpc_url:
            print(f"connect a Rerun viewer to {session.grpc_url}  - Ctrl-C to stop", flush=True)
        else:
            print("no viewer could be served", file=sys.stderr)
            return 1
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            session.close()
    return 0 if sent else 1


def recover_main(argv: Sequence[str] | None = None) -> int:
    """``qchain recover LOG.mcap``: make a killed run's recording whole from its journal.
    Exit codes: 0 done, 2 nothing to recover, not readable, or not writable."""
    args, limits = _parse("qchain recover", "Make the recording of a killed run whole: the records its journal "
                          "(LOG.mcap.journal) holds are written into it.", argv)
    try:
        before = os.stat(args.log).st_mtime_ns if os.path.exists(args.log) else None
        rec = recover(args.log, limits=limits)
    except _ERRORS as exc:
        return _error("recover", exc)
    if before is not None and os.stat(args.log).st_mtime_ns == before:
        print(printable(f"nothing to recover: {args.log} is complete and has no journal (left as it is)"))
        return 0
    print("recovered " + "\n".join(map(printable, _summary(rec))))
    return 0


def layout_main(argv: Sequence[str] | None = None) -> int:
    """``qchain layout LOG.mcap [-o layout.json]``: the Foxglove layout of a recording.
    Exit codes: 0 done, 2 not a readable recording, or an output that cannot be written."""
    args, limits = _parse("qchain layout", "Write the Foxglove layout of a recording (3D arm, frame tree, named "
                          "plots); import it in Foxglove's layout menu.", argv, lambda parser: parser.add_argument(
                              "-o", "--out", type=file_argument, default=None,
                              help="output file (default: standard output)"))
    try:
        if args.out is not None:
            refuse_recording(args.out, args.log, f"-o {args.out} is the recording")
            if args.out.is_file() and args.out.stat().st_size > 0:
                with open(args.out, "rb") as fh:
                    head = fh.read(64).lstrip()
                if not head.startswith(b"{"):  # an earlier layout (JSON) is replaced; anything else is kept
                    raise LoggingError(f"-o {args.out} exists and is not a layout (JSON); refusing to overwrite it")
            if args.out.is_dir():
                raise LoggingError(f"-o must be a file path, got the folder {args.out}")
            try:  # a device or a FIFO there is refused, never replaced (os.replace below would)
                check_output_path("-o", args.out)
            except BadInput as exc:
                raise LoggingError(str(exc)) from None
        rec = read_recording(args.log, limits=limits)
        text = layout_json(rec.info, rec.q.shape[1], rec.v.shape[1], rec.p.shape[1])
        if args.out is None:
            print(text)
        else:
            try:
                with written_whole(args.out, prefix=".layout-") as fh:  # short: see recover
                    fh.write(text + "\n")
            except OSError as exc:
                raise LoggingError(f"cannot write {args.out} ({exc.strerror or exc})") from None
            print(f"wrote {printable(args.out)}")
    except _ERRORS as exc:
        return _error("layout", exc)
    return 0


def export_main(argv: Sequence[str] | None = None) -> int:
    """``qchain export LOG.mcap -o BAG.mcap``: a recording as a ROS 2 bag
    (:func:`qchain.recording.ros2.export_ros2`). Exit codes: 0 done, 2 not a readable
    recording, or an output that cannot be written (then left as it was)."""
    from ..recording.ros2 import export_ros2

    args, limits = _parse("qchain export", "Write a recording as a ROS 2 bag: an MCAP file of the ros2 profile "
                          "(/tf, /joint_states, /qchain/pressures, /qchain/markers) for ros2 bag play, Foxglove and "
                          "rosbags.", argv, lambda parser: parser.add_argument(
                              "-o", "--out", type=file_argument, required=True, help="the bag to write (.mcap)"))
    try:
        refuse_recording(args.out, args.log, f"-o {args.out} is the recording")
        try:
            check_output_path("-o", args.out)
        except BadInput as exc:
            raise LoggingError(str(exc)) from None
        count = export_ros2(args.log, args.out, limits=limits)
    except _ERRORS as exc:
        return _error("export", exc)
    print(printable(f"wrote {args.out} (ROS 2 bag, {count} messages)"))
    return 0


def add_logging_arguments(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """Add ``--mcap OUT``, ``--serve``, ``--connect URL``, ``--rrd OUT``, ``--bind HOST``,
    ``--rerun-rate HZ`` and ``--realtime`` to ``parser`` (one argument group, returned)."""
    g = parser.add_argument_group(
        "recording and viewing",
        "Every run is recorded to an MCAP file (default runs/<scene>-<timestamp>.mcap); replay it with "
        "`qchain replay FILE`, or open it in Foxglove (layout: `qchain layout FILE`).",
    )
    g.add_argument("--mcap", metavar="OUT", type=Path, default=None,
                   help="MCAP recording path (default: runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap)")
    g.add_argument("--serve", action="store_true", help="serve a live Rerun web viewer on 127.0.0.1 and print its URL")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    g.add_argument("--rrd", metavar="OUT", type=Path, default=None, help="also write a Rerun .rrd file")
    g.add_argument("--bind", default=DEFAULT_BIND, help="address --serve listens on (default 127.0.0.1: this machine "
                   "only)")
    g.add_argument("--rerun-rate", metavar="HZ", type=float, default=None,
                   help="send the viewer/.rrd at most HZ samples a simulated second (default: all; the MCAP always "
                        "gets all)")
    g.add_argument("--realtime", action="store_true",
                   help="pace the run to the wall clock (1 simulated second a second), to watch it live")
    return g


def logger_from_args(args: argparse.Namespace, info: RunInfo, default_mcap_path: str | os.PathLike | None = None,
                     **kwargs) -> RunLogger:
    """The :class:`RunLogger` the flags of :func:`add_logging_arguments` ask for: the recording
    at ``--mcap``, else ``default_mcap_path``, else :func:`default_mcap_path` of
    ``info.scene_path``; ``kwargs`` go to :class:`RunLogger` (with ``--serve`` it lingers unless
    ``linger=False``). ``ValueError`` for ``--serve`` with ``--connect``, :class:`LoggingError`
    for an output path that cannot be used."""
    serve = bool(getattr(args, "serve", False))
    connect = getattr(args, "connect", None)
    if serve and connect:
        raise ValueError("--serve and --connect exclude each other")
    path = getattr(args, "mcap", None)
    if path is None:
        path = default_mcap_path if default_mcap_path is not None else _default_mcap_path(info.scene_path)
    kwargs.setdefault("linger", serve)
    kwargs.setdefault("rerun_rate", getattr(args, "rerun_rate", None))
    return RunLogger(info, path, serve=serve, connect=connect, rrd=getattr(args, "rrd", None),
                     bind=getattr(args, "bind", DEFAULT_BIND), **kwargs)
