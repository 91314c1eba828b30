"""MCAP records one by one, with resynchronisation after damage, within a reading budget.

The mcap library's ``StreamReader`` stops at the first damaged record; :func:`scan` parses
the records with the library's own record classes and, past damage, searches for the next
record it can trust (docs/recording.md, "Damage"), candidates found by one regular
expression so that the search stays linear. With ``final=False`` it reads a file still being
written, stopping before a record that is not complete yet."""

from __future__ import annotations

import io
import re
import struct
import zlib
from dataclasses import dataclass, field

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (Attachment, AttachmentIndex, Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message,
                          MessageIndex, Metadata, MetadataIndex, Schema, Statistics, SummaryOffset)

from .bounded import LimitExceeded, ReadBudget, decompress
from .records import unseal

__all__ = ["MAGIC", "Item", "scan", "summary_records"]

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_MESSAGE_FIXED = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_KNOWN = {int(op) for op in Opcode}
_COMPRESSIONS = ("", "zstd", "lz4")
#: The record classes that parse a record outside a chunk field by field (a length check)
_CLASSES = {Opcode.HEADER: Header, Opcode.METADATA: Metadata, Opcode.MESSAGE_INDEX: MessageIndex,
            Opcode.CHUNK_INDEX: ChunkIndex, Opcode.ATTACHMENT: Attachment, Opcode.ATTACHMENT_INDEX: AttachmentIndex,
            Opcode.STATISTICS: Statistics, Opcode.METADATA_INDEX: MetadataIndex,
            Opcode.SUMMARY_OFFSET: SummaryOffset, Opcode.DATA_END: DataEnd, Opcode.SCHEMA: Schema,
            Opcode.CHANNEL: Channel}
#: Where a record a resynchronisation may trust can start: a chunk, metadata or footer
#: opcode followed by a length below 2**40 (no record of a file under a terabyte is longer).
_CANDIDATE = re.compile(rb"[\x02\x06\x0c](?=.{5}\x00\x00\x00)", re.DOTALL)


@dataclass
class Item:
    """One thing :func:`scan` found.

    ``kind`` is ``"chunk"`` (``records``: the records inside, ``chunk``: its header,
    ``reason``: a size field found damaged while the data are intact, else ""),
    ``"metadata"`` (``record``), ``"footer"``, ``"record"`` (any other intact record,
    ``record`` is None: skipped by length), ``"damage"`` (``reason``; ``end`` is where
    reading went on) or ``"end"`` (the file ends inside a record, ``reason``). Offsets are
    bytes from the file's start.
    """

    kind: str
    offset: int
    end: int
    opcode: int = 0
    record: object = None
    records: list = field(default_factory=list)
    chunk: Chunk | None = None
    reason: str = ""


def _records(data: bytes, budget: ReadBudget | None, offset: int) -> list:
    """The records inside a chunk's uncompressed ``data`` (the library's record classes);
    records of an opcode the format does not know are skipped, as the library does."""
    out = []
    n = len(data)
    view = memoryview(data)
    p = 0
    count = 0
    left = budget.records_left if budget is not None else None
    while p < n:
        if n - p < 9:
            raise ValueError("a record cut at the end of the chunk data")
        opcode, length = _HEAD.unpack_from(data, p)
        e = p + 9 + length
        if e > n:
            raise ValueError(f"a record inside the chunk claims {length} bytes, past the chunk's end")
        if opcode == Opcode.MESSAGE:
            if length < _MESSAGE_FIXED.size:
                raise ValueError("a message record too short")
            cid, seq, log_time, publish_time = _MESSAGE_FIXED.unpack_from(data, p + 9)
            out.append(Message(channel_id=cid, sequence=seq, log_time=log_time, publish_time=publish_time,
                               data=bytes(view[p + 9 + _MESSAGE_FIXED.size : e])))
        elif opcode in (Opcode.CHANNEL, Opcode.SCHEMA):
            stream = ReadDataStream(io.BytesIO(view[p + 9 : e]))
            out.append((Channel if opcode == Opcode.CHANNEL else Schema).read(stream))
        elif opcode in _KNOWN or opcode == 0:
            raise ValueError(f"a record of opcode 0x{opcode:02x} inside a chunk")
        p = e
        count += 1
        if left is not None and count > left:
            budget.count(count, offset)  # raises
    if budget is not None:
        budget.count(count, offset)
    return out


def _chunk(buf, pos: int, length: int, budget: ReadBudget | None = None) -> tuple[Chunk, list, str]:
    """The chunk record at ``pos`` (its body ``length`` bytes), its records and a note (a
    damaged size field whose data are intact); raises ValueError on any damage,
    :class:`LimitExceeded` past the budget."""
    body = pos + 9
    if length < _CHUNK_FIXED.size + 8:
        raise ValueError("chunk record too short")
    start_t, end_t, usize, crc, clen = _CHUNK_FIXED.unpack_from(buf, body)
    if clen > 8 or length < _CHUNK_FIXED.size + clen + 8:
        raise ValueError("chunk compression field damaged")
    (dlen,) = struct.unpack_from("<Q", buf, body + _CHUNK_FIXED.size + clen)
    if _CHUNK_FIXED.size + clen + 8 + dlen != length:
        raise ValueError("chunk lengths disagree")
    if budget is None and usize > 1 << 32:
        raise ValueError("chunk size field damaged")
    try:
        compression = bytes(buf[body + _CHUNK_FIXED.size : body + _CHUNK_FIXED.size + clen]).decode()
    except UnicodeDecodeError:
        raise ValueError("chunk compression field damaged") from None
    if compression not in _COMPRESSIONS:
        raise ValueError(f"unknown compression {compression!r}")
    if crc == 0:
        raise ValueError("chunk without a CRC")
    a = body + _CHUNK_FIXED.size + clen + 8
    if budget is not None:
        budget.spend(dlen, pos)
    data = bytes(buf[a : a + dlen])
    raw = decompress(compression, data, usize, budget, pos)
    if zlib.crc32(raw) != crc:
        if len(raw) != usize:
            raise ValueError(f"its data decompress to {'more than ' if len(raw) > usize else ''}{len(raw)} "
                             f"bytes, not the {usize} it declares, and fail its CRC")
        raise ValueError("CRC mismatch")
    note = "" if len(raw) == usize else (f"the chunk at byte {pos} declares {usize} bytes uncompressed, its data "
                                         f"are {len(raw)} (they match its CRC: read, nothing lost)")
    try:
        records = _records(raw, budget, pos)
    except (ValueError, LimitExceeded):
        raise
    except Exception as exc:  # the library's EndOfFile, struct and UTF-8 errors on a damaged record inside
        raise ValueError(f"{type(exc).__name__}: {exc}") from None
    chunk = Chunk(compression=compression, data=data, message_start_time=start_t, message_end_time=end_t,
                  uncompressed_crc=crc, uncompressed_size=usize)
    return chunk, records, note


def _metadata(buf, pos: int, length: int, budget: ReadBudget | None = None) -> Metadata:
    if budget is not None:
        budget.spend(length, pos)
    try:
        return Metadata.read(ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : pos + 9 + length]))))
    except Exception as exc:  # EndOfFile, struct and UTF-8 errors of a damaged record
        raise ValueError(f"{type(exc).__name__}: {exc}") from None


def _exact(buf, pos: int, length: int, opcode: int, budget: ReadBudget | None) -> bool:
    """Whether the record at ``pos`` parses (the mcap library's record class) to exactly its
    ``length`` bytes; a message outside a chunk (its data are the rest of it) counts as such."""
    cls = _CLASSES.get(opcode)
    if cls is None:
        return opcode == Opcode.MESSAGE
    if budget is not None:
        budget.spend(length, pos)
    stream = ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : pos + 9 + length])))
    try:
        cls.read(stream)
    except Exception:  # the library's EndOfFile, struct and UTF-8 errors: it does not parse
        return False
    return stream.count == length


def _footer_pos(buf, start: int = len(MAGIC)) -> int | None:
    """Where a complete file's footer record is (its last 37 bytes: the record and the closing
    magic), if one is there at or after ``start``, else None."""
    size = len(buf)
    fpos = size - len(MAGIC) - 29
    if fpos < start or bytes(buf[size - len(MAGIC):]) != MAGIC:
        return None
    opcode, length = _HEAD.unpack_from(buf, fpos)
    return fpos if opcode == Opcode.FOOTER and length == 20 else None


def _followed(buf, end: int, size: int, final: bool) -> bool:
    """Whether a record skipped by its length ends where the file ends or another record
    could start: a known opcode whose length stays inside the file (or a header not written
    yet, for a file still growing)."""
    if end == size or (size - end < 9 and not final):
        return True
    if size - end < 9:
        return False
    opcode, length = _HEAD.unpack_from(buf, end)
    return opcode in _KNOWN and (end + 9 + length <= size or not final)


def _trusted_at(buf, pos: int, size: int, budget: ReadBudget | None = None) -> Item | None:
    """The record at ``pos`` if it is one a resynchronisation may trust, else None."""
    if size - pos < 9:
        return None
    opcode, length = _HEAD.unpack_from(buf, pos)
    end = pos + 9 + length
    if end > size:
        return None
    try:  # a record that does not parse is none to trust (a reading limit passed is said, never skipped)
        if opcode == Opcode.CHUNK:
            chunk, records, note = _chunk(buf, pos, length, budget)
            return Item("chunk", pos, end, opcode, records=records, chunk=chunk, reason=note)
        if opcode == Opcode.METADATA and length < 1 << 28:
            rec = _metadata(buf, pos, length, budget)
            if rec.name.startswith("qchain"):
                if budget is not None:
                    budget.spend(length, pos)  # the seal's check
                if unseal(rec.metadata) is not None:
                    return Item("metadata", pos, end, opcode, record=rec)
            return None
    except LimitExceeded:
        raise
    except ValueError:
        return None
    if opcode == Opcode.FOOTER and length == 20 and bytes(buf[end : end + 8]) == MAGIC:
        return Item("footer", pos, end + 8, opcode)
    return None


def _resync(buf, start: int, size: int, budget: ReadBudget | None = None) -> Item | None:
    """The first trusted record at or after ``start`` (linear in the bytes searched)."""
    for m in _CANDIDATE.finditer(buf, start, size):
        item = _trusted_at(buf, m.start(), size, budget)
        if item is not None:
            return item
    return None


def scan(buf, start: int = len(MAGIC), final: bool = True, budget: ReadBudget | None = None):
    """Items of the MCAP data in ``buf`` (bytes, bytearray or mmap) from ``start`` on.

    Parameters
    ----------
    buf : bytes-like
        The file's bytes (its magic included).
    start : int
        Offset of the first record.
    final : bool
        The file is complete as it stands. If False (a file still being written), a record
        not complete yet ends the scan without an ``"end"`` item; the last item's ``end`` is
        where to resume.
    budget : ReadBudget or None
        What the scan may process (None: no limit, for a file this process wrote).

    Raises
    ------
    LimitExceeded
        The budget is spent (a decompression bomb, crafted lengths, too many records).

    Yields
    ------
    Item
    """
    size = len(buf)
    pos = start
    while pos < size:
        if size - pos < 9:
            if final:
                yield Item("end", pos, size, reason=f"the file ends inside a record at byte {pos}")
            return
        opcode, length = _HEAD.unpack_from(buf, pos)
        end = pos + 9 + length
        why = ""
        if opcode not in _KNOWN:
            why = f"no MCAP record at byte {pos} (opcode 0x{opcode:02x})"
        elif end > size:
            if not final:
                return  # a record still being written
            nxt = _resync(buf, pos + 1, size, budget)
            if nxt is None:
                yield Item("end", pos, size, opcode, reason=f"the file ends inside a record at byte {pos}")
                return
            why = f"a record at byte {pos} claims {length} bytes, past the end of the file"
        else:
            try:
                if opcode == Opcode.CHUNK:
                    chunk, records, note = _chunk(buf, pos, length, budget)
                    yield Item("chunk", pos, end, opcode, records=records, chunk=chunk, reason=note)
                elif opcode != Opcode.FOOTER and not _followed(buf, end, size, final) and \
                        not _exact(buf, pos, length, opcode, budget):
                    # a length that was damaged larger would skip the records after it (a whole
                    # chunk): trusted only where its fields fill it exactly or a record follows it
                    raise ValueError(f"its length {length} does not end where another record starts")
                elif opcode == Opcode.METADATA:
                    yield Item("metadata", pos, end, opcode, record=_metadata(buf, pos, length, budget))
                elif opcode == Opcode.FOOTER:
                    Footer.read(ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : end]))))
                    if bytes(buf[end : end + 8]) != MAGIC:
                        if size - end < 8:  # cut inside the closing magic
                            if final:
                                yield Item("end", pos, size, opcode, reason="the file ends inside its closing magic")
                            return
                        raise ValueError("no closing magic after the footer")
                    yield Item("footer", pos, end + 8, opcode)
                    return
                else:
                    yield Item("record", pos, end, opcode)
                    if opcode == Opcode.DATA_END and final:
                        fpos = _footer_pos(buf, end)
                        if fpos is not None:  # the summary between: read by its CRC (summary_records)
                            yield Item("footer", fpos, size, Opcode.FOOTER)
                            return
                pos = end
                continue
            except LimitExceeded:
                raise
            except (ValueError, struct.error, UnicodeDecodeError) as exc:
                why = f"{Opcode(opcode).name.lower()} record at byte {pos} is damaged ({exc})"
            except Exception as exc:  # the library's own errors on a damaged record
                why = f"record at byte {pos} is damaged ({type(exc).__name__}: {exc})"
        nxt = _resync(buf, pos + 1, size, budget)
        if nxt is None:
            if not final:
                return  # maybe the rest is still coming
            yield Item("damage", pos, size, opcode, reason=why + "; nothing readable after it")
            return
        yield Item("damage", pos, nxt.offset, opcode, reason=why)
        yield nxt
        if nxt.kind == "footer":
            return
        pos = nxt.end



def summary_records(buf, budget: ReadBudget | None = None):
    """``(chunk indexes, statistics or None)`` of a complete file's summary, if its footer
    and summary are intact (the summary's CRC matches), else None; the records parsed
    are counted in ``budget``."""
    fpos = _footer_pos(buf)
    if fpos is None:
        return None
    start, offsets, crc = struct.unpack_from("<QQI", buf, fpos + 9)
    if not (len(MAGIC) <= start <= fpos) or crc == 0:
        return None
    got = zlib.crc32(bytes(buf[start:fpos]))
    got = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start, offsets), got)
    if got != crc:
        return None
    out = []
    stats = None
    pos = start
    try:
        while pos + 9 <= fpos:
            opcode, length = _HEAD.unpack_from(buf, pos)
            if pos + 9 + length <= fpos and opcode in (Opcode.CHUNK_INDEX, Opcode.STATISTICS):
                stream = ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : pos + 9 + length])))
                if budget is not None:
                    budget.count(1, pos)
                if opcode == Opcode.CHUNK_INDEX:
                    out.append(ChunkIndex.read(stream))
                else:
                    stats = Statistics.read(stream)
            pos += 9 + length
    except LimitExceeded:
        raise
    except Exception:  # a summary whose CRC matches but whose records do not parse: not used
        return None
    return out, stats
