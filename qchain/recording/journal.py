"""The journal ``run.mcap.journal``: the simulating process's own copy of every record, on disk at
once (an MCAP file of the mcap library's ``Writer``, one chunk a batch, one write each; see
docs/recording.md, "How it is built").

The simulating process holds an exclusive ``flock`` on the journal while the run lasts:
another run on the same path is refused, and a journal nobody holds is a killed run's."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import stat
import struct
import zlib
from contextlib import suppress
from pathlib import Path

import numpy as np
from mcap.records import Channel, Message
from mcap.writer import CompressionType, IndexType, Writer

from .bounded import ReadBudget, ReadLimits, loads, open_regular
from .records import LoggingError, RecordingFormatError, RecordLayout, ns, seal, unseal
from .scan import MAGIC, scan

__all__ = ["journal_path", "JournalWriter", "JournalReader", "journal_owner", "chunk_record", "ROWS_ENCODING"]

#: Message encoding of the journal's rows: little-endian float64 rows of the layout in the
#: channel's metadata.
ROWS_ENCODING = "qchain.rows.f64le"
ROWS_TOPIC = "/qchain/rows"
#: The metadata record that repeats the rows channel's id and layout (sealed)
LAYOUT_RECORD = "qchain.journal.layout"


def journal_path(mcap_path: str | os.PathLike) -> Path:
    """Where the journal of the recording ``mcap_path`` lives."""
    p = Path(mcap_path)
    return p.with_name(p.name + ".journal")


def journal_owner(path: str | os.PathLike) -> int | None:
    """The pid of the live process writing the journal ``path``, 0 if a live process holds
    it but its pid is unknown, None if nobody holds it (or it does not exist, or it is not
    a regular file: a FIFO or a device is never opened, so this never waits)."""
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        # a recording's name too long for a journal beside it: none can be; a loop of links:
        # no file a run could hold (the reader says it cannot read it)
        if exc.errno in (errno.ENAMETOOLONG, errno.ELOOP):
            return None
        raise
    if not stat.S_ISREG(st.st_mode):
        return None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except FileNotFoundError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise
            with suppress(OSError, ValueError):
                head = os.pread(fd, 1 << 16, 0)
                for item in scan(head, final=False, budget=ReadBudget(len(head))):
                    if item.kind == "metadata" and item.record.name == "qchain.journal":
                        return int(item.record.metadata.get("pid", "0"))
            return 0
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log and publish time
_CHUNK_HEAD = struct.Struct("<BQQQQIIQ")  # opcode, record length, start and end time, size, crc, "", records length


def chunk_record(channel: int, sequence: int, log_time: int, publish_time: int, data) -> bytes:
    """An uncompressed MCAP chunk record holding one message record, as the mcap library's
    ``Writer`` writes it (``compression=NONE``, CRCs on): ``data`` a bytes-like payload,
    times in ns."""
    data = memoryview(data).cast("B")
    n = len(data)
    message = _MESSAGE_HEAD.pack(0x05, 22 + n, channel, sequence, log_time, publish_time)
    size = len(message) + n
    crc = zlib.crc32(data, zlib.crc32(message))
    return b"".join((_CHUNK_HEAD.pack(0x06, 40 + size, log_time, log_time, size, crc, 0, size), message, data))


class JournalWriter:
    """Appends batches of record rows to a journal (the simulating process's side).

    Parameters
    ----------
    path : path
        The journal file; created (or truncated), then locked.
    metadata : dict of str
        The recording's ``qchain`` metadata (sealed here again).
    mcap_path : str or None
        The recording the journal belongs to (None: a viewer-only run).
    """

    def __init__(self, path: str | os.PathLike, metadata: dict[str, str], mcap_path: str | None):
        self.path = Path(path)
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise LoggingError(f"another run is writing {mcap_path or self.path} (its journal {self.path} "
                                   "is locked)") from None
            raise
        os.ftruncate(fd, 0)
        self._fh = os.fdopen(fd, "wb")  # buffered: the Writer flushes it at each batch
        self._w = Writer(self._fh, chunk_size=1 << 40, compression=CompressionType.NONE,
                         index_types=IndexType.NONE, use_statistics=False, use_summary_offsets=False)
        self._w.start(profile="", library="qchain journal")
        self._w.add_metadata("qchain", seal({k: v for k, v in metadata.items() if k != "crc32"}))
        self._w.add_metadata("qchain.journal", seal({"pid": str(os.getpid()), "mcap": mcap_path or ""}))
        self._w.flush()
        self._channel: int | None = None
        self._seq = 0
        self.closed = False

    def start(self, layout: RecordLayout) -> None:
        """Declare the run's record layout (before the first batch)."""
        sid = self._w.register_schema("qchain.RecordRows", "", b"")
        self._channel = self._w.register_channel(ROWS_TOPIC, ROWS_ENCODING, sid,
                                                 {"layout": json.dumps(layout.to_json())})
        # the layout again, sealed, outside the first chunk: a damaged first chunk (which
        # declares the channel) does not take the rows of the later ones with it
        self._w.add_metadata(LAYOUT_RECORD, seal({"layout": json.dumps(layout.to_json()),
                                                  "channel": str(self._channel)}))

    def append(self, rows: np.ndarray) -> None:
        """Append rows (K, row_width) float64 as one message in a chunk of its own: on disk
        (in the operating system's hands) when this returns.

        The first batch goes through the mcap library's ``Writer`` (its chunk carries the
        schema and channel records too); the later ones are the same chunk record built
        here: one ``struct.pack`` and one CRC instead of the ``Writer``'s hundred-odd Python
        calls a chunk, the largest part of the journal's cost to the simulating process
        (``benchmarks/bench_recording_cost.py --journal``; a test checks the bytes equal
        the ``Writer``'s)."""
        t = rows[:, 0]
        log_time, publish_time = ns(float(t[-1])), ns(float(t[0]))
        if self._seq == 0:
            self._w.add_message(self._channel, log_time, rows.tobytes(), publish_time, 0)
            self._w.flush()
        else:
            self._fh.write(chunk_record(self._channel, self._seq & 0xFFFFFFFF, log_time, publish_time,
                                        np.ascontiguousarray(rows)))
            self._fh.flush()
        self._seq += 1

    def finish(self, outcome: dict[str, str]) -> None:
        """Write how the run ended and the journal's summary; keep the lock."""
        if self.closed:
            return
        self._w.add_metadata("qchain.outcome", seal(outcome))
        self._w.finish()
        self._fh.flush()
        self.closed = True

    def release(self, remove: bool) -> None:
        """Close the file (the lock goes with it); ``remove`` deletes it first."""
        if remove:
            with suppress(FileNotFoundError):
                self.path.unlink()
        with suppress(OSError):
            self._fh.close()


class JournalReader:
    """Reads a journal, also while it grows (the writer's and the reader's side).

    Call :meth:`poll` for what was appended since the last call: a list of row blocks
    (numpy arrays). ``layout``, ``metadata`` (the ``qchain`` entries), ``outcome`` and
    ``finished`` fill in as the journal says them; ``damage`` lists what could not be read
    (a damaged record, a layout or a block of rows that does not fit) and ``lost`` the part
    of it that may have held rows (all but a record cut at the end, where a killed run's
    journal stops).

    Parameters
    ----------
    path : path
        A regular file (a FIFO or a device is refused, never waited on).
    limits : ReadLimits or None
        What reading it may cost, in proportion to its size when opened (a journal left by
        a killed run is read within them; the writer reading its own run's journal, which
        grows, passes None).

    Raises
    ------
    FileNotFoundError
    RecordingFormatError
        Not a regular file, or it cannot be read.
    """

    def __init__(self, path: str | os.PathLike, limits: ReadLimits | None = None):
        self.path = Path(path)
        self._fd = open_regular(os.fspath(self.path))
        size = os.fstat(self._fd).st_size
        if limits is not None and size > limits.max_file_bytes:
            os.close(self._fd)
            self._fd = -1
            raise RecordingFormatError(f"{self.path}: the journal is {size} bytes, more than the "
                                       f"{limits.max_file_bytes} bytes a recording may have "
                                       "(ReadLimits.max_file_bytes allows more): refused")
        self._budget = None if limits is None else ReadBudget(size, limits)
        self._buf = bytearray()
        self._base = 0  # file offset of _buf[0]
        self._pos = len(MAGIC)  # next record's offset in the file
        self.layout: RecordLayout | None = None
        self.metadata: dict[str, str] | None = None
        self.outcome: dict[str, str] | None = None
        self.finished = False
        self.damage: list[str] = []
        self.lost: list[str] = []
        self._rows_channels: set[int] = set()

    def _lose(self, what: str) -> None:
        self.damage.append(what)
        self.lost.append(what)

    def _declare(self, channel: int, layout_json: str, where: str) -> None:
        """The rows channel ``channel`` of ``layout_json``, declared at ``where``: taken if it
        is the run's layout (one layout a journal; the same channel may be declared twice)."""
        try:
            layout = RecordLayout.from_json(loads(layout_json, "the journal's row layout"))
        except (ValueError, TypeError, KeyError) as exc:
            self._lose(f"the rows channel {channel} in {where}: its layout is not usable ({exc}): its rows are not "
                       "read")
            return
        if self.layout is not None and layout.to_json() != self.layout.to_json():
            self._lose(f"the rows channel {channel} in {where} has the layout {layout.to_json()}, the journal's "
                       f"first {self.layout.to_json()}: its rows are not read")
            self._rows_channels.discard(channel)
            return
        self.layout = layout
        self._rows_channels.add(channel)

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def poll(self, final: bool = False) -> list[np.ndarray]:
        """The row blocks appended since the last call. ``final``: the journal will not grow
        any more (its writer is gone): a cut record at its end is reported, not awaited.

        Raises
        ------
        LoggingError
            Not a qchain journal.
        LimitExceeded
            Past the reading budget.
        """
        size = os.fstat(self._fd).st_size  # read what is there now, never more
        while self._base + len(self._buf) < size:
            data = os.pread(self._fd, min(1 << 22, size - self._base - len(self._buf)), self._base + len(self._buf))
            if not data:
                break
            self._buf += data
        if self._base == 0 and len(self._buf) < len(MAGIC):
            return []
        if self._base == 0 and bytes(self._buf[: len(MAGIC)]) != MAGIC:
            raise LoggingError(f"{self.path} is not a qchain journal")
        out: list[np.ndarray] = []
        resume = self._pos
        for item in scan(self._buf, start=self._pos - self._base, final=final, budget=self._budget):
            resume = item.end + self._base
            if item.kind == "chunk":
                for rec in item.records:
                    if isinstance(rec, Channel) and rec.message_encoding == ROWS_ENCODING:
                        self._declare(rec.id, rec.metadata.get("layout", ""), f"the chunk at byte {item.offset}")
                    elif isinstance(rec, Message) and rec.channel_id in self._rows_channels:
                        width = self.layout.row_width
                        if len(rec.data) % (8 * width):
                            self._lose(f"a block of rows in the chunk at byte {item.offset} is {len(rec.data)} "
                                       f"bytes, not whole rows of {width} numbers: not read")
                            continue
                        out.append(np.frombuffer(rec.data, dtype=np.float64).reshape(-1, width))
                    elif isinstance(rec, Message):
                        self._lose(f"a block of rows in the chunk at byte {item.offset} is on channel "
                                   f"{rec.channel_id}, which no usable rows channel declares: not read")
            elif item.kind == "metadata":
                entries = unseal(item.record.metadata)
                if entries is None:
                    self._lose(f"metadata record {item.record.name[:80]!r} at byte {item.offset}: checksum mismatch")
                elif item.record.name == "qchain":
                    self.metadata = entries
                elif item.record.name == "qchain.outcome":
                    self.outcome = entries
                elif item.record.name == LAYOUT_RECORD:
                    cid = entries.get("channel", "")
                    if cid.isascii() and cid.isdigit() and len(cid) < 6:
                        self._declare(int(cid), entries.get("layout", ""), f"the metadata record at byte "
                                                                           f"{item.offset}")
            elif item.kind == "footer":
                self.finished = True
            elif item.kind == "damage":
                self._lose(item.reason)
            elif item.kind == "end":
                self.damage.append(item.reason)
        drop = resume - self._base
        if drop > (1 << 20):  # keep memory flat on long runs
            del self._buf[:drop]
            self._base += drop
        self._pos = resume
        return out
