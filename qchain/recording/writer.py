"""The writer: reads records and feeds the sinks (the recording, the Rerun view).

For a file, the writer is a process of its own (``python -m qchain.recording.writer``:
its own interpreter, so its work takes nothing from the simulating process's GIL and runs
on another core). It reads the run's journal as it grows (every ``poll`` seconds), so the
simulating process never waits for it and nothing is lost when it is slow or starved.
Control messages (configuration, flush, end) go over a socket pair with
:mod:`multiprocessing.connection`. If the simulating process dies, the writer sees the
connection close, reads the journal to its end and finishes the recording, with an
outcome saying so; then it removes the journal. For an in-memory stream the writer is a
thread of the simulating process fed through a queue (no journal: a stream dies with the
process anyway).
"""

from __future__ import annotations

import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .records import Batch, RecordLayout, RunInfo

__all__ = ["Sinks", "ThreadWriter", "launch", "prepare_writer", "take_spare", "WRITER_POLL"]

#: s between two reads of the journal when the writer is idle.
WRITER_POLL = 0.02
#: Wall time (s) records gather in the writer before they go to Rerun in one batch.
DEFAULT_RERUN_LATENCY = 0.2


class Sinks:
    """The sinks one writer feeds: an MCAP recording and/or a Rerun view."""

    def __init__(self, cfg: dict, mcap_stream: BinaryIO | None, warn):
        from .mcap_sink import McapSink

        self.info = RunInfo.from_json(cfg["info"])
        self.warn = warn
        self.mcap: McapSink | None = None
        self.rerun = None
        out = mcap_stream if mcap_stream is not None else cfg.get("mcap")
        if out is not None:
            self.mcap = McapSink(out, self.info, recording_id=cfg["recording_id"],
                                 flush_interval=cfg["flush_interval"], flush_wall_interval=cfg["flush_wall_interval"])
        self._rr_thread: threading.Thread | None = None
        if cfg.get("serve") or cfg.get("connect"):  # before "ready": the URL, or a missing viewer, first
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

    def _start_rerun(self, cfg: dict) -> None:
        from .rerun_sink import DEFAULT_BIND, RerunSink

        try:
            self.rerun = RerunSink(self.info, serve=bool(cfg.get("serve")), connect=cfg.get("connect"),
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
        if self._rr_thread is not None or (self.rerun is not None and self.rerun.rec is not None):
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
        if not pending or self.rerun is None or self.rerun.rec is None:
            return
        b = pending[0] if len(pending) == 1 else Batch.concatenate(pending)
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
                and not self.rerun.started)

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
        return {"n_records": self.n_records, "last_t": self.last_t}

    def finish(self, outcome: dict) -> dict:
        self._send_rerun(wait=True)
        if self.mcap is not None:
            self.mcap.finish(outcome)
        if self.rerun is not None:
            try:
                self.rerun.finish()
            except Exception as exc:  # pragma: no cover - best effort
                self.warn(f"Rerun flush failed ({type(exc).__name__}: {exc})")
        return {"n_records": self.n_records, "last_t": self.last_t}

    def abandon(self) -> None:
        if self.mcap is not None:
            self.mcap.abandon()

    def close(self) -> None:
        self._rerun_started(wait=True)
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


# --------------------------------------------------------------------------------------
# The writer process
# --------------------------------------------------------------------------------------


def _drain(journal, sinks: Sinks, final: bool = False) -> None:
    for rows in journal.poll(final=final):
        sinks.write_rows(rows, journal.layout)


def _send(conn: Connection, msg) -> bool:
    """Send to the simulating process; False when it is gone."""
    try:
        conn.send(msg)
        return True
    except OSError:
        return False


def process_main(fd: int) -> int:
    """Entry point of the writer process; ``fd`` is its end of the control socket pair."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the simulating process decides when to stop
    conn = Connection(fd)
    try:
        import foxglove.messages  # noqa: F401  (imports first: they take most of the start-up)
        import mcap.writer  # noqa: F401
        import orjson  # noqa: F401
    except ImportError:
        pass
    try:
        kind, cfg = conn.recv()
    except (EOFError, OSError):
        return 2
    if kind != "config":
        _send(conn, ("error", {"message": "the log writer got no configuration"}))
        return 2
    from .journal import JournalReader

    startup: list[str] = []

    def warn_live(msg: str) -> None:
        print(f"qchain.logging: warning: {msg}", file=sys.stderr, flush=True)

    try:
        sinks = Sinks(cfg, None, startup.append)
        journal = JournalReader(cfg["journal"])
    except Exception as exc:
        _send(conn, ("error", {"message": f"{type(exc).__name__}: {exc}"}))
        return 2
    sinks.warn = warn_live
    web = sinks.rerun.web if sinks.rerun is not None else None
    # the simulating process may be gone already (killed while this process started): then
    # the journal holds everything it logged, and the recording is finished from it below
    alive = _send(conn, ("ready", {"viewer_url": sinks.viewer_url,
                                   "grpc_url": sinks.rerun.grpc_url if sinks.rerun is not None else None,
                                   "warnings": startup, "pid": os.getpid(),
                                   "web_pid": web.pid if web is not None else None}))
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
                _drain(journal, sinks)
                alive = _send(conn, ("flushed", sinks.flush()))
            elif kind == "end":
                deadline = time.monotonic() + 60.0
                while not journal.finished and time.monotonic() < deadline:
                    _drain(journal, sinks, final=False)
                    if not journal.finished:
                        time.sleep(0.005)
                _drain(journal, sinks, final=True)
                outcome = dict(body)
        if outcome is None:  # the simulating process is gone: the journal holds all it logged
            _drain(journal, sinks, final=True)
            out = journal.outcome
            outcome = ({"success": out.get("success") == "true", "status": int(out.get("status", -1)),
                        "message": out.get("message", ""), "nfev": int(out.get("nfev", 0))} if out else
                       {"success": False, "status": -1,
                        "message": "the simulating process ended without closing its log (killed?)"})
        summary = sinks.finish(outcome)
    except Exception as exc:  # the disk full and the like: say so; the journal keeps the records
        msg = f"the log writer failed: {type(exc).__name__}: {exc}"
        warn_live(msg)
        sinks.abandon()
        _send(conn, ("error", {"message": msg}))
        return 1
    journal.close()
    if cfg.get("remove_journal", True):
        try:
            Path(cfg["journal"]).unlink()
        except FileNotFoundError:
            pass
    alive = _send(conn, ("finished", summary)) and alive
    if alive:  # a served viewer stays up until the simulating process lets go
        try:
            while True:
                conn.recv()
        except (EOFError, OSError):
            pass
    sinks.close()
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
        try:
            p.wait(5.0)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    _SPARES.clear()


import atexit  # noqa: E402

atexit.register(_stop_spares)

if __name__ == "__main__":
    sys.exit(process_main(int(sys.argv[1])))
