"""The writer: reads records and feeds the sinks (the recording, the Rerun view).

For a file it is a process of its own (``python -m qchain.recording.writer``) that reads the
journal as it grows, controlled over a socket pair with :mod:`multiprocessing.connection`;
for an in-memory stream, a thread fed through a queue. A viewer at ``connect`` is fed from a
thread of its own (:class:`RemoteViewer`), since the Rerun SDK can hold a sender without end:
see docs/recording.md, "How it is built". The process ends with ``os._exit`` within
:data:`TEARDOWN_LIMIT` s of its leave of Rerun."""

from __future__ import annotations

import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from contextlib import suppress
from multiprocessing.connection import Connection
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .records import Batch, RecordLayout, RunInfo
from .rerun_sink import _bounded, _reap

__all__ = ["Sinks", "RemoteViewer", "ThreadWriter", "launch", "prepare_writer", "take_spare", "WRITER_POLL",
           "TEARDOWN_LIMIT", "BEAT_INTERVAL"]

#: s between two reads of the journal when the writer is idle.
WRITER_POLL = 0.02
#: Wall time (s) records gather in the writer before they go to Rerun in one batch.
DEFAULT_RERUN_LATENCY = 0.2
#: s the writer's leave of Rerun (disconnect, servers stopped) may take before it exits anyway.
TEARDOWN_LIMIT = 5.0
#: s between two signs of life of the writer while it finishes a recording.
BEAT_INTERVAL = 1.0


class RemoteViewer:
    """A Rerun viewer at a URL, fed by a thread of its own.

    The Rerun SDK waits without end for a peer that stops taking data: once about 100 MB
    are queued its ``send_columns`` blocks, and its ``flush`` (whatever its timeout then)
    and ``disconnect`` wait for the peer. Here only the feeding thread can be held up: a
    viewer that has taken nothing for ``timeout`` s (a call of the thread that has not
    returned, a flush that timed out) is given up, said once with ``warn``, and fed no more.

    Parameters
    ----------
    sink : RerunSink
        Connected to the viewer (``sink.rec`` set).
    url : str
    timeout : float, s
    warn : callable(str)
    """

    def __init__(self, sink, url: str, timeout: float, warn):
        self.sink, self.url, self.timeout, self.warn = sink, url, float(timeout), warn
        self.stalled: str | None = None  # why the viewer was given up
        self.fed = False
        self._cv = threading.Condition()
        self._ops: list = []
        self._busy_since: float | None = None  # when the thread's current Rerun call began
        self._thread = threading.Thread(target=self._loop, name="qchain-rerun-remote", daemon=True)
        self._thread.start()

    # -- the caller's side (never blocks on Rerun) --------------------------------------

    def put(self, b: Batch) -> None:
        """Queue a batch for the viewer (dropped once it is given up)."""
        if self.stalled is not None or self._stuck():
            return
        with self._cv:
            self._ops.append(("batch", b))
            self._cv.notify()
        self.fed = True

    def flush(self) -> str | None:
        """Wait until the viewer has taken everything queued so far; None when it has,
        else why not (the viewer is then given up)."""
        return self._do("flush", self.timeout + 2.0)

    def finish(self) -> str | None:
        """Flush, then disconnect (bounded); None when the viewer took everything. (A
        flush may return while the data only sit in the system's buffers: a peer that
        stalled then holds the disconnect.)"""
        why = self.flush()
        if why is None and not self._do("disconnect", TEARDOWN_LIMIT, give_up=False):
            self._give_up(f"it did not close the connection within {TEARDOWN_LIMIT:g} s")
            why = self.stalled
        return why

    def close(self) -> None:
        """Stop feeding; the thread ends when its call returns (or with the process)."""
        with self._cv:
            self._ops.append(("stop", None))
            self._cv.notify()

    def _stuck(self) -> bool:
        since = self._busy_since
        if since is not None and time.monotonic() - since > self.timeout:
            self._give_up(f"it has taken no data for {self.timeout:g} s")
            return True
        return False

    def _give_up(self, why: str) -> None:
        if self.stalled is not None:
            return
        self.stalled = why
        with self._cv:
            self._ops.clear()
            self._ops.append(("stop", None))
            self._cv.notify()
        bound_exit(self.sink)  # this process's exit must not wait for that peer either
        self.warn(f"the Rerun viewer at {self.url} stopped answering ({why}) and was given up; the MCAP log is not "
                  "affected")

    def _do(self, kind: str, limit: float, give_up: bool = True):
        """Queue ``kind`` and wait for it: its result, or why not after ``limit`` s of a
        call that does not return."""
        if self.stalled is not None:
            return self.stalled if kind == "flush" else False
        box: list = []
        done = threading.Event()
        with self._cv:
            self._ops.append((kind, (box, done)))
            self._cv.notify()
        while not done.wait(0.05):
            since = self._busy_since
            if self.stalled is not None or not self._thread.is_alive():
                break
            if since is not None and time.monotonic() - since > limit:
                if give_up:
                    self._give_up(f"it has taken no data for {self.timeout:g} s")
                break
        if kind == "flush":
            if box and box[0] is not None:
                self._give_up(box[0])
            return self.stalled if not box or box[0] is not None else None
        return bool(box)

    # -- the feeding thread ---------------------------------------------------------------

    def _loop(self) -> None:
        while True:
            with self._cv:
                while not self._ops:
                    self._cv.wait()
                ops, self._ops = self._ops, []
            batches = []
            for kind, arg in ops:
                if kind == "batch":
                    batches.append(arg)
                    continue
                if batches:
                    if not self._send(Batch.concatenate(batches) if len(batches) > 1 else batches[0]):
                        return
                    batches = []
                if kind == "stop":
                    return
                box, done = arg
                self._busy_since = time.monotonic()
                try:
                    if kind == "flush":
                        try:
                            self.sink.rec.flush(timeout_sec=self.timeout)
                            box.append(None)
                        except Exception:  # the SDK's "Flush timed out"
                            box.append(f"it did not take the data within {self.timeout:g} s")
                    else:  # disconnect
                        self.sink.close()
                        box.append(True)
                finally:
                    self._busy_since = None
                    done.set()
            if batches and not self._send(Batch.concatenate(batches) if len(batches) > 1 else batches[0]):
                return

    def _send(self, b: Batch) -> bool:
        self._busy_since = time.monotonic()
        try:
            self.sink.write_batch(b)
            return True
        except Exception as exc:  # a viewer problem never stops the recording
            self.stalled = self.stalled or f"Rerun failed: {type(exc).__name__}: {exc}"
            self.warn(f"Rerun logging to {self.url} failed and is switched off ({type(exc).__name__}: {exc})")
            return False
        finally:
            self._busy_since = None


def bound_exit(sink) -> None:
    """The stream of ``sink`` is never waited for again, nor (beyond TEARDOWN_LIMIT) this
    process's exit."""
    sink.abandon()


class Sinks:
    """The sinks one writer feeds: an MCAP recording, a Rerun view of this machine (served,
    an ``.rrd`` file) and a Rerun viewer at a URL (:class:`RemoteViewer`)."""

    def __init__(self, cfg: dict, mcap_stream: BinaryIO | None, warn):
        from .mcap_sink import McapSink

        self.info = RunInfo.from_json(cfg["info"])
        self.warn = warn
        self.mcap: McapSink | None = None
        self.rerun = None  # the Rerun view of this machine: served, .rrd
        self.remote: RemoteViewer | None = None  # a viewer at a URL
        out = mcap_stream if mcap_stream is not None else cfg.get("mcap")
        if out is not None:
            self.mcap = McapSink(out, self.info, recording_id=cfg["recording_id"],
                                 flush_interval=cfg["flush_interval"], flush_wall_interval=cfg["flush_wall_interval"])
        self._rr_thread: threading.Thread | None = None
        if cfg.get("connect"):  # before "ready": a viewer that does not answer is said first
            self._start_remote(cfg)
        if cfg.get("serve"):  # before "ready": the URL first
            self._start_rerun(cfg)
        elif cfg.get("rrd"):  # a .rrd file only: Rerun (a large import) comes up while the MCAP is written
            self._rr_thread = threading.Thread(target=self._start_rerun, args=(cfg,), name="qchain-rerun-start",
                                               daemon=True)
            self._rr_thread.start()
        self.n_records = 0
        self.last_t: float | None = None
        rate = cfg.get("rerun_rate")
        self._rr_dt = 0.0 if not rate else 1.0 / float(rate)
        self._rr_next = -math.inf
        # Rerun costs a few ms a send_columns batch whatever its size, so its records gather
        # here for up to rerun_latency s of wall time (the MCAP gets them at once)
        self._rr_latency = float(cfg.get("rerun_latency", DEFAULT_RERUN_LATENCY))
        self._rr_pending: list[Batch] = []
        self._rr_count = 0
        self._rr_wall0 = 0.0

    def _start_remote(self, cfg: dict) -> None:
        from .rerun_sink import CONNECT_TIMEOUT, RerunSink

        url = cfg["connect"]
        timeout = float(cfg.get("viewer_timeout", CONNECT_TIMEOUT))
        try:
            sink = RerunSink(self.info, connect=url, recording_id=cfg["recording_id"], warn=lambda m: self.warn(m),
                             viewer_timeout=timeout)
        except Exception as exc:  # no viewer: say so, keep the MCAP
            self.warn(f"Rerun could not start ({type(exc).__name__}: {exc}); the run goes on and the MCAP log is "
                      "still written")
            return
        if sink.rec is not None:
            self.remote = RemoteViewer(sink, url, timeout, lambda m: self.warn(m))

    def _start_rerun(self, cfg: dict) -> None:
        from .rerun_sink import DEFAULT_BIND, RerunSink

        try:
            self.rerun = RerunSink(self.info, serve=bool(cfg.get("serve")),
                                   rrd=cfg.get("rrd"), bind=cfg.get("bind", DEFAULT_BIND),
                                   grpc_port=cfg.get("grpc_port"), web_port=cfg.get("web_port"),
                                   recording_id=cfg["recording_id"],
                                   server_memory_limit=cfg.get("server_memory_limit", "1GiB"),
                                   warn=lambda m: self.warn(m))
        except Exception as exc:  # no viewer or .rrd: say so, keep the MCAP
            self.warn(f"Rerun could not start ({type(exc).__name__}: {exc}); the run goes on and the MCAP log is "
                      "still written")
            self.rerun = None

    def _rerun_started(self, wait: bool) -> bool:
        th = self._rr_thread
        if th is not None:
            if not wait and th.is_alive():
                return False
            th.join()
            self._rr_thread = None
        return True

    @property
    def viewer_url(self) -> str | None:
        return None if self.rerun is None else self.rerun.viewer_url

    @property
    def serving(self) -> bool:
        return self.rerun is not None and self.rerun.serving

    def write_rows(self, rows: np.ndarray, layout: RecordLayout) -> None:
        if len(rows):
            self.write_batch(Batch.from_rows(rows, layout))

    def write_batch(self, b: Batch) -> None:
        self.n_records += len(b)
        self.last_t = float(b.t[-1])
        if self.mcap is not None:
            self.mcap.write_batch(b)
        if self._rr_thread is not None or (self.rerun is not None and self.rerun.rec is not None) or \
                self.remote is not None:
            if self._rr_dt > 0.0:  # a display rate: one record every rerun_rate-th of a second
                keep = []
                nxt, dt = self._rr_next, self._rr_dt
                for i, t in enumerate(b.t.tolist()):
                    if t >= nxt - 1e-6 * dt:  # (rounding of t = k dt must not skip a sample)
                        keep.append(i)
                        nxt = t + dt
                self._rr_next = nxt
                if len(keep) < len(b):
                    b = b.take(keep)
            if len(b):
                if not self._rr_pending:
                    self._rr_wall0 = time.monotonic()
                self._rr_pending.append(b)
                self._rr_count += len(b)
                if self._rr_count >= 4096:
                    self._send_rerun()

    def _send_rerun(self, wait: bool = False) -> None:
        if not self._rerun_started(wait):
            return
        pending, self._rr_pending, self._rr_count = self._rr_pending, [], 0
        if not pending:
            return
        b = pending[0] if len(pending) == 1 else Batch.concatenate(pending)
        if self.remote is not None:
            self.remote.put(b)
        if self.rerun is None or self.rerun.rec is None:
            return
        try:
            self.rerun.write_batch(b)
        except Exception as exc:  # a viewer problem never stops the MCAP
            self.warn(f"Rerun logging failed and is switched off ({type(exc).__name__}: {exc})")
            self.rerun.close()
            self.rerun = None

    def tick(self) -> None:
        if self.mcap is not None:
            self.mcap.tick()
        if self._rr_pending and (time.monotonic() - self._rr_wall0 >= self._rr_latency or self._rerun_fresh()):
            self._send_rerun()

    def _rerun_fresh(self) -> bool:
        """Rerun is up but has had no batch yet: its first batch (the blueprint, the static
        geometry) goes at once, so a live viewer shows the arm as soon as it can."""
        th = self._rr_thread
        return ((th is None or not th.is_alive()) and self.rerun is not None and self.rerun.rec is not None
                and not self.rerun.started) or (self.remote is not None and not self.remote.fed
                                                and self.remote.stalled is None)

    def flush(self) -> dict:
        """Everything so far into the files (MCAP chunk closed) and out to the viewer."""
        self._send_rerun(wait=True)
        if self.mcap is not None:
            self.mcap.flush()
        if self.rerun is not None and self.rerun.rec is not None:
            try:
                self.rerun.rec.flush(timeout_sec=10.0)
            except Exception as exc:  # pragma: no cover - best effort
                self.warn(f"Rerun flush failed ({type(exc).__name__}: {exc})")
        if self.remote is not None:
            self.remote.flush()  # bounded; a viewer that took nothing is given up (and said)
        return {"n_records": self.n_records, "last_t": self.last_t}

    def finish(self, outcome: dict) -> dict:
        """The recording finished first, then the Rerun view of this machine (the ``.rrd``
        file finalised); a viewer at a URL is :meth:`finish_viewer`'s."""
        if self.mcap is not None:
            self.mcap.finish(outcome)
        self._send_rerun(wait=True)
        if self.rerun is not None:
            try:
                self.rerun.finish()
            except Exception as exc:  # pragma: no cover - best effort
                self.warn(f"Rerun flush failed ({type(exc).__name__}: {exc})")
        return {"n_records": self.n_records, "last_t": self.last_t}

    @property
    def viewer_pending(self) -> bool:
        """A viewer at a URL still to be given the rest of the data."""
        return self.remote is not None and self.remote.stalled is None

    def finish_viewer(self) -> str | None:
        """Give a viewer at a URL the rest (within its timeout) and disconnect from it
        (within :data:`TEARDOWN_LIMIT`); None when it took everything, else why not."""
        return None if self.remote is None else self.remote.finish()

    def abandon(self) -> None:
        if self.mcap is not None:
            self.mcap.abandon()

    def close(self) -> None:
        self._rerun_started(wait=True)
        if self.remote is not None:
            self.remote.close()
        if self.rerun is not None:
            self.rerun.close()


# --------------------------------------------------------------------------------------
# The thread writer (in-memory streams)
# --------------------------------------------------------------------------------------


class ThreadWriter:
    """Feeds :class:`Sinks` from a queue on a thread of this process."""

    def __init__(self, cfg: dict, stream: BinaryIO, warn, max_queue: int):
        startup: list[str] = []
        self.sinks = Sinks(cfg, stream, startup.append)
        self.sinks.warn = warn
        for m in startup:
            warn(m)
        self.max_queue = int(max_queue)
        self.pending = 0  # records queued, not written yet
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.summary: dict | None = None
        self.broken: str | None = None
        self.thread = threading.Thread(target=self._loop, name="qchain-log-writer", daemon=True)
        self.thread.start()

    def put_rows(self, rows: np.ndarray, layout: RecordLayout) -> None:
        while self.pending >= self.max_queue and self.thread.is_alive():  # bounded: wait rather than grow
            time.sleep(0.0005)
        self.pending += len(rows)
        self.q.put(("R", rows, layout))

    def flush(self, timeout: float) -> dict | None:
        box: list = []
        done = threading.Event()
        self.q.put(("F", box, done))
        return box[0] if done.wait(timeout) and box else None

    def end(self, outcome: dict) -> dict:
        self.q.put(("E", outcome))
        while self.thread.is_alive():
            self.thread.join(0.2)
        return self.summary or {}

    def _loop(self) -> None:
        q, sinks = self.q, self.sinks
        outcome = None
        try:
            while outcome is None:
                try:
                    items = [q.get(timeout=0.25)]
                except queue.Empty:
                    sinks.tick()
                    continue
                while len(items) < 1024:
                    try:
                        items.append(q.get_nowait())
                    except queue.Empty:
                        break
                for item in items:
                    if item[0] == "R":
                        sinks.write_rows(item[1], item[2])
                        self.pending -= len(item[1])
                    elif item[0] == "F":
                        item[1].append(sinks.flush())
                        item[2].set()
                    elif item[0] == "E":
                        outcome = item[1]
                        break
                sinks.tick()
        except Exception as exc:
            self.broken = f"the log writer failed ({type(exc).__name__}: {exc})"
            outcome = {"success": False, "status": -1, "message": self.broken}
        try:
            self.summary = sinks.finish(outcome)
        except Exception as exc:  # pragma: no cover - a stream that fails
            self.broken = f"the log writer could not finish ({type(exc).__name__}: {exc})"
        sinks.finish_viewer()  # bounded; a viewer given up is warned of


# --------------------------------------------------------------------------------------
# The writer process
# --------------------------------------------------------------------------------------


def _drain(journal, sinks: Sinks, final: bool = False, beat=None) -> None:
    for rows in journal.poll(final=final):
        sinks.write_rows(rows, journal.layout)
        if beat is not None:
            beat()


_SEND_LOCK = threading.Lock()  # the feeding thread of a viewer may warn while the main thread sends


def _send(conn: Connection, msg) -> bool:
    """Send to the simulating process; False when it is gone."""
    try:
        with _SEND_LOCK:
            conn.send(msg)
        return True
    except OSError:
        return False


def process_main(fd: int) -> int:
    """Entry point of the writer process; ``fd`` is its end of the control socket pair."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the simulating process decides when to stop
    conn = Connection(fd)
    with suppress(ImportError):
        import foxglove.messages  # noqa: F401  (imports first: they take most of the start-up)
        import mcap.writer  # noqa: F401
        import orjson  # noqa: F401
    try:
        kind, cfg = conn.recv()
    except (EOFError, OSError):
        return 2
    if kind != "config":
        _send(conn, ("error", {"message": "the log writer got no configuration"}))
        return 2
    if cfg.get("cwd"):  # a spare writer started in another working folder: relative paths are the run's
        with suppress(OSError):
            os.chdir(cfg["cwd"])
    from .journal import JournalReader

    startup: list[str] = []
    gone = threading.Event()  # the simulating process no longer listens

    def warn_live(msg: str) -> None:
        """To the simulating process, which warns (once, in its own words); else to stderr."""
        if gone.is_set() or not _send(conn, ("warning", msg)):
            gone.set()
            print(f"qchain.logging: warning: {msg}", file=sys.stderr, flush=True)

    last_beat = [0.0]

    def beat() -> None:
        """A sign of life while the simulating process waits for the end."""
        now = time.monotonic()
        if now - last_beat[0] >= BEAT_INTERVAL and not gone.is_set():
            last_beat[0] = now
            if not _send(conn, ("progress", sinks.n_records)):
                gone.set()

    try:
        sinks = Sinks(cfg, None, startup.append)
        journal = JournalReader(cfg["journal"])
    except Exception as exc:
        _send(conn, ("error", {"message": f"{type(exc).__name__}: {exc}"}))
        return 2
    sinks.warn = warn_live
    # the simulating process may be gone already (killed while this process started): then
    # the journal holds everything it logged, and the recording is finished from it below
    alive = _send(conn, ("ready", {"viewer_url": sinks.viewer_url,
                                   "grpc_url": getattr(sinks.rerun, "grpc_url", None),
                                   "warnings": startup, "pid": os.getpid(),
                                   "web_pid": getattr(getattr(sinks.rerun, "web", None), "pid", None)}))
    poll = float(cfg.get("poll", WRITER_POLL))
    outcome = None
    try:
        while outcome is None and alive:
            _drain(journal, sinks)
            sinks.tick()
            try:
                if not conn.poll(poll):
                    continue
                kind, body = conn.recv()
            except (EOFError, OSError):
                alive = False
                break
            if kind == "flush":
                _drain(journal, sinks, beat=beat)
                alive = _send(conn, ("flushed", sinks.flush()))
            elif kind == "end":
                body = dict(body)
                # the journal's end is waited for only where it was written (a full disk or a file
                # size limit stops it: then the records there are all there will be)
                deadline = time.monotonic() + (60.0 if body.pop("journal_finished", True) else 0.0)
                while not journal.finished and time.monotonic() < deadline:
                    _drain(journal, sinks, final=False, beat=beat)
                    beat()
                    if not journal.finished:
                        time.sleep(0.005)
                _drain(journal, sinks, final=True, beat=beat)
                outcome = dict(body)
        if outcome is None:  # the simulating process is gone: the journal holds all it logged
            gone.set()
            _drain(journal, sinks, final=True)
            out = journal.outcome
            outcome = ({"success": out.get("success") == "true", "status": int(out.get("status", -1)),
                        "message": out.get("message", ""), "nfev": int(out.get("nfev", 0))} if out else
                       {"success": False, "status": -1,
                        "message": "the simulating process ended without closing its log (killed?)"})
        beat()
        summary = sinks.finish(outcome)
    except Exception as exc:  # the disk full and the like: say so; the journal keeps the records
        msg = f"the log writer failed: {type(exc).__name__}: {exc}"
        print(f"qchain.logging: warning: {msg}", file=sys.stderr, flush=True)
        sinks.abandon()
        _send(conn, ("error", {"message": msg}))
        _bounded(sinks.close, TEARDOWN_LIMIT, "qchain-rerun-close")
        return 1
    journal.close()
    with suppress(FileNotFoundError):
        Path(cfg["journal"]).unlink()
    # the recording is complete: said before anything of Rerun's that may wait for a peer
    summary["viewer_pending"] = sinks.viewer_pending
    alive = _send(conn, ("finished", summary)) and alive
    if sinks.remote is not None:  # within its timeout; a viewer given up is warned of
        taken = sinks.finish_viewer() is None
        alive = alive and not gone.is_set() and _send(conn, ("viewer", {"taken": taken}))
    if alive:  # a served viewer stays up until the simulating process lets go
        with suppress(EOFError, OSError):
            while True:
                conn.recv()
    gone.set()
    _bounded(sinks.close, TEARDOWN_LIMIT, "qchain-rerun-close")  # then os._exit, whatever Rerun still waits for
    return 0


def launch() -> tuple[subprocess.Popen, Connection]:
    """A new writer process (it imports what it needs at once, then waits for its
    configuration) and this process's end of its control connection."""
    import socket

    a, b = socket.socketpair()
    pkg_parent = str(Path(__file__).resolve().parents[2])  # the same qchain as this process's
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [pkg_parent, env.get("PYTHONPATH")]))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    # Rerun's own log lines about a viewer that stalls or goes away (its gRPC client, its
    # flushes) would repeat, many times over, the one warning the writer gives of it
    env.setdefault("RUST_LOG", "error,re_grpc_client=off,re_sdk::recording_stream=off,re_quota_channel=off")
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "qchain.recording.writer", str(b.fileno())],
            env=env, stdin=subprocess.DEVNULL, pass_fds=(b.fileno(),), close_fds=True,
            process_group=0,  # Ctrl-C in a terminal reaches the simulation, not the writer
        )
    finally:
        b.close()
    return proc, Connection(a.detach())


_SPARES: list[tuple[subprocess.Popen, Connection]] = []


def prepare_writer(rerun: bool = False) -> None:
    """Start a writer process now, for the next :class:`~qchain.logging.RunLogger` of this
    process to use: its start-up (a fresh interpreter importing numpy, mcap, foxglove-sdk)
    then runs on another core while the model is built. Without a later logger it exits
    with this process. ``rerun`` is accepted for compatibility (Rerun is imported when the
    configuration asks for it)."""
    _SPARES[:] = [(p, c) for p, c in _SPARES if p.poll() is None]
    if not _SPARES:
        _SPARES.append(launch())


def take_spare() -> tuple[subprocess.Popen, Connection] | None:
    """A prepared writer still waiting, if any."""
    while _SPARES:
        p, c = _SPARES.pop()
        if p.poll() is None:
            return p, c
        c.close()
    return None


def _stop_spares() -> None:  # pragma: no cover - interpreter shutdown
    for p, c in _SPARES:
        c.close()  # the writer sees EOF before its configuration and exits
        _reap(p, 5.0)
    _SPARES.clear()


import atexit  # noqa: E402

atexit.register(_stop_spares)

if __name__ == "__main__":
    _code = 1
    try:
        _code = process_main(int(sys.argv[1]))
    finally:  # never the interpreter's exit: Rerun's exit handler waits for a stalled peer without end
        for _f in (sys.stdout, sys.stderr):
            with suppress(Exception):
                _f.flush()
        os._exit(_code)
