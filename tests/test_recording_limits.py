"""Reading an untrusted recording is bounded in time and memory: compression bombs, huge declared
lengths, deep nesting, a million segments and big files are refused within the reading budget."""

import io
import json
import os
import struct
import time
import tracemalloc
import zlib

import pytest

from helpers import deadline
from qchain.cli.recording import layout_main, recover_main, replay_main
from qchain.logging import ReadLimits, RecordingFormatError, read_recording
from qchain.recording.scan import scan
from support import (
    assert_valid,
    chunk_record,
    craft,
    craft_chunks,
    info_json,
    refused_recording,
    splice,
    write,
    zstd_rle,
)


@pytest.mark.slow
def test_parsed_numbers_are_charged_to_the_reading_budget(tmp_path):
    """2 million backbone points of "[0.0,0.0,0.0]" in a 7 KiB zstd file once took 594 MB
    (1.26 GB at 4.4 million): orjson makes 53 bytes of objects a number. Now refused before
    parsing, naming the file and the byte, within the budget of the file's size."""
    import json

    from support import N_SEG, craft, good_states

    s = good_states(1)[0]
    P = 2_000_000
    text = json.dumps({**s, "backbone": "@"}).encode()
    pts = b"[" + b",".join([b"[0.0,0.0,0.0]"] * P) + b"]"
    blob = text.replace(b'"@"', b"[" + b",".join([pts] * N_SEG) + b"]")
    data = craft([blob], chunks=1)
    assert len(data) < 64 * 1024
    path = tmp_path / "amp.mcap"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(RecordingFormatError, match=r"the numbers of its state messages\): reading it would "
                                                       r"process more than"):
            read_recording(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20, peak


def test_a_file_bigger_than_the_limit_is_refused_before_it_is_read(tmp_path, capsys):
    """A sparse file of 64 GiB (before: a MemoryError, 'out of memory' with exit code 1, or
    the whole file read into memory): refused from its size, naming the file and the limit."""
    p = tmp_path / "huge.mcap"
    with open(p, "wb") as fh:
        fh.write(b"\x89MCAP0\r\n")
        fh.truncate(64 << 30)
    t0 = time.monotonic()
    with deadline(20, "reading a 64 GiB sparse file"):
        with pytest.raises(RecordingFormatError, match=r"huge\.mcap: the file is 68719476736 bytes .*"
                                                       r"ReadLimits\.max_file_bytes"):
            read_recording(p)
        assert recover_main([str(p)]) == 2
    assert time.monotonic() - t0 < 10
    err = capsys.readouterr().err
    assert err.startswith(f"qchain recover: error: {p}: the file is") and err.count("\n") == 1
    assert os.path.getsize(p) == 64 << 30
    small = tmp_path / "small.mcap"
    small.write_bytes(craft_chunks())
    with pytest.raises(RecordingFormatError, match="more than the 0.0009766 MiB"):
        read_recording(small, limits=ReadLimits(max_file_bytes=1024))
    with pytest.raises(ValueError, match="max_file_bytes"):
        ReadLimits(max_file_bytes=0)


def test_an_lz4_bomb_is_refused_within_the_budget(tmp_path):
    """The zstd bombs were tested; lz4 (at most 255:1, 64 MiB of zeros in 256 KiB) too: refused
    by the budget, naming the file, the byte and the limit to raise."""
    import lz4.frame

    good = craft_chunks()
    raw = bytes(64 << 20)
    bomb = lz4.frame.compress(raw, compression_level=0)
    c = b"lz4"
    body = struct.pack("<QQQII", 0, 0, len(raw), zlib.crc32(raw), len(c)) + c + struct.pack("<Q", len(bomb)) + bomb
    first = next(it.offset for it in scan(good) if it.kind == "chunk")
    p = tmp_path / "lz4bomb.mcap"
    p.write_bytes(good[:first] + struct.pack("<BQ", 0x06, len(body)) + body + good[first:])
    with deadline(20, "an lz4 bomb"):
        with pytest.raises(RecordingFormatError, match=rf"{p.name}: at byte {first}.*ReadLimits\.expansion"):
            read_recording(p, limits=ReadLimits(expansion=8.0, slack_bytes=1 << 20))
        assert len(read_recording(p)) == 6  # within the default budget: decompressed, its zeros are damage


@pytest.mark.parametrize("opcode", [0x01, 0x03, 0x05, 0x09, 0x0C, 0x80])
def test_a_record_claiming_2_63_bytes_loses_nothing(tmp_path, opcode):
    good = craft_chunks()
    first = next(it.offset for it in scan(good) if it.kind == "chunk")
    p = tmp_path / "long.mcap"
    p.write_bytes(good[:first] + struct.pack("<BQ", opcode, 1 << 63) + bytes(16) + good[first:])
    with deadline(10, "a record of 2**63 bytes"):
        rec = read_recording(p)
    assert len(rec) == 6 and rec.damage


def test_deep_nesting_is_refused_naming_the_file_and_the_byte(tmp_path):
    """Run information, channel list and a state message nested 100000 deep (a
    RecursionError before): each a RecordingFormatError naming the file and the byte."""
    deep = "[" * 100_000 + "]" * 100_000
    cases = [
        ({"info": '{"n_segments": 2, "params": {"x": ' + deep + "}}"}, None, "the run information"),
        ({"channels": deep}, None, "channel list"),
        ({"info": json.dumps(info_json(params={"x": json.loads("[" * 70 + "]" * 70)}))}, None, "nested more than 64"),
        (None, [b'{"t": 0, "step": 0, "q": ' + deep.encode() + b"}"], "the state message in the chunk at byte"),
    ]
    for k, (meta, states, what) in enumerate(cases):
        p = write(tmp_path, craft(states=states, meta=meta), f"deep{k}.mcap")
        err = refused_recording(p, what)
        assert "byte" in str(err)


@pytest.mark.slow
def test_a_million_segments_is_refused_at_once(tmp_path):
    """A 6 MB file declaring a million segments (a layout asking for 10 GiB before): refused
    from the metadata, in well under a second, by read_recording and by qchain layout."""
    n = 1_000_000
    data = craft(states=[], info=info_json(n_segments=n, radii=[0.015] * n, chamber_radii=None))
    assert len(data) > 6e6
    p = write(tmp_path, data)
    t0 = time.monotonic()
    refused_recording(p, "declares 1000000 segments, more than 10000")
    assert time.monotonic() - t0 < 5.0
    assert layout_main([str(p), "-o", str(tmp_path / "l.json")]) == 2
    assert not (tmp_path / "l.json").exists()
    # the limit is the reader's to raise
    ok = write(tmp_path, craft(info=info_json(n_segments=2)), "two.mcap")
    refused_recording(ok, "declares 2 segments, more than 1", limits=ReadLimits(max_segments=1))


def test_the_commands_raise_the_segment_limit_with_a_flag(tmp_path, capsys):
    """A run whose budget allowed more segments than the reader's default is read back by
    raising --max-segments, never by editing code; a value outside 1..1e6 is a usage error."""
    two = write(tmp_path, craft(info=info_json(n_segments=2)), "two.mcap")
    out = tmp_path / ("l" * 240 + ".json")  # its temporary name must stay under the 255-byte limit too
    assert layout_main([str(two), "-o", str(out), "--max-segments", "1"]) == 2
    assert "--max-segments of qchain replay, recover and layout" in capsys.readouterr().err
    assert layout_main([str(two), "-o", str(out), "--max-segments", "2"]) == 0 and out.stat().st_size > 0
    assert sorted(x.name for x in tmp_path.iterdir()) == sorted(["two.mcap", out.name])  # no temporary left
    for bad in ("0", "1000001"):
        with pytest.raises(SystemExit) as exc:
            layout_main([str(two), "--max-segments", bad])
        assert exc.value.code == 2 and f"found {bad}" in capsys.readouterr().err
    assert replay_main([str(two), "--rrd", str(tmp_path / "r.rrd"), "--max-segments", "1"]) == 2
    assert not (tmp_path / "r.rrd").exists()


@pytest.mark.slow
def test_a_zstd_bomb_is_refused_in_bounded_time_and_memory(tmp_path, gib_bomb):
    """A 32 KiB chunk expanding to 1 GiB (no answer in 60 s before): refused naming the file
    and the chunk's byte, within seconds, having held well under 1 GiB."""
    data = splice(craft(), gib_bomb)
    p = write(tmp_path, data)
    at = data.index(gib_bomb)
    tracemalloc.start()
    try:
        t0 = time.monotonic()
        err = refused_recording(p, "decompression bomb")
        elapsed = time.monotonic() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"at byte {at}" in str(err)
    assert elapsed < 10.0
    assert peak < 200 * 2**20, peak  # the budget: 64 MiB + 256 x 40 KB
    # the same through the commands: an error, exit code 2, the file left as it was
    assert layout_main([str(p)]) == 2 and recover_main([str(p)]) == 2
    assert p.read_bytes() == data


def test_a_bomb_declaring_a_small_size_is_refused_too(tmp_path):
    """The same frame in a chunk that declares 1000 bytes (the declared size is not
    trusted): refused as a bomb within the same bounds."""
    small = chunk_record("zstd", zstd_rle(1 << 30), 1000, 12345)
    data = splice(craft(), small)
    t0 = time.monotonic()
    err = refused_recording(write(tmp_path, data), "declaring 1000 bytes")
    assert "decompression bomb" in str(err) and f"at byte {data.index(small)}" in str(err)
    assert time.monotonic() - t0 < 10.0


def test_many_tiny_records_in_a_chunk_are_refused(tmp_path):
    """A chunk of 10 million empty private records (9 bytes each, 90 MB compressing to a
    few KB): refused by the record count before parsing them all."""
    import zstandard

    raw = b"\x80" + bytes(8)
    body = raw * 10_000_000
    rec = chunk_record("zstd", zstandard.ZstdCompressor(level=3).compress(body), len(body), zlib.crc32(body))
    del body
    p = write(tmp_path, splice(craft(), rec))
    t0 = time.monotonic()
    err = refused_recording(p)
    assert ("records inside chunks" in str(err) or "decompression bomb" in str(err))
    assert time.monotonic() - t0 < 10.0


def test_a_huge_declared_length_is_damage_not_an_allocation(tmp_path):
    """Records that declare lengths of up to 2**64 - 1 bytes: reported (the file ends inside
    a record, or damage), nothing allocated for them."""
    data = craft()
    first = next(item.offset for item in scan(data) if item.kind == "chunk")
    for length in (2**64 - 1, 2**40, len(data)):
        bad = data[:first + 1] + struct.pack("<Q", length) + data[first + 9:]
        rec = read_recording(write(tmp_path, bad, f"len{length}.mcap"))
        assert rec.damage and len(rec) == 3  # the first chunk lost, the second read
        assert_valid(rec)


def test_a_stream_is_read_up_to_its_limit(tmp_path):
    data = craft()
    assert len(read_recording(io.BytesIO(data))) == 6
    with pytest.raises(RecordingFormatError, match="more than 1000 bytes"):
        read_recording(io.BytesIO(data), limits=ReadLimits(max_stream_bytes=1000))
    with open("/dev/zero", "rb") as zero:  # an endless stream: refused from its first bytes
        with pytest.raises(RecordingFormatError, match="not an MCAP file"):
            read_recording(zero)
