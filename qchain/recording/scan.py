"""MCAP records one by one, with resynchronisation after damage.

The mcap library's ``StreamReader`` stops at the first damaged record, so one flipped bit
in a chunk would lose every intact chunk after it. :func:`scan` parses the records with
the library's own record classes, and where a record is damaged (a chunk whose CRC or
compression fails, a length that runs past the file, an unknown opcode) it reports the
damage and searches forward for the next record it can trust: a chunk whose uncompressed
data match its CRC, or a metadata record whose qchain seal matches. Every byte between is
reported as damaged; nothing after it is lost.

:func:`scan` also reads a file that is still being written (``final=False``): it stops
before a record that is not complete yet and says where to resume.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Chunk, Footer, Metadata
from mcap.stream_reader import breakup_chunk

from .records import unseal

__all__ = ["MAGIC", "Item", "scan", "summary_chunks"]

MAGIC = b"\x89MCAP0\r\n"
_HEAD = struct.Struct("<BQ")
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_KNOWN = {int(op) for op in Opcode}
_COMPRESSIONS = ("", "zstd", "lz4")


@dataclass
class Item:
    """One thing :func:`scan` found.

    ``kind`` is ``"chunk"`` (``records``: the records inside, ``chunk``: its header),
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


def _chunk(buf, pos: int, length: int) -> tuple[Chunk, list]:
    """The chunk record at ``pos`` (its body ``length`` bytes) and its records; raises
    ValueError on any damage."""
    body = pos + 9
    if length < _CHUNK_FIXED.size + 8:
        raise ValueError("chunk record too short")
    _, _, usize, _, clen = _CHUNK_FIXED.unpack_from(buf, body)
    if clen > 8 or length < _CHUNK_FIXED.size + clen + 8:
        raise ValueError("chunk compression field damaged")
    (dlen,) = struct.unpack_from("<Q", buf, body + _CHUNK_FIXED.size + clen)
    if _CHUNK_FIXED.size + clen + 8 + dlen != length:
        raise ValueError("chunk lengths disagree")
    if usize > 1 << 32:
        raise ValueError("chunk size field damaged")
    chunk = Chunk.read(ReadDataStream(io.BytesIO(bytes(buf[body : body + length]))))
    if chunk.compression not in _COMPRESSIONS:
        raise ValueError(f"unknown compression {chunk.compression!r}")
    if chunk.uncompressed_crc == 0:
        raise ValueError("chunk without a CRC")
    try:
        records = breakup_chunk(chunk, validate_crc=True)
    except ValueError:
        raise
    except Exception as exc:  # zstd errors, a damaged record inside, ...
        raise ValueError(f"{type(exc).__name__}: {exc}") from None
    return chunk, records


def _metadata(buf, pos: int, length: int) -> Metadata:
    rec = Metadata.read(ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : pos + 9 + length]))))
    return rec


def _trusted_at(buf, pos: int, size: int) -> Item | None:
    """The record at ``pos`` if it is one a resynchronisation may trust, else None."""
    if size - pos < 9:
        return None
    opcode, length = _HEAD.unpack_from(buf, pos)
    end = pos + 9 + length
    if end > size:
        return None
    if opcode == Opcode.CHUNK:
        try:
            chunk, records = _chunk(buf, pos, length)
        except (ValueError, struct.error, UnicodeDecodeError):
            return None
        return Item("chunk", pos, end, opcode, records=records, chunk=chunk)
    if opcode == Opcode.METADATA and length < 1 << 28:
        try:
            rec = _metadata(buf, pos, length)
        except Exception:
            return None
        if rec.name.startswith("qchain") and unseal(rec.metadata) is not None:
            return Item("metadata", pos, end, opcode, record=rec)
        return None
    if opcode == Opcode.FOOTER and length == 20 and bytes(buf[end : end + 8]) == MAGIC:
        return Item("footer", pos, end + 8, opcode)
    return None


def _resync(buf, start: int, size: int) -> Item | None:
    """The first trusted record at or after ``start``."""
    pos = start
    candidates = (Opcode.CHUNK, Opcode.METADATA, Opcode.FOOTER)
    while pos < size:
        nxt = min((i for i in (buf.find(bytes([op]), pos, size) for op in candidates) if i >= 0), default=-1)
        if nxt < 0:
            return None
        item = _trusted_at(buf, nxt, size)
        if item is not None:
            return item
        pos = nxt + 1
    return None


def scan(buf, start: int = len(MAGIC), final: bool = True):
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
            nxt = _resync(buf, pos + 1, size)
            if nxt is None:
                yield Item("end", pos, size, opcode, reason=f"the file ends inside a record at byte {pos}")
                return
            why = f"a record at byte {pos} claims {length} bytes, past the end of the file"
        else:
            try:
                if opcode == Opcode.CHUNK:
                    chunk, records = _chunk(buf, pos, length)
                    yield Item("chunk", pos, end, opcode, records=records, chunk=chunk)
                elif opcode == Opcode.METADATA:
                    yield Item("metadata", pos, end, opcode, record=_metadata(buf, pos, length))
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
                pos = end
                continue
            except (ValueError, struct.error, UnicodeDecodeError) as exc:
                why = f"{Opcode(opcode).name.lower()} record at byte {pos} is damaged ({exc})"
            except Exception as exc:  # the library's own errors on a damaged record
                why = f"record at byte {pos} is damaged ({type(exc).__name__}: {exc})"
        nxt = _resync(buf, pos + 1, size)
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



def summary_chunks(buf) -> list | None:
    """The chunk indexes of a complete file's summary, if its footer and summary are intact
    (the summary's CRC matches), else None."""
    from mcap.records import ChunkIndex

    size = len(buf)
    fpos = size - len(MAGIC) - 29
    if fpos < len(MAGIC) or bytes(buf[size - len(MAGIC):]) != MAGIC:
        return None
    opcode, length = _HEAD.unpack_from(buf, fpos)
    if opcode != Opcode.FOOTER or length != 20:
        return None
    start, offsets, crc = struct.unpack_from("<QQI", buf, fpos + 9)
    if not (len(MAGIC) <= start <= fpos) or crc == 0:
        return None
    import zlib

    got = zlib.crc32(bytes(buf[start:fpos]))
    got = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, start, offsets), got)
    if got != crc:
        return None
    out = []
    pos = start
    while pos + 9 <= fpos:
        opcode, length = _HEAD.unpack_from(buf, pos)
        if opcode == Opcode.CHUNK_INDEX:
            out.append(ChunkIndex.read(ReadDataStream(io.BytesIO(bytes(buf[pos + 9 : pos + 9 + length])))))
        pos += 9 + length
    return out
