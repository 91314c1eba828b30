"""The journal's hand-built chunk records against the mcap library's ``Writer`` and reader."""

import io

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from qchain.recording.journal import JournalReader, JournalWriter, chunk_record, journal_path
from qchain.recording.records import RecordLayout


def _writer_chunk(channel, sequence, log_time, publish_time, data: bytes) -> bytes:
    """The chunk record the mcap library writes for one message (the journal's settings)."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.NONE, index_types=IndexType.NONE,
               use_statistics=False, use_summary_offsets=False)
    w.start(profile="", library="x")
    sid = w.register_schema("s", "", b"")
    ch = w.register_channel("/c", "e", sid, {})
    w.add_message(ch, 1, b"first", 1, 0)  # the schema and channel go with the first chunk
    w.flush()
    before = buf.tell()
    assert ch == channel
    w.add_message(ch, log_time, data, publish_time, sequence)
    w.flush()
    return buf.getvalue()[before:]


def test_a_hand_built_chunk_equals_the_mcap_writer_s_bytes():
    rng = np.random.default_rng(3)
    for K, seq, t0, t1 in ((1, 1, 0, 0), (20, 7, 123_000_000, 503_000_000), (64, 0xFFFFFFFF, 10**15, 10**15 + 5)):
        rows = rng.normal(size=(K, 13))
        ref = _writer_chunk(1, seq, t1, t0, rows.tobytes())
        assert chunk_record(1, seq, t1, t0, rows) == ref
        assert chunk_record(1, seq, t1, t0, rows.tobytes()) == ref


def test_journal_batches_read_back_by_the_mcap_reader_and_the_journal_reader(tmp_path):
    """Batches after the first (hand-built chunks) read back bit for bit, by the mcap
    library's reader and by :class:`JournalReader`; a flipped bit in a hand-built chunk's
    rows fails its CRC: that batch is reported damaged, the others read."""
    lay = RecordLayout(3, 3, 3, 1, 4)
    path = journal_path(tmp_path / "run.mcap")
    jw = JournalWriter(path, {"format_version": "2"}, str(tmp_path / "run.mcap"))
    jw.start(lay)
    rng = np.random.default_rng(5)
    batches = []
    for b in range(5):
        rows = rng.normal(size=(b + 1, lay.row_width))
        rows[:, 0] = 0.1 * b + 0.02 * np.arange(b + 1)
        batches.append(rows)
        jw.append(rows if b != 3 else np.asfortranarray(rows))  # a non-contiguous caller too
    jw.finish({"success": "true"})
    jw.release(remove=False)
    with open(path, "rb") as fh:
        got = [np.frombuffer(m.data, dtype=np.float64).reshape(-1, lay.row_width)
               for _, _, m in make_reader(fh).iter_messages()]
    assert len(got) == 5 and all(np.array_equal(a, b) for a, b in zip(got, batches))
    jr = JournalReader(path)
    try:
        blocks = jr.poll(final=True)
        assert jr.finished and not jr.damage and jr.layout == lay
        assert len(blocks) == 5 and all(np.array_equal(a, b) for a, b in zip(blocks, batches))
    finally:
        jr.close()
    data = bytearray(path.read_bytes())
    at = bytes(data).find(batches[2].tobytes()) + 17
    data[at] ^= 0x10
    path.write_bytes(bytes(data))
    jr = JournalReader(path)
    try:
        blocks = jr.poll(final=True)
        assert len(jr.damage) == 1 and "CRC" in jr.damage[0].upper(), jr.damage
        assert len(blocks) == 4 and all(np.array_equal(a, b) for a, b in zip(blocks, batches[:2] + batches[3:]))
    finally:
        jr.close()
