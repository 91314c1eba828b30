"""Damaged recordings: a flipped bit loses at most its own chunk, and damaged metadata is
reported, never used."""

from __future__ import annotations

import io

import numpy as np
import pytest
from logging_fixtures import arm_info, arm_records

from qchain.logging import RecordingFormatError, RunLogger, read_recording
from qchain.recording.scan import scan

N = 600


@pytest.fixture(scope="module")
def clean():
    """A recording of N records in about 12 chunks, and where its records are."""
    records = arm_records(N, dt=1e-3)
    buf = io.BytesIO()
    with RunLogger(arm_info(), buf, flush_interval=0.05, quiet=True) as log:
        for r in records:
            log.log(r)
    data = buf.getvalue()
    chunks, metas = [], []
    first = 0
    for item in scan(data):
        if item.kind == "chunk":
            k = sum(1 for r in item.records if type(r).__name__ == "Message" and r.channel_id == 1)
            chunks.append((item.offset, item.end, first, first + k))
            first += k
        elif item.kind == "metadata":
            metas.append((item.offset, item.end, item.record.name))
    assert first == N and len(chunks) >= 10
    t = np.array([r.t for r in records])
    q = np.array([r.q for r in records])
    return data, chunks, metas, t, q


def _flip(data: bytes, pos: int, bit: int) -> bytes:
    b = bytearray(data)
    b[pos] ^= 1 << bit
    return bytes(b)


def test_a_flipped_bit_in_a_chunk_loses_only_that_chunk(clean):
    """90 single-bit flips at random places inside chunks: each recording reads; every
    record outside the damaged chunk is there, equal to what was logged; the records lost are
    those of that chunk at most, and the gap names the time range around them."""
    data, chunks, _, t, q = clean
    rng = np.random.default_rng(17)
    lost_only_itself = 0
    for _ in range(90):
        c = int(rng.integers(len(chunks)))
        a, b, first, last = chunks[c]
        pos = int(rng.integers(a, b))
        rec = read_recording(io.BytesIO(_flip(data, pos, int(rng.integers(8)))))
        idx = np.searchsorted(t, rec.t)
        np.testing.assert_array_equal(rec.t, t[idx])
        np.testing.assert_array_equal(rec.q, q[idx])
        missing = sorted(set(range(N)) - set(idx.tolist()))
        assert set(missing) <= set(range(first, last)), (pos, missing[:3])
        if missing:
            assert missing == list(range(first, last))  # the whole chunk, nothing else
            (gap,) = rec.gaps
            assert gap.after_t == (t[first - 1] if first else None) and gap.before_t == (t[last] if last < N else None)
            assert rec.to_trajectory().success is False and "are missing" in rec.to_trajectory().message
        else:  # a bit the CRC does not cover and the reading does not need (a chunk's time fields)
            assert not rec.gaps
        lost_only_itself += 1
    assert lost_only_itself == 90


def test_flips_outside_the_chunks_lose_nothing(clean):
    """Flips in the header, metadata, message indexes, summary and footer: every record
    still reads; a damaged qchain metadata record is reported (its CRC32 seal fails) and
    its intact second copy is used; a damaged outcome is reported and not used."""
    data, chunks, metas, t, q = clean
    inside = np.zeros(len(data), dtype=bool)
    for a, b, _, _ in chunks:
        inside[a:b] = True
    outside = np.flatnonzero(~inside[8:]) + 8
    rng = np.random.default_rng(18)
    for pos in rng.choice(outside, 60, replace=False).tolist():
        flipped = _flip(data, pos, int(rng.integers(8)))
        rec = read_recording(io.BytesIO(flipped))
        np.testing.assert_array_equal(rec.t, t)
        np.testing.assert_array_equal(rec.q, q)
        assert not rec.gaps
        assert rec.info == arm_info()
        for a, b, name in metas:
            if a <= pos < b:
                assert rec.damage, (pos, name)
                if name == "qchain.outcome":
                    assert rec.outcome is None
    # the first qchain metadata copy damaged: reported, the second copy is used
    a, b, name = metas[0]
    assert name == "qchain"
    scene_at = data.index(b"synthetic", a)  # inside the scene text
    rec = read_recording(io.BytesIO(_flip(data, scene_at, 0)))
    assert rec.info.scene == arm_info().scene and any("fails its checksum" in d for d in rec.damage)


def test_a_damaged_length_outside_the_chunks_never_swallows_a_chunk(clean):
    """Four bits of the length of every record between the chunks (the header, the metadata,
    the message indexes, the data end), flipped: a length grown past its record
    once skipped the chunk after it unread (a third of a recording lost to one bit); now a
    skipped record must end where another starts, else the reading resynchronises after it."""
    from qchain.recording.scan import MAGIC

    data, chunks, _, t, q = clean
    inside = np.zeros(len(data), dtype=bool)
    for a, b, _, _ in chunks:
        inside[a:b] = True
    between = []
    for item in scan(data):
        if not inside[item.offset] and item.kind != "footer":
            between.append(item.offset)  # up to the data end (the summary is read by its CRC)
    assert len(between) >= 10 and between[0] == len(MAGIC)
    flips = 0
    for pos in between:
        for bit in (3, 12, 20, 33):  # lengths grown by 8 B, 4 KiB (a chunk's size), 1 MiB, 8 GiB
            rec = read_recording(io.BytesIO(_flip(data, pos + 1 + bit // 8, bit % 8)))
            np.testing.assert_array_equal(rec.t, t, err_msg=f"length of the record at byte {pos}, bit {bit}")
            np.testing.assert_array_equal(rec.q, q)
            assert not rec.gaps
            flips += 1
    assert flips == 4 * len(between)


def test_damaged_metadata_is_never_used_silently(clean):
    """Both copies of the qchain metadata damaged: a clear error, not a recording whose scene
    or radii changed without a word."""
    data, _, metas, _, _ = clean
    copies = [(a, b) for a, b, name in metas if name == "qchain"]
    assert len(copies) == 2
    flipped = data
    for a, b in copies:
        flipped = _flip(flipped, flipped.index(b"radii", a), 2)
    with pytest.raises(RecordingFormatError, match="qchain metadata record is damaged"):
        read_recording(io.BytesIO(flipped))


def test_a_flipped_bit_in_a_chunk_size_field_loses_nothing(clean):
    """Flips in each chunk's declared uncompressed size (a little larger, much larger, beyond
    any reading budget): the size is not trusted, the data decompress within the budget
    and match the chunk's CRC, so every record reads back equal; the damaged field is
    reported, and the file is never refused as a decompression bomb."""
    import struct

    data, chunks, _, t, q = clean
    for a, _, _, _ in chunks[::3]:
        for bit in (3, 40, 62):
            pos = a + 9 + 16 + bit // 8  # the uncompressed size field (after start and end times)
            flipped = _flip(data, pos, bit % 8)
            assert struct.unpack_from("<Q", flipped, a + 25)[0] != struct.unpack_from("<Q", data, a + 25)[0]
            rec = read_recording(io.BytesIO(flipped))
            np.testing.assert_array_equal(rec.t, t)
            np.testing.assert_array_equal(rec.q, q)
            assert not rec.gaps
            assert [d for d in rec.damage if "declares" in d] == \
                [f"the chunk at byte {a} declares {struct.unpack_from('<Q', flipped, a + 25)[0]} bytes uncompressed, "
                 f"its data are {struct.unpack_from('<Q', data, a + 25)[0]} (they match its CRC: read, nothing lost)"]


def test_the_search_past_damage_is_linear(clean):
    """4 MB of bytes that each look like the start of a chunk record, after a damaged one:
    the search for the next trusted record examines each once (it took 66 s, quadratic in
    the damaged bytes, before); every record reads."""
    import time

    data, chunks, _, t, q = clean
    at = chunks[1][0]
    junk = (b"\x06\x05" + bytes(7)) * ((4 << 20) // 9)
    t0 = time.monotonic()
    rec = read_recording(io.BytesIO(data[:at] + junk + data[at:]))
    assert time.monotonic() - t0 < 10.0
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.q, q)
    assert any(f"byte {at}" in d for d in rec.damage)
