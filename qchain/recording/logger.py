""":class:`RunLogger`: the simulation's side of the recording service (docs/recording.md, "How it
is built": it appends rows to the journal and never waits for the writer but in ``flush`` and
at the end)."""

from __future__ import annotations

import io
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
import warnings
import weakref
from contextlib import suppress
from pathlib import Path
from typing import BinaryIO

import numpy as np

from .journal import JournalReader, JournalWriter, journal_path
from .mcap_sink import info_metadata
from .options import check_outputs
from .records import (
    CONTACT_WIDTH,
    DEFAULT_FLUSH_INTERVAL,
    DEFAULT_FLUSH_WALL_INTERVAL,
    LoggingError,
    LoggingWarning,
    RecordLayout,
    RunInfo,
    StepRecord,
    default_base,
    pack_contacts,
)
from .rerun_sink import CONNECT_TIMEOUT, DEFAULT_BIND, _reap
from .writer import DEFAULT_RERUN_LATENCY, TEARDOWN_LIMIT, WRITER_POLL, ThreadWriter, launch, take_spare

__all__ = ["RunLogger", "DEFAULT_MAX_QUEUE", "WRITER_SILENCE"]

#: Records the thread writer's queue holds before ``log()`` waits.
DEFAULT_MAX_QUEUE = 4096
#: s without a word from the writer process (it says it is alive every second while it
#: finishes) after which the recording is finished here from the journal instead.
WRITER_SILENCE = 30.0
def _tendon_shape(tension, tendons) -> tuple[int, int]:
    """``(nt, M)`` of a record's tensions (nt,) and tendon paths (nt, M, 3) (None: none)."""
    if tension is None:
        if tendons is not None:
            raise ValueError("record.tendons without record.tension: the tensions come with the paths")
        return 0, 0
    if np.ndim(tension) != 1 or np.shape(tension)[0] < 1:
        raise ValueError(f"record.tension must be a vector of nt >= 1 tensions (N), got shape {np.shape(tension)}")
    nt = np.shape(tension)[0]
    if tendons is None:
        return nt, 0
    sh = np.shape(tendons)
    if len(sh) != 3 or sh[0] != nt or sh[2] != 3 or sh[1] < 1:
        raise ValueError(f"record.tendons must have shape ({nt}, M, 3) with M >= 1, got {sh}")
    return nt, sh[1]


def _tendon_block(tension, tendons, lay: RecordLayout, step) -> tuple[np.ndarray, np.ndarray]:
    """A record's tensions and tendon paths as the row's two blocks, checked against ``lay``."""
    if (np.shape(tension) != (lay.nt,) or (lay.M and np.shape(tendons) != (lay.nt, lay.M, 3))
            or (not lay.M and tendons is not None)):
        raise ValueError(f"record.tension and record.tendons have shapes {np.shape(tension)}, "
                         f"{np.shape(tendons) if tendons is not None else None} at step {step}; the first record had "
                         f"({lay.nt},), {(lay.nt, lay.M, 3) if lay.M else None}")
    return np.asarray(tension, dtype=np.float64), np.ravel(np.asarray(tendons if lay.M else (), dtype=np.float64))


_COLUMNS = ("step", "q", "v", "p", "kinetic", "potential", "total", "backbone", "tip_frames")
_OPEN: weakref.WeakSet = weakref.WeakSet()


def _close_open_loggers() -> None:  # pragma: no cover - interpreter shutdown
    for lg in list(_OPEN):
        with suppress(Exception):
            lg.linger = False
            lg.close(success=False, status=-1, message="the process exited without closing its log")


import atexit  # noqa: E402

atexit.register(_close_open_loggers)


class RunLogger:
    """Fans step records out to an MCAP recording and Rerun, away from the simulation.

    Parameters
    ----------
    info : RunInfo
        Static information, recorded once.
    mcap : path, binary stream or None
        Where to write the MCAP recording. A path (parent folders are created; checked
        before anything is written, see :func:`qchain.logging.check_outputs`) is written by
        a separate writer process from the run's journal; a binary stream (e.g.
        ``io.BytesIO``) by a thread of this process, and it is left open. ``None`` writes
        no MCAP.
    serve : bool
        Host a live Rerun gRPC server and web viewer on ``bind`` and print the URL.
    connect : str or None
        URL of a running Rerun viewer, e.g. ``rerun+http://127.0.0.1:9876/proxy``.
    rrd : path or None
        Also write a Rerun ``.rrd`` file.
    bind : str
        Address the servers listen on; ``127.0.0.1`` (this machine only) by default.
    grpc_port, web_port : int or None
        Ports of the gRPC server and the web viewer; by default 9876 and 9090 when free,
        else free ports.
    worker : {"auto", "process", "thread"}
        ``"auto"`` takes a process for file outputs and a thread for a stream.
    flush_interval : float, s
        Simulation time a record may wait before it is on disk (the batches of ``log()``
        and of :class:`~qchain.recording.recorder.ChainRecorder` span at most this, and so do the
        recording's chunks).
    flush_wall_interval : float, s
        Wall time between the recording's chunk flushes.
    max_queue : int
        Records the thread worker's queue holds before ``log()`` waits.
    linger : bool
        When serving, keep the viewer served after the run until Ctrl-C (for the CLI).
    recording_id : str or None
        Rerun recording id (default: a new UUID), also stored in the MCAP.
    server_memory_limit : str
        What the served gRPC server keeps for viewers that connect late.
    rerun_rate : float or None, 1/s
        Send Rerun at most this many records a simulated second (None: every record).
    rerun_latency : float, s
        Wall time records gather before they go to Rerun in one batch.
    quiet : bool
        Do not print the viewer URL.
    startup_timeout : float, s
        How long to wait for a viewer's URL (serving or connecting).
    viewer_timeout : float, s
        How long a viewer at ``connect`` has to answer the connection (its HTTP/2 settings),
        and to take data: a viewer that takes nothing for that long is given up with a
        warning (the recording never waits for it), and at the end this logger waits at
        most that long (plus its disconnect, at most 5 s) for the viewer to take the rest.

    Notes
    -----
    Use it as a context manager: leaving the block records success, an exception a failure
    with its text, and the file is finished in every case (:meth:`set_outcome` records a
    simulation's own status first). Call ``log()`` from one thread. What a killed run loses:
    docs/recording.md, "How it is built".
    """

    def __init__(self, info: RunInfo, mcap: str | os.PathLike | BinaryIO | None = None, *, serve: bool = False,
                 connect: str | None = None, rrd: str | os.PathLike | None = None, bind: str = DEFAULT_BIND,
                 grpc_port: int | None = None, web_port: int | None = None, worker: str = "auto",
                 flush_interval: float = DEFAULT_FLUSH_INTERVAL,
                 flush_wall_interval: float = DEFAULT_FLUSH_WALL_INTERVAL, max_queue: int = DEFAULT_MAX_QUEUE,
                 linger: bool = False, recording_id: str | None = None, server_memory_limit: str = "1GiB",
                 rerun_rate: float | None = None, rerun_latency: float = DEFAULT_RERUN_LATENCY, quiet: bool = False,
                 startup_timeout: float = 60.0, viewer_timeout: float = CONNECT_TIMEOUT, **legacy):
        legacy.pop("chunk_bytes", None)  # accepted for compatibility: chunks are cut by time
        if legacy:
            raise TypeError(f"RunLogger got unexpected arguments {sorted(legacy)}")
        if not isinstance(info, RunInfo):
            raise TypeError(f"info must be a RunInfo, got {type(info).__name__}")
        for name, value in (("flush_interval", flush_interval), ("flush_wall_interval", flush_wall_interval),
                            ("rerun_latency", rerun_latency), ("viewer_timeout", viewer_timeout)):
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number of seconds > 0, got {value!r}")
        if not (isinstance(max_queue, int) and max_queue >= 1):
            raise ValueError(f"max_queue must be an int >= 1, got {max_queue!r}")
        if rerun_rate is not None and not (isinstance(rerun_rate, (int, float)) and rerun_rate > 0):
            raise ValueError(f"rerun_rate must be None or > 0 records a simulated second, got {rerun_rate!r}")
        if worker not in ("auto", "process", "thread"):
            raise ValueError(f"worker must be 'auto', 'process' or 'thread', got {worker!r}")
        if serve and connect:
            raise ValueError("serve and connect exclude each other: serve hosts a viewer, connect uses one")
        stream = None
        mcap_path = None
        if mcap is not None:
            if isinstance(mcap, (str, os.PathLike)):
                mcap_path = Path(mcap)
            elif hasattr(mcap, "write"):
                seekable = getattr(mcap, "seekable", None)
                if not (callable(seekable) and seekable()) or isinstance(mcap, io.TextIOBase):
                    raise ValueError(f"mcap must be a path, a binary stream that can seek (the MCAP writer goes back "
                                     f"to its start) or None, got a {type(mcap).__name__} that "
                                     f"{'is a text stream' if isinstance(mcap, io.TextIOBase) else 'cannot seek'}")
                stream = mcap
            else:
                raise ValueError(f"mcap must be a path, a binary stream or None, got {type(mcap).__name__}")
        if rrd is not None:
            rrd = Path(rrd)
        if worker == "auto":
            worker = "thread" if stream is not None else "process"
        if worker == "process" and stream is not None:
            raise ValueError("worker='process' cannot write into an in-memory stream; use worker='thread'")
        for notice in check_outputs(mcap_path, rrd, info.scene_file):
            warnings.warn(f"qchain.logging: {notice}", LoggingWarning, stacklevel=2)
        self.info = info
        self.mcap_path = mcap_path
        self.rrd_path = rrd
        self.worker = worker
        self.linger = bool(linger)
        self.quiet = bool(quiet)
        self.flush_interval = float(flush_interval)
        self.recording_id = recording_id or str(uuid.uuid4())
        self.viewer_url: str | None = None
        self.grpc_url: str | None = None
        self.worker_pid: int | None = None
        self.web_pid: int | None = None
        self.journal_path: Path | None = None
        self.n_logged = 0
        self.last_t: float | None = None
        self._layout: RecordLayout | None = None
        self._closed = False
        self._broken: str | None = None
        self._notice: str | None = None  # a trouble the recording came through complete (said as a warning)
        self._warned_broken = False
        self._outcome: dict | None = None
        self._final: dict | None = None
        self._buf: list[np.ndarray] = []  # rows of log() waiting for a batch
        self._buf_t0 = 0.0
        self._buf_wall = 0.0
        self._tmpdir: str | None = None
        self.viewer_timeout = float(viewer_timeout)
        cfg = {
            "info": info.to_json(), "mcap": None if mcap_path is None else str(mcap_path), "serve": bool(serve),
            "connect": connect, "rrd": None if rrd is None else str(rrd), "bind": bind, "grpc_port": grpc_port,
            "web_port": web_port, "recording_id": self.recording_id, "flush_interval": float(flush_interval),
            "flush_wall_interval": float(flush_wall_interval), "server_memory_limit": server_memory_limit,
            "rerun_rate": rerun_rate, "rerun_latency": float(rerun_latency), "poll": WRITER_POLL,
            "viewer_timeout": float(viewer_timeout),
        }
        if worker == "thread":
            warn = lambda m: warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=2)  # noqa: E731
            self._thread = ThreadWriter(cfg, stream, warn, max_queue)
            self.viewer_url = self._thread.sinks.viewer_url
            self.grpc_url = getattr(self._thread.sinks.rerun, "grpc_url", None)
        else:
            # (a viewer at connect has viewer_timeout to answer before the writer is ready)
            self._start_process(cfg, startup_timeout + (float(viewer_timeout) if connect else 0.0),
                                bool(serve or connect))
        if self.viewer_url and not self.quiet:
            print(f"qchain: live Rerun viewer at {self.viewer_url}  (open it in a browser)", file=sys.stderr,
                  flush=True)
        _OPEN.add(self)

    # -- the writer process -------------------------------------------------------------------

    def _start_process(self, cfg: dict, timeout: float, wait_ready: bool) -> None:
        if self.mcap_path is not None:
            jp = journal_path(self.mcap_path)
        else:  # a viewer-only run: the journal lives in a folder of its own, removed at the end
            self._tmpdir = tempfile.mkdtemp(prefix="qchain-run-")
            jp = Path(self._tmpdir) / "run.journal"
        self.journal_path = jp
        existed = os.path.lexists(jp)  # (check_outputs refused a journal of another run)
        try:
            self._journal = JournalWriter(jp, info_metadata(self.info, self.recording_id),
                                          None if self.mcap_path is None else str(self.mcap_path))
        except (OSError, ValueError) as exc:  # nothing is left behind: a journal made here is removed
            if not existed:
                with suppress(OSError):
                    os.unlink(jp)
            if self._tmpdir is not None:
                shutil.rmtree(self._tmpdir, ignore_errors=True)
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise LoggingError(f"the recording's journal {jp} cannot be written ({why})") from None
        cfg["journal"] = str(jp)
        with suppress(OSError):  # (a deleted working folder: relative paths fail as they would here)
            cfg["cwd"] = os.getcwd()
        self._proc, self._conn = take_spare() or launch()
        self.worker_pid = self._proc.pid
        self._conn.send(("config", cfg))
        self._ready_pending = True
        if wait_ready:  # the viewer's URL, or that it is missing, comes first
            self._take_ready(timeout, starting=True)

    def _absorb(self, msg) -> bool:
        """Take a warning of the writer's (warned here) or a sign of life: True; else False."""
        if isinstance(msg, tuple) and msg and msg[0] == "warning":
            warnings.warn(f"qchain.logging: {msg[1]}", LoggingWarning, stacklevel=5)
            return True
        return isinstance(msg, tuple) and bool(msg) and msg[0] == "progress"

    def _recv(self, timeout: float, idle: float | None = None):
        """The writer's next message (its warnings warned on the way), or None: ``timeout``
        s in all, ``idle`` s without a word from it (signs of life count), or it is gone."""
        start = last = time.monotonic()
        while True:
            now = time.monotonic()
            wait = min(0.5, max(0.0, start + timeout - now))
            if idle is not None:
                wait = min(wait, max(0.0, last + idle - now))
            try:
                if self._conn.poll(wait):
                    msg = self._conn.recv()
                    last = time.monotonic()
                    if not self._absorb(msg):
                        return msg
                    continue
            except (EOFError, OSError):
                return None
            now = time.monotonic()
            if self._proc.poll() is not None or now >= start + timeout or (idle is not None and now >= last + idle):
                with suppress(EOFError, OSError):
                    while self._conn.poll(0):
                        msg = self._conn.recv()
                        if not self._absorb(msg):
                            return msg
                return None

    def _take_ready(self, timeout: float, starting: bool = False) -> None:
        if not getattr(self, "_ready_pending", False):
            return
        self._ready_pending = False
        msg = self._recv(timeout)
        if msg is None or msg[0] != "ready":
            why = (msg[1].get("message") if msg else None) or "it did not answer in time or exited"
            why = f"the log writer could not start ({why})"
            if starting:
                self._proc.kill()
                self._proc.wait()
                self._conn.close()
                self._journal.release(remove=True)
                raise LoggingError(why)
            self._broken = self._broken or why
            return
        body = msg[1]
        for m in body.get("warnings", []):
            warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=5 if starting else 4)
        self.viewer_url = body.get("viewer_url")
        self.grpc_url = body.get("grpc_url")
        self.web_pid = body.get("web_pid")

    # -- logging -----------------------------------------------------------------------------

    def _init_layout(self, r: StepRecord) -> RecordLayout:
        n = self.info.n_segments
        shapes = {f: np.shape(getattr(r, f)) for f in ("q", "v", "p", "backbone", "tip_frames")}
        for f in ("q", "v", "p"):
            if len(shapes[f]) != 1:
                raise ValueError(f"record.{f} must be a vector, got shape {shapes[f]}")
        bb = shapes["backbone"]
        if len(bb) != 3 or bb[0] != n or bb[2] != 3 or bb[1] < 1:
            raise ValueError(f"record.backbone must have shape ({n}, P, 3) with P >= 1, got {bb}")
        if shapes["tip_frames"] != (n, 7):
            raise ValueError(f"record.tip_frames must have shape ({n}, 7), got {shapes['tip_frames']}")
        nt, M = _tendon_shape(r.tension, r.tendons)
        return self._set_layout(RecordLayout(shapes["q"][0], shapes["v"][0], shapes["p"][0], n, bb[1],
                                             self.info.max_contacts, nt, M))

    def _set_layout(self, lay: RecordLayout) -> RecordLayout:
        self._shapes = {"q": (lay.nq,), "v": (lay.nv,), "p": (lay.n_p,), "backbone": (lay.n, lay.P, 3),
                        "tip_frames": (lay.n, 7)}
        self._layout = lay
        self._width = lay.row_width
        if self.worker == "process":
            self._journal.start(lay)
        return lay

    def _shape_error(self, r: StepRecord) -> ValueError:
        for f, expected in self._shapes.items():
            got = np.shape(getattr(r, f))
            if got != expected:
                return ValueError(f"record.{f} has shape {got} at step {r.step}; the first record had {expected}")
        return ValueError(f"record at step {r.step} does not match the first record's shapes {self._shapes}")

    def _warn_broken(self, step) -> None:
        if not self._warned_broken:
            self._warned_broken = True
            warnings.warn(f"qchain.logging: {self._broken}; records from step {step} on are not logged",
                          LoggingWarning, stacklevel=3)

    def log(self, record: StepRecord) -> None:
        """Take one record (copied). It is on disk at the latest ``flush_interval / 2`` of
        simulation time or 50 ms of wall time later.

        Raises
        ------
        ValueError
            Shapes that differ from the first record's, or a time that is not finite and >= 0.
        LoggingError
            The logger is closed, or the journal cannot be written (a full disk).
        """
        if self._closed:
            raise LoggingError("log() on a closed RunLogger")
        if self._layout is None:
            self._init_layout(record)
        t = record.t
        if not (t >= 0.0 and t < math.inf):
            raise ValueError(f"record.t must be finite and >= 0 s, got {t!r} at step {record.step}")
        q, v, p, bb, tf = record.q, record.v, record.p, record.backbone, record.tip_frames
        base = record.base_frame
        shapes = self._shapes
        if np.shape(bb) != shapes["backbone"] or np.shape(tf) != shapes["tip_frames"]:
            raise self._shape_error(record)
        if base is None:
            base = default_base(np.asarray(bb, dtype=float))
        extra = ()
        if self._layout.C:
            block, dropped = pack_contacts(record.contacts, self._layout.C, self.info)
            self._said_dropped(dropped, t)
            extra = (block.ravel(),)
        if self._layout.nt:
            extra += _tendon_block(record.tension, record.tendons, self._layout, record.step)
        try:
            row = np.concatenate(((t, record.step), q, v, p, (record.kinetic, record.potential, record.total), base,
                                  np.ravel(bb), np.ravel(tf)) + extra, dtype=np.float64)
        except ValueError:
            raise self._shape_error(record) from None
        if row.shape[0] != self._width or np.shape(q) != shapes["q"] or np.shape(v) != shapes["v"] \
                or np.shape(p) != shapes["p"] or np.shape(base) != (7,):
            raise self._shape_error(record) if np.shape(base) == (7,) else ValueError(
                f"record.base_frame must have shape (7,), got {np.shape(base)} at step {record.step}")
        if self.worker == "thread":  # a queue put: no batching needed
            self._write(row[None, :])
            self.n_logged += 1
            return
        buf = self._buf
        if not buf:
            self._buf_t0 = t
            self._buf_wall = time.monotonic()
        buf.append(row)
        self.n_logged += 1
        if t - self._buf_t0 >= 0.5 * self.flush_interval or len(buf) >= 256 or \
                time.monotonic() - self._buf_wall >= 0.05:
            self._flush_buffer()

    def _said_dropped(self, dropped: int, t: float) -> None:
        """Warn once that samples had more contacts than the rows hold."""
        if dropped and not getattr(self, "_warned_contacts", False):
            self._warned_contacts = True
            warnings.warn(f"qchain.logging: {dropped} contact(s) more than RunInfo.max_contacts = "
                          f"{self.info.max_contacts} at t = {t:.6g} s: the largest forces are recorded, the rest not "
                          "(said once)", LoggingWarning, stacklevel=4)

    def _flush_buffer(self) -> None:
        if self._buf:
            rows = np.stack(self._buf)
            self._buf = []
            self._write(rows)

    def _write(self, rows: np.ndarray) -> None:
        if self._broken is not None and self.worker == "thread":
            self._warn_broken(int(rows[0, 1]))
            return
        if self.worker == "thread":
            self._thread.put_rows(rows, self._layout)
        else:
            try:
                self._journal.append(rows)
            except OSError as exc:
                raise LoggingError(f"the recording's journal {self.journal_path} cannot be written "
                                   f"({exc.strerror or exc}): the run stops here, its records up to "
                                   f"t = {self.last_t} s are kept") from exc
        self.last_t = float(rows[-1, 0])

    def log_rows(self, rows: np.ndarray, layout: RecordLayout) -> None:
        """Take ``K`` records given as rows of ``layout``: the cheapest way in (one write to
        the journal for all of them, no buffering here).

        Parameters
        ----------
        rows : (K, layout.row_width) float64
            One record a row (see :class:`RecordLayout`).
        layout : RecordLayout
            Must be the run's: that of its first record.

        Raises
        ------
        ValueError
            A layout or shape that differs from the run's, or a time that is not finite and
            >= 0.
        LoggingError
            The logger is closed, or the journal cannot be written (a full disk).
        """
        if self._closed:
            raise LoggingError("log_rows() on a closed RunLogger")
        if not isinstance(layout, RecordLayout):
            raise TypeError(f"layout must be a RecordLayout, got {type(layout).__name__}")
        if not (isinstance(rows, np.ndarray) and rows.dtype == np.float64 and rows.ndim == 2
                and rows.shape[1] == layout.row_width):
            raise ValueError(f"rows must be a float64 array of shape (K, {layout.row_width}), got "
                             f"{getattr(rows, 'dtype', type(rows).__name__)} {np.shape(rows)}")
        K = rows.shape[0]
        if K == 0:
            return
        if self._layout is None:
            if layout.n != self.info.n_segments:
                raise ValueError(f"layout.n = {layout.n} segments, but the run's RunInfo has {self.info.n_segments}")
            if layout.C != self.info.max_contacts:
                raise ValueError(f"layout.C = {layout.C} contacts, but the run's RunInfo.max_contacts is "
                                 f"{self.info.max_contacts}")
            self._set_layout(layout)
        elif layout is not self._layout and layout != self._layout:
            raise ValueError(f"layout {layout} differs from the run's {self._layout} (fixed by its first record)")
        t = rows[:, 0]
        if not (t.min() >= 0.0 and t.max() < math.inf):  # NaN fails both
            i = int(np.flatnonzero(~((t >= 0.0) & (t < math.inf)))[0])
            raise ValueError(f"t must be finite and >= 0 s, got {float(t[i])!r} at step {int(rows[i, 1])}")
        self._flush_buffer()
        self._write(rows.copy() if self.worker == "thread" else rows)
        self.n_logged += K

    def log_columns(self, t, step, q, v, p, kinetic, potential, total, backbone, tip_frames, base=None,
                    contacts=None, tension=None, tendons=None) -> None:
        """Take ``K`` records given as columns: the batch form of :meth:`log`.

        Parameters
        ----------
        t : (K,) s
        step : (K,) int
        q : (K, nq)
        v : (K, nv)
        p : (K, 3 n) Pa
        kinetic, potential, total : (K,) J
        backbone : (K, n, P, 3) m
        tip_frames : (K, n, 7)
        base : (K, 7) or None
            As the fields of :class:`StepRecord`, one row a record.
        contacts : sequence of K Contacts-like (or None) or None
            Each record's active contacts, as :attr:`StepRecord.contacts`.
        tension : (K, nt) N or None
        tendons : (K, nt, M, 3) m or None
            Each record's tensions and tendon paths, as :attr:`StepRecord.tension` and
            :attr:`StepRecord.tendons`.
        """
        if self._closed:
            raise LoggingError("log_columns() on a closed RunLogger")
        t = np.asarray(t, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t must have shape (K,), got {t.shape}")
        K = t.shape[0]
        cols = [np.asarray(x, dtype=np.float64) for x in (step, q, v, p, kinetic, potential, total, backbone,
                                                          tip_frames)]
        for name, x in zip(_COLUMNS, cols):
            if x.ndim < 1 or x.shape[0] != K:
                raise ValueError(f"{name} must have a leading axis of K = {K} (the length of t), got shape {x.shape}")
        if K == 0:
            return
        if self._layout is None:
            self._init_layout(StepRecord(float(t[0]), int(cols[0][0]), *(x[0] for x in cols[1:]),
                                         tension=None if tension is None else np.asarray(tension)[0],
                                         tendons=None if tendons is None else np.asarray(tendons)[0]))
        step, q, v, p, kinetic, potential, total, backbone, tip_frames = cols
        for f, x in (("q", q), ("v", v), ("p", p), ("backbone", backbone), ("tip_frames", tip_frames)):
            if x.shape[1:] != self._shapes[f]:
                raise ValueError(f"{f} has rows of shape {x.shape[1:]}; the first record had {self._shapes[f]}")
        if base is None:
            base = np.stack([default_base(b) for b in backbone])
        base = np.asarray(base, dtype=np.float64)
        if base.shape != (K, 7):
            raise ValueError(f"base must have shape ({K}, 7), got {base.shape}")
        extra = ()
        C = self._layout.C
        if C:
            if contacts is not None and len(contacts) != K:
                raise ValueError(f"contacts must hold K = {K} entries (one a record, None: no contact), got "
                                 f"{len(contacts)}")
            blocks = np.empty((K, C * CONTACT_WIDTH))
            for k in range(K):
                block, dropped = pack_contacts(None if contacts is None else contacts[k], C, self.info)
                self._said_dropped(dropped, float(t[k]))
                blocks[k] = block.ravel()
            extra = (blocks,)
        if self._layout.nt:
            if tension is None or np.shape(tension)[0] != K or (tendons is not None and np.shape(tendons)[0] != K):
                raise ValueError(f"tension (and tendons) must hold K = {K} rows (the run has tendons)")
            extra += (np.concatenate([np.concatenate(_tendon_block(tension[k], None if tendons is None else tendons[k],
                                                                   self._layout, int(step[k])))[None]
                                      for k in range(K)]),)
        rows = np.concatenate((t[:, None], step[:, None], q, v, p, kinetic[:, None], potential[:, None],
                               total[:, None], base, backbone.reshape(K, -1), tip_frames.reshape(K, -1)) + extra,
                              axis=1)
        self.log_rows(rows, self._layout)

    def set_outcome(self, success: bool = True, message: str = "", status: int | None = None, nfev: int = 0) -> None:
        """Record how the run ended (written when the logger closes).

        Parameters
        ----------
        success : bool
        message : str
            Why the run ended.
        status : int or None
            0 finished, 1 stopped by an event, -1 failed; default 0 if success else -1.
        nfev : int
            Number of forward-dynamics evaluations.
        """
        if status is None:
            status = 0 if success else -1
        self._outcome = {"success": bool(success), "message": str(message), "status": int(status), "nfev": int(nfev)}

    def flush(self, timeout: float = 60.0) -> dict:
        """Wait until every record logged so far is in the MCAP file (its chunk closed and
        handed to the operating system) and sent to Rerun.

        Returns ``{"n_records": written so far, "last_t": s}``; raises :class:`LoggingError`
        if the writer does not answer within ``timeout`` seconds.
        """
        if self._closed:
            raise LoggingError("flush() on a closed RunLogger")
        self._flush_buffer()
        if self.worker == "thread":
            out = self._thread.flush(timeout)
            if out is None:
                raise LoggingError(f"the log writer did not flush within {timeout} s")
            return out
        self._take_ready(timeout)
        if self._broken is not None:
            raise LoggingError(self._broken)
        try:
            self._conn.send(("flush", None))
        except OSError:
            self._broken = "the log writer process is gone"
            raise LoggingError(self._broken) from None
        msg = self._recv(timeout)
        if msg is None or msg[0] != "flushed":
            self._broken = f"the log writer did not flush within {timeout} s ({msg})"
            raise LoggingError(self._broken)
        return {"n_records": msg[1]["n_records"], "last_t": msg[1]["last_t"]}

    # -- closing -----------------------------------------------------------------------------

    def close(self, success: bool | None = None, message: str | None = None, status: int | None = None) -> dict:
        """Finish the recording (MCAP summary written) and stop the writer.

        Parameters are as for :meth:`set_outcome` and override it when given. Returns a
        summary dict: ``n_records`` (written), ``last_t`` (s: the time the recording
        reaches), ``mcap``, ``rrd``, ``viewer_url``. With ``linger`` and a served viewer,
        waits for Ctrl-C first.
        """
        if self._closed:
            return self._final or {}
        self._closed = True
        _OPEN.discard(self)
        outcome = dict(self._outcome or {"success": True, "message": "finished", "status": 0, "nfev": 0})
        if success is not None:
            outcome["success"] = bool(success)
            outcome["status"] = int(status) if status is not None else (0 if success else -1)
        elif status is not None:
            outcome["status"] = int(status)
        if message is not None:
            outcome["message"] = str(message)
        outcome["n_logged"] = self.n_logged
        try:
            self._flush_buffer()
        except LoggingError as exc:
            self._broken = str(exc)
        if self.worker == "thread":
            summary = self._thread.end(outcome)
            self._broken = self._broken or self._thread.broken
            try:
                if self.linger and self.viewer_url:
                    self._wait_while_serving(lambda: True)
            finally:
                self._thread.sinks.close()
        else:
            summary = self._close_process(outcome)
        self._final = {
            "n_records": summary.get("n_records", 0),
            "last_t": summary.get("last_t"),
            "mcap": None if self.mcap_path is None else str(self.mcap_path),
            "rrd": None if self.rrd_path is None else str(self.rrd_path),
            "viewer_url": self.viewer_url,
            "error": self._broken,
            "warning": self._notice,
        }
        said = self._broken if self._broken is not None else self._notice
        if said is not None:
            warnings.warn(f"qchain.logging: {said}", LoggingWarning, stacklevel=2)
        return self._final

    def _wait_while_serving(self, alive) -> None:
        print(f"qchain: the run is over; still serving the viewer at {self.viewer_url} - press Ctrl-C to stop",
              file=sys.stderr, flush=True)
        with suppress(KeyboardInterrupt):
            while alive():
                time.sleep(0.5)

    def _close_process(self, outcome: dict) -> dict:
        from .mcap_sink import outcome_entries

        proc = self._proc
        summary: dict = {}
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if hasattr(signal, "pthread_sigmask") \
            else None
        finished = False
        try:  # a second Ctrl-C must not leave the journal without its end
            try:
                self._journal.finish(outcome_entries(outcome, self.n_logged, self.last_t))
                finished = True
            except OSError as exc:
                self._broken = self._broken or f"the journal could not be finished ({exc.strerror or exc})"
        finally:
            if old is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)
        msg = None
        interrupted = None
        try:
            self._take_ready(120.0)
            if proc.poll() is None:
                try:
                    # (a journal that could not be finished: the writer does not wait for its end)
                    self._conn.send(("end", {**outcome, "journal_finished": finished}))
                    # as long as it takes, while the writer says it is alive (every second)
                    msg = self._recv(math.inf, idle=WRITER_SILENCE)
                except OSError:
                    msg = None
        except KeyboardInterrupt as exc:  # the journal is complete: the writer finishes the recording
            interrupted = exc             # on its own (or `qchain recover` does); this process goes
            msg = ("left", {})
        if msg is not None and msg[0] == "finished":
            summary = msg[1]
            if summary.pop("viewer_pending", False):
                self._wait_for_viewer()
        elif interrupted is None:
            why = (msg[1].get("message") if msg and msg[0] == "error" else None) or \
                ("the log writer did not confirm the end of the recording" if proc.poll() is not None else
                 f"the log writer stopped answering (nothing for {WRITER_SILENCE:g} s)")
            summary = self._finish_here(outcome, why)
            if summary and summary.get("n_records") == self.n_logged:  # complete all the same: said, not a failure
                trouble = why if self._broken is None or self._broken == why else f"{self._broken}; {why}"
                self._notice = f"{trouble}; the recording was finished from the journal, complete"
                self._broken = None
            else:
                self._broken = self._broken or why
        try:
            if self.linger and self.viewer_url and proc.poll() is None and summary:
                self._wait_while_serving(lambda: proc.poll() is None)
        finally:
            self._conn.close()
            self._journal.release(remove=False)
            if summary or interrupted is not None:  # its own leave of Rerun (bounded) need not hold us up
                threading.Thread(target=_reap, args=(proc, 30.0 if interrupted is None else None),
                                 name="qchain-log-reaper", daemon=True).start()
            else:
                _reap(proc)
            if self._tmpdir is not None:  # (a writer still reading the journal holds it open)
                shutil.rmtree(self._tmpdir, ignore_errors=True)
        if interrupted is not None:
            raise interrupted
        return summary

    def _wait_for_viewer(self) -> None:
        """The recording is complete; a viewer at ``connect`` is given the rest by the writer
        within ``viewer_timeout`` (then its disconnect, bounded): wait for that, said if it
        was given up. Ctrl-C stops the waiting (the writer ends on its own)."""
        try:
            msg = self._recv(self.viewer_timeout + TEARDOWN_LIMIT + 10.0)
        except KeyboardInterrupt:
            warnings.warn("qchain.logging: the viewer was not waited for (interrupted); the MCAP log is complete",
                          LoggingWarning, stacklevel=4)
            return
        if msg is None:
            warnings.warn(f"qchain.logging: the viewer was not done within {self.viewer_timeout:g} s; the MCAP log "
                          "is complete", LoggingWarning, stacklevel=4)

    def _finish_here(self, outcome: dict, why: str) -> dict:
        """The writer failed (``why``): finish the recording in this process from the journal
        (the records are all there), if there is a recording to finish; the summary, or {}
        (then ``_broken`` says why)."""
        if self.mcap_path is None or not self.journal_path.exists():
            return {}
        with suppress(OSError, subprocess.TimeoutExpired):
            self._proc.kill()
            self._proc.wait(10)
        from .mcap_sink import McapSink

        try:
            jr = JournalReader(self.journal_path)
            blocks = jr.poll(final=True)
            jr.close()
            sink = McapSink(self.mcap_path, self.info, recording_id=self.recording_id,
                            flush_interval=self.flush_interval, flush_wall_interval=1e9)
            from .records import Batch

            for rows in blocks:
                sink.write_batch(Batch.from_rows(rows, jr.layout))
            outcome = dict(outcome)
            outcome["message"] = f"{outcome.get('message', '')} (recording finished from the journal: {why})"
            sink.finish(outcome)
            self.journal_path.unlink()
            return {"n_records": sink.n_records, "last_t": sink.last_t}
        except Exception as exc:
            self._broken = f"{self._broken or why}; finishing the recording from the journal failed too " \
                           f"({type(exc).__name__}: {exc}); the records stay in {self.journal_path}"
            return {}

    def __enter__(self) -> RunLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
            return
        self.linger = False
        if issubclass(exc_type, KeyboardInterrupt):
            last = float(self._buf[-1][0]) if self._buf else self.last_t
            message = "interrupted (KeyboardInterrupt)" + ("" if last is None else f" at t = {last:.6g} s")
        else:
            message = f"the simulation raised {exc_type.__name__}: {exc}"
        self.close(success=False, status=-1, message=message)
