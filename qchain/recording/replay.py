"""Re-logging a recording into Rerun (``qchain replay``), making a killed run's recording
whole (``qchain recover``) and writing its Foxglove layout (``qchain layout``)."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import uuid
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .journal import journal_owner, journal_path
from .reader import Recording, read_recording
from .records import DEFAULT_FLUSH_INTERVAL, LoggingError, LoggingWarning, RecordingFormatError
from .rerun_sink import DEFAULT_BIND

__all__ = ["ReplaySession", "replay", "replay_main", "recover", "recover_main", "layout_main"]


@dataclass
class ReplaySession:
    """What :func:`replay` did; ``close()`` stops a served viewer.

    Attributes
    ----------
    recording : Recording
    viewer_url : str or None
        Web viewer URL while serving.
    grpc_url : str or None
    """

    recording: Recording
    viewer_url: str | None = None
    grpc_url: str | None = None
    _sink: Any = None

    @property
    def trajectory(self):
        return self.recording.to_trajectory()

    def close(self) -> None:
        if self._sink is not None:
            self._sink.close()
            self._sink = None

    def __enter__(self) -> ReplaySession:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _warn_incomplete(recording: Recording, stacklevel: int) -> None:
    if recording.truncated:
        where = f"t = {recording.t[-1]:.6g} s (step {int(recording.step[-1])})" if len(recording) else "its start"
        warnings.warn(f"qchain.logging: {recording.path} is truncated; replaying up to {where} ("
                      f"{recording.stop_reason})", LoggingWarning, stacklevel=stacklevel)
    for g in recording.gaps:
        warnings.warn(f"qchain.logging: {recording.path}: {g.describe()}", LoggingWarning, stacklevel=stacklevel)


def replay(path: str | os.PathLike, serve: bool = False, connect: str | None = None,
           rrd: str | os.PathLike | None = None, *, bind: str = DEFAULT_BIND, grpc_port: int | None = None,
           web_port: int | None = None, batch: int = 2000, quiet: bool = False) -> ReplaySession:
    """Re-log a qchain MCAP recording into Rerun with its original simulation times.

    Parameters
    ----------
    path : path
        The recording.
    serve, connect, rrd
        As for :class:`RunLogger`: host a viewer on ``bind`` (loopback by default), send
        to a running viewer, write a ``.rrd`` file. At least one must be given.
    batch : int
        Records a ``send_columns`` batch.

    Returns
    -------
    ReplaySession
        Keep it (and the process) alive while a served viewer is used; ``close()`` it
        after. A truncated or damaged recording warns (:class:`LoggingWarning`) what is
        missing.

    Raises
    ------
    RecordingFormatError
        Not a qchain MCAP recording.
    ValueError
        No target given, or both ``serve`` and ``connect``.
    """
    from .rerun_sink import RerunSink

    if not (serve or connect or rrd):
        raise ValueError("replay needs a target: serve=True, connect=URL or rrd=PATH")
    if serve and connect:
        raise ValueError("serve and connect exclude each other")
    recording = read_recording(path)
    _warn_incomplete(recording, 3)
    if rrd is not None:
        Path(rrd).parent.mkdir(parents=True, exist_ok=True)
    info = recording.info
    if info.duration is None and len(recording):
        info.duration = float(recording.t[-1]) if recording.t[-1] > 0 else None
    sink = RerunSink(info, serve=serve, connect=connect, rrd=rrd, bind=bind, grpc_port=grpc_port,
                     web_port=web_port, recording_id=recording.metadata.get("recording_id") or str(uuid.uuid4()),
                     warn=lambda m: warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=3))
    b = recording.batch()
    step = max(1, int(batch))
    for a in range(0, len(recording), step):
        sink.write_batch(b.take(slice(a, a + step)))
    sink.finish()
    session = ReplaySession(recording, sink.viewer_url, sink.grpc_url, sink if sink.serving else None)
    if not sink.serving:
        sink.close()
    elif session.viewer_url and not quiet:
        print(f"qchain: replay served at {session.viewer_url}  (open it in a browser)", file=sys.stderr, flush=True)
    return session


def recover(path: str | os.PathLike) -> Recording:
    """Make the recording of a killed run whole: read what the file and the run's journal
    hold together, write it as a complete recording in place of the file (atomically),
    remove the journal. Returns the recording as written.

    Raises
    ------
    LoggingError
        A run is still writing ``path`` (its journal is locked).
    RecordingFormatError
        Neither the file nor a journal holds a qchain recording.
    """
    from .mcap_sink import McapSink

    path = Path(path)
    jp = journal_path(path)
    owner = journal_owner(jp)
    if owner is not None:
        raise LoggingError(f"a run{f' (pid {owner})' if owner else ''} is still writing {path}; recover it after it "
                           "ends or is killed")
    if not path.exists() and not jp.exists():
        raise FileNotFoundError(f"{path}: no such recording, and no journal of a run writing it")
    rec = read_recording(path)  # (without the file, from the journal alone: the writer never started)
    out = rec.outcome or {"success": "false", "status": "-1", "message": ""}
    message = out.get("message") or "the run was killed"
    if rec.recovered or rec.truncated:
        message += f" (recovered by `qchain recover`: {len(rec)} records, {rec.recovered} from the journal)"
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".recovering", dir=path.parent)
    os.close(fd)
    try:
        sink = McapSink(tmp, rec.info, recording_id=rec.metadata.get("recording_id", str(uuid.uuid4())),
                        flush_interval=DEFAULT_FLUSH_INTERVAL, flush_wall_interval=1e9)
        sink.write_batch(rec.batch())
        sink.finish({"success": out.get("success") == "true", "status": int(out.get("status", -1)),
                     "message": message, "nfev": int(out.get("nfev", 0) or 0)})
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    if jp.exists():
        jp.unlink()
    return read_recording(path)


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
    for d in rec.damage:
        if "metadata" in d:
            lines.append(f"damaged: {d}")
    return lines


def replay_main(argv: Sequence[str] | None = None) -> int:
    """``qchain replay LOG.mcap [--serve | --connect URL | --rrd OUT]``; returns the exit code.

    Without a target the replay is served on 127.0.0.1 (``--serve``) until Ctrl-C.
    Exit codes: 0 done, 2 not a (readable) qchain recording or bad arguments.
    """
    parser = argparse.ArgumentParser(prog="qchain replay", description="Re-log a qchain MCAP recording into Rerun "
                                     "with its original simulation times.")
    parser.add_argument("log", type=Path, help="the .mcap recording")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--serve", action="store_true", help="serve a web viewer on 127.0.0.1 (the default)")
    target.add_argument("--connect", metavar="URL", help="send to a running Rerun viewer (rerun+http://HOST:PORT/proxy)")
    target.add_argument("--rrd", metavar="OUT", type=Path, help="write a Rerun .rrd file")
    parser.add_argument("--bind", default=DEFAULT_BIND, help="address to serve on (default 127.0.0.1: this machine only)")
    args = parser.parse_args(argv)
    serve = args.serve or not (args.connect or args.rrd)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LoggingWarning)
            session = replay(args.log, serve=serve, connect=args.connect, rrd=args.rrd, bind=args.bind, quiet=True)
    except (RecordingFormatError, FileNotFoundError, IsADirectoryError) as exc:
        print(f"qchain replay: error: {exc}", file=sys.stderr)
        return 2
    rec = session.recording
    lines = _summary(rec)
    lines[0] = "replayed " + lines[0] if len(rec) else lines[0]
    print("\n".join(lines))
    if args.rrd:
        print(f"wrote {args.rrd}")
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
    return 0


def recover_main(argv: Sequence[str] | None = None) -> int:
    """``qchain recover LOG.mcap``: make a killed run's recording whole from its journal."""
    parser = argparse.ArgumentParser(prog="qchain recover", description="Make the recording of a killed run whole: "
                                     "the records its journal (LOG.mcap.journal) holds are written into it.")
    parser.add_argument("log", type=Path, help="the .mcap recording")
    args = parser.parse_args(argv)
    try:
        rec = recover(args.log)
    except (LoggingError, FileNotFoundError, IsADirectoryError) as exc:
        print(f"qchain recover: error: {exc}", file=sys.stderr)
        return 2
    print("recovered " + "\n".join(_summary(rec)))
    return 0


def layout_main(argv: Sequence[str] | None = None) -> int:
    """``qchain layout LOG.mcap [-o layout.json]``: the Foxglove layout of a recording."""
    from .foxglove_layout import layout_json

    parser = argparse.ArgumentParser(prog="qchain layout", description="Write the Foxglove layout of a recording "
                                     "(3D arm, frame tree, named plots); import it in Foxglove's layout menu.")
    parser.add_argument("log", type=Path, help="the .mcap recording")
    parser.add_argument("-o", "--out", type=Path, default=None, help="output file (default: standard output)")
    args = parser.parse_args(argv)
    try:
        rec = read_recording(args.log)
    except (RecordingFormatError, FileNotFoundError, IsADirectoryError) as exc:
        print(f"qchain layout: error: {exc}", file=sys.stderr)
        return 2
    text = layout_json(rec.info, rec.q.shape[1], rec.v.shape[1], rec.p.shape[1])
    if args.out is None:
        print(text)
    else:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
        print(f"wrote {args.out}")
    return 0
