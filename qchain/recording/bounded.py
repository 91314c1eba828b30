"""The bounded reading layer: what reading one recording may cost, and the pieces that keep to it.

Everything that reads a recording goes through here (docs/recording.md, "Files from anywhere").
A limit exceeded raises :class:`LimitExceeded`, a :class:`RecordingFormatError` that says the
offset, the limit and how to raise it; the reader adds the file's name."""

from __future__ import annotations

import io
import math
import os
import stat
from dataclasses import dataclass

from ..checks.paths import file_kind
from ..errors import LimitExceeded, RecordingFormatError

_MAGIC = b"\x89MCAP0\r\n"

__all__ = ["ReadLimits", "DEFAULT_LIMITS", "ReadBudget", "LimitExceeded", "open_source", "open_regular", "decompress",
           "loads", "depth"]


@dataclass(frozen=True)
class ReadLimits:
    """What reading one recording may cost; every limit exceeded is a
    :class:`~qchain.logging.RecordingFormatError` naming the file, the offset and the limit.

    Bytes processed may be ``expansion`` x the file's size + ``slack_bytes``, records inside chunks
    ``records_per_byte`` x its size + ``slack_records``; ``max_segments`` bounds the segments
    declared, ``max_depth`` JSON nesting, ``max_stream_bytes`` a stream, ``max_file_bytes`` a file
    (refused from its size, before it is read). Defaults and why: docs/recording.md, "Files from
    anywhere"."""

    expansion: float = 256.0
    slack_bytes: int = 64 << 20
    records_per_byte: float = 0.25
    slack_records: int = 100_000
    max_segments: int = 10_000
    max_depth: int = 64
    max_stream_bytes: int = 1 << 30
    max_file_bytes: int = 4 << 30

    def __post_init__(self) -> None:
        for name in ("expansion", "records_per_byte"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value)
                                                                                      and value > 0):
                raise ValueError(f"ReadLimits.{name} must be a finite number > 0, got {value!r}")
        for name in ("slack_bytes", "slack_records", "max_segments", "max_depth", "max_stream_bytes",
                     "max_file_bytes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"ReadLimits.{name} must be an int >= 1, got {value!r}")


DEFAULT_LIMITS = ReadLimits()


def _mib(n: float) -> str:
    return f"{n / (1 << 20):.4g} MiB"


class ReadBudget:
    """Bytes processed and records parsed while reading one file of ``size`` bytes."""

    def __init__(self, size: int, limits: ReadLimits = DEFAULT_LIMITS):
        self.limits = limits
        self.size = int(size)
        self.max_bytes = int(limits.expansion * self.size) + limits.slack_bytes
        self.max_records = int(limits.records_per_byte * self.size) + limits.slack_records
        self.bytes = 0
        self.records = 0

    @property
    def bytes_left(self) -> int:
        return max(0, self.max_bytes - self.bytes)

    @property
    def records_left(self) -> int:
        return max(0, self.max_records - self.records)

    def spend(self, n: int, offset: int, what: str = "") -> None:
        """Count ``n`` bytes processed at ``offset``; raise past the limit."""
        self.bytes += n
        if self.bytes > self.max_bytes:
            raise self.too_many_bytes(offset, what)

    def too_many_bytes(self, offset: int, what: str = "") -> LimitExceeded:
        lim = self.limits
        return LimitExceeded(
            f"at byte {offset}{f' ({what})' if what else ''}: reading it would process more than "
            f"{_mib(self.max_bytes)} ({lim.expansion:g} x its size of {self.size} bytes + {_mib(lim.slack_bytes)}): "
            "a decompression bomb or crafted lengths, refused (ReadLimits.expansion allows more)", offset)

    def count(self, n: int, offset: int) -> None:
        """Count ``n`` records parsed at ``offset``; raise past the limit."""
        self.records += n
        if self.records > self.max_records:
            lim = self.limits
            raise LimitExceeded(
                f"at byte {offset}: more than {self.max_records} records inside chunks ({lim.records_per_byte:g} a "
                f"byte of its {self.size} bytes + {lim.slack_records}): refused (ReadLimits.records_per_byte allows "
                "more)", offset)


# --------------------------------------------------------------------------------------
# Opening
# --------------------------------------------------------------------------------------


def open_regular(path: str) -> int:
    """A read-only file descriptor of the regular file ``path``.

    Never waits: a FIFO, a device, a socket or a folder is refused from its ``stat`` before
    it is opened and again from the opened descriptor (``O_NONBLOCK``), in case it changed
    in between.

    Raises
    ------
    FileNotFoundError
    RecordingFormatError
        Not a regular file, or it cannot be read (the message names the path and why).
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        mode = os.stat(path).st_mode
        fd = os.open(path, flags) if stat.S_ISREG(mode) else -1
    except FileNotFoundError:
        raise FileNotFoundError(2, "no such recording", path) from None
    except OSError as exc:  # permission denied, a path through a file, a name too long, ...
        raise RecordingFormatError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except ValueError as exc:  # a NUL byte in the path
        raise RecordingFormatError(f"{path!r}: not a usable path ({exc})") from None
    if fd < 0:
        raise RecordingFormatError(f"{path}: {file_kind(mode, detailed=True)}, not a recording file: refused")
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise RecordingFormatError(f"{path}: {file_kind(st.st_mode, detailed=True)}, not a recording file: refused")
    except BaseException:
        os.close(fd)
        raise
    return fd


def _too_big(name: str, size: int, why: str) -> RecordingFormatError:
    return RecordingFormatError(f"{name}: the file is {size} bytes ({_mib(size)}), {why}: refused")


def read_fd(fd: int, size: int, name: str) -> bytearray:
    """Exactly the first ``size`` bytes of ``fd`` (fewer if the file was cut meanwhile)."""
    try:
        buf = bytearray(size)
    except (MemoryError, OverflowError):
        raise _too_big(name, size, "more than this process can hold in memory") from None
    view = memoryview(buf)
    got = 0
    try:
        while got < size:
            n = os.readv(fd, [view[got:]])
            if n == 0:
                break
            got += n
    except OSError as exc:
        raise RecordingFormatError(f"{name}: cannot be read at byte {got} ({exc.strerror or exc})") from None
    finally:
        view.release()
    if got < size:
        del buf[got:]
    return buf


def open_source(source, argument: str, function: str, limits: ReadLimits = DEFAULT_LIMITS):
    """``(name, data, is_path)`` of a recording given as a path or a binary stream.

    A path is read to the size it has when opened (a file still growing is read as it stood:
    never an ``mmap``, which a file cut meanwhile would turn into a crash); a stream up to
    ``limits.max_stream_bytes``. A path that does not exist gives ``data = None``.

    Raises
    ------
    TypeError
        ``source`` is neither a path nor a binary stream (the message names ``argument``
        of ``function``).
    RecordingFormatError
        Not a regular file, cannot be read, a stream that is too long or not binary.
    """
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        if not isinstance(name, str):
            name = os.fsdecode(name)
        if name == "":
            raise ValueError(f"{function}: {argument} is an empty path")
        try:
            fd = open_regular(name)
        except FileNotFoundError:
            return name, None, True
        try:
            size = os.fstat(fd).st_size
            if size > limits.max_file_bytes:
                raise _too_big(name, size, f"more than the {_mib(limits.max_file_bytes)} a recording may have "
                                           "(ReadLimits.max_file_bytes allows more)")
            return name, read_fd(fd, size, name), True
        finally:
            os.close(fd)
    read = getattr(source, "read", None)
    if isinstance(source, (bytes, bytearray, memoryview)):
        raise TypeError(f"{function}: {argument} must be a path (str or os.PathLike) or a binary stream; got "
                        f"{type(source).__name__} (wrap bytes in io.BytesIO)")
    if not callable(read):
        raise TypeError(f"{function}: {argument} must be a path (str or os.PathLike) or a binary stream with read(); "
                        f"got {'None' if source is None else type(source).__name__}")
    if isinstance(source, io.TextIOBase):
        raise TypeError(f"{function}: {argument} is a text stream, not binary mode: expected a binary stream (open the file with 'rb')")
    name = getattr(source, "name", None)
    if not isinstance(name, str):
        name = f"<{type(source).__name__}>"
    cap = limits.max_stream_bytes
    data = bytearray()
    while len(data) <= cap:
        try:
            piece = read(min(1 << 20, cap + 1 - len(data)))
        except UnicodeDecodeError:  # a text stream the checks above did not know
            raise TypeError(f"{function}: {argument} is a text stream, not binary mode: expected a binary stream (open the file with "
                            "'rb')") from None
        except OSError as exc:
            raise RecordingFormatError(f"{name}: cannot be read at byte {len(data)} ({exc.strerror or exc})") from None
        if piece is None:  # a non-blocking stream with nothing now
            raise RecordingFormatError(f"{name}: the stream has no data now (non-blocking); pass a path or a "
                                       "blocking binary stream")
        if isinstance(piece, str):
            raise TypeError(f"{function}: {argument} is a text stream, not binary mode: expected a binary stream (open the file with "
                            "'rb')")
        if not isinstance(piece, (bytes, bytearray, memoryview)):
            raise TypeError(f"{function}: {argument}.read() returned {type(piece).__name__}, not bytes")
        if not piece:
            break
        data += piece
        if len(data) >= len(_MAGIC) and data[: len(_MAGIC)] != _MAGIC:
            break  # not an MCAP file: the reader says so from its first bytes, no need for the rest
    if len(data) > cap:
        raise RecordingFormatError(f"{name}: the stream holds more than {cap} bytes (ReadLimits.max_stream_bytes): "
                                   "refused")
    return name, data, False


# --------------------------------------------------------------------------------------
# Decompression
# --------------------------------------------------------------------------------------


def decompress(compression: str, data: bytes, declared: int, budget: ReadBudget | None, offset: int):
    """The chunk data ``data`` decompressed (bytes or bytearray), never more than the budget
    allows, whatever size the chunk declares or the data's own headers say.

    With a budget, decompression goes on up to what the budget has left (so a damaged size
    field loses nothing: the chunk's CRC decides whether the data are intact), in pieces (no
    buffer of a declared size is allocated ahead); data that expand further raise
    :class:`LimitExceeded`. Without one, up to ``declared + 1`` bytes. Data the codec
    cannot decode raise ``ValueError`` (damage: the caller reports the chunk and reads on).
    """
    left = declared if budget is None else budget.bytes_left
    if compression == "":
        out = data
    elif compression == "zstd":
        import zstandard

        out = bytearray()
        try:
            with zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=False) as r:
                while len(out) <= left:
                    piece = r.read(min(1 << 22, left + 1 - len(out)))
                    if not piece:
                        break
                    out += piece
        except zstandard.ZstdError as exc:
            raise ValueError(f"zstd: {exc}") from None
    elif compression == "lz4":
        import lz4.frame

        d = lz4.frame.LZ4FrameDecompressor()
        out = bytearray()
        try:
            piece = d.decompress(data, max_length=min(1 << 22, left + 1))
            while piece:
                out += piece
                if len(out) > left or d.eof:
                    break
                piece = d.decompress(b"", max_length=min(1 << 22, left + 1 - len(out)))
        except Exception as exc:  # lz4 says RuntimeError
            raise ValueError(f"lz4: {exc}") from None
    else:
        raise ValueError(f"unknown compression {compression!r}")
    if budget is not None:
        if len(out) > left:  # it does expand past what the budget allows
            raise budget.too_many_bytes(offset, f"a {compression or 'raw'} chunk of {len(data)} bytes declaring "
                                                f"{declared} bytes")
        budget.spend(len(out), offset)
    return out


# --------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------


def depth(value, limit: int) -> int:
    """Nesting depth of a parsed JSON value (a scalar 0), counted up to ``limit + 1``."""
    deepest = 0
    stack = [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = v.values()
        elif not isinstance(v, list):
            continue
        d += 1
        if d > deepest:
            deepest = d
            if d > limit:
                return d
        stack.extend((x, d) for x in v if isinstance(x, (dict, list)))
    return deepest


def loads(text, what: str, limits: ReadLimits = DEFAULT_LIMITS):
    """``text`` (str or bytes) parsed as JSON; ``ValueError`` saying ``what`` and why for
    anything that is not JSON with finite numbers nested at most ``limits.max_depth`` deep."""
    import orjson

    try:
        value = orjson.loads(text)
    except orjson.JSONDecodeError as exc:
        raise ValueError(f"{what} is not valid JSON ({exc})") from None
    if depth(value, limits.max_depth) > limits.max_depth:
        raise ValueError(f"{what} is nested more than {limits.max_depth} deep (ReadLimits.max_depth)")
    return value
