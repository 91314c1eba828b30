"""Re-logging a recording into Rerun (``qchain replay``), making a killed run's recording
whole (``qchain recover``) and writing its Foxglove layout (``qchain layout``).

Sending to a viewer at ``--connect URL`` runs in a child process of its own, killed past
a deadline: the Rerun SDK's gRPC client waits forever for a peer that stops answering, even
at interpreter exit (docs/recording.md, "Files from anywhere")."""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import tempfile
import uuid
import warnings
from contextlib import suppress
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from .bounded import ReadLimits
from .journal import journal_owner, journal_path
from .reader import Recording, read_recording
from .records import DEFAULT_FLUSH_INTERVAL, LoggingError, LoggingWarning
from .rerun_sink import CONNECT_TIMEOUT, DEFAULT_BIND, RerunSink, _bounded, _die_with_parent, probe_viewer

__all__ = ["ReplaySession", "replay", "recover", "probe_viewer", "CONNECT_TIMEOUT"]


@dataclass
class ReplaySession:
    """What :func:`replay` did; ``close()`` stops a served viewer.

    Attributes
    ----------
    recording : Recording
    viewer_url : str or None
        Web viewer URL while serving.
    grpc_url : str or None
    problems : list of str
        What did not work out (each also warned as a LoggingWarning).
    sent : bool or None
        Whether the viewer at ``connect`` took the recording (None: no ``connect``).
    """

    recording: Recording
    viewer_url: str | None = None
    grpc_url: str | None = None
    _sink: Any = None
    problems: list = field(default_factory=list)
    sent: bool | None = None

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


class _IncompleteWarning(LoggingWarning):
    """What a recording lacks (the command line says it in its summary instead)."""


def _warn_incomplete(recording: Recording, stacklevel: int) -> None:
    if recording.truncated:
        where = f"t = {recording.t[-1]:.6g} s (step {int(recording.step[-1])})" if len(recording) else "its start"
        warnings.warn(f"qchain.logging: {recording.path} is truncated; replaying up to {where} ("
                      f"{recording.stop_reason})", _IncompleteWarning, stacklevel=stacklevel)
    for g in recording.gaps:
        warnings.warn(f"qchain.logging: {recording.path}: {g.describe()}", _IncompleteWarning, stacklevel=stacklevel)
    if recording.nonfinite:
        warnings.warn(f"qchain.logging: {recording.path} holds non-finite values (null in the file, read as NaN): "
                      + "; ".join(recording.nonfinite), _IncompleteWarning, stacklevel=stacklevel)
    if recording.disorder:
        warnings.warn(f"qchain.logging: {recording.path}: {recording.disorder}", _IncompleteWarning,
                      stacklevel=stacklevel)


# --------------------------------------------------------------------------------------
# A viewer at --connect: answered within a timeout, fed by a child process with a deadline
# --------------------------------------------------------------------------------------

#: Seconds the sending child may take beyond that to start and read the recording.
SEND_STARTUP = 30.0


def _send_main() -> None:
    """The sending child: ``python -c "...; _send_main()" PARENT_PID PATH URL TIMEOUT LIMITS``.

    Prints ``sent`` or ``failed: WHY`` on its standard output and ends with ``os._exit``
    (the Rerun SDK would wait for a stalled viewer forever at interpreter exit)."""
    parent, path, url, timeout, limits = int(sys.argv[1]), sys.argv[2], sys.argv[3], float(sys.argv[4]), sys.argv[5]
    _die_with_parent(signal.SIGKILL)
    if os.getppid() != parent:  # the parent is gone already
        os._exit(1)
    code, line = 1, "failed: nothing sent"
    try:
        rec = read_recording(path, limits=ReadLimits(**json.loads(limits)))
        problems: list[str] = []
        sink = _rerun_sink(rec, connect=url, warn=problems.append)
        if sink.rec is None:
            line = "failed: " + ("; ".join(problems) or "no connection")
        else:
            _write_all(rec, sink, 2000)
            try:
                sink.rec.flush(timeout_sec=timeout)
                code, line = 0, "sent"
            except RuntimeError:
                line = f"failed: the viewer did not take the recording within {timeout:g} s"
            else:  # close the connection cleanly, if that is quick
                _bounded(sink.rec.disconnect, 2.0, "qchain-replay-disconnect")
    except Exception as exc:  # reported to the parent, which warns
        line = f"failed: {type(exc).__name__}: {exc}"
    sys.stdout.write(line.replace("\n", " ") + "\n")
    sys.stdout.flush()
    os._exit(code)


def _rerun_sink(rec: Recording, **kwargs) -> RerunSink:
    """A :class:`RerunSink` for the recording ``rec`` (its id; its plots' time axis the
    recording's times where the run did not say its duration)."""
    info = rec.info
    if info.duration is None and len(rec):
        info.duration = float(rec.t[-1]) if rec.t[-1] > 0 else None
    return RerunSink(info, recording_id=rec.metadata.get("recording_id") or str(uuid.uuid4()), **kwargs)


def _write_all(rec: Recording, sink: RerunSink, batch: int) -> None:
    """Every record of ``rec`` to ``sink``, ``batch`` records a ``send_columns`` batch."""
    b = rec.batch()
    for a in range(0, len(rec), batch):
        sink.write_batch(b.take(slice(a, a + batch)))


def _send(path: str, url: str, timeout: float, limits: ReadLimits) -> str | None:
    """Send the recording at ``path`` to the viewer at ``url`` from a child process; None
    when done, else why not. The child is killed if it is not done in time."""
    code = "from qchain.recording.replay import _send_main; _send_main()"
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
    proc = subprocess.Popen([sys.executable, "-c", code, str(os.getpid()), path, url, repr(float(timeout)),
                             json.dumps(asdict(limits))], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    deadline = timeout + SEND_STARTUP
    try:
        out, _ = proc.communicate(timeout=deadline)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return f"the viewer did not take the recording within {deadline:g} s: stopped"
    finally:
        if proc.poll() is None:  # an interrupt: the child goes with it
            proc.kill()
            proc.wait()
    line = out.decode(errors="replace").strip().splitlines()[-1:] or [""]
    if line[0] == "sent" and proc.returncode == 0:
        return None
    return line[0].removeprefix("failed: ") or f"the sending process ended with code {proc.returncode}"


def _check_rrd(rrd, recording_path) -> None:
    """Refuse an ``.rrd`` path that cannot be written, or that is the recording itself."""
    from .options import check_outputs, refuse_recording

    refuse_recording(rrd, recording_path, f"--rrd {rrd} is the recording being replayed")
    try:
        mode = os.stat(rrd).st_mode
    except OSError:
        mode = None
    if mode is not None and not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        raise LoggingError(f"--rrd {rrd} exists and is not a regular file (a FIFO or a device): refused")
    check_outputs(None, rrd, min_free=1 << 20)


def replay(path: str | os.PathLike, serve: bool = False, connect: str | None = None,
           rrd: str | os.PathLike | None = None, *, bind: str = DEFAULT_BIND, grpc_port: int | None = None,
           web_port: int | None = None, batch: int = 2000, quiet: bool = False, limits: ReadLimits | None = None,
           timeout: float = CONNECT_TIMEOUT) -> ReplaySession:
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
    limits : ReadLimits or None
        What reading the recording may cost.
    timeout : float, s
        How long a viewer at ``connect`` has to answer, and then to take the recording
        (sent from a child process, killed if it is not done ``timeout`` + 30 s after it
        started).

    Returns
    -------
    ReplaySession
        Keep it (and the process) alive while a served viewer is used; ``close()`` it
        after. A truncated or damaged recording warns (:class:`LoggingWarning`) what is
        missing; a viewer that cannot be reached or does not answer in time is warned and
        listed in ``problems``.

    Raises
    ------
    TypeError
        ``path`` is not a path.
    RecordingFormatError
        Not a (readable) qchain MCAP recording.
    LoggingError
        An ``.rrd`` path that cannot be written (or is the recording itself), or an ``.rrd``
        file that was not written.
    ValueError
        No target given, or both ``serve`` and ``connect``.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"replay: path must be a path (str or os.PathLike), got "
                        f"{'None' if path is None else type(path).__name__}")
    if not (serve or connect or rrd):
        raise ValueError("replay needs a target: serve=True, connect=URL or rrd=PATH")
    if serve and connect:
        raise ValueError("serve and connect exclude each other")
    if connect is not None and not isinstance(connect, str):
        raise TypeError(f"replay: connect must be a URL (str), got {type(connect).__name__}")
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout <= 3600:
        raise ValueError(f"replay: timeout must be a number of seconds > 0 and <= 3600, got {timeout!r}")
    limits = ReadLimits() if limits is None else limits
    if rrd is not None:
        _check_rrd(rrd, path)
    recording = read_recording(path, limits=limits)
    _warn_incomplete(recording, 3)
    problems: list[str] = []

    def problem(msg: str) -> None:
        problems.append(msg)
        warnings.warn(f"qchain.logging: {msg}", LoggingWarning, stacklevel=4)

    sent = None
    if connect:
        why = probe_viewer(connect, timeout)
        if why is None:
            why = _send(os.fspath(path), connect, timeout, limits)
        sent = why is None
        if not sent:
            problem(f"no Rerun viewer took the recording at {connect} ({why}); nothing was sent there")
    session = ReplaySession(recording, problems=problems, sent=sent)
    if not (serve or rrd):
        return session
    sink = None
    try:
        sink = _rerun_sink(recording, serve=serve, rrd=rrd, bind=bind, grpc_port=grpc_port, web_port=web_port,
                           warn=problem)
        _write_all(recording, sink, max(1, int(batch)))
        sink.finish()
    except BaseException as exc:
        if sink is not None:
            sink.close()
        if isinstance(exc, RuntimeError):  # the Rerun SDK's errors: a file that cannot be written, ...
            raise LoggingError(f"the replay into Rerun failed ({exc})" + (f"; {rrd} is not complete" if rrd
                                                                          else "")) from None
        raise
    session.viewer_url, session.grpc_url = sink.viewer_url, sink.grpc_url
    session._sink = sink if sink.serving else None
    if not sink.serving:
        sink.close()
    elif session.viewer_url and not quiet:
        print(f"qchain: replay served at {session.viewer_url}  (open it in a browser)", file=sys.stderr, flush=True)
    if rrd is not None:
        try:
            written = os.path.getsize(rrd) > 0
        except OSError:
            written = False
        if not written:
            session.close()
            raise LoggingError(f"the .rrd file {rrd} was not written")
    return session


def recover(path: str | os.PathLike, *, limits: ReadLimits | None = None) -> Recording:
    """Make the recording of a killed run whole: read what the file and the run's journal
    hold together, write it as a complete recording in place of the file (atomically),
    remove the journal. Returns the recording as written. What the old file lacked (gaps
    left by damage, non-finite values) is said in the new one's outcome message. A complete
    file without a journal is left as it is (nothing to recover).

    Raises
    ------
    TypeError
        ``path`` is not a path.
    LoggingError
        A run is still writing ``path`` (its journal is locked), or the recovered recording
        cannot be written next to it.
    RecordingFormatError
        Neither the file nor a journal holds a (readable) qchain recording.
    FileNotFoundError
    """
    from .mcap_sink import McapSink

    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"recover: path must be a path (str or os.PathLike), got "
                        f"{'None' if path is None else type(path).__name__}")
    path = Path(path)
    jp = journal_path(path)
    owner = journal_owner(jp)
    if owner is not None:
        raise LoggingError(f"a run{f' (pid {owner})' if owner else ''} is still writing {path}; recover it after it "
                           "ends or is killed")
    if not os.path.lexists(path) and not os.path.lexists(jp):
        raise FileNotFoundError(f"{path}: no such recording, and no journal of a run writing it")
    # a link is kept: the file it names is replaced (in that file's folder)
    target = Path(os.path.realpath(path)) if os.path.islink(path) else path
    if target is not path:  # the file a link names is replaced: it must be no journal, nor have one of its own
        if os.path.lexists(jp) and target == Path(os.path.realpath(jp)):
            raise LoggingError(f"{path} is a link to its own journal {jp}: nothing was changed (recover a path of its "
                               "own: move the journal to NAME.mcap.journal and recover NAME.mcap)")
        tj = journal_path(target)
        if os.path.lexists(tj) and Path(os.path.realpath(tj)) != Path(os.path.realpath(jp)):
            raise LoggingError(f"{path} is a link to {target}, which has a journal of its own ({tj}): nothing was "
                               f"changed; recover {target}")
    # (without the file, from the journal alone: the writer never started)
    rec = read_recording(path, limits=limits)
    if not (rec.truncated or rec.recovered or rec.gaps or os.path.lexists(jp)):
        return rec  # a complete file and no journal: nothing to recover, the file is left as it is
    if rec.journal_unread:
        raise LoggingError(f"{path}: its journal {jp} cannot be (wholly) merged ({rec.journal_unread}); nothing was "
                           "changed (the journal would be lost): move it away to recover the file without it")
    out = rec.outcome or {"success": "false", "status": "-1", "message": ""}
    message = out.get("message") or "the run was killed"
    if rec.recovered or rec.truncated:
        message += f" (recovered by `qchain recover`: {len(rec)} records, {rec.recovered} from the journal)"
    for g in rec.gaps:
        message += f"; before recovery {g.describe()}"
    tmp = None
    try:
        # a short name of its own (not the file's name plus a suffix: that can pass the file
        # system's limit for a name check_outputs accepts), hidden, in the same folder
        fd, tmp = tempfile.mkstemp(prefix=".recovering-", dir=target.parent)
        os.close(fd)
        sink = McapSink(tmp, rec.info, recording_id=rec.metadata.get("recording_id", str(uuid.uuid4())),
                        flush_interval=DEFAULT_FLUSH_INTERVAL, flush_wall_interval=1e9)
        try:
            sink.write_batch(rec.batch())
            sink.finish({"success": out.get("success") == "true" and not rec.gaps,
                         "status": int(out.get("status", -1)), "message": message,
                         "nfev": int(out.get("nfev", 0) or 0)})
        finally:
            sink.abandon()
        with suppress(OSError):  # the file's own mode (mkstemp's is 0600)
            os.chmod(tmp, stat.S_IMODE(os.stat(target).st_mode) if os.path.exists(target) else 0o666 & ~_umask())
        os.replace(tmp, target)
    except OSError as exc:
        raise LoggingError(f"cannot write the recovered recording of {path} ({exc.strerror or exc}); the file and its "
                           "journal are as they were") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    if os.path.lexists(jp):  # (not Path.exists: a name too long for a journal raises there)
        jp.unlink()
    return read_recording(path, limits=limits)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
